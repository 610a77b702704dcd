"""Bulk density and normal-stress-ratio closures.

* Bulk density, Weinhart et al. (2012) Eq. (52): ``rho_c / rho_p = c0 - exp((theta - c2) / c1)``
  (theta, c1, c2 in degrees; rho_p = 6/pi for d = m = 1). Paper: c0 = 0.5985, c1 = 4.8,
  c2 = 40.85 deg, err = 0.002 (fitted to steady disordered flows with lambda > 0).
* Stress ratio, Eq. (53): ``K = 1 + (theta - d1) / d0``. Paper: d0 = 132 deg, d1 = 21.50 deg,
  err = 0.013.

Both are fitted by weighted least squares (:mod:`.lsq`: the runs' decorrelated standard errors as
weights, covariance inflated by the Birge ratio when the scatter exceeds them) with stated
reduced forms when the full form is not identified (:mod:`.forms`, :mod:`.identify`); error
Eq. (49) of the residuals (of rho_c/rho_p and of K respectively).
"""

from __future__ import annotations

import math

import numpy as np

from ..units import RHO_PARTICLE
from .forms import Form, _parts, fit_forms
from .result import FitResult, data_range, failed_fit, finite_mask

EQ52 = "Weinhart et al. 2012 Eq. (52)"
EQ53 = "Weinhart et al. 2012 Eq. (53)"
DENSITY_PARAMS = ("c0", "c1", "c2", "nu_ref", "dnu_dtheta")
STRESS_RATIO_PARAMS = ("d0", "d1", "K_ref")


def density_eq52(theta, c0, c1, c2, rho_p: float = RHO_PARTICLE):
    """Eq. (52): bulk density rho_c (m d-3) at inclination theta (degrees)."""
    theta = np.asarray(theta, dtype=float)
    out = rho_p * (c0 - np.exp((theta - c2) / c1))
    return out[()] if out.ndim == 0 else out


def stress_ratio_eq53(theta, d0, d1):
    """Eq. (53): normal stress ratio K at inclination theta (degrees)."""
    out = 1.0 + (np.asarray(theta, dtype=float) - d1) / d0
    return out[()] if np.ndim(out) == 0 else out


def _density_forms(theta_ref: float):
    def eq52(t, c0, c1, c2):
        return c0 - np.exp((t - c2) / c1)

    def p0_eq52(t, y):
        c0 = float(np.max(y)) + 0.01
        c1 = 5.0
        c2 = float(np.max(t) - c1 * math.log(max(c0 - y[np.argmax(t)], 1e-6)))
        return [c0, c1, c2]

    return [
        Form("eq52", eq52, ("c0", "c1", "c2"), p0_eq52, "rho_c/rho_p = c0 - exp((theta - c2)/c1)",
             bounds={"c0": (0.0, 1.0), "c1": (1e-3, 90.0), "c2": (-90.0, 500.0)},
             min_points=4),
        Form("linear", lambda t, a, b: a + b * (t - theta_ref), ("nu_ref", "dnu_dtheta"),
             lambda t, y: [float(np.mean(y)), 0.0],
             f"rho_c/rho_p = nu_ref + dnu_dtheta (theta - {theta_ref:.4g}) over the fitted "
             "range (the curvature of Eq. 52 is not identified)", min_points=3),
        Form("constant", lambda t, a: a + 0.0 * t, ("nu_ref",), lambda t, y: [float(np.mean(y))],
             "rho_c/rho_p = nu_ref over the fitted range (no trend with theta identified)",
             min_points=3),
    ]


