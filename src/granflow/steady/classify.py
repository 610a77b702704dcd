"""Flow-state classification of a chute-flow run (Weinhart et al. 2012 §6 and §8).

The paper classifies each run from the energy ratio E_kin/<E_ela> (kinetic energy over the
time-averaged elastic energy, §6, Fig. 3) and, for smooth bases (§8, Fig. 10), from the density
profile:

* **arrested** -- the ratio falls below 1e-5 (§6, the rule of the hstop search), or the mean
  velocity has stopped while a few loose grains keep rocking (rules 1b, 1c below);
* **steady** -- the ratio becomes time independent (§6: "constant within t in [1800, 2000]");
* **accelerating** -- the ratio keeps increasing (§6, theta >= 30 deg for lambda = 1);
* **oscillating** -- stop-and-go flow with "large oscillations in the ratio" due to spontaneous
  ordering and disordering (§8, Fig. 10 lower right);
* **layered** -- steady flow "strongly layered throughout the flow", ordered in x-y planes, i.e.
  a strong density oscillation in z with a period of about one diameter (§8, Fig. 10 lower left);
* **undecided** -- none of the above can be asserted yet (still relaxing, decelerating, too
  little data).

The paper's "constant" and "keeps increasing" are judged by eye; here they are statistical tests
(:mod:`granflow.steady.timeseries`): the steady onset t0 is pymbar's maximum-effective-sample-size
equilibration time, and trends are OLS slopes whose standard errors account for serial correlation.
Every threshold is a named module constant below, with its reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .timeseries import (
    DEFAULT_EQUILIBRATION_ORIGINS,
    TrendResult,
    curvature_test,
    detect_equilibration,
    trend_test,
)

__all__ = [
    "STATES",
    "FLOWING_STATES",
    "ARREST_RATIO",
    "ARREST_HOLD_TIME",
    "ARREST_VELOCITY",
    "ARREST_RATIO_RATTLERS",
    "ARREST_HOLD_RATTLERS",
    "ALPHA_TREND",
    "MIN_RELATIVE_CHANGE",
    "TREND_WINDOW_FRACTION",
    "LONG_WINDOW_FRACTION",
    "MIN_TREND_SAMPLES",
    "TAIL_VETO_P",
    "EQUIVALENCE_MARGIN",
    "MIN_STEADY_NEFF",
    "NEFF_FULL_CONFIDENCE",
    "P_NO_TREND",
    "OSC_DROP_DECADES",
    "OSC_RECOVER_DECADES",
    "OSC_LEVEL_QUANTILE",
    "MIN_OSCILLATION_CYCLES",
    "LAYERING_THRESHOLD",
    "LAYER_PERIOD_RANGE",
    "BULK_OFFSET_BASE",
    "BULK_OFFSET_SURFACE",
    "FlowClassification",
    "classify_flow",
    "oscillation_cycles",
    "layering_amplitude",
    "layered_state",
    "paper_arrest_time",
]

STATES = ("arrested", "steady", "accelerating", "layered", "oscillating", "undecided")
#: States in which the material flows (everything the hstop search calls "flowing").
FLOWING_STATES = ("steady", "accelerating", "layered", "oscillating")

# --- arrested ------------------------------------------------------------------------------
#: Paper §6: a flow is arrested when E_kin/<E_ela> falls below 1e-5.
ARREST_RATIO = 1e-5
#: The ratio must stay below ARREST_RATIO over the last ARREST_HOLD_TIME time units (at least one
#: sample).  Arrested piles keep losing energy (§6: "a further decrease of kinetic energy was
#: observed"), whereas a stop-and-go flow recovers; 5 time units = 1000 collision times is
#: negligible against the 500-unit arrest horizon yet ignores single-sample dips.
ARREST_HOLD_TIME = 5.0

#: Rattler-tolerant arrest: a pile in which the depth-mean velocity stays below
#: ARREST_VELOCITY (sqrt(g d)) and the ratio below ARREST_RATIO_RATTLERS over the last
#: ARREST_HOLD_RATTLERS time units is arrested too.  Without rolling resistance a single surface
#: grain can rock in its pocket for ever (pure rolling dissipates nothing): at theta = 16 deg,
#: t_c = 0.01 one such grain kept E_kin/<E_ela> oscillating between 2e-6 and 5.5e-4 with a period
#: of 13.5 for t > 40 while the mean velocity was 1e-6, i.e. the pile had stopped.  A flowing layer
#: near hstop moves at u_bar >~ 0.05, fifty times ARREST_VELOCITY.
ARREST_VELOCITY = 1e-3
#: ... with the ratio at most this (two decades above the paper's threshold; flowing 1e-1 ... 10).
ARREST_RATIO_RATTLERS = 1e-3
#: ... over this long (four times ARREST_HOLD_TIME: the rule is looser, so it must hold longer).
ARREST_HOLD_RATTLERS = 20.0

#: Rocking-tolerant arrest, the looser form: the depth-mean velocity below ARREST_VELOCITY over
#: the last ARREST_HOLD_ROCKING time units, with the ratio below ARREST_RATIO_ROCKING.  With the
#: paper's species (t_c = 0.005, stiffer, so less elastic energy per load) one loose grain in an
#: arrested H = 16 layer at 20.58 deg kept E_kin/<E_ela> swinging between 8e-4 and 5.5e-2 (a
#: regular cycle) from t = 100 to the cap t = 2000 while |u_bar| <= 2e-5: the "stop-and-go"
#: rule counted 68 cycles and called it oscillating, i.e. flowing, and the H = 16 bracket came out
#: 20.33-20.58 deg, below the H = 24 one (20.50-20.75) -- an inverted hstop (reference run of
#: 2026-11-26).  A stop-and-go flow flows in its "go" phases (u_bar ~ 0.05 ... 1); 100 time units
#: (20 000 collision times) without any mean motion is an arrest.
ARREST_HOLD_ROCKING = 100.0
#: ... with the ratio at most this (flowing layers near hstop: 10 ... 100; one decade margin
#: below the 1e-1 ... 10 of a slow flow).
ARREST_RATIO_ROCKING = 1.0

# --- trends ----------------------------------------------------------------------------------
#: Significance level of every trend test.  The monitor re-tests every check interval, so a
#: stricter level than 5 % keeps repeated-testing false alarms rare.
ALPHA_TREND = 0.01
#: Practical-relevance margin: a significant trend only counts when the fitted change of the ratio
#: over the tested window exceeds 5 % of its mean (E_kin ~ u^2, i.e. ~2.5 % in velocity -- well
#: below the ~12 % scatter of the flow-rule fit, Table 1 err(F)).  Without it a very long tail
#: would eventually make any negligible drift (slow compaction) "significant".
MIN_RELATIVE_CHANGE = 0.05
#: Default length of the recent window whose trend decides "accelerating"/"constant": the paper
#: judges constancy over the last 10 % of the run (t in [1800, 2000] of [0, 2000]).
TREND_WINDOW_FRACTION = 0.1
#: The accelerating check also tests the last half of the run: the max-N_eff onset of a steadily
#: rising series is pushed late (a short tail always looks flat), and "keeps increasing" (§6) is a
#: statement about the run, not about its last 10 %.  A spin-up that ends in a plateau inside this
#: window is not flagged because its quadratic coefficient is significantly negative.
LONG_WINDOW_FRACTION = 0.5
#: "Keeps increasing" is a statement about the whole stationary-looking tail: when the tail after
#: the onset t0 contains a tested window and itself shows no rise (one-sided p > 0.05), a rise
#: inside that window is a slow fluctuation, not acceleration.  Seen at theta = 24, H = 10 in a
#: 10 x 5 box (500 grains): the ratio fluctuates by +-25 % over ~100 time units, and its last half
#: "rose" by 41 % (p = 0.003) while the 410-unit tail had slope -8 %.
TAIL_VETO_P = 0.05
#: Fewest samples a trend window may have (it is widened to this many if needed).
MIN_TREND_SAMPLES = 20

# --- steady ---------------------------------------------------------------------------------
#: Equivalence margin (TOST): a steady tail must be *shown* to be flat, not merely not shown to
#: trend -- the (1 - 2 alpha) confidence interval of the relative change of the ratio, by the
#: tail's fitted linear trend, over one trend window (the averaging time; the whole tail if
#: shorter) must lie inside +-20 %.  This is the power guard for short, noisy tails (a ramp hidden
#: in noise must not pass as steady).  On the paper's log-scale Fig. 3 (1e-6 ... 10) a 20 % change
#: is invisible, so the rule is stricter than the paper's by-eye "constant".  (Over the whole tail
#: instead, a 500-grain box whose ratio fluctuates by +-25 % could not be shown flat in 1000 time
#: units: the change over a longer span has a proportionally wider interval.)
EQUIVALENCE_MARGIN = 0.2
#: A steady verdict needs at least this many uncorrelated samples after the onset t0: with fewer
#: the trend test has too little power to mean anything.
MIN_STEADY_NEFF = 10.0
#: Steady confidence reaches 1 (on the sample-size factor) at this many uncorrelated samples:
#: the mean is then known to ~1/sqrt(50) = 14 % of one standard deviation.
NEFF_FULL_CONFIDENCE = 50.0
#: Steady confidence reaches 1 (on the trend factor) when the smallest trend p-value is above
#: this: no hint of a trend at all.
P_NO_TREND = 0.2

# --- oscillating (stop-and-go) ----------------------------------------------------------------
#: A "stop" is a drop of log10(ratio) by at least this many decades below the flowing level
#: (a factor 10: steady-flow fluctuations of the ratio are tens of percent, ~0.1 decade).
OSC_DROP_DECADES = 1.0
#: ... and the "go" is a recovery to within this many decades of the flowing level (hysteresis
#: half a decade wide, so that noise around one threshold is not counted as cycles).
OSC_RECOVER_DECADES = 0.5
#: The flowing level is this quantile of log10(ratio) (robust to the stops themselves).
OSC_LEVEL_QUANTILE = 0.9
#: Complete stop-and-go cycles needed to call a flow oscillating.  One dip-and-recover can be the
#: initial compaction followed by spin-up; repeated ones cannot.
MIN_OSCILLATION_CYCLES = 2

# --- layered ----------------------------------------------------------------------------------
#: Normalised amplitude (first-harmonic amplitude / mean density in the bulk) above which a flow is
#: layered.  A perfectly ordered stack of planes, coarse-grained with the paper's Gaussian
#: w = 0.25 (§7), has a first-harmonic amplitude 2 exp(-(2 pi w)^2/2) = 0.58 of the mean; a
#: disordered bulk, averaged over x, y and time, has a few percent at most.  0.1 sits a factor ~6
#: below perfect order and well above disordered noise.
LAYERING_THRESHOLD = 0.1
#: Periods (in d) scanned for the layering oscillation: close-packed planes are sqrt(2/3) = 0.82 d
#: apart, square-stacked ones 1 d.
LAYER_PERIOD_RANGE = (0.75, 1.25)
#: The bulk where layering is measured is [b + 2, s - 4], the paper's bulk-density region (Eq. 51):
#: it excludes the base layering that every rough base imposes and the dilute surface.
BULK_OFFSET_BASE = 2.0
BULK_OFFSET_SURFACE = 4.0

_MIN_SAMPLES = 10


@dataclass
class FlowClassification:
    """Outcome of :func:`classify_flow`.

    state: one of :data:`STATES`; onset: start time of the steady window (the detected
    equilibration time t0) for "steady"/"layered", else None; confidence: in [0, 1];
    statistics: the numbers the decision used (plain floats/ints/bools); reason: short text.
    """

    state: str
    onset: float | None
    confidence: float
    statistics: dict = field(default_factory=dict)
    reason: str = ""

    @property
    def flowing(self) -> bool:
        """True for every state except arrested and undecided."""
        return self.state in FLOWING_STATES

    @property
    def layered(self) -> bool:
        return bool(self.statistics.get("layered", False))

    def explain(self) -> str:
        """One-line human-readable summary for logs."""
        parts = [f"flow state {self.state} (confidence {self.confidence:.2f})"]
        if self.onset is not None:
            parts.append(f"steady since t={self.onset:.6g}")
        if self.reason:
            parts.append(self.reason)
        s = self.statistics
        if "ratio_last" in s:
            parts.append(f"E_kin/<E_ela>={s['ratio_last']:.3g}")
        if "window_p_increase" in s and not math.isnan(s.get("window_slope", math.nan)):
            parts.append(f"window slope={s['window_slope']:.3g}/t (p_up={s['window_p_increase']:.2g})")
        if "tail_n_eff" in s:
            parts.append(f"tail N_eff={s['tail_n_eff']:.1f}, p={s.get('tail_p_value', math.nan):.2g}")
        if "layering_amplitude" in s and not math.isnan(s["layering_amplitude"]):
            parts.append(f"layering={s['layering_amplitude']:.3f}")
        return "; ".join(parts)


def paper_arrest_time(time, energy_ratio, *, threshold: float = ARREST_RATIO,
                      after: float = 10.0, horizon: float = 500.0,
                      every: float = 1.0) -> float | None:
    """The paper's literal arrest test (§6; MercuryDPM's hstop driver of that paper): the run
    is arrested at the first sample time t = k ``every`` (k integer), ``after`` < t <=
    ``horizon``, at which E_kin/E_ela < ``threshold``; None if there is none (flowing).

    An independent check of :func:`classify_flow`'s arrest rules (a hold time, rattler and
    rocking rules) on a run's stored series (``series.nc``: ``t``, ``energy_ratio``).  That
    ratio counts the rotational kinetic energy too, where the driver counts translation only,
    so a run arrested by this test on granflow's series is arrested by the driver's as well.
    """
    t = np.asarray(time, dtype=float)
    r = np.asarray(energy_ratio, dtype=float)
    if t.shape != r.shape or t.ndim != 1:
        raise ValueError("time and energy_ratio must be 1-D arrays of the same length")
    if not (every > 0 and math.isfinite(every)):
        raise ValueError(f"every = {every!r} is out of range: allowed (0, inf)")
    k = np.round(t / every)
    on_grid = np.abs(t - k * every) <= 1e-9 * np.maximum(1.0, np.abs(t))
    hit = on_grid & (t > after) & (t <= horizon) & (r < threshold)
    return float(t[hit][0]) if hit.any() else None


def oscillation_cycles(
    ratio, *, drop_decades: float = OSC_DROP_DECADES, recover_decades: float = OSC_RECOVER_DECADES,
    level_quantile: float = OSC_LEVEL_QUANTILE,
) -> dict:
    """Count complete stop-and-go cycles of an energy-ratio series.

    With L = log10(ratio) and the flowing level L_hi = quantile(L, ``level_quantile``), a Schmitt
    trigger is "low" once L < L_hi - drop_decades and "high" again once L > L_hi - recover_decades.
    A cycle is high -> low -> high: a series that starts low (from rest) and rises is no cycle.
    Returns dict(cycles, stops, level, min_decades) where
    min_decades is the deepest drop below the level.
    """
    r = np.asarray(ratio, dtype=float)
    r = r[~np.isnan(r)]
    if r.size == 0:
        return {"cycles": 0, "stops": 0, "level": math.nan, "min_decades": 0.0}
    with np.errstate(divide="ignore"):
        logr = np.log10(np.clip(r, 1e-300, None))
    finite = logr[np.isfinite(logr)]
    if finite.size == 0:
        return {"cycles": 0, "stops": 0, "level": math.nan, "min_decades": 0.0}
    level = float(np.quantile(finite, level_quantile))
    lo, hi = level - drop_decades, level - recover_decades
    state = None
    stops = cycles = 0
    for v in logr:
        if v > hi:
            if state == "low" and stops:  # a stop after flowing, then flowing again
                cycles += 1
            state = "high"
        elif v < lo:
            if state == "high":
                stops += 1
            state = "low"
    return {"cycles": int(cycles), "stops": int(stops), "level": level,
            "min_decades": float(level - np.min(logr))}


def _bulk_range(z, rho):
    dense = rho[rho > 0.1 * np.max(rho)]
    if dense.size == 0:
        return None
    occupied = np.nonzero(rho > 0.5 * np.median(dense))[0]
    b, s = float(z[occupied[0]]), float(z[occupied[-1]])
    lo, hi = b + BULK_OFFSET_BASE, s - BULK_OFFSET_SURFACE
    if hi - lo < 3 * LAYER_PERIOD_RANGE[1]:
        lo, hi = b + 1.0, s - 1.0
    return lo, hi


def layering_amplitude(z, density, *, bulk: tuple[float, float] | None = None,
                       periods=None) -> dict:
    """Normalised amplitude of the z-layering of a density profile in the bulk.

    In the bulk [lo, hi] (default [b + 2, s - 4], Eq. 51, with b and s the first and last z where
    the density exceeds half its dense level) fits rho = c0 + c1 (z - zc) + a cos(2 pi z/p) +
    b sin(2 pi z/p) by least squares for each trial period p in ``periods`` (default 51 values in
    :data:`LAYER_PERIOD_RANGE`) and returns dict(amplitude = max_p sqrt(a^2+b^2)/c0, period,
    bulk_lo, bulk_hi).  The amplitude is scale free (density or volume fraction alike).
    """
    z = np.asarray(z, dtype=float)
    rho = np.asarray(density, dtype=float)
    if z.shape != rho.shape or z.ndim != 1:
        raise ValueError("z and density must be 1-D arrays of the same length")
    nan = {"amplitude": math.nan, "period": math.nan, "bulk_lo": math.nan, "bulk_hi": math.nan}
    ok = np.isfinite(z) & np.isfinite(rho)
    z, rho = z[ok], rho[ok]
    if z.size < 8 or np.max(rho) <= 0:
        return nan
    order = np.argsort(z)
    z, rho = z[order], rho[order]
    rng = bulk if bulk is not None else _bulk_range(z, rho)
    if rng is None:
        return nan
    lo, hi = rng
    sel = (z >= lo) & (z <= hi)
    if np.count_nonzero(sel) < 8 or hi - lo < 2 * LAYER_PERIOD_RANGE[0]:
        return {**nan, "bulk_lo": float(lo), "bulk_hi": float(hi)}
    zs, rs = z[sel], rho[sel]
    zc = 0.5 * (lo + hi)
    if periods is None:
        periods = np.linspace(LAYER_PERIOD_RANGE[0], LAYER_PERIOD_RANGE[1], 51)
    best_amp, best_p = -1.0, math.nan
    for p in np.asarray(periods, dtype=float):
        k = 2.0 * np.pi / p
        design = np.column_stack([np.ones_like(zs), zs - zc, np.cos(k * zs), np.sin(k * zs)])
        coef, *_ = np.linalg.lstsq(design, rs, rcond=None)
        if coef[0] <= 0:
            continue
        amp = math.hypot(coef[2], coef[3]) / coef[0]
        if amp > best_amp:
            best_amp, best_p = amp, float(p)
    if best_amp < 0:
        return {**nan, "bulk_lo": float(lo), "bulk_hi": float(hi)}
    return {"amplitude": float(best_amp), "period": best_p, "bulk_lo": float(lo), "bulk_hi": float(hi)}


def layered_state(state: str, z, density) -> tuple[str, float, str]:
    """A steady run whose time-averaged bulk density profile is layered in z (first-harmonic
    amplitude above :data:`LAYERING_THRESHOLD`, :func:`layering_amplitude`) is ``layered``
    (paper §8: the lambda = 1/2 flows "strongly layered throughout the flow"; Eq. 47 and the
    shape factor are fitted to disordered flows only).  Returns (state, amplitude, note to
    append to the explanation).  Other states, and profiles too thin for a bulk, are unchanged.

    The energy-ratio classification cannot see this (a layered flow is as steady as a disordered
    one); measured on the lambda = 1/2 reference (2026-11-26): H = 10 at 23, 26, 27, 28 deg
    amplitudes 0.333, 0.140, 0.108, 0.065 (Froude numbers +188, +42, +30, +16 % above Eq. 47),
    H = 20 and 30 at 26-27 deg 0.03-0.04; the lambda = 1 reference's steady runs at most 0.021."""
    amp = float(layering_amplitude(z, density)["amplitude"])
    if state == "steady" and math.isfinite(amp) and amp > LAYERING_THRESHOLD:
        return "layered", amp, (f"; layered in z: bulk density first-harmonic amplitude "
                                f"{amp:.3f} > {LAYERING_THRESHOLD:g}")
    return state, amp, ""


