"""Bulk density and normal-stress-ratio closures.

* Bulk density, Weinhart et al. (2012) Eq. (52): ``rho_c / rho_p = c0 - exp((theta - c2) / c1)``
  (theta, c1, c2 in degrees; rho_p = 6/pi for d = m = 1). Paper: c0 = 0.5985, c1 = 4.8,
  c2 = 40.85 deg, err = 0.002 (fitted to steady disordered flows with lambda > 0).
* Stress ratio, Eq. (53): ``K = 1 + (theta - d1) / d0``. Paper: d0 = 132 deg, d1 = 21.50 deg,
  err = 0.013.

Both are fitted with scipy.optimize.curve_fit; stderr from the covariance matrix (scaled by the
residual variance unless absolute ``sigma`` is given); error Eq. (49) of the residuals
(of rho_c/rho_p and of K respectively).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import optimize

from ..units import RHO_PARTICLE
from .result import FitResult, covariance_stderr, data_range, error_eq49, failed_fit, finite_mask

EQ52 = "Weinhart et al. 2012 Eq. (52)"
EQ53 = "Weinhart et al. 2012 Eq. (53)"
DENSITY_PARAMS = ("c0", "c1", "c2")
STRESS_RATIO_PARAMS = ("d0", "d1")


def density_eq52(theta, c0, c1, c2, rho_p: float = RHO_PARTICLE):
    """Eq. (52): bulk density rho_c (m d-3) at inclination theta (degrees)."""
    theta = np.asarray(theta, dtype=float)
    out = rho_p * (c0 - np.exp((theta - c2) / c1))
    return out[()] if out.ndim == 0 else out


def stress_ratio_eq53(theta, d0, d1):
    """Eq. (53): normal stress ratio K at inclination theta (degrees)."""
    out = 1.0 + (np.asarray(theta, dtype=float) - d1) / d0
    return out[()] if np.ndim(out) == 0 else out


def _curve_fit(f, x, y, p0, sigma, bounds=(-np.inf, np.inf)):
    with warnings.catch_warnings():
        warnings.simplefilter("error", optimize.OptimizeWarning)
        return optimize.curve_fit(f, x, y, p0=p0, sigma=sigma,
                                  absolute_sigma=sigma is not None, bounds=bounds,
                                  maxfev=20000)


def fit_bulk_density(theta, rho_c, *, sigma=None, rho_p: float = RHO_PARTICLE, lam=None,
                     contact_law=None, min_points: int = 4) -> FitResult:
    """Fit Eq. (52) to bulk densities rho_c (m d-3) of steady runs at inclinations theta (deg).

    ``sigma``: optional standard deviations of rho_c (used as absolute weights). The paper fits
    all steady disordered flows with lambda > 0 together; select those runs before calling.
    """
    coords = dict(lam=lam, contact_law=contact_law)
    theta, rho_c = (np.asarray(x, dtype=float).ravel() for x in (theta, rho_c))
    m = finite_mask(theta, rho_c)
    n = int(m.sum())
    if n < min_points:
        return failed_fit("density", EQ52, DENSITY_PARAMS,
                          f"too few runs: {n}, need {min_points}", n, **coords)
    th, y = theta[m], rho_c[m] / rho_p
    s = None if sigma is None else np.asarray(sigma, dtype=float).ravel()[m] / rho_p
    c0 = float(y.max()) + 0.01
    c1 = 5.0
    c2 = float(th.max() - c1 * math.log(max(c0 - y[np.argmax(th)], 1e-6)))
    try:
        popt, pcov = _curve_fit(lambda t, c0, c1, c2: c0 - np.exp((t - c2) / c1), th, y,
                                [c0, c1, c2], s, bounds=([0.0, 1e-3, -90.0], [1.0, 90.0, 500.0]))
    except (RuntimeError, ValueError, optimize.OptimizeWarning) as exc:
        return failed_fit("density", EQ52, DENSITY_PARAMS, f"fit failed: {exc}", n, **coords)
    params = dict(zip(DENSITY_PARAMS, map(float, popt)))
    resid = y - (params["c0"] - np.exp((th - params["c2"]) / params["c1"]))
    return FitResult(
        kind="density", equation=EQ52, params=params, stderr=covariance_stderr(pcov, DENSITY_PARAMS),
        error=error_eq49(resid), n_points=n, ok=True, message=f"fitted {n} runs",
        error_measure="Eq. (49) of rho_c/rho_p - fit (volume fraction)",
        valid_range={"theta": data_range(th)},
        coords={k: v for k, v in coords.items() if v is not None},
        extra={"rho_p": rho_p},
    )


def fit_stress_ratio(theta, K, *, sigma=None, lam=None, contact_law=None,
                     min_points: int = 3) -> FitResult:
    """Fit Eq. (53) K = 1 + (theta - d1)/d0 to stress ratios of steady runs (theta in degrees)."""
    coords = dict(lam=lam, contact_law=contact_law)
    theta, K = (np.asarray(x, dtype=float).ravel() for x in (theta, K))
    m = finite_mask(theta, K)
    n = int(m.sum())
    if n < min_points:
        return failed_fit("stress_ratio", EQ53, STRESS_RATIO_PARAMS,
                          f"too few runs: {n}, need {min_points}", n, **coords)
    th, y = theta[m], K[m]
    s = None if sigma is None else np.asarray(sigma, dtype=float).ravel()[m]
    slope, icpt = np.polyfit(th, y, 1)
    if slope == 0:
        return failed_fit("stress_ratio", EQ53, STRESS_RATIO_PARAMS,
                          "K does not vary with theta: d0 is infinite", n, **coords)
    p0 = [1.0 / slope, (1.0 - icpt) / slope]
    try:
        popt, pcov = _curve_fit(lambda t, d0, d1: 1.0 + (t - d1) / d0, th, y, p0, s)
    except (RuntimeError, ValueError, optimize.OptimizeWarning) as exc:
        return failed_fit("stress_ratio", EQ53, STRESS_RATIO_PARAMS, f"fit failed: {exc}", n,
                          **coords)
    params = dict(zip(STRESS_RATIO_PARAMS, map(float, popt)))
    resid = y - stress_ratio_eq53(th, **params)
    return FitResult(
        kind="stress_ratio", equation=EQ53, params=params,
        stderr=covariance_stderr(pcov, STRESS_RATIO_PARAMS), error=error_eq49(resid),
        n_points=n, ok=True, message=f"fitted {n} runs", error_measure="Eq. (49) of K - K_fit",
        valid_range={"theta": data_range(th)},
        coords={k: v for k, v in coords.items() if v is not None},
    )
