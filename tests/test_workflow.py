"""Integration tests of the Snakemake campaign workflow (Snakefile, workflow/, config/).

* the tiny campaign (config/test-tiny.yaml) runs end to end -- bases, grid runs, the adaptive
  hstop search as a checkpoint chain, rows, table, fits, library, executed report -- and its
  library opens with the consumption API;
* `snakemake --lint` is clean;
* every invalid configuration fails before any job starts, naming the key and its range;
* a simulation job killed with SIGKILL mid-run, then the workflow rerun, ends with the same
  library content as the undisturbed run (the job resumes from its checkpoint);
* rerunning the library step with unchanged data reuses the library version.

Each workflow runs in its own temporary working directory (``--directory``), so the tests never
touch the repository's results/ or .snakemake/.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from granflow.closures import campaign_table, library_versions, open_library

REPO = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]
TINY = REPO / "config" / "test-tiny.yaml"
RESULTS = Path("results") / "test-tiny"


def snakemake(workdir, *args, timeout=600, configfile=TINY):
    cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(workdir),
           *args]
    if configfile is not None:
        cmd += ["--configfile", str(configfile)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def _check(proc):
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    return proc


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny campaign, run once undisturbed (shared by the tests of this module)."""
    work = tmp_path_factory.mktemp("tiny")
    t0 = time.monotonic()
    _check(snakemake(work, "--cores", "2"))
    return work, time.monotonic() - t0


def test_tiny_campaign_end_to_end(tiny):
    work, wall = tiny
    res = work / RESULTS
    lib = open_library(res / "closures.nc")  # verifies the content hash
    assert lib.attrs["library_name"] == "granflow-tiny"
    # generated from the configuration and the fits, not written by hand
    red = lib.attrs["reductions_vs_paper"]
    assert "chute box 6 x 4 (paper 20 x 10)" in red and "collision time t_c 0.02" in red
    assert "flow_rule: flow rule from steady runs" in red
    assert "6 x 4 box" in lib.attrs["library_note"]  # the config's free-text note
    kinds = set(lib.attrs["kinds"].split())
    assert {"hstop", "flow_rule", "friction", "alpha", "density", "stress_ratio"} <= kinds
    manifest = json.loads((res / "closures.json").read_text())
    assert manifest["version"] == 1 and manifest["content_hash"] == lib.attrs["content_hash"]
    assert (res / "library" / "granflow-tiny-v1.nc").is_file()
    # every run (grid and search) is either in the table or listed as excluded
    runs = {p.parent.relative_to(res).as_posix() for p in res.rglob("summary.json")}
    table = pd.read_csv(res / "campaign_table.csv")
    excluded = pd.read_csv(res / "excluded_runs.csv")
    assert set(table["run"]) | set(excluded["run"]) == runs
    assert len(campaign_table(lib)) == len(table) >= 1
    # the grid of the config (3 chute + 3 segregation runs) plus the search's own points
    assert len(runs) >= 6
    state = json.loads(sorted((res / "hstop" / "linear" / "lambda~1").glob("step~*.json"),
                              key=lambda p: int(p.stem.split("~")[1]))[-1].read_text())
    assert state["search"]["next"] is None and len(state["search"]["runs"]) == 3
    # the bisection chain at H = 2: two bracket runs, in the table, stopped as soon as decided
    steps = sorted((res / "hstop" / "linear" / "lambda~1" / "bisect" / "H~2" / "rep~0")
                   .glob("step~*.json"),
                   key=lambda p: int(p.stem.split("~")[1]))
    last = json.loads(steps[-1].read_text())
    assert last["bisection"]["next"] is None and len(last["bisection"]["runs"]) == 2
    for t, st in last["bisection"]["runs"]:
        run = f"bracket/linear/lambda~1/theta~{t:g}/H~2"
        assert run in runs and st in ("arrested", "flowing", "undecided")
        assert table.loc[table["run"] == run, "state"].item() == st
    for t, h, _ in state["search"]["runs"]:
        assert f"chute/linear/lambda~1/theta~{t:g}/H~{h:g}" in runs
    # a run directory has the Paramspace layout and every output of the job contract
    run = res / "chute" / "linear" / "lambda~1" / "theta~26" / "H~3"
    for f in ("summary.json", "profiles.nc", "series.nc", "final_state.npz", "params.yaml",
              "row.json", "simulate.log"):
        assert (run / f).is_file(), f
    assert "INFO" in (run / "simulate.log").read_text()  # progress/log lines of the job
    # spare cores: the workflow hands its --cores to the runs (granflow.engine.threads)
    import numba

    if numba.config.NUMBA_NUM_THREADS >= 2 and Path("/proc/stat").exists():
        for log in res.glob("*/linear/**/simulate.log"):
            assert "spare cores: {'max_threads': 2, 'enabled': True" in log.read_text(), log
    # one base for every run over (lambda = 1, 6 x 4)
    assert [p.relative_to(res).as_posix() for p in res.glob("bases/*/*/base.npy")] == \
        ["bases/lambda~1/box~6x4/base.npy"]
    # the executed report: every figure, as inline PNG and as files
    html = (res / "report.html").read_text()
    for title in ("What this library knows", "Flow-state map", "Flow rule", "Depth profiles",
                  "Bulk density", "Segregation", "Snapshot", "Held-out check", "Closure table",
                  "Continuum consumers"):
        assert title in html, title
    assert html.count("data:image/png;base64,") >= 6
    assert "Traceback" not in html
    figs = sorted(p.name for p in (res / "figures").glob("*.png"))
    # the continuum section: switch predictions always (an empty panel that says so when the
    # tiny campaign has no steady run); the shallow-layer bump only with a steady run
    steady = ((table["state"] == "steady")
              & ((table["kind"] == "chute") if "kind" in table else True)).any()
    assert figs == sorted(["density_K_alpha.png", "flow_rule.png", "flow_state_map.png",
                           "heldout_z.png", "profiles.png", "segregation.png", "snapshot.png",
                           "continuum_switch_predictions.png"]
                          + (["continuum_shallow_layer.png"] if steady else []))
    assert wall < 600


