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
import subprocess
from pathlib import Path

from . import __version__
from .units import UNIT_SYSTEM


def git_commit(path: str | os.PathLike | None = None) -> str:
    """Commit hash of the git checkout holding ``path`` (default: this package), or 'unknown'.

    A '+dirty' suffix marks uncommitted changes to tracked files.
    """
    where = Path(path) if path is not None else Path(__file__).resolve().parent
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


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def atomic_to_netcdf(dataset, path: str | os.PathLike, **kwargs) -> None:
    """Write an xarray Dataset to netCDF atomically (temporary file, then rename).

    The CF encoding of :func:`granflow.cfconventions.encoding` (no _FillValue on coordinates,
    int32 instead of int64) is applied under any ``encoding`` given."""
    from .cfconventions import encoding as cf_encoding

    enc = cf_encoding(dataset)
    for name, e in (kwargs.pop("encoding", None) or {}).items():
        enc[name] = {**enc.get(name, {}), **e}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        dataset.to_netcdf(tmp, encoding=enc, **kwargs)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
