"""Exact solutions the continuum solvers are tested against.

* :func:`mangeney_dam_break` -- dam break of an infinite reservoir of height h0 onto a dry,
  inclined, flat bed with Coulomb friction mu = tan(delta) (Mangeney, Heinrich & Roche 2000,
  Pure Appl. Geophys. 157, 1081), for Eq. (34) with alpha = 1 and stress ratio K:
  with c0 = sqrt(K g cos(theta) h0) and m = g sin(theta) - g cos(theta) tan(delta) (m >= 0),

      x <= x0 - c0 t + m t^2/2:   h = h0,  u = m t     (the reservoir slides as a block)
      x0 - c0 t + m t^2/2 < x < x0 + 2 c0 t + m t^2/2:
          h = (2 c0 - (x - x0)/t + m t/2)^2 / (9 K g cos(theta)),
          u = 2/3 ((x - x0)/t + c0 + m t)
      beyond the front x_B = x0 + 2 c0 t + m t^2/2:   h = 0.

  It is Ritter's frictionless solution in the frame that accelerates at m.  The test also checks
  this transcription against tilupy's independent implementation
  (``tilupy.analytic_sol.Mangeney_dry``, K = 1, g = 9.81: the same solution at t sqrt(9.81)).
"""

from __future__ import annotations

import math

import numpy as np

from .closures import G


def mangeney_dam_break(x, t: float, h0: float, theta: float, delta: float, *, x0: float = 0.0,
                       K: float = 1.0, g: float = G):
    """(h, u) of the Mangeney et al. (2000) dam break at positions ``x`` and time ``t`` > 0
    (theta, delta in degrees; requires theta >= delta so the whole fan moves downslope)."""
    if theta < delta:
        raise ValueError(f"theta = {theta} < delta = {delta}: the solution assumes m >= 0")
    if not t > 0:
        raise ValueError("t must be > 0")
    x = np.asarray(x, float)
    th, de = math.radians(theta), math.radians(delta)
    gc = g * math.cos(th)
    c0 = math.sqrt(K * gc * h0)
    m = g * math.sin(th) - gc * math.tan(de)
    xi = x - x0
    xa = -c0 * t + 0.5 * m * t * t
    xb = 2.0 * c0 * t + 0.5 * m * t * t
    fan = (xi > xa) & (xi < xb)
    h = np.where(xi <= xa, h0, np.where(fan, (2 * c0 - xi / t + 0.5 * m * t) ** 2 / (9 * K * gc),
                                        0.0))
    u = np.where(xi <= xa, m * t, np.where(fan, 2.0 / 3.0 * (xi / t + c0 + m * t), np.nan))
    return h, u


def dam_break_front(t: float, h0: float, theta: float, delta: float, *, x0: float = 0.0,
                    K: float = 1.0, g: float = G) -> float:
    """Front position x_B(t) = x0 + 2 c0 t + m t^2 / 2 of :func:`mangeney_dam_break`."""
    th, de = math.radians(theta), math.radians(delta)
    c0 = math.sqrt(K * g * math.cos(th) * h0)
    m = g * math.sin(th) - g * math.cos(th) * math.tan(de)
    return x0 + 2.0 * c0 * t + 0.5 * m * t * t