def test_rerun_of_library_step_reuses_the_version(tiny):
    work, _ = tiny
    res = work / RESULTS
    before = open_library(res / "closures.nc").attrs["content_hash"]
    _check(snakemake(work, str(RESULTS / "closures.nc"), "--cores", "2",
                     "--forcerun", "fit", "library"))
    manifest = json.loads((res / "closures.json").read_text())
    assert manifest["reused"] is True and manifest["version"] == 1
    assert library_versions(res / "library", "granflow-tiny") == [1]
    assert open_library(res / "closures.nc").attrs["content_hash"] == before


def test_dry_run_of_the_tiny_campaign_lists_every_rule(tmp_path):
    """The README's dry run (`snakemake -n --configfile config/test-tiny.yaml`) plans every
    stage, including `collect`, whose input waits on the unfinished hstop checkpoint chain."""
    proc = _check(snakemake(tmp_path, "-n", timeout=300))
    out = proc.stdout + proc.stderr
    table = dict(re.findall(r"^(\w+)\s+(\d+)$", out, re.M))
    # 3 grid + 3 segregation runs, the search's first point is a grid point: 6 simulations
    assert table.get("simulate") == "6" and table.get("row") == "6", out[-3000:]
    for rule in ("base", "warm_engine", "hstop_step", "collect", "fit", "library", "report"):
        assert table.get(rule) == "1", (rule, out[-3000:])
    assert "This was a dry-run" in out
    assert not (tmp_path / "results").exists()


def test_base_rule_makes_the_base_the_config_names(tmp_path):
    """`base:` settling friction, fill and band reach the base job's command (dry run, shell
    commands printed); left out, the defaults (a frictional pile, the text's band) do."""
    overlay = tmp_path / "base.yaml"
    overlay.write_text("base: {settle_mu_c: 0.0, fill_packing: 0.648, band: top}\n")
    commands = {}
    for name, extra in (("mercury", [str(overlay)]), ("default", [])):
        work = tmp_path / name
        work.mkdir()
        cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(work), "-n",
               "-p", "--configfile", str(TINY), *extra]
        proc = _check(subprocess.run(cmd, capture_output=True, text=True, timeout=300))
        commands[name] = [line for line in proc.stdout.splitlines() if "prepare-base" in line]
    assert len(commands["mercury"]) == 1, commands
    assert "--settle-mu-c 0.0 --fill-packing 0.648 --band top" in commands["mercury"][0]
    assert "--settle-mu-c 0.5 --fill-packing 0.6 --band paper" in commands["default"][0]