def fit_bulk_density(theta, rho_c, *, sigma=None, rho_p: float = RHO_PARTICLE, lam=None,
                     contact_law=None, min_points: int = 4, ids=None, selection: str = "",
                     seed: int = 0, sigma_parts=None) -> FitResult:
    """Fit Eq. (52) to bulk densities rho_c (m d-3) of steady runs at inclinations theta (deg).

    ``sigma``: standard errors of rho_c (weights, absolute covariance).  Falls back to a linear,
    then a constant volume fraction over the fitted range when Eq. (52)'s parameters are not
    identified (:mod:`.forms`); the parameters are ``c0, c1, c2`` (Eq. 52) and ``nu_ref,
    dnu_dtheta`` (reduced forms, reference angle ``extra["theta_ref"]``).  The paper fits all
    steady disordered flows with lambda > 0 together; select those runs before calling.
    """
    coords = dict(lam=lam, contact_law=contact_law)
    theta, rho_c = (np.asarray(x, dtype=float).ravel() for x in (theta, rho_c))
    m = finite_mask(theta, rho_c)
    ids = np.asarray(ids if ids is not None else np.arange(theta.size)).astype(str)
    n = int(m.sum())
    if n < 2:
        return failed_fit("density", EQ52, DENSITY_PARAMS,
                          f"too few runs: {n}, need {min_points}", n, **coords)
    th, y = theta[m], rho_c[m] / rho_p
    sd = None if sigma is None else np.asarray(sigma, dtype=float).ravel()[m] / rho_p
    theta_ref = float(np.mean(th))
    forms = _density_forms(theta_ref)
    forms[0].min_points = min_points
    return fit_forms(
        "density", EQ52, DENSITY_PARAMS, forms, th, y, sigma=sd, ids=ids[m], coords=coords,
        valid_range={"theta": data_range(th)}, extra={"rho_p": rho_p, "theta_ref": theta_ref},
        error_measure="Eq. (49) of rho_c/rho_p - fit (volume fraction)", selection=selection,
        seed=seed, sigma_parts={k: v / rho_p for k, v in (_parts(sigma_parts, m) or {}).items()})


def fit_stress_ratio(theta, K, *, sigma=None, lam=None, contact_law=None,
                     min_points: int = 3, ids=None, selection: str = "", seed: int = 0,
                     sigma_parts=None) -> FitResult:
    """Fit Eq. (53) K = 1 + (theta - d1)/d0 to stress ratios of steady runs (theta in degrees).

    ``sigma``: standard errors of K.  Falls back to a constant ``K_ref`` over the fitted range
    when no trend with theta is identified (d0 unidentified).
    """
    coords = dict(lam=lam, contact_law=contact_law)
    theta, K = (np.asarray(x, dtype=float).ravel() for x in (theta, K))
    m = finite_mask(theta, K)
    ids = np.asarray(ids if ids is not None else np.arange(theta.size)).astype(str)
    n = int(m.sum())
    if n < 2:
        return failed_fit("stress_ratio", EQ53, STRESS_RATIO_PARAMS,
                          f"too few runs: {n}, need {min_points}", n, **coords)
    th, y = theta[m], K[m]
    sd = None if sigma is None else np.asarray(sigma, dtype=float).ravel()[m]

    def p0(t, yy):
        slope, icpt = np.polyfit(t, yy, 1) if len(t) > 1 else (1e-3, 1.0)
        slope = slope if abs(slope) > 1e-6 else 1e-3
        return [1.0 / slope, (1.0 - icpt) / slope]

    forms = [
        Form("eq53", lambda t, d0, d1: 1.0 + (t - d1) / d0, ("d0", "d1"), p0,
             "K = 1 + (theta - d1)/d0", min_points=min_points),
        Form("constant", lambda t, k: k + 0.0 * t, ("K_ref",), lambda t, yy: [float(np.mean(yy))],
             "K = K_ref over the fitted range (no trend with theta identified)",
             min_points=min_points),
    ]
    return fit_forms("stress_ratio", EQ53, STRESS_RATIO_PARAMS, forms, th, y, sigma=sd,
                     ids=ids[m], coords=coords, valid_range={"theta": data_range(th)},
                     error_measure="Eq. (49) of K - K_fit", selection=selection, seed=seed,
                     sigma_parts=_parts(sigma_parts, m))
