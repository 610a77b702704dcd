"""Run orchestration: time stepping in chunks, sampling, checkpoint/resume and outputs.

A run advances a :class:`~granflow.engine.system.ParticleSystem` in chunks of
``sample_every`` steps (default t_c/2, the paper's snapshot interval, Weinhart et al. 2012 §5);
after each chunk it records the energy time series (kinetic, elastic, gravitational; the
energy ratio E_kin/E_ela of §6) and the mean downslope velocity, and hands the state to
*observers* (coarse-graining accumulators, steady-state monitors) that may also ask the run to
stop early.

Checkpoints hold the complete state (particles, neighbour list, contact history, time series,
observer states) and are written atomically, so a run killed at any moment resumes from the
last checkpoint and finishes with exactly the numbers of an uninterrupted run.

A run also counts what it cost (:meth:`ChuteRun.cost`): wall-clock and CPU seconds of the
process (CPU time of all its threads: core seconds that do not grow when other jobs share the
cores), summed over the segments of a run that was killed and resumed (the checkpoint carries
the totals up to its writing; the work after the last checkpoint is redone and counted once).
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
import time as _time
from pathlib import Path

import numpy as np

from .system import ParticleSystem

log = logging.getLogger(__name__)

SERIES = ("time", "e_kin", "e_ela", "e_grav", "u_mean")


def cpu_seconds() -> float:
    """CPU seconds of this process, all threads, and of its finished child processes (the
    LAMMPS ranks of a run on the second engine, counted once they have been waited for)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class EnergySeries:
    """Time series of energies and the mean downslope velocity of the mobile particles."""

    name = "series"

    def __init__(self):
        self.data = {k: [] for k in SERIES}

    def sample(self, system: ParticleSystem):
        e = system.energies()
        select = getattr(system, "mobile_selection", None)  # the engine's; a dump's has none
        mobile = select() if select is not None else ~system.fixed
        # a contiguous copy either way (a slice or a mask): the same mean, bit for bit
        u_mobile = np.ascontiguousarray(system.vel[mobile, 0])
        u = float(np.mean(u_mobile)) if u_mobile.size else 0.0
        for key, value in zip(SERIES, (system.time, e["kinetic"], e["elastic"], e["gravitational"], u)):
            self.data[key].append(float(value))

    def arrays(self) -> dict:
        return {k: np.asarray(v, dtype=np.float64) for k, v in self.data.items()}

    def state_dict(self) -> dict:
        return self.arrays()

    def load_state_dict(self, state: dict):
        self.data = {k: list(np.asarray(state[k], dtype=np.float64)) for k in SERIES}


def _flatten_observer_states(observers) -> dict:
    out = {}
    for obs in observers:
        for key, value in obs.state_dict().items():
            arr = np.asarray(value)
            if arr.dtype == object:
                arr = np.array(json.dumps(value))
            out[f"obs__{obs.name}__{key}"] = arr
    return out


def _restore_observer_states(observers, extra: dict):
    for obs in observers:
        prefix = f"obs__{obs.name}__"
        state = {k[len(prefix):]: v for k, v in extra.items() if k.startswith(prefix)}
        if state:
            obs.load_state_dict(state)


