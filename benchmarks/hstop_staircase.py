"""The paper's §6 hstop walk as a *staircase* whose state carries over (issue 14, lambda = 1/2).

Weinhart et al. (2012) §6: "Starting from an initial filling height H = 4 and inclination
theta = 21 deg, the angle was increased in steps of 1 deg until eventually a flowing state was
reached.  From this initial flowing state, the height was increased by 2 particle heights, if
the flow arrested, or else the angle decreased by 1/2 deg"; a run is arrested when E_kin/E_ela
falls below 1e-5 within 500 time units.  The campaign's bisection chains read the initial
conditions either as fresh falls (``protocol: fresh_fall``) or as a flow continued at fixed H
(``protocol: continuation``).  This script runs the third reading: every run starts from the
final state of the run before it -- tilted to the new angle (the angle steps), or with the
missing 2 particle heights poured on top of the arrested pile, at rest, its contacts kept (the
height steps; ``granflow simulate --from STATE --top-up``).

The walk is :class:`granflow.steady.hstop_search.HstopSearch` (every step simulated:
``skip_implied=False``, since each run needs its predecessor's state); each run has the run
parameters of a continuation bracket run of the configuration (arrested within
``arrest_horizon`` = 500, otherwise flowing: stopped once steady or accelerating, or at 500).
The runs are written as campaign bracket runs (``<out>/bracket/<law>/lambda~L/theta~T/H~H``),
so ``benchmarks/hstop_brackets.py <out>`` fits Eq. (45) to them against Table 1; a rerun reuses
finished runs (each run's summary.json) and resumes a killed one from its checkpoint.

    .venv/bin/python benchmarks/hstop_staircase.py --configfile config/reference-lambda-half.yaml \
        --lam 0.5 --out results/staircase-lambda-half [--H-max 24]

Prints each run (theta, H, flow state, stop time, particles added, wall time), the walk's
(H, theta_arrested, theta_flowing) intervals and Table 1's theta_stop at each H.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def merged_config(configfile: str | None) -> dict:
    """config/config.yaml with ``configfile`` merged over it (as Snakemake's --configfile)."""
    from granflow.campaign.config import load_yaml

    def merge(a: dict, b: dict) -> dict:
        out = dict(a)
        for k, v in b.items():
            out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
        return out

    cfg = load_yaml(ROOT / "config" / "config.yaml")
    return merge(cfg, load_yaml(configfile)) if configfile else cfg


def staircase_params(config: dict, law: str, lam: float, theta: float, H: float) -> dict:
    """Run parameters of a continuation bracket run of ``config`` at (theta, H)."""
    from granflow.campaign import grid as G

    config = json.loads(json.dumps(config))  # a copy
    bis = config["campaigns"]["chute"].setdefault("hstop_bisection", {})
    bis["protocol"] = "continuation"
    return G.run_params(config, G.RunPoint("bracket", law, lam, theta, H))


def table1_theta_stop(lam: float, H: float) -> float:
    """Table 1's theta_stop(H) (Eq. 45 inverted), degrees; nan if Table 1 has no lambda row."""
    from granflow.fitting.hstop import theta_stop_eq45
    from granflow.reference import paper_value

    d1, d2, A = (paper_value("hstop", k, lam) for k in ("delta1", "delta2", "A"))
    return float(theta_stop_eq45(H, d1, d2, A))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configfile", default=None, help="campaign configuration merged over "
                    "config/config.yaml (species, numerics, box, base)")
    ap.add_argument("--law", default="linear")
    ap.add_argument("--lam", type=float, required=True, help="basal roughness lambda")
    ap.add_argument("--out", required=True, help="results folder (runs under bracket/...)")
    ap.add_argument("--theta0", type=float, default=21.0, help="first angle (paper: 21)")
    ap.add_argument("--H0", type=float, default=4.0, help="first filling height (paper: 4)")
    ap.add_argument("--H-max", type=float, default=24.0, help="largest filling height")
    ap.add_argument("--max-runs", type=int, default=40)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)

    from granflow.campaign import grid as G
    from granflow.campaign.collect import engine_stop_without_flow_state
    from granflow.simulate import prepare_base_file, simulate
    from granflow.steady.hstop_search import HstopSearch

    config = merged_config(args.configfile)
    out = Path(args.out)
    # the campaign's base (same seed and layers as its bracket runs)
    Lx, Ly = G.box(config, "bracket")  # the runs are bracket runs: their box
    base_cfg = G.base_settings(config)
    base = out / "bases" / f"lambda~{G.format_value(args.lam)}" / f"box~{G.format_value(Lx)}x{G.format_value(Ly)}" / "base.npy"
    if not base.exists():
        prepare_base_file(args.lam, Lx, Ly, int(base_cfg.get("seed", 1)), base,
                          base_layers=float(base_cfg["layers"]),
                          settle_time=float(base_cfg.get("settle_time", 30.0)),
                          **G.base_making(config))
    search = HstopSearch(theta0=args.theta0, H0=args.H0, H_max=args.H_max,
                         max_runs=args.max_runs, skip_implied=False)
    prev = None  # (run folder, H) of the last run
    print(f"{'theta':>6} {'H':>5} {'state':>12} {'t_stop':>7} {'added':>6} {'wall s':>7}  start")
    while (point := search.next_point()) is not None:
        theta, H = point
        run_dir = out / G.run_path(G.RunPoint("bracket", args.law, args.lam, theta, H))
        summary_file = run_dir / "summary.json"
        start = "fresh fall" if prev is None else (
            f"top-up of {prev[0].relative_to(out)}" if H > prev[1] + 1e-9
            else f"tilt of {prev[0].relative_to(out)}")
        t0 = time.monotonic()
        if not summary_file.exists():
            params = staircase_params(config, args.law, args.lam, theta, H)
            simulate(params, run_dir, base_file=base, threads=args.threads,
                     from_state=None if prev is None else prev[0] / "final_state.npz",
                     top_up=prev is not None and H > prev[1] + 1e-9)
        summary = json.loads(summary_file.read_text())
        state = summary.get("flow_state")
        added = (summary.get("parent") or {}).get("topped_up", "")
        print(f"{theta:6.2f} {H:5.1f} {state:>12} {summary.get('t_final', math.nan):7.1f} "
              f"{added!s:>6} {time.monotonic() - t0:7.0f}  {start}", flush=True)
        if engine_stop_without_flow_state(summary):
            search.record_failed(theta, H, "engine guard before any flow state")
            break
        search.record(theta, H, state)
        prev = (run_dir, H)
    print(f"walk ended: {search.done_reason}")
    print(f"\n{'H':>5} {'theta_arr':>9} {'theta_flo':>9} {'Table 1 theta_stop':>18}")
    for H, ta, tf in search.intervals(complete_only=False):
        print(f"{H:5.1f} {ta:9.2f} {tf:9.2f} {table1_theta_stop(args.lam, H):18.2f}")
    return search


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
