"""Where a system beyond the L3 loses: the pair pass's loads replayed with cold caches (issue 15).

On the scaling benchmark's tiled chute (``bench_engine_scaling.py``'s 10 x 5 dense chute tiled
k x k, one thread, 300 steps of run-in) this replays, on the engine's own pair list, near list
and contacts, the loads of two parts of the pair pass, each after a 512 MB read that flushes
the caches (``cold``) and again at once (``warm``):

* the contacts' gather of four velocity rows per particle (vel, omega and the mid-step pair:
  four (n, 3) arrays) against the same values in one packed 16-double row per particle;
* the scan of the near list (positions and radii of both particles of each near pair) through
  pair indices (the engine's ``near`` -> ``pi``, ``pj``) against (i, j) stored in the near list.

Prints ns per particle (and per contact / near pair).  Run it on a quiet machine:

    .venv/bin/python benchmarks/bench_cold_replay.py [--tiles 10 3] [--rounds 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_engine_scaling as S  # noqa: E402
import bench_engine_vs_lammps as B  # noqa: E402


@njit
def flush(big):
    t = 0.0
    for i in range(0, big.shape[0], 8):
        t += big[i]
    return t


@njit
def gather_separate(ci, cj, vel, omega, vh, wh):
    t = 0.0
    for q in range(ci.shape[0]):
        i = ci[q]
        j = cj[q]
        for c in range(3):
            t += (vel[i, c] - vel[j, c] + omega[i, c] + omega[j, c] + vh[i, c] - vh[j, c]
                  + wh[i, c] + wh[j, c])
    return t


@njit
def gather_packed(ci, cj, p):
    t = 0.0
    for q in range(ci.shape[0]):
        i = ci[q]
        j = cj[q]
        for c in range(3):
            t += (p[i, c] - p[j, c] + p[i, 3 + c] + p[j, 3 + c] + p[i, 6 + c] - p[j, 6 + c]
                  + p[i, 9 + c] + p[j, 9 + c])
    return t


@njit(inline="always")
def _touches(pos, rad, i, j):
    """Whether particles i and j overlap (the scan's test; no periodic image: a replay)."""
    dx = pos[i, 0] - pos[j, 0]
    dy = pos[i, 1] - pos[j, 1]
    dz = pos[i, 2] - pos[j, 2]
    rs = rad[i] + rad[j]
    return (dx * dx + dy * dy + dz * dz) < rs * rs


@njit
def scan_by_pair_index(near, pi, pj, pos, rad):
    t = 0
    for k in range(near.shape[0]):
        p = near[k]
        i = pi[p]
        j = pj[p]
        t += _touches(pos, rad, i, j)
    return t


@njit
def scan_direct(ni, nj, pos, rad):
    t = 0
    for k in range(ni.shape[0]):
        i = ni[k]
        j = nj[k]
        t += _touches(pos, rad, i, j)
    return t


def replay(state, k, rounds, big):
    from granflow.engine.lib import kernels as K

    s = S.tiled_system(state, k, k)
    s.step(300)
    n = s.n
    touch = np.flatnonzero(s._pair_array("pstate") == K.CONTACT)
    ci = s.pi[touch].astype(np.int64)
    cj = s.pj[touch].astype(np.int64)
    nn = int(s._pair_array("near_n")[0])
    near = s._pair_array("near")[:nn].copy()
    ni = s.pi[near].copy()
    nj = s.pj[near].copy()
    rng = np.random.default_rng(0)
    rows = [rng.random((n, 3)) for _ in range(4)]
    packed = np.zeros((n, 16))
    for a, r in enumerate(rows):
        packed[:, 3 * a:3 * a + 3] = r
    print(f"N = {n}: listed pairs {len(s.pi) / n:.2f}, near pairs {nn / n:.2f}, contacts "
          f"{len(ci) / n:.2f} per particle")
    cases = {
        "gather, four arrays": (lambda: gather_separate(ci, cj, *rows), len(ci), "contact"),
        "gather, packed row": (lambda: gather_packed(ci, cj, packed), len(ci), "contact"),
        "scan via pair index": (lambda: scan_by_pair_index(near, s.pi, s.pj, s.pos, s.radius),
                                nn, "near pair"),
        "scan, (i, j) direct": (lambda: scan_direct(ni, nj, s.pos, s.radius), nn, "near pair"),
    }
    for f, _, _ in cases.values():
        f()
    best = {name: [np.inf, np.inf] for name in cases}
    for _ in range(rounds):
        for name, (f, _, _) in cases.items():
            flush(big)
            t0 = time.perf_counter()
            f()
            t1 = time.perf_counter()
            f()
            t2 = time.perf_counter()
            best[name][0] = min(best[name][0], t1 - t0)
            best[name][1] = min(best[name][1], t2 - t1)
    for name, (_, m, unit) in cases.items():
        cold, warm = best[name]
        print(f"  {name:22s} cold {1e9 * cold / n:6.2f} ns per particle ({1e9 * cold / m:6.2f} "
              f"per {unit}), warm {1e9 * warm / n:6.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tiles", type=int, nargs="+", default=[10, 3])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args(argv)
    import numba

    numba.set_num_threads(1)
    B.LX, B.LY = S.SMALL_BOX
    state = B.prepare(20.0, 1, False, 10.0, 60.0, 1.0)
    big = np.ones(64_000_000)  # 512 MB
    flush(big)
    for k in args.tiles:
        replay(state, k, args.rounds, big)


if __name__ == "__main__":
    main()