def test_bracket_box_gets_its_own_base_job(tmp_path):
    """``hstop_bisection.Lx/Ly``: a bracket run falls onto a base made in its own box, a steady
    grid run onto the campaign's (dry run of one run of each kind, shell commands printed)."""
    overlay = tmp_path / "box.yaml"
    overlay.write_text("campaigns:\n  chute:\n    hstop_bisection:\n      Lx: 5.0\n      Ly: 3.0\n")
    plans = {}
    for kind in ("bracket", "chute"):
        target = f"{RESULTS}/{kind}/linear/lambda~1/theta~25/H~3/summary.json"
        cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(tmp_path),
               "-n", "-p", "--configfile", str(TINY), str(overlay), "--", target]
        proc = _check(subprocess.run(cmd, capture_output=True, text=True, timeout=300))
        plans[kind] = (re.findall(r"prepare-base --lam 1 --Lx (\S+) --Ly (\S+)", proc.stdout),
                       re.findall(r"--base (\S+)", proc.stdout),
                       re.findall(r'"Lx": ([0-9.]+), "Ly": ([0-9.]+)', proc.stdout))
    assert plans["bracket"] == ([("5", "3")], [f"{RESULTS}/bases/lambda~1/box~5x3/base.npy"],
                                [("5.0", "3.0")])
    assert plans["chute"] == ([("6", "4")], [f"{RESULTS}/bases/lambda~1/box~6x4/base.npy"],
                              [("6.0", "4.0")])


def _bisection_plan(tmp_path, bisection_yaml):
    """Dry-run plan of the tiny campaign with ``hstop_bisection`` keys overlaid: (output, job
    counts by rule)."""
    overlay = tmp_path / "bisection.yaml"
    overlay.write_text("campaigns:\n  chute:\n    hstop_bisection:\n      " + bisection_yaml)
    work = tmp_path / "work"
    work.mkdir()
    cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(work), "-n",
           "--configfile", str(TINY), str(overlay)]
    proc = _check(subprocess.run(cmd, capture_output=True, text=True, timeout=300))
    out = proc.stdout + proc.stderr
    return out, dict(re.findall(r"^(\w+)\s+(\d+)$", out, re.M))


def test_continuation_chain_starts_each_bracket_run_from_the_flowing_run_above(tmp_path):
    """hstop_bisection.protocol: continuation (paper §6): the chain's first run falls fresh and
    flows; the next, 4 deg lower, starts from its final state (its summary names that state and
    its sha256), and both run under the arrest horizon (t_end 20 here) without the
    decisively-flowing stop."""
    overlay = tmp_path / "continuation.yaml"
    overlay.write_text(
        "campaigns:\n  chute:\n    hstop_bisection:\n      enabled: true\n      H: [2.0]\n"
        "      guess: {2.0: 32.0}\n      step: 4.0\n      tolerance: 1.0\n      max_runs: 2\n"
        "      protocol: continuation\n      arrest_horizon: 20.0\n")
    work = tmp_path / "work"
    work.mkdir()
    chain = RESULTS / "hstop" / "linear" / "lambda~1" / "bisect" / "H~2" / "rep~0" / "chain.json"
    cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(work),
           "--cores", "2", "--configfile", str(TINY), str(overlay), "--", str(chain)]
    _check(subprocess.run(cmd, capture_output=True, text=True, timeout=600))
    state = json.loads((work / chain).read_text())
    runs = state["bisection"]["runs"]
    assert [t for t, _ in runs] == [32.0, 28.0] and runs[0][1] != "arrested", runs
    res = work / RESULTS / "bracket" / "linear" / "lambda~1"
    first = json.loads((res / "theta~32" / "H~2" / "summary.json").read_text())
    second = json.loads((res / "theta~28" / "H~2" / "summary.json").read_text())
    assert "parent_state" not in json.dumps(first.get("parent") or {})
    parent_file = res / "theta~32" / "H~2" / "final_state.npz"
    assert Path(second["parent"]["parent_state"]) == parent_file.resolve()
    import hashlib
    assert second["parent"]["parent_state_sha256"] == hashlib.sha256(
        parent_file.read_bytes()).hexdigest()
    for summary in (first, second):
        assert summary["params"]["t_end"] == 20.0
        assert summary["params"]["stop_when_flowing"] is False


