"""granflow: closure relations for shallow granular flows from discrete particle simulations.

Pipeline (data flows one way): ``engine`` (numba DPM chute) -> ``coarse`` (coarse-graining,
Weinhart et al. 2012 §3) -> ``steady`` (flow-state classification, §6) -> ``fitting``
(closure fits, §9) -> ``closures`` (versioned netCDF closure libraries).

All quantities are nondimensional: particle diameter d = 1, mass m = 1, gravity g = 1
(see :mod:`granflow.units`).
"""

__version__ = "0.1.0"
