"""Cost of each stage of the pair pass on the benchmark chute (issue 15: where a contact's time goes).

Replays the pair pass of ``kernels.pair_pass`` (linear law, one thread) on the prepared dense
chute of ``bench_engine_vs_lammps.py`` (4392 particles after the run-in, skin 0.2) with a
monotonic-clock read around each stage of each block and chunk, ``--reps`` passes per round,
and prints per stage the best round's time per step, per contact and per near pair:

* ``scan``: which near pairs touch (positions and radii gathered by pair index);
* ``compact``: the touching pairs to the front of the block's scratch list;
* ``gather``: the chunk's pair data into the work row (``_gather_linear``);
* ``maths``: the vectorised linear law (``_linear_maths``);
* ``scatter``: results back to the history and, from the work row, added to the particles'
  forces and torques (``_scatter_linear`` as a step that keeps no rows calls it; before
  2026-11-28 the rows were written and a separate ``push`` stage added them).

The replay leaves out the opened contacts (none in a steady dense flow between two steps) and
the per-block bookkeeping; its sum is ~90 % of the profile's pair pass
(``bench_engine_profile.py``).  The history is updated on every pass, as in a run.  Wall clock
(a CPU-time read per chunk would cost more than the stages): run it on a quiet machine.

    .venv/bin/python benchmarks/bench_pair_stages.py [--reps 200] [--rounds 5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numba import njit

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_engine_vs_lammps as B  # noqa: E402
from bench_engine_profile import CLOCK_MONOTONIC, _clock_gettime  # noqa: E402

from granflow.engine.lib import kernels as K  # noqa: E402

STAGES = ("scan", "compact", "gather", "maths", "scatter")


@njit
def _now(buf):
    _clock_gettime(CLOCK_MONOTONIC, buf.ctypes)
    return float(buf[0]) + 1e-9 * float(buf[1])


@njit
def replay(reps, pos, vel, omega, vel_h, omega_h, radius, ptype, Lx, Ly, pi, pj, mred, hist_t,
           hflag, coef, work, dt, near, nnear, ntouch, scratch, crow, cext, ridx, pstate, force,
           torque, acc, buf):
    """``reps`` passes of the pair pass's stages; seconds per stage added to ``acc``.  Returns
    the number of contacts of the last pass."""
    box = (Lx, Ly, 0.5 * Lx, 0.5 * Ly)
    half_Lx = 0.5 * Lx
    half_Ly = 0.5 * Ly
    ncont = 0
    for _ in range(reps):
        ncont = 0
        for b in range((nnear + K.PAIR_BLOCK - 1) // K.PAIR_BLOCK):
            k0 = b * K.PAIR_BLOCK
            k1 = min(k0 + K.PAIR_BLOCK, nnear)
            t0 = _now(buf)
            for k in range(np.uint64(k0), np.uint64(k1)):
                p = near[k]
                i = pi[p]
                j = pj[p]
                dx = K._wrap_select(pos[i, 0] - pos[j, 0], Lx, half_Lx)
                dy = K._wrap_select(pos[i, 1] - pos[j, 1], Ly, half_Ly)
                dz = pos[i, 2] - pos[j, 2]
                r2 = dx * dx + dy * dy + dz * dz
                rsum = radius[i] + radius[j]
                ntouch[k] = r2 < rsum * rsum
            t1 = _now(buf)
            ncu = np.uint64(k0)
            for k in range(np.uint64(k0), np.uint64(k1)):
                p = near[k]
                t = ntouch[k]
                pstate[p] = t
                scratch[ncu] = p
                ncu += np.uint64(t)
            nc = np.int64(ncu)
            t2 = _now(buf)
            acc[0] += t1 - t0
            acc[1] += t2 - t1
            for q0 in range(k0, nc, K.CHUNK):
                m = min(K.CHUNK, nc - q0)
                ta = _now(buf)
                K._gather_linear(work, 0, scratch, q0, m, pos, vel, omega, vel_h, omega_h,
                                 radius, ptype, box, pi, pj, mred, hist_t, coef)
                tb = _now(buf)
                K._linear_maths(work, 0, m, dt, True)
                tc = _now(buf)
                K._scatter_linear(work, 0, scratch, q0, m, True, crow, cext, ridx, pstate,
                                  hist_t, hflag, k0, False, True, pi, pj, force, torque, 0.0)
                td = _now(buf)
                acc[2] += tb - ta
                acc[3] += tc - tb
                acc[4] += td - tc
            ncont += nc - k0
    return ncont


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=200, help="pair passes per round")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=300, help="steps of run-in before the replay")
    args = ap.parse_args(argv)
    import numba

    numba.set_num_threads(1)
    state = B.prepare(20.0, 1, False, 10.0, 60.0, 1.0)
    ref = B.paper_species()
    fb, _ = B.matched_species(ref)
    s = B.make_system(state, ref, fb)
    s.step(args.steps)
    pair = dict(zip(K.PAIR_ARRAYS, s._pair))
    law_tab, coef, all_linear = s._coefficients()
    if not all_linear:
        raise SystemExit("the benchmark chute is not all-linear: nothing to replay")
    nnear = int(pair["near_n"][0])
    data = (s.pos, s.vel, s.omega, s.vel.copy(), s.omega.copy(), s.radius, s.ptype, s.Lx, s.Ly,
            s.pi, s.pj, pair["mred"], s.hist_t.copy(), pair["hflag"].copy(), coef, s._work, s.dt,
            pair["near"], nnear, pair["ntouch"].copy(), pair["scratch"].copy(),
            pair["crow"].copy(), pair["cext"].copy(), pair["ridx"].copy(),
            pair["pstate"].copy(), s.force.copy(), s.torque.copy())
    buf = np.zeros(2, np.int64)
    acc = np.zeros(len(STAGES))
    replay(2, *data, acc, buf)  # compile, warm the caches
    best = np.full(len(STAGES), np.inf)
    for _ in range(args.rounds):
        acc[:] = 0.0
        ncont = replay(args.reps, *data, acc, buf)
        best = np.minimum(best, acc / args.reps * 1e6)
    print(f"pair-pass stages (replay, 1 thread, wall clock, best of {args.rounds} rounds of "
          f"{args.reps} passes): N = {s.n}, {nnear} near pairs, {ncont} contacts")
    print(f"{'stage':8s} {'us/step':>8s} {'ns/contact':>11s} {'ns/near pair':>13s}")
    for name, v in zip(STAGES, best):
        print(f"{name:8s} {v:8.1f} {1e3 * v / ncont:11.1f} {1e3 * v / nnear:13.2f}")
    print(f"{'sum':8s} {best.sum():8.1f} {1e3 * best.sum() / ncont:11.1f}")


if __name__ == "__main__":
    main()
