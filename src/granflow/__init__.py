"""granflow: closure relations for shallow granular flows from discrete particle simulations.

Pipeline (data flows one way): ``engine`` (numba DPM chute) -> ``coarse`` (coarse-graining,
Weinhart et al. 2012 §3) -> ``steady`` (flow-state classification, §6) -> ``fitting``
(closure fits, §9) -> ``closures`` (versioned netCDF closure libraries).

All quantities are nondimensional: particle diameter d = 1, mass m = 1, gravity g = 1
(see :mod:`granflow.units`).
"""

__version__ = "0.1.0"


def _register_closures_accessor():
    """Make ``ds.closures`` (the closure evaluators, :class:`granflow.closures.evaluate.
    ClosuresAccessor`) available after ``import granflow``.  The evaluators are imported on
    first use: a placeholder descriptor on ``xarray.Dataset`` removes itself, imports
    :mod:`granflow.closures` (which registers the real accessor) and hands over."""
    try:
        import xarray as xr
    except ImportError:  # pragma: no cover - xarray is a dependency
        return
    if "closures" in vars(xr.Dataset):
        return

    class _ClosuresOnFirstUse:
        def __get__(self, obj, cls=None):
            if vars(xr.Dataset).get("closures") is self:
                delattr(xr.Dataset, "closures")
            from . import closures  # noqa: F401 -- registers ds.closures

            return xr.Dataset.closures if obj is None else obj.closures

    xr.Dataset.closures = _ClosuresOnFirstUse()


_register_closures_accessor()
