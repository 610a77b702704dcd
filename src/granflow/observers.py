"""Run observers: on-the-fly coarse-graining and early stopping, attached to a chute run.

Observers are called by :class:`granflow.engine.run.ChuteRun` after every sample interval
(default t_c/2, Weinhart et al. 2012 §5).  They keep only running sums, never trajectories, and
checkpoint with the run (``state_dict`` / ``load_state_dict``):

* :class:`ProfileObserver` feeds each snapshot (positions, velocities, contacts with forces and
  contact points) to a :class:`granflow.coarse.DepthProfileAccumulator` (Eq. 13-32, 43), in
  time windows, so that the profiles of the steady window alone can be kept at the end.
* :class:`MonitorObserver` feeds the energies to a
  :class:`granflow.steady.SteadyStateMonitor` (§6: E_kin / <E_ela>) and asks the run to stop
  once the flow is arrested, clearly accelerating, or steady with enough averaging time.
* :class:`SegregationObserver` (bidisperse runs) records the small-particle centre of mass
  relative to the flow's, feeds a :class:`granflow.steady.segregation.SegregationMonitor`, and
  holds a steady flow running until the segregated state is steady too (seed 002 §6).
"""

from __future__ import annotations

import json
import math

import numpy as np

from .coarse import DepthProfileAccumulator
from .steady.monitor import SteadyStateMonitor
from .steady.segregation import SegregationMonitor


def _as_arrays(state: dict) -> dict:
    """A monitor's state dict as numpy arrays (strings as 0-d string arrays), for np.savez."""
    return {k: np.array(v) if isinstance(v, str) else np.asarray(v) for k, v in state.items()}


class ProfileObserver:
    """Coarse-grain every ``every``-th sample into depth profiles, by time window."""

    name = "profiles"

    def __init__(self, accumulator: DepthProfileAccumulator, every: int = 1, t_start: float = 0.0):
        self.acc = accumulator
        self.every = max(1, int(every))
        self.t_start = float(t_start)
        self._calls = 0

    def sample(self, system):
        self._calls += 1
        if system.time < self.t_start or (self._calls - 1) % self.every:
            return
        c = system.contacts()
        pos, fixed = system.pos, system.fixed
        ci, cj = c["contact_i"], c["contact_j"]
        diameter = 2.0 * system.radius
        species = system.ptype
        mass = system.mass
        vel = system.vel
        if (cj < 0).any():
            # flat-wall contacts (j = -1): a virtual fixed partner appended at index N, so the
            # wall force is spread on the base half-line like any base contact
            n = len(fixed)
            cj = np.where(cj < 0, n, cj)
            pos = np.vstack([pos, [[0.0, 0.0, -1.0]]])
            vel = np.vstack([vel, [[0.0, 0.0, 0.0]]])
            fixed = np.append(fixed, True)
            diameter = np.append(diameter, 0.0)
            species = np.append(species, 0)
            mass = np.append(mass, 1.0)
        self.acc.add_snapshot(system.time, pos, vel, mass, diameter, species, fixed, ci, cj,
                              c["contact_force"], c["contact_rij"], c["contact_point"])

    def state_dict(self) -> dict:
        state = dict(self.acc.state_dict())
        state["observer_calls"] = np.int64(self._calls)
        return state

    def load_state_dict(self, state: dict):
        state = dict(state)
        self._calls = int(state.pop("observer_calls"))
        self.acc = DepthProfileAccumulator.from_state_dict(state)

    def dataset(self, t_from: float | None = None, attrs=None):
        """Profiles averaged over the windows starting at or after ``t_from`` (all if None)."""
        acc = self.acc
        if t_from is not None and acc.window_length is not None and acc.t_first is not None:
            keep = {k: w for k, w in acc._windows.items()
                    if acc.t_first + k * acc.window_length >= t_from - 1e-9}
            if keep:
                acc = DepthProfileAccumulator.from_state_dict(acc.state_dict())
                acc._windows = keep
        return acc.to_dataset(attrs)


