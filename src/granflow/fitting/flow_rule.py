"""Flow rule and basal friction closures.

* Flow rule, Weinhart et al. (2012) Eq. (47): ``F = beta_lambda h / hstop(theta; lambda=1) - gamma_lambda``
  for delta3 < theta < delta_acc (Eq. 46, 48). hstop of lambda = 1 is used for every lambda.
  Fitted by weighted least squares to steady runs; standard errors *unconditional* on the
  hstop(theta; 1) fit (joint bootstrap over its refits and the runs); reduced form gamma = 0
  (Pouliquen's F = beta h/hstop) when gamma is not identified; error Eq. (49) of F - F_fit.
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
from .forms import Form, _parts, fit_forms
from .result import FitResult, data_range, error_eq49, failed_fit, finite_mask

EQ47 = "Weinhart et al. 2012 Eq. (47)"
EQ50 = "Weinhart et al. 2012 Eq. (50)"
FLOW_RULE_PARAMS = ("beta", "gamma")
FRICTION_PARAMS = ("delta1", "delta2", "A", "beta", "gamma")


def _hstop_params(hstop1):
    """(delta1, delta2, A) from a FitResult or a mapping."""
    if isinstance(hstop1, FitResult):
        if hstop1.state == "failed":
            raise ValueError(f"hstop(theta; 1) fit could not be made: {hstop1.message}")
        hstop1 = hstop1.params
    return tuple(float(hstop1[k]) for k in HSTOP_PARAMS)


def froude_eq47(h, theta, beta, gamma, delta1, delta2, A, d: float = 1.0):
    """Eq. (47): Froude number of steady flow of height h at inclination theta (degrees)."""
    return beta * np.asarray(h, dtype=float) / hstop_eq45(theta, delta1, delta2, A, d) - gamma


def mu_eq50(h, F, delta1, delta2, A, beta, gamma, d: float = 1.0):
    """Eq. (50): basal friction mu(h, F) (delta1, delta2 in degrees; A in d).

    Eq. (50) inverts the flow rule F = beta h / hstop(mu) - gamma, so it holds for F + gamma
    > 0 only; with the paper's gamma < 0 the formula has a pole at F = -gamma - beta h / A
    (thin layers) and is meaningless below F = -gamma.  There mu is its arrest limit
    tan(delta1) (h / hstop -> 0): continuous at F = -gamma, non-decreasing in F, no pole
    (a pole made the uniform-layer ODE of one closure-ensemble member chatter without end)."""
    h = np.asarray(h, dtype=float)
    F = np.asarray(F, dtype=float)
    t1, t2 = math.tan(math.radians(delta1)), math.tan(math.radians(delta2))
    x = F + gamma
    with np.errstate(divide="ignore", invalid="ignore"):
        out = t1 + (t2 - t1) / (beta * h / (A * d * x) + 1.0)
    out = np.where((x > 0) | np.isnan(x), out, t1 + 0.0 * h)  # 0 * h: NaN h stays NaN
    return out[()] if np.ndim(out) == 0 else out


def _hstop_samples(hstop1, n_max: int, batch: int = 0):
    """(delta1, delta2, A) rows ``batch * n_max`` ... ``(batch + 1) * n_max - 1`` of the hstop
    fit's ensemble (bootstrap)."""
    if isinstance(hstop1, FitResult):
        ens = hstop1.ensemble_array()
        return ens[batch * n_max:(batch + 1) * n_max] if ens.shape[0] else None
    return None


def joint_bootstrap(form, x_of, y, hstop1, sigma, n_boot: int, seed: int, batch: int = 0):
    """Unconditional ensemble of a closure fitted to data that depend on hstop(theta; 1):
    replicate b pairs the b-th bootstrap refit of hstop (its ensemble) with a resample of the
    runs (cases, with replacement) and refits ``form``; rows stay aligned with the hstop
    ensemble (NaN where a replicate could not be fitted), so that composed closures (Eq. 50)
    can join the two ensembles sample by sample.  ``x_of(p)`` gives the model input for hstop
    parameters p = (delta1, delta2, A) (NaN for runs outside (delta1, delta2)).  ``batch`` k
    pairs the next ``n_boot`` hstop refits (rows k n_boot ...) with resamples of its own
    generator (seed, k), so that batches appended in order stay aligned."""
    from .lsq import least_squares

    samples = _hstop_samples(hstop1, n_boot, batch)
    if samples is None or samples.shape[0] < (10 if batch == 0 else 1):
        return ()
    rng = np.random.default_rng(seed if batch == 0 else [seed, batch])
    n = y.size
    out = []
    for row in samples:
        idx = rng.integers(0, n, n)
        xb = np.asarray(x_of(tuple(row)), dtype=float)
        xb = xb[..., idx]
        yb = y[idx]
        ok = np.all(np.isfinite(np.atleast_2d(xb)), axis=0) & np.isfinite(yb)
        sb = None if sigma is None else sigma[idx][ok]
        need = form.min_points if form.min_points is not None else len(form.free) + 1
        if ok.sum() < need or len(np.unique(idx[ok])) < len(form.free) + 1:
            out.append((math.nan,) * len(form.free))
            continue
        try:
            fit = least_squares(form.model, xb[..., ok], yb[ok], form.p0(xb[..., ok], yb[ok]),
                                form.free, sigma=sb, bounds=form.bounds)
            out.append(tuple(fit.params.values()))
        except (RuntimeError, ValueError, optimize.OptimizeWarning, FloatingPointError):
            out.append((math.nan,) * len(form.free))
    return tuple(out)


