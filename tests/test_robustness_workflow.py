"""The whole campaign workflow under kills, corruption, concurrency and bad folders (issue 19 §2).

* **Three kills.**  The tiny campaign (config/test-tiny.yaml) is killed with SIGKILL at three
  moments -- during the simulations (Snakemake alone is killed: its jobs must not run on as
  orphans), during the fits (Snakemake alone) and during the library write (the whole process
  group, the moment the library's temporary file exists) -- and rerun as the README says
  (``snakemake --unlock``, then ``snakemake --cores 2 --rerun-incomplete``).  Each must end with
  the library content hash of an undisturbed campaign, version 1 only, no granflow process of
  the campaign left and no partial file under results/.
* **Corrupt outputs.**  A truncated profiles.nc / summary.json of one run in a finished campaign:
  the rerun names the file, recomputes that run only and gives the same library; no other
  output is lost.
* **Two workflows** on one results folder: the second is refused (Snakemake's incomplete-output
  check, or with --rerun-incomplete its lock), the first finishes with the undisturbed library.
* **Read-only or full results folder**: the workflow fails before any job, with a clear message.

These run several tiny campaigns (2-4 minutes each on 2 busy cores): ``pytest -m slow``.
Each workflow runs in its own temporary working directory (``--directory``).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from granflow.closures import campaign_table, library_versions, open_library

REPO = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]
TINY = REPO / "config" / "test-tiny.yaml"
RESULTS = Path("results") / "test-tiny"
PARTIAL = re.compile(r"^\..+\.(tmp-.+|staging-\d+-[0-9a-f]+)$")


def snakemake_cmd(work, *args, configfile=TINY):
    cmd = [*SNAKEMAKE, "--snakefile", str(REPO / "Snakefile"), "--directory", str(work), *args]
    if configfile is not None:
        cmd += ["--configfile", str(configfile)]
    return cmd


def snakemake(work, *args, timeout=900, configfile=TINY):
    return subprocess.run(snakemake_cmd(work, *args, configfile=configfile),
                          capture_output=True, text=True, timeout=timeout)


def check(proc):
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    return proc


def start(work, *args, log=None):
    """Start a workflow in its own session (so that its process group can be killed)."""
    out = open(log or os.devnull, "w")
    return subprocess.Popen(snakemake_cmd(work, *args), stdout=out, stderr=subprocess.STDOUT,
                            start_new_session=True)


def granflow_processes(work: Path) -> list[tuple[int, str]]:
    """(pid, command line) of the granflow processes working in ``work`` (cwd at or below it)."""
    found = []
    work = work.resolve()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        try:
            cwd = Path(os.readlink(d / "cwd")).resolve()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            comm = (d / "comm").read_text().strip()
        except OSError:
            continue
        if (cwd == work or work in cwd.parents) and ("granflow" in cmd or comm == "granflow-sim"):
            found.append((int(d.name), cmd.strip()))
    return found


def wait_no_processes(work: Path, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        procs = granflow_processes(work)
        if not procs:
            return time.monotonic() - (deadline - timeout)
        time.sleep(0.1)
    raise AssertionError(f"processes still running in {work}: {granflow_processes(work)}")


def assert_no_partial_files(res: Path):
    """Nothing half-written under the results folder: no temporaries of atomic writes, no
    checkpoint or pid file, and every netCDF, npz and JSON file reads back."""
    bad = []
    for p in res.rglob("*"):
        if not p.is_file():
            continue
        if PARTIAL.match(p.name) or p.name in ("checkpoint.npz", "simulate.pid") \
                or p.name.startswith(".granflow-write-probe"):
            bad.append(f"{p}: left behind")
            continue
        try:
            if p.suffix == ".nc":
                with xr.open_dataset(p) as ds:
                    ds.load()
            elif p.suffix == ".npz":
                with np.load(p) as z:
                    for k in z.files:
                        z[k]
            elif p.suffix == ".npy":
                np.load(p)
            elif p.suffix == ".json":
                json.loads(p.read_text())
        except Exception as exc:  # noqa: BLE001 - any failure is the finding
            bad.append(f"{p}: {type(exc).__name__}: {exc}")
    assert not bad, "\n".join(bad)


def library_summary(work: Path):
    res = work / RESULTS
    lib = open_library(res / "closures.nc")
    manifest = json.loads((res / "closures.json").read_text())
    return lib, manifest


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The undisturbed tiny campaign."""
    work = tmp_path_factory.mktemp("reference")
    t0 = time.monotonic()
    check(snakemake(work, "--cores", "2"))
    lib, manifest = library_summary(work)
    print(f"\nreference campaign: {time.monotonic() - t0:.0f} s, library "
          f"{lib.attrs['content_hash']} (v{manifest['version']})")
    return work, lib