def _trend_ok(res: TrendResult) -> bool:
    return res.n >= 5 and math.isfinite(res.coefficient)


def _relevant(res: TrendResult, min_rel: float) -> bool:
    rel = res.relative_change
    return not math.isfinite(rel) or abs(rel) >= min_rel


def _equivalent(res: TrendResult, alpha: float, margin: float, horizon: float | None = None) -> bool:
    """TOST: the (1 - 2 alpha) CI of the relative change over ``horizon`` (default: the span; never
    more than the span) of the fitted linear trend lies within +-margin."""
    if not (_trend_ok(res) and math.isfinite(res.relative_change) and res.mean != 0):
        return False
    length = res.span if horizon is None else min(float(horizon), res.span)
    se_rel = res.stderr * length / abs(res.mean)
    change = res.coefficient * length / abs(res.mean)
    half = float(stats.t.ppf(1.0 - alpha, res.dof)) * se_rel
    return abs(change) + half <= margin


def _rising(window_res: TrendResult, curv: TrendResult, alpha: float, min_rel: float) -> bool:
    """Significant, relevant increase that is not levelling off (keeps increasing)."""
    if not _trend_ok(window_res):
        return False
    if not (window_res.p_increase < alpha and _relevant(window_res, min_rel)):
        return False
    levelling = _trend_ok(curv) and curv.p_decrease < alpha
    return not levelling


