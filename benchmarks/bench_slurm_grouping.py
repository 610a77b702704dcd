"""Slurm overhead of the tiny campaign, with and without grouping short jobs.

Runs config/test-tiny.yaml three ways in fresh working directories, interleaved ``--repeat``
times: locally (``--cores 2``, the peer), through ``profiles/slurm`` with its ``groups``
removed (every job its own Slurm job: the profile before grouping), and through
``profiles/slurm`` as shipped (a run's row in its simulation's job, collect -> report in one
job).  Prints wall times, Slurm jobs submitted, the overhead over the local run and the library
content hash of every run (all must be equal).

Needs a running Slurm (``bash workflow/cluster/local-slurm.sh start``) and the plugin
(``pip install -e ".[cluster]"``).

    .venv/bin/python benchmarks/bench_slurm_grouping.py [--repeat 1]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "config" / "test-tiny.yaml"
RECORD = REPO / "benchmarks" / "slurm_grouping.json"


def ungrouped_profile(dest: Path) -> Path:
    """A copy of profiles/slurm without its `groups` block."""
    text = (REPO / "profiles" / "slurm" / "config.yaml").read_text()
    text = re.sub(r"\ngroups:\n(?:  .*\n)+", "\n", text)
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "config.yaml").write_text(text)
    return dest


def run(workdir: Path, profile: Path | None) -> dict:
    cmd = [sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile"),
           "--directory", str(workdir), "--configfile", str(TINY)]
    cmd += ["--workflow-profile", str(profile)] if profile else ["--cores", "2"]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    wall = time.monotonic() - t0
    out = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{out[-3000:]}")
    manifest = json.loads((workdir / "results" / "test-tiny" / "closures.json").read_text())
    return {"wall_s": wall, "slurm_jobs": out.count("has been submitted with SLURM jobid"),
            "hash": manifest["content_hash"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--no-record", action="store_true",
                    help="do not write benchmarks/slurm_grouping.json")
    ap.add_argument("--no-warmup", action="store_true",
                    help="skip the unmeasured local run that fills numba's on-disk cache")
    args = ap.parse_args()
    if shutil.which("sbatch") is None:
        raise SystemExit("no Slurm here: bash workflow/cluster/local-slurm.sh install && ... start")
    results = {"local": [], "slurm, ungrouped": [], "slurm, grouped": []}
    with tempfile.TemporaryDirectory(prefix="bench-slurm-", dir=os.environ.get("TMPDIR")) as tmp:
        tmp = Path(tmp)
        profiles = {"local": None, "slurm, ungrouped": ungrouped_profile(tmp / "ungrouped"),
                    "slurm, grouped": REPO / "profiles" / "slurm"}
        if not args.no_warmup:
            res = run(tmp / "warmup", None)
            print(f"warm-up (local, unmeasured) {res['wall_s']:.1f} s", flush=True)
            shutil.rmtree(tmp / "warmup", ignore_errors=True)
        for r in range(args.repeat):
            for name, profile in profiles.items():
                work = tmp / f"{name.replace(', ', '-').replace(' ', '')}-{r}"
                res = run(work, profile)
                results[name].append(res)
                print(f"[{r}] {name:18s} {res['wall_s']:7.1f} s  {res['slurm_jobs']:3d} Slurm jobs"
                      f"  {res['hash']}  (load {os.getloadavg()[0]:.2f})", flush=True)
                shutil.rmtree(work, ignore_errors=True)
    local = min(r["wall_s"] for r in results["local"])
    print("\nbest of", args.repeat, "(overhead = wall - local wall; ratio = wall / local wall)")
    for name, rs in results.items():
        best = min(r["wall_s"] for r in rs)
        print(f"{name:18s} {best:7.1f} s  overhead {best - local:6.1f} s  ratio {best / local:5.2f}"
              f"  jobs {rs[0]['slurm_jobs']}")
    hashes = {r["hash"] for rs in results.values() for r in rs}
    print("library content hashes:", "all equal" if len(hashes) == 1 else "DIFFER", *hashes)
    if not args.no_record:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO,
                                capture_output=True, text=True).stdout.strip()
        record = {name: {"wall_s": round(min(r["wall_s"] for r in rs), 1),
                         "slurm_jobs": rs[0]["slurm_jobs"]} for name, rs in results.items()}
        record.update(commit=commit, repeat=args.repeat, load=round(os.getloadavg()[0], 2),
                      hashes_equal=len(hashes) == 1)
        RECORD.write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
        print(f"recorded in {RECORD.relative_to(REPO)} (the README quotes the job counts)")
    return 0 if len(hashes) == 1 else 1


if __name__ == "__main__":
    raise SystemExit(main())
