"""Spare cores for a running chute: more numba threads while the machine has idle cores.

A campaign on a laptop (``snakemake --cores 2``) runs one job per core, but its tail -- the
last runs, a sequential hstop bisection chain -- leaves cores idle.  The engine's results do
not depend on the number of threads (the pair pass sums every particle's forces in the serial
order; ``tests/test_engine_threads.py``), so a run may change its thread count *while it
runs* without changing a single bit of its output.  :class:`SpareCores` does that: polled by
:class:`~granflow.engine.run.ChuteRun` every ``interval_s`` of wall time, it

* measures the CPU that *other* processes used since the last poll (the machine's busy time
  from ``/proc/stat`` minus this process's own CPU time), so a run never takes a core that
  someone else -- another job, a fit, the user's own work -- is using;
* takes an extra thread when a whole core has been idle (``spare >= TAKE``) and gives its
  extra threads back as soon as another process needs them (``others > cores - threads +
  GIVE``: the machine is oversubscribed);
* holds one lock file per thread in a lease folder shared by the campaign's jobs (``slot-K``,
  ``fcntl.flock``; released by the kernel when a process dies), so the jobs of one campaign
  together never run more threads than its ``--cores``; a job that finds no free slot at
  its start writes ``want-<pid>`` and every borrower gives its extra threads back at once;
* keeps a borrowed thread only if it pays: the run's steps per wall second over the first
  interval on the new count must beat the interval before it by ``PAYS``, or the thread goes
  back and the run stays below that count to its end.  Threads do not pay on small systems:
  the default campaign's 600-particle chute ran at half its one-thread speed on two threads
  (88 s -> 178 s wall, 4x the CPU), a 2400-particle one at 0.9x, the dense 4405-particle
  benchmark chute (bench_engine_threads.py) 1.43x faster.

Nothing here changes a number: the thread count is recorded (wall seconds per count) in the
run's ``simulate.log`` only, so every output file stays identical.  Off on Slurm (a job's
cores are its allocation) and where ``/proc/stat`` or ``fcntl`` are missing (the run keeps its
threads).
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

log = logging.getLogger(__name__)

#: take another thread when this many cores were idle over the last interval
TAKE = 0.75
#: give extra threads back when other processes used this much more than the free cores
GIVE = 0.35
#: a borrowed thread stays only if the step rate on it is at least this times the rate before
PAYS = 1.15
#: environment variables through which the workflow hands a job its campaign's cores
ENV_MAX_THREADS = "GRANFLOW_MAX_THREADS"
ENV_LEASE = "GRANFLOW_CORE_LEASE"


def proc_stat_busy() -> float | None:
    """Busy CPU seconds of the whole machine since boot (Linux ``/proc/stat``), or None."""
    try:
        with open("/proc/stat") as fh:
            fields = fh.readline().split()
    except OSError:
        return None
    if not fields or fields[0] != "cpu":
        return None
    ticks = [int(x) for x in fields[1:]]
    idle = ticks[3] + (ticks[4] if len(ticks) > 4 else 0)  # idle + iowait
    # guest time is already counted in user/nice
    busy = sum(ticks[:8]) - idle
    return busy / os.sysconf("SC_CLK_TCK")


def own_cpu() -> float:
    """CPU seconds of this process (all its threads)."""
    t = os.times()
    return t.user + t.system


def machine_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover (not Linux)
        return os.cpu_count() or 1


class CoreLease:
    """One lock file per thread in a folder shared by the jobs of a campaign."""

    def __init__(self, folder, slots: int):
        import fcntl  # noqa: F401  (ImportError off POSIX: the caller disables borrowing)

        self.folder = Path(folder)
        self.slots = int(slots)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.held: dict[int, int] = {}  # slot -> fd
        self.want = self.folder / f"want-{os.getpid()}"

    def take(self) -> bool:
        """Lock one more free slot; False when all are held."""
        import fcntl

        for k in range(self.slots):
            if k in self.held:
                continue
            fd = os.open(self.folder / f"slot-{k}", os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                continue
            self.held[k] = fd
            return True
        return False

    def give(self, keep: int):
        """Release held slots until ``keep`` remain."""
        for k in sorted(self.held, reverse=True):
            if len(self.held) <= keep:
                break
            os.close(self.held.pop(k))  # closing the descriptor drops its flock

    def set_wanting(self, wanting: bool):
        if wanting:
            self.want.touch()
        else:
            self.want.unlink(missing_ok=True)

    def others_want(self) -> bool:
        """True when another live job waits for a slot (stale want files are removed)."""
        for f in self.folder.glob("want-*"):
            try:
                pid = int(f.name[5:])
            except ValueError:
                continue
            if pid == os.getpid():
                continue
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                f.unlink(missing_ok=True)
                continue
            except PermissionError:
                pass
            return True
        return False

    def close(self):
        self.give(0)
        self.set_wanting(False)


class SpareCores:
    """Adjust a run's numba threads, between ``base`` and ``max_threads``, to the idle cores.

    ``busy``/``own``/``clock``/``apply`` are injectable for tests (machine busy seconds, own
    CPU seconds, wall clock, thread setter).  ``record`` holds wall seconds per thread count.
    """

    def __init__(self, max_threads: int, base: int = 1, lease_dir=None, interval_s: float = 2.0,
                 cores: int | None = None, busy=proc_stat_busy, own=own_cpu,
                 clock=time.monotonic, apply=None, wait_s: float = 10.0, progress=None):
        import numba

        self.base = max(1, int(base))
        self.max_threads = max(self.base, min(int(max_threads), numba.config.NUMBA_NUM_THREADS))
        self.cores = int(cores or machine_cores())
        self.interval_s = float(interval_s)
        self.busy, self.own, self.clock = busy, own, clock
        self.apply = apply or numba.set_num_threads
        self.threads = self.base
        self.record: dict[int, float] = {}
        self.enabled = self.max_threads > self.base and self.busy() is not None
        self.lease = None
        if self.enabled and lease_dir is not None:
            try:
                self.lease = CoreLease(lease_dir, self.max_threads)
            except (ImportError, OSError) as exc:  # no fcntl, unwritable folder
                log.info("spare cores: no lease folder (%s); measuring idle cores only", exc)
        self._wait_s = float(wait_s)
        self._last = None
        # steps done so far (e.g. the system's step count): the borrowed thread must pay
        self.progress = progress
        self.ceiling = self.max_threads  # lowered when a count did not pay
        self.speedups: dict[int, float] = {}  # rate on K threads / rate on K - 1 (trials)
        self._steps = None
        self._trial = None  # (threads, rate before the thread was taken)

    # ---------------------------------------------------------------- lifecycle
    def start(self):
        """Take the base slots (waiting up to ``wait_s`` for borrowers to give theirs back)."""
        self.apply(self.threads)
        now = self.clock()
        self._last = (now, self.busy() if self.enabled else None, self.own())
        self._since = now
        self._steps = self.progress() if self.progress is not None else None
        if self.lease is None:
            return self
        deadline = now + self._wait_s
        while len(self.lease.held) < self.base:
            if self.lease.take():
                continue
            self.lease.set_wanting(True)
            if self.clock() >= deadline:
                log.info("spare cores: no free slot in %s; running on without one",
                         self.lease.folder)
                break
            time.sleep(0.25)
        if len(self.lease.held) >= self.base:
            self.lease.set_wanting(False)
        return self

    def close(self):
        self._account(self.clock())
        if self.lease is not None:
            self.lease.close()

    def _account(self, now):
        if self._last is not None:
            self.record[self.threads] = self.record.get(self.threads, 0.0) + now - self._since
            self._since = now

    def _set(self, threads: int, now):
        if threads != self.threads:
            self._account(now)
            log.info("spare cores: %d -> %d threads", self.threads, threads)
            self.threads = threads
            self.apply(threads)

    # ---------------------------------------------------------------- polling
    def poll(self):
        """Called often (cheap when the interval has not passed); may change the threads."""
        if not self.enabled:
            return self.threads
        now = self.clock()
        t0, busy0, own0 = self._last
        if now - t0 < self.interval_s:
            return self.threads
        busy, own = self.busy(), self.own()
        self._last = (now, busy, own)
        dt = now - t0
        others = max(0.0, ((busy - busy0) - (own - own0)) / dt)
        rate = None  # steps per wall second over the interval (all of it on self.threads)
        if self.progress is not None:
            steps = self.progress()
            rate = (steps - self._steps) / dt
            self._steps = steps
        lease = self.lease
        if lease is not None and len(lease.held) < self.base:  # still waiting for a slot
            if lease.take():
                lease.set_wanting(False)
        if self._trial is not None and rate is not None:
            tried, before = self._trial
            self._trial = None
            if self.threads == tried and before > 0:
                self.speedups[tried] = round(rate / before, 3)
                if rate < PAYS * before:  # the thread did not pay: back, and not again
                    log.info("spare cores: %d threads ran at %.2f x the speed on %d; staying "
                             "below %d", tried, rate / before, tried - 1, tried)
                    self.ceiling = tried - 1
                    if lease is not None:
                        lease.give(max(self.base, tried - 1))
                    self._set(tried - 1, now)
                    return self.threads
        if self.threads > self.base and (others > self.cores - self.threads + GIVE
                                         or (lease is not None and lease.others_want())):
            if lease is not None:
                lease.give(self.base)
            self._set(self.base, now)
        elif (self.threads < min(self.max_threads, self.ceiling)
              and self.cores - others - self.threads >= TAKE
              and (lease is None or not lease.others_want())):
            if lease is None or lease.take():
                if rate is not None:
                    self._trial = (self.threads + 1, rate)
                self._set(self.threads + 1, now)
        return self.threads

    def summary(self) -> dict:
        """Wall seconds and measured speed-up per thread count (JSON keys: strings), and the
        count the run stayed below after a thread did not pay."""
        return {"max_threads": self.max_threads, "enabled": self.enabled,
                "wall_s_at_threads": {str(k): round(v, 3) for k, v in sorted(self.record.items())},
                "speedup_at_threads": {str(k): v for k, v in sorted(self.speedups.items())},
                "ceiling": self.ceiling}


def from_environment(threads: int, max_threads: int | None = None, lease_dir=None):
    """A :class:`SpareCores` from the arguments or the workflow's environment, or None."""
    if max_threads is None:
        env = os.environ.get(ENV_MAX_THREADS, "").strip()
        try:
            max_threads = int(env) if env else None
        except ValueError:
            raise ValueError(f"{ENV_MAX_THREADS} = {env!r} is out of range: allowed an integer "
                             "in [1, 1024]") from None
        where = ENV_MAX_THREADS
    else:
        where = "max_threads"
    if max_threads is not None and not 1 <= int(max_threads) <= 1024:
        raise ValueError(f"{where} = {max_threads!r} is out of range: allowed [1, 1024]")
    if lease_dir is None:
        lease_dir = os.environ.get(ENV_LEASE) or None
    if max_threads is None or max_threads <= (threads or 1):
        return None
    spare = SpareCores(max_threads, base=threads or 1, lease_dir=lease_dir)
    return spare if spare.enabled else None
