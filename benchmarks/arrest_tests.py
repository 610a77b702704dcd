"""granflow's arrest rules against the paper's literal arrest test, run by run.

For every bracket and chute run under the results folders (``summary.json`` + ``series.nc``)
prints granflow's flow state beside the paper's test as its driver applies it
(:func:`granflow.steady.classify.paper_arrest_time`: E_kin/E_ela < 1e-5 at a whole time unit
after t = 10, within the horizon t = 500), and counts the runs on which the two disagree.  A run
that granflow stopped early (an arrest, or ``stop_when_flowing``) is judged on the time it ran:
"flowing" by the paper's test then means "not arrested by t_final", and the smallest ratio after
t = 10 says how far it was from an arrest.  The series' ratio counts rotation too (the driver
counts translation only), so an arrest by this test is one by the driver's as well.

    .venv/bin/python benchmarks/arrest_tests.py results/reference-lambda-half
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
import xarray as xr

from granflow.steady.classify import paper_arrest_time

POINT = re.compile(r"lambda~(?P<lam>[0-9.]+)/theta~(?P<theta>[0-9.]+)/H~(?P<H>[0-9.]+)")


def arrest_rows(*roots, horizon: float = 500.0) -> list[dict]:
    """One row per run: lambda, H, theta, granflow's state, t_final, the paper test's arrest
    time (None: none by min(t_final, horizon)), the smallest ratio after t = 10."""
    rows = []
    for root in map(Path, roots):
        for kind in ("bracket", "chute"):
            for f in sorted((root / kind).glob("**/summary.json")):
                series = f.with_name("series.nc")
                m = POINT.search(f.as_posix())
                if m is None or not series.exists():
                    continue
                summary = json.loads(f.read_text())
                with xr.open_dataset(series) as ds:
                    t = ds["t"].values
                    r = ds["energy_ratio"].values
                late = t > 10.0
                rows.append({"lam": float(m["lam"]), "H": float(m["H"]),
                             "theta": float(m["theta"]), "state": summary["flow_state"],
                             "t_final": float(summary["t_final"]),
                             "paper_arrest": paper_arrest_time(t, r, horizon=horizon),
                             "min_ratio": float(np.nanmin(r[late])) if late.any() else np.nan})
    return sorted(rows, key=lambda row: (row["lam"], row["H"], row["theta"]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", nargs="+", help="campaign results folders")
    ap.add_argument("--horizon", type=float, default=500.0)
    args = ap.parse_args()
    rows = arrest_rows(*args.results, horizon=args.horizon)
    disagree = {"granflow arrested, paper test not": 0, "paper test arrested, granflow not": 0}
    print(f"{'lambda':>6} {'H':>5} {'theta':>6}  {'granflow':<12} {'t_final':>7}  "
          f"{'paper test':<16} {'min ratio':>9}")
    for row in rows:
        ours = row["state"] == "arrested"
        theirs = row["paper_arrest"] is not None
        test = f"arrested t={row['paper_arrest']:g}" if theirs else "not arrested"
        flag = ""
        if ours and not theirs:
            disagree["granflow arrested, paper test not"] += 1
            flag = "  <- differs"
        elif theirs and not ours:
            disagree["paper test arrested, granflow not"] += 1
            flag = "  <- differs"
        print(f"{row['lam']:6g} {row['H']:5g} {row['theta']:6.2f}  {row['state']:<12} "
              f"{row['t_final']:7.1f}  {test:<16} {row['min_ratio']:9.2e}{flag}")
    print(f"{len(rows)} runs; " + "; ".join(f"{k}: {v}" for k, v in disagree.items()))


if __name__ == "__main__":
    main()
