"""Coarse-graining of DEM snapshots into depth profiles and depth averages (Weinhart 2012 §3).

* :class:`DepthProfileAccumulator` / :func:`coarse_grain_profiles`: Gaussian coarse-grained
  density (Eq. 13), momentum (Eq. 16), velocity (Eq. 17) and stress (Eq. 32, with the flow-base
  half-line term) averaged over the periodic x-y plane and over time (Eq. 43), as an xarray
  Dataset with dim ``z``.
* :mod:`granflow.coarse.derived`: flow height (Eq. 42), depth averages (Eq. 33), bulk density
  (Eq. 51), local friction / shear rate / inertial number profiles.
* :mod:`granflow.coarse.diffusion`: tagged-particle self-diffusion in z and its closure;
  :mod:`granflow.coarse.segregation_flux`: the small particles' volume flux through each level
  in a segregation transient and T-eq. (27)'s rates regressed on it.
"""

from .derived import (
    KAPPA,
    depth_average_summary,
    depth_averages,
    flow_height,
    interval_mean,
    local_profiles,
)
from .profiles import (
    DEFAULT_CUTOFF,
    DEFAULT_WIDTH,
    SNAPSHOT_KEYS,
    DepthProfileAccumulator,
    coarse_grain_profiles,
)

__all__ = [
    "DEFAULT_CUTOFF",
    "DEFAULT_WIDTH",
    "KAPPA",
    "SNAPSHOT_KEYS",
    "DepthProfileAccumulator",
    "coarse_grain_profiles",
    "depth_average_summary",
    "depth_averages",
    "flow_height",
    "interval_mean",
    "local_profiles",
]