class ChuteRun:
    """Drive a system to ``t_end`` with sampling, observers, checkpoints and early stopping.

    Parameters
    ----------
    system : the prepared system (ignored when a checkpoint is found and ``resume`` is True)
    t_end : hard cap on the simulated time
    sample_every : steps between samples (default: t_c/2 in steps)
    observers : objects with ``name``, ``sample(system)``, ``state_dict()``, ``load_state_dict()``
        and optionally ``should_stop(system) -> (bool, reason)``
    checkpoint : path of the checkpoint file (None: no checkpoints)
    checkpoint_every_s : wall-clock seconds between checkpoints
    checkpoint_identity : a JSON string written into every checkpoint (``run_identity``), which
        the caller compares before it resumes one (:func:`granflow.simulate.simulate`: the run
        parameters that decide the physics and the files it started from)
    """

    def __init__(self, system: ParticleSystem, t_end: float, sample_every: int | None = None,
                 observers=(), checkpoint: str | os.PathLike | None = None,
                 checkpoint_every_s: float = 60.0, progress: bool | None = None,
                 stop_hook=None, checkpoint_identity: str | None = None):
        if not (t_end > 0 and math.isfinite(t_end)):
            raise ValueError(f"t_end = {t_end!r} is out of range: allowed (0, inf)")
        self.system = system
        self.t_end = float(t_end)
        t_c = system.interactions.min_collision_time()
        self.sample_every = int(sample_every) if sample_every else max(1, int(round(0.5 * t_c / system.dt)))
        self.series = EnergySeries()
        self.observers = [self.series, *observers]
        self.checkpoint = Path(checkpoint) if checkpoint else None
        self.checkpoint_every_s = float(checkpoint_every_s)
        self.checkpoint_identity = checkpoint_identity
        self.progress = sys.stderr.isatty() if progress is None else progress
        self.stop_hook = stop_hook
        # called after every chunk of steps (e.g. SpareCores.poll, which changes the numba
        # threads: the numbers do not depend on them); each must be cheap
        self.tick_hooks = []
        self.stop_reason = "t_end reached"
        self.resumed_from = None
        # cost of the earlier segments (restored from a checkpoint) and the start of this one;
        # the caller may move the start back to include its set-up (granflow.simulate does)
        self.cost_before = {"wall_s": 0.0, "cpu_s": 0.0, "segments": 0}
        self.segment_start = (_time.monotonic(), cpu_seconds())

    # ------------------------------------------------------------------ checkpoint
    def save_checkpoint(self):
        if self.checkpoint is None:
            return
        extra = _flatten_observer_states(self.observers)
        extra["stop_reason"] = np.array(self.stop_reason)
        cost = self.cost()
        extra["cost_wall_s"] = np.array(cost["wall_s"])
        extra["cost_cpu_s"] = np.array(cost["cpu_s"])
        extra["cost_segments"] = np.array(cost["segments"])
        if self.checkpoint_identity is not None:
            extra["run_identity"] = np.array(self.checkpoint_identity)
        self.system.save(self.checkpoint, extra=extra)

    def cost(self) -> dict:
        """Wall and CPU seconds of the run so far, all segments (``segments``: processes)."""
        wall0, cpu0 = self.segment_start
        before = self.cost_before
        return {"wall_s": before["wall_s"] + _time.monotonic() - wall0,
                "cpu_s": before["cpu_s"] + cpu_seconds() - cpu0,
                "segments": int(before["segments"]) + 1}

    def try_resume(self) -> bool:
        """Load the checkpoint if there is one; returns True when resumed."""
        if self.checkpoint is None or not self.checkpoint.exists():
            return False
        system, extra = ParticleSystem.load(self.checkpoint)
        self.system = system
        _restore_observer_states(self.observers, extra)
        if "cost_wall_s" in extra:  # checkpoints written before the cost was kept have none
            self.cost_before = {"wall_s": float(extra["cost_wall_s"]),
                                "cpu_s": float(extra["cost_cpu_s"]),
                                "segments": int(extra["cost_segments"])}
        self.resumed_from = float(system.time)
        log.info("resumed from checkpoint %s at t = %.4g", self.checkpoint, system.time)
        return True

    # ------------------------------------------------------------------ main loop
    @property
    def n_steps_total(self) -> int:
        return int(round(self.t_end / self.system.dt))

    def run(self) -> "ChuteRun":
        sys_ = self.system
        if sys_.step_count == 0 and not self.series.data["time"]:
            for obs in self.observers:
                obs.sample(sys_)
        bar = None
        if self.progress:
            try:
                from tqdm import tqdm

                bar = tqdm(total=self.n_steps_total, initial=sys_.step_count, unit="step",
                           desc=f"chute", mininterval=1.0)
            except ImportError:  # pragma: no cover
                bar = None
        last_ckpt = _time.monotonic()
        last_log = _time.monotonic()
        total = self.n_steps_total
        finished = False
        while sys_.step_count < total:
            n = min(self.sample_every - sys_.step_count % self.sample_every, total - sys_.step_count)
            sys_.step(n)
            if sys_.step_count % self.sample_every == 0 or sys_.step_count == total:
                for obs in self.observers:
                    obs.sample(sys_)
                stop, reason = self._should_stop()
                if stop:
                    self.stop_reason = reason
                    finished = True
            if bar is not None:
                bar.update(n)
            for hook in self.tick_hooks:
                hook()
            now = _time.monotonic()
            if bar is None and now - last_log > 30.0:
                e = self.series.data
                log.info("t = %.2f / %.0f, E_kin = %.4g, E_ela = %.4g, u = %.4g", sys_.time,
                         self.t_end, e["e_kin"][-1], e["e_ela"][-1], e["u_mean"][-1])
                last_log = now
            if finished:
                break
            if self.checkpoint is not None and now - last_ckpt > self.checkpoint_every_s:
                self.save_checkpoint()
                last_ckpt = _time.monotonic()
        if bar is not None:
            bar.close()
        log.info("run finished at t = %.4g: %s", sys_.time, self.stop_reason)
        return self

    def _should_stop(self):
        for obs in self.observers:
            fn = getattr(obs, "should_stop", None)
            if fn is not None:
                stop, reason = fn(self.system)
                if stop:
                    return True, reason
        if self.stop_hook is not None:
            return self.stop_hook(self)
        return False, ""
