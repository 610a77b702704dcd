"""Engine throughput against the number of particles, and memory per particle (issue 15).

Prepares (once, cached in ``benchmarks/_work/``) a dense flowing chute in a 10 x 5 box with the
protocol of ``bench_engine_vs_lammps.py`` (theta = 24 deg, lambda = 1, H = 20: ~1000 flow +
~100 base particles, the paper's species, skin 0.2, dt = 1e-4), then tiles it kx x ky times in
the periodic x, y directions (an exact periodic image of the same flow) to get N from ~1.1e3 to
~1.1e5, and times ``ParticleSystem.step`` on each (``--repeat`` rounds over all sizes; at least
``--min-steps`` steps and ~``--seconds`` of work per run, so that every run contains neighbour-
list rebuilds; or ``--steps S`` at every size: the same stretch of the flow, which is the fair
comparison, since the tiled start runs faster than the flow later on).  Prints particle-steps
per second (best and median), their ratio to the smallest system, the load average, and the
memory: bytes per particle held by the engine's
arrays after the run (particles, pair list, contact history and rows, near list, work rows),
and the growth of the process's peak resident memory per particle.

With ``--lammps`` the peer runs the same tiled systems in the same rounds (LAMMPS
``gran/hooke/history``, same species, skin, dt and steps, one process, its default spatial sort
of the atoms every 1000 steps; input as in ``bench_engine_vs_lammps.py``) and the table adds its
particle-steps per second, its own ratio to its smallest system, and granflow / LAMMPS per N:
whether a drop with N is the engine's or the machine's memory system's.

    .venv/bin/python benchmarks/bench_engine_scaling.py [--tiles 1 2 3 5 7 10] [--repeat 3]
        [--threads 1] [--lammps] [--steps 3000]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_engine_vs_lammps as B  # noqa: E402

SMALL_BOX = (10.0, 5.0)


def tiled_system(state, kx, ky):
    """The prepared small-box state repeated kx x ky times (zero contact history)."""
    from granflow.engine.chute import ChuteConfig
    from granflow.engine.system import ParticleSystem
    from granflow.units import RHO_PARTICLE

    lx, ly = SMALL_BOX
    ref = B.paper_species()
    fb, _ = B.matched_species(ref)
    cfg = ChuteConfig(theta=B.THETA, H=float(state["H"]), lam=B.LAM, Lx=lx * kx, Ly=ly * ky,
                      flow=ref, base=fb, skin=B.SKIN)
    tab = cfg.interactions()
    s = ParticleSystem(lx * kx, ly * ky, tab, gvec=cfg.gravity, skin=B.SKIN)
    fixed0 = np.asarray(state["fixed"], bool)
    parts = {k: [] for k in ("pos", "vel", "omega", "diameter", "fixed")}
    for a in range(kx):
        for b in range(ky):
            shift = np.array([a * lx, b * ly, 0.0])
            for name in ("vel", "omega", "diameter"):
                parts[name].append(np.asarray(state[name])[~fixed0])
            parts["pos"].append(np.asarray(state["pos"])[~fixed0] + shift)
            parts["fixed"].append(np.zeros((~fixed0).sum(), bool))
    for a in range(kx):  # fixed (base) particles last
        for b in range(ky):
            shift = np.array([a * lx, b * ly, 0.0])
            for name in ("vel", "omega", "diameter"):
                parts[name].append(np.asarray(state[name])[fixed0])
            parts["pos"].append(np.asarray(state["pos"])[fixed0] + shift)
            parts["fixed"].append(np.ones(fixed0.sum(), bool))
    arr = {k: np.concatenate(v) for k, v in parts.items()}
    ptype = np.where(arr["fixed"], len(tab.type_names) - 1, 0)
    s.set_particles(arr["pos"], arr["diameter"], density=RHO_PARTICLE, ptype=ptype,
                    fixed=arr["fixed"])
    s.vel[:] = arr["vel"]
    s.omega[:] = arr["omega"]
    s.initialize()
    return s


def lammps_rate(s, k, steps, H) -> float:
    """LAMMPS particle-steps per second (its loop time) on the tiled system ``s``."""
    lx, ly = SMALL_BOX
    B.LX, B.LY = lx * k, ly * k
    try:
        out = B.run_lammps(B.state_of(s, H), steps, 1, s.dt, 1, B.WORK / f"scaling_lammps_{k}")
    finally:
        B.LX, B.LY = SMALL_BOX
    print(f"           LAMMPS: N = {out['n']:7d}, {steps:6d} steps, "
          f"{out['n'] * steps / out['loop']:.3g} particle-steps/s, {out['rebuilds']} rebuilds",
          flush=True)
    return out["n"] * steps / out["loop"]


def engine_bytes(s) -> int:
    """Bytes held by the engine's arrays (particles, pairs, rows, near list, work rows)."""
    total = 0
    for name in s._ARRAYS:
        total += np.asarray(getattr(s, name)).nbytes
    total += sum(a.nbytes for a in s._pair)
    total += s._work.nbytes + s._inv_mass.nbytes + s._inv_inertia.nbytes + s._level_of.nbytes
    return total