def fit_flow_rule(theta, h, F, hstop1, *, state=None, theta_min=None, theta_max=None,
                  lam=None, contact_law=None, d: float = 1.0, min_points: int = 3, sigma=None,
                  ids=None, selection: str = "", n_bootstrap: int = 200, seed: int = 0,
                  sigma_parts=None) -> FitResult:
    """Fit Eq. (47) F = beta h/hstop(theta; 1) - gamma to steady runs.

    Parameters
    ----------
    theta, h, F : arrays of inclination (degrees), flow height and Froude number.
    hstop1 : FitResult of :func:`~granflow.fitting.fit_hstop` for lambda = 1, or a mapping with
        delta1, delta2, A.  With a FitResult that has a bootstrap ensemble the standard errors
        are *unconditional*: a joint bootstrap over the hstop refits and the runs
        (:func:`joint_bootstrap`); with a mapping they are conditional on it.
    state : optional array of flow states; only ``"steady"`` runs are used when given.
    theta_min, theta_max : optional delta3 and delta_acc (Eq. 46, 48): only runs with
        theta_min < theta < theta_max are used.
    sigma : standard errors of F per run (weights).
    Runs outside (delta1, delta2) of lambda = 1, where hstop(theta; 1) is infinite or zero, are
    dropped and counted in the message.  When gamma is not identified the reduced form
    F = beta h/hstop (Pouliquen's flow rule, gamma fixed at 0) is fitted instead.
    """
    coords = dict(lam=lam, contact_law=contact_law)
    try:
        d1, d2, A = _hstop_params(hstop1)
    except ValueError as exc:
        return failed_fit("flow_rule", EQ47, FLOW_RULE_PARAMS, str(exc), 0, **coords)
    theta, h, F = (np.asarray(x, dtype=float).ravel() for x in (theta, h, F))
    ids = np.asarray(ids if ids is not None else np.arange(theta.size)).astype(str)
    sig = None if sigma is None else np.asarray(sigma, dtype=float).ravel()
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
    if n < 2:
        return failed_fit("flow_rule", EQ47, FLOW_RULE_PARAMS,
                          f"too few steady runs inside (delta1, delta2) of lambda=1: {n}, need "
                          f"{min_points}", n, **coords)
    th_m, h_m = theta[mask], h[mask]
    x = h_m / hs[mask]
    y = F[mask]
    s = None if sig is None else sig[mask]
    forms = [
        Form("eq47", lambda xx, beta, gamma: beta * xx - gamma, ("beta", "gamma"),
             lambda xx, yy: [0.2, 0.0], "F = beta h/hstop(theta; 1) - gamma",
             min_points=min_points),
        Form("pouliquen", lambda xx, beta: beta * xx, ("beta",),
             lambda xx, yy: [float(np.sum(xx * yy) / np.sum(xx * xx))],
             "F = beta h/hstop(theta; 1) (Pouliquen 1999: gamma not identified, fixed at 0)",
             fixed={"gamma": (0.0, "reduced form F = beta h/hstop: gamma not identified by the "
                                   "data, fixed at 0 (Pouliquen 1999)")}, min_points=min_points),
    ]

    def x_of(p):
        hsb = hstop_eq45(th_m, *p, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.isfinite(hsb) & (hsb > 0), h_m / hsb, np.nan)

    boot = None
    if isinstance(hstop1, FitResult) and hstop1.ensemble and n_bootstrap > 0:
        def boot(form, lsq, batch=0):
            return joint_bootstrap(form, x_of, y, hstop1, s, n_bootstrap, seed, batch)
    res = fit_forms("flow_rule", EQ47, FLOW_RULE_PARAMS, forms, x, y, sigma=s, ids=ids[mask],
                    coords=coords,
                    valid_range={"h": data_range(h_m), "theta": data_range(th_m),
                                 "F": data_range(y)},
                    extra={"hstop1": {"delta1": d1, "delta2": d2, "A": A},
                           "n_outside": n_outside},
                    error_measure="Eq. (49) of F - F_fit", selection=selection, seed=seed,
                    bootstrap=boot, sigma_parts=_parts(sigma_parts, mask))
    if n_outside:
        res = res.replace(message=res.message + f"; dropped {n_outside} outside (delta1, delta2) "
                                                "of lambda=1")
    if boot is None:
        res = res.replace(stderr_method=res.stderr_method + " (conditional on the hstop "
                                                             "parameters)")
    return res