def _library_write_started(work: Path) -> bool:
    lib_dir = work / RESULTS / "library"
    try:
        return any(PARTIAL.match(n) for n in os.listdir(lib_dir))
    except OSError:
        return False


def _running(work: Path, words) -> bool:
    return any(all(w in cmd for w in words) for _, cmd in granflow_processes(work))


def _simulating(work: Path) -> bool:
    """A simulation job runs and some run has checkpointed (it is mid-run)."""
    return _running(work, ("simulate",)) and any((work / RESULTS).rglob("checkpoint.npz"))


MOMENTS = {
    # moment: (condition, poll interval in s, what is killed)
    "simulations": (_simulating, 0.05, "snakemake"),
    "fits": (lambda w: _running(w, ("campaign", "fit")), 0.01, "snakemake"),
    "library write": (_library_write_started, 0.001, "process group"),
}


@pytest.mark.slow
@pytest.mark.parametrize("moment", list(MOMENTS))
def test_campaign_killed_and_rerun_as_the_readme_says(reference, tmp_path, moment):
    ref_work, ref_lib = reference
    condition, poll, victim = MOMENTS[moment]
    log = tmp_path / "killed-run.log"
    proc = start(tmp_path, "--cores", "2", log=log)
    deadline = time.monotonic() + 900
    hit = False
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if condition(tmp_path):
                hit = True
                break
            time.sleep(poll)
        assert hit, f"the campaign ended before the moment '{moment}' was seen"
        if victim == "snakemake":
            os.kill(proc.pid, signal.SIGKILL)
        else:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    left_at_kill = sorted(str(p.relative_to(tmp_path)) for p in (tmp_path / RESULTS).rglob("*")
                          if p.is_file() and (PARTIAL.match(p.name)
                                              or p.name == "checkpoint.npz"))
    # no orphans: jobs of a killed Snakemake stop by themselves within seconds
    stopped_after = wait_no_processes(tmp_path, timeout=20.0)
    assert not (tmp_path / RESULTS / "closures.json").exists() or moment != "simulations"
    # the README: unlock once, then rerun with --rerun-incomplete
    unlock = snakemake(tmp_path, "--unlock", timeout=300)
    check(unlock)
    t0 = time.monotonic()
    rerun = check(snakemake(tmp_path, "--cores", "2", "--rerun-incomplete"))
    rerun_s = time.monotonic() - t0
    lib, manifest = library_summary(tmp_path)
    print(f"\nkilled during {moment} ({victim}; partial files at the kill: {left_at_kill}); "
          f"orphans gone after {stopped_after:.1f} s; rerun {rerun_s:.0f} s; library "
          f"{lib.attrs['content_hash']} (reference {ref_lib.attrs['content_hash']})")
    assert lib.attrs["content_hash"] == ref_lib.attrs["content_hash"]
    assert manifest["version"] == 1 and library_versions(tmp_path / RESULTS / "library",
                                                         "granflow-tiny") == [1]
    pd.testing.assert_frame_equal(campaign_table(lib).set_index("run").sort_index(),
                                  campaign_table(ref_lib).set_index("run").sort_index())
    assert not granflow_processes(tmp_path)
    assert_no_partial_files(tmp_path / RESULTS)
    if moment == "simulations":
        assert "resumed from checkpoint" in "".join(
            p.read_text() for p in (tmp_path / RESULTS).rglob("simulate.log")), rerun.stdout[-2000:]
    if moment == "library write":
        assert any("library" in p for p in left_at_kill), left_at_kill


