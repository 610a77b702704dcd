"""Provenance attributes attached to every granflow output.

Each output file carries the granflow version, the git commit of the source tree (when it is a
git checkout), a hash of the configuration that produced it, the run parameters and the unit
system, so that any number can be traced back to the code and inputs that made it.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import re
import subprocess
from pathlib import Path

from . import __version__
from .units import UNIT_SYSTEM


def git_commit(path: str | os.PathLike | None = None) -> str:
    """Commit hash of the git checkout holding ``path`` (default: this package), or 'unknown'.

    A '+dirty' suffix marks uncommitted changes to tracked files.  Without ``path`` it is the
    commit of the code this process *loaded*, read once when the module was imported: a run
    that writes its outputs hours later, after the checkout has moved on (an editable install
    under development), names the code that computed them, not the checkout's HEAD by then.
    """
    if path is None:
        return _LOADED_COMMIT
    return _query_git(Path(path))


def _query_git(where: Path) -> str:
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, timeout=10
        )
        if commit.returncode != 0:
            return "unknown"
        sha = commit.stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=where, capture_output=True, text=True, timeout=10,
        )
        return sha + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


_LOADED_COMMIT = _query_git(Path(__file__).resolve().parent)


def _canonical(obj):
    """JSON-serialisable canonical form (numpy scalars/arrays become plain lists/floats)."""
    try:
        import numpy as np

        if isinstance(obj, np.ndarray):
            return obj.tolist()
        if isinstance(obj, np.generic):
            return obj.item()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(obj, dict):
        return {str(k): _canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    return obj


def config_hash(config) -> str:
    """SHA-256 (hex, first 16 chars) of the canonical JSON form of a configuration mapping."""
    blob = json.dumps(_canonical(config), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def provenance_attrs(config=None, **parameters) -> dict:
    """Global attributes for an output: version, commit, config hash, parameters, units.

    Parameter values are stored as netCDF-compatible scalars/strings under ``param_<name>``.
    """
    attrs = {
        "granflow_version": __version__,
        "git_commit": git_commit(),
        "units_system": UNIT_SYSTEM,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    if config is not None:
        attrs["config_hash"] = config_hash(config)
        attrs["config_json"] = json.dumps(_canonical(config), sort_keys=True)
    for key, value in parameters.items():
        value = _canonical(value)
        if isinstance(value, bool):
            value = int(value)
        if value is None:
            value = "none"
        if isinstance(value, (list, dict)):
            value = json.dumps(value, sort_keys=True)
        attrs[f"param_{key}"] = value
    return attrs


def _host() -> str:
    import socket

    return socket.gethostname().replace("/", "_") or "localhost"


def temporary_path(path: str | os.PathLike) -> Path:
    """Name of the temporary sibling an atomic write of ``path`` goes through:
    ``.<name>.tmp-<host>-<pid>`` (host and pid tell a later run whether its writer is gone)."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp-{_host()}-{os.getpid()}")


#: temporary files of atomic writes: ``.<name>.tmp-<host>-<pid>`` (this module; older ones
#: without the host) and the library's ``.<name>.staging-<pid>-<hex>``
_TEMPORARY = re.compile(r"^\..+\.(?:tmp-(?:(?P<host>.+)-)?(?P<pid>\d+)"
                        r"|staging-(?P<spid>\d+)-[0-9a-f]+)$")


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    except OSError:
        return False
    return True


def remove_stale_temporaries(directory: str | os.PathLike) -> list[Path]:
    """Delete the temporary files that killed writers left in ``directory``.

    An atomic write goes through a temporary sibling (:func:`temporary_path`, the library's
    staging files) that is renamed into place at the end; a writer killed with SIGKILL (or a
    machine that went down) leaves it behind.  Such a file is removed when its writer is known
    to be gone: it was written on this host (or names no host) by a process that no longer
    runs.  Files of other hosts (a shared file system) are left alone.  Returns the removed
    paths; never raises.
    """
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    here = _host()
    for entry in entries:
        m = _TEMPORARY.match(entry.name)
        if m is None:
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
        except OSError:
            continue
        host = m.group("host")
        pid = int(m.group("pid") or m.group("spid"))
        if host is not None and host != here:
            continue
        if pid == os.getpid() or _pid_alive(pid):
            continue
        try:
            os.unlink(entry.path)
            removed.append(Path(entry.path))
        except OSError:
            pass
    return removed


def remove_stale_temporaries_under(root: str | os.PathLike) -> list[Path]:
    """:func:`remove_stale_temporaries` in ``root`` and every folder below it."""
    removed = []
    for folder, _, _ in os.walk(root):
        removed += remove_stale_temporaries(folder)
    return removed


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename).

    Temporaries left in that folder by killed writers are removed first
    (:func:`remove_stale_temporaries`); a failed write removes its own."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path.parent)
    tmp = temporary_path(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_to_netcdf(dataset, path: str | os.PathLike, **kwargs) -> None:
    """Write an xarray Dataset to netCDF atomically (temporary file, then rename).

    The CF encoding of :func:`granflow.cfconventions.encoding` (no _FillValue on coordinates,
    int32 instead of int64) is applied under any ``encoding`` given.  Temporaries left in the
    folder by killed writers are removed first (:func:`remove_stale_temporaries`)."""
    from .cfconventions import encoding as cf_encoding

    enc = cf_encoding(dataset)
    for name, e in (kwargs.pop("encoding", None) or {}).items():
        enc[name] = {**enc.get(name, {}), **e}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path.parent)
    tmp = temporary_path(path)
    try:
        dataset.to_netcdf(tmp, encoding=enc, **kwargs)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