class MonitorObserver:
    """Early stopping by :class:`SteadyStateMonitor` on the run's energy series."""

    name = "monitor"

    def __init__(self, monitor: SteadyStateMonitor, series):
        self.monitor = monitor
        self.series = series  # the run's EnergySeries (already sampled before this observer)

    def sample(self, system):
        d = self.series.data
        self.monitor.update(d["time"][-1], d["e_kin"][-1], d["e_ela"][-1], d["u_mean"][-1])

    def should_stop(self, system):
        dec = self.monitor.decision()
        if dec.stop:
            return True, f"{dec.reason}: {dec.message}"
        return False, ""

    def state_dict(self) -> dict:
        return _as_arrays(self.monitor.state_dict())

    def load_state_dict(self, state: dict):
        self.monitor = SteadyStateMonitor.from_state_dict(state)

    def final(self) -> dict:
        """Final classification of the run (state, steady window start, confidence, reason)."""
        self.monitor.flush()
        dec = self.monitor.decision()
        cls = self.monitor.classify() if not dec.stop else self.monitor.classification
        if cls is None:
            cls = self.monitor.classify()
        state = dec.state if dec.stop else cls.state
        start = dec.steady_start if dec.stop else cls.onset
        if dec.stop and dec.reason == "flowing":
            # a bracketing run stopped once it was decisively not arresting: flowing for hstop,
            # but without the averaging a steady closure needs
            state = "flowing"
        return {
            "flow_state": state,
            "steady_start": float("nan") if start is None else float(start),
            "confidence": float(dec.confidence if dec.stop else cls.confidence),
            "stop_reason": dec.reason if dec.stop else "t_end",
            "explanation": cls.explain() if cls is not None else dec.message,
            "statistics_json": json.dumps(getattr(cls, "statistics", {}), default=_json_float),
        }


class SegregationObserver:
    """Segregation indicator s = z_com(small) - z_com(flow) and the segregated-steady stop rule.

    With ``energy`` (the run's :class:`MonitorObserver`) the energy monitor's "steady" stop is
    deferred: the run stops as steady only when the segregation monitor is steady as well and
    ``averaging_time`` has passed since the later of the two onsets.  An "accelerating" stop is
    deferred too while the segregated state is still forming, unless the growth is decisive
    (the energy ratio grew by the monitor's ``accel_growth_factor``, velocity x3.2): as the large
    particles rise the mixture flows faster, and that slow rise (E_kin x1.55 between t = 120 and
    240 at the paper's species, sigma = 0.75, 25 deg, H = 8, a flow that then levels off) is not a
    runaway flow.  Arrested stops pass through unchanged.
    """

    name = "segregation"

    def __init__(self, monitor: SegregationMonitor, small_type: int = 0, energy=None):
        self.monitor = monitor
        self.small_type = int(small_type)
        self.energy = energy
        if energy is not None:  # take over the energy monitor's steady stop
            energy_stop = energy.should_stop

            def gated(system, _stop=energy_stop):
                stop, reason = _stop(system)
                if stop and reason.startswith("steady"):
                    return False, ""
                if stop and reason.startswith("accelerating") and not self._decisive_growth():
                    st = self.monitor.state
                    if st is None or not st.steady:  # check again later
                        energy.monitor.reopen("the segregated state is still forming")
                        return False, ""
                return stop, reason
            energy.should_stop = gated

    def _decisive_growth(self) -> bool:
        """The energy ratio grew by the energy monitor's ``accel_growth_factor`` between half
        the elapsed time and now: accelerating whatever segregation does."""
        mon = self.energy.monitor
        s = mon.series()
        growth = mon._growth(s["ratio"], s["time"])
        return bool(math.isfinite(growth) and growth >= mon.accel_growth_factor)

    def indicator(self, system) -> float:
        flow = ~system.fixed
        small = flow & (system.ptype == self.small_type)
        if not small.any():
            return math.nan
        z = system.pos[:, 2]
        m = system.mass[flow]
        return float(z[small].mean() - (m @ z[flow]) / m.sum())

    def sample(self, system):
        self.monitor.update(system.time, self.indicator(system))

    def steady_start(self, energy_start: float | None) -> float | None:
        """Start of the window that is steady in energy and segregation (None if not both)."""
        st = self.monitor.state
        if st is None or not st.steady or energy_start is None or not math.isfinite(energy_start):
            return None
        return max(float(energy_start), float(st.onset))

    def should_stop(self, system):
        if self.energy is None:
            return False, ""
        dec = self.energy.monitor.decision()
        if not (dec.stop and dec.reason == "steady"):
            return False, ""
        st = self.monitor.state
        start = self.steady_start(dec.steady_start)
        if start is None or system.time - start < self.monitor.averaging_time:
            return False, ""
        return True, (f"steady: energy steady from t={dec.steady_start:.6g}, segregated state "
                      f"steady from t={st.onset:.6g}; {st.message}")

    def state_dict(self) -> dict:
        return _as_arrays(self.monitor.state_dict())

    def load_state_dict(self, state: dict):
        self.monitor = SegregationMonitor.from_state_dict(state)

    def final(self) -> dict:
        """Final segregation verdict (after flushing the open bin)."""
        self.monitor.flush()
        st = self.monitor.check()
        return dict(st.as_dict(), time=np.asarray(self.monitor.time),
                    value=np.asarray(self.monitor.value))


def _json_float(x):
    try:
        return float(x)
    except (TypeError, ValueError):
        return str(x)
