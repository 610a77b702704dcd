"""Weighted least squares shared by the closure fits: covariance, chi-square, ensemble.

:func:`least_squares` wraps :func:`scipy.optimize.curve_fit`.  With per-point uncertainties
``sigma`` (each run's decorrelated standard error) the fit is weighted and its covariance is
absolute; the chi-square of the residuals gives the Birge ratio R = sqrt(chi2/dof), and when
R > 1 (more scatter than the runs' own uncertainties explain) the covariance is inflated by R^2,
so that a stated standard error is never smaller than the scatter of the data supports.
Without ``sigma`` the covariance is scaled by the residual variance (curve_fit's default; the
same thing with unit weights).  A parametric ensemble (draws from the normal distribution with
that covariance) is returned for propagating the uncertainty into evaluated closures.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats

#: parameter samples stored per closure (bootstrap refits or covariance draws)
N_ENSEMBLE = 200


@dataclass
class LsqFit:
    params: dict
    cov: np.ndarray
    stderr: dict
    chi2: float
    dof: int
    p_value: float
    birge: float
    weighted: bool
    bounds: dict
    residuals: np.ndarray

    def diagnostics(self) -> dict:
        return {"chi2": self.chi2, "dof": self.dof, "chi2_p_value": self.p_value,
                "birge_ratio": self.birge, "weighted": self.weighted}

    def ensemble(self, n: int = N_ENSEMBLE, seed: int = 0) -> tuple:
        return covariance_ensemble(list(self.params.values()), self.cov, n, seed)


def usable_sigma(sigma, n: int):
    """``sigma`` as an array of positive standard errors, or None (unweighted fit).

    Runs without a usable standard error (NaN or 0: too few time windows to estimate one) get
    the largest one of the other runs -- conservative, so they never dominate a fit; when fewer
    than half of the runs have one, the fit is unweighted.  :func:`n_imputed` counts them."""
    if sigma is None:
        return None
    s = np.asarray(sigma, dtype=float).ravel()
    if s.size != n:
        return None
    good = np.isfinite(s) & (s > 0)
    if good.sum() < max(1, (n + 1) // 2):
        return None
    return np.where(good, s, s[good].max())


def n_imputed(sigma) -> int:
    """Number of entries of ``sigma`` that :func:`usable_sigma` replaces."""
    if sigma is None:
        return 0
    s = np.asarray(sigma, dtype=float).ravel()
    return int(np.sum(~(np.isfinite(s) & (s > 0))))


def least_squares(model, x, y, p0, names, *, sigma=None, bounds=None, maxfev: int = 20000
                  ) -> LsqFit:
    """Fit ``model(x, *p)`` to ``y``; raises RuntimeError/ValueError/OptimizeWarning on failure.

    ``bounds``: ``{name: (lo, hi)}`` (missing names unbounded).
    """
    y = np.asarray(y, dtype=float)
    names = list(names)
    s = usable_sigma(sigma, y.size)
    bounds = dict(bounds or {})
    lo = [bounds.get(n, (-np.inf, np.inf))[0] for n in names]
    hi = [bounds.get(n, (-np.inf, np.inf))[1] for n in names]
    with warnings.catch_warnings():
        warnings.simplefilter("error", optimize.OptimizeWarning)
        popt, pcov = optimize.curve_fit(model, x, y, p0=p0, sigma=s, absolute_sigma=s is not None,
                                        bounds=(lo, hi), maxfev=maxfev)
    resid = y - model(x, *popt)
    dof = int(y.size - len(names))
    chi2 = p = birge = math.nan
    pcov = np.atleast_2d(np.asarray(pcov, dtype=float))
    if s is not None and dof > 0:
        chi2 = float(np.sum((resid / s) ** 2))
        p = float(stats.chi2.sf(chi2, dof))
        birge = math.sqrt(chi2 / dof)
        if birge > 1.0:
            pcov = pcov * birge ** 2
    if dof <= 0:
        pcov = np.full_like(pcov, np.nan)
    params = dict(zip(names, map(float, popt)))
    se = {}
    for n, var in zip(names, np.diag(pcov)):
        se[n] = float(math.sqrt(var)) if np.isfinite(var) and var >= 0 else math.nan
    return LsqFit(params=params, cov=pcov, stderr=se, chi2=chi2, dof=dof, p_value=p, birge=birge,
                  weighted=s is not None, bounds={n: bounds[n] for n in names if n in bounds},
                  residuals=resid)


def covariance_ensemble(values, cov, n: int = N_ENSEMBLE, seed: int = 0) -> tuple:
    """``n`` draws from N(values, cov) as a tuple of tuples (empty if cov is not usable)."""
    values = np.asarray(values, dtype=float)
    cov = np.atleast_2d(np.asarray(cov, dtype=float))
    if not (np.all(np.isfinite(values)) and np.all(np.isfinite(cov))):
        return ()
    rng = np.random.default_rng(seed)
    try:
        draws = rng.multivariate_normal(values, cov, size=int(n), check_valid="raise",
                                        method="eigh")
    except (ValueError, np.linalg.LinAlgError):
        return ()
    return tuple(tuple(map(float, row)) for row in draws)


def prediction_variance(model, x, params, cov, eps: float = 1e-6) -> np.ndarray:
    """Linear (delta-method) variance of ``model(x, *params)`` from the parameter covariance."""
    p = np.asarray(params, dtype=float)
    cov = np.atleast_2d(np.asarray(cov, dtype=float))
    if not np.all(np.isfinite(cov)):
        return np.full(np.shape(x)[-1] if np.ndim(x) else 1, np.nan)
    f0 = np.asarray(model(x, *p), dtype=float)
    J = np.empty((f0.size, p.size))
    for k in range(p.size):
        h = eps * max(1.0, abs(p[k]))
        q = p.copy()
        q[k] += h
        J[:, k] = (np.asarray(model(x, *q), dtype=float).ravel() - f0.ravel()) / h
    return np.einsum("ij,jk,ik->i", J, cov, J)


def variance_split(model, x, params, sigma_parts: dict, eps: float = 1e-6) -> dict:
    """How much of each parameter's variance comes from each part of the runs' uncertainty.

    For a weighted least-squares fit with per-run variances s_i^2 = sum_k v_ik (e.g. within-run
    and between-seed), the parameter covariance (J^T W J)^-1 with W = diag(1/s^2) splits
    exactly into sandwich terms C_k = (J^T W J)^-1 J^T W diag(v_k) W J (J^T W J)^-1, sum_k C_k =
    (J^T W J)^-1.  Returns ``{param: {part: fraction}}`` of the diagonal (fractions sum to 1).
    ``sigma_parts``: ``{part: standard deviations per run}``."""
    p = np.asarray(list(params.values()), dtype=float)
    names = list(params)
    parts = {k: np.asarray(v, dtype=float) ** 2 for k, v in sigma_parts.items()}
    total = sum(parts.values())
    if not np.all(np.isfinite(total) & (total > 0)):
        return {}
    f0 = np.asarray(model(x, *p), dtype=float).ravel()
    J = np.empty((f0.size, p.size))
    for k in range(p.size):
        h = eps * max(1.0, abs(p[k]))
        q = p.copy()
        q[k] += h
        J[:, k] = (np.asarray(model(x, *q), dtype=float).ravel() - f0) / h
    w = 1.0 / total
    try:
        A = np.linalg.inv(J.T @ (w[:, None] * J))
    except np.linalg.LinAlgError:
        return {}
    out = {n: {} for n in names}
    diag_total = np.diag(A)
    for part, v in parts.items():
        B = J.T @ ((w * w * v)[:, None] * J)
        C = A @ B @ A
        for i, n in enumerate(names):
            out[n][part] = float(C[i, i] / diag_total[i]) if diag_total[i] > 0 else math.nan
    return out
