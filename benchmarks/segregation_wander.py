"""Not a timing: how far one run's Ps stderr is from the truth when its segregated state
wanders (granflow.reference.SEGREGATION_DEFAULT_WANDER, SEGREGATION_WINDOW_SEM_RATIO).

Reads the per-window Ps series that ``benchmarks/segregation_approach.py RUN --json OUT`` writes
(one run, or a chain of continuations with ``--parent``), keeps the windows starting at or
after ``--t-from`` (past the approach) and prints

* the series' mean and its standard error with the windows' autocorrelation
  (:func:`granflow.steady.timeseries.standard_error_of_mean`), the windows' standard deviation
  and their autocorrelation time (first lag where the autocorrelation falls below 1/e);
* for each averaging length L (``--lengths``, time units; a run's profile window is one such
  mean): the standard deviation of the means of consecutive L-unit stretches -- how much one
  profile window's Ps differs from another's -- against the root mean square of the standard
  errors each stretch gives of itself, and their ratio.  A ratio near 1 means one window's
  stderr is honest; well above 1, the state wanders on times longer than L, and only runs
  longer than that wander time (or seeds) measure the error.

    .venv/bin/python benchmarks/segregation_approach.py RUN --parent PARENT --json w.json
    .venv/bin/python benchmarks/segregation_wander.py w.json [w2.json ...] --t-from 1000
        [--lengths 60 120 300] [--n-flow N]

``--n-flow N`` adds each spread relative to the mean times sqrt(N), the constant C of
granflow.fitting.segregation.wander_sd (granflow.reference.SEGREGATION_WANDER_SCALING), and the
relative spread that C predicts at this N.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np


def autocorrelation_time(x, spacing: float = 1.0) -> float:
    """First lag (times ``spacing``) where the autocorrelation of ``x`` falls below 1/e; NaN
    if it does not within half the series."""
    x = np.asarray(x, dtype=float)
    y = x - x.mean()
    den = float(np.dot(y, y))
    if den <= 0 or x.size < 4:
        return math.nan
    for k in range(1, x.size // 2):
        if float(np.dot(y[:-k], y[k:])) / den < math.exp(-1.0):
            return k * spacing
    return math.nan


def block_scatter(x, per_block: int) -> dict:
    """Means of consecutive blocks of ``per_block`` values: their standard deviation (``sd``),
    the rms of each block's own autocorrelated standard error of its mean (``sem``), their
    ``ratio`` and the number of blocks ``n``."""
    from granflow.steady.timeseries import standard_error_of_mean

    x = np.asarray(x, dtype=float)
    n = x.size // per_block
    if n < 2 or per_block < 2:
        return {"n": n, "sd": math.nan, "sem": math.nan, "ratio": math.nan}
    blocks = x[:n * per_block].reshape(n, per_block)
    sd = float(blocks.mean(axis=1).std(ddof=1))
    sem = float(np.sqrt(np.mean([standard_error_of_mean(b) ** 2 for b in blocks])))
    return {"n": n, "sd": sd, "sem": sem, "ratio": sd / sem if sem > 0 else math.nan}


def wander(t_start, Ps, *, t_from: float, window: float, lengths=(60.0, 120.0, 300.0)) -> dict:
    """The statistics the module docstring lists, for windows of length ``window``."""
    from granflow.steady.timeseries import standard_error_of_mean

    t_start, Ps = np.asarray(t_start, dtype=float), np.asarray(Ps, dtype=float)
    x = Ps[(t_start >= t_from) & np.isfinite(Ps)]
    if x.size < 4:
        raise ValueError(f"{x.size} windows start at or after --t-from = {t_from:g}: allowed "
                         "a t_from that leaves at least 4")
    out = {"n_windows": int(x.size), "mean": float(x.mean()),
           "sem": float(standard_error_of_mean(x)), "sd": float(x.std(ddof=1)),
           "acf_time": autocorrelation_time(x, window), "blocks": {}}
    for L in lengths:
        k = int(round(L / window))
        out["blocks"][float(L)] = block_scatter(x, k)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("series", nargs="+", help="JSON files of segregation_approach.py --json")
    ap.add_argument("--t-from", type=float, required=True,
                    help="windows starting before this are the approach, left out")
    ap.add_argument("--lengths", type=float, nargs="+", default=[60.0, 120.0, 300.0],
                    help="averaging lengths L in time units (a profile window's length)")
    ap.add_argument("--n-flow", type=int, default=None,
                    help="the run's number of flow particles N: also print C = (sd of the "
                         "L-unit means / mean) sqrt(N) and the relative spread granflow's "
                         "wander_sd assumes (granflow.reference.SEGREGATION_WANDER_C / sqrt(N))")
    args = ap.parse_args(argv)
    if args.n_flow is not None and args.n_flow <= 0:
        ap.error(f"--n-flow must be a positive number of particles, got {args.n_flow}")
    for path in args.series:
        w = json.load(open(path))
        win = float(w["window"]["cg_window"] if isinstance(w["window"], dict) else w["window"])
        ws = w["windows"]
        r = wander(ws["t_start"], ws["Ps"], t_from=args.t_from, window=win,
                   lengths=args.lengths)
        t_end = max(ws["t_start"]) + win
        print(f"{path}: {r['n_windows']} windows of {win:g} over t = {args.t_from:g}-{t_end:g}: "
              f"Ps {r['mean']:.3f} +- {r['sem']:.3f} (autocorrelated), windows' sd "
              f"{r['sd']:.3f}, autocorrelation time {r['acf_time']:.4g}")
        for L, b in r["blocks"].items():
            print(f"   {L:6g}-unit means: {b['n']:3d}, sd {b['sd']:.3f} against their own "
                  f"stderrs {b['sem']:.3f}: {b['ratio']:.2f}x")
        if args.n_flow is not None:
            from granflow.reference import SEGREGATION_WANDER_C

            root = math.sqrt(args.n_flow)
            spreads = [(f"{win:g}-unit windows", r["sd"])] + [
                (f"{L:g}-unit means", b["sd"]) for L, b in r["blocks"].items()]
            print(f"   N = {args.n_flow}: " + "; ".join(
                f"{name} {100 * sd / r['mean']:.2f} % (C {sd / r['mean'] * root:.3f})"
                for name, sd in spreads)
                + f"; granflow's wander_sd assumes {100 * SEGREGATION_WANDER_C / root:.2f} %"
                f" (C {SEGREGATION_WANDER_C:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
