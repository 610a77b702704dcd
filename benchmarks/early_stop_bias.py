"""How far an early-stopped steady run's depth-averaged velocity lies from the paper's protocol.

The paper integrates every steady run to t = 2000 and averages over the last T = 100 (004 §5,
§6); granflow's monitor stops a run once its energy ratio is shown flat (TOST, +-20 % of the
ratio over one averaging time) and averages from the detected onset.  A thick layer still
relaxing with a time scale of a few hundred units can pass that test while creeping.  This
script continues each early-stopped steady run of a campaign from its ``final_state.npz``
(positions, velocities and contact history; ``granflow simulate --from``, same inclination)
without early stopping, to the paper's t = 2000 in all, and compares u_bar = <u_mean> over
the early run's steady window with u_bar over the last T of the continuation:

    .venv/bin/python benchmarks/early_stop_bias.py RESULTS_DIR [--lam 0.5] [--jobs 2]
        [--t-total 2000] [--out DIR]

F = u_bar / sqrt(g h cos theta) at the same h, so the relative change of u_bar is that of F.
Prints one row per run (theta, H, early t_final, u_bar early, u_bar at t_total, relative
change, the continuation's slope over its last 2 T) and writes ``early_stop_bias.json`` in
--out.  Runs that reached t_total already are listed with no continuation.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import xarray as xr
import yaml

REPO = Path(__file__).resolve().parents[1]


def mean_u(series_nc, t_from, t_to=math.inf):
    with xr.open_dataset(series_nc) as s:
        t = s[list(s.coords)[0]].to_numpy()
        u = s["u_mean"].to_numpy()
    m = (t >= t_from) & (t <= t_to)
    return float(np.mean(u[m])), t, u


def slope(t, u, t_from):
    m = t >= t_from
    if m.sum() < 3:
        return math.nan
    return float(np.polyfit(t[m], u[m], 1)[0])


def simulate_from(params_file: Path, dest: Path, state: Path) -> None:
    """``granflow simulate PARAMS --out DEST --from STATE`` (the continuation)."""
    cmd = [str(Path(sys.executable).with_name("granflow")), "simulate", str(params_file),
           "--out", str(dest), "--from", str(state)]
    with open(dest / "continue.log", "w") as log:
        subprocess.run(cmd, check=True, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)


def continue_run(run_dir: Path, out: Path, t_total: float, runner=None) -> dict:
    summary = json.loads((run_dir / "summary.json").read_text())
    t_final = float(summary["t_final"])
    p = yaml.safe_load((run_dir / "params.yaml").read_text())
    T = float(p.get("averaging_time", 100.0))
    row = {"run": str(run_dir), "theta": float(p["theta"]), "H": float(p["H"]),
           "state": summary["flow_state"], "t_final": t_final,
           "steady_start": summary.get("steady_start"), "averaging_time": T,
           "F_early": summary["depth_averages"].get("froude"),
           "h_early": summary["depth_averages"].get("flow_height")}
    row["u_early"], _, _ = mean_u(run_dir / "series.nc", float(summary["steady_start"]), t_final)
    rest = t_total - t_final
    if rest < T:
        row.update(continued=False, u_paper=math.nan, rel_change=math.nan)
        return row
    dest = out / run_dir.relative_to(run_dir.parents[3])
    dest.mkdir(parents=True, exist_ok=True)
    if not (dest / "summary.json").exists():
        p.update(early_stop=False, t_end=rest)
        (dest / "params.yaml").write_text(yaml.safe_dump(p, sort_keys=True))
        (runner or simulate_from)(dest / "params.yaml", dest, run_dir / "final_state.npz")
    cont = json.loads((dest / "summary.json").read_text())
    t_end = float(cont["t_final"])
    row["u_paper"], t, u = mean_u(dest / "series.nc", t_end - T, t_end)
    row["slope_last_2T"] = slope(t, u, t_end - 2 * T)
    # the scatter of T-averages within one steady run: sd of consecutive T-block means of the
    # continuation, against the run's reported standard error of its mean (``u_bar_sem``:
    # batch means over its cg windows, within the early run's steady window)
    edges = np.arange(0.0, t_end - T + 1e-9, T)
    blocks = [float(np.mean(u[(t >= a) & (t < a + T)])) for a in edges]
    row["n_blocks"] = len(blocks)
    row["block_sd"] = float(np.std(blocks, ddof=1)) if len(blocks) > 2 else math.nan
    row["sem_reported"] = summary["depth_averages"].get("u_bar_sem")
    row["block_sd_over_sem"] = (row["block_sd"] / row["sem_reported"]
                                if row["sem_reported"] else math.nan)
    row["rel_change"] = row["u_paper"] / row["u_early"] - 1.0
    row["F_paper_est"] = (row["F_early"] * (1.0 + row["rel_change"])
                          if row["F_early"] is not None else math.nan)
    row.update(continued=True, continuation=str(dest), continuation_t=t_end,
               continuation_state=cont["flow_state"])
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", help="a campaign's results/<name> folder")
    ap.add_argument("--lam", type=float, default=None, help="only runs at this lambda")
    ap.add_argument("--t-total", type=float, default=2000.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=None, help="continuations here (default RESULTS/early_stop_bias)")
    args = ap.parse_args(argv)
    res = Path(args.results)
    out = Path(args.out) if args.out else res / "early_stop_bias"
    runs = []
    for s in sorted((res / "chute").glob("*/lambda~*/theta~*/H~*/summary.json")):
        d = s.parent
        lam = float(d.parent.parent.name.split("~")[1])
        if args.lam is not None and abs(lam - args.lam) > 1e-9:
            continue
        if json.loads(s.read_text())["flow_state"] == "steady":
            runs.append(d)
    if not runs:
        raise SystemExit(f"no steady chute runs under {res}/chute")
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = list(pool.map(lambda d: continue_run(d, out, args.t_total), runs))
    print(f"{'theta':>5} {'H':>4} {'t_stop':>7} {'u_early':>8} {'u_t' + format(args.t_total, 'g'):>8} "
          f"{'rel':>7} {'slope/100':>9} {'F_early':>7} {'F_paper':>7} {'blocks':>6} "
          f"{'sd(T-mean)':>10} {'u_sem':>7} {'ratio':>6}")
    for r in rows:
        print(f"{r['theta']:5g} {r['H']:4g} {r['t_final']:7.0f} {r['u_early']:8.3f} "
              f"{r['u_paper']:8.3f} {r['rel_change']:+7.2%} "
              f"{100 * r.get('slope_last_2T', math.nan):9.3f} {r['F_early']:7.3f} "
              f"{r.get('F_paper_est', math.nan):7.3f} {r.get('n_blocks', 0):6d} "
              f"{r.get('block_sd', math.nan):10.3f} {r.get('sem_reported') or math.nan:7.3f} "
              f"{r.get('block_sd_over_sem', math.nan):6.1f}")
    done = [r for r in rows if r["continued"]]
    if done:
        rel = np.array([r["rel_change"] for r in done])
        print(f"continued {len(done)} of {len(rows)} runs: relative change of u_bar "
              f"mean {rel.mean():+.2%}, min {rel.min():+.2%}, max {rel.max():+.2%}")
    out.mkdir(parents=True, exist_ok=True)
    (out / "early_stop_bias.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
