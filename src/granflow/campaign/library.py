"""Publish a campaign's closure library: one version per distinct content, never overwritten.

Versioning and reruns.  The versioned files ``<directory>/<name>-v<N>.nc`` are written by
:func:`granflow.closures.write_library`, which never overwrites a version.  A workflow may run
the library step again with *the same* fits (a forced rerun, a rerun after a killed job whose
resumed run ended with identical numbers, a changed notebook ...): :func:`publish_library`
therefore builds the dataset first, compares its ``content_hash`` (a hash of the data values,
not of provenance attributes such as ``created``) with the versions already present, and

* reuses the existing version when one has the same content (no new file),
* otherwise writes the next version N + 1.

The workflow's own output is the fixed path ``results/<campaign>/closures.nc`` -- a byte copy of
the chosen version -- plus ``library.json`` naming that version, so downstream rules and users
have a stable path while every distinct library ever produced stays on disk, unmodified.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from ..closures import build_library_dataset, library_path, library_versions, open_library
from ..closures import write_library
from ..provenance import atomic_write_bytes


def find_version_with_content(directory, name: str, content_hash: str):
    """Highest existing version of ``name`` in ``directory`` whose content hash matches."""
    for v in reversed(library_versions(directory, name)):
        path = library_path(directory, name, v)
        try:
            lib = open_library(path, verify=True)
        except (ValueError, OSError):
            continue
        if lib.attrs.get("content_hash") == content_hash:
            return v, path
    return None, None


def publish_library(directory, name: str, fits, table, *, out=None, manifest=None, config=None,
                    reductions: str | None = None, attrs=None) -> dict:
    """Write (or reuse) the library version with this content; copy it to ``out``.

    Returns ``{"path", "version", "content_hash", "reused"}`` (also written to ``manifest``).
    """
    directory = Path(directory)
    probe = build_library_dataset(fits, table, name=name, version=1, config=config, attrs=attrs,
                                  reductions=reductions)
    digest = probe.attrs["content_hash"]
    version, path = find_version_with_content(directory, name, digest)
    reused = path is not None
    if not reused:
        path = write_library(directory, name, fits, table, config=config, attrs=attrs,
                             reductions=reductions)
        version = int(open_library(path).attrs["library_version"])
    info = {"path": os.fspath(path), "version": int(version), "content_hash": digest,
            "reused": reused, "name": name}
    if out is not None:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
        shutil.copyfile(path, tmp)
        os.replace(tmp, out)
    if manifest is not None:
        atomic_write_bytes(manifest, json.dumps(info, indent=1).encode())
    return info
