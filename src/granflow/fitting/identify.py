"""What the data identify: per-parameter identifiability, closure status, held-out z-scores.

A number that is precise and wrong is worse than no number, so every fitted closure is assessed
before it is stored (issue 13).  :func:`assess` marks each parameter of a :class:`FitResult`

* ``identified`` when all of these hold:

  1. its standard error is finite and positive (a fit without residual degrees of freedom
     cannot say how well it knows a parameter);
  2. it is not at an optimiser bound (within a relative 1e-6, :data:`BOUND_RTOL`);
  3. its standard error is at most ``max(rel |value|, abs)`` with the per-parameter tolerances
     of :data:`TOLERANCES` -- relative (``rel`` = 0.5: the 2-sigma interval excludes zero) for
     scales such as A, beta, d0, Pmax, and absolute (in the parameter's units) for offsets whose
     value says nothing about their precision: angles (delta1, d1: 2 degrees; delta2, reached
     only by extrapolating hstop to 0, and c2: 3 degrees), the
     flow-rule offset gamma (0.1 in Froude number, the paper's err(F) is 0.12), the packing
     fraction c0 (0.01);
  4. no other parameter of the fit is correlated with it beyond ``|r| > 0.999``
     (:data:`CORRELATION_LIMIT`; the bootstrap ensemble or the covariance gives r): there the
     data fix only a combination of the two (the ridge is 2000 times longer than it is wide)
     and each one alone is arbitrary along it;
  5. it does not follow another parameter's active bound (``extra['bound_conditional']``, set
     by the hstop fit, :func:`granflow.fitting.hstop.bound_conditional`, and by every form
     :func:`granflow.fitting.forms.fit_forms` fits, :func:`granflow.fitting.forms.
     bound_conditional`): a refit with that bound moved does not move it by more than its
     stderr.  (A bootstrap whose every
     refit sits at the same bound reports a small stderr for the parameter traded against
     it.)
  6. for a bootstrap stderr (``extra['bootstrap']``, :func:`granflow.fitting.result.
     bootstrap_summary`): test 3 holds at the upper end of the stderr's Monte Carlo 95 % range
     (what another bootstrap seed could give; the fit refits until that range and the
     fraction's Wilson interval below lie on one side of their limits, or 8 times the
     requested refits and at least 400, :func:`granflow.fitting.result.bootstrap_cap`,
     :func:`granflow.fitting.result.bootstrap_undecided`), and the parameter sits at an
     optimiser bound in at most 15.9 % of the refits, at the upper end of the fraction's Wilson
     95 % interval (:data:`granflow.fitting.result.BOOTSTRAP_BOUND_FRACTION`: more, and the
     bound sets the stderr's percentile, not the data; the fraction is stored whatever it
     is, ``extra['bootstrap']['at_bound_fraction']``).  A
     percentile stderr from one batch of refits can fall on either side of its tolerance:
     with refits running off to a bound its 84th percentile lies in a sparse tail and changes
     with the seed (the lambda = 1/2 reference's delta2: 2.6-6.2 degrees over six seeds of
     200 refits, 11 % of refits at the bound).

* ``unidentified`` otherwise (the reason says which test failed), ``fixed`` when a reduced form
  sets it (the reason says to what and why), ``not_in_form`` when the stored form lacks it.

The closure's ``status`` is ``ok`` when every parameter of its full form is identified,
``reduced`` when a stated reduced form is identified instead (:mod:`granflow.fitting.forms`),
``unidentified`` when no form is, ``misfit`` when its residuals show a trend or curvature in the
closure's input that the form does not describe (:func:`residual_structure`, F-test p < 1e-3) or
held-out runs contradict it
(:func:`heldout_zscores`: |z| > 3 for a single held-out run, and for n runs the limit with the
same 0.27 % false-alarm probability for the largest of them, :func:`heldout_limit`; Student-t
quantiles for unweighted fits, whose z is scaled by the other runs' scatter), ``failed``
when no fit could be made.  ``ok`` is True for ``ok`` and ``reduced`` only.

Held-out check.  For a closure fitted to runs with measurements y_i (uncertainty s_i, the run's
decorrelated standard error), each run i in turn is left out, the closure is refitted to the
others and predicts y_i:

    z_i = (y_i - yhat_(-i)) / sqrt(s_i^2 + var(yhat_(-i)) + tau_(-i)^2),

with var(yhat) the parameter uncertainty of the refit at x_i and tau^2 the closure's intrinsic
scatter estimated without run i, max(0, (sum r_j^2 - sum s_j^2)/(n - 1 - p)) -- the scatter
about the closure that the runs' own uncertainties do not explain.  |z| > 3 means the closure,
with the uncertainty it states, does not predict a run it was not fitted to.

Chi-square.  The runs' standard errors come from one run's decorrelated time windows; runs
with other seeds scatter more than that (above all near hstop and in small boxes), so the
chi-square per degree of freedom of a campaign fit is often well above 1.  It is reported
(``chi2``, ``dof``, ``birge_ratio``) and inflates every stated standard error by the Birge
ratio, but it is not by itself a misfit: random scatter is what the intrinsic scatter tau
describes; a misfit is structure the form misses, or a held-out run it cannot predict.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from .result import BOOTSTRAP_BOUND_FRACTION, FitResult

#: (rel, abs) tolerance of each parameter: identified if stderr <= max(rel |value|, abs).
TOLERANCES = {
    "hstop": {"delta1": (0.0, 2.0), "delta2": (0.0, 3.0), "A": (0.5, 0.0)},
    "hstop_eq38": {"delta1": (0.0, 2.0), "delta2": (0.0, 3.0), "A": (0.5, 0.0)},
    "flow_rule": {"beta": (0.5, 0.0), "gamma": (0.5, 0.1)},
    "friction": {"delta1": (0.0, 2.0), "delta2": (0.0, 3.0), "A": (0.5, 0.0),
                 "beta": (0.5, 0.0), "gamma": (0.5, 0.1)},
    "alpha": {"d_lambda": (0.5, 0.0), "alpha_constant": (0.0, 0.05)},
    "density": {"c0": (0.0, 0.01), "c1": (0.5, 0.0), "c2": (0.0, 3.0),
                "nu_ref": (0.0, 0.01), "dnu_dtheta": (0.5, 0.0)},
    "stress_ratio": {"d0": (0.5, 0.0), "d1": (0.0, 2.0), "K_ref": (0.0, 0.05)},
    "segregation": {"Ps": (0.5, 1.0)},
    "segregation_asymmetric": {"Ps": (0.5, 1.0), "kappa": (0.0, 0.25)},
    "Ps_law": {"Pmax": (0.5, 0.0), "k": (0.5, 0.0), "slope": (0.5, 0.0)},
    "mu_I": {"mu_s": (0.0, 0.05), "mu_d": (0.0, 0.05), "I0": (0.5, 0.0)},
}
#: default tolerance of a parameter not listed above
DEFAULT_TOLERANCE = (0.5, 0.0)
#: a parameter within this relative distance of an optimiser bound is "at the bound"
BOUND_RTOL = 1e-6
#: |correlation| above which two parameters are only identified as a combination
CORRELATION_LIMIT = 0.999
#: a held-out run with |z| above this (for one run; see :func:`heldout_limit`) flags a closure
HELDOUT_Z_LIMIT = 3.0


def heldout_limit(n: int, z1: float = HELDOUT_Z_LIMIT, dof: int | None = None) -> float:
    """|z| limit for the largest of ``n`` held-out z-scores with the false-alarm probability of
    one |z| > ``z1`` (0.27 % for 3; Bonferroni): 3.0 for one run, 3.5 for 6, 3.6 for 10, 4.1
    for 60.  Without it a correct closure fitted to 60 runs would be flagged 15 % of the time.
    With ``dof`` (an unweighted fit, whose z is scaled by the scatter of the other runs: the
    externally studentized residual, Student-t distributed) the t quantile is used."""
    from scipy import stats

    n = max(int(n), 1)
    p1 = 2.0 * stats.norm.sf(z1)
    if dof is not None and dof >= 1:
        return float(stats.t.isf(p1 / (2.0 * n), dof))
    return float(stats.norm.isf(p1 / (2.0 * n)))

CRITERION = (
    "identified: stderr finite and > 0; not within a relative 1e-6 of an optimiser bound; "
    "stderr <= max(rel |value|, abs) with the per-parameter (rel, abs) of "
    "granflow.fitting.identify.TOLERANCES; |correlation| with every other parameter <= 0.999; "
    "not moved by more than its stderr when another parameter's active bound is moved; "
    "for bootstrap stderrs, the stderr's Monte Carlo 95 % range also within the tolerance and "
    "the parameter at an optimiser bound in at most 15.9 % of the refits (upper end of its "
    "Wilson 95 % interval). "
    "Closure ok when every parameter of its (full or stated reduced) form is identified and "
    "no held-out run has |z| above 3 (one run; for n runs the Bonferroni-equivalent limit, "
    "granflow.fitting.identify.heldout_limit).")


def tolerance(kind: str, param: str) -> tuple[float, float]:
    """(rel, abs) identifiability tolerance of ``param`` of closure ``kind``."""
    return TOLERANCES.get(kind, {}).get(param, DEFAULT_TOLERANCE)


def at_bound(value: float, lo: float, hi: float, rtol: float = BOUND_RTOL) -> bool:
    """Whether ``value`` is within a relative ``rtol`` of the bound ``lo`` or ``hi``."""
    for b in (lo, hi):
        if b is None or not math.isfinite(b):
            continue
        if abs(value - b) <= rtol * max(1.0, abs(b)):
            return True
    return False


def correlation_matrix(result: FitResult, names: Sequence[str]):
    """Correlation matrix of ``names`` from the ensemble (or ``extra['covariance']``), or None."""
    idx = [list(result.params).index(n) for n in names]
    ens = result.ensemble_array()
    cov = None
    if ens.shape[0] >= 5:
        sub = ens[:, idx]
        sub = sub[np.all(np.isfinite(sub), axis=1)]
        if sub.shape[0] >= 5:
            cov = np.cov(sub, rowvar=False)
    elif "covariance" in result.extra:
        full = np.asarray(result.extra["covariance"], dtype=float)
        if full.shape == (len(result.params),) * 2:
            cov = full[np.ix_(idx, idx)]
    if cov is None:
        return None
    cov = np.atleast_2d(cov)
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = cov / np.outer(d, d)
    return r


def _data_bound_text(name: str, bound: dict | None) -> str:
    """', name <= v (95 % one-sided, ...)' for the reason of a parameter an optimiser bound
    limits on one side (:func:`granflow.fitting.result.data_bound`); '' without one."""
    if not bound:
        return ""
    pct = 100 * bound["level"]
    if not math.isfinite(bound["value"]):
        return (f": not even that (more than {pct:g} % of the refits at the bound; the data "
                "bound it from neither side)")
    op, q = ("<=", pct) if bound["side"] == "upper" else (">=", 100 - pct)
    return (f": {name} {op} {bound['value']:.4g} ({pct:g} % one-sided, the refits' "
            f"{q:g}th percentile)")


def assess_parameters(result: FitResult, free: Sequence[str] | None = None,
                      fixed: dict | None = None) -> tuple[dict, dict]:
    """Per-parameter (status, reason) dicts of a fit; see the module docstring.

    ``free``: the parameters the stored form fitted (default: all finite ones); ``fixed``:
    ``{param: reason}`` for parameters a reduced form sets.  Other parameters are
    ``not_in_form``.
    """
    fixed = dict(fixed or {})
    names = list(result.params)
    if free is None:
        free = [n for n in names if n not in fixed and math.isfinite(result.params[n])]
    free = list(free)
    bounds = result.extra.get("bounds", {}) or {}
    status, reason = {}, {}
    corr = correlation_matrix(result, free) if len(free) > 1 else None
    for n in names:
        if n in fixed:
            status[n], reason[n] = "fixed", fixed[n]
            continue
        if n not in free:
            status[n], reason[n] = "not_in_form", "not a parameter of the stored form"
            continue
        v, se = result.params[n], result.stderr.get(n, math.nan)
        rel, ab = tolerance(result.kind, n)
        lim = max(rel * abs(v), ab)
        why = []
        if not math.isfinite(v):
            why.append("value is not finite")
        if not (math.isfinite(se) and se > 0):
            why.append(f"stderr {se:.3g} is not finite and positive (no residual degrees of "
                       "freedom, or the fit did not converge)")
        lo_hi = bounds.get(n)
        if lo_hi is not None and math.isfinite(v) and at_bound(v, *lo_hi):
            why.append(f"at the optimiser bound ({lo_hi[0]:.6g}, {lo_hi[1]:.6g})")
        elif n in result.extra.get("at_bound", ()):
            why.append("at an optimiser bound")
        if n in (result.extra.get("bound_conditional") or {}):
            why.append(result.extra["bound_conditional"][n])
        what = (f"{rel:g} |value| = {rel * abs(v):.3g}" if rel * abs(v) >= ab
                else f"the absolute tolerance {ab:g}")
        if math.isfinite(se) and se > 0 and se > lim:
            why.append(f"stderr {se:.3g} exceeds {what}")
        boot = result.extra.get("bootstrap") or {}
        se_range = (boot.get("stderr_range") or {}).get(n)
        if (se_range is not None and math.isfinite(se) and 0 < se <= lim
                and math.isfinite(se_range[1]) and se_range[1] > lim):
            why.append(f"stderr {se:.3g} is within {what}, but not beyond the bootstrap's "
                       f"Monte Carlo error: over {boot.get('refits')} refits it could be "
                       f"{se_range[0]:.3g} ... {se_range[1]:.3g} (95 %; another bootstrap seed "
                       "could give an stderr above the tolerance)")
        frac = (boot.get("at_bound_fraction") or {}).get(n)
        f_range = (boot.get("at_bound_fraction_range") or {}).get(n) or [frac, frac]
        if frac is not None and math.isfinite(frac) and frac > BOOTSTRAP_BOUND_FRACTION:
            why.append(f"at an optimiser bound in {100 * frac:.1f} % of {boot.get('refits')} "
                       f"bootstrap refits (> {100 * BOOTSTRAP_BOUND_FRACTION:.1f} %): the bound, "
                       "not the data, sets its stderr; the data limit it on one side only"
                       + _data_bound_text(n, (boot.get("data_bound") or {}).get(n)))
        elif (frac is not None and math.isfinite(f_range[1])
              and f_range[1] > BOOTSTRAP_BOUND_FRACTION):
            why.append(f"at an optimiser bound in {100 * frac:.1f} % of {boot.get('refits')} "
                       f"bootstrap refits, which does not exclude more than "
                       f"{100 * BOOTSTRAP_BOUND_FRACTION:.1f} % (Wilson range up to "
                       f"{100 * f_range[1]:.1f} %): the bound may set its stderr")
        if corr is not None:
            i = free.index(n)
            for j, m in enumerate(free):
                if j != i and np.isfinite(corr[i, j]) and abs(corr[i, j]) > CORRELATION_LIMIT:
                    why.append(f"correlation {corr[i, j]:+.4f} with {m}: only a combination is "
                               "determined")
        if why:
            status[n], reason[n] = "unidentified", "; ".join(why)
        else:
            status[n], reason[n] = "identified", (
                f"stderr {se:.3g} <= {lim:.3g}" + (" (relative)" if rel * abs(v) >= ab else
                                                  " (absolute)"))
    return status, reason


def assess(result: FitResult, *, form: str = "full", free=None, fixed=None) -> FitResult:
    """The fit with ``param_status``/``param_reason``, ``status``, ``ok`` and ``form`` set.

    A failed fit stays ``failed``; otherwise ``ok`` if every free parameter is identified
    (``form == "full"``) or ``reduced`` (another form), else ``unidentified``.
    """
    if result.status == "failed" or (not result.ok and not result.status):
        names = list(result.params)
        return result.replace(status="failed", ok=False, form=form,
                              param_status={n: "not_fitted" for n in names},
                              param_reason={n: result.message for n in names})
    status, reason = assess_parameters(result, free, fixed)
    free_names = [n for n, s in status.items() if s in ("identified", "unidentified")]
    all_ok = bool(free_names) and all(status[n] == "identified" for n in free_names)
    if all_ok:
        st = "ok" if form == "full" else "reduced"
    else:
        st = "unidentified"
    diag = dict(result.diagnostics)
    diag["identifiability_criterion"] = CRITERION
    return result.replace(param_status=status, param_reason=reason, status=st,
                          ok=st in ("ok", "reduced"), form=form, diagnostics=diag)


def intrinsic_scatter(residuals, sigma=None, n_params: int = 0) -> float:
    """tau^2 = max(0, (sum r^2 - sum s^2) / (n - p)): scatter about a closure beyond the runs'
    own uncertainties (all of the residual variance when ``sigma`` is None)."""
    r = np.asarray(residuals, dtype=float)
    s = np.zeros_like(r) if sigma is None else np.asarray(sigma, dtype=float)
    ok = np.isfinite(r) & np.isfinite(s)
    dof = int(ok.sum()) - int(n_params)
    if dof <= 0:
        return math.nan
    return max(0.0, float((np.sum(r[ok] ** 2) - np.sum(s[ok] ** 2)) / dof))


def heldout_zscores(ids, y, sigma, refit: Callable, n_params: int,
                    min_fit_points: int | None = None) -> dict:
    """Leave-one-out z-scores (module docstring) for runs ``ids`` with measurements ``y``.

    ``refit(keep)`` fits the closure to the boolean selection ``keep`` and returns
    ``(predict, pred_var)``: callables giving the prediction at each run (array over all runs)
    and its parameter variance, or None when no fit could be made.  Returns ``{id: z}`` (NaN
    where the refit failed).
    """
    y = np.asarray(y, dtype=float)
    s = np.zeros_like(y) if sigma is None else np.where(np.isfinite(sigma), sigma, 0.0)
    n = len(y)
    min_fit_points = n_params + 1 if min_fit_points is None else min_fit_points
    out = {}
    for i in range(n):
        keep = np.ones(n, dtype=bool)
        keep[i] = False
        if keep.sum() < min_fit_points:
            out[ids[i]] = math.nan
            continue
        res = refit(keep)
        if res is None:
            out[ids[i]] = math.nan
            continue
        pred, var = res
        yhat = np.asarray(pred, dtype=float)
        tau2 = intrinsic_scatter((y - yhat)[keep], s[keep], n_params)
        if not math.isfinite(tau2):
            tau2 = 0.0
        v = float(np.asarray(var, dtype=float)[i]) if var is not None else 0.0
        den = math.sqrt(s[i] ** 2 + max(v, 0.0) + tau2)
        out[ids[i]] = float((y[i] - yhat[i]) / den) if den > 0 else math.nan
    return out


#: p-value below which residual structure (a quadratic in the closure's input) flags a misfit
STRUCTURE_P = 1e-3


def residual_structure(x, residuals, sigma=None) -> tuple[float, float]:
    """Does the closure's form miss structure?  F-test of a quadratic a + b x + c x^2 fitted to
    the residuals (weighted by 1/sigma^2) against no structure, scaled by the residuals' own
    scatter -- so a closure with scatter beyond the runs' standard errors is not flagged for that
    alone, only for a *trend or curvature* in its input ``x`` that it does not describe.
    Returns (F statistic, p-value); NaN with fewer than 5 runs."""
    from scipy import stats

    x = np.asarray(x, dtype=float)
    r = np.asarray(residuals, dtype=float)
    w = np.ones_like(r) if sigma is None else 1.0 / np.asarray(sigma, dtype=float) ** 2
    ok = np.isfinite(x) & np.isfinite(r) & np.isfinite(w)
    x, r, w = x[ok], r[ok], w[ok]
    n = r.size
    if n < 5 or np.ptp(x) == 0:
        return math.nan, math.nan
    xs = (x - x.mean()) / np.ptp(x)
    A = np.column_stack([np.ones(n), xs, xs * xs]) * np.sqrt(w)[:, None]
    rw = r * np.sqrt(w)
    coef, *_ = np.linalg.lstsq(A, rw, rcond=None)
    rss1 = float(np.sum((rw - A @ coef) ** 2))
    rss0 = float(np.sum(rw ** 2))
    dof = n - 3
    if rss1 <= 0 or dof <= 0:
        return math.inf, 0.0
    F = ((rss0 - rss1) / 3.0) / (rss1 / dof)
    return float(F), float(stats.f.sf(F, 3, dof))


def apply_structure(result: FitResult, x, residuals, sigma=None, p_limit: float = STRUCTURE_P
                    ) -> FitResult:
    """Store the residual-structure test in ``diagnostics``; an ok closure whose residuals show
    significant structure in its input (p < ``p_limit``) becomes ``misfit``."""
    F, p = residual_structure(x, residuals, sigma)
    diag = dict(result.diagnostics)
    diag["structure_F"], diag["structure_p"] = F, p
    out = result.replace(diagnostics=diag)
    if result.ok and math.isfinite(p) and p < p_limit:
        msg = (f"residuals show a trend/curvature in the closure's input that the "
               f"{result.form} form does not describe (F-test p = {p:.2g} < {p_limit:g})")
        out = out.replace(status="misfit", ok=False, message=f"{result.message}; {msg}")
    return out


def apply_heldout(result: FitResult, zscores: dict, limit: float | None = None,
                  dof: int | None = None) -> FitResult:
    """Store held-out z-scores in ``diagnostics``; an ok closure whose largest |z| exceeds
    ``limit`` (default :func:`heldout_limit` of the number of held-out runs: 3 for one run; t
    quantiles with ``dof`` for unweighted fits) becomes ``misfit`` (not ok), naming the worst
    run."""
    diag = dict(result.diagnostics)
    finite = {k: v for k, v in zscores.items() if math.isfinite(v)}
    if limit is None:
        limit = heldout_limit(len(finite), dof=dof)
    diag["heldout_z"] = {str(k): float(v) for k, v in zscores.items()}
    diag["heldout_max_abs_z"] = max((abs(v) for v in finite.values()), default=math.nan)
    diag["heldout_limit"] = limit
    out = result.replace(diagnostics=diag)
    if finite and result.ok and diag["heldout_max_abs_z"] > limit:
        worst = max(finite, key=lambda k: abs(finite[k]))
        msg = (f"held-out run {worst} has z = {finite[worst]:+.2f} (|z| > {limit:g}): the "
               "closure does not predict a run it was not fitted to within its stated "
               "uncertainty")
        out = out.replace(status="misfit", ok=False, message=f"{result.message}; {msg}")
    return out
