"""Does the order of the particles in memory set the engine's rate at 1e5 particles? (issue 15)

The scaling benchmark (``bench_engine_scaling.py``) finds granflow's throughput at 1.1e5
particles at 0.70 of its rate at 1.1e3.  If the cause were the distance in memory between a
contact's two particles (the engine's sort puts the mobile particles in (x, y, z) bins of one
diameter, x slowest, so a partner one bin ahead in x lies ~Ly * h particles ahead), an order
with a smaller such distance would run faster.  This benchmark times the same tiled system
(the scaling benchmark's dense 10 x 5 chute, tiled kx x ky) in several orders, each given
before the run with the engine's own re-sort switched off (``sort_min_mobile`` above N), one
thread, the orders interleaved in each round:

- ``engine``: the tiled order, the engine re-sorting as in a run (the reference);
- ``xyz``: the engine's order (x, y, z bins) given up front;
- ``yxz``: y slowest;
- ``morton``, ``hilbert``: the (x, y) columns along a Z-order or Hilbert curve, z within;
- ``long-x`` / ``long-y``: the same number of particles tiled 100 x 1 / 1 x 100 in xyz order,
  where a partner is at most ~250 (long-x) particles ahead.

Prints ns per particle-step (best and median over rounds) and each order's ratio to
``engine`` at the same N, and the 1.1e3 and 1e4 rates for scale.

    .venv/bin/python benchmarks/bench_particle_order.py [--repeat 3] [--tiles 10]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_engine_scaling as S  # noqa: E402
import bench_engine_vs_lammps as B  # noqa: E402


def _part1by1(v):
    v = v.astype(np.int64) & 0xFFFF
    v = (v | (v << 8)) & 0x00FF00FF
    v = (v | (v << 4)) & 0x0F0F0F0F
    v = (v | (v << 2)) & 0x33333333
    return (v | (v << 1)) & 0x55555555


def _hilbert_index(n, x, y):
    """Index along a Hilbert curve over an n x n grid (n a power of two) of cells (x, y)."""
    x = x.astype(np.int64).copy()
    y = y.astype(np.int64).copy()
    d = np.zeros_like(x)
    s = n // 2
    while s > 0:
        rx = ((x & s) > 0).astype(np.int64)
        ry = ((y & s) > 0).astype(np.int64)
        d += s * s * ((3 * rx) ^ ry)
        m = ry == 0
        flip = m & (rx == 1)
        x[flip] = s - 1 - x[flip]
        y[flip] = s - 1 - y[flip]
        t = x[m].copy()
        x[m] = y[m]
        y[m] = t
        s //= 2
    return d


def order(pos, Lx, Ly, kind):
    """Permutation of particles at ``pos``: (x, y) columns of one diameter in the order
    ``kind``, z bins within a column, ties by index."""
    nx, ny = int(Lx), int(Ly)
    ix = np.clip((pos[:, 0] / Lx * nx).astype(np.int64), 0, nx - 1)
    iy = np.clip((pos[:, 1] / Ly * ny).astype(np.int64), 0, ny - 1)
    iz = (pos[:, 2] - pos[:, 2].min()).astype(np.int64)
    if kind == "xyz":
        col = ix * ny + iy
    elif kind == "yxz":
        col = iy * nx + ix
    elif kind == "morton":
        col = _part1by1(ix) | (_part1by1(iy) << 1)
    elif kind == "hilbert":
        n = 1
        while n < max(nx, ny):
            n *= 2
        col = _hilbert_index(n, ix, iy)
    else:
        raise ValueError(kind)
    return np.lexsort((np.arange(len(ix)), iz, col))


def ordered_system(state, kx, ky, kind):
    """The tiled system with its mobile and its fixed particles each in order ``kind``
    (``engine``: tiled order, engine re-sort on; otherwise re-sort off)."""
    s = S.tiled_system(state, kx, ky)
    if kind == "engine":
        return s
    from granflow.engine.system import ParticleSystem
    from granflow.units import RHO_PARTICLE

    fixed = np.asarray(s.fixed, bool)
    parts = []
    for sel in (~fixed, fixed):
        idx = np.flatnonzero(sel)
        parts.append(idx[order(s.pos[idx], s.Lx, s.Ly, kind)])
    perm = np.concatenate(parts)
    t = ParticleSystem(s.Lx, s.Ly, s.interactions, gvec=s.gvec, skin=s.skin)
    t.set_particles(s.pos[perm], 2.0 * s.radius[perm], density=RHO_PARTICLE,
                    ptype=s.ptype[perm], fixed=fixed[perm])
    t.vel[:] = s.vel[perm]
    t.omega[:] = s.omega[perm]
    t.sort_min_mobile = 10 ** 12
    t.initialize()
    return t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tiles", type=int, default=10, help="k: the k x k tiled system")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=3.0, help="work per run (estimate)")
    args = ap.parse_args(argv)
    import numba

    numba.set_num_threads(1)
    B.LX, B.LY = S.SMALL_BOX
    state = B.prepare(20.0, 1, False, 10.0, 60.0, 1.0)
    w = S.tiled_system(state, 1, 1)
    w.step(20)
    k = args.tiles
    cases = [("1x1 engine", 1, 1, "engine"), ("3x3 engine", 3, 3, "engine"),
             (f"{k}x{k} engine", k, k, "engine"), (f"{k}x{k} xyz", k, k, "xyz"),
             (f"{k}x{k} yxz", k, k, "yxz"), (f"{k}x{k} morton", k, k, "morton"),
             (f"{k}x{k} hilbert", k, k, "hilbert"), (f"long-x {k * k}x1 xyz", k * k, 1, "xyz"),
             (f"long-y 1x{k * k} xyz", 1, k * k, "xyz")]
    rows = {c[0]: [] for c in cases}
    nof = {}
    print(f"one thread, {args.repeat} round(s); load {os.getloadavg()[0]:.2f}")
    for r in range(args.repeat):
        for name, kx, ky, kind in cases:
            s = ordered_system(state, kx, ky, kind)
            steps = max(1000, int(args.seconds * 2.0e7 / s.n))
            t0 = time.perf_counter()
            s.step(steps)
            wall = time.perf_counter() - t0
            ns = 1e9 * wall / (s.n * steps)
            rows[name].append(ns)
            nof[name] = s.n
            print(f"  round {r + 1}: {name:22s} N = {s.n:7d} {steps:6d} steps {ns:6.1f} ns per "
                  f"particle-step, {s.n_rebuilds} rebuilds, load {os.getloadavg()[0]:.2f}",
                  flush=True)
    ref = f"{k}x{k} engine"
    print()
    print(f"{'system / order':24s} {'N':>7s} {'best ns/ps':>10s} {'median':>8s} "
          f"{'rate / engine order (best)':>27s}")
    for name, *_ in cases:
        best = min(rows[name])
        ratio = min(rows[ref]) / best if nof[name] == nof[ref] else float("nan")
        print(f"{name:24s} {nof[name]:7d} {best:10.1f} {np.median(rows[name]):8.1f} "
              f"{ratio:27.3f}")


if __name__ == "__main__":
    main()
