"""CF-1.8 and ACDD-1.3 metadata shared by every granflow netCDF writer.

Each writer (``series.nc``, ``profiles.nc``, ``campaign_table.nc``, closure libraries) calls
:func:`apply` on its dataset before writing it with
:func:`granflow.provenance.atomic_to_netcdf`, which encodes it with :func:`encoding`:

* global attributes: ``Conventions = "CF-1.8, ACDD-1.3"``, ``title``, ``summary``, ``keywords``,
  ``history``, ``date_created`` (the provenance ``created``; also ``date_issued``,
  ``date_modified``, ``date_metadata_modified``), ``id``, ``naming_authority``,
  ``source``, ``processing_level``, ``product_version``, ``references``, ``comment`` (the unit
  system) and, where the configuration's ``metadata`` section states them, the attribution
  (creator, institution, publisher, project, license, ...: :func:`attribution`);
* per variable: ``coverage_content_type`` (``coordinate`` for coordinates,
  ``qualityInformation`` for uncertainties, spreads, flags and counts, ``modelResult`` for the
  rest) unless the writer set one;
* encoding: no ``_FillValue`` on coordinate variables (CF 2.5.1) and 32-bit instead of 64-bit
  integers (netCDF-3/CF tools do not read int64; values must fit, else ValueError).

What granflow deliberately does not write (see README "Output conventions"): CF
``standard_name`` (the standard-name table has no granular-flow quantities, and the few
generic names -- time, height -- require dimensional units), ACDD geospatial and
``time_coverage_*`` attributes (a simulation has no place on Earth and no calendar time).
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np

from . import __version__
from .units import UNIT_SYSTEM

CONVENTIONS = "CF-1.8, ACDD-1.3"
KEYWORDS = ("granular flow, shallow granular flow, discrete particle simulation, DEM, "
            "coarse-graining, closure relations, basal friction, segregation")
REFERENCES = ("Weinhart, Thornton, Luding & Bokhove (2012), Closure relations for shallow granular "
              "flows from particle simulations, Granular Matter 14, 531-552; Thornton, Weinhart, "
              "Ogarko & Luding, Multi-scale methods for multi-component granular materials")
#: configuration ``metadata`` keys copied into every output that knows the configuration
ATTRIBUTION_KEYS = ("creator_name", "creator_email", "creator_url", "creator_type",
                    "creator_institution", "institution", "publisher_name", "publisher_email",
                    "publisher_url", "publisher_type", "publisher_institution", "project",
                    "program", "license", "acknowledgement", "contributor_name",
                    "contributor_role")
#: attributes that hold the creation time (differ between two writes of the same data)
CREATION_TIME_ATTRS = ("history", "date_created", "date_issued", "date_modified",
                       "date_metadata_modified")
#: coverage_content_type of variables whose names end like this
QUALITY_SUFFIXES = ("_stderr", "_std", "_error", "_ok", "_n_points", "_message",
                    "_confidence", "n_snapshots", "n_windows")


#: environment variable carrying the attribution (JSON) to jobs that do not see the configuration
ATTRIBUTION_ENV = "GRANFLOW_METADATA"


def attribution(config=None) -> dict:
    """ACDD attribution: the configuration's ``metadata`` section, else the JSON in
    ``$GRANFLOW_METADATA`` (the workflow sets it for its jobs: attribution is not a run
    parameter, so changing it reruns nothing)."""
    meta = (config or {}).get("metadata") if isinstance(config, dict) else None
    if not meta and os.environ.get(ATTRIBUTION_ENV):
        try:
            meta = json.loads(os.environ[ATTRIBUTION_ENV])
        except ValueError:
            raise ValueError(f"${ATTRIBUTION_ENV} is not valid JSON: "
                             f"{os.environ[ATTRIBUTION_ENV][:200]!r}") from None
    return {k: str(v) for k, v in (meta or {}).items() if k in ATTRIBUTION_KEYS and v}


def coverage_content_type(name: str, is_coord: bool) -> str:
    """ISO 19115-1 content type of a variable (ACDD ``coverage_content_type``)."""
    if is_coord:
        return "coordinate"
    if name.endswith(QUALITY_SUFFIXES):
        return "qualityInformation"
    return "modelResult"


def _command_line() -> str:
    argv = [a if len(a) < 200 else a[:200] + "..." for a in sys.argv]
    return " ".join(argv)


def apply(ds, *, kind: str, title: str, summary: str, config=None, identifier=None):
    """Add the CF/ACDD global and variable attributes to ``ds`` (in place; returns ``ds``).

    ``kind`` names the output (``series``, ``profiles``, ``campaign_table``,
    ``closure_library``); ``config`` is the configuration whose ``metadata`` section gives the
    attribution; ``identifier`` becomes ``id`` (default: ``granflow-<kind>-<config_hash>``).
    Attributes the writer already set are kept.
    """
    attrs = ds.attrs
    created = attrs.get("created")
    config_hash = attrs.get("config_hash", "")
    defaults = {
        "Conventions": CONVENTIONS,
        "title": title,
        "summary": summary,
        "keywords": KEYWORDS,
        "history": (f"{created + ' ' if created else ''}created by granflow {__version__} "
                    f"({kind}): {_command_line()}"),
        "date_created": created,
        "date_issued": created,
        "date_modified": created,
        "date_metadata_modified": created,
        "id": identifier or f"granflow-{kind}" + (f"-{config_hash}" if config_hash else ""),
        "naming_authority": "granflow",
        "source": f"granflow {__version__} discrete particle simulation (numba DEM)",
        "processing_level": ("model output: coarse-grained particle simulation"
                             if kind in ("series", "profiles") else
                             "derived: fits and tables from coarse-grained particle simulations"),
        "product_version": __version__,
        "references": REFERENCES,
        "comment": f"units: {UNIT_SYSTEM}",
        "granflow_output": kind,
    }
    defaults.update(attribution(config))
    for key, value in defaults.items():
        if value is not None and key not in attrs:
            attrs[key] = value
    if attrs.get("Conventions") != CONVENTIONS:
        attrs["Conventions"] = CONVENTIONS
    coords = set(ds.coords)
    for name, var in ds.variables.items():
        var.attrs.setdefault("coverage_content_type",
                             coverage_content_type(str(name), name in coords))
    return ds


def encoding(ds) -> dict:
    """netCDF encoding: no _FillValue on coordinates, int64 stored as int32, strings as
    fixed-width UTF-8 character arrays (CF's classic strings; xarray reads them back as
    strings) instead of HDF5 variable-length strings.

    Why character arrays: a variable-length string's length is a number in the file, and HDF5
    allocates what it says before it can tell the file is corrupt -- one flipped byte made the
    reader of a 0.5 MB closure library (schema 2.0) allocate 1.2 GB before it failed.  A
    character array is the size its shape declares (``benchmarks/library_damage_memory.py``:
    142 of 549 stored lengths set to ~1e9 grew a 2.0 library's reader by up to 1 GB, none of
    the 514 a 2.1 library keeps -- netCDF-4's dimension lists -- by more than 10 MB)."""
    enc = {}
    for name, var in ds.variables.items():
        e = {}
        if name in ds.coords:
            e["_FillValue"] = None
        if var.dtype.kind in "OUS":
            e["dtype"] = "S1"
        if var.dtype.kind in "iu" and var.dtype.itemsize == 8:
            values = np.asarray(var.values)
            if values.size and (values.min() < np.iinfo(np.int32).min
                                or values.max() > np.iinfo(np.int32).max):
                raise ValueError(f"variable {name!r} does not fit in int32 (CF tools do not "
                                 "read int64)")
            e["dtype"] = "int32"
        if e:
            enc[name] = e
    return enc