def classify_flow(
    time, energy_ratio, u_bar=None, density_profile=None, z=None, *,
    trend_window: float | None = None,
    alpha: float = ALPHA_TREND,
    min_relative_change: float = MIN_RELATIVE_CHANGE,
    arrest_ratio: float = ARREST_RATIO,
    arrest_hold: float = ARREST_HOLD_TIME,
    min_steady_neff: float = MIN_STEADY_NEFF,
    equivalence_margin: float = EQUIVALENCE_MARGIN,
    min_oscillation_cycles: int = MIN_OSCILLATION_CYCLES,
    layering_threshold: float = LAYERING_THRESHOLD,
    bulk: tuple[float, float] | None = None,
    n_origins: int = DEFAULT_EQUILIBRATION_ORIGINS,
    min_onset: float = -math.inf,
) -> FlowClassification:
    """Classify a run from its energy-ratio time series (and optionally u_bar and rho(z)).

    Parameters: ``time`` and ``energy_ratio`` (E_kin/<E_ela>) sampled at increasing times; ``u_bar``
    the depth-averaged velocity at the same times (optional; tested like the ratio);
    ``density_profile`` and ``z`` a time-averaged density (or volume-fraction) depth profile
    (optional; layering).  ``trend_window``: length in time units of the recent window tested for a
    trend (default :data:`TREND_WINDOW_FRACTION` of the span, at least :data:`MIN_TREND_SAMPLES`).

    Decision order (first match wins):

    1. arrested: the ratio has been above ``arrest_ratio`` and is below it over the last
       ``arrest_hold`` time units (paper §6); or (u_bar given) the mean velocity is below
       :data:`ARREST_VELOCITY` and the ratio below :data:`ARREST_RATIO_RATTLERS` over the last
       :data:`ARREST_HOLD_RATTLERS` (a few rocking grains keep the ratio above 1e-5); or
       (u_bar given) the mean velocity is below :data:`ARREST_VELOCITY` over the last
       :data:`ARREST_HOLD_ROCKING` with the ratio below :data:`ARREST_RATIO_ROCKING` (loose
       grains swing the ratio by decades, but the mean flow never restarts);
    2. oscillating: at least ``min_oscillation_cycles`` complete stop-and-go cycles
       (:func:`oscillation_cycles`);
    3. accelerating: over the recent window, the tail after t0 or the last half of the run
       (:data:`LONG_WINDOW_FRACTION`), the ratio (or u_bar) has a
       significant (one-sided p < alpha) and relevant (>= ``min_relative_change`` of its mean)
       positive slope that is not levelling off (quadratic coefficient not significantly negative);
       a recent or long window that lies inside the tail is ignored when the tail itself shows
       no rise (:data:`TAIL_VETO_P`);
    4. steady: t0 = detect_equilibration(ratio) (max of the ratio's and u_bar's, searched from
       ``min_onset`` on: the start-up transient of the run, see the monitor; the tail keeps at
       least the recent window), the tail after
       t0 has >= ``min_steady_neff`` uncorrelated samples, no significant-and-relevant trend, and
       its trend is shown (TOST) to change the ratio by less than ``equivalence_margin`` per
       recent window (the recent window, inside the tail, is not tested on its own: with slow
       fluctuations of a small box a 100-unit window "trends" far too often); onset = time[t0];
    5. otherwise undecided (relaxing, decelerating, or too little data).

    Layered (density given): a flowing, non-accelerating, non-oscillating run whose
    :func:`layering_amplitude` exceeds ``layering_threshold`` is "layered" (onset kept if steady).
    """
    t = np.asarray(time, dtype=float)
    r = np.asarray(energy_ratio, dtype=float)
    if t.shape != r.shape or t.ndim != 1:
        raise ValueError("time and energy_ratio must be 1-D arrays of the same length")
    u = None if u_bar is None else np.asarray(u_bar, dtype=float)
    if u is not None and u.shape != t.shape:
        raise ValueError("u_bar must have the same length as time")
    keep = ~np.isnan(r) & np.isfinite(t)
    t, r = t[keep], r[keep]
    if u is not None:
        u = u[keep]
    stats_: dict = {"n_samples": int(t.size)}

    layer = {"amplitude": math.nan}
    if density_profile is not None:
        if z is None:
            raise ValueError("density_profile needs z")
        layer = layering_amplitude(z, density_profile, bulk=bulk)
        stats_.update({"layering_amplitude": layer["amplitude"],
                       "layering_period": layer.get("period", math.nan),
                       "layering_bulk_lo": layer.get("bulk_lo", math.nan),
                       "layering_bulk_hi": layer.get("bulk_hi", math.nan)})
    is_layered = bool(math.isfinite(layer["amplitude"]) and layer["amplitude"] > layering_threshold)
    stats_["layered"] = is_layered

    if t.size < _MIN_SAMPLES:
        return FlowClassification("undecided", None, 0.0, stats_, "too few samples")
    stats_["ratio_last"] = float(r[-1])
    stats_["t_last"] = float(t[-1])

    # 1. arrested (paper §6: ratio falls below 1e-5)
    hold = t >= t[-1] - arrest_hold
    hold[-1] = True
    below = bool(np.all(r[hold] < arrest_ratio))
    was_above = bool(np.any(r[~hold] >= arrest_ratio)) if np.any(~hold) else False
    stats_["arrest_ratio"] = arrest_ratio
    if below and was_above:
        rmax = float(np.max(r[hold]))
        decades = math.log10(arrest_ratio / rmax) if rmax > 0 else math.inf
        conf = float(min(1.0, 0.5 + 0.5 * decades))
        stats_["arrest_decades_below"] = decades
        return FlowClassification("arrested", None, conf, stats_,
                                  f"ratio below {arrest_ratio:g} over the last {arrest_hold:g} time units")

    # 1b. arrested with rattlers: the mean flow has stopped, a few grains still rock
    if u is not None and t[-1] - t[0] > ARREST_HOLD_RATTLERS:
        hold_r = t >= t[-1] - ARREST_HOLD_RATTLERS
        with np.errstate(invalid="ignore"):
            still = bool(np.all(np.abs(u[hold_r]) < ARREST_VELOCITY)
                         and np.all(r[hold_r] < ARREST_RATIO_RATTLERS))
            moved = bool(np.any(r[~hold_r] >= ARREST_RATIO_RATTLERS))
        if still and moved:
            umax = float(np.nanmax(np.abs(u[hold_r])))
            stats_["arrest_u_max"] = umax
            stats_["arrest_ratio_max"] = float(np.nanmax(r[hold_r]))
            return FlowClassification(
                "arrested", None, 1.0, stats_,
                f"mean velocity |u_bar| <= {umax:.2g} < {ARREST_VELOCITY:g} and ratio < "
                f"{ARREST_RATIO_RATTLERS:g} over the last {ARREST_HOLD_RATTLERS:g} time units "
                f"(rattlers keep the ratio above {arrest_ratio:g})")

    # 1c. arrested, rocking: no mean motion for ARREST_HOLD_ROCKING, loose grains still swing
    #     the ratio by decades (which the stop-and-go rule below would count as cycles)
    if u is not None and t[-1] - t[0] > ARREST_HOLD_ROCKING:
        hold_k = t >= t[-1] - ARREST_HOLD_ROCKING
        with np.errstate(invalid="ignore"):
            still = bool(np.all(np.abs(u[hold_k]) < ARREST_VELOCITY)
                         and np.all(r[hold_k] < ARREST_RATIO_ROCKING))
            moved = bool(np.any(np.abs(u[~hold_k]) >= ARREST_VELOCITY))
        if still and moved:
            umax = float(np.nanmax(np.abs(u[hold_k])))
            rmax = float(np.nanmax(r[hold_k]))
            stats_["arrest_u_max"] = umax
            stats_["arrest_ratio_max"] = rmax
            return FlowClassification(
                "arrested", None, 1.0, stats_,
                f"mean velocity |u_bar| <= {umax:.2g} < {ARREST_VELOCITY:g} over the last "
                f"{ARREST_HOLD_ROCKING:g} time units while loose grains swing the ratio up to "
                f"{rmax:.2g} (< {ARREST_RATIO_ROCKING:g}): no stop-and-go, the mean flow never "
                f"restarts")

    # 2. oscillating (§8: stop-and-go)
    osc = oscillation_cycles(r)
    stats_.update({"oscillation_cycles": osc["cycles"], "oscillation_stops": osc["stops"],
                   "oscillation_depth_decades": osc["min_decades"]})
    if osc["cycles"] >= min_oscillation_cycles:
        conf = float(min(1.0, osc["cycles"] / (2.0 * min_oscillation_cycles)))
        return FlowClassification("oscillating", None, conf, stats_,
                                  f"{osc['cycles']} stop-and-go cycles of >= {OSC_DROP_DECADES:g} decade")

    finite = np.isfinite(r)
    if u is not None:
        finite &= np.isfinite(u)
    t, r = t[finite], r[finite]
    u = u[finite] if u is not None else None
    if t.size < _MIN_SAMPLES:
        return FlowClassification("undecided", None, 0.0, stats_, "too few finite samples")

    # recent trend window
    span = float(t[-1] - t[0])
    w = TREND_WINDOW_FRACTION * span if trend_window is None else float(trend_window)
    iw = int(np.searchsorted(t, t[-1] - w, side="left"))
    iw = min(iw, max(t.size - MIN_TREND_SAMPLES, 0))
    series = {"ratio": r} if u is None else {"ratio": r, "u_bar": u}

    window_res = {k: trend_test(v[iw:], t[iw:]) for k, v in series.items()}
    window_curv = {k: curvature_test(v[iw:], t[iw:]) for k, v in series.items()}
    stats_.update({"window_start": float(t[iw]), **window_res["ratio"].as_dict("window_"),
                   "window_curvature_p_decrease": window_curv["ratio"].p_decrease})
    if u is not None:
        stats_.update({"u_window_slope": window_res["u_bar"].slope,
                       "u_window_p_increase": window_res["u_bar"].p_increase})

    il = int(np.searchsorted(t, t[-1] - LONG_WINDOW_FRACTION * span, side="left"))
    il = min(il, max(t.size - MIN_TREND_SAMPLES, 0))
    long_res = {k: trend_test(v[il:], t[il:]) for k, v in series.items()}
    long_curv = {k: curvature_test(v[il:], t[il:]) for k, v in series.items()}
    stats_.update({"long_window_start": float(t[il]), "long_slope": long_res["ratio"].slope,
                   "long_p_increase": long_res["ratio"].p_increase,
                   "long_curvature_p_decrease": long_curv["ratio"].p_decrease})

    # equilibration (steady onset) and tail tests
    i_min = min(int(np.searchsorted(t, min_onset, side="left")), max(t.size - MIN_TREND_SAMPLES, 0))
    t0 = i_min
    neff = math.inf
    # the tail after t0 covers at least the recent window: a late origin with a few samples always
    # "wins" the effective-sample-size criterion (its correlation time cannot be resolved)
    tail_min = max(int(t.size - iw), MIN_TREND_SAMPLES)
    for k, v in series.items():
        i0, g0, ne = detect_equilibration(v[i_min:], n_origins=n_origins, min_tail=tail_min)
        i0 += i_min
        t0 = max(t0, i0)
        stats_[f"{k}_equilibration_index"] = int(i0)
        stats_[f"{k}_equilibration_g"] = g0
    tail_res = {k: trend_test(v[t0:], t[t0:]) for k, v in series.items()}
    tail_curv = {k: curvature_test(v[t0:], t[t0:]) for k, v in series.items()}
    neff = min(res.n_eff for res in tail_res.values())
    stats_.update({"onset_index": int(t0), "onset_time": float(t[t0]),
                   **tail_res["ratio"].as_dict("tail_"), "tail_n_eff": neff})

    # 3. accelerating
    for k in series:
        tail_flat = tail_res[k].p_increase > TAIL_VETO_P
        for name, res, curv, start in (("window", window_res[k], window_curv[k], iw),
                                       ("tail", tail_res[k], tail_curv[k], t0),
                                       ("long", long_res[k], long_curv[k], il)):
            if name != "tail" and t0 <= start and tail_flat:
                continue  # a rise inside a longer stationary tail is a fluctuation
            if _rising(res, curv, alpha, min_relative_change):
                stats_["accelerating_test"] = f"{k}_{name}"
                return FlowClassification(
                    "accelerating", None, float(1.0 - res.p_increase), stats_,
                    f"{k} rises over the {name} window (rel. change {res.relative_change:+.3g}, "
                    f"p={res.p_increase:.2g})")

    # 4. steady
    trending = []
    pmin = 1.0
    for k in series:
        for name, res in (("window", window_res[k]), ("tail", tail_res[k])):
            if not _trend_ok(res):
                continue
            if name == "window" and t0 <= iw:
                continue  # inside the tail, whose equivalence test bounds the drift per window
            pmin = min(pmin, res.p_value)
            if res.p_value < alpha and _relevant(res, min_relative_change):
                trending.append(f"{k}_{name}")
    not_flat = [k for k in series if not _equivalent(tail_res[k], alpha, equivalence_margin, w)]
    stats_["trending"] = ",".join(trending)
    stats_["tail_not_shown_flat"] = ",".join(not_flat)
    if not trending and not not_flat and neff >= min_steady_neff:
        conf = float(min(1.0, neff / NEFF_FULL_CONFIDENCE) * min(1.0, pmin / P_NO_TREND))
        onset = float(t[t0])
        if is_layered:
            lconf = float(min(1.0, max(0.0, layer["amplitude"] / layering_threshold - 1.0)))
            return FlowClassification("layered", onset, min(conf, lconf), stats_,
                                      "steady and layered in z")
        return FlowClassification("steady", onset, conf, stats_,
                                  "no significant trend after the onset")
    if trending:
        why = "trend in " + ",".join(trending)
    elif not_flat:
        why = f"tail not shown flat within +-{equivalence_margin:g} ({','.join(not_flat)})"
    else:
        why = f"tail N_eff {neff:.1f} < {min_steady_neff:g}"
    if is_layered and r[-1] >= arrest_ratio:
        lconf = float(min(1.0, max(0.0, layer["amplitude"] / layering_threshold - 1.0)))
        return FlowClassification("layered", None, 0.5 * lconf, stats_,
                                  f"layered in z, not yet steady ({why})")
    return FlowClassification("undecided", None, 0.0, stats_, why)
