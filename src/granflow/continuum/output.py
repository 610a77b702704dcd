"""CF/ACDD attributes and provenance for the datasets the continuum models return.

Every model result is an :class:`xarray.Dataset` whose variables carry CF ``units`` (``1`` with
the scale in ``nondimensional_unit``, see :mod:`granflow.units`) and ``long_name``; :func:`finish`
adds the provenance (granflow version, git commit, creation time, unit system) and the CF-1.8 /
ACDD-1.3 global attributes of :mod:`granflow.cfconventions`, so a result can be written with
:func:`granflow.provenance.atomic_to_netcdf` as it is.
"""

from __future__ import annotations

import datetime as _dt
import functools

from .. import __version__, cfconventions
from ..units import UNIT_SYSTEM


@functools.lru_cache(maxsize=1)
def _commit() -> str:
    from ..provenance import git_commit

    return git_commit()


def finish(ds, kind: str, title: str, summary: str):
    """Add provenance and CF/ACDD attributes to a continuum-model result (in place)."""
    ds.attrs.setdefault("granflow_version", __version__)
    ds.attrs.setdefault("git_commit", _commit())
    ds.attrs.setdefault("units_system", UNIT_SYSTEM)
    ds.attrs.setdefault("created", _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    ds.attrs.setdefault("continuum_model", kind)
    cfconventions.apply(ds, kind=f"continuum_{kind}", title=f"granflow {title}", summary=summary)
    ds.attrs["processing_level"] = "model output: continuum model driven by closure relations"
    ds.attrs["source"] = f"granflow {__version__} continuum model ({kind})"
    return ds
