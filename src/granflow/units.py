"""Units and CF attribute conventions used throughout granflow.

granflow works in the nondimensional units of Weinhart et al. (2012) §5: the flow-particle
diameter d, particle mass m and gravitational acceleration g are all 1, so lengths are in d,
times in sqrt(d/g), velocities in sqrt(g d), densities in m/d^3, stresses in m g/d^2.
For 0.1 mm glass beads the time unit is 3.2 ms and the velocity unit 0.031 m/s.

Every variable written by granflow carries CF ``units`` and ``long_name`` attributes;
:func:`cf` builds them so that the strings stay identical across modules.  The constants below
(``LENGTH = "d"``, ``TIME = "sqrt(d/g)"``, ...) name each quantity's unit in the paper's
notation.  That notation is *not* a UDUNITS unit -- UDUNITS (cf_units, every CF-aware tool)
reads ``d`` as a day and ``m`` as a metre -- so the ``units`` attribute of a nondimensional
quantity is ``1`` (:func:`cf_units`), and the scale it is a multiple of is stated in the
``nondimensional_unit`` attribute (:func:`nondimensional_unit`), written for pint with
``particle_diameter``, ``particle_mass`` and pint's ``gravity`` (standard gravity)::

    ureg = pint.UnitRegistry()
    ureg.define("particle_diameter = 0.1 mm"); ureg.define("particle_mass = 1.4e-9 g")
    u = ds.u_bar.values * ureg(ds.u_bar.attrs["nondimensional_unit"])   # -> m/s via .to()

Angles keep ``degree`` (a UDUNITS unit).
"""

from __future__ import annotations

import math

import re

#: The unit system, as stored in the ``units_system`` global attribute of every output.
UNIT_SYSTEM = ("nondimensional: particle diameter d = 1, particle mass m = 1, gravity g = 1; "
               "variables have units '1' and state the scale they are a multiple of in "
               "'nondimensional_unit' (pint syntax: particle_diameter, particle_mass, gravity)")

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
DIFFUSIVITY = "d2 sqrt(g/d)"
ANGLE = "degree"
PER_DEGREE = "degree-1"
DIMENSIONLESS = "1"

#: Particle material density for d = m = 1: rho_p = m / (pi d^3 / 6).
RHO_PARTICLE = 6.0 / math.pi


#: pint names of the paper's scales d, m, g
SCALE_NAMES = {"d": "particle_diameter", "m": "particle_mass", "g": "gravity"}
#: units written as they are (UDUNITS units)
CF_UNITS_AS_IS = {ANGLE, PER_DEGREE, DIMENSIONLESS}

_TOKEN = re.compile(r"sqrt\(|[dmg](?:-?\d+)?|[()*/ ]")


def cf_units(units: str) -> str:
    """The CF (UDUNITS) ``units`` string of a unit in the paper's notation: angles and pure
    numbers as they are, every combination of d, m, g as ``1`` (nondimensional)."""
    return units if units in CF_UNITS_AS_IS else "1"


def nondimensional_unit(units: str) -> str | None:
    """The scale of a unit in the paper's notation as a pint expression, or None for angles and
    pure numbers: ``sqrt(d/g)`` -> ``(particle_diameter/gravity)**0.5``, ``m d-3`` ->
    ``particle_mass*particle_diameter**-3``."""
    if units in CF_UNITS_AS_IS:
        return None
    out, pos = [], 0
    text = units.strip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            raise ValueError(f"unit {units!r}: cannot read {text[pos:]!r} (use d, m, g, "
                             f"exponents like d-3, '*', '/', sqrt(...))")
        tok = m.group(0)
        pos = m.end()
        if tok == "sqrt(":
            out.append("sqrt(")
        elif tok[0] in SCALE_NAMES:
            out.append(SCALE_NAMES[tok[0]] + (f"**{int(tok[1:])}" if len(tok) > 1 else ""))
        elif tok == " ":
            out.append("*")
        else:
            out.append(tok)
    expr = "".join(out)
    # sqrt(...) -> (...)**0.5, innermost first
    while "sqrt(" in expr:
        i = expr.rindex("sqrt(")
        depth, j = 0, i + 4
        for j in range(i + 4, len(expr)):
            depth += {"(": 1, ")": -1}.get(expr[j], 0)
            if depth == 0:
                break
        expr = expr[:i] + expr[i + 4:j + 1] + "**0.5" + expr[j + 1:]
    return expr


def cf(units: str, long_name: str, **extra) -> dict:
    """CF attributes for one variable: ``units`` (UDUNITS, see :func:`cf_units`),
    ``long_name``, the ``nondimensional_unit`` scale where there is one, plus any extras.
    ``units`` is given in the paper's notation (the constants of this module)."""
    attrs = {"units": cf_units(units), "long_name": long_name}
    scale = nondimensional_unit(units)
    if scale is not None:
        attrs["nondimensional_unit"] = scale
    attrs.update(extra)
    return attrs