def test_bisection_chains_all_start_at_once(tmp_path):
    """Three hstop bisection chains (H = 2, 3, 5) are all in the plan from the start: three
    first steps and three chain files, so that the chains run side by side (before the
    per-chain rule, the collect rule's walk over the chains held each chain back until the
    previous one was finished: one chain at a time on any number of cores)."""
    out, table = _bisection_plan(tmp_path, "H: [2.0, 3.0, 5.0]\n")
    assert table.get("hstop_bisect_step") == "3", out[-3000:]
    assert table.get("hstop_bisect_chain") == "3", out[-3000:]
    for H in ("2", "3", "5"):
        assert f"bisect/H~{H}/rep~0/step~0.json" in out, H


def test_bisection_replicates_per_height(tmp_path):
    """``replicates: {H: n}`` gives only the named heights n chains (seeds seed .. seed + n - 1):
    three chains at H = 2 and one at H = 3 and 5 -- five first steps, rep~1 and rep~2 at H = 2
    only."""
    out, table = _bisection_plan(tmp_path, "H: [2.0, 3.0, 5.0]\n      replicates: {2.0: 3}\n")
    assert table.get("hstop_bisect_step") == "5", out[-3000:]
    assert table.get("hstop_bisect_chain") == "5", out[-3000:]
    for k in ("0", "1", "2"):
        assert f"bisect/H~2/rep~{k}/step~0.json" in out, k
    assert "bisect/H~3/rep~1/" not in out and "bisect/H~5/rep~1/" not in out


def test_replicate_bases_give_each_replicate_chain_a_base_of_its_own(tmp_path):
    """``hstop_bisection.replicate_bases``: replicate chain k of a height falls onto the base of
    seed base.seed + k (its own file, made by the base_replicate rule the same way as the
    campaign's base); chain 0 and every grid run keep the campaign's base; without the key all
    chains share it.  Combined with replicated grid runs it is refused (the hstop fit would
    join a grid run and a bracket chain of different bases)."""
    from granflow.campaign import grid as G
    from granflow.campaign.config import load_yaml, semantic_errors

    cfg = load_yaml(TINY)
    bis = cfg["campaigns"]["chute"]["hstop_bisection"]
    bis.update(replicates=3)
    rep2 = G.RunPoint("bracket", "linear", 1.0, 24.0, 2.0, replicate=2)
    grid_run = G.RunPoint("chute", "linear", 1.0, 24.0, 2.0)
    shared = "bases/lambda~1/box~6x4/base.npy"
    assert G.base_path(cfg, rep2) == shared and G.base_seed(cfg, rep2) == 1
    bis.update(replicate_bases=True)
    assert G.base_path(cfg, rep2) == "bases/lambda~1/box~6x4/seed~3/base.npy"
    assert G.base_seed(cfg, rep2) == 3
    assert G.base_path(cfg, G.RunPoint("bracket", "linear", 1.0, 24.0, 2.0)) == shared
    assert G.base_path(cfg, grid_run) == shared
    assert semantic_errors(cfg) == []
    cfg["numerics"]["replicates"] = 2
    errors = semantic_errors(cfg)
    assert len(errors) == 1 and "hstop_bisection.replicate_bases = true" in errors[0], errors
    # the workflow makes that base with the campaign's settings and the replicate's seed
    overlay = tmp_path / "bases.yaml"
    overlay.write_text("base: {band: top}\ncampaigns:\n  chute:\n    hstop_bisection:\n"
                       "      replicates: 3\n      replicate_bases: true\n")
    target = "results/test-tiny/bases/lambda~1/box~6x4/seed~3/base.npy"
    cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(tmp_path), "-n",
           "-p", "--configfile", str(TINY), str(overlay), "--", target]
    proc = _check(subprocess.run(cmd, capture_output=True, text=True, timeout=300))
    lines = [line for line in proc.stdout.splitlines() if "prepare-base" in line]
    assert len(lines) == 1 and "--seed 3 " in lines[0] and "--band top" in lines[0], proc.stdout
    assert "base_replicate" in proc.stdout


