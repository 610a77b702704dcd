"""Core time a finished campaign spent in its simulations, by run kind and filling height.

Reads the last line of every ``simulate.log`` under a campaign's results folder (``granflow
simulate`` ends it with "... at t = T (N flow particles, W s wall; whole run C s cpu, W' s
wall, S segments)") and prints the core hours, the simulated time and the particle count per
group -- what a cluster allocation for the same campaign needs (``--workflow-profile
profiles/slurm``), independent of how many cores ran it here.

Core hours are the runs' CPU time (all threads, all segments of a run killed and resumed from
its checkpoint), which other jobs sharing the cores do not inflate.  Logs written before the
CPU time was recorded (before 2026-11-26) give only the last segment's wall time: their runs
count wall time times threads (a run that took spare cores, ``granflow.engine.threads``, at
the thread counts of its log's "spare cores:" line), an upper bound on a shared machine and a
lower bound for a resumed run; the table says how many runs are counted that way.

    .venv/bin/python benchmarks/campaign_cost.py results/reference-lambda1
"""

from __future__ import annotations

import argparse
import ast
import re
from collections import defaultdict
from pathlib import Path

LAST = re.compile(r"at t = ([0-9.eE+-]+) \((\d+) flow particles, ([0-9.]+) s wall"
                  r"(?:; whole run ([0-9.]+) s cpu, ([0-9.]+) s wall, (\d+) segments)?\)")
SPARE = re.compile(r"spare cores: (\{.*\})")


def spare_record(lines) -> dict[int, float]:
    """Wall seconds per thread count from a log's last "spare cores:" line ({} if none)."""
    for line in reversed(lines):
        m = SPARE.search(line)
        if m:
            rec = ast.literal_eval(m.group(1)).get("wall_s_at_threads", {})
            return {int(k): float(v) for k, v in rec.items()}
    return {}


def run_costs(results: Path):
    """(kind, H, t_final, n_flow, wall_s, core_s, wall_s_multi, cpu_measured, segments) for
    every finished run: ``core_s`` is the CPU time where the log has it (``cpu_measured``),
    else wall time times threads; ``wall_s`` the whole run's where known, else the last
    segment's; ``segments`` None where unknown."""
    out = []
    for log in sorted(results.rglob("simulate.log")):
        lines = log.read_text(errors="replace").strip().splitlines()
        m = LAST.search(lines[-1]) if lines else None
        if m is None:
            continue
        rel = log.parent.relative_to(results).parts
        H = next((p.split("~", 1)[1] for p in rel if p.startswith("H~")), "?")
        wall = float(m.group(3))
        rec = spare_record(lines)
        # the time outside the stepping loop (set-up, outputs) ran on one thread
        multi = sum(w for k, w in rec.items() if k > 1)
        thread_s = wall + sum((k - 1) * w for k, w in rec.items())
        if m.group(4) is not None:
            out.append((rel[0], H, float(m.group(1)), int(m.group(2)), float(m.group(5)),
                        float(m.group(4)), multi, True, int(m.group(6))))
        else:
            out.append((rel[0], H, float(m.group(1)), int(m.group(2)), wall, thread_s, multi,
                        False, None))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path)
    args = ap.parse_args()
    rows = run_costs(args.results)
    if not rows:
        raise SystemExit(f"no finished simulate.log under {args.results}")
    groups = defaultdict(list)
    for kind, H, t, n, w, core, multi, measured, seg in rows:
        groups[(kind, H)].append((t, n, w, core, multi, measured))
    print(f"{'kind':<12} {'H':>6} {'runs':>5} {'t simulated':>12} {'core h':>8} {'wall h':>8} "
          f"{'wall h >1 thr':>14} {'cpu measured':>13}")
    for (kind, H), g in sorted(groups.items(), key=lambda kv: (kv[0][0], float(kv[0][1])
                                                                if kv[0][1] != "?" else 0)):
        print(f"{kind:<12} {H:>6} {len(g):>5} {sum(x[0] for x in g):>12.0f} "
              f"{sum(x[3] for x in g) / 3600:>8.3f} {sum(x[2] for x in g) / 3600:>8.3f} "
              f"{sum(x[4] for x in g) / 3600:>14.3f} {sum(x[5] for x in g):>8d} of {len(g)}")
    total = sum(r[5] for r in rows) / 3600
    wall = sum(r[4] for r in rows) / 3600
    multi = sum(r[6] for r in rows) / 3600
    n_cpu = sum(r[7] for r in rows)
    resumed = sum(1 for r in rows if r[8] is not None and r[8] > 1)
    print(f"total: {len(rows)} runs, {total:.2f} core hours in the simulations ({wall:.2f} h of "
          f"run wall time, {multi:.2f} h of it on more than one thread)")
    print(f"core time: CPU time for {n_cpu} of {len(rows)} runs ({resumed} of them resumed from "
          f"a checkpoint, all segments counted); wall time x threads of the last segment for "
          f"{len(rows) - n_cpu} (logs without CPU time)")


if __name__ == "__main__":
    main()
