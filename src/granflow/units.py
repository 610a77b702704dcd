"""Units and CF attribute conventions used throughout granflow.

granflow works in the nondimensional units of Weinhart et al. (2012) §5: the flow-particle
diameter d, particle mass m and gravitational acceleration g are all 1, so lengths are in d,
times in sqrt(d/g), velocities in sqrt(g d), densities in m/d^3, stresses in m g/d^2.
For 0.1 mm glass beads the time unit is 3.1 ms and the velocity unit 0.031 m/s.

Every variable written by granflow carries CF-style ``units`` and ``long_name`` attributes;
:func:`cf` builds them so that the strings stay identical across modules.
"""

from __future__ import annotations

import math

#: The unit system, as stored in the ``units_system`` global attribute of every output.
UNIT_SYSTEM = "nondimensional: particle diameter d = 1, particle mass m = 1, gravity g = 1"

LENGTH = "d"
TIME = "sqrt(d/g)"
VELOCITY = "sqrt(g*d)"
ACCELERATION = "g"
MASS = "m"
DENSITY = "m d-3"
MASS_PER_AREA = "m d-2"
STRESS = "m g d-2"
FORCE = "m g"
ENERGY = "m g d"
SHEAR_RATE = "sqrt(g/d)"
ANGLE = "degree"
PER_DEGREE = "degree-1"
DIMENSIONLESS = "1"

#: Particle material density for d = m = 1: rho_p = m / (pi d^3 / 6).
RHO_PARTICLE = 6.0 / math.pi


def cf(units: str, long_name: str, **extra) -> dict:
    """CF attributes for one variable: ``units`` and ``long_name`` plus any extras."""
    attrs = {"units": units, "long_name": long_name}
    attrs.update(extra)
    return attrs