def test_job_records_hold_no_path_of_the_venv(tmp_path):
    """Snakemake reruns a job whose recorded params or command template changed.  The granflow
    executable's path used to be a param of every rule, so moving the project or recreating its
    venv elsewhere reran a whole campaign; the records of a finished job now hold no path of
    the Python that ran it, and a second run has nothing to do."""
    target = "results/test-tiny/bases/lambda~1/box~6x4/base.npy"
    cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(tmp_path),
           "--cores", "1", "--configfile", str(TINY), "--", target]
    _check(subprocess.run(cmd, capture_output=True, text=True, timeout=600))
    records = [json.loads(f.read_text())
               for f in (tmp_path / ".snakemake" / "metadata").iterdir() if f.is_file()]
    assert records, "no Snakemake job record"
    venv = str(Path(sys.executable).parent)
    for rec in records:
        assert venv not in json.dumps(rec.get("params")), rec.get("params")
        assert venv not in str(rec.get("code")), rec.get("code")
        assert str(rec.get("code")).startswith("granflow -v prepare-base")
    again = _check(subprocess.run(cmd[:-2] + ["-n", "--", target], capture_output=True,
                                  text=True, timeout=300))
    assert "Nothing to be done" in again.stdout + again.stderr


def test_long_sequential_work_is_scheduled_first(tmp_path):
    """Priorities in the plan of the tiny campaign: segregation runs (slowest sigma first) above
    hstop chain steps above steady runs (thick first) -- longest-processing-time order, so that
    a campaign does not end on one core running the last chain alone."""
    proc = _check(snakemake(tmp_path, "-n", timeout=300))
    out = proc.stdout + proc.stderr
    prio = {}
    for block in re.split(r"\n(?=(?:local)?(?:rule|checkpoint) )", out):
        head = block.split("\n", 1)[0]
        m = re.search(r"^\s+priority: ([0-9.]+)$", block, re.M)
        w = re.search(r"^\s+wildcards: (.*)$", block, re.M)
        if head.split()[-1].rstrip(":") in ("simulate", "hstop_step", "hstop_bisect_step"):
            prio[(head.split()[-1].rstrip(":"), w.group(1) if w else "")] = \
                float(m.group(1)) if m else 0.0
    seg = {k[1]: v for k, v in prio.items() if "kind=segregation" in k[1]}
    chute = {k[1]: v for k, v in prio.items() if "kind=chute" in k[1]}
    assert seg and chute, out[-3000:]
    assert min(seg.values()) > max(chute.values())
    by_sigma = sorted(seg.items(), key=lambda kv: float(re.search(r"sigma~([0-9.]+)", kv[0])[1]))
    assert [v for _, v in by_sigma] == sorted(v for _, v in by_sigma)  # sigma near 1 first
    steps = [v for (rule, _), v in prio.items() if rule == "hstop_step"]
    assert steps and min(steps) >= 1 > max(chute.values()) and max(steps) < min(seg.values())


def test_snakemake_report_of_the_tiny_campaign(tiny):
    """The README's `snakemake --report results/report.zip`, for the finished tiny campaign."""
    import zipfile

    work, _ = tiny
    _check(snakemake(work, "--report", "results/report.zip", timeout=600))
    with zipfile.ZipFile(work / "results" / "report.zip") as z:
        names = z.namelist()
    assert any(n.endswith("report.html") for n in names), names[:20]
    assert any(n.endswith("closures.nc") for n in names), names[:20]


