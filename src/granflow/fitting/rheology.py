"""Local mu(I) rheology fitted to coarse-grained depth profiles.

Implements seed 001 Eq. (2.13) (Jop, Forterre & Pouliquen):
``mu(I) = mu_s + (mu_d - mu_s) / (I0 / I + 1)``, with the inertial number
``I = shear_rate d / sqrt(p / rho_p)`` and the local friction ``mu = sigma_xz / sigma_zz`` taken
from steady depth profiles (points near the base and the free surface, where the local
rheology fails, should be removed by the caller). Fitted with scipy.optimize.curve_fit; stderr from
the covariance matrix (scaled by the residual variance); error Eq. (49) of mu - mu_fit.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import optimize

from .result import FitResult, covariance_stderr, data_range, error_eq49, failed_fit, finite_mask

EQ213 = "seed 001 Eq. (2.13) mu(I) rheology"
MU_I_PARAMS = ("mu_s", "mu_d", "I0")


def mu_of_I(I, mu_s, mu_d, I0):
    """mu(I) = mu_s + (mu_d - mu_s)/(I0/I + 1) (written as (mu_d - mu_s) I/(I0 + I))."""
    I = np.asarray(I, dtype=float)
    out = mu_s + (mu_d - mu_s) * I / (I0 + I)
    return out[()] if out.ndim == 0 else out


def inertial_number(shear_rate, pressure, d: float = 1.0, rho_p: float = 6.0 / np.pi):
    """I = shear_rate d / sqrt(p / rho_p)."""
    return np.asarray(shear_rate, float) * d / np.sqrt(np.asarray(pressure, float) / rho_p)


def fit_mu_I(I, mu, *, lam=None, contact_law=None, min_points: int = 4) -> FitResult:
    """Fit mu_s, mu_d, I0 of Eq. (2.13) to local (I, mu) points."""
    coords = dict(lam=lam, contact_law=contact_law)
    I, mu = (np.asarray(x, dtype=float).ravel() for x in (I, mu))
    m = finite_mask(I, mu) & (I > 0)
    n = int(m.sum())
    if n < min_points:
        return failed_fit("mu_I", EQ213, MU_I_PARAMS, f"too few (I, mu) points: {n}, need "
                          f"{min_points}", n, **coords)
    x, y = I[m], mu[m]
    p0 = [float(y.min()), float(y.max()) + 0.05, float(np.median(x))]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", optimize.OptimizeWarning)
            popt, pcov = optimize.curve_fit(mu_of_I, x, y, p0=p0,
                                            bounds=([0.0, 0.0, 1e-8], [10.0, 10.0, 1e3]),
                                            maxfev=20000)
    except (RuntimeError, ValueError, optimize.OptimizeWarning) as exc:
        return failed_fit("mu_I", EQ213, MU_I_PARAMS, f"fit failed: {exc}", n, **coords)
    params = dict(zip(MU_I_PARAMS, map(float, popt)))
    return FitResult(
        kind="mu_I", equation=EQ213, params=params, stderr=covariance_stderr(pcov, MU_I_PARAMS),
        error=error_eq49(y - mu_of_I(x, **params)), n_points=n, ok=True,
        message=f"fitted {n} points", error_measure="Eq. (49) of mu - mu_fit",
        valid_range={"I": data_range(x)},
        coords={k: v for k, v in coords.items() if v is not None},
    )
