"""One run on 1 and on 2 (or more) threads: speed-up and proof of identical results (issue 15).

Runs the prepared dense chute of ``bench_engine_vs_lammps.py`` (4405 particles, theta = 24 deg,
skin 0.2, dt = 1e-4; prepared on first use) for ``--steps`` steps from the same start state,
alternating the thread counts in the same process (``numba.set_num_threads``), ``--repeat``
rounds, and prints for every round the wall time per step of each count, the ratio, and the
machine's 1-minute load average (the speed-up is only meaningful when the machine has the
cores to spare: a load average near 0 before the run).  Then it checks that the final states
of all runs are bit-for-bit equal (positions, velocities, angular velocities, forces, torques,
tangential springs, pair list, elastic and released energies) and prints a SHA-256 of them.

    .venv/bin/python benchmarks/bench_engine_threads.py [--steps 10000] [--repeat 5]
        [--threads 1 2] [--tiles K]

``--tiles K``: instead, the 10 x 5 dense chute of ``bench_engine_scaling.py`` tiled K x K times
(K = 3: 9918 particles, 5: 27550), to see how the speed-up grows with N.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_engine_vs_lammps as B  # noqa: E402


def state_digest(s) -> tuple[str, dict]:
    """SHA-256 over the dynamic state of a system, and the arrays hashed."""
    arrays = {"pos": s.pos, "vel": s.vel, "omega": s.omega, "force": s.force,
              "torque": s.torque, "hist_t": s.hist_t, "pi": s.pi, "pj": s.pj,
              "energies": np.array([s.e_elastic, s.e_released, s.max_overlap])}
    h = hashlib.sha256()
    for name, a in arrays.items():
        h.update(name.encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest(), {k: np.array(v, copy=True) for k, v in arrays.items()}


def run(state, steps, threads, tiles=0):
    import numba

    numba.set_num_threads(threads)
    if tiles:
        import bench_engine_scaling as S

        s = S.tiled_system(state, tiles, tiles)
    else:
        ref = B.paper_species()
        fb, _ = B.matched_species(ref)
        s = B.make_system(state, ref, fb)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    c0 = time.process_time()
    s.step(steps)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    digest, arrays = state_digest(s)
    return dict(wall=wall, cpu=cpu, load=load, digest=digest, arrays=arrays, n=s.n)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--H", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--tiles", type=int, default=0,
                    help="the scaling benchmark's 10 x 5 chute tiled K x K (default: the 20 x 10 "
                         "benchmark chute)")
    args = ap.parse_args(argv)
    import numba

    if max(args.threads) > numba.config.NUMBA_NUM_THREADS:
        ap.error(f"--threads {max(args.threads)} > NUMBA_NUM_THREADS = "
                 f"{numba.config.NUMBA_NUM_THREADS}")
    if args.tiles:
        import bench_engine_scaling as S

        B.LX, B.LY = S.SMALL_BOX
    state = B.prepare(args.H, args.seed, False, 10.0, 60.0, 1.0)
    for t in args.threads:  # compile / load the cache, warm up
        n = run(state, 20, t, args.tiles)["n"]
    print(f"dense chute, N = {n}, {args.steps} steps per run, threads "
          f"{args.threads} alternating, {args.repeat} rounds; numba threading layer "
          f"{numba.threading_layer()}")
    head = "  ".join(f"{t} thr us/step" for t in args.threads)
    print(f"{'round':>5}  {head}  " + "  ".join(f"x{t}/x{args.threads[0]}"
                                                for t in args.threads[1:]) + "  load avg")
    results = {t: [] for t in args.threads}
    for r in range(args.repeat):
        row = {}
        for t in args.threads:
            row[t] = run(state, args.steps, t, args.tiles)
            results[t].append(row[t])
        base = row[args.threads[0]]["wall"]
        times = "  ".join(f"{row[t]['wall'] / args.steps * 1e6:13.1f}" for t in args.threads)
        ratios = "  ".join(f"{base / row[t]['wall']:7.3f}" for t in args.threads[1:])
        loads = "/".join(f"{row[t]['load']:.2f}" for t in args.threads)
        print(f"{r + 1:>5}  {times}  {ratios}  {loads}", flush=True)
    print()
    t0 = args.threads[0]
    med0 = float(np.median([x["wall"] for x in results[t0]]))
    best0 = min(x["wall"] for x in results[t0])
    for t in args.threads[1:]:
        med = float(np.median([x["wall"] for x in results[t]]))
        best = min(x["wall"] for x in results[t])
        print(f"speed-up {t} threads / {t0}: median {med0 / med:.3f}, best {best0 / best:.3f} "
              f"(median of the per-round ratios "
              f"{np.median([a['wall'] / b['wall'] for a, b in zip(results[t0], results[t])]):.3f})")
    # identical results for every thread count and every repeat
    ref = results[t0][0]
    same = True
    for t in args.threads:
        for x in results[t]:
            for k, a in ref["arrays"].items():
                if not np.array_equal(a, x["arrays"][k]):
                    same = False
                    print(f"DIFFERENT: {k} with {t} threads")
    digests = sorted({x["digest"] for t in args.threads for x in results[t]})
    print(f"final states of all {sum(len(v) for v in results.values())} runs bit-for-bit "
          f"identical: {same}; SHA-256 of the state: {', '.join(digests)}")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
