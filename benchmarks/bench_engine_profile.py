"""Per-step profile of the granflow engine on the LAMMPS benchmark's dense chute (issue 15).

Runs the prepared state of ``bench_engine_vs_lammps.py`` (4405 particles, theta = 24 deg,
skin 0.2, dt = 1e-4; prepared on first use) through a copy of the engine's step loop written in
numba with a clock read (``clock_gettime`` through ctypes, ~25 ns) between its parts, and prints
the time per step of each part:

* ``pair_forces``: the contact kernel over the listed pairs (and the flat wall, if any);
* ``accumulate``: summing the per-pair rows into per-particle forces and torques;
* ``integrate``: velocity-Verlet kicks, drift and the predicted velocity;
* ``rebuild``: neighbour list (``hgrid_pairs``) and contact-history transfer;
* ``max_displacement``: the Verlet-skin check (measured displacements, only when a bound
  sum dt max|v| crosses a threshold).

Where the engine fuses parts into one pass, the table says so (one row for the fused pass).
The profiled loop does what ``kernels.advance`` does, in the same order, so its total is the
engine's time per step plus ~10 clock reads; the script checks that the profiled loop ends in
the state that ``ParticleSystem.step`` reaches (bit for bit).

    .venv/bin/python benchmarks/bench_engine_profile.py [--steps 10000] [--threads 1]
        [--repeat 3]

Works against older engine versions too (the "legacy" loop, chosen automatically when the
engine lacks ``kernels.STEP_API``), so a "before" table is made with the old source on
``PYTHONPATH``::

    git archive <commit> | tar -x -C /tmp/gf_old
    PYTHONPATH=/tmp/gf_old/src .venv/bin/python benchmarks/bench_engine_profile.py
"""

from __future__ import annotations

import argparse
import ctypes
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np
from numba import njit

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_engine_vs_lammps as B  # noqa: E402
from granflow.engine.lib import kernels as K  # noqa: E402
from granflow.engine.lib.hgrid import hgrid_pairs  # noqa: E402

_libc = ctypes.CDLL(None)
_clock_gettime = _libc.clock_gettime
_clock_gettime.argtypes = [ctypes.c_int, ctypes.c_void_p]
_clock_gettime.restype = ctypes.c_int
CLOCK_MONOTONIC = 1
CLOCK_PROCESS_CPUTIME_ID = 2


