"""Segregation closures: steady small-particle profiles and the Peclet number law.

* Steady profile, Thornton et al. T-eq. (28) (Gray & Chugunov 2006): on scaled depth z in [0, 1]
  (0 = base, 1 = surface) the small-particle volume fraction is

      phi(z) = (1 - e^{-phi0 Ps}) e^{(phi0 - z) Ps}
               / (1 - e^{-(1 - phi0) Ps} + (1 - e^{-phi0 Ps}) e^{(phi0 - z) Ps}),

  the no-flux steady solution of T-eq. (27), i.e. ``dphi/dz = -Ps phi (1 - phi)`` (segregation
  flux Sr phi(1-phi) downwards balanced by diffusion Dr dphi/dz, Ps = Sr/Dr), with
  ``int_0^1 phi dz = phi0``. Small particles collect at the base for Ps > 0.
* Asymmetric flux (Gajjar & Gray 2014, seed 001 Eq. 2.9): flux A C(1 - C)(1 - kappa C) with
  A(kappa) chosen so that the maximum flux equals that of C(1 - C) (max 1/4; A = 1.6 for
  kappa = 0.89). The steady profile solves ``dphi/dz = -Ps A phi (1 - phi)(1 - kappa phi)`` with
  ``int_0^1 phi dz = phi0``; it has the implicit closed form G(phi) = c - A Ps z with
  G(phi) = ln phi - ln(1 - phi)/(1 - kappa) + kappa ln(1 - kappa phi)/(1 - kappa), which is
  inverted by Newton's method, with c set by the mass constraint (Brent's method, Gauss-Legendre
  quadrature). kappa = 0 reduces to T-eq. (28).
* Size-ratio law, T-eq. (29): ``Ps(sigma) = Pmax (1 - exp(-k (1/sigma - 1)))``,
  sigma = d_small/d_large; paper: Pmax = 7.35, k = 5.21.

Per-run fits use scipy.optimize.curve_fit; stderr from the covariance matrix (scaled by the
residual variance) and a 95 % confidence interval ``Ps +- t_{0.975, n-1} stderr``. Coarse-grained
profile points are correlated over the coarse-graining width, so that interval is optimistic
when the profile is sampled more finely than w. Error: Eq. (49) of phi - phi_fit.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd
from scipy import integrate, optimize, special, stats

from .forms import Form, _parts, fit_forms
from .result import FitResult, covariance_stderr, data_range, error_eq49, failed_fit, finite_mask

TEQ28 = "Thornton et al. T-eq. (28)"
TEQ29 = "Thornton et al. T-eq. (29)"
ASYM = "Gajjar & Gray 2014 asymmetric flux (seed 001 Eq. 2.9), steady profile"


# ---------------------------------------------------------------------------- symmetric profile
def phi_teq28(z, Ps, phi0):
    """T-eq. (28) steady small-particle fraction at scaled depth z in [0, 1] (0 = base).

    Evaluated in the overflow-safe logistic form phi = expit(-(Ps (z - phi0) + ln(b/a))) with
    a = 1 - e^{-phi0 Ps}, b = 1 - e^{-(1 - phi0) Ps}; Ps = 0 gives phi = phi0.
    """
    z = np.asarray(z, dtype=float)
    Ps = float(Ps)
    phi0 = float(phi0)
    if not 0.0 < phi0 < 1.0:
        raise ValueError(f"phi0 must be in (0, 1), got {phi0}")
    if abs(Ps) < 1e-12:
        out = np.full_like(z, phi0)
    else:
        a = -math.expm1(-phi0 * Ps)
        b = -math.expm1(-(1.0 - phi0) * Ps)
        out = special.expit(-(Ps * (z - phi0) + math.log(b / a)))
    return out[()] if out.ndim == 0 else out


def fit_Ps(z, phi, phi0=None, *, sigma=None, contact_law=None, min_points: int = 4,
           confidence: float = 0.95) -> FitResult:
    """Fit Ps of T-eq. (28) to one run's profile phi(z) on scaled depth z in [0, 1].

    ``phi0``: mean small-particle fraction (set-up value, 0.5 in the paper); by default the
    trapezoidal mean of the profile. ``sigma`` tags the result with the run's size ratio.
    The result's ``extra["ci95"]`` holds the confidence interval of Ps.
    """
    coords = dict(contact_law=contact_law, sigma=sigma)
    z, phi = (np.asarray(x, dtype=float).ravel() for x in (z, phi))
    m = finite_mask(z, phi)
    n = int(m.sum())
    if n < min_points:
        return failed_fit("segregation", TEQ28, ("Ps",), f"too few profile points: {n}", n,
                          **coords)
    z, phi = z[m], phi[m]
    order = np.argsort(z)
    z, phi = z[order], phi[order]
    if phi0 is None:
        phi0 = float(integrate.trapezoid(phi, z) / (z[-1] - z[0]))
    if not 0.0 < phi0 < 1.0:
        return failed_fit("segregation", TEQ28, ("Ps",), f"phi0 = {phi0} not in (0, 1)", n,
                          **coords)
    slope = np.polyfit(z, phi, 1)[0]
    p0 = [float(-slope / max(phi0 * (1 - phi0), 1e-3))]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", optimize.OptimizeWarning)
            popt, pcov = optimize.curve_fit(lambda zz, Ps: phi_teq28(zz, Ps, phi0), z, phi, p0=p0,
                                            maxfev=5000)
    except (RuntimeError, ValueError, optimize.OptimizeWarning) as exc:
        return failed_fit("segregation", TEQ28, ("Ps",), f"fit failed: {exc}", n, **coords)
    Ps = float(popt[0])
    se = covariance_stderr(pcov, ["Ps"])["Ps"]
    tq = float(stats.t.ppf(0.5 + confidence / 2, n - 1))
    resid = phi - phi_teq28(z, Ps, phi0)
    return FitResult(
        kind="segregation", equation=TEQ28, params={"Ps": Ps}, stderr={"Ps": se},
        error=error_eq49(resid), n_points=n, ok=True, message=f"fitted {n} profile points",
        error_measure="Eq. (49) of phi - phi_fit",
        valid_range={"z": data_range(z)},
        coords={k: v for k, v in coords.items() if v is not None},
        extra={"phi0": phi0, "ci95": (Ps - tq * se, Ps + tq * se), "confidence": confidence,
               "rms_residual": float(np.sqrt(np.mean(resid ** 2)))},
    )


# ---------------------------------------------------------------------------- asymmetric flux
def asymmetric_flux_amplitude(kappa: float) -> float:
    """A(kappa) such that max_C A C(1-C)(1-kappa C) = 1/4 (the maximum of C(1-C))."""
    kappa = float(kappa)
    if not 0.0 <= kappa < 1.0:
        raise ValueError(f"kappa must be in [0, 1), got {kappa}")
    # the flux maximum: the smaller root of 3 kappa c^2 - 2 (1 + kappa) c + 1 = 0, in the
    # cancellation-free form (the textbook form lost c entirely at kappa ~ 1e-17 in a fit)
    c = 2.0 / (2 * (1 + kappa) + math.sqrt(4 * (1 + kappa) ** 2 - 12 * kappa))
    return 0.25 / (c * (1 - c) * (1 - kappa * c))


def _G(phi, kappa):
    """Antiderivative of 1/(phi(1-phi)(1-kappa phi)) (partial fractions)."""
    return (np.log(phi) - np.log1p(-phi) / (1 - kappa)
            + kappa * np.log1p(-kappa * phi) / (1 - kappa))


def _G_of_logit(y, kappa):
    """G(phi) with phi = expit(y), computed without cancellation."""
    return (special.log_expit(y) - special.log_expit(-y) / (1 - kappa)
            + kappa * np.log1p(-kappa * special.expit(y)) / (1 - kappa))


def _G_inverse(target, kappa, iterations: int = 100):
    """phi with G(phi) = target, by Newton's method on y = logit(phi) (vectorised).

    dG/dy = 1/(1 - kappa phi) lies in [1, 1/(1 - kappa)], so G(y) is monotone with bounded slope
    and the iteration started from its asymptotes converges quickly.
    """
    target = np.asarray(target, dtype=float)
    y = np.where(target < 0, target, (1 - kappa) * target)
    for _ in range(iterations):
        step = (_G_of_logit(y, kappa) - target) * (1 - kappa * special.expit(y))
        y = y - step
        if np.all(np.abs(step) < 1e-13 * (1 + np.abs(y))):
            break
    return special.expit(y)


_GL_X, _GL_W = np.polynomial.legendre.leggauss(128)
_GL_X = 0.5 * (_GL_X + 1.0)
_GL_W = 0.5 * _GL_W


def phi_asymmetric(z, Ps, phi0, kappa, A=None):
    """Steady profile under the asymmetric flux A C(1-C)(1-kappa C) on z in [0, 1], mean phi0.

    ``A`` defaults to :func:`asymmetric_flux_amplitude` (kappa). Solves
    dphi/dz = -A Ps phi(1-phi)(1-kappa phi) with int_0^1 phi dz = phi0 (see module docstring).
    """
    phi0 = float(phi0)
    if not 0.0 < phi0 < 1.0:
        raise ValueError(f"phi0 must be in (0, 1), got {phi0}")
    A = asymmetric_flux_amplitude(kappa) if A is None else float(A)
    rate = A * float(Ps)
    z = np.asarray(z, dtype=float)
    if abs(rate) < 1e-12:
        out = np.full_like(z, phi0)
        return out[()] if out.ndim == 0 else out

    def mass(c):
        return float(np.sum(_GL_W * _G_inverse(c - rate * _GL_X, kappa))) - phi0

    span = 800.0 / (1 - kappa) + abs(rate) + 1.0
    c = optimize.brentq(mass, -span, span, xtol=1e-14, rtol=1e-14, maxiter=500)
    out = _G_inverse(c - rate * z, kappa)
    return out[()] if out.ndim == 0 else out


#: optimiser bounds of the asymmetric-flux profile fit (kappa in [0, 1): seed 001 Eq. 2.9)
ASYM_BOUNDS = {"Ps": (-100.0, 100.0), "kappa": (0.0, 0.99)}
#: why the reduced (symmetric) form fixes kappa
KAPPA_ZERO = ("fixed at 0, the symmetric flux of T-eq. 28 (a special case of Eq. 2.9): the "
              "profile does not identify kappa")


def fit_asymmetric_flux(z, phi, phi0=None, *, sigma=None, contact_law=None,
                        min_points: int = 5) -> FitResult:
    """Fit Ps and kappa of the asymmetric-flux steady profile to one run's phi(z).

    Through :func:`.forms.fit_forms`: the full form (Ps, kappa) first; where it does not
    identify kappa (kappa at its bound 0: no asymmetry in the profile; or a stderr beyond
    :data:`.identify.TOLERANCES`), the symmetric form with kappa fixed at 0 (status
    ``reduced``).  Profile points are not independent runs (the coarse-graining kernel
    correlates neighbours), so no held-out or residual-structure test is made and the
    covariance stderrs are lower bounds: :func:`granflow.campaign.collect.segregation_fit`
    replaces them by the spread of per-window fits.
    """
    coords = dict(contact_law=contact_law, sigma=sigma)
    names = ("Ps", "kappa")
    z, phi = (np.asarray(x, dtype=float).ravel() for x in (z, phi))
    m = finite_mask(z, phi)
    n = int(m.sum())
    if n < min_points:
        return failed_fit("segregation_asymmetric", ASYM, names,
                          f"too few profile points: {n}", n, **coords)
    z, phi = z[m], phi[m]
    order = np.argsort(z)
    z, phi = z[order], phi[order]
    if phi0 is None:
        phi0 = float(integrate.trapezoid(phi, z) / (z[-1] - z[0]))
    if not 0.0 < phi0 < 1.0:
        return failed_fit("segregation_asymmetric", ASYM, names,
                          f"phi0 = {phi0} not in (0, 1)", n, **coords)
    sym = fit_Ps(z, phi, phi0)
    ps0 = min(max(sym.params["Ps"] if sym.ok else 1.0, -99.0), 99.0)
    full = Form("asymmetric", lambda zz, Ps, kappa: phi_asymmetric(zz, Ps, phi0, kappa),
                names, lambda x, y: [ps0, 0.3],
                "dphi/dz = -A(kappa) Ps phi (1 - phi)(1 - kappa phi)", bounds=dict(ASYM_BOUNDS),
                min_points=min_points)
    symmetric = Form("symmetric", lambda zz, Ps: phi_asymmetric(zz, Ps, phi0, 0.0), ("Ps",),
                     lambda x, y: [ps0], "kappa = 0: dphi/dz = -Ps phi (1 - phi)",
                     bounds={"Ps": ASYM_BOUNDS["Ps"]}, fixed={"kappa": (0.0, KAPPA_ZERO)},
                     min_points=min_points)
    res = fit_forms("segregation_asymmetric", ASYM, names, [full, symmetric], z, phi,
                    coords=coords, valid_range={"z": data_range(z)},
                    error_measure="Eq. (49) of phi - phi_fit", heldout=False, structure=False)
    if res.state == "failed":
        return res
    kappa = res.params["kappa"]
    resid = phi - phi_asymmetric(z, res.params["Ps"], phi0, kappa)
    extra = {**res.extra, "phi0": phi0, "A": asymmetric_flux_amplitude(kappa),
             "rms_residual": float(np.sqrt(np.mean(resid ** 2)))}
    return res.replace(extra=extra)


def compare_segregation_models(z, phi, phi0=None) -> pd.DataFrame:
    """Fit the symmetric (T-eq. 28) and asymmetric-flux profiles to one run and compare residuals.

    Columns: model, ok, status, n_params, Ps, Ps_stderr, kappa, kappa_status, rms_residual,
    error (Eq. 49), aic (Gaussian AIC = n ln(RSS/n) + 2 k, k the free parameters of the stored
    form; lower is better; the points are correlated, so differences are indicative only).
    The asymmetric row is :func:`fit_asymmetric_flux`'s: where the profile does not identify
    kappa it is the symmetric form again (status ``reduced``, kappa ``fixed`` at 0).
    """
    rows = []
    for name, fit in (("symmetric T-eq.28", fit_Ps(z, phi, phi0)),
                      ("asymmetric flux", fit_asymmetric_flux(z, phi, phi0))):
        rms = fit.extra.get("rms_residual", math.nan)
        n = fit.n_points
        k = sum(1 for st in fit.param_status.values() if st in ("identified", "unidentified")
                ) if fit.param_status else len(fit.params)
        usable = fit.state in ("ok", "reduced", "misfit", "unidentified")
        aic = n * math.log(rms ** 2) + 2 * k if usable and rms > 0 else math.nan
        rows.append({"model": name, "ok": fit.ok, "status": fit.state, "n_params": k,
                     "Ps": fit.params["Ps"], "Ps_stderr": fit.stderr["Ps"],
                     "kappa": fit.params.get("kappa", 0.0),
                     "kappa_status": fit.param_status.get("kappa", "not_in_form"),
                     "rms_residual": rms, "error": fit.error, "aic": aic})
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------- Ps(sigma) law
def Ps_teq29(sigma, Pmax, k):
    """T-eq. (29): Ps(sigma) = Pmax (1 - exp(-k (1/sigma - 1))), sigma = d_small/d_large."""
    sigma = np.asarray(sigma, dtype=float)
    out = Pmax * -np.expm1(-k * (1.0 / sigma - 1.0))
    return out[()] if out.ndim == 0 else out


def fit_Ps_law(sigma, Ps, Ps_stderr=None, *, contact_law=None, min_points: int = 3, ids=None,
               selection: str = "", seed: int = 0, sigma_parts=None,
               one_sided=None) -> FitResult:
    """Fit T-eq. (29) to per-run Peclet numbers Ps at size ratios sigma.

    ``Ps_stderr``: each run's standard error of Ps (from decorrelated windows); the points are
    weighted by it (absolute covariance, inflated by the Birge ratio when the scatter exceeds
    it).  While Ps is still linear in 1/sigma - 1 the saturation Pmax and the rate k are not
    identified separately (only their product, the initial slope): the fit then falls back to
    the reduced form Ps = slope (1/sigma - 1) over the fitted range (:mod:`.forms`) and states
    what the data do show about Pmax, a lower bound ``extra["Pmax_lower_bound"]`` =
    max_i(Ps_i - 1.645 s_i) (one-sided 95 %: T-eq. 29 never exceeds Pmax; for a reduced form
    the s_i are inflated by its Birge ratio when > 1, ``extra["bounds_stderr_inflation"]``).
    Where instead Ps has already saturated over the fitted range (every ratio on the plateau,
    as the paper's set-up gives at 1/sigma = 1.5-2), k is not identified either: the plateau
    form Ps = Pmax is the other reduced form, and of the two the one with the smaller weighted
    chi-square is kept (both have one parameter), with ``extra["k_lower_bound"]``
    (:func:`k_lower_bound`).

    ``one_sided``: runs whose segregated state was not shown steady, as (sigma, Ps, stderr,
    side) arrays; side +1 for a run that started mixed (its Ps approaches the steady value from
    below: a lower bound), -1 for one that started segregated (from above: an upper bound).
    They enter no fit; with a reduced form they and the fitted runs bound k from both sides
    (:func:`k_interval`, every run's interval end at once at 95 %, Bonferroni):
    ``extra["k_upper_bound"]`` (inf where nothing bounds it), and ``k_lower_bound`` is the
    larger of the two lower bounds.
    """
    coords = dict(contact_law=contact_law)
    names = ("Pmax", "k", "slope")
    sigma, Ps = (np.asarray(x, dtype=float).ravel() for x in (sigma, Ps))
    ids = np.asarray(ids if ids is not None else np.arange(sigma.size)).astype(str)
    m = finite_mask(sigma, Ps) & (sigma > 0) & (sigma < 1)
    s = None if Ps_stderr is None else np.asarray(Ps_stderr, dtype=float).ravel()
    n = int(m.sum())
    if n < 2:
        return failed_fit("Ps_law", TEQ29, names, f"too few size ratios: {n}, need {min_points}",
                          n, **coords)
    from .lsq import usable_sigma

    x, y = sigma[m], Ps[m]
    s = None if s is None else usable_sigma(s[m], n)
    err = np.zeros_like(y) if s is None else s
    lower = float(np.max(y - 1.645 * err))
    forms = [
        Form("teq29", Ps_teq29, ("Pmax", "k"),
             lambda xx, yy: [float(np.max(yy)) * 1.1, 2.0],
             "Ps = Pmax (1 - exp(-k (1/sigma - 1)))",
             bounds={"Pmax": (0.0, 1e4), "k": (0.0, 1e3)}, min_points=min_points),
        Form("linear", lambda xx, a: a * (1.0 / xx - 1.0), ("slope",),
             lambda xx, yy: [float(np.sum(yy * (1 / xx - 1)) / np.sum((1 / xx - 1) ** 2))],
             "Ps = slope (1/sigma - 1) over the fitted range: Ps has not saturated, so Pmax and "
             "k are not identified separately; Pmax_lower_bound says what the data show",
             min_points=min_points),
    ]
    plateau = Form("plateau", lambda xx, P: P * np.ones_like(np.asarray(xx, dtype=float)),
                   ("Pmax",), lambda xx, yy: [float(np.mean(yy))],
                   "Ps = Pmax over the fitted range: Ps has saturated, so k is not identified; "
                   "k_lower_bound says what the data show", min_points=min_points)
    common = dict(sigma=s, ids=ids[m], coords=coords, valid_range={"sigma": data_range(x)},
                  extra={"Pmax_lower_bound": lower}, error_measure="Eq. (49) of Ps - Ps_fit",
                  selection=selection, seed=seed, sigma_parts=_parts(sigma_parts, m))
    res = fit_forms("Ps_law", TEQ29, names, forms, x, y, **common)
    if res.form == "full":
        return res
    # T-eq. 29 not identified: still linear, or already saturated?  Both reduced forms have one
    # parameter; keep the one whose weighted chi-square is smaller (the linear form on a
    # plateau had chi2 6612 for 3 degrees of freedom and was called "reduced")
    alt = fit_forms("Ps_law", TEQ29, names, [forms[0], plateau], x, y, **common)
    good = ("ok", "reduced")
    if alt.form == "plateau" and alt.status in good and (
            res.status not in good
            or alt.diagnostics.get("chi2", math.inf) < res.diagnostics.get("chi2", math.inf)):
        res = alt
    # the bounds use the runs' standard errors, inflated by the Birge ratio where the runs
    # scatter about the chosen form more than those say
    birge = res.diagnostics.get("birge_ratio", math.nan)
    inflate = float(birge) if s is not None and math.isfinite(birge) and birge > 1 else 1.0
    extra = {"Pmax_lower_bound": float(np.max(y - 1.645 * inflate * err))}
    if res.form == "plateau":
        extra["k_lower_bound"] = k_lower_bound(x, y, None if s is None else inflate * err)
    if res.form in ("plateau", "linear") and s is not None:
        xo = yo = so = side = np.zeros(0)
        if one_sided is not None:
            xo, yo, so, side = (np.asarray(v, dtype=float).ravel() for v in one_sided)
            ok = finite_mask(xo, yo, so, side) & (xo > 0) & (xo < 1) & (side != 0)
            xo, yo, so, side = xo[ok], yo[ok], so[ok], side[ok]
        n_one = int(xo.size)
        # every interval end at once at 95 % (Bonferroni over the 2 ends of each fitted run and
        # the one end of each one-sided run); fitted runs' stderrs Birge-inflated as above
        zq = float(stats.norm.ppf(1.0 - 0.05 / (2 * x.size + n_one)))
        k_lo, k_hi = k_interval(
            np.concatenate([x, xo]),
            np.concatenate([y - zq * inflate * err, np.where(side > 0, yo - zq * so, 0.0)]),
            np.concatenate([y + zq * inflate * err, np.where(side < 0, yo + zq * so, math.inf)]))
        extra["k_upper_bound"] = k_hi
        if math.isfinite(k_lo):
            extra["k_lower_bound"] = max(k_lo, extra.get("k_lower_bound", 0.0) or 0.0)
        extra["k_bound_runs_one_sided"] = float(n_one)
    if inflate > 1:
        extra["bounds_stderr_inflation"] = inflate
    return res.replace(extra={**res.extra, **extra})


def k_interval(x, lower, upper, k_grid=None) -> tuple[float, float]:
    """The k of T-eq. 29 for which some Pmax puts every run's Ps inside its interval
    [lower_i, upper_i] (``x``: sigma values; an open end is 0 or inf).

    For a given k, Pmax must lie in [max_i lower_i / f_i(k), min_i upper_i / f_i(k)] with
    f_i(k) = 1 - e^{-k (1/sigma_i - 1)}; k is feasible where that interval is not empty.
    Scanned on a log grid of k in [1e-2, 1e3] (200 points per decade); returns (smallest,
    largest) feasible k, 0 / inf where the scan's end is feasible, (nan, nan) where no k is
    (the intervals contradict T-eq. 29)."""
    inv = 1.0 / np.asarray(x, dtype=float)
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    k = np.logspace(-2, 3, 1001) if k_grid is None else np.asarray(k_grid, dtype=float)
    f = -np.expm1(-np.outer(k, inv - 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        pmax_lo = np.max(np.where(lo > 0, lo / f, 0.0), axis=1)
        pmax_hi = np.min(np.where(np.isfinite(hi), hi / f, math.inf), axis=1)
    feasible = pmax_lo <= pmax_hi
    if not feasible.any():
        return math.nan, math.nan
    idx = np.flatnonzero(feasible)
    k_lo = 0.0 if idx[0] == 0 else float(k[idx[0]])
    k_hi = math.inf if idx[-1] == len(k) - 1 else float(k[idx[-1]])
    return k_lo, k_hi


def k_lower_bound(x, Ps, Ps_stderr=None) -> float:
    """One-sided 95 % lower bound on T-eq. 29's k from a saturated sweep, or 0 where the data
    give none.

    T-eq. 29's ratio g(k) = Ps(b)/Ps(a) = (1 - e^{-k (b - 1)}) / (1 - e^{-k (a - 1)}) between
    the largest and the smallest 1/sigma (a < b) falls from (b - 1)/(a - 1) at k = 0 to 1 as
    k grows, whatever Pmax; the measured ratio's upper end (means at each end, each moved by
    1.645 of its standard error, or of the scatter about their mean where there is no
    standard error) bounds k from below: k >= g^-1(ratio_upper).  ``x`` are sigma values."""
    inv = 1.0 / np.asarray(x, dtype=float)
    y = np.asarray(Ps, dtype=float)
    se = (np.full_like(y, np.std(y, ddof=1) if y.size > 1 else math.nan)
          if Ps_stderr is None else np.asarray(Ps_stderr, dtype=float))
    lo_x, hi_x = inv.min(), inv.max()
    if not hi_x > lo_x or lo_x <= 1.0:
        return math.nan

    def end(mask):
        n = int(mask.sum())
        return float(np.mean(y[mask])), float(math.sqrt(np.sum(se[mask] ** 2)) / n)

    ya, sa = end(np.isclose(inv, lo_x))
    yb, sb = end(np.isclose(inv, hi_x))
    if not (ya - 1.645 * sa > 0):
        return 0.0
    ratio = (yb + 1.645 * sb) / (ya - 1.645 * sa)
    a, b = lo_x - 1.0, hi_x - 1.0
    if ratio >= b / a:
        return 0.0
    if ratio <= 1.0:
        return math.inf

    def g(k):
        return -math.expm1(-k * b) / -math.expm1(-k * a) - ratio

    hi = 1.0
    while g(hi) > 0 and hi < 1e6:
        hi *= 2.0
    return float(optimize.brentq(g, 1e-9, hi)) if g(hi) <= 0 else math.inf


# ------------------------------------------------------------ one run's Ps and its wander
def wander_sd(Ps, n_flow) -> float:
    """How far one run's Ps (its profile window's mean) lies from its state's long-time mean,
    one standard deviation: ``C |Ps| / sqrt(n_flow)`` with C =
    :data:`granflow.reference.SEGREGATION_WANDER_C` (1.63), measured from long runs and
    continuations at 284-7560 flow particles (the relative spread of profile-window means falls
    as 1 / sqrt(N); :data:`granflow.reference.SEGREGATION_WANDER_SCALING`).  The segregated
    state wanders over 40-300 time units, as long as a profile window, so the standard error
    of a run's own windows misses most of it (2-8x at the default set-up).  NaN when ``Ps`` or
    ``n_flow`` is not a finite positive number."""
    from ..reference import SEGREGATION_WANDER_C

    try:
        Ps, n = float(Ps), float(n_flow)
    except (TypeError, ValueError):
        return math.nan
    if not (math.isfinite(Ps) and math.isfinite(n) and n > 0):
        return math.nan
    return SEGREGATION_WANDER_C * abs(Ps) / math.sqrt(n)


#: how a per-run Ps stderr is made (granflow.campaign.collect.segregation_fit)
PS_STDERR_METHOD = ("the larger of the standard error of the mean of the run's per-window fits "
                    "(decorrelated windows: Ps_windows_sem) and the wander of a profile window's "
                    "Ps in time measured at the run's number of flow particles N (C Ps / sqrt(N), "
                    "C = {c:.2f}: Ps_wander_sd; granflow.fitting.segregation.wander_sd)")


# ----------------------------------------------------------- several runs at one size ratio
#: said of a size ratio with a single run (granflow.reference.segregation_seed_scatter_note
#: has the measured scatter between seeds, in the library's reductions_vs_paper)
ONE_RUN_NOTE = ("one run at this ratio: its Ps stderr is its profile windows' or, where larger, "
                "the wander in time measured at its number of particles (wander_sd); the "
                "scatter between this campaign's insertion seeds is not measured (replicates)")


def combine_Ps_runs(fits) -> list:
    """One ``segregation`` fit per (contact law, sigma) from the per-run T-eq. (28) fits.

    A campaign with replicates (insertion seeds) or several starts at one size ratio has
    several per-run fits there; the library holds one value per ratio.  Fits of other kinds and
    ratios with one run pass through unchanged.  At a ratio with several runs the identified
    ones (``ok``: steady flow, steady segregated state, Ps identified) are averaged:

        Ps = mean(Ps_i),  stderr^2 = max(s^2, mean(sem_i^2)) / n,

    s the standard deviation between the runs and sem_i each run's own (decorrelated windows)
    standard error: the runs' spread measures what one run's windows cannot see (another seed,
    another start, a segregated state that wanders over longer times than a profile window),
    and where the runs agree better than their own errors say, those errors stand.  The 95 %
    interval uses Student's t with n - 1 degrees of freedom.  ``extra``: ``Ps_between_run_sd``
    (s), ``runs_combined`` (n), ``Ps_runs`` and ``Ps_runs_sem`` (each run's value and error),
    ``Ps_within_run_sem`` (sqrt(mean sem_i^2) / sqrt(n): what the runs' own errors alone give),
    ``Ps_windows_sem`` and ``Ps_wander_sd`` (the two parts of sem_i, each as rms / sqrt(n)).
    With no identified run, the first run's fit (by run name) stands for the ratio, unidentified,
    its message naming the others."""
    groups: dict = {}
    order = []
    for r in fits:
        if r.kind != "segregation":
            order.append(("pass", id(r), r))
            continue
        key = (str(r.coords.get("contact_law")), float(r.coords.get("sigma", math.nan)))
        if key not in groups:
            groups[key] = []
            order.append(("group", key, None))
        groups[key].append(r)
    out = []
    for what, key, r in order:
        if what == "pass":
            out.append(r)
            continue
        runs = sorted(groups[key], key=lambda f: str(f.runs_used[0]) if f.runs_used else "")
        if len(runs) == 1:
            out.append(runs[0].replace(selection=(runs[0].selection + "; " if runs[0].selection
                                                  else "") + ONE_RUN_NOTE))
            continue
        out.append(_combined_Ps_fit(runs))
    return out


def _combined_Ps_fit(runs) -> FitResult:
    from .identify import assess

    names = [str(f.runs_used[0]) if f.runs_used else "?" for f in runs]
    is_good = [f.ok and math.isfinite(f.params.get("Ps", math.nan)) for f in runs]
    good = [f for f, g in zip(runs, is_good) if g]
    used = [n for n, g in zip(names, is_good) if g]
    left = [n for n, g in zip(names, is_good) if not g]
    if not good:
        first = runs[0]
        values = ", ".join(f"{n}: {f.params.get('Ps', math.nan):.4g}"
                           for f, n in zip(runs, names))
        note = (f"; {len(runs)} runs at this ratio, none with an identified steady Ps "
                f"({values}): the first stands for the ratio")
        return first.replace(message=first.message + note,
                             runs_used=tuple(names),
                             extra=dict(first.extra, runs_combined=0))
    v = np.array([f.params["Ps"] for f in good], dtype=float)
    sem = np.array([f.stderr.get("Ps", math.nan) for f in good], dtype=float)
    n = len(good)
    within2 = float(np.nanmean(sem ** 2)) if np.isfinite(sem).any() else math.nan
    if n == 1:
        f = good[0]
        return f.replace(message=f.message + (
            f"; the only identified run of {len(runs)} at this ratio (left out: "
            f"{', '.join(left)})"), extra=dict(f.extra, runs_combined=1))
    mean = float(v.mean())
    sd = float(v.std(ddof=1))
    var = max(sd ** 2, within2) if math.isfinite(within2) else sd ** 2
    se = math.sqrt(var / n)
    half = float(stats.t.ppf(0.975, n - 1)) * se
    phi0 = [f.extra.get("phi0") for f in good if f.extra.get("phi0") is not None]
    depth = [f.extra.get("scaled_depth") for f in good
             if f.extra.get("scaled_depth") is not None]
    base = good[0]
    extra = dict(
        phi0=float(np.mean(phi0)) if phi0 else math.nan,
        scaled_depth=float(np.nanmean(depth)) if depth else math.nan,
        ci95=(mean - half, mean + half),
        Ps_between_run_sd=sd, runs_combined=n,
        Ps_runs=[float(x) for x in v], Ps_runs_sem=[float(x) for x in sem],
        Ps_within_run_sem=math.sqrt(within2 / n) if math.isfinite(within2) else math.nan,
        segregation_state=str(base.extra.get("segregation_state", "")),
    )
    # the two parts of each run's own error (granflow.campaign.collect.segregation_fit), for
    # the mean: its windows' and the wander at its number of particles
    for key in ("Ps_windows_sem", "Ps_wander_sd"):
        parts = np.array([f.extra.get(key, math.nan) for f in good], dtype=float)
        extra[key] = (math.sqrt(float(np.mean(parts ** 2)) / n) if np.isfinite(parts).all()
                      else math.nan)
    ratio = sd / math.sqrt(within2) if math.isfinite(within2) and within2 > 0 else math.nan
    message = (f"mean of {n} runs' T-eq. (28) fits ({', '.join(used)}): "
               f"Ps {', '.join(f'{x:.4g}' for x in v)}; spread between runs {sd:.3g} = "
               f"{ratio:.2g}x the runs' own standard errors (rms)"
               + (f"; left out (not identified): {', '.join(left)}" if left else ""))
    combined = FitResult(
        kind="segregation", equation=base.equation, params={"Ps": mean}, stderr={"Ps": se},
        error=float(np.mean([f.error for f in good])), n_points=int(sum(f.n_points for f in good)),
        ok=True, message=message,
        stderr_method=("standard error of the mean of the runs: sqrt(max(between-run variance, "
                       "mean within-run sem^2) / n)"),
        error_measure=base.error_measure, valid_range=dict(base.valid_range),
        coords=dict(base.coords), extra=extra, runs_used=tuple(used),
        selection=f"{n} of {len(runs)} runs at sigma = {base.coords.get('sigma')}")
    return assess(combined)