def test_report_job_record_holds_the_notebooks_hash_not_its_path(tiny):
    """The report job's record names the notebook by its content hash (a param), not by its
    path (an input's path is recorded too, and moving the project then remade the report):
    editing the notebook remakes the report, moving the project does not."""
    import hashlib

    work, _ = tiny
    records = [json.loads(f.read_text())
               for f in (work / ".snakemake" / "metadata").iterdir() if f.is_file()]
    report = [r for r in records if r.get("rule") == "report"]
    assert len(report) == 3, [r.get("rule") for r in records]  # one per output
    sha = hashlib.sha256((REPO / "notebooks" / "campaign_report.py").read_bytes()).hexdigest()
    for rec in report:
        assert sha in json.dumps(rec.get("params")), rec.get("params")
        assert str(REPO) not in json.dumps(rec), json.dumps(rec)[:2000]
        assert "$GRANFLOW_REPORT_NOTEBOOK" in str(rec.get("code"))
    assert (work / RESULTS / "report.html").stat().st_size > 0


def test_lint_is_clean():
    proc = _check(snakemake(REPO, "--lint", configfile=None))
    assert "Congratulations, your workflow is in a good condition" in proc.stdout + proc.stderr


BAD_CONFIGS = {
    "theta_high": ("campaigns: {chute: {enabled: true, grids: [{theta: [95.0], H: [4.0]}]}}",
                   "campaigns.chute.grids[0].theta[0] = 95.0", "(0, 90)"),
    "theta_zero": ("campaigns: {segregation: {enabled: true, theta: 0.0}}",
                   "campaigns.segregation.theta = 0.0", "(0, 90)"),
    "H_zero": ("campaigns: {chute: {enabled: true, grids: [{theta: [24.0], H: [0.0]}]}}",
               "campaigns.chute.grids[0].H[0] = 0.0", "> 0"),
    "H_negative": ("campaigns: {segregation: {enabled: true, H: -2.0}}",
                   "campaigns.segregation.H = -2.0", "> 0"),
    "lambda_negative": ("campaigns: {chute: {enabled: true, lambda: [-1.0]}}",
                        "campaigns.chute.lambda[0] = -1.0", ">= 0"),
    "sigma_high": ("campaigns: {segregation: {enabled: true, sigma: [1.2]}}",
                   "campaigns.segregation.sigma[0] = 1.2", "(0, 1]"),
    "sigma_zero": ("campaigns: {segregation: {enabled: true, sigma: [0.0]}}",
                   "campaigns.segregation.sigma[0] = 0.0", "(0, 1]"),
    "unknown_law": ("campaigns: {chute: {enabled: true, contact_law: [hooke]}}",
                    "campaigns.chute.contact_law[0] = 'hooke'", "linear, hertz, plastic"),
    "unknown_key": ("numerics: {t_endd: 100.0}", "unknown key(s) ['t_endd']", "allowed keys"),
    "averaging_longer_than_run": ("numerics: {t_end: 100.0, averaging_time: 150.0}",
                                  "numerics.averaging_time = 150.0 is longer than the run, "
                                  "numerics.t_end = 100.0", "at most t_end"),
    "one_size_ratio": ("campaigns: {segregation: {enabled: true, sigma: [0.5, 1.0]}}",
                       "campaigns.segregation.sigma = [0.5, 1.0]", "at least 3 distinct size"),
    "slurm_over_limit": ("cluster: {over_limit: sometimes}", "cluster.over_limit = 'sometimes'",
                         "['cap', 'refuse']"),
    "base_band": ("base: {band: middle}", "base.band = 'middle'", "['paper', 'top']"),
    "base_settle_friction": ("base: {settle_mu_c: -0.5}", "base.settle_mu_c = -0.5", ">= 0"),
    "unknown_nested_key": ("campaigns: {chute: {enabled: true, hstop_search: {enabled: false, "
                           "H00: 3}}}", "unknown key(s) ['H00']", "allowed keys"),
}


@pytest.mark.parametrize("case", sorted(BAD_CONFIGS))
def test_invalid_config_fails_before_any_job(case, tmp_path):
    text, key, allowed = BAD_CONFIGS[case]
    bad = tmp_path / "bad.yaml"
    bad.write_text(text + "\n")
    proc = snakemake(tmp_path, "-n", "--cores", "1", configfile=bad, timeout=120)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert "invalid campaign configuration" in out and key in out and allowed in out, out[-3000:]
    assert not (tmp_path / "results").exists()  # nothing started


