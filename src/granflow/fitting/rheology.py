"""Local mu(I) rheology fitted to coarse-grained depth profiles.

Implements seed 001 Eq. (2.13) (Jop, Forterre & Pouliquen):
``mu(I) = mu_s + (mu_d - mu_s) / (I0 / I + 1)``, with the inertial number
``I = shear_rate d / sqrt(p / rho_p)`` and the local friction ``mu = sigma_xz / sigma_zz`` taken
from steady depth profiles (points near the base and the free surface, where the local
rheology fails, should be removed by the caller). Fitted with scipy.optimize.curve_fit through
:func:`granflow.fitting.forms.fit_forms`: stderr from the covariance scaled by the residual
variance, the identifiability tests of :mod:`granflow.fitting.identify`, held-out z-scores;
error Eq. (49) of mu - mu_fit.
"""

from __future__ import annotations

import numpy as np

from .forms import Form, fit_forms
from .result import FitResult, data_range, failed_fit, finite_mask

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


def fit_mu_I(I, mu, *, lam=None, contact_law=None, min_points: int = 4, ids=None,
             seed: int = 0) -> FitResult:
    """Fit mu_s, mu_d, I0 of Eq. (2.13) to local (I, mu) points.

    Through :func:`.forms.fit_forms` (one form): the result says which parameters the points
    identify (:mod:`.identify`), e.g. I0 and mu_d are not separately identified while every
    point has I << I0, and carries held-out z-scores and a covariance ensemble."""
    coords = dict(lam=lam, contact_law=contact_law)
    I, mu = (np.asarray(x, dtype=float).ravel() for x in (I, mu))
    m = finite_mask(I, mu) & (I > 0)
    n = int(m.sum())
    if n < min_points:
        return failed_fit("mu_I", EQ213, MU_I_PARAMS, f"too few (I, mu) points: {n}, need "
                          f"{min_points}", n, **coords)
    x, y = I[m], mu[m]
    ids = None if ids is None else np.asarray(ids).astype(str)[m]
    form = Form("eq213", mu_of_I, MU_I_PARAMS,
                lambda xx, yy: [float(yy.min()), float(yy.max()) + 0.05, float(np.median(xx))],
                "mu = mu_s + (mu_d - mu_s) I / (I0 + I)",
                bounds={"mu_s": (0.0, 10.0), "mu_d": (0.0, 10.0), "I0": (1e-8, 1e3)},
                min_points=min_points)
    res = fit_forms("mu_I", EQ213, MU_I_PARAMS, [form], x, y, ids=ids, coords=coords,
                    valid_range={"I": data_range(x)}, error_measure="Eq. (49) of mu - mu_fit",
                    seed=seed)
    return _saturation_reached(res, float(x.max()))


#: mu_d is identified only where the points reach I >= I0 (half the rise mu_d - mu_s seen)
SATURATION_SEEN = 0.5


def _saturation_reached(res: FitResult, I_max: float) -> FitResult:
    """mu_d is the I -> infinity limit: points that stay below I0 see less than half of the rise
    mu_d - mu_s, and then mu_d (with I0) is an extrapolation of the curvature of the points,
    however small its covariance stderr (measured: 40 points at I = 0.001-0.01 on seed 001's
    curve, I0 = 0.279, gave mu_d = 0.41 +- 0.03 against 0.682)."""
    if res.state == "failed" or not res.param_status:
        return res
    I0 = res.params["I0"]
    seen = I_max / (I0 + I_max) if I0 > 0 else 1.0
    if seen >= SATURATION_SEEN:
        return res
    why = (f"the points reach I = {I_max:.3g}, below I0 = {I0:.3g}: they see {100 * seen:.0f} % "
           f"of the rise mu_d - mu_s (< {100 * SATURATION_SEEN:.0f} %), so mu_d is an "
           "extrapolation")
    status, reason = dict(res.param_status), dict(res.param_reason)
    for p in ("mu_d", "I0"):
        reason[p] = reason[p] + "; " + why if status[p] == "unidentified" else why
        status[p] = "unidentified"
    return res.replace(param_status=status, param_reason=reason, status="unidentified",
                       ok=False, message=res.message + "; " + why)
