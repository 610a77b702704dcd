"""Cost of on-the-fly coarse-graining as a fraction of simulation time (issue 4).

Builds a dense flowing chute (theta = 24 deg, H = 10, lambda = 1, paper contact parameters) and
times, interleaved in the same process so that machine load affects both alike,

* the engine alone: advancing sample intervals of t_c/2 (25 steps) with the energy series, and
* the same plus a coarse-graining snapshot every t_c/2 (contacts + depth-profile accumulation),

then prints the coarse-graining overhead as a fraction of the simulation time.

    .venv/bin/python benchmarks/bench_coarse_overhead.py [--Lx 20 --Ly 10 --H 10 --rounds 6]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--Lx", type=float, default=20.0)
    ap.add_argument("--Ly", type=float, default=10.0)
    ap.add_argument("--H", type=float, default=10.0)
    ap.add_argument("--spinup", type=float, default=15.0, help="flow time before timing")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--samples", type=int, default=200, help="samples (t_c/2 each) per round")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()

    import numba

    numba.set_num_threads(args.threads)
    from granflow.coarse import DepthProfileAccumulator
    from granflow.engine.chute import BaseConfig, ChuteConfig, build_chute, prepare_rough_base
    from granflow.engine.run import EnergySeries
    from granflow.observers import ProfileObserver

    base = prepare_rough_base(BaseConfig(lam=1.0, Lx=args.Lx, Ly=args.Ly, base_layers=6.0,
                                         settle_time=15.0))
    sys_ = build_chute(ChuteConfig(theta=24.0, H=args.H, Lx=args.Lx, Ly=args.Ly), base)
    every = int(round(0.5 * 0.005 / sys_.dt))
    sys_.step(int(args.spinup / sys_.dt))
    series = EnergySeries()
    acc = DepthProfileAccumulator(-2.0, 2 * args.H + 10, 0.05, width=0.25, Lx=args.Lx,
                                  Ly=args.Ly, window_length=10.0)
    prof = ProfileObserver(acc)
    prof.sample(sys_)  # warm up the coarse-graining kernels (compile excluded)
    t_engine = t_cg = 0.0
    for _ in range(args.rounds):
        t0 = time.perf_counter()
        for _ in range(args.samples):
            sys_.step(every)
            series.sample(sys_)
        t1 = time.perf_counter()
        for _ in range(args.samples):
            sys_.step(every)
            series.sample(sys_)
            prof.sample(sys_)
        t2 = time.perf_counter()
        t_engine += t1 - t0
        t_cg += (t2 - t1) - (t1 - t0)
    n = len(sys_.radius)
    steps = args.rounds * args.samples * every
    print(f"chute theta=24 H={args.H} box {args.Lx:g}x{args.Ly:g}: {int((~sys_.fixed).sum())} flow + "
          f"{int(sys_.fixed.sum())} base particles, snapshot every {every} steps (t_c/2), "
          f"{args.threads} thread(s), load {os.getloadavg()[0]:.2f}")
    print(f"engine alone      : {t_engine:8.2f} s for {steps} steps "
          f"({n * steps / t_engine / 1e6:.2f} M particle-steps/s)")
    print(f"coarse-graining   : {t_cg:8.2f} s for {args.rounds * args.samples} snapshots "
          f"({1e6 * t_cg / (args.rounds * args.samples) / n:.2f} us per particle per snapshot)")
    print(f"overhead fraction : {t_cg / t_engine:.1%} of simulation time")


if __name__ == "__main__":
    main()