def maxrss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: kB


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tiles", type=int, nargs="+", default=[1, 2, 3, 5, 7, 10],
                    help="tiling factors k (k x k copies of the 10 x 5 box)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seconds", type=float, default=3.0, help="work per run (estimate)")
    ap.add_argument("--min-steps", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=0,
                    help="the same number of steps at every N (the same stretch of the flow from "
                         "the tiled start: the start runs faster than the long run, so equal "
                         "work per N compares different stretches); default: ~--seconds of work")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--lammps", action="store_true",
                    help="run LAMMPS on the same systems (peer scaling, same rounds)")
    args = ap.parse_args(argv)
    if args.steps < 0:
        ap.error(f"--steps must be >= 1 (or 0: ~--seconds of work per size), not {args.steps}")
    if args.repeat < 1 or args.min_steps < 1 or min(args.tiles) < 1 or args.threads < 1:
        ap.error("--repeat, --min-steps, --tiles and --threads must be >= 1")
    import numba

    numba.set_num_threads(args.threads)
    B.LX, B.LY = SMALL_BOX
    state = B.prepare(20.0, args.seed, False, 10.0, 60.0, 1.0)
    w = tiled_system(state, 1, 1)
    w.step(20)  # compile / load the cache
    print(f"dense chute tiled from a {SMALL_BOX[0]:g} x {SMALL_BOX[1]:g} box "
          f"(N0 = {w.n}), {args.threads} thread(s), {args.repeat} round(s)")
    rows = {k: [] for k in args.tiles}
    lrows = {k: [] for k in args.tiles}
    mem = {}
    rss0 = maxrss_bytes()
    for r in range(args.repeat):
        for k in args.tiles:
            s = tiled_system(state, k, k)
            steps = args.steps or max(args.min_steps, int(args.seconds * 2.0e7 / s.n))
            load = os.getloadavg()[0]
            t0 = time.perf_counter()
            s.step(steps)
            wall = time.perf_counter() - t0
            rows[k].append((s.n, steps, s.n * steps / wall, load, s.n_rebuilds))
            if args.lammps:
                lrows[k].append(lammps_rate(tiled_system(state, k, k), k, steps, state["H"]))
            if r == 0:
                rss = maxrss_bytes()
                mem[k] = (engine_bytes(s) / s.n, max(rss - rss0, 0) / s.n, len(s.pi) / s.n)
                rss0 = max(rss0, rss)
            print(f"  round {r + 1}: N = {s.n:7d}, {steps:6d} steps, "
                  f"{s.n * steps / wall:.3g} particle-steps/s, {s.n_rebuilds} rebuilds, "
                  f"load {load:.2f}", flush=True)
    print()
    print(f"{'N':>8} {'best ps/s':>11} {'median ps/s':>12} {'best/best(N0)':>13} "
          f"{'pairs/N':>8} {'engine B/N':>10} {'peak RSS B/N':>12} {'load':>6}")
    ref = max(x[2] for x in rows[args.tiles[0]])
    for k in args.tiles:
        n = rows[k][0][0]
        best = max(x[2] for x in rows[k])
        med = float(np.median([x[2] for x in rows[k]]))
        eb, rb, ppn = mem[k]
        print(f"{n:>8d} {best:>11.3g} {med:>12.3g} {best / ref:>13.3f} {ppn:>8.2f} {eb:>10.0f} "
              f"{rb:>12.0f} {max(x[3] for x in rows[k]):>6.2f}")
    if args.lammps:
        print()
        print(f"{'N':>8} {'LAMMPS best ps/s':>17} {'best/best(N0)':>13} {'granflow/LAMMPS best':>21} "
              f"{'median of rounds':>17}")
        lref = max(lrows[args.tiles[0]])
        for k in args.tiles:
            n = rows[k][0][0]
            lb = max(lrows[k])
            gb = max(x[2] for x in rows[k])
            med = float(np.median([g[2] / l for g, l in zip(rows[k], lrows[k])]))
            print(f"{n:>8d} {lb:>17.3g} {lb / lref:>13.3f} {gb / lb:>21.3f} {med:>17.3f}")
    print("(engine B/N: bytes of the engine's arrays per particle after the run; peak RSS B/N: "
          "growth of the process's peak resident memory when that size first ran, per "
          "particle — it includes the temporaries of a rebuild)")


if __name__ == "__main__":
    main()
