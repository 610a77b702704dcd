"""Adaptive search for the arrested/flowing demarcation h_stop(theta) (Weinhart et al. 2012 §6).

The paper (§6, used again in §8 for every basal roughness lambda) brackets the demarcation line
with runs chosen by this walk: "Starting from an initial filling height H = 4 and inclination
theta = 21 deg, the angle was increased in steps of 1 deg until eventually a flowing state was
reached.  From this initial flowing state, the height was increased by 2 particle heights, if the
flow arrested, or else the angle decreased by 1/2 deg, assuming the curve is monotonically
decreasing."  A run is arrested when E_kin/<E_ela> falls below 1e-5 within 500 time units
(:data:`ARREST_HORIZON`), otherwise flowing.  "This procedure yields intervals of the inclination
angle for each height and, vice versa, height intervals for each angle, between which the
demarcation line lies"; those intervals are fitted with Eq. (45) (``granflow.fitting``).

:class:`HstopSearch` is that walk as a pure state machine (``next_point`` / ``record``), and
:func:`run_hstop_search` drives it with a callable that runs one simulation.

Ambiguities of the paper's description and how they are resolved here:

1. *Which runs follow the first flowing state.*  Read literally ("from this initial flowing state
   ... if the flow arrested") the rule applies to every later run: after a flowing run lower theta
   by 1/2 at the same H; after an arrested run raise H by 2 at the same theta.  The walk thus
   staircases down the h_stop curve towards larger H and smaller theta.  Before the first flowing
   state an arrested run raises theta by 1 (not H by 2).
2. *Monotonicity.*  "Assuming the curve is monotonically decreasing": a flowing run at (theta, H)
   implies flowing at every theta' >= theta, H' >= H, an arrested run implies arrested at every
   theta' <= theta, H' <= H.  The interval for filling height H is therefore
   theta_arrested(H) = max{theta of arrested runs with H' >= H} and
   theta_flowing(H) = min{theta of flowing runs with H' <= H}, which gives every visited H an
   interval even when the walk only passed through it with a single run (after an arrested run at
   (theta, H) the step to H + 2 brackets H + 2 from above by the flowing run at the same or larger
   theta on a smaller H).  Intervals inconsistent with monotonicity (noisy runs) are reported with
   ``consistent = False`` instead of being silently dropped.
3. *Termination.*  The paper gives none; the walk ends when H would exceed ``H_max``, theta would
   exceed ``theta_max`` before anything flows, theta would drop below ``theta_min``, or after
   ``max_runs`` runs.  A walk step whose outcome is already implied by monotonicity (e.g. theta
   first-flowing - 1 at H = 4, simulated in the upward phase) is not simulated again
   (``skip_implied``); it is kept in ``inferred``.
4. *States other than arrested/flowing.*  The paper's rule is binary (arrested within 500 time
   units, "otherwise ... flowing"), so every classifier state except "arrested" -- steady,
   accelerating, layered, oscillating and undecided -- counts as flowing.
5. *H is the filling height* (about 200 H particles), not the measured flow height h; the
   intervals are in (H, theta).  Convert with the measured h of each run before fitting Eq. (45)
   if the fit is to be in h.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

__all__ = [
    "ARREST_HORIZON",
    "HstopInterval",
    "HstopSearch",
    "run_hstop_search",
    "is_flowing",
]

#: Paper §6: a run is arrested when E_kin/<E_ela> falls below 1e-5 within 500 time units.
ARREST_HORIZON = 500.0

_EPS = 1e-9


def is_flowing(state) -> bool:
    """Binary arrested/flowing verdict of the paper from a state string, bool, or an object with a
    ``state`` attribute (FlowClassification, MonitorDecision).  Only "arrested" is not flowing."""
    if isinstance(state, bool):
        return state
    s = getattr(state, "state", state)
    if not isinstance(s, str):
        raise TypeError(f"cannot interpret {state!r} as a flow state")
    return s.strip().lower() != "arrested"


@dataclass(frozen=True)
class HstopInterval:
    """Bracket of the demarcation at filling height H: arrested at theta_arrested, flowing at
    theta_flowing (either may be nan if no run bounds that side); consistent is False when the
    runs contradict monotonicity (theta_arrested >= theta_flowing)."""

    H: float
    theta_arrested: float
    theta_flowing: float
    consistent: bool

    @property
    def width(self) -> float:
        return self.theta_flowing - self.theta_arrested

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.H, self.theta_arrested, self.theta_flowing)


class HstopSearch:
    """The paper's adaptive (theta, H) walk as a state machine::

        s = HstopSearch()
        while (p := s.next_point()) is not None:
            theta, H = p
            s.record(theta, H, run(theta, H))      # "arrested" or anything flowing
        s.intervals()                              # [(H, theta_arrested, theta_flowing), ...]
    """

    def __init__(self, theta0: float = 21.0, H0: float = 4.0, dtheta_up: float = 1.0,
                 dtheta_down: float = 0.5, dH: float = 2.0, H_max: float = 40.0,
                 theta_max: float = 40.0, theta_min: float = 5.0, max_runs: int = 200,
                 skip_implied: bool = True):
        if dtheta_up <= 0 or dtheta_down <= 0 or dH <= 0:
            raise ValueError("step sizes must be positive")
        self.theta0, self.H0 = float(theta0), float(H0)
        self.dtheta_up, self.dtheta_down, self.dH = float(dtheta_up), float(dtheta_down), float(dH)
        self.H_max, self.theta_max, self.theta_min = float(H_max), float(theta_max), float(theta_min)
        self.max_runs = int(max_runs)
        self.skip_implied = bool(skip_implied)
        self.runs: list[tuple[float, float, bool]] = []  # (theta, H, flowing) of simulated runs
        self.inferred: list[tuple[float, float, bool]] = []  # walk steps implied, not simulated
        self.phase = "up"  # "up" until the first flowing run, then "walk"; "done" at the end
        self.done_reason = ""
        self._next: tuple[float, float] | None = (self.theta0, self.H0)

    # -- state machine --------------------------------------------------------------------
    def next_point(self) -> tuple[float, float] | None:
        """The next (theta, H) to simulate, or None when the search is finished."""
        return self._next

    def record(self, theta: float, H: float, state) -> tuple[float, float] | None:
        """Record the outcome of the run at (theta, H) and return the next point (or None).

        ``state``: "arrested"/other state string, a bool (True = flowing), or an object with a
        ``state`` attribute.  The point must be the one :meth:`next_point` proposed.
        """
        if self._next is None:
            raise RuntimeError("the search is finished")
        theta, H = float(theta), float(H)
        if abs(theta - self._next[0]) > _EPS or abs(H - self._next[1]) > _EPS:
            raise ValueError(f"expected a result for {self._next}, got ({theta}, {H})")
        flowing = is_flowing(state)
        self.runs.append((theta, H, flowing))
        nxt = self._advance(theta, H, flowing)
        while nxt is not None and self.skip_implied:
            implied = self.implied_state(*nxt)
            if implied is None:
                break
            self.inferred.append((nxt[0], nxt[1], implied))
            nxt = self._advance(nxt[0], nxt[1], implied)
        self._next = nxt
        return self._next

    def record_failed(self, theta: float, H: float, why: str = "") -> None:
        """The run at the proposed (theta, H) gave no flow state (an engine guard stopped it
        before the classifier had one, e.g. an overlap on impact while the layer fell in): it is
        no evidence either way and is not recorded; the walk ends here (every later point would
        rest on it) with the reason in ``done_reason``."""
        if self._next is None:
            raise RuntimeError("the search is finished")
        theta, H = float(theta), float(H)
        if abs(theta - self._next[0]) > _EPS or abs(H - self._next[1]) > _EPS:
            raise ValueError(f"expected a result for {self._next}, got ({theta}, {H})")
        self._next = self._finish(f"the run at theta = {theta:g}, H = {H:g} gave no flow state"
                                  + (f" ({why})" if why else ""))

    def implied_state(self, theta: float, H: float) -> bool | None:
        """Outcome at (theta, H) implied by monotonicity from the simulated runs: True (flowing),
        False (arrested) or None (unknown, or the runs contradict each other there)."""
        flo = any(f and t <= theta + _EPS and h <= H + _EPS for t, h, f in self.runs)
        arr = any(not f and t >= theta - _EPS and h >= H - _EPS for t, h, f in self.runs)
        if flo == arr:
            return None
        return flo

    def _advance(self, theta: float, H: float, flowing: bool):
        if len(self.runs) >= self.max_runs:
            return self._finish("max_runs reached")
        if self.phase == "up":
            if not flowing:
                nt = theta + self.dtheta_up
                if nt > self.theta_max + _EPS:
                    return self._finish(f"no flow up to theta_max={self.theta_max:g}")
                return (nt, H)
            self.phase = "walk"
        if flowing:
            nt = theta - self.dtheta_down
            if nt < self.theta_min - _EPS:
                return self._finish(f"still flowing at theta_min={self.theta_min:g}")
            return (nt, H)
        nH = H + self.dH
        if nH > self.H_max + _EPS:
            return self._finish(f"H_max={self.H_max:g} reached")
        return (theta, nH)

    def _finish(self, why: str):
        self.phase = "done"
        self.done_reason = why
        return None

    @property
    def done(self) -> bool:
        return self._next is None

    # -- results ---------------------------------------------------------------------------
    def interval_objects(self) -> list[HstopInterval]:
        """One :class:`HstopInterval` per visited H (ascending), using monotonicity (module doc)."""
        out = []
        for H in sorted({h for _, h, _ in self.runs}):
            arr = [t for t, h, f in self.runs if not f and h >= H - _EPS]
            flo = [t for t, h, f in self.runs if f and h <= H + _EPS]
            ta = max(arr) if arr else math.nan
            tf = min(flo) if flo else math.nan
            consistent = not (arr and flo and ta >= tf)
            out.append(HstopInterval(H, ta, tf, consistent))
        return out

    def intervals(self, *, complete_only: bool = True) -> list[tuple[float, float, float]]:
        """[(H, theta_arrested, theta_flowing), ...] for every visited H whose interval is bounded on
        both sides and consistent (all visited H if ``complete_only`` is False)."""
        res = []
        for iv in self.interval_objects():
            if complete_only and not (iv.consistent and math.isfinite(iv.theta_arrested)
                                      and math.isfinite(iv.theta_flowing)):
                continue
            res.append(iv.as_tuple())
        return res

    def height_intervals(self) -> list[tuple[float, float, float]]:
        """[(theta, H_arrested, H_flowing), ...]: the paper's "height intervals for each angle" --
        for every visited theta the largest arrested H' at theta' >= theta and the smallest flowing
        H' at theta' <= theta (nan where unbounded)."""
        res = []
        for th in sorted({t for t, _, _ in self.runs}):
            arr = [h for t, h, f in self.runs if not f and t >= th - _EPS]
            flo = [h for t, h, f in self.runs if f and t <= th + _EPS]
            res.append((th, max(arr) if arr else math.nan, min(flo) if flo else math.nan))
        return res

    def state_dict(self) -> dict:
        """Plain-value state for checkpointing a long campaign."""
        return {
            "config": {k: getattr(self, k) for k in ("theta0", "H0", "dtheta_up", "dtheta_down", "dH",
                                                      "H_max", "theta_max", "theta_min", "max_runs",
                                                      "skip_implied")},
            "runs": [list(r) for r in self.runs], "phase": self.phase,
            "inferred": [list(r) for r in self.inferred],
            "done_reason": self.done_reason,
            "next": None if self._next is None else list(self._next),
        }

    @classmethod
    def from_state_dict(cls, d: dict) -> "HstopSearch":
        s = cls(**d["config"])
        s.runs = [(float(t), float(h), bool(f)) for t, h, f in d["runs"]]
        s.inferred = [(float(t), float(h), bool(f)) for t, h, f in d.get("inferred", [])]
        s.phase = d["phase"]
        s.done_reason = d["done_reason"]
        s._next = None if d["next"] is None else (float(d["next"][0]), float(d["next"][1]))
        return s


def run_hstop_search(run_fn: Callable[[float, float], object], **kwargs) -> HstopSearch:
    """Drive :class:`HstopSearch` (constructed with ``kwargs``) with ``run_fn(theta, H) -> state``
    until it finishes; returns the search (``.intervals()``, ``.runs``, ``.done_reason``).

    ``run_fn`` should simulate for :data:`ARREST_HORIZON` time units and report "arrested" if the
    energy ratio fell below 1e-5 (e.g. a :class:`~granflow.steady.monitor.SteadyStateMonitor` with
    ``t_cap=500 + ARREST_HOLD_TIME`` -- the monitor confirms an arrest after the hold time -- and
    ``decision().reason == "arrested"``), anything else otherwise.
    """
    search = HstopSearch(**kwargs)
    while (point := search.next_point()) is not None:
        theta, H = point
        search.record(theta, H, run_fn(theta, H))
    return search
