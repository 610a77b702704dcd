"""Flow rule and basal friction closures.

* Flow rule, Weinhart et al. (2012) Eq. (47): ``F = beta_lambda h / hstop(theta; lambda=1) - gamma_lambda``
  for delta3 < theta < delta_acc (Eq. 46, 48). hstop of lambda = 1 is used for every lambda.
  Fitted by linear least squares (scipy.optimize.curve_fit) to steady runs; stderr from the
  covariance matrix (conditional on the hstop(theta; 1) parameters); error Eq. (49) of F - F_fit.
* Friction, Eq. (50) (= Eq. 37 with lambda-dependent beta, gamma):
  ``mu(h, F; lambda) = tan d1 + (tan d2 - tan d1) / (beta_lambda h / (A d (F + gamma_lambda)) + 1)``
  with delta1, delta2, A of lambda = 1. :func:`friction_closure` combines an hstop(lambda=1) fit
  and a flow-rule fit; its error is Eq. (49) of mu(h, F) - tan(theta) over steady runs, since
  steady uniform flow has mu = tan(theta).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from .hstop import HSTOP_PARAMS, hstop_eq45
from .result import FitResult, covariance_stderr, data_range, error_eq49, failed_fit, finite_mask

EQ47 = "Weinhart et al. 2012 Eq. (47)"
EQ50 = "Weinhart et al. 2012 Eq. (50)"
FLOW_RULE_PARAMS = ("beta", "gamma")
FRICTION_PARAMS = ("delta1", "delta2", "A", "beta", "gamma")


def _hstop_params(hstop1):
    """(delta1, delta2, A) from a FitResult or a mapping."""
    if isinstance(hstop1, FitResult):
        if not hstop1.ok:
            raise ValueError(f"hstop(theta; 1) fit is not usable: {hstop1.message}")
        hstop1 = hstop1.params
    return tuple(float(hstop1[k]) for k in HSTOP_PARAMS)


def froude_eq47(h, theta, beta, gamma, delta1, delta2, A, d: float = 1.0):
    """Eq. (47): Froude number of steady flow of height h at inclination theta (degrees)."""
    return beta * np.asarray(h, dtype=float) / hstop_eq45(theta, delta1, delta2, A, d) - gamma


def mu_eq50(h, F, delta1, delta2, A, beta, gamma, d: float = 1.0):
    """Eq. (50): basal friction mu(h, F) (delta1, delta2 in degrees; A in d)."""
    h = np.asarray(h, dtype=float)
    F = np.asarray(F, dtype=float)
    t1, t2 = math.tan(math.radians(delta1)), math.tan(math.radians(delta2))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = t1 + (t2 - t1) / (beta * h / (A * d * (F + gamma)) + 1.0)
    return out[()] if np.ndim(out) == 0 else out


def fit_flow_rule(theta, h, F, hstop1, *, state=None, theta_min=None, theta_max=None,
                  lam=None, contact_law=None, d: float = 1.0, min_points: int = 3) -> FitResult:
    """Fit Eq. (47) F = beta h/hstop(theta; 1) - gamma to steady runs.

    Parameters
    ----------
    theta, h, F : arrays of inclination (degrees), flow height and Froude number.
    hstop1 : FitResult of :func:`~granflow.fitting.fit_hstop` for lambda = 1, or a mapping with
        delta1, delta2, A.
    state : optional array of flow states; only ``"steady"`` runs are used when given.
    theta_min, theta_max : optional delta3 and delta_acc (Eq. 46, 48): only runs with
        theta_min < theta < theta_max are used.
    Runs outside (delta1, delta2) of lambda = 1, where hstop(theta; 1) is infinite or zero, are
    dropped and counted in the message.
    """
    coords = dict(lam=lam, contact_law=contact_law)
    try:
        d1, d2, A = _hstop_params(hstop1)
    except ValueError as exc:
        return failed_fit("flow_rule", EQ47, FLOW_RULE_PARAMS, str(exc), 0, **coords)
    theta, h, F = (np.asarray(x, dtype=float).ravel() for x in (theta, h, F))
    mask = finite_mask(theta, h, F)
    if state is not None:
        mask &= np.asarray(state).astype(str).ravel() == "steady"
    if theta_min is not None:
        mask &= theta > theta_min
    if theta_max is not None:
        mask &= theta < theta_max
    hs = hstop_eq45(theta, d1, d2, A, d)
    inside = np.isfinite(hs) & (hs > 0)
    n_outside = int(np.sum(mask & ~inside))
    mask &= inside
    n = int(mask.sum())
    if n < min_points:
        return failed_fit("flow_rule", EQ47, FLOW_RULE_PARAMS,
                          f"too few steady runs inside (delta1, delta2) of lambda=1: {n}, need "
                          f"{min_points}", n, **coords)
    x = h[mask] / hs[mask]
    y = F[mask]
    try:
        popt, pcov = optimize.curve_fit(lambda x, beta, gamma: beta * x - gamma, x, y,
                                        p0=[0.2, 0.0])
    except (RuntimeError, ValueError, optimize.OptimizeWarning) as exc:
        return failed_fit("flow_rule", EQ47, FLOW_RULE_PARAMS, f"fit failed: {exc}", n, **coords)
    params = dict(zip(FLOW_RULE_PARAMS, map(float, popt)))
    resid = y - (params["beta"] * x - params["gamma"])
    return FitResult(
        kind="flow_rule", equation=EQ47, params=params,
        stderr=covariance_stderr(pcov, FLOW_RULE_PARAMS), error=error_eq49(resid), n_points=n,
        ok=True, message=f"fitted {n} steady runs" + (
            f"; dropped {n_outside} outside (delta1, delta2) of lambda=1" if n_outside else ""),
        error_measure="Eq. (49) of F - F_fit",
        valid_range={"h": data_range(h[mask]), "theta": data_range(theta[mask]),
                     "F": data_range(F[mask])},
        coords={k: v for k, v in coords.items() if v is not None},
        extra={"hstop1": {"delta1": d1, "delta2": d2, "A": A}},
    )


def friction_closure(hstop1: FitResult, flow_rule: FitResult, *, theta=None, h=None, F=None,
                     d: float = 1.0) -> FitResult:
    """Eq. (50) friction closure mu(h, F; lambda) from hstop(theta; 1) and the lambda flow rule.

    The parameters are delta1, delta2, A of the lambda = 1 hstop fit and beta, gamma of the flow
    rule, with their stderr carried over (independent fits, no covariance). When steady-run data
    ``theta, h, F`` are given, ``error`` is Eq. (49) of mu(h, F) - tan(theta); otherwise NaN.
    The valid range is the flow-rule fit's (h, F, theta).
    """
    coords = dict(flow_rule.coords)
    if not hstop1.ok or not flow_rule.ok:
        which = "hstop(theta; 1)" if not hstop1.ok else "flow rule"
        return failed_fit("friction", EQ50, FRICTION_PARAMS, f"{which} fit is not usable",
                          0, **coords)
    params = {k: hstop1.params[k] for k in HSTOP_PARAMS}
    params.update({k: flow_rule.params[k] for k in FLOW_RULE_PARAMS})
    stderr = {k: hstop1.stderr[k] for k in HSTOP_PARAMS}
    stderr.update({k: flow_rule.stderr[k] for k in FLOW_RULE_PARAMS})
    error, n = math.nan, 0
    if theta is not None and h is not None and F is not None:
        theta, h, F = (np.asarray(x, dtype=float).ravel() for x in (theta, h, F))
        m = finite_mask(theta, h, F)
        resid = mu_eq50(h[m], F[m], d=d, **params) - np.tan(np.radians(theta[m]))
        error, n = error_eq49(resid), int(m.sum())
    return FitResult(
        kind="friction", equation=EQ50, params=params, stderr=stderr, error=error,
        n_points=n, ok=True,
        message="composed from hstop(theta; 1) and the flow rule",
        stderr_method=f"hstop: {hstop1.stderr_method}; beta, gamma: {flow_rule.stderr_method}",
        error_measure="Eq. (49) of mu(h, F) - tan(theta) over steady runs",
        valid_range=dict(flow_rule.valid_range), coords=coords,
    )