def _threads_asked(argv) -> int:
    """The ``--threads`` value on the command line (1 if absent or not a number: ``main``'s
    parser reports it): the clock is fixed at import, before the numba loop compiles with it."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--threads", default="1")
    v = pre.parse_known_args(argv)[0].threads
    return int(v) if v.isdigit() else 1


#: clock of the profile (``GRANFLOW_PROFILE_CLOCK=cpu|wall``): by default the process's CPU time
#: at one thread (robust on a shared machine) and the wall clock at more (CPU time adds up the
#: threads: a two-thread pass would read as twice its duration)
_CLOCK_NAME = os.environ.get("GRANFLOW_PROFILE_CLOCK") or (
    "cpu" if _threads_asked(sys.argv[1:]) <= 1 else "wall")
if _CLOCK_NAME not in ("cpu", "wall"):
    raise SystemExit(f"GRANFLOW_PROFILE_CLOCK must be cpu or wall, not {_CLOCK_NAME!r}")
CLOCK = CLOCK_PROCESS_CPUTIME_ID if _CLOCK_NAME == "cpu" else CLOCK_MONOTONIC


#: run the pair pass in this many runs of blocks (``--slots``; default: the number of threads),
#: e.g. the two-thread split on one thread, to see the cost of the split itself
FORCE_SLOTS = 0
#: the engine balances the pair pass's runs of blocks (``kernels.split_runs``; since 2026-11-24)
BALANCED = hasattr(K, "split_runs")
#: the engine keeps large systems in spatial order (``kernels.sort_particles``; 2026-11-25)
SORTS = hasattr(K, "sort_particles")


@njit
def _no_sort(pos, vel, omega, vel_p, omega_p, force, torque, radius, inv_mass, mass, inv_inertia,
             inertia, ptype, fixed, ids, level_of, wall_hist, wall_dmax, wall_rows, wall_state,
             Lx, Ly, pi, pj, hist_t, hist_dmax):
    return pi, pj, hist_t, hist_dmax


_sort_particles = K.sort_particles if SORTS else _no_sort
#: the pair pass keeps the rows of steps nobody reads in block buffers (2026-11-25)
LOCAL_ROWS = "keep_rows" in K.pair_pass.py_func.__code__.co_varnames
#: the particle pass adds the rows of the pair pass's runs 1... itself (no serial push_rows)
PUSH_IN_PARTICLE_PASS = "push" in K.particle_pass.py_func.__code__.co_varnames
_timer = time.process_time if CLOCK == CLOCK_PROCESS_CPUTIME_ID else time.perf_counter


@njit
def _now(buf):
    _clock_gettime(CLOCK, buf.ctypes)
    return float(buf[0]) + 1e-9 * float(buf[1])


# categories (columns of ``acc``)
PAIR, ACC, INTEG, REBUILD, DISP, NEAR, NCAT = 0, 1, 2, 3, 4, 5, 6
CATS = ("pair_forces", "accumulate", "integrate", "rebuild", "max_displacement", "near list")


# ------------------------------------------------------------------------------ legacy engine
@njit
def _legacy_loop(nsteps, pos, vel, omega, force, torque, radius, inv_mass, mass, inv_inertia,
                 ptype, fixed, Lx, Ly, gvec, pi, pj, hist_t, hist_dmax, pos_ref, skin, level_of,
                 level_cell, use_wall, wall_type, wall_hist, wall_dmax, law_tab, kn_tab, gn_tab,
                 kt_tab, gt_tab, mu_tab, k2_tab, dt, pair_out, wall_out, buf, acc):
    """``kernels.advance`` of the engine before issue 15 with clock reads."""
    half_skin2 = 0.25 * skin * skin
    vel_p = np.empty_like(vel)
    omega_p = np.empty_like(omega)
    for step in range(nsteps):
        t0 = _now(buf)
        K._half_kick(vel, omega, force, torque, inv_mass, inv_inertia, dt)
        K._drift(pos, vel, inv_mass, Lx, Ly, dt)
        K._predict_velocity(vel, omega, force, torque, inv_mass, inv_inertia, dt, vel_p, omega_p)
        t1 = _now(buf)
        disp2 = K.max_displacement_sq(pos, pos_ref, Lx, Ly)
        t2 = _now(buf)
        acc[INTEG] += t1 - t0
        acc[DISP] += t2 - t1
        if disp2 > half_skin2:
            npi, npj = hgrid_pairs(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell)
            nt, nd = K.transfer_history(pi, pj, hist_t, hist_dmax, npi, npj, pos.shape[0])
            pi = npi
            pj = npj
            hist_t = nt
            hist_dmax = nd
            pair_out = np.zeros((pi.shape[0], K.NOUT))
            pos_ref[:, :] = pos
            t3 = _now(buf)
            acc[REBUILD] += t3 - t2
            t2 = t3
        K.pair_forces(pos, vel_p, omega_p, vel, omega, radius, inv_mass, ptype, Lx, Ly, pi, pj,
                      hist_t, hist_dmax, law_tab, kn_tab, gn_tab, kt_tab, gt_tab, mu_tab, k2_tab,
                      dt, True, pair_out)
        if use_wall:
            K.wall_forces(pos, vel_p, omega_p, vel, omega, radius, inv_mass, ptype, wall_type,
                          wall_hist, wall_dmax, law_tab, kn_tab, gn_tab, kt_tab, gt_tab, mu_tab,
                          k2_tab, dt, True, wall_out)
        t4 = _now(buf)
        K.accumulate_forces(inv_mass, mass, gvec, pi, pj, pair_out, use_wall, wall_out, force,
                            torque)
        t5 = _now(buf)
        K._half_kick(vel, omega, force, torque, inv_mass, inv_inertia, dt)
        t6 = _now(buf)
        acc[PAIR] += t4 - t2
        acc[ACC] += t5 - t4
        acc[INTEG] += t6 - t5
    return pi, pj, hist_t, hist_dmax


def legacy_profile(s, nsteps):
    acc = np.zeros(NCAT)
    buf = np.zeros(2, np.int64)
    s._cache_inverse()
    t0 = _timer()
    s.pi, s.pj, s.hist_t, s.hist_dmax = _legacy_loop(
        nsteps, s.pos, s.vel, s.omega, s.force, s.torque, s.radius, s._inv_mass, s.mass,
        s._inv_inertia, s.ptype, s.fixed, s.Lx, s.Ly, s.gvec, s.pi, s.pj, s.hist_t, s.hist_dmax,
        s.pos_ref, s.skin, s._level_of, s._level_cell, s.use_wall, s.wall_type, s.wall_hist,
        s.wall_dmax, *s.tables, s.dt, s.pair_out, s.wall_out, buf, acc)
    wall = _timer() - t0
    return acc, wall, {}


# ------------------------------------------------------------------------------ main
def profile(state, nsteps, new_api):
    ref = B.paper_species()
    fb, _ = B.matched_species(ref)
    s = B.make_system(state, ref, fb)
    fn = new_profile if new_api else legacy_profile
    acc, wall, labels = fn(s, nsteps)
    # the profiled loop must reach the state that the engine's own stepping reaches
    t = B.make_system(state, ref, fb)
    t0 = _timer()
    t.step(nsteps)
    engine_wall = _timer() - t0
    same = all(np.array_equal(getattr(s, k), getattr(t, k))
               for k in ("pos", "vel", "omega", "ids") if hasattr(t, k))
    return acc, wall, engine_wall, same, labels


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--H", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--slots", type=int, default=0,
                    help="runs of blocks of the pair pass (default: the number of threads)")
    args = ap.parse_args(argv)
    global FORCE_SLOTS
    FORCE_SLOTS = args.slots
    import numba

    numba.set_num_threads(args.threads)
    state = B.prepare(args.H, args.seed, False, 10.0, 60.0, 1.0)
    new_api = hasattr(K, "STEP_API")
    print(f"clock: {'process CPU time' if CLOCK == CLOCK_PROCESS_CPUTIME_ID else 'wall'} "
          "(GRANFLOW_PROFILE_CLOCK=cpu|wall)")
    print(f"engine: {Path(K.__file__).parent.parent.parent.parent} "
          f"({'issue-15 step loop' if new_api else 'legacy step loop'}), {args.threads} thread(s), "
          f"{args.steps} steps x {args.repeat} repeats")
    profile(state, 50, new_api)  # compile
    rows = []
    for rep in range(args.repeat):
        load = os.getloadavg()[0]
        acc, wall, engine_wall, same, labels = profile(state, args.steps, new_api)
        rows.append((acc, wall, engine_wall, same, load))
        print(f"  repeat {rep + 1}: profiled loop {wall / args.steps * 1e6:.1f} us/step, "
              f"engine step() {engine_wall / args.steps * 1e6:.1f} us/step, same final state: "
              f"{same}, load average {load:.2f}", flush=True)
    best = min(rows, key=lambda r: r[1])
    acc, wall = best[0], best[1]
    n = len(state["diameter"])
    print()
    print(f"per-step profile (repeat with the fastest profiled loop; N = {n}, "
          f"{args.threads} thread(s), load average {best[4]:.2f})")
    print(f"{'part':<34} {'us/step':>8} {'share':>6}")
    for k, name in enumerate(CATS):
        label = labels.get(name, name)
        if label is None or (name == "near list" and not new_api):
            continue
        print(f"{label:<34} {acc[k] / args.steps * 1e6:8.1f} {acc[k] / wall:6.1%}")
    other = wall - acc.sum()
    print(f"{'(loop, clock reads, rest)':<34} {other / args.steps * 1e6:8.1f} {other / wall:6.1%}")
    print(f"{'total':<34} {wall / args.steps * 1e6:8.1f} "
          f"({n * args.steps / wall:.3g} particle-steps/s; engine step(): "
          f"{n * args.steps / best[2]:.3g})")
    if not all(r[3] for r in rows):
        raise SystemExit("the profiled loop did not reproduce ParticleSystem.step bit for bit")


# ------------------------------------------------------------------------------ issue-15 engine
@njit
def _new_loop(nsteps, pos, vel, omega, force, torque, radius, inv_mass, mass, inv_inertia, ptype,
              fixed, Lx, Ly, gvec, pi, pj, hist_t, hist_dmax, hflag, mred, crow, cext, ridx, prel,
              pstate, scratch, blk_pair_overlap, blk_pair_erel, blk_pair_nc, near_tmp,
              near_count, near, near_n, ntouch, near_ref, near_ok, pos_ref, skin, level_of,
              level_cell, use_wall, wall_type, wall_hist, wall_dmax, wall_rows, wall_state,
              law_tab, coef, all_linear, work, dt, nslots, buf, acc, inertia, ids, sort_min,
              sort_every):
    """``kernels.advance`` (issue 15) with clock reads; the guards are left out.  The spatial
    sort of large systems (``kernels.sort_particles``, where the engine has it) counts as part
    of the rebuild."""
    n = pos.shape[0]
    nblock = (n + K.PARTICLE_BLOCK - 1) // K.PARTICLE_BLOCK
    blk_overlap = np.zeros(nblock)
    blk_erel = np.zeros(nblock)
    blk_bad = np.zeros(nblock, dtype=np.bool_)
    blk_disp = np.zeros(nblock)
    blk_disp_near = np.zeros(nblock)
    half_skin = 0.5 * skin
    near_skin = K.NEAR_FRACTION * skin
    half_near = 0.5 * near_skin
    vel_p = np.empty_like(vel)
    omega_p = np.empty_like(omega)
    run_start = np.empty(nslots + 1, dtype=np.int64)
    n_mobile = 0
    while n_mobile < n and not fixed[n_mobile]:
        n_mobile += 1
    nreb = 0
    lrow = np.empty((work.shape[0], K.PAIR_BLOCK, 9))
    lext = np.empty((work.shape[0], K.PAIR_BLOCK, 3))
    _T = np.bool_(True)  # run-time flags where the engine has them (one specialisation)
    _F = np.bool_(False)
    serial = np.bool_(nslots == 1)  # as kernels.advance: one thread, no parallel region
    t0 = _now(buf)
    if PUSH_IN_PARTICLE_PASS:
        K.particle_pass(_F, _F, _F, _T, _F, pos, vel, omega, vel_p, omega_p, force,
                        torque, radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec, dt,
                        use_wall, wall_type, wall_hist, wall_dmax, wall_rows, wall_state, law_tab,
                        coef, pos_ref, blk_overlap, blk_erel, blk_bad, blk_disp, near_ref,
                        blk_disp_near, serial, _F, run_start, near, near_n, pi, pj, crow, pstate,
                        scratch, blk_pair_nc)
    else:
        K.particle_pass(_F, _F, _F, _T, _F, pos, vel, omega, vel_p, omega_p, force,
                        torque, radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec, dt,
                        use_wall, wall_type, wall_hist, wall_dmax, wall_rows, wall_state, law_tab,
                        coef, pos_ref, blk_overlap, blk_erel, blk_bad, blk_disp, near_ref,
                        blk_disp_near, serial)
    acc[INTEG] += _now(buf) - t0
    bound, bound_near = K._exact_displacements(pos, pos_ref, near_ref, Lx, Ly, blk_disp,
                                               blk_disp_near, serial)
    for step in range(nsteps):
        t0 = _now(buf)
        if bound > half_skin or bound_near > half_near:  # measured only when a bound crosses
            bound, bound_near = K._exact_displacements(pos, pos_ref, near_ref, Lx, Ly, blk_disp,
                                                       blk_disp_near, serial)
        t1 = _now(buf)
        acc[DISP] += t1 - t0
        if bound > half_skin:
            if SORTS and n_mobile >= sort_min and nreb % sort_every == 0:
                pi, pj, hist_t, hist_dmax = _sort_particles(
                    pos, vel, omega, vel_p, omega_p, force, torque, radius, inv_mass, mass,
                    inv_inertia, inertia, ptype, fixed, ids, level_of, wall_hist, wall_dmax,
                    wall_rows, wall_state, Lx, Ly, pi, pj, hist_t, hist_dmax)
            nreb += 1
            pi, pj, hist_t, hist_dmax = K.rebuild_pairs(pos, radius, fixed, Lx, Ly, skin,
                                                        level_of, level_cell, pi, pj, hist_t,
                                                        hist_dmax)
            (hflag, mred, crow, cext, ridx, prel, pstate, scratch, blk_pair_overlap,
             blk_pair_erel, blk_pair_nc, near_tmp, near_count, near, near_n, ntouch, near_ref,
             near_ok) = K.pair_index(pi, pj, hist_t, inv_mass, n)
            pos_ref[:, :] = pos
            bound = 0.0
            t2 = _now(buf)
            acc[REBUILD] += t2 - t1
            t1 = t2
        if near_ok[0] == 0 or bound_near > half_near:
            K.near_pass(pos, radius, hflag, Lx, Ly, pi, pj, near_skin, near_tmp, near_count,
                        pstate, serial)
            K.near_index(near_tmp, near_count, near, near_n)
            near_ref[:, :] = pos
            near_ok[0] = 1
            bound_near = 0.0
            t2 = _now(buf)
            acc[NEAR] += t2 - t1
            t1 = t2
        if LOCAL_ROWS:
            K.split_runs(near_n[0], blk_pair_nc, nslots, run_start)
            K.pair_pass(pos, vel_p, omega_p, vel, omega, radius, ptype, Lx, Ly, pi, pj, mred,
                        hist_t, hist_dmax, hflag, law_tab, coef, all_linear, work, dt, _T, crow,
                        cext, ridx, prel, pstate, scratch, blk_pair_overlap, blk_pair_erel,
                        blk_pair_nc, run_start, force, torque, near, near_n, ntouch,
                        step + 1 == nsteps, lrow, lext)
            b1 = run_start[1]
        elif BALANCED:
            K.split_runs(near_n[0], blk_pair_nc, nslots, run_start)
            K.pair_pass(pos, vel_p, omega_p, vel, omega, radius, ptype, Lx, Ly, pi, pj, mred,
                        hist_t, hist_dmax, hflag, law_tab, coef, all_linear, work, dt, True, crow,
                        cext, ridx, prel, pstate, scratch, blk_pair_overlap, blk_pair_erel,
                        blk_pair_nc, run_start, force, torque, near, near_n, ntouch)
            b1 = run_start[1]
        else:
            K.pair_pass(pos, vel_p, omega_p, vel, omega, radius, ptype, Lx, Ly, pi, pj, mred,
                        hist_t, hist_dmax, hflag, law_tab, coef, all_linear, work, dt, True, crow,
                        cext, ridx, prel, pstate, scratch, blk_pair_overlap, blk_pair_erel,
                        blk_pair_nc, nslots, force, torque, near, near_n, ntouch)
            b1 = (near_n[0] + K.PAIR_BLOCK - 1) // K.PAIR_BLOCK // nslots
        if not PUSH_IN_PARTICLE_PASS:
            K.push_rows(b1, near_n[0], pi, pj, crow, pstate, scratch, blk_pair_nc, force,
                        torque)
        t2 = _now(buf)
        if PUSH_IN_PARTICLE_PASS:  # the rows of runs 1... added in the particle pass
            K.particle_pass(False, True, True, step + 1 < nsteps, False, pos, vel, omega, vel_p,
                            omega_p, force, torque, radius, inv_mass, mass, inv_inertia, ptype,
                            Lx, Ly, gvec, dt, use_wall, wall_type, wall_hist, wall_dmax,
                            wall_rows, wall_state, law_tab, coef, pos_ref, blk_overlap, blk_erel,
                            blk_bad, blk_disp, near_ref, blk_disp_near, serial, True, run_start,
                            near, near_n, pi, pj, crow, pstate, scratch, blk_pair_nc)
        else:
            K.particle_pass(False, True, True, step + 1 < nsteps, False, pos, vel, omega, vel_p,
                            omega_p, force, torque, radius, inv_mass, mass, inv_inertia, ptype,
                            Lx, Ly, gvec, dt, use_wall, wall_type, wall_hist, wall_dmax,
                            wall_rows, wall_state, law_tab, coef, pos_ref, blk_overlap, blk_erel,
                            blk_bad, blk_disp, near_ref, blk_disp_near, serial)
        step_len = dt * np.sqrt(K._block_max(blk_disp)) + K.BOUND_SLACK
        bound += step_len
        bound_near += step_len
        t3 = _now(buf)
        acc[PAIR] += t2 - t1
        acc[ACC] += t3 - t2
    return pi, pj, hist_t, hist_dmax


def new_profile(s, nsteps):
    acc = np.zeros(NCAT)
    buf = np.zeros(2, np.int64)
    s._cache_inverse()
    s._index_pairs()
    t0 = _timer()
    s.pi, s.pj, s.hist_t, s.hist_dmax = _new_loop(
        nsteps, s.pos, s.vel, s.omega, s.force, s.torque, s.radius, s._inv_mass, s.mass,
        s._inv_inertia, s.ptype, s.fixed, s.Lx, s.Ly, s.gvec, s.pi, s.pj, s.hist_t, s.hist_dmax,
        *s._pair, s.pos_ref, s.skin, s._level_of, s._level_cell, s.use_wall, s.wall_type,
        s.wall_hist, s.wall_dmax, s.wall_rows, s.wall_state, *s._coefficients(), s._work, s.dt,
        numba.get_num_threads() if not FORCE_SLOTS else FORCE_SLOTS, buf, acc, s.inertia,
        s.ids if SORTS else np.zeros(0, np.int64), getattr(s, "sort_min_mobile", 0),
        getattr(s, "sort_every", 1))
    wall = _timer() - t0
    labels = {"pair_forces": "pair pass (contacts + sums)",
              "accumulate": "particle pass (kicks+drift+wall+disp)",
              "near list": "near list (rebuild)",
              "integrate": "first opening kick/drift (once)",
              "max_displacement": "max_displacement (block maxima)"}
    return acc, wall, labels


if __name__ == "__main__":
    main()