def _copy_campaign(src: Path, dst: Path):
    shutil.copytree(src, dst, symlinks=True, dirs_exist_ok=True)  # copy2: mtimes kept


def _fingerprints(res: Path, skip: str, forced_rows: bool = False):
    """(mtime, sha) of every run output outside run ``skip`` and of the bases; with
    ``forced_rows`` (``--forcerun row`` rewrites every row.json) only the sha of row.json."""
    import hashlib

    out = {}
    for p in sorted(res.rglob("*")):
        rel = p.relative_to(res).as_posix()
        if not p.is_file() or rel.startswith(skip) or not (
                rel.startswith(("chute/", "segregation/", "bases/", "hstop/"))):
            continue
        if p.name.endswith(".log"):
            continue
        sha = hashlib.sha256(p.read_bytes()).hexdigest()
        out[rel] = sha if forced_rows and p.name == "row.json" else (p.stat().st_mtime_ns, sha)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", ["profiles.nc", "summary.json"])
def test_corrupt_run_output_recomputes_that_run_only(reference, tmp_path, name):
    """Truncate one output of one finished run: the rerun names the file and what is wrong,
    recomputes that run only (every other run's files stay as they were), and the library is
    the undisturbed one."""
    ref_work, ref_lib = reference
    _copy_campaign(ref_work, tmp_path)
    rel = "chute/linear/lambda~1/theta~26/H~3"
    target = tmp_path / RESULTS / rel / name
    data = target.read_bytes()
    target.write_bytes(data[: len(data) // 3])
    before = _fingerprints(tmp_path / RESULTS, rel)
    first = snakemake(tmp_path, "--cores", "2")
    out = first.stdout + first.stderr
    row_log = (tmp_path / RESULTS / rel / "row.log").read_text()
    print(f"\n{name} truncated -> {row_log.strip()}")
    assert first.returncode != 0 and "Error in rule row" in out, out[-3000:]
    assert f"'{RESULTS / rel / name}'" in row_log and "truncated" in row_log, row_log
    assert "removed it" in row_log and "rerun the workflow to recompute this run" in row_log
    assert not target.exists()
    second = check(snakemake(tmp_path, "--cores", "2"))
    ran = re.findall(r"rule simulate:\n(?:.*\n)*?\s+wildcards: kind=(\w+), law=(\w+), "
                     r"point=(\S+)", second.stdout + second.stderr)
    assert [f"{k}/{law}/{pt}" for k, law, pt in ran] == [rel], ran
    assert _fingerprints(tmp_path / RESULTS, rel) == before  # nothing else touched
    lib, _ = library_summary(tmp_path)
    assert lib.attrs["content_hash"] == ref_lib.attrs["content_hash"]
    assert_no_partial_files(tmp_path / RESULTS)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["series.nc", "final_state.npz"])
def test_corrupt_output_not_read_by_the_row_rule(reference, tmp_path, name):
    """series.nc and final_state.npz are not inputs of the row rule, so their corruption is
    found when the row step runs again (here: ``--forcerun row``); then as above."""
    ref_work, ref_lib = reference
    _copy_campaign(ref_work, tmp_path)
    rel = "segregation/linear/lambda~1/theta~28/H~4/sigma~0.75"
    target = tmp_path / RESULTS / rel / name
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0x55  # one byte changed, same size
    target.write_bytes(bytes(data))
    before = _fingerprints(tmp_path / RESULTS, rel, forced_rows=True)
    first = snakemake(tmp_path, "--cores", "2", "--forcerun", "row")
    row_log = (tmp_path / RESULTS / rel / "row.log").read_text()
    print(f"\n{name} one byte changed -> {row_log.strip()}")
    assert first.returncode != 0
    assert f"'{RESULTS / rel / name}'" in row_log and "removed it" in row_log, row_log
    second = check(snakemake(tmp_path, "--cores", "2"))
    ran = re.findall(r"rule simulate:\n(?:.*\n)*?\s+wildcards: kind=(\w+), law=(\w+), "
                     r"point=(\S+)", second.stdout + second.stderr)
    assert [f"{k}/{law}/{pt}" for k, law, pt in ran] == [rel], ran
    # the other runs' outputs untouched; their forced rows rewritten with the same content
    assert _fingerprints(tmp_path / RESULTS, rel, forced_rows=True) == before
    lib, _ = library_summary(tmp_path)
    assert lib.attrs["content_hash"] == ref_lib.attrs["content_hash"]


@pytest.mark.slow
def test_second_workflow_on_the_same_folder_is_refused(reference, tmp_path):
    """A second Snakemake on the folder of a running campaign is refused: started plainly it
    stops at the running jobs' incomplete outputs (or the lock); started as the profiles do,
    with --rerun-incomplete (which skips that check), Snakemake's lock refuses it.  The first
    workflow is not disturbed and ends with the undisturbed library."""
    ref_work, ref_lib = reference
    first = start(tmp_path, "--cores", "2", log=tmp_path / "first.log")
    try:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and first.poll() is None \
                and not _simulating(tmp_path):
            time.sleep(0.05)
        assert first.poll() is None, "the first workflow ended too soon"
        for extra in ((), ("--rerun-incomplete",)):
            second = snakemake(tmp_path, "--cores", "2", *extra, timeout=300)
            out = second.stdout + second.stderr
            refusal = [l for l in out.splitlines()
                       if "lock" in l.lower() or "IncompleteFilesException" in l]
            print(f"\nsecond workflow {' '.join(extra) or '(plain)'}: rc {second.returncode}: "
                  + " | ".join(refusal)[:300])
            assert second.returncode != 0
            locked = "Directory cannot be locked" in out or "LockException" in out
            assert locked or (not extra and "IncompleteFilesException" in out), out[-2000:]
            assert "rule simulate:" not in out  # it started no job
            assert first.poll() is None  # the first one was not disturbed
        assert first.wait(timeout=900) == 0, (tmp_path / "first.log").read_text()[-3000:]
    finally:
        if first.poll() is None:
            os.killpg(first.pid, signal.SIGKILL)
    lib, manifest = library_summary(tmp_path)
    assert lib.attrs["content_hash"] == ref_lib.attrs["content_hash"] and manifest["version"] == 1
    assert_no_partial_files(tmp_path / RESULTS)
    assert not granflow_processes(tmp_path)


def _unshare_available():
    try:
        return subprocess.run(["unshare", "-rm", "true"], capture_output=True,
                              timeout=30).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


@pytest.mark.skipif(not _unshare_available(), reason="needs unshare -rm (namespaces)")
@pytest.mark.parametrize("options,expect", [
    ("ro,size=1m", "is not writable: writing in 'results' failed (Read-only file system)"),
    ("size=256k", "free, the campaign (6 runs left) needs about"),
])
def test_read_only_or_full_results_folder_fails_before_any_job(tmp_path, options, expect):
    """A tmpfs mounted on results/ in a private mount namespace: read-only, or 256 KiB (the
    tiny campaign writes ~9 MB).  The workflow stops at once with the message; no job ran."""
    (tmp_path / "results").mkdir()
    script = (f"mount -t tmpfs -o {options} tmpfs {tmp_path / 'results'} && exec \"$@\"")
    t0 = time.monotonic()
    proc = subprocess.run(["unshare", "-rm", "sh", "-c", script, "sh",
                           *snakemake_cmd(tmp_path, "--cores", "2")],
                          capture_output=True, text=True, timeout=300)
    wall = time.monotonic() - t0
    out = proc.stdout + proc.stderr
    print(f"\n{options}: {[l for l in out.splitlines() if 'output folder' in l]}")
    assert proc.returncode != 0
    assert expect in out, out[-3000:]
    assert "Select jobs to execute" not in out and "rule base" not in out
    assert wall < 120
