"""The Slurm side of the campaign workflow (granflow.campaign.cluster, profiles/slurm).

Fast tests (default suite): Slurm time limits parse, requests above a partition's limits are
capped or refused with a message naming rule, request and limit, the status command follows
the cluster's accounting.

``cluster`` tests (``pytest -m cluster``; need a running Slurm -- ``bash
workflow/cluster/local-slurm.sh install && bash workflow/cluster/local-slurm.sh start`` -- and
``pip install -e ".[cluster]"``): the README's cluster commands, i.e. the tiny campaign through
``profiles/slurm``, give a library with the same content hash as a local run; a request the
cluster cannot satisfy fails before any job is submitted.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from granflow.campaign import cluster as C

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "config" / "test-tiny.yaml"
SNAKEMAKE = [sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile")]


@pytest.mark.parametrize("text,minutes", [
    ("UNLIMITED", None), ("INFINITE", None), ("30", 30), ("1:30:00", 90), ("2-00:00:00", 2880),
    ("1-12", 2160), ("0:10", 1), ("45:30", 46)])
def test_slurm_time_limits_parse_to_minutes(text, minutes):
    assert C.parse_slurm_time(text) == minutes


LIMITS = C.PartitionLimits("debug", max_cpus=2, max_mem_mb=24000, max_runtime=60)


def test_requests_above_cpus_and_time_are_capped_with_a_message():
    fitted, msgs = C.fit_request("simulate", {"cpus_per_task": 4, "runtime": 2880,
                                              "mem_mb": 4000}, LIMITS)
    assert fitted == {"cpus_per_task": 2, "runtime": 60, "mem_mb": 4000}
    assert msgs == [
        "rule simulate: cpus_per_task = 4 exceeds what partition 'debug' can give (2 CPUs on "
        "its largest node): capped to 2",
        "rule simulate: runtime = 2880 exceeds what partition 'debug' can give (60 minutes "
        "MaxTime): capped to 60"]
    same, none = C.fit_request("row", {"cpus_per_task": 1, "runtime": 15, "mem_mb": 2000}, LIMITS)
    assert same == {"cpus_per_task": 1, "runtime": 15, "mem_mb": 2000} and none == []


def test_memory_above_the_largest_node_and_refuse_policy_are_refused():
    with pytest.raises(C.ClusterRequestError, match=r"rule report: mem_mb = 64000 exceeds what "
                       r"partition 'debug' can give \(24000 MB memory on its largest node\)"):
        C.fit_request("report", {"cpus_per_task": 1, "runtime": 10, "mem_mb": 64000}, LIMITS)
    with pytest.raises(C.ClusterRequestError, match="cpus_per_task = 4 .*pend forever.*"
                       "numerics.threads"):
        C.fit_request("simulate", {"cpus_per_task": 4, "runtime": 10, "mem_mb": 10}, LIMITS,
                      over_limit="refuse")


def test_plan_takes_threads_and_overrides_from_the_configuration():
    plan = C.ClusterPlan({"cluster": {"partition": "short", "account": "proj1",
                                      "resources": {"fit": {"runtime": 5}}}}, threads=4)
    assert plan.partition == "short" and plan.account == "proj1"
    assert plan.requested("simulate")["cpus_per_task"] == 4
    assert plan.requested("fit") == {"cpus_per_task": 1, "runtime": 5, "mem_mb": 4000}
    assert plan.fitted("simulate", on_slurm=False)["cpus_per_task"] == 4  # locally: as asked


@pytest.mark.parametrize("config_out,sacct_ok,expected", [
    ("AccountingStorageType   = accounting_storage/none\n", True, "squeue"),
    ("AccountingStorageType   = accounting_storage/slurmdbd\n", True, "sacct"),
    ("AccountingStorageType   = accounting_storage/slurmdbd\n", False, "squeue"),
    (None, False, "squeue")])
def test_status_command_follows_accounting(monkeypatch, config_out, sacct_ok, expected):
    def fake_run(cmd):
        if cmd[:3] == ["scontrol", "show", "config"]:
            return config_out
        if cmd[0] == "sacct":
            return "" if sacct_ok else None
        return None
    monkeypatch.setattr(C, "_run", fake_run)
    assert C.slurm_status_command() == expected


# ----------------------------------------------------------------------------- on a real Slurm
def _slurm_up() -> bool:
    if shutil.which("sinfo") is None:
        return False
    try:
        proc = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True,
                              timeout=20)
    except (OSError, subprocess.SubprocessError):
        return False
    return proc.returncode == 0 and any(s.startswith(("idle", "mix", "alloc"))
                                        for s in proc.stdout.split())


def _plugin_installed() -> bool:
    try:
        import snakemake_executor_plugin_slurm  # noqa: F401
    except ImportError:
        return False
    return True


def readme_cluster_commands() -> list[str]:
    """The commands of the README's "Running on a cluster" code block."""
    text = (REPO / "README.md").read_text()
    section = text.split("## Running on a cluster", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    return [line.split("  #")[0].strip() for line in block.splitlines()
            if line.strip() and not line.lstrip().startswith("#")]


def test_readme_cluster_block_is_what_the_cluster_test_runs():
    cmds = readme_cluster_commands()
    assert cmds == [
        "sudo bash workflow/cluster/local-slurm.sh install",
        "sudo bash workflow/cluster/local-slurm.sh start",
        '.venv/bin/pip install -e ".[cluster]"',
        ".venv/bin/snakemake --workflow-profile profiles/slurm --configfile config/test-tiny.yaml",
        "sudo bash workflow/cluster/local-slurm.sh stop",
    ]


def _snakemake(workdir, *args, timeout=1800):
    t0 = time.monotonic()
    proc = subprocess.run([*SNAKEMAKE, "--directory", str(workdir), *args],
                          capture_output=True, text=True, timeout=timeout, cwd=REPO)
    return proc, time.monotonic() - t0


@pytest.fixture(scope="module")
def local_tiny(tmp_path_factory):
    work = tmp_path_factory.mktemp("local")
    proc, wall = _snakemake(work, "--cores", "2", "--configfile", str(TINY))
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return work, wall


def _hash(work):
    return json.loads((work / "results" / "test-tiny" / "closures.json").read_text())[
        "content_hash"]


@pytest.mark.cluster
@pytest.mark.skipif(not _slurm_up(), reason="no Slurm node up")
@pytest.mark.skipif(not _plugin_installed(), reason='pip install -e ".[cluster]"')
def test_tiny_campaign_through_the_slurm_profile_equals_the_local_run(local_tiny, tmp_path):
    """The README's cluster command (in a scratch directory) against a local run."""
    local_work, local_wall = local_tiny
    cmd = readme_cluster_commands()[3].split()
    assert cmd[:2] == [".venv/bin/snakemake", "--workflow-profile"]
    proc, wall = _snakemake(tmp_path, *cmd[1:])
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    jobs = out.count("has been submitted with SLURM jobid")
    groups = re.findall(r"slurm_logs/group_(\w+?)_", out)
    h_local, h_slurm = _hash(local_work), _hash(tmp_path)
    print(f"\nlocal run:  {local_wall:6.1f} s  library {h_local}")
    print(f"slurm run:  {wall:6.1f} s  library {h_slurm}  ({jobs} Slurm jobs, groups "
          f"{sorted(set(groups))}, status command {C.slurm_status_command()}, load "
          f"{os.getloadavg()[0]:.2f})")
    assert h_slurm == h_local
    # short jobs ride along: no Slurm job of its own for a row, collect, fit, library, report
    for rule in ("row", "collect", "fit", "library", "report"):
        assert f"slurm_logs/rule_{rule}/" not in out, rule
    assert {"run", "closures"} <= set(groups)


@pytest.mark.cluster
@pytest.mark.skipif(not _slurm_up(), reason="no Slurm node up")
@pytest.mark.skipif(not _plugin_installed(), reason='pip install -e ".[cluster]"')
def test_impossible_request_fails_before_any_job_is_submitted(tmp_path):
    limits = C.slurm_partition_limits()
    assert limits is not None and limits.max_cpus == os.cpu_count()
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"cluster: {{resources: {{report: {{mem_mb: {limits.max_mem_mb * 4}}}}}}}\n")
    proc, wall = _snakemake(tmp_path, "--workflow-profile", str(REPO / "profiles" / "slurm"),
                            "--configfile", str(TINY), str(bad), timeout=300)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert (f"rule report: mem_mb = {limits.max_mem_mb * 4} exceeds what partition "
            f"'{limits.partition}' can give ({limits.max_mem_mb} MB memory") in out, out[-3000:]
    assert "has been submitted with SLURM jobid" not in out
    assert not (tmp_path / "results").exists()


@pytest.mark.cluster
@pytest.mark.skipif(not _slurm_up(), reason="no Slurm node up")
@pytest.mark.skipif(os.geteuid() != 0, reason="local-slurm.sh needs root")
def test_local_slurm_script_is_idempotent():
    """install/start on a running cluster only check it; stop twice, start again: back up."""
    script = ["bash", str(REPO / "workflow" / "cluster" / "local-slurm.sh")]

    def run(cmd):
        proc = subprocess.run([*script, cmd], capture_output=True, text=True, timeout=180)
        return proc.returncode, proc.stdout + proc.stderr

    rc, out = run("install")
    assert rc == 0 and "already installed" in out, out
    rc, out = run("start")
    assert rc == 0 and "slurmctld running" in out and "is idle" in out, out
    for _ in range(2):
        rc, out = run("stop")
        assert rc == 0, out
    assert "slurmd not running" in out and "slurmctld not running" in out
    rc, _ = run("status")
    assert rc == 1
    rc, out = run("start")
    assert rc == 0 and "started slurmctld" in out, out
    assert _slurm_up()