def _pids_of(run_dir: Path, rel: Path):
    """PIDs of `granflow simulate` processes working on ``run_dir`` (started by this test; the
    job's command line names the run directory relative to the working directory ``rel``)."""
    pids = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        args = [c.decode(errors="replace") for c in cmd]
        if "simulate" not in args or rel.as_posix() not in args:
            continue
        try:
            cwd = Path(os.readlink(d / "cwd"))
        except OSError:
            continue
        if (cwd / rel).resolve() == run_dir.resolve():
            pids.append(int(d.name))
    return pids


def test_killed_job_and_rerun_give_the_same_library(tiny, tmp_path):
    """SIGKILL one simulation job mid-run; the rerun resumes it and the library is identical."""
    ref_work, _ = tiny
    ref = open_library(ref_work / RESULTS / "closures.nc")
    rel = RESULTS / "chute" / "linear" / "lambda~1" / "theta~26" / "H~3"
    victim = tmp_path / rel
    cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(tmp_path),
           "--configfile", str(TINY), "--cores", "2", str(RESULTS / "closures.nc")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    killed = False
    deadline = time.monotonic() + 300
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if (victim / "checkpoint.npz").exists():
                pids = _pids_of(victim, rel)
                if pids:
                    for pid in pids:
                        os.kill(pid, signal.SIGKILL)
                    killed = True
                    break
            time.sleep(0.05)
        out, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert killed, "the victim job finished before it could be killed"
    assert proc.returncode != 0 and "Error in rule simulate" in out
    assert (victim / "checkpoint.npz").exists()        # kept for the rerun
    assert not (victim / "summary.json").exists()
    _check(snakemake(tmp_path, str(RESULTS / "closures.nc"), "--cores", "2"))
    assert "resumed from checkpoint" in (victim / "simulate.log").read_text()
    assert not (victim / "checkpoint.npz").exists()    # removed once the outputs exist
    lib = open_library(tmp_path / RESULTS / "closures.nc")
    assert lib.attrs["content_hash"] == ref.attrs["content_hash"]
    a = campaign_table(lib).set_index("run").sort_index()
    b = campaign_table(ref).set_index("run").sort_index()
    pd.testing.assert_frame_equal(a, b)


def test_restart_from_neighbour_chains_steady_runs_from_the_middle_angle(tmp_path):
    """``restart_from_neighbour: true``: the tiny grid's runs at H = 3 (18, 24, 26 deg) form a
    chain rooted at 24 deg: the 18 and 26 deg runs need 24's final state and start from it with
    --from-if-steady; 24 falls fresh.  Run for real, the 26 deg run's outputs name the 24 deg
    run as parent, or say why they could not (24 deg not steady)."""
    overlay = tmp_path / "restart.yaml"
    overlay.write_text("campaigns:\n  chute:\n    restart_from_neighbour: true\n")
    work = tmp_path / "work"
    work.mkdir()
    base = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(work),
            "--configfile", str(TINY), str(overlay)]
    proc = _check(subprocess.run([*base, "-n", "-p"], capture_output=True, text=True,
                                 timeout=300))
    out = proc.stdout + proc.stderr
    root = "chute/linear/lambda~1/theta~24/H~3/final_state.npz"
    cmds = [c for c in out.splitlines() if " simulate " in c and "chute/linear" in c]
    assert sum(f"--from-if-steady results/test-tiny/{root}" in c for c in cmds) == 2, out[-3000:]
    assert not any("theta~24/H~3/params.yaml" in c and "--from" in c for c in cmds)
    target = "results/test-tiny/chute/linear/lambda~1/theta~26/H~3/summary.json"
    _check(subprocess.run([*base, "--cores", "2", target], capture_output=True, text=True,
                          timeout=900))
    child = json.loads((work / target).read_text())
    parent = json.loads((work / "results/test-tiny/chute/linear/lambda~1/theta~24/H~3"
                         / "summary.json").read_text())
    if parent["flow_state"] == "steady":
        assert child["parent"]["parent_state"] == str((work / "results/test-tiny" / root).resolve())
        assert child["parent"]["parent_theta"] == 24.0
    else:
        assert repr(parent["flow_state"]) in child["parent"]["restart_skipped"]
