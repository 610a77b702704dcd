"""Early-stopping monitor for chute-flow runs (Weinhart et al. 2012 §5, §6).

The paper integrates every run to t = 2000 and averages the profiles over the last T = 100 time
units once the energy ratio E_kin/<E_ela> is constant (§5, §6); arrested runs are recognised by the
ratio falling below 1e-5 (§6).  :class:`SteadyStateMonitor` is fed the energies as the simulation
advances and says when the run can stop:

* **arrested** -- the ratio is below 1e-5 for :data:`~granflow.steady.classify.ARREST_HOLD_TIME`
  (checked on every sample bin, O(1));
* **accelerating** -- the classifier says accelerating at t >= ``min_accelerating_time`` with
  confidence >= ``accel_confidence`` and the ratio grew by at least :data:`ACCEL_MIN_GROWTH`
  from the highest level it had up to half the elapsed time (after the start-up window) to
  the last window, or it grew by
  ``accel_growth_factor`` whatever the test says;
* **steady** -- the classifier says steady (or layered) with at least ``averaging_time`` of data
  after the steady onset, at ``steady_confirmations`` consecutive checks (default 2: every check is
  a new chance for a noisy ramp to look flat once); :attr:`SteadyStateMonitor.steady_start` is where the coarse-grained
  profiles must start;
* **flowing** (only with ``stop_when_flowing``, for runs that bracket hstop) -- the run is
  decisively not arresting: the classifier, with a flatness window of ``flowing_window``
  (default 20) instead of the averaging time, finds it steady at ``steady_confirmations``
  consecutive checks, or accelerating with a growth of at least :data:`ACCEL_MIN_GROWTH` after
  the start-up transient.  The paper's binary rule needs nothing more for the demarcation (§6);
* **t_cap** -- the hard cap (paper: 2000).

Samples are block-averaged into bins of ``sample_interval`` (so a caller may feed every time step
at amortised O(1) cost and bounded memory); the classifier runs only every ``check_every`` time
units.  <E_ela> is the mean elastic energy over the last ``ela_window`` time units (the paper uses a
late window, [1000, 2000], and notes any window longer than 100 suffices).  The whole state is
plain numbers/arrays (:meth:`SteadyStateMonitor.state_dict`), so a checkpointed run resumes the
monitor exactly.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np

from .classify import (
    ALPHA_TREND,
    ARREST_HOLD_TIME,
    ARREST_RATIO,
    FlowClassification,
    classify_flow,
)

__all__ = [
    "ACCEL_CONFIDENCE",
    "ACCEL_GROWTH_FACTOR",
    "ACCEL_MIN_GROWTH",
    "MIN_ACCELERATING_FRACTION",
    "MonitorDecision",
    "SteadyStateMonitor",
]

#: Stop as accelerating when the one-sided trend p-value is below 1e-3 (confidence 0.999): the
#: classifier already needs p < ALPHA_TREND; the stricter level guards against stopping on the
#: repeated tests of a long run.
ACCEL_CONFIDENCE = 0.999
#: ... or when the ratio (E_kin ~ u^2) grew tenfold between half the elapsed time and now
#: (velocity x3.2): no spin-up of a steady flow looks like that after ``min_accelerating_time``.
ACCEL_GROWTH_FACTOR = 10.0
#: A significant trend alone is not enough to stop as accelerating: the ratio must also have grown
#: by this factor between half the elapsed time and now (velocity +22 %).  Without it, the slow
#: final spin-up of a thick steady flow in a small (noisy) box was stopped as "accelerating" at
#: t = 110 with growth x1.09 (theta = 24, H = 10, 10 x 5 box).
ACCEL_MIN_GROWTH = 1.5
#: Default ``min_accelerating_time`` = this fraction of ``t_cap`` (500 for the paper's 2000, the
#: paper's arrest horizon): a steady flow's spin-up from rest also "accelerates", and before the
#: plateau is reached the two cannot be told apart.  Raise it for thick flows that spin up slowly.
MIN_ACCELERATING_FRACTION = 0.25

_CONFIG_KEYS = (
    "t_cap", "averaging_time", "check_every", "sample_interval", "ela_window",
    "min_accelerating_time", "accel_confidence", "accel_growth_factor", "stop_on_oscillating",
    "steady_confirmations",
    "alpha", "arrest_ratio", "arrest_hold", "n_origins", "min_onset", "stop_when_flowing",
    "flowing_window",
)


def as_scalar(v):
    """A 0-d array (as ``np.load`` returns saved scalars) as a Python scalar; arrays unchanged."""
    v = np.asarray(v)
    return v.item() if v.ndim == 0 else v


@dataclass(frozen=True)
class MonitorDecision:
    """What :meth:`SteadyStateMonitor.decision` returns.

    stop: whether the run should stop now; reason: "continue", "arrested", "accelerating",
    "steady", "oscillating" or "t_cap"; state: the latest flow state (see
    :mod:`granflow.steady.classify`); t: time of the latest sample bin; steady_start: start of the
    steady window (None unless steady/layered); confidence: of the state; message: one-line log text.
    """

    stop: bool
    reason: str
    state: str
    t: float
    steady_start: float | None
    confidence: float
    message: str

    def explain(self) -> str:
        return self.message


class SteadyStateMonitor:
    """Incremental steady-state / arrest / acceleration detector with early stopping.

    Usage::

        mon = SteadyStateMonitor(t_cap=2000, averaging_time=100)
        while True:
            ...advance the simulation...
            mon.update(t, e_kin, e_ela, u_bar)
            d = mon.decision()
            if d.stop:
                break
        profiles = coarse_grain(snapshots with time >= mon.steady_start)   # if d.reason == "steady"
    """

    def __init__(
        self,
        t_cap: float = 2000.0,
        averaging_time: float = 100.0,
        check_every: float = 10.0,
        sample_interval: float = 1.0,
        ela_window: float | None = None,
        min_accelerating_time: float | None = None,
        accel_confidence: float = ACCEL_CONFIDENCE,
        accel_growth_factor: float = ACCEL_GROWTH_FACTOR,
        stop_on_oscillating: bool = False,
        steady_confirmations: int = 2,
        alpha: float = ALPHA_TREND,
        arrest_ratio: float = ARREST_RATIO,
        arrest_hold: float = ARREST_HOLD_TIME,
        n_origins: int = 100,
        min_onset: float = 0.0,
        stop_when_flowing: bool = False,
        flowing_window: float = 20.0,
    ):
        if averaging_time <= 0 or check_every <= 0 or sample_interval <= 0:
            raise ValueError("averaging_time, check_every and sample_interval must be positive")
        self.t_cap = float(t_cap)
        self.averaging_time = float(averaging_time)
        self.check_every = float(check_every)
        self.sample_interval = float(sample_interval)
        self.ela_window = float(averaging_time if ela_window is None else ela_window)
        self.min_accelerating_time = float(
            MIN_ACCELERATING_FRACTION * t_cap if min_accelerating_time is None else min_accelerating_time)
        self.accel_confidence = float(accel_confidence)
        self.accel_growth_factor = float(accel_growth_factor)
        self.stop_on_oscillating = bool(stop_on_oscillating)
        self.steady_confirmations = max(int(steady_confirmations), 1)
        self.alpha = float(alpha)
        self.arrest_ratio = float(arrest_ratio)
        self.arrest_hold = float(arrest_hold)
        self.n_origins = int(n_origins)
        #: earliest steady onset: the start-up transient (insertion fall, landing) is excluded
        self.min_onset = float(min_onset)
        #: stop as soon as the run is decisively flowing (hstop brackets need no averaging)
        self.stop_when_flowing = bool(stop_when_flowing)
        #: flatness window of the flowing test (shorter than the averaging time)
        self.flowing_window = float(flowing_window)

        self._cap = 256
        self._n = 0
        self._time = np.empty(self._cap)
        self._ekin = np.empty(self._cap)
        self._eela = np.empty(self._cap)
        self._ubar = np.empty(self._cap)
        self._cum_eela = np.zeros(self._cap + 1)  # cumulative sums of binned E_ela
        self._has_u = False
        # current (partial) bin
        self._t_origin = math.nan
        self._bin_index = -1
        self._acc = np.zeros(5)  # sum t, e_kin, e_ela, u_bar, count
        # arrest tracking
        self._above_seen = False
        self._below_since = math.nan
        self._arrested = False
        # checks
        self._next_check = math.nan
        self._decision = MonitorDecision(False, "continue", "undecided", math.nan, None, 0.0,
                                         "no data yet")
        self._classification: FlowClassification | None = None
        self._n_checks = 0
        self._steady_streak = 0
        self._flowing_streak = 0

    # ------------------------------------------------------------------ feeding
    def update(self, t: float, e_kin: float, e_ela: float, u_bar: float | None = None) -> None:
        """Add one sample (time must not decrease).  Amortised O(1) except at check times.

        Samples are averaged into bins of ``sample_interval``; a bin is closed (and the arrest and
        check logic run) when the first sample of a later bin arrives, or at once when t >= t_cap.
        """
        t = float(t)
        if math.isnan(self._t_origin):
            self._t_origin = t
            self._next_check = t + self.check_every
        if self._n and t < self._time[self._n - 1]:
            raise ValueError("time must be non-decreasing")
        k = int(math.floor((t - self._t_origin) / self.sample_interval))
        if k != self._bin_index and self._acc[4] > 0:
            self._flush()
        self._bin_index = k
        self._acc += (t, float(e_kin), float(e_ela), 0.0 if u_bar is None else float(u_bar), 1.0)
        if u_bar is not None:
            self._has_u = True
        if t >= self.t_cap:  # close the bin now so that the cap decision is not deferred
            self._flush()

    def flush(self) -> MonitorDecision:
        """Close the partial sample bin (e.g. at the end of a run or before a final decision)."""
        if self._acc[4] > 0:
            self._flush()
        return self._decision

    def _flush(self) -> None:
        st, sk, se, su, c = self._acc
        self._acc[:] = 0.0
        if self._n == self._cap:
            self._grow()
        i = self._n
        tb = st / c
        self._time[i], self._ekin[i], self._eela[i], self._ubar[i] = tb, sk / c, se / c, su / c
        self._cum_eela[i + 1] = self._cum_eela[i] + se / c
        self._n = i + 1
        self._after_bin(tb)

    def _grow(self) -> None:
        self._cap *= 2
        for name in ("_time", "_ekin", "_eela", "_ubar"):
            old = getattr(self, name)
            new = np.empty(self._cap)
            new[: old.size] = old
            setattr(self, name, new)
        cum = np.zeros(self._cap + 1)
        cum[: self._cum_eela.size] = self._cum_eela
        self._cum_eela = cum

    def _norm(self, t_end: float) -> float:
        """Mean binned E_ela over the last ela_window time units before t_end."""
        n = self._n
        j0 = int(np.searchsorted(self._time[:n], t_end - self.ela_window, side="left"))
        j0 = min(j0, n - 1)
        return (self._cum_eela[n] - self._cum_eela[j0]) / (n - j0)

    def _after_bin(self, tb: float) -> None:
        if self._decision.stop:
            return
        # O(1) arrest test on the newest bin
        norm = self._norm(tb)
        ek = self._ekin[self._n - 1]
        ratio = ek / norm if norm > 0 else math.inf
        if ratio >= self.arrest_ratio:
            self._above_seen = True
            self._below_since = math.nan
        elif self._above_seen:
            if math.isnan(self._below_since):
                self._below_since = tb
            if tb - self._below_since >= self.arrest_hold:
                self._arrested = True
                self._set_decision(True, "arrested", "arrested", tb, None, 1.0,
                                   f"t={tb:.6g}: stop, arrested: E_kin/<E_ela>={ratio:.3g} < "
                                   f"{self.arrest_ratio:g} since t={self._below_since:.6g}")
                return
        if tb >= self._next_check or tb >= self.t_cap:
            while self._next_check <= tb:
                self._next_check += self.check_every
            self._check(tb)

    # ------------------------------------------------------------------ evaluation
    def series(self) -> dict:
        """Binned series so far: time, e_kin, e_ela, u_bar (None if never given), ratio."""
        n = self._n
        t = self._time[:n].copy()
        norm = self._norm(t[-1]) if n else math.nan
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = self._ekin[:n] / norm if norm > 0 else np.full(n, np.inf)
        return {"time": t, "e_kin": self._ekin[:n].copy(), "e_ela": self._eela[:n].copy(),
                "u_bar": self._ubar[:n].copy() if self._has_u else None, "ratio": ratio}

    def classify(self) -> FlowClassification:
        """Run the classifier on the binned series now (does not change the decision)."""
        s = self.series()
        return classify_flow(
            s["time"], s["ratio"], s["u_bar"], trend_window=self.averaging_time, alpha=self.alpha,
            arrest_ratio=self.arrest_ratio, arrest_hold=self.arrest_hold, n_origins=self.n_origins,
            min_onset=self.min_onset)

    def _growth(self, ratio: np.ndarray, t: np.ndarray) -> float:
        """Growth of the ratio: median of the last ``averaging_time`` window over the highest
        earlier level, the largest window median (windows of ``averaging_time``, centres every
        half window, after the first window's start-up) up to half the elapsed time.

        For a flow that keeps accelerating the highest earlier level is the one at half the
        elapsed time.  A steady flow that wanders (a small box's slow fluctuations) may sit in
        a dip at half the elapsed time; measured against the dip, its return to the earlier
        level looked like growth: the theta = 24, H = 10 run of the default (E_kin 288 at
        t ~ 110, 110 at t ~ 190, 244 at t ~ 360) was stopped as "accelerating (growth x1.6)"."""
        tn = t[-1]
        w = self.averaging_time
        last = ratio[t >= tn - w]
        last = last[np.isfinite(last)]
        tm = self._t_origin + 0.5 * (tn - self._t_origin)
        centres = np.arange(self._t_origin + w, tm + 0.25 * w, 0.5 * w)
        if centres.size == 0 or centres[-1] < tm - 0.25 * w:
            centres = np.append(centres, tm)
        levels = []
        for c in centres:
            seg = ratio[(t >= c - 0.5 * w) & (t <= c + 0.5 * w)]
            seg = seg[np.isfinite(seg)]
            if seg.size:
                levels.append(float(np.median(seg)))
        if last.size == 0 or not levels:
            return math.nan
        m = max(levels)
        return float(np.median(last)) / m if m > 0 else math.inf

    def _check(self, tb: float) -> None:
        self._n_checks += 1
        elapsed = tb - self._t_origin
        cap = tb >= self.t_cap
        if self.stop_when_flowing and elapsed >= self.flowing_window and not cap:
            if self._check_flowing(tb):
                return
        if elapsed < self.averaging_time and not cap:
            self._set_decision(False, "continue", "undecided", tb, None, 0.0,
                               f"t={tb:.6g}: continue, less than averaging_time of data")
            return
        s = self.series()
        c = classify_flow(
            s["time"], s["ratio"], s["u_bar"], trend_window=self.averaging_time, alpha=self.alpha,
            arrest_ratio=self.arrest_ratio, arrest_hold=self.arrest_hold, n_origins=self.n_origins,
            min_onset=self.min_onset)
        self._classification = c
        onset = c.onset if c.state in ("steady", "layered") else None
        ready = onset is not None and tb - onset >= self.averaging_time
        self._steady_streak = self._steady_streak + 1 if ready else 0
        msg = c.explain()
        if c.state == "arrested":
            self._set_decision(True, "arrested", c.state, tb, None, c.confidence, f"t={tb:.6g}: stop; {msg}")
            return
        if ready and self._steady_streak >= self.steady_confirmations:
            self._set_decision(True, "steady", c.state, tb, onset, c.confidence,
                               f"t={tb:.6g}: stop, steady window [{onset:.6g}, {tb:.6g}]; {msg}")
            return
        if c.state == "accelerating" and tb - self._t_origin >= self.min_accelerating_time:
            growth = self._growth(s["ratio"], s["time"])
            significant = c.confidence >= self.accel_confidence and growth >= ACCEL_MIN_GROWTH
            if significant or growth >= self.accel_growth_factor:
                self._set_decision(True, "accelerating", c.state, tb, None, c.confidence,
                                   f"t={tb:.6g}: stop, accelerating (growth x{growth:.3g}); {msg}")
                return
        if c.state == "oscillating" and self.stop_on_oscillating:
            self._set_decision(True, "oscillating", c.state, tb, None, c.confidence,
                               f"t={tb:.6g}: stop; {msg}")
            return
        if cap:
            self._set_decision(True, "t_cap", c.state, tb, onset, c.confidence,
                               f"t={tb:.6g}: stop at the cap t_cap={self.t_cap:g}; {msg}")
            return
        self._set_decision(False, "continue", c.state, tb, onset, c.confidence, f"t={tb:.6g}: continue; {msg}")

    def _check_flowing(self, tb: float) -> bool:
        """The bracket runs' stop: steady over ``flowing_window`` (confirmed) or clearly
        accelerating after the start-up -- decisively not arresting.  True when it stopped."""
        s = self.series()
        c = classify_flow(
            s["time"], s["ratio"], s["u_bar"], trend_window=self.flowing_window,
            alpha=self.alpha, arrest_ratio=self.arrest_ratio, arrest_hold=self.arrest_hold,
            n_origins=self.n_origins, min_onset=self.min_onset)
        if c.state == "arrested":
            return False  # the regular check stops it
        onset = c.onset if c.state in ("steady", "layered") else None
        self._flowing_streak = self._flowing_streak + 1 if onset is not None else 0
        growth = self._growth(s["ratio"], s["time"]) if c.state == "accelerating" else 0.0
        if (self._flowing_streak >= self.steady_confirmations
                or (c.state == "accelerating" and tb >= self.min_onset
                    and c.confidence >= self.accel_confidence and growth >= ACCEL_MIN_GROWTH)):
            self._classification = c
            self._set_decision(True, "flowing", c.state, tb, onset, c.confidence,
                               f"t={tb:.6g}: stop, decisively flowing ({c.state}); {c.explain()}")
            return True
        return False

    def reopen(self, why: str) -> None:
        """Withdraw a stop decision so that the monitor goes on checking (a caller that defers
        this stop, e.g. an accelerating verdict on a mixture that is still segregating, wants
        the later verdicts rather than the first one kept)."""
        d = self._decision
        if d.stop:
            self._set_decision(False, "continue", d.state, d.t, d.steady_start, d.confidence,
                               f"{d.message}; deferred: {why}")

    def _set_decision(self, stop, reason, state, t, start, conf, msg) -> None:
        self._decision = MonitorDecision(bool(stop), reason, state, float(t),
                                         None if start is None else float(start), float(conf), msg)

    def decision(self) -> MonitorDecision:
        """The latest decision (evaluated at the last check; O(1)).  Once ``stop`` is True it stays."""
        return self._decision

    @property
    def steady_start(self) -> float | None:
        """Start time of the steady window (None unless the latest decision found steady flow)."""
        return self._decision.steady_start

    @property
    def classification(self) -> FlowClassification | None:
        """The classification made at the latest check (None before the first one)."""
        return self._classification

    @property
    def n_samples(self) -> int:
        """Number of completed sample bins."""
        return self._n

    # ------------------------------------------------------------------ checkpointing
    def state_dict(self) -> dict:
        """Complete state as plain values (numpy arrays, floats, ints, bools, strings).

        Suitable for ``np.savez`` (decision and classification are JSON strings)."""
        n = self._n
        d = {k: getattr(self, k) for k in _CONFIG_KEYS}
        d.update({
            "time": self._time[:n].copy(), "e_kin": self._ekin[:n].copy(),
            "e_ela": self._eela[:n].copy(), "u_bar": self._ubar[:n].copy(),
            "cum_e_ela": self._cum_eela[: n + 1].copy(), "has_u": self._has_u, "t_origin": self._t_origin, "bin_index": self._bin_index,
            "acc": self._acc.copy(), "above_seen": self._above_seen,
            "below_since": self._below_since, "arrested": self._arrested,
            "next_check": self._next_check, "n_checks": self._n_checks,
            "steady_streak": self._steady_streak,
            "flowing_streak": self._flowing_streak,
            "decision_json": json.dumps(asdict(self._decision)),
            "classification_json": "" if self._classification is None else json.dumps(
                {"state": self._classification.state, "onset": self._classification.onset,
                 "confidence": self._classification.confidence,
                 "statistics": self._classification.statistics,
                 "reason": self._classification.reason}, default=float),
        })
        return d

    @classmethod
    def from_state_dict(cls, d) -> "SteadyStateMonitor":
        """Rebuild a monitor from :meth:`state_dict` output (also from an ``np.load`` archive)."""
        scalar = as_scalar
        cfg = {k: scalar(d[k]) for k in _CONFIG_KEYS if k in d}  # older states lack min_onset
        m = cls(**cfg)
        time = np.asarray(d["time"], dtype=float)
        n = time.size
        while m._cap < n:
            m._grow()
        m._n = n
        m._time[:n] = time
        m._ekin[:n] = np.asarray(d["e_kin"], dtype=float)
        m._eela[:n] = np.asarray(d["e_ela"], dtype=float)
        m._ubar[:n] = np.asarray(d["u_bar"], dtype=float)
        m._cum_eela[: n + 1] = np.asarray(d["cum_e_ela"], dtype=float)
        m._has_u = bool(scalar(d["has_u"]))
        m._t_origin = float(scalar(d["t_origin"]))
        m._bin_index = int(scalar(d["bin_index"]))
        m._acc = np.asarray(d["acc"], dtype=float).copy()
        m._above_seen = bool(scalar(d["above_seen"]))
        m._below_since = float(scalar(d["below_since"]))
        m._arrested = bool(scalar(d["arrested"]))
        m._next_check = float(scalar(d["next_check"]))
        m._n_checks = int(scalar(d["n_checks"]))
        m._steady_streak = int(scalar(d["steady_streak"]))
        m._flowing_streak = int(scalar(d["flowing_streak"])) if "flowing_streak" in d else 0
        m._decision = MonitorDecision(**json.loads(str(scalar(d["decision_json"]))))
        cj = str(scalar(d["classification_json"]))
        if cj:
            m._classification = FlowClassification(**json.loads(cj))
        return m
