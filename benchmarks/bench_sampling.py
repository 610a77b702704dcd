"""Where a default-campaign run's time goes: the time steps against the work between them.

Runs the first ``--t-end`` time units of three runs of the embedded default campaign (a steady
chute, a thin hstop bracket, a segregation run; their parameters as the workflow builds them,
early stopping off, one thread, over a rough base prepared here) through
:func:`granflow.simulate.simulate`, with a clock around every ``ParticleSystem.step`` call and
around every observer's ``sample``, and prints per run the cost per sample (every t_c/2) of the
steps and of each observer, and the share of the run spent between the steps.  The peer is the
stepping itself, measured in the same run.

    .venv/bin/python benchmarks/bench_sampling.py [--t-end 40]
"""

from __future__ import annotations

import argparse
import collections
import tempfile
import time
from pathlib import Path

#: (label, kind, theta, H, sigma) of the default campaign's runs measured
RUNS = (("steady chute, H = 10, 26 deg", "chute", 26.0, 10.0, None),
        ("bracket, H = 1.5, 27 deg", "bracket", 27.0, 1.5, None),
        ("segregation, H = 8, sigma = 0.6", "segregation", 25.0, 8.0, 0.6))


def timed_run(params: dict, base_file, out) -> dict:
    """Run ``params`` with clocks around the steps and each observer; seconds and calls."""
    import granflow.engine.run as R
    from granflow.simulate import simulate

    secs, calls = collections.Counter(), collections.Counter()
    step, run = R.ParticleSystem.step, R.ChuteRun.run

    def timed_step(self, n):
        t = time.perf_counter()
        step(self, n)
        secs["steps"] += time.perf_counter() - t
        calls["steps"] += 1

    def timed_run_loop(self):
        for obs in self.observers:
            def sample(system, f=obs.sample, name=obs.name):
                t = time.perf_counter()
                f(system)
                secs[name] += time.perf_counter() - t
                calls[name] += 1
            obs.sample = sample
        t = time.perf_counter()
        out_ = run(self)
        secs["run"] += time.perf_counter() - t
        return out_

    R.ParticleSystem.step, R.ChuteRun.run = timed_step, timed_run_loop
    try:
        simulate(params, out, base_file=base_file, threads=1)
    finally:
        R.ParticleSystem.step, R.ChuteRun.run = step, run
    return {"secs": secs, "calls": calls}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=40.0, help="simulated time of each run")
    args = ap.parse_args()

    from granflow.campaign.config import load_yaml
    from granflow.campaign.grid import RunPoint, run_params
    from granflow.simulate import prepare_base_file

    repo = Path(__file__).resolve().parents[1]
    config = load_yaml(repo / "config" / "config.yaml")
    law = config["campaigns"]["chute"]["contact_law"][0]
    with tempfile.TemporaryDirectory(prefix="bench-sampling-") as tmp:
        tmp = Path(tmp)
        chute = config["campaigns"]["chute"]
        base = tmp / "base.npy"
        prepare_base_file(1.0, chute["Lx"], chute["Ly"], config["base"]["seed"], base,
                          base_layers=config["base"]["layers"],
                          settle_time=config["base"]["settle_time"])
        points = [(label, RunPoint(kind, law, 1.0, theta, H, sigma or 1.0))
                  for label, kind, theta, H, sigma in RUNS]
        for label, p in points:  # compile outside the clocks
            warm = dict(run_params(config, p), t_end=0.05, early_stop=False)
            timed_run(warm, base, tmp / f"warm-{p.kind}")
        print(f"first {args.t_end:g} time units of each run, one thread; us per sample (t_c/2)")
        print(f"{'run':34s} {'steps':>8s} {'energies':>9s} {'profiles':>9s} {'monitor':>8s} "
              f"{'segr.':>6s} {'between steps':>14s}")
        for label, p in points:
            params = dict(run_params(config, p), t_end=args.t_end, early_stop=False)
            r = timed_run(params, base, tmp / p.kind)
            s, n = r["secs"], r["calls"]
            per = {k: 1e6 * s[k] / max(n[k], 1) for k in s}
            between = s["run"] - s["steps"]
            print(f"{label:34s} {per['steps']:8.1f} {per.get('series', 0):9.1f} "
                  f"{per.get('profiles', 0):9.1f} "
                  f"{per.get('monitor', per.get('monitor_passive', 0)):8.1f} "
                  f"{per.get('segregation', 0):6.1f} {100 * between / s['run']:12.1f} %")


if __name__ == "__main__":
    main()
