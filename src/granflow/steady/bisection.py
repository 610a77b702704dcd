"""Bisection of the arrested/flowing demarcation at one filling height: the hstop brackets.

The paper's walk (§6, :mod:`granflow.steady.hstop_search`) visits heights one after another in
fixed steps of 1/2 and 1 degree, so every bracket costs several runs in sequence and ends 0.5
degrees wide.  For a fitted hstop(theta) (Eq. 45) what matters is a narrow bracket at each of a
few well-chosen heights, and the heights are independent: :class:`Bisection` brackets
theta_stop(H) at one H by

1. a first run at the predicted theta_stop(H) (from a prior curve: only where to start, it never
   enters a fit);
2. steps away from the known side, doubling (``step``, 2 ``step``, 4 ``step`` ...), until one run
   arrests and one flows;
3. bisection of that bracket until it is at most ``tolerance`` wide,

and stops after ``max_runs``.  Chains at different heights run concurrently (one Snakemake
checkpoint chain each).  States are binary as in the paper: every state but ``arrested`` is
flowing, except ``failed`` -- a run that an engine guard ended before it had any flow state (an
overlap on impact while a soft layer falls in): it is neither, and the chain stops there with a
note (every angle of that height would fall the same way; the species is too soft for it).  An outcome that contradicts monotonicity at this height (an arrest above a flowing
angle, as happens with run-to-run noise right at the demarcation) is kept: the bracket is then
[max arrested, min flowing] swapped and flagged ``consistent = False``, and the chain stops.
Angles are rounded to ``resolution`` so that run directories stay readable.
"""

from __future__ import annotations

import math

_EPS = 1e-9
#: state of a run that gives no flow state (see the module docstring)
FAILED = "failed"


class Bisection:
    """Bracket theta_stop(H) at one height by expanding steps and bisection (module docstring)."""

    def __init__(self, H: float, theta_guess: float, *, step: float = 1.0,
                 tolerance: float = 0.25, max_runs: int = 8, theta_min: float = 5.0,
                 theta_max: float = 60.0, resolution: float = 0.01):
        if not (H > 0 and step > 0 and tolerance > 0 and max_runs >= 1 and resolution > 0):
            raise ValueError("need H, step, tolerance, resolution > 0 and max_runs >= 1")
        if not theta_min < theta_max:
            raise ValueError("need theta_min < theta_max")
        self.H = float(H)
        self.step = float(step)
        self.tolerance = float(tolerance)
        self.max_runs = int(max_runs)
        self.theta_min = float(theta_min)
        self.theta_max = float(theta_max)
        self.resolution = float(resolution)
        self.theta_guess = self._round(min(max(float(theta_guess), self.theta_min),
                                           self.theta_max))
        self.runs: list[tuple[float, str]] = []  # (theta, state)
        self.note = ""

    def _round(self, theta: float) -> float:
        return round(round(theta / self.resolution) * self.resolution, 10)

    # ---------------------------------------------------------------- bracket
    @property
    def theta_arrested(self) -> float:
        a = [t for t, s in self.runs if s == "arrested"]
        return max(a) if a else -math.inf

    @property
    def theta_flowing(self) -> float:
        f = [t for t, s in self.runs if s not in ("arrested", FAILED)]
        return min(f) if f else math.inf

    @property
    def consistent(self) -> bool:
        return self.theta_arrested < self.theta_flowing

    @property
    def width(self) -> float:
        return self.theta_flowing - self.theta_arrested

    def interval(self) -> tuple[float, float, float, bool]:
        """(H, theta_arrested, theta_flowing, consistent); swapped when inconsistent."""
        lo, hi = self.theta_arrested, self.theta_flowing
        if lo > hi:
            lo, hi = hi, lo
        return self.H, lo, hi, self.consistent

    # ---------------------------------------------------------------- walk
    def next_point(self) -> float | None:
        """The next angle to run, or None when the bracket is done (or cannot be improved)."""
        if len(self.runs) >= self.max_runs:
            self.note = f"stopped after max_runs = {self.max_runs}"
            return None
        if not self.runs:
            return self.theta_guess
        if self.runs[-1][1] == FAILED:
            self.note = (f"the run at theta = {self.runs[-1][0]:g} ended (engine guard) before it "
                         f"had a flow state: no bracket from it")
            return None
        if not self.consistent:
            self.note = "outcomes contradict monotonicity at this height (noise at the demarcation)"
            return None
        lo, hi = self.theta_arrested, self.theta_flowing
        if math.isfinite(lo) and math.isfinite(hi):
            if hi - lo <= self.tolerance + _EPS:
                self.note = f"bracket {hi - lo:.3g} deg <= tolerance {self.tolerance:g}"
                return None
            mid = self._round(0.5 * (lo + hi))
            if not lo + _EPS < mid < hi - _EPS:  # the resolution cannot split it further
                self.note = "bracket at the angle resolution"
                return None
            return mid
        # one side only: step away from it, doubling
        n_side = len(self.runs)
        d = self.step * 2 ** (n_side - 1)
        if math.isfinite(hi):  # only flowing runs: go down
            nxt = self._round(hi - d)
            if nxt < self.theta_min - _EPS:
                self.note = f"flowing down to theta_min = {self.theta_min:g}"
                return None
            return max(nxt, self.theta_min)
        nxt = self._round(lo + d)
        if nxt > self.theta_max + _EPS:
            self.note = f"arrested up to theta_max = {self.theta_max:g}"
            return None
        return min(nxt, self.theta_max)

    def record(self, theta: float, state: str) -> None:
        """Record the flow state of the run at ``theta`` (any state but "arrested" and
        "failed" flows)."""
        self.runs.append((self._round(float(theta)), str(state)))

    # ---------------------------------------------------------------- state
    _KEYS = ("H", "step", "tolerance", "max_runs", "theta_min", "theta_max", "resolution",
             "theta_guess")

    def state_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self._KEYS}
        d["runs"] = [[t, s] for t, s in self.runs]
        d["note"] = self.note
        nxt = self.next_point()
        d["next"] = nxt
        d["note"] = self.note
        return d

    @classmethod
    def from_state_dict(cls, d: dict) -> "Bisection":
        b = cls(d["H"], d["theta_guess"], step=d["step"], tolerance=d["tolerance"],
                max_runs=d["max_runs"], theta_min=d["theta_min"], theta_max=d["theta_max"],
                resolution=d["resolution"])
        b.runs = [(float(t), str(s)) for t, s in d.get("runs", [])]
        b.note = d.get("note", "")
        return b
