"""Core time a finished campaign spent in its simulations, by run kind and filling height.

Reads the last line of every ``simulate.log`` under a campaign's results folder (``granflow
simulate`` ends it with "... at t = T (N flow particles, W s wall)") and prints the core hours
(one thread per run), the simulated time and the particle count per group -- what a cluster
allocation for the same campaign needs (``--workflow-profile profiles/slurm``), independent of
how many cores ran it here.  A run resumed from a checkpoint reports only its last segment.

    .venv/bin/python benchmarks/campaign_cost.py results/reference-lambda1
"""

from __future__ import annotations

import argparse
import re
from collections import defaultdict
from pathlib import Path

LAST = re.compile(r"at t = ([0-9.eE+-]+) \((\d+) flow particles, ([0-9.]+) s wall\)")


def run_costs(results: Path):
    """(kind, H, t_final, n_flow, wall_s) for every finished run under ``results``."""
    out = []
    for log in sorted(results.rglob("simulate.log")):
        lines = log.read_text(errors="replace").strip().splitlines()
        m = LAST.search(lines[-1]) if lines else None
        if m is None:
            continue
        rel = log.parent.relative_to(results).parts
        H = next((p.split("~", 1)[1] for p in rel if p.startswith("H~")), "?")
        out.append((rel[0], H, float(m.group(1)), int(m.group(2)), float(m.group(3))))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path)
    args = ap.parse_args()
    rows = run_costs(args.results)
    if not rows:
        raise SystemExit(f"no finished simulate.log under {args.results}")
    groups = defaultdict(list)
    for kind, H, t, n, w in rows:
        groups[(kind, H)].append((t, n, w))
    print(f"{'kind':<12} {'H':>6} {'runs':>5} {'t simulated':>12} {'core h':>8}")
    for (kind, H), g in sorted(groups.items(), key=lambda kv: (kv[0][0], float(kv[0][1])
                                                                if kv[0][1] != "?" else 0)):
        print(f"{kind:<12} {H:>6} {len(g):>5} {sum(x[0] for x in g):>12.0f} "
              f"{sum(x[2] for x in g) / 3600:>8.3f}")
    total = sum(r[4] for r in rows) / 3600
    print(f"total: {len(rows)} runs, {total:.2f} core hours in the simulations")


if __name__ == "__main__":
    main()
