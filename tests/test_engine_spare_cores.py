"""Spare cores (issue 15): a run takes idle cores while it runs, gives them back, and no number
changes (granflow.engine.threads).

* the policy, on a scripted machine (injected CPU counters and clock): an idle core is taken
  after one interval, given back as soon as another process needs it, never taken from a
  busy machine, never beyond ``max_threads``; the wall time per thread count adds up;
  a borrowed thread that does not raise the step rate by ``PAYS`` goes back for good (small
  systems run slower on two threads), one that does stays;
* the lease: one lock per thread, shared by the jobs of a campaign; a dead job's locks are
  freed by the kernel; a job waiting for a slot makes the borrowers give theirs back;
* a run whose threads change every few steps ends with exactly the numbers of a one-thread run;
* bad values of ``max_threads`` / ``$GRANFLOW_MAX_THREADS`` are refused before any compute.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numba
import numpy as np
import pytest

from granflow.engine import threads as T


class Machine:
    """Scripted CPU counters: ``others`` and ``own`` cores busy from now on."""

    def __init__(self):
        self.t = 0.0
        self.busy_s = 0.0
        self.own_s = 0.0
        self.others = 0.0
        self.own_rate = 1.0
        self.applied = []

    def advance(self, dt):
        self.t += dt
        self.busy_s += (self.others + self.own_rate) * dt
        self.own_s += self.own_rate * dt

    def spare(self, max_threads=2, cores=2, lease_dir=None, progress=None):
        s = T.SpareCores(max_threads, cores=cores, lease_dir=lease_dir, interval_s=2.0,
                         busy=lambda: self.busy_s, own=lambda: self.own_s,
                         clock=lambda: self.t, apply=self.applied.append, wait_s=0.0,
                         progress=progress)
        return s.start()


class Stepper:
    """Scripted engine: ``rate[k]`` steps per wall second on k threads."""

    def __init__(self, machine, rate):
        self.m, self.rate, self.steps, self.spare = machine, rate, 0.0, None

    def run(self, dt):
        self.steps += self.rate[self.spare.threads] * dt
        self.m.own_rate = float(self.spare.threads)
        self.m.advance(dt)
        return self.spare.poll()


@pytest.fixture(autouse=True)
def _enough_numba_threads(monkeypatch):
    # SpareCores caps max_threads at NUMBA_NUM_THREADS; the policy tests use a fake setter
    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", max(8, numba.config.NUMBA_NUM_THREADS))


def test_an_idle_core_is_taken_after_one_interval_and_given_back_when_needed():
    m = Machine()
    s = m.spare()
    assert s.threads == 1 and m.applied == [1]
    m.advance(1.0)
    assert s.poll() == 1  # the interval has not passed
    m.advance(1.5)
    assert s.poll() == 2 and m.applied[-1] == 2  # nothing else ran: one core idle
    m.own_rate = 2.0
    for _ in range(3):
        m.advance(2.0)
        assert s.poll() == 2  # stays: its own two threads fill the machine
    m.others, m.own_rate = 0.67, 1.33  # a third runnable thread: timeshared
    m.advance(2.0)
    assert s.poll() == 1 and m.applied[-1] == 1
    m.others, m.own_rate = 1.0, 1.0  # the other job runs on
    for _ in range(3):
        m.advance(2.0)
        assert s.poll() == 1
    m.others = 0.0  # it ended
    m.advance(2.0)
    assert s.poll() == 2
    m.advance(1.0)
    s.close()
    # wall seconds per thread count add up to the run's wall time
    assert sum(s.record.values()) == pytest.approx(m.t)
    assert s.record[2] == pytest.approx((10.5 - 2.5) + (19.5 - 18.5))
    assert s.summary()["wall_s_at_threads"] == {"1": pytest.approx(m.t - s.record[2]),
                                                "2": pytest.approx(s.record[2])}


def test_no_core_is_taken_from_a_busy_machine_or_beyond_max_threads():
    m = Machine()
    m.others = 0.4  # light load elsewhere: 0.6 of a core free is not a core
    s = m.spare(max_threads=4, cores=2)
    for _ in range(5):
        m.advance(2.0)
        assert s.poll() == 1
    m2 = Machine()
    s2 = m2.spare(max_threads=3, cores=8)  # a big machine, but the campaign asked for 3
    for _ in range(6):
        m2.advance(2.0)
        m2.own_rate = float(s2.poll())
    assert s2.threads == 3 and max(m2.applied) == 3


def test_lease_slots_are_exclusive_freed_by_a_dead_job_and_given_to_a_waiting_one(tmp_path):
    a = T.CoreLease(tmp_path, slots=2)
    b = T.CoreLease(tmp_path, slots=2)
    assert a.take() and a.take() and not a.take()
    assert not b.take()  # flock: another open file description of the same slot
    a.give(1)
    assert b.take() and not b.take()
    a.close()
    b.close()
    # a job that dies holding both slots: the kernel drops its locks
    code = ("import sys, time; sys.path.insert(0, {src!r}); from granflow.engine.threads "
            "import CoreLease; c = CoreLease({d!r}, 2); assert c.take() and c.take(); "
            "print('held', flush=True); time.sleep(60)").format(
        src=os.fspath(T.__file__).rsplit("/granflow/", 1)[0], d=os.fspath(tmp_path))
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        c = T.CoreLease(tmp_path, slots=2)
        assert not c.take()
    finally:
        proc.kill()
        proc.wait()
    assert c.take() and c.take()
    c.close()
    # want files: a live other process counts, a dead one is removed
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / f"want-{dead.pid}").touch()
    assert not c.others_want() and not (tmp_path / f"want-{dead.pid}").exists()
    (tmp_path / f"want-{os.getppid()}").touch()
    assert c.others_want()


def test_a_waiting_job_makes_the_borrower_give_back(tmp_path):
    m = Machine()
    borrower = m.spare(lease_dir=tmp_path)
    m.advance(2.0)
    assert borrower.poll() == 2 and len(borrower.lease.held) == 2
    # a second job of the campaign starts: no free slot, so it asks (its start does not wait here)
    waiting = T.CoreLease(tmp_path, slots=2)
    assert not waiting.take()
    (tmp_path / f"want-{os.getppid()}").touch()  # a live process other than this one
    m.own_rate = 2.0
    m.advance(2.0)
    assert borrower.poll() == 1 and len(borrower.lease.held) == 1
    assert waiting.take()
    (tmp_path / f"want-{os.getppid()}").unlink()
    m.advance(2.0)
    assert borrower.poll() == 1  # no slot left for a second thread, idle or not
    waiting.close()
    m.advance(2.0)
    assert borrower.poll() == 2
    borrower.close()
    assert not any(tmp_path.glob("want-*"))


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two numba threads")
def test_changing_threads_during_a_run_changes_no_number(monkeypatch):
    """A chute whose threads alternate 1, 2, 1, ... every few steps through ChuteRun's tick
    hook ends with the state of a one-thread run, bit for bit."""
    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", 2, raising=False)
    from tests.test_engine_threads import _packing, _state, _assert_same

    from granflow.engine.run import ChuteRun

    nt = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        ref = ChuteRun(_packing(), t_end=400 * 1e-4, sample_every=7)
        ref.system.dt = 1e-4
        ref.run()
        s = _packing()
        s.dt = 1e-4
        run = ChuteRun(s, t_end=400 * 1e-4, sample_every=7)
        used = []

        def toggle():
            numba.set_num_threads(2 if numba.get_num_threads() == 1 else 1)
            used.append(numba.get_num_threads())

        run.tick_hooks.append(toggle)
        run.run()
    finally:
        numba.set_num_threads(nt)
    assert set(used) == {1, 2} and len(used) > 50
    assert ref.system.step_count == run.system.step_count == 400
    _assert_same(_state(ref.system), _state(run.system))


def test_bad_max_threads_is_refused_before_any_compute(monkeypatch, tmp_path):
    from granflow.simulate import simulate

    monkeypatch.setenv(T.ENV_MAX_THREADS, "two")
    with pytest.raises(ValueError, match="GRANFLOW_MAX_THREADS = 'two'.*integer in \\[1, 1024\\]"):
        T.from_environment(1)
    monkeypatch.setenv(T.ENV_MAX_THREADS, "0")
    with pytest.raises(ValueError, match="GRANFLOW_MAX_THREADS = 0.*\\[1, 1024\\]"):
        T.from_environment(1)
    monkeypatch.delenv(T.ENV_MAX_THREADS)
    assert T.from_environment(1) is None  # not asked for: no spare cores
    assert T.from_environment(2, max_threads=2) is None  # nothing beyond the job's threads
    with pytest.raises(ValueError, match="max_threads = -1 is out of range"):
        simulate({"theta": 24.0, "H": 2.0, "Lx": 4.0, "Ly": 4.0, "t_end": 1.0}, tmp_path / "run",
                 max_threads=-1)
    assert not (tmp_path / "run" / "checkpoint.npz").exists()
    assert not list((tmp_path / "run").glob("*.nc"))


@pytest.mark.parametrize("speedup, keeps", [(0.5, False), (1.10, False), (1.20, True), (1.43, True)])
def test_a_borrowed_thread_stays_only_if_it_raises_the_step_rate(speedup, keeps):
    m = Machine()
    eng = Stepper(m, {1: 1000.0, 2: 1000.0 * speedup, 3: 1000.0 * speedup})
    eng.spare = s = m.spare(max_threads=3, cores=4, progress=lambda: eng.steps)
    assert eng.run(2.0) == 2  # idle cores: a thread is taken ...
    after = eng.run(2.0)  # ... and judged on the next interval
    assert s.speedups[2] == pytest.approx(speedup, rel=1e-9)
    if keeps:
        assert after == 3  # it paid; the next idle core is tried too
        assert eng.run(2.0) == 2  # the third thread gave nothing (rate on 3 = rate on 2)
        assert s.ceiling == 2
        for _ in range(5):
            assert eng.run(2.0) == 2
    else:
        assert after == 1 and s.ceiling == 1
        for _ in range(5):  # never tried again, although cores stay idle
            assert eng.run(2.0) == 1
    s.close()
    summary = s.summary()
    assert summary["ceiling"] == s.ceiling
    assert summary["speedup_at_threads"]["2"] == pytest.approx(speedup, abs=1e-3)
    assert sum(s.record.values()) == pytest.approx(m.t)
