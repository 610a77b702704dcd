"""Full and reduced forms of a closure: fit the full form, fall back to what the data identify.

Where the data cannot identify every parameter of a closure's full form (the curvature of
Eq. 52 with no run near 40 degrees, T-eq. 29's saturation while Ps is still linear in 1/sigma,
K without a detectable trend in theta), :func:`fit_forms` fits the stated reduced forms in turn
and stores the first one whose parameters are all identified (:mod:`.identify`), with status
``reduced`` and the reason the fuller forms failed.  It never invents a number: a parameter a
reduced form drops is ``not_in_form`` (NaN) or, where the reduced form is a special case of the
full one (the flow rule with gamma = 0), ``fixed`` at that special value with the reason.  If no
form is identified the full form is returned with status ``unidentified``.

Every returned fit carries an ensemble (covariance draws, or a bootstrap when the caller gives
one), its chi-square diagnostics and the held-out z-scores of its runs (:func:`.identify.heldout_zscores`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import optimize

from .identify import apply_heldout, apply_structure, assess, heldout_zscores
from .lsq import (N_ENSEMBLE, least_squares, n_imputed, prediction_variance, usable_sigma,
                  variance_split)
from .result import (FitResult, bootstrap_cap, bootstrap_stderr, bootstrap_summary,
                     bootstrap_undecided, data_range, error_eq49, failed_fit)


@dataclass
class Form:
    """One form of a closure: ``model(x, *free)`` with the parameters ``free``.

    ``fixed``: ``{param: (value, reason)}`` for parameters the form sets; ``p0(x, y)`` the
    start values; ``bounds`` ``{param: (lo, hi)}``; ``extra(x, y)`` form-specific extras.
    """

    name: str
    model: Callable
    free: tuple
    p0: Callable
    description: str
    bounds: dict = field(default_factory=dict)
    fixed: dict = field(default_factory=dict)
    min_points: int | None = None
    extra: Callable | None = None
    #: ``{param: (lo, hi)}``: the bounds a refit uses when ``param`` sits at one of its
    #: ``bounds`` (:func:`bound_conditional`); default :func:`moved_bounds`
    moved: dict = field(default_factory=dict)


#: fraction of a finite bound interval by which :func:`moved_bounds` moves an active bound inwards
MOVE_FRACTION = 0.25


def moved_bounds(value: float, lo: float, hi: float) -> tuple[float, float]:
    """The bounds (lo, hi) with the one ``value`` sits at moved inwards: by
    :data:`MOVE_FRACTION` of the interval when both are finite, else by half of
    ``max(|bound|, |value|, 1)``."""
    at_lo = abs(value - lo) <= abs(value - hi)
    if math.isfinite(lo) and math.isfinite(hi):
        step = MOVE_FRACTION * (hi - lo)
    else:
        b = lo if at_lo else hi
        step = 0.5 * max(abs(b), abs(value), 1.0)
    return (lo + step, hi) if at_lo else (lo, hi - step)


def bound_conditional(form: Form, lsq, x, y, sigma, stderr: dict) -> dict:
    """Free parameters of a fitted form that only an active optimiser bound determines:
    ``{param: reason}`` (criterion 5 of :mod:`.identify`).

    A parameter at a bound is not a result, and neither is one the fit trades against it (the
    flat lambda = 1/2 hstop brackets put delta2 - delta1 at its bound and A followed it,
    :func:`granflow.fitting.hstop.bound_conditional`).  The form is refitted with every active
    bound moved inwards (``form.moved`` or :func:`moved_bounds`); a parameter not at a bound
    that moves by more than its stderr (``stderr``: the one the fit reports) follows the bound.
    """
    from .identify import at_bound

    active = [p for p in form.free if p in form.bounds
              and at_bound(lsq.params[p], *form.bounds[p])]
    others = [p for p in form.free if p not in active]
    if not active or not others:
        return {}
    bounds = dict(form.bounds)
    moved = []
    for p in active:
        lo, hi = form.bounds[p]
        bounds[p] = tuple(form.moved.get(p, moved_bounds(lsq.params[p], lo, hi)))
        moved.append(f"{p} in [{lo:.6g}, {hi:.6g}] -> [{bounds[p][0]:.6g}, {bounds[p][1]:.6g}]")
    start = [min(max(lsq.params[p], bounds.get(p, (-np.inf, np.inf))[0]),
                 bounds.get(p, (-np.inf, np.inf))[1]) for p in form.free]
    try:
        new = least_squares(form.model, x, y, start, form.free, sigma=sigma, bounds=bounds)
    except (RuntimeError, ValueError, optimize.OptimizeWarning, FloatingPointError) as exc:
        return {p: f"conditional on {', '.join(active)} at an optimiser bound (a refit with the "
                   f"bound moved failed: {exc})" for p in others}
    out = {}
    for p in others:
        shift = abs(new.params[p] - lsq.params[p])
        se = stderr.get(p, math.nan)
        if not (math.isfinite(se) and se > 0) or shift > se:
            out[p] = (f"determined by the bound of {', '.join(active)}: moving it "
                      f"({'; '.join(moved)}) moves {p} from {lsq.params[p]:.4g} to "
                      f"{new.params[p]:.4g}, "
                      f"{shift / se if math.isfinite(se) and se > 0 else math.inf:.1f} stderr")
    return out


def _result_from(kind, equation, all_params, form: Form, lsq, x, y, n, coords, valid_range,
                 extra, error_measure, ensemble, stderr_method, stderr_override=None):
    params = {p: math.nan for p in all_params}
    stderr = {p: math.nan for p in all_params}
    params.update(lsq.params)
    stderr.update(lsq.stderr if stderr_override is None else stderr_override)
    for p, (v, _) in form.fixed.items():
        params[p] = float(v)
        stderr[p] = 0.0
    # ensemble over all params (fixed: constant; not in form: NaN)
    ens = ()
    if ensemble:
        arr = np.asarray(ensemble, dtype=float)
        full = np.full((arr.shape[0], len(all_params)), np.nan)
        names = list(all_params)
        for j, p in enumerate(form.free):
            full[:, names.index(p)] = arr[:, j]
        for p, (v, _) in form.fixed.items():
            full[:, names.index(p)] = float(v)
        ens = tuple(tuple(map(float, row)) for row in full)
    ex = dict(extra)
    ex["bounds"] = {p: tuple(b) for p, b in form.bounds.items()}
    ex["covariance_free"] = np.asarray(lsq.cov).tolist()
    if form.extra is not None:
        ex.update(form.extra(x, y))
    diag = lsq.diagnostics()
    return FitResult(
        kind=kind, equation=equation, params=params, stderr=stderr,
        error=error_eq49(lsq.residuals), n_points=n, ok=True,
        message=f"{form.name} form ({form.description}) fitted to {n} runs"
                + ("; weighted by the runs' standard errors" if lsq.weighted else ""),
        stderr_method=stderr_method, error_measure=error_measure,
        valid_range=dict(valid_range), coords={k: v for k, v in coords.items() if v is not None},
        extra=ex, ensemble=ens, diagnostics=diag)


def _distinct_x(x) -> int | None:
    """Number of distinct values of a 1-D abscissa (None for other inputs)."""
    try:
        xa = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return None
    if xa.ndim != 1:
        return None
    return int(np.unique(np.round(xa[np.isfinite(xa)], 9)).size)


def _adaptive_bootstrap(kind, form, lsq, bootstrap):
    """The ensemble of ``bootstrap(form, fit, batch)`` for batch 0, 1, ... until no
    identifiability test of the form's parameters is left to the bootstrap's Monte Carlo error
    (:func:`.result.bootstrap_undecided`), a batch comes back empty, or
    :func:`.result.bootstrap_cap` rows; and its ``extra['bootstrap']`` summary (rows
    kept aligned: a batch's rows follow the previous batch's, NaN rows included)."""
    from .identify import at_bound, tolerance

    free = list(form.free)
    bounds = [form.bounds.get(p, (-math.inf, math.inf)) if form.bounds else
              (-math.inf, math.inf) for p in free]
    limits = [max(r * abs(lsq.params[p]), a) for p, (r, a) in
              zip(free, (tolerance(kind, p) for p in free))]
    ens = list(bootstrap(form, lsq, 0))
    requested = len(ens)

    def finite_rows():
        arr = np.asarray(ens, dtype=float).reshape(-1, len(free))
        arr = arr[np.all(np.isfinite(arr), axis=1)]
        ab = np.array([[at_bound(v, *b) for v, b in zip(row, bounds)] for row in arr],
                      bool).reshape(-1, len(free))
        return arr, ab

    batch = 1
    while requested and len(ens) < bootstrap_cap(requested):
        arr, ab = finite_rows()
        if not bootstrap_undecided(arr, limits, ab):
            break
        more = list(bootstrap(form, lsq, batch))
        if not more:
            break
        ens.extend(more)
        batch += 1
    arr, ab = finite_rows()
    info = bootstrap_summary(arr, free, ab, requested=requested)
    info["attempted"] = len(ens)
    return tuple(ens), info


def fit_forms(kind: str, equation: str, all_params, forms: list[Form], x, y, *, sigma=None,
              ids=None, coords=None, valid_range=None, extra=None, error_measure: str = "",
              selection: str = "", n_ensemble: int = N_ENSEMBLE, seed: int = 0,
              bootstrap: Callable | None = None, heldout: bool = True, structure: bool = True,
              structure_x=None, sigma_parts: dict | None = None) -> FitResult:
    """Fit ``forms`` (full first) to (x, y); return the first identified one (module docstring).

    ``x`` may be any array-like the models accept (e.g. a 2-row array); ``y`` 1D.  ``sigma``:
    per-run standard errors (weights, absolute covariance with Birge inflation).  ``ids``: run
    identifiers (``runs_used``; held-out z-scores are keyed by them).  ``bootstrap(form, fit,
    batch)``, if given, returns batch ``batch`` of an ensemble (n_samples x n_free; empty when
    there is no more) that replaces the covariance draws and gives the standard errors (e.g. a
    joint bootstrap over an hstop fit the model depends on); batches are drawn until the
    identifiability tests are decided (:func:`_adaptive_bootstrap`).
    ``structure_x``: the closure's physical input (default ``x`` when 1D), against which the
    residuals are tested for structure the form misses (:func:`.identify.residual_structure`).
    ``heldout``/``structure`` False: no held-out z-scores / no residual-structure test (points
    that are not independent runs, e.g. one run's profile, whose neighbours are correlated).
    ``sigma_parts``: ``{part: per-run standard deviations}`` whose squares add up to ``sigma``^2
    (within-run and between-seed): each parameter's variance is split into them
    (:func:`.lsq.variance_split`, ``diagnostics["uncertainty_split"]``).
    """
    coords = dict(coords or {})
    y = np.asarray(y, dtype=float)
    n = int(y.size)
    ids = [str(i) for i in (ids if ids is not None else range(n))]
    s = usable_sigma(sigma, n)
    n_imp = n_imputed(sigma) if s is not None else 0
    attempts = []
    for k, form in enumerate(forms):
        need = form.min_points if form.min_points is not None else len(form.free) + 1
        if n < need:
            attempts.append((form, failed_fit(kind, equation, all_params,
                                              f"{form.name} form: {n} runs, need {need}", n,
                                              **coords)))
            continue
        n_x = _distinct_x(x)
        if len(form.free) >= 3 and n_x is not None and n_x <= len(form.free):
            # a curve of k >= 3 parameters through k distinct abscissae interpolates their means:
            # its form is untested and its curvature set by the scatter (measured: Eq. 52 on
            # five lambda = 1/2 runs at 26, 27, 28 deg gave c1 = 0.61 +- 0.10 deg, "identified")
            attempts.append((form, failed_fit(
                kind, equation, all_params,
                f"{form.name} form: {len(form.free)} parameters on {n_x} distinct x values "
                f"(need {len(form.free) + 1})", n, **coords)))
            continue
        try:
            lsq = least_squares(form.model, x, y, form.p0(x, y), form.free, sigma=s,
                                bounds=form.bounds)
        except (RuntimeError, ValueError, optimize.OptimizeWarning, FloatingPointError) as exc:
            attempts.append((form, failed_fit(kind, equation, all_params,
                                              f"{form.name} form: fit failed: {exc}", n,
                                              **coords)))
            continue
        if bootstrap is not None:
            ens, boot_info = _adaptive_bootstrap(kind, form, lsq, bootstrap)
            arr = np.asarray(ens, dtype=float) if len(ens) else np.zeros((0, len(form.free)))
            sd = {p: bootstrap_stderr(arr[:, j]) if arr.size else math.nan
                  for j, p in enumerate(form.free)}
            method = (f"bootstrap ({len(ens)} refits; stderr = half the central 68 % range)")
            res = _result_from(kind, equation, all_params, form, lsq, x, y, n, coords,
                               valid_range or {}, {**(extra or {}), "bootstrap": boot_info,
                                                  "bootstrap_refits": boot_info["refits"]},
                               error_measure, ens, method, sd)
        else:
            ens = lsq.ensemble(n_ensemble, seed)
            method = ("covariance of the weighted fit (absolute; inflated by the Birge ratio "
                      "when > 1); ensemble drawn from it" if lsq.weighted else
                      "covariance scaled by the residual variance; ensemble drawn from it")
            res = _result_from(kind, equation, all_params, form, lsq, x, y, n, coords,
                               valid_range or {}, extra or {}, error_measure, ens, method)
        cond = bound_conditional(form, lsq, x, y, s, res.stderr)
        if cond:
            res = res.replace(extra={**res.extra, "bound_conditional": cond})
        fixed = {p: reason for p, (_, reason) in form.fixed.items()}
        res = assess(res, form="full" if k == 0 else form.name, free=list(form.free),
                     fixed=fixed)
        res = res.replace(runs_used=tuple(ids), selection=selection)
        if sigma_parts and lsq.weighted:
            split = variance_split(form.model, x, lsq.params, sigma_parts)
            if split:
                d = dict(res.diagnostics)
                d["uncertainty_split"] = split
                res = res.replace(diagnostics=d)
        sx = structure_x if structure_x is not None else (x if np.ndim(x) == 1 else None)
        if structure and sx is not None:
            res = apply_structure(res, sx, lsq.residuals, s)
        if heldout:
            res = _with_heldout(res, form, x, y, s, ids)
        attempts.append((form, res))
        if res.status in ("ok", "reduced", "misfit"):
            break
    chosen = next((r for _, r in attempts if r.status in ("ok", "reduced", "misfit")), None)
    if chosen is None:
        chosen = next((r for _, r in attempts if r.status != "failed"), attempts[0][1])
    tried = {}
    for form, r in attempts:
        why = "; ".join(f"{p}: {r.param_reason.get(p, '')}" for p, st in r.param_status.items()
                        if st == "unidentified") or r.message
        tried[form.name] = {"status": r.status, "why": why if r.status != "ok" else ""}
    diag = dict(chosen.diagnostics)
    diag["forms_tried"] = tried
    diag["runs_without_stderr"] = n_imp
    msg = chosen.message
    if n_imp:
        msg += (f"; {n_imp} run(s) without a standard error weighted with the largest of the "
                "others")
    if chosen.form != "full":
        full = attempts[0][1]
        msg += f"; full form {forms[0].name} not identified ({tried[forms[0].name]['why']})"
        if full.status == "failed":
            msg = chosen.message + f"; full form {forms[0].name} failed: {full.message}"
    elif chosen.status == "unidentified":
        msg += "; no form identified: " + " | ".join(f"{k}: {v['why']}" for k, v in tried.items())
    return chosen.replace(diagnostics=diag, message=msg, runs_used=tuple(ids),
                          selection=selection)


def _with_heldout(res: FitResult, form: Form, x, y, s, ids) -> FitResult:
    xa = np.asarray(x, dtype=float)

    def take(keep):
        return xa[..., keep]

    def refit(keep):
        try:
            lsq = least_squares(form.model, take(keep), y[keep], form.p0(take(keep), y[keep]),
                                form.free, sigma=None if s is None else s[keep],
                                bounds=form.bounds)
        except (RuntimeError, ValueError, optimize.OptimizeWarning, FloatingPointError):
            return None
        p = list(lsq.params.values())
        pred = form.model(xa, *p)
        var = prediction_variance(form.model, xa, p, lsq.cov)
        return pred, var

    z = heldout_zscores(ids, y, s, refit, len(form.free))
    return apply_heldout(res, z, dof=None if s is not None else len(y) - 1 - len(form.free))


def _parts(sigma_parts, mask):
    """``sigma_parts`` restricted to the runs of ``mask`` (see :func:`.forms.fit_forms`)."""
    if not sigma_parts:
        return None
    return {k: np.asarray(v, dtype=float).ravel()[mask] for k, v in sigma_parts.items()}


def data_valid_range(**arrays) -> dict:
    """``{name: (min, max)}`` of each array's finite values."""
    return {k: data_range(v) for k, v in arrays.items()}