def friction_closure(hstop1: FitResult, flow_rule: FitResult, *, theta=None, h=None, F=None,
                     d: float = 1.0) -> FitResult:
    """Eq. (50) friction closure mu(h, F; lambda) from hstop(theta; 1) and the lambda flow rule.

    The parameters are delta1, delta2, A of the lambda = 1 hstop fit and beta, gamma of the flow
    rule.  Its ensemble joins the two sample by sample (the flow rule's joint bootstrap is
    aligned with the hstop refits), so evaluated mu(h, F) carries both uncertainties and their
    correlation.  Its status is the worse of the two (ok < reduced < unidentified/misfit), each
    parameter keeping its own status and reason.  When steady-run data ``theta, h, F`` are
    given, ``error`` is Eq. (49) of mu(h, F) - tan(theta); otherwise NaN.  The valid range is
    the flow-rule fit's (h, F, theta), and its runs are the flow rule's.
    """
    coords = dict(flow_rule.coords)
    if hstop1.state == "failed" or flow_rule.state == "failed":
        which = "hstop(theta; 1)" if hstop1.state == "failed" else "flow rule"
        return failed_fit("friction", EQ50, FRICTION_PARAMS, f"{which} fit could not be made",
                          0, **coords)
    params = {k: hstop1.params[k] for k in HSTOP_PARAMS}
    params.update({k: flow_rule.params[k] for k in FLOW_RULE_PARAMS})
    stderr = {k: hstop1.stderr[k] for k in HSTOP_PARAMS}
    stderr.update({k: flow_rule.stderr[k] for k in FLOW_RULE_PARAMS})
    pstat = {k: hstop1.param_status.get(k, "identified" if hstop1.ok else "unidentified")
             for k in HSTOP_PARAMS}
    preason = {k: "hstop(theta; 1): " + hstop1.param_reason.get(k, "") for k in HSTOP_PARAMS}
    pstat.update({k: flow_rule.param_status.get(k, "identified" if flow_rule.ok
                                                else "unidentified") for k in FLOW_RULE_PARAMS})
    preason.update({k: "flow rule: " + flow_rule.param_reason.get(k, "") for k in FLOW_RULE_PARAMS})
    rank = {"ok": 0, "reduced": 1, "unidentified": 2, "misfit": 3}
    worst = max((hstop1.state, flow_rule.state), key=lambda st: rank.get(st, 4))
    status = worst if worst in rank else "unidentified"
    ens = ()
    he, fe = hstop1.ensemble_array(), flow_rule.ensemble_array()
    if he.shape[0] and fe.shape[0]:
        m = min(he.shape[0], fe.shape[0])
        fidx = [list(flow_rule.params).index(k) for k in FLOW_RULE_PARAMS]
        joined = np.hstack([he[:m, :3], fe[:m][:, fidx]])
        ens = tuple(tuple(map(float, row)) for row in joined)
    error, n = math.nan, 0
    if theta is not None and h is not None and F is not None:
        theta, h, F = (np.asarray(x, dtype=float).ravel() for x in (theta, h, F))
        m = finite_mask(theta, h, F)
        resid = mu_eq50(h[m], F[m], d=d, **params) - np.tan(np.radians(theta[m]))
        error, n = error_eq49(resid), int(m.sum())
    msg = (f"composed from hstop(theta; 1) [{hstop1.state}] and the flow rule "
           f"[{flow_rule.state}, {flow_rule.form} form]")
    return FitResult(
        kind="friction", equation=EQ50, params=params, stderr=stderr, error=error,
        n_points=n, ok=status in ("ok", "reduced"), message=msg,
        stderr_method=f"hstop: {hstop1.stderr_method}; beta, gamma: {flow_rule.stderr_method}",
        error_measure="Eq. (49) of mu(h, F) - tan(theta) over steady runs",
        valid_range=dict(flow_rule.valid_range), coords=coords, status=status,
        form=flow_rule.form, param_status=pstat, param_reason=preason, ensemble=ens,
        diagnostics={"identifiability_criterion": flow_rule.diagnostics.get(
            "identifiability_criterion", "")},
        runs_used=flow_rule.runs_used, selection=flow_rule.selection,
    )
