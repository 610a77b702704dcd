"""Stopping height hstop(theta; lambda) fitted to arrested/flowing brackets.

Implements Weinhart et al. (2012) Eq. (45) (Pouliquen's form, Eq. 35):

    hstop(theta) = A d (tan delta2 - tan theta) / (tan theta - tan delta1),  delta1 < theta < delta2,

with hstop = inf for theta <= delta1 and 0 for theta >= delta2, and, for comparison only, the
earlier exponential form Eq. (38) (Pouliquen 1999):

    hstop'(theta) = A' d ln[(tan delta2' - tan delta1') / (tan theta - tan delta1')].

(The extracted PDF text of Eq. 38 shows the ratio inverted, ln[(tan theta - tan d1)/(tan d2 - tan d1)],
which is negative on (d1, d2); with A' > 0 the form above is the one with the stated limiting
behaviour -- diverging at delta1', zero at delta2' -- and is the same curve with A' -> -A'.)

Input data are the bracketing intervals of the adaptive search (physics.md §5, paper §6): for each
height H, the largest inclination at which the run arrested, ``theta_arrested_max``, and the
smallest at which it flowed, ``theta_flowing_min``. A height with only one kind of run gives a
one-sided interval. The fit minimises the horizontal (theta) distance from the curve
theta_stop(H) to the intervals (zero where the curve crosses an interval), as in the paper. Because
that objective is flat for every curve crossing all intervals, a small tie-break term
``tie_break * (theta_stop(H) - interval midpoint)^2`` picks the curve through the middle of the
intervals among those; ``tie_break=0`` gives the paper's objective alone.

Uncertainties are from a bootstrap over intervals (``stderr_method="bootstrap"``): the intervals
are resampled with replacement ``n_bootstrap`` times and refitted; stderr is half the central
68 % range of the refitted parameters (robust to the few resamples that drop the thinnest
brackets, on which delta2 rests), and the refits are kept as the closure's ensemble.  Further
batches of ``n_bootstrap`` refits follow while an identifiability test is within the Monte
Carlo error of its limit (:func:`granflow.fitting.result.bootstrap_undecided`; at most
:func:`granflow.fitting.result.bootstrap_cap` refits), so that a status does not depend on
the bootstrap's seed; ``extra['bootstrap']`` says how many refits were made.  Brackets
on several base realisations (a ``base`` label per interval, e.g. a campaign's ``base_seed``) are
not independent when one base lifts all of its brackets: the offset common to a base is
estimated as a random effect (:func:`base_scatter`) and each refit shifts each base's brackets by
a draw of it. The error measure is Eq. (49) of the horizontal distances
(degrees). The paper fitted Eq. (38) by the vertical distance; here both forms use the horizontal
distance so that their errors compare like with like.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import optimize

from .identify import at_bound, tolerance
from .result import (FitResult, bootstrap_cap, bootstrap_stderr, bootstrap_undecided,
                     bootstrap_summary, error_eq49, failed_fit)

EQ45 = "Weinhart et al. 2012 Eq. (45)"
EQ38 = "Weinhart et al. 2012 Eq. (38)"
HSTOP_PARAMS = ("delta1", "delta2", "A")
INTERVAL_COLUMNS = ("H", "theta_arrested_max", "theta_flowing_min")
#: states counted as flowing for the demarcation (the paper's binary rule, §6: a run is arrested
#: when E_kin/E_ela falls below 1e-5, otherwise flowing -- including runs left "undecided" at
#: their cap, which did not arrest)
FLOWING_STATES = ("steady", "accelerating", "layered", "oscillating", "undecided", "flowing")
#: ``stop_reason`` of a campaign-table row whose run an engine guard ended before the classifier
#: had any flow state (e.g. an overlap on impact while a soft layer falls in): no evidence of
#: flowing or arresting, left out of the hstop intervals (its state stays ``undecided``)
ENGINE_STOP_NO_STATE = "engine guard before any flow state"
#: optimiser bounds of (delta1, delta2 - delta1, A)
_LOWER = (0.0, 1e-3, 1e-6)
_UPPER = (89.0, 60.0, 1e5)
#: where an active bound is moved to test what the other parameters owe to it: a refit with the
#: bound there (still physically meaningless on either side: delta2 - delta1 of 30 deg, A of
#: 1e-3 d) must not move a parameter by more than its stderr, else that parameter is determined
#: only by the bound (:func:`bound_conditional`)
_MOVED_LOWER = (5.0, 0.25, 1e-3)
_MOVED_UPPER = (60.0, 30.0, 1e3)
_WHICH = {"delta1": 0, "delta2": 1, "A": 2}


# ---------------------------------------------------------------------------- closed forms
def hstop_eq45(theta, delta1, delta2, A, d: float = 1.0):
    """Eq. (45): stopping height at inclination ``theta`` (degrees); inf below delta1, 0 above delta2."""
    theta = np.asarray(theta, dtype=float)
    t, t1, t2 = np.tan(np.radians(theta)), math.tan(math.radians(delta1)), math.tan(math.radians(delta2))
    with np.errstate(divide="ignore", invalid="ignore"):
        h = A * d * (t2 - t) / (t - t1)
    h = np.where(theta <= delta1, np.inf, np.where(theta >= delta2, 0.0, h))
    return h[()] if h.ndim == 0 else h


def theta_stop_eq45(h, delta1, delta2, A, d: float = 1.0):
    """Inverse of Eq. (45): inclination (degrees) at which height ``h`` stops; delta1 as h -> inf."""
    h = np.asarray(h, dtype=float)
    t1, t2 = math.tan(math.radians(delta1)), math.tan(math.radians(delta2))
    Ad = A * d
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(np.isinf(h), t1, (Ad * t2 + h * t1) / (h + Ad))
    out = np.degrees(np.arctan(t))
    return out[()] if out.ndim == 0 else out


def hstop_eq38(theta, delta1, delta2, A, d: float = 1.0):
    """Eq. (38), exponential form: A d ln[(tan d2 - tan d1)/(tan theta - tan d1)] on (d1, d2)."""
    theta = np.asarray(theta, dtype=float)
    t, t1, t2 = np.tan(np.radians(theta)), math.tan(math.radians(delta1)), math.tan(math.radians(delta2))
    with np.errstate(divide="ignore", invalid="ignore"):
        h = A * d * np.log((t2 - t1) / (t - t1))
    h = np.where(theta <= delta1, np.inf, np.where(theta >= delta2, 0.0, h))
    return h[()] if h.ndim == 0 else h


def theta_stop_eq38(h, delta1, delta2, A, d: float = 1.0):
    """Inverse of Eq. (38): tan theta = tan d1 + (tan d2 - tan d1) exp(-h/(A d))."""
    h = np.asarray(h, dtype=float)
    t1, t2 = math.tan(math.radians(delta1)), math.tan(math.radians(delta2))
    with np.errstate(over="ignore"):
        t = t1 + (t2 - t1) * np.exp(-h / (A * d))
    out = np.degrees(np.arctan(t))
    return out[()] if out.ndim == 0 else out


_FORMS = {"eq45": (EQ45, "hstop", theta_stop_eq45), "eq38": (EQ38, "hstop_eq38", theta_stop_eq38)}


# ---------------------------------------------------------------------------- intervals
def hstop_intervals_from_runs(theta, H=None, state=None, replicate=None) -> pd.DataFrame:
    """Bracketing intervals [theta_arrested_max, theta_flowing_min] per height (and replicate)
    from raw runs.

    Accepts arrays ``theta, H, state`` (and optionally ``replicate``) or a single DataFrame
    (campaign table or any frame with columns theta, H, state and optionally replicate) as
    first argument. 'arrested' runs are arrested; steady, accelerating, layered, oscillating and
    undecided runs count as flowing (:data:`FLOWING_STATES`). A height with only arrested (only
    flowing) runs gets ``theta_flowing_min = +inf`` (``theta_arrested_max = -inf``): a one-sided
    interval. If the largest arrested angle exceeds the smallest flowing one (non-monotone
    outcome), the two are swapped so the interval still brackets the demarcation; ``n_inverted``
    counts them.

    A frame with a ``stop_reason`` column: rows stopped by an engine guard before they had any
    flow state (:data:`ENGINE_STOP_NO_STATE`) are left out; they say nothing about arrest.

    Replicates (insertion seed + k, column ``replicate``) bracket their own arrest: each
    (H, replicate) gets its own interval, so that k chains at one height are k data for the fit
    and its bootstrap, and their scatter enters the fit's error, instead of one interval widened
    by the seed scatter (pooling the seeds' runs inverts the bracket as soon as one seed arrests
    above another's flowing angle).  Runs without a replicate index count as replicate 0.

    A frame with a ``base`` or ``base_seed`` column (the base realisation a run fell onto: a
    campaign table's ``base_seed``, or any label) gives each interval the ``base`` of its runs,
    which the fit uses to model an offset common to one base's brackets
    (:func:`base_scatter`); an (H, replicate) whose runs lie on several bases is an error.
    """
    base = None
    if isinstance(theta, pd.DataFrame):
        frame = theta
        if "stop_reason" in frame.columns:
            frame = frame[frame["stop_reason"].astype(str) != ENGINE_STOP_NO_STATE]
        theta, H, state = frame["theta"].to_numpy(float), frame["H"].to_numpy(float), frame["state"].to_numpy()
        if "replicate" in frame.columns:
            replicate = frame["replicate"].to_numpy(float)
        col = next((c for c in ("base", "base_seed") if c in frame.columns), None)
        if col is not None:
            base = frame[col].to_numpy(object)
    theta = np.asarray(theta, dtype=float)
    H = np.asarray(H, dtype=float)
    state = np.asarray(state).astype(str)
    rep = (np.zeros(theta.shape) if replicate is None
           else np.nan_to_num(np.asarray(replicate, dtype=float), nan=0.0))
    unknown = set(state) - set(FLOWING_STATES) - {"arrested"}
    if unknown:
        raise ValueError(f"unknown flow state(s) {sorted(unknown)}")
    rows = []
    for h in np.unique(H[np.isfinite(H)]):
        for k in np.unique(rep[H == h]):
            sel = (H == h) & (rep == k)
            arrested = theta[sel & (state == "arrested")]
            flowing = theta[sel & (state != "arrested")]
            lo = float(arrested.max()) if arrested.size else -math.inf
            hi = float(flowing.min()) if flowing.size else math.inf
            inverted = lo > hi
            if inverted:
                lo, hi = hi, lo
            row = {"H": float(h), "theta_arrested_max": lo, "theta_flowing_min": hi,
                   "inverted": bool(inverted), "replicate": int(k)}
            if base is not None:
                labels = {b for b in base[sel] if not _missing(b)}
                if len(labels) > 1:
                    raise ValueError(f"the runs at H = {h:g}, replicate {int(k)} lie on several "
                                     f"bases {sorted(map(str, labels))}: a bracket must lie on "
                                     "one base")
                row["base"] = labels.pop() if labels else None
            rows.append(row)
    extra = ["inverted", "replicate"] + (["base"] if base is not None else [])
    return pd.DataFrame(rows, columns=list(INTERVAL_COLUMNS) + extra)


def _missing(label) -> bool:
    return label is None or (isinstance(label, float) and math.isnan(label))


def _as_intervals(intervals, runs):
    if intervals is None and runs is None:
        raise ValueError("give either intervals or runs")
    if intervals is None:
        intervals = hstop_intervals_from_runs(runs)
    if not isinstance(intervals, pd.DataFrame):
        intervals = pd.DataFrame(intervals, columns=list(INTERVAL_COLUMNS))
    for col in INTERVAL_COLUMNS:
        if col not in intervals.columns:
            raise ValueError(f"hstop intervals are missing column {col!r}")
    H = intervals["H"].to_numpy(float)
    lo = intervals["theta_arrested_max"].to_numpy(float)
    hi = intervals["theta_flowing_min"].to_numpy(float)
    rep = (intervals["replicate"].fillna(0).to_numpy(int) if "replicate" in intervals.columns
           else np.zeros(H.shape, int))
    # base realisation of each interval as a code 0, 1, ... (-1: not known)
    base = np.full(H.shape, -1, int)
    if "base" in intervals.columns:
        labels = [None if _missing(b) else str(b) for b in intervals["base"]]
        known = sorted({b for b in labels if b is not None})
        base = np.array([-1 if b is None else known.index(b) for b in labels], int)
    keep = np.isfinite(H) & (H > 0) & ~(np.isnan(lo) & np.isnan(hi))
    lo = np.where(np.isnan(lo), -np.inf, lo)
    hi = np.where(np.isnan(hi), np.inf, hi)
    return H[keep], lo[keep], hi[keep], rep[keep], base[keep]


def base_scatter(offsets, base) -> dict | None:
    """Standard deviation of an offset common to one base realisation's brackets.

    ``offsets``: bracket midpoint minus the fitted curve's angle (degrees, two-sided brackets);
    ``base``: each bracket's base code (-1: unknown, left out).  One-way random-effects model
    offset_ij = b_j + e_ij with the method-of-moments (ANOVA) estimate for unequal group sizes,
    sigma_b^2 = max(0, (MSB - MSW) / n0), n0 = (N - sum n_j^2 / N) / (J - 1).  Needs J >= 2
    bases and N > J brackets; returns None otherwise.  The fit's bootstrap then shifts each base's
    brackets by its own draw of N(0, sigma_b^2): replicate chains on other bases
    (``hstop_bisection.replicate_bases``) are not independent data when one base lifts all of its
    brackets, and resampling brackets one by one would not see it."""
    offsets = np.asarray(offsets, dtype=float)
    base = np.asarray(base, dtype=int)
    ok = (base >= 0) & np.isfinite(offsets)
    offsets, base = offsets[ok], base[ok]
    codes = np.unique(base)
    J, N = len(codes), len(offsets)
    if J < 2 or N <= J:
        return None
    n = np.array([np.sum(base == c) for c in codes], float)
    means = np.array([offsets[base == c].mean() for c in codes])
    grand = offsets.mean()
    msb = float(np.sum(n * (means - grand) ** 2) / (J - 1))
    msw = float(sum(np.sum((offsets[base == c] - m) ** 2) for c, m in zip(codes, means)) / (N - J))
    n0 = float((N - np.sum(n ** 2) / N) / (J - 1))
    var_b = max(0.0, (msb - msw) / n0)
    return {"n_bases": int(J), "n_brackets": int(N), "sigma_between": math.sqrt(var_b),
            "sigma_within": math.sqrt(msw), "mean_offsets": [float(m) for m in means],
            "brackets_per_base": [int(k) for k in n],
            "method": "one-way random effects, ANOVA (method of moments) estimate, unequal "
                      "group sizes; offsets of two-sided bracket midpoints from the fitted curve"}



def bracket_offsets_by_base(runs: pd.DataFrame, delta1: float, delta2: float, A: float,
                            d: float = 1.0) -> pd.DataFrame:
    """Where each base realisation's brackets lie against an Eq. (45) curve: one row per
    ``base_seed`` of ``runs`` (campaign-table rows with theta, H, state, replicate, base_seed)
    with the number of two-sided brackets, their mean and standard deviation of (midpoint -
    curve angle at H) in degrees.  A base's mean far from the others' is the scatter between
    base realisations (``hstop_bisection.replicate_bases``) that a single base's fit cannot
    see and that the fit over several bases carries as a random effect (:func:`base_scatter`)."""
    cols = ["base_seed", "brackets", "mean_offset", "std_offset"]
    if "base_seed" not in runs.columns or not len(runs):
        return pd.DataFrame(columns=cols)
    iv = hstop_intervals_from_runs(runs)  # each bracket's base; refused when it has two
    two = (np.isfinite(iv["theta_arrested_max"]) & np.isfinite(iv["theta_flowing_min"])
           & iv["base"].notna())
    iv = iv[two]
    mid = 0.5 * (iv["theta_arrested_max"] + iv["theta_flowing_min"])
    off = mid - theta_stop_eq45(iv["H"].to_numpy(float), delta1, delta2, A, d)
    rows = [{"base_seed": int(b), "brackets": int(len(g)), "mean_offset": float(g.mean()),
             "std_offset": float(g.std(ddof=1)) if len(g) > 1 else math.nan}
            for b, g in off.groupby(iv["base"].astype(float).to_numpy())]
    return pd.DataFrame(rows, columns=cols)

# ---------------------------------------------------------------------------- fitting
def horizontal_distance(theta_curve, lo, hi):
    """Distance (degrees) from curve angles to intervals [lo, hi]; zero inside the interval."""
    return np.maximum(0.0, np.maximum(lo - theta_curve, theta_curve - hi))


def _residuals(p, H, lo, hi, two_sided, tie, theta_stop, d):
    delta1, width, A = p
    th = theta_stop(H, delta1, delta1 + width, A, d)
    r = horizontal_distance(th, lo, hi)
    if tie > 0 and np.any(two_sided):
        mid = 0.5 * (lo[two_sided] + hi[two_sided])
        r = np.concatenate([r, math.sqrt(tie) * (th[two_sided] - mid)])
    return r


def _solve(H, lo, hi, tie, theta_stop, d, starts, bounds=(_LOWER, _UPPER)):
    two_sided = np.isfinite(lo) & np.isfinite(hi)
    lower, upper = (np.asarray(b, dtype=float) for b in bounds)
    best = None
    for p0 in starts:
        p0 = np.clip(p0, lower + 1e-9 * np.maximum(1.0, np.abs(lower)),
                     upper - 1e-9 * np.maximum(1.0, np.abs(upper)))
        try:
            sol = optimize.least_squares(
                _residuals, p0, args=(H, lo, hi, two_sided, tie, theta_stop, d),
                bounds=(list(lower), list(upper)), x_scale=[1.0, 1.0, max(p0[2], 1e-3)],
                method="trf", xtol=1e-10, ftol=1e-12, gtol=1e-12, max_nfev=1000)
        except (ValueError, FloatingPointError):
            continue
        if not np.all(np.isfinite(sol.x)):
            continue
        if best is None or sol.cost < best.cost:
            best = sol
    return best


def _starts(H, lo, hi, d):
    finite_angles = np.concatenate([lo[np.isfinite(lo)], hi[np.isfinite(hi)]])
    amin, amax = float(finite_angles.min()), float(finite_angles.max())
    starts = []
    for off1 in (0.5, 2.0, 5.0):
        for off2 in (1.0, 5.0, 12.0):
            d1 = max(amin - off1, 0.5)
            d2 = amax + off2
            mid = np.where(np.isfinite(lo) & np.isfinite(hi), 0.5 * (lo + hi), np.nan)
            t, t1, t2 = np.tan(np.radians(mid)), math.tan(math.radians(d1)), math.tan(math.radians(d2))
            with np.errstate(invalid="ignore", divide="ignore"):
                A_est = H * (t - t1) / (t2 - t) / d
            A_est = A_est[np.isfinite(A_est) & (A_est > 0)]
            A0 = float(np.median(A_est)) if A_est.size else 3.0
            starts.append(np.array([d1, d2 - d1, A0]))
    return starts


def bound_conditional(H, lo, hi, tie, theta_stop, d, x, stderr, at_b) -> dict:
    """Parameters that only an active optimiser bound determines: ``{name: reason}``.

    A parameter at a bound is not a result (:mod:`.identify`), and neither is a parameter that
    the fit trades against it: with delta2 - delta1 at its upper bound, brackets that show no
    rise of theta_stop in thin layers fix only (tan delta2 - tan delta1) A, so A follows the
    bound and its bootstrap stderr (every refit at the same bound) says nothing about it.  The
    fit is repeated with each active bound moved (:data:`_MOVED_LOWER`, :data:`_MOVED_UPPER`);
    a parameter not at a bound that moves by more than its stderr is conditional on the bound.
    """
    if not at_b:
        return {}
    lower, upper = list(_LOWER), list(_UPPER)
    moved = []
    for name in at_b:
        j = _WHICH[name]
        if abs(x[j] - _UPPER[j]) <= abs(x[j] - _LOWER[j]):
            upper[j] = _MOVED_UPPER[j]
            moved.append(f"{'delta2 - delta1' if j == 1 else name} <= {_UPPER[j]:g} -> "
                         f"{_MOVED_UPPER[j]:g}")
        else:
            lower[j] = _MOVED_LOWER[j]
            moved.append(f"{'delta2 - delta1' if j == 1 else name} >= {_LOWER[j]:g} -> "
                         f"{_MOVED_LOWER[j]:g}")
    sol = _solve(H, lo, hi, tie, theta_stop, d, [np.asarray(x, dtype=float)]
                 + _starts(H, lo, hi, d), bounds=(lower, upper))
    if sol is None or not sol.success:
        return {n: f"conditional on {', '.join(at_b)} at an optimiser bound (a refit with the "
                   f"bound moved did not converge)" for n in _WHICH if n not in at_b}
    new = {"delta1": sol.x[0], "delta2": sol.x[0] + sol.x[1], "A": sol.x[2]}
    old = {"delta1": x[0], "delta2": x[0] + x[1], "A": x[2]}
    out = {}
    for name in _WHICH:
        if name in at_b:
            continue
        shift = abs(new[name] - old[name])
        se = stderr.get(name, math.nan)
        if not (math.isfinite(se) and se > 0) or shift > se:
            out[name] = (f"determined by the bound of {', '.join(at_b)}: moving it "
                         f"({'; '.join(moved)}) moves {name} from {old[name]:.4g} to "
                         f"{new[name]:.4g}, {shift / se if se > 0 else math.inf:.1f} stderr")
    return out


def _fit_hstop(form, intervals, runs, lam, contact_law, n_bootstrap, seed, tie_break, d,
               min_intervals):
    equation, kind, theta_stop = _FORMS[form]
    coords = dict(lam=lam, contact_law=contact_law)
    try:
        H, lo, hi, rep, base = _as_intervals(intervals, runs)
    except ValueError as exc:
        return failed_fit(kind, equation, HSTOP_PARAMS, str(exc), 0, "bootstrap", **coords)
    two_sided = np.isfinite(lo) & np.isfinite(hi)
    n_two = int(two_sided.sum())
    if n_two < min_intervals:
        return failed_fit(kind, equation, HSTOP_PARAMS,
                          f"too few arrested/flowing brackets: {n_two} two-sided intervals, "
                          f"need at least {min_intervals}", len(H), "bootstrap", **coords)
    best = _solve(H, lo, hi, tie_break, theta_stop, d, _starts(H, lo, hi, d))
    if best is None or not best.success:
        msg = "optimizer did not converge" + (f": {best.message}" if best is not None else "")
        return failed_fit(kind, equation, HSTOP_PARAMS, msg, len(H), "bootstrap", **coords)
    delta1, width, A = best.x
    params = {"delta1": float(delta1), "delta2": float(delta1 + width), "A": float(A)}
    th = theta_stop(H, params["delta1"], params["delta2"], params["A"], d)
    dist = horizontal_distance(th, lo, hi)
    scatter = base_scatter(np.where(two_sided, 0.5 * (lo + hi) - th, np.nan), base)
    sigma_b = scatter["sigma_between"] if scatter else 0.0

    rng = np.random.default_rng(seed)
    boot, boot_at = [], []
    n = len(H)
    n_codes = int(base.max()) + 1 if len(base) else 0
    lower, upper = np.asarray(_LOWER), np.asarray(_UPPER)
    # refits in batches of n_bootstrap until no identifiability test is left to the bootstrap's
    # Monte Carlo error (bootstrap_undecided), or bootstrap_cap(n_bootstrap) refits: a stderr from
    # one batch can change with the seed across its tolerance
    limits = [max(r * abs(v), a) for (r, a), v in
              zip((tolerance(kind, k) for k in HSTOP_PARAMS), params.values())]
    attempted, cap = 0, bootstrap_cap(n_bootstrap)
    while attempted < cap:
        for _ in range(min(int(n_bootstrap), cap - attempted)):
            attempted += 1
            idx = rng.integers(0, n, n)
            if int(two_sided[idx].sum()) < min_intervals:
                continue
            lo_b, hi_b = lo[idx], hi[idx]
            if sigma_b > 0:  # an offset common to each base's brackets, drawn anew per refit
                shift = np.append(rng.normal(0.0, sigma_b, n_codes), 0.0)[base[idx]]
                lo_b, hi_b = lo_b + shift, hi_b + shift
            sol = _solve(H[idx], lo_b, hi_b, tie_break, theta_stop, d, [best.x])
            if sol is not None and sol.success:
                boot.append([sol.x[0], sol.x[0] + sol.x[1], sol.x[2]])
                boot_at.append([at_bound(v, a, b) for v, a, b in zip(sol.x, lower, upper)])
        if len(boot) >= 10 and not bootstrap_undecided(boot, limits, boot_at):
            break
    boot = np.asarray(boot).reshape(-1, 3)
    boot_info = bootstrap_summary(boot, HSTOP_PARAMS, np.asarray(boot_at, bool).reshape(-1, 3),
                                  requested=n_bootstrap)
    boot_info["attempted"] = attempted
    if len(boot) >= 10:
        stderr = {k: bootstrap_stderr(boot[:, j]) for j, k in enumerate(HSTOP_PARAMS)}
        boot_msg = f"bootstrap: {len(boot)} of {attempted} refits"
    else:
        stderr = {k: math.nan for k in HSTOP_PARAMS}
        boot_msg = f"bootstrap failed ({len(boot)} usable refits); stderr NaN"
    if scatter:
        boot_msg += (f"; brackets on {scatter['n_bases']} base realisations: an offset common to "
                     f"one base's brackets, sigma_b = {sigma_b:.2f} deg (random effects; within "
                     f"a base {scatter['sigma_within']:.2f}), "
                     + ("is drawn per base in every refit" if sigma_b > 0 else
                        "is not resolved above the scatter within a base"))
    finite = np.concatenate([lo[np.isfinite(lo)], hi[np.isfinite(hi)]])
    at_b = [name for name, v, lo_b, hi_b in (("delta1", delta1, _LOWER[0], _UPPER[0]),
                                             ("delta2", width, _LOWER[1], _UPPER[1]),
                                             ("A", A, _LOWER[2], _UPPER[2]))
            if at_bound(v, lo_b, hi_b)]
    conditional = bound_conditional(H, lo, hi, tie_break, theta_stop, d, best.x, stderr, at_b)
    return FitResult(
        kind=kind, equation=equation, params=params, stderr=stderr, error=error_eq49(dist),
        n_points=int(n), ok=True,
        message=f"fitted {n} intervals ({n_two} two-sided); curve crosses "
                f"{int(np.sum(dist == 0))}; {boot_msg}",
        stderr_method="bootstrap",
        error_measure="Eq. (49) of the horizontal (theta) distances to the intervals, degrees",
        valid_range={"theta": (float(finite.min()), float(finite.max())),
                     "h": (float(H.min()), float(H.max()))},
        coords={k: v for k, v in coords.items() if v is not None},
        extra={"max_distance": float(dist.max()), "n_two_sided": n_two, "tie_break": tie_break,
               "at_bound": at_b, "bound_conditional": conditional, "base_scatter": scatter,
               "bootstrap": boot_info, "bootstrap_refits": int(len(boot)),
               **({"base_sigma_between": float(sigma_b)} if scatter else {}),
               "intervals": {"H": H.tolist(), "lo": lo.tolist(), "hi": hi.tolist(),
                             "replicate": rep.tolist(), "base": base.tolist()}},
        ensemble=tuple(tuple(map(float, row)) for row in boot),
    )


def _heldout(result: FitResult, theta_stop, tie_break, d) -> FitResult:
    """Leave-one-out z-scores of the two-sided brackets: each bracket is left out, the curve is
    refitted to the others and its theta_stop(H) compared with the bracket's midpoint, with the
    bracket's own uncertainty (uniform: width / sqrt 12), the curve's (bootstrap ensemble of
    the full fit at that H) and the scatter of the arrest angle itself (tau, as for the other
    closures, :mod:`granflow.fitting.identify`: estimated without bracket i from the other
    brackets' residuals about the refitted curve, tau^2 = max(0, (sum r_j^2 - sum w_j^2/12) /
    (n - 1 - 3)); one arrest scatters between insertion seeds by about a 0.25 deg bracket's
    width, which replicate chains show and a bracket's width does not):
    z = (theta_pred - mid) / sqrt(var_pred + width^2 / 12 + tau^2)."""
    from .identify import apply_heldout

    iv = result.extra.get("intervals")
    if result.status == "failed" or not iv:
        return result
    H, lo, hi = (np.asarray(iv[k], dtype=float) for k in ("H", "lo", "hi"))
    rep = np.asarray(iv.get("replicate") or np.zeros(H.size), dtype=int)
    two = np.isfinite(lo) & np.isfinite(hi)
    ens = result.ensemble_array()
    z = {}
    for i in np.nonzero(two)[0]:
        keep = np.ones(H.size, bool)
        keep[i] = False
        key = f"H={H[i]:g}" + (f" seed~{rep[i]}" if rep[i] else "")
        if int((two & keep).sum()) < 3:
            z[key] = math.nan
            continue
        p0 = [result.params["delta1"], result.params["delta2"] - result.params["delta1"],
              result.params["A"]]
        sol = _solve(H[keep], lo[keep], hi[keep], tie_break, theta_stop, d, [np.array(p0)])
        if sol is None or not sol.success:
            z[key] = math.nan
            continue
        pred = float(theta_stop(H[i], sol.x[0], sol.x[0] + sol.x[1], sol.x[2], d))
        others = two & keep
        mids = 0.5 * (lo[others] + hi[others])
        res = theta_stop(H[others], sol.x[0], sol.x[0] + sol.x[1], sol.x[2], d) - mids
        dof = int(others.sum()) - len(HSTOP_PARAMS)
        tau2 = (max(0.0, float(np.sum(res ** 2) - np.sum((hi[others] - lo[others]) ** 2) / 12.0))
                / dof if dof > 0 else 0.0)
        var = tau2
        if len(ens) >= 10:
            th = np.array([theta_stop(H[i], e[0], e[1], e[2], d) for e in ens])
            var += float(np.nanvar(th, ddof=1))
        mid, w = 0.5 * (lo[i] + hi[i]), hi[i] - lo[i]
        z[key] = float((pred - mid) / math.sqrt(var + w * w / 12.0)) if var + w * w > 0 else math.nan
    return apply_heldout(result, z)


def fit_hstop(intervals=None, *, runs=None, lam=None, contact_law=None, n_bootstrap: int = 200,
              seed: int = 0, tie_break: float = 1e-3, d: float = 1.0,
              min_intervals: int = 4) -> FitResult:
    """Fit Eq. (45) hstop(theta; lambda) to arrested/flowing brackets (see module docstring).

    Parameters
    ----------
    intervals : DataFrame with columns H, theta_arrested_max, theta_flowing_min (one-sided
        intervals use -inf/+inf or NaN), or None when ``runs`` is given.
    runs : DataFrame with columns theta, H, state (e.g. a campaign table filtered to one lambda);
        intervals are derived with :func:`hstop_intervals_from_runs`. The heights used are the
        ``H`` column (filling heights, as in the paper's search).
    Returns a FitResult with params delta1, delta2 (degrees), A (in d), bootstrap stderr.
    """
    from .identify import assess

    res = _fit_hstop("eq45", intervals, runs, lam, contact_law, n_bootstrap, seed, tie_break, d,
                     min_intervals)
    return _heldout(assess(res), theta_stop_eq45, tie_break, d)


def fit_hstop_eq38(intervals=None, *, runs=None, lam=None, contact_law=None,
                   n_bootstrap: int = 200, seed: int = 0, tie_break: float = 1e-3,
                   d: float = 1.0, min_intervals: int = 4) -> FitResult:
    """Fit the exponential form Eq. (38) to the same brackets, for comparison with Eq. (45)."""
    from .identify import assess

    res = _fit_hstop("eq38", intervals, runs, lam, contact_law, n_bootstrap, seed, tie_break, d,
                     min_intervals)
    return _heldout(assess(res), theta_stop_eq38, tie_break, d)


def compare_hstop_forms(intervals=None, *, runs=None, **kwargs) -> pd.DataFrame:
    """Fit Eq. (45) and Eq. (38) to the same brackets; one row per form with params and error."""
    rows = []
    for name, fn in (("eq45", fit_hstop), ("eq38", fit_hstop_eq38)):
        r = fn(intervals, runs=runs, **kwargs)
        row = {"form": name, "equation": r.equation, "ok": r.ok, "error": r.error,
               "n_points": r.n_points}
        row.update(r.params)
        row.update({f"{k}_stderr": v for k, v in r.stderr.items()})
        rows.append(row)
    return pd.DataFrame(rows)
