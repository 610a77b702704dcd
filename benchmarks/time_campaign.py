"""Wall time of a whole campaign from a fresh working directory, recorded for the README.

Runs ``snakemake --cores N [--configfile CONFIG]`` in a new temporary directory (fresh
results; numba's on-disk cache as it is), prints the wall time with the machine's load and
records it in ``benchmarks/campaign_times.json`` under the configuration's name.  The README
quotes these records; ``tests/test_readme.py`` checks that it quotes them exactly.

    .venv/bin/python benchmarks/time_campaign.py                        # default campaign
    .venv/bin/python benchmarks/time_campaign.py --configfile config/segregation-sweep.yaml
    .venv/bin/python benchmarks/time_campaign.py --workdir /tmp/default-run   # keep the results
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RECORD = REPO / "benchmarks" / "campaign_times.json"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configfile", default=None)
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--no-record", action="store_true")
    ap.add_argument("--workdir", default=None,
                    help="run in this new (or empty) directory and keep its results")
    args = ap.parse_args()
    name = Path(args.configfile).stem if args.configfile else "config"
    if args.workdir:
        work = Path(args.workdir).resolve()
        if work.exists() and any(work.iterdir()):
            raise SystemExit(f"--workdir {work} is not empty: the timing needs fresh results")
        work.mkdir(parents=True, exist_ok=True)
        context = contextlib.nullcontext(str(work))
    else:
        context = tempfile.TemporaryDirectory(prefix="time-campaign-")
    with context as tmp:
        cmd = [sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile"),
               "--directory", tmp, "--cores", str(args.cores)]
        if args.configfile:
            cmd += ["--configfile", str(Path(args.configfile).resolve())]
        load0 = os.getloadavg()[0]
        t0 = time.monotonic()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.monotonic() - t0
        load1 = os.getloadavg()[0]
    if proc.returncode != 0:
        raise SystemExit(proc.stdout[-3000:] + proc.stderr[-3000:])
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO,
                            capture_output=True, text=True).stdout.strip()
    entry = {"minutes": round(wall / 60, 1), "cores": args.cores, "commit": commit,
             "date": dt.date.today().isoformat(), "load_before": round(load0, 2),
             "load_after": round(load1, 2), "cpus": os.cpu_count()}
    print(f"{name}: {entry['minutes']} min on {args.cores} cores (load {load0:.2f} -> "
          f"{load1:.2f}, {os.cpu_count()} CPUs, commit {commit})")
    if not args.no_record:
        records = json.loads(RECORD.read_text()) if RECORD.exists() else {}
        records[name] = entry
        RECORD.write_text(json.dumps(records, indent=2, sort_keys=True) + "\n")
        print(f"recorded in {RECORD.relative_to(REPO)}")


if __name__ == "__main__":
    main()
