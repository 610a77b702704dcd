"""Single runs under kills, corruption and bad output folders (issue 19, section 2).

* a bidisperse (segregation) run killed with SIGKILL mid-run and run again ends bit-identical
  to an undisturbed one -- particles, energy series, segregation monitor and profiles;
* a truncated or corrupt checkpoint gives an error naming the file and what is wrong, is
  removed, and the rerun recomputes the run from t = 0 to the undisturbed numbers;
* truncated or corrupt run outputs (final_state.npz, profiles.nc, series.nc, summary.json)
  are refused by the step that reads them, naming the file and the problem;
* a read-only or full output folder fails before any compute, with a clear message.

Soft particles (t_c = 0.02) in a 6 x 4 box keep each run to seconds (t_end = 30 is ~3 s of
wall time: long enough to be killed mid-run with checkpoints every 0.1 s).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

from granflow.campaign.collect import derive_row, verify_run_outputs
from granflow.simulate import CorruptFileError, load_state, prepare_base_file

BIDISPERSE = dict(theta=28.0, H=4.0, lam=1.0, Lx=6.0, Ly=4.0, seed=3, t_end=30.0, t_c=0.02,
                  base_layers=4.0, sigma=0.75, phi0=0.5, checkpoint_every_s=0.1,
                  averaging_time=3.0, check_every=1.0, cg_window=2.0, sample_interval=0.04)


def run_cli(params_file, out, base, wait=True, timeout=600):
    cmd = [sys.executable, "-m", "granflow.cli", "simulate", str(params_file), "--out", str(out),
           "--base", str(base)]
    if wait:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def checkpoint_time(ckpt: Path) -> float:
    try:
        with np.load(ckpt) as data:
            return json.loads(str(data["meta_json"]))["time"]
    except Exception:  # being replaced right now (atomic rename): try again
        return -1.0


def kill_when_checkpointed(proc, ckpt: Path, t_min: float, timeout=300.0):
    """SIGKILL ``proc`` once its checkpoint is past simulated time ``t_min``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if ckpt.exists() and checkpoint_time(ckpt) > t_min:
            break
        time.sleep(0.01)
    assert proc.poll() is None, "the run finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return checkpoint_time(ckpt)


def assert_same_run(a: Path, b: Path):
    """Bit-identical numbers of two run folders (provenance times aside)."""
    sa, sb = np.load(a / "final_state.npz"), np.load(b / "final_state.npz")
    for key in ("pos", "vel", "omega", "hist_t", "pi", "pj"):
        assert np.array_equal(sa[key], sb[key]), key
    with xr.open_dataset(a / "series.nc") as da, xr.open_dataset(b / "series.nc") as db:
        for name in da.data_vars:
            assert np.array_equal(da[name].values, db[name].values, equal_nan=True), name
        for key in ("flow_state", "t_final", "stop_reason", "steady_start",
                    "segregation_state", "segregation_onset"):
            if key in da.attrs:
                assert str(da.attrs[key]) == str(db.attrs[key]), key
    for name in ("profiles.nc", "profiles_history.nc"):  # the latter: bidisperse runs
        if not (a / name).exists() and not (b / name).exists():
            continue
        with xr.open_dataset(a / name) as pa, xr.open_dataset(b / name) as pb:
            for var in pa.data_vars:
                assert np.array_equal(pa[var].values, pb[var].values, equal_nan=True), var
    ja = json.loads((a / "summary.json").read_text())
    jb = json.loads((b / "summary.json").read_text())
    for key in ("flow_state", "t_final", "steady_start", "depth_averages", "segregation"):
        assert ja[key] == jb[key], key


@pytest.fixture(scope="module")
def bidisperse_job(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bidisperse")
    base = tmp / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 3, base, base_layers=4.0, settle_time=10.0)
    pfile = tmp / "params.yaml"
    pfile.write_text(yaml.safe_dump(BIDISPERSE))
    ref = tmp / "ref"
    res = run_cli(pfile, ref, base)
    assert res.returncode == 0, res.stderr
    return tmp, pfile, base, ref


def test_killed_bidisperse_run_resumes_bit_identical(bidisperse_job):
    """SIGKILL mid-run (after a checkpoint past t = 3), run again: the same numbers as the
    undisturbed run, the segregation monitor (indicator series, state, onset) included."""
    tmp, pfile, base, ref = bidisperse_job
    killed = tmp / "killed"
    proc = run_cli(pfile, killed, base, wait=False)
    t_kill = kill_when_checkpointed(proc, killed / "checkpoint.npz", 3.0)
    assert 3.0 < t_kill < BIDISPERSE["t_end"]
    assert not (killed / "summary.json").exists()
    assert (killed / "simulate.pid").exists()  # SIGKILL: no handler ran; the rerun ignores it
    res = run_cli(pfile, killed, base)
    assert res.returncode == 0, res.stderr
    assert_same_run(ref, killed)
    with xr.open_dataset(ref / "series.nc") as ds:
        n_monitor = ds["segregation_indicator"].size
        assert n_monitor > 5  # the monitor really ran
    print(f"bidisperse run SIGKILLed at checkpoint t = {t_kill:.2f} of {BIDISPERSE['t_end']}, "
          f"rerun: particles, series ({n_monitor} segregation-indicator samples), profiles "
          "and summary bit-identical to the undisturbed run")
    # nothing left behind: no checkpoint, no pid file, no temporaries
    assert sorted(p.name for p in killed.iterdir()) == [
        "final_state.npz", "profiles.nc", "profiles_history.nc", "series.nc", "summary.json"]


@pytest.mark.parametrize("damage", ["truncated", "overwritten_block", "garbage", "empty"])
def test_corrupt_checkpoint_is_named_removed_and_rerun_recomputes(bidisperse_job, damage):
    tmp, pfile, base, ref = bidisperse_job
    run = tmp / f"ckpt-{damage}"
    proc = run_cli(pfile, run, base, wait=False)
    kill_when_checkpointed(proc, run / "checkpoint.npz", 2.0)
    ckpt = run / "checkpoint.npz"
    data = ckpt.read_bytes()
    if damage == "truncated":
        ckpt.write_bytes(data[: len(data) // 2])
    elif damage == "overwritten_block":  # same size, 4 KiB in the middle replaced: CRC fails
        mid = len(data) // 3
        ckpt.write_bytes(data[:mid] + os.urandom(4096) + data[mid + 4096:])
    elif damage == "garbage":
        ckpt.write_bytes(os.urandom(len(data)))
    else:
        ckpt.write_bytes(b"")
    res = run_cli(pfile, run, base)
    assert res.returncode == 2, res.stderr
    msg = res.stderr
    print(f"checkpoint {damage}: {msg.strip()}")
    assert f"checkpoint '{ckpt}'" in msg, msg
    assert "removed it: run again to restart this run from t = 0" in msg, msg
    assert "Traceback" not in msg
    assert not ckpt.exists()
    res = run_cli(pfile, run, base)
    assert res.returncode == 0, res.stderr
    assert_same_run(ref, run)


def _damage(path: Path, how: str):
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "flipped":  # same size, one byte in the middle changed
        mid = len(data) // 2
        path.write_bytes(data[:mid] + bytes([data[mid] ^ 0xFF]) + data[mid + 1:])
    else:
        path.write_bytes(b"")


CORRUPTION_CASES = [(f, how) for f in ("final_state.npz", "profiles.nc", "series.nc",
                                         "summary.json") for how in ("truncated", "flipped",
                                                                      "empty")]


@pytest.mark.parametrize("name,how", CORRUPTION_CASES)
def test_corrupt_run_output_is_refused_naming_the_file(bidisperse_job, tmp_path, name, how):
    """The row step reads a run back before using it: a truncated, bit-flipped or empty output
    gives an error naming the file and what is wrong; the workflow's row step removes it so
    that the rerun recomputes that run; the run's other outputs are untouched."""
    _, _, _, ref = bidisperse_job
    rel = "segregation/linear/lambda~1/theta~28/H~4/sigma~0.75"
    run = tmp_path / rel
    shutil.copytree(ref, run)
    verify_run_outputs(run)  # the intact copy reads back
    _damage(run / name, how)
    others = {p.name: p.read_bytes() for p in run.iterdir() if p.name != name}
    with pytest.raises(CorruptFileError) as err:
        derive_row(run, rel=rel, segregation_window=5.0)
    msg = str(err.value)
    print(f"{name} {how}: {msg}")
    assert repr(str(run / name)) in msg
    if name == "summary.json":
        assert "is not valid JSON, truncated or corrupt" in msg, msg
    elif how == "flipped":
        assert "does not hold what the run wrote (its SHA-256 differs" in msg, msg
    else:
        assert "bytes, the run wrote" in msg and "(truncated or replaced)" in msg, msg
    assert (run / name).exists()  # derive_row alone removes nothing
    from granflow.campaign.collect import write_row

    with pytest.raises(CorruptFileError, match="removed it.*: rerun the workflow to recompute "
                                               "this run") as err:
        write_row(run, tmp_path / "row.json", rel=rel, segregation_window=5.0)
    # the bad file and the summary (the row rule's input: the rerun recomputes the run) go
    assert err.value.removed and not (run / name).exists()
    assert not (run / "summary.json").exists() and not (tmp_path / "row.json").exists()
    others.pop("summary.json", None)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == others


def test_missing_run_output_is_named_and_the_run_marked_for_recompute(bidisperse_job, tmp_path):
    from granflow.campaign.collect import write_row

    _, _, _, ref = bidisperse_job
    rel = "segregation/linear/lambda~1/theta~28/H~4/sigma~0.75"
    run = tmp_path / rel
    shutil.copytree(ref, run)
    (run / "series.nc").unlink()
    with pytest.raises(FileNotFoundError, match=r"time-series file '.*series.nc' of a finished "
                                                r"run is missing; removed the run's summary"):
        write_row(run, tmp_path / "row.json", rel=rel, segregation_window=5.0)
    assert not (run / "summary.json").exists()


def test_final_state_errors_name_the_file(tmp_path):
    """load_state (final_state.npz, --from restarts) on files that are not a particle state."""
    missing = tmp_path / "nothing.npz"
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_state(missing)
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    with pytest.raises(CorruptFileError, match=r"lacks the arrays \[.*'meta_json'"):
        load_state(other)
    text = tmp_path / "text.npz"
    text.write_text("not an archive")
    with pytest.raises(CorruptFileError, match=r"is not a .npz archive \(it starts with b'not '"):
        load_state(text)
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    with pytest.raises(CorruptFileError, match=r"particle state file '.*empty.npz' is empty"):
        load_state(empty)


def _unshare_available():
    try:
        return subprocess.run(["unshare", "-rm", "true"], capture_output=True,
                              timeout=30).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


needs_unshare = pytest.mark.skipif(not _unshare_available(),
                                   reason="needs unshare -rm (user and mount namespaces)")


def in_mounted_tmpfs(folder: Path, options: str, cmd: list[str], timeout=300):
    """Run ``cmd`` with a fresh tmpfs (mount ``options``) on ``folder``, in a private mount
    namespace: a read-only or tiny file system without root rights on the host."""
    script = f"mount -t tmpfs -o {options} tmpfs {folder} && exec \"$@\""
    return subprocess.run(["unshare", "-rm", "sh", "-c", script, "sh", *cmd],
                          capture_output=True, text=True, timeout=timeout)


@needs_unshare
@pytest.mark.parametrize("options,expect", [
    ("ro,size=1m", "is not writable: writing in"),
    ("size=64k", "free, the run needs about"),
])
def test_read_only_or_full_output_folder_fails_before_compute(bidisperse_job, tmp_path,
                                                              options, expect):
    _, pfile, base, _ = bidisperse_job
    folder = tmp_path / "mnt"
    folder.mkdir()
    t0 = time.monotonic()
    res = in_mounted_tmpfs(folder, options, [sys.executable, "-m", "granflow.cli", "simulate",
                                             str(pfile), "--out", str(folder / "run"),
                                             "--base", str(base)])
    wall = time.monotonic() - t0
    assert res.returncode == 2, res.stderr
    assert expect in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert f"output folder '{folder / 'run'}'" in res.stderr
    assert wall < 30  # refused at once, not after the run (a run takes ~10 s plus compiling)


@needs_unshare
def test_full_folder_during_the_run_is_an_error_naming_the_file(tmp_path):
    """The free-space check passes (the estimate is an upper bound of the outputs, but other
    writers may fill the disk later): a write that then fails still says which file, and
    leaves no partial file."""
    from granflow.provenance import atomic_write_bytes

    folder = tmp_path / "mnt"
    folder.mkdir()
    code = ("import sys\nfrom granflow.provenance import atomic_write_bytes\n"
            "try:\n    atomic_write_bytes(sys.argv[1], b'x' * 200_000)\n"
            "except OSError as e:\n    print('ERR', e)\n"
            "import os\nprint('LEFT', sorted(os.listdir(os.path.dirname(sys.argv[1]))))\n")
    res = in_mounted_tmpfs(folder, "size=64k", [sys.executable, "-c", code,
                                               str(folder / "summary.json")])
    assert "ERR [Errno 28] No space left on device" in res.stdout, res.stdout + res.stderr
    assert "LEFT []" in res.stdout


def test_run_stops_when_its_workflow_process_is_killed(bidisperse_job, tmp_path):
    """A `granflow simulate` started by a workflow (GRANFLOW_WORKFLOW_PROCESS names it) stops
    within about a second when that process is SIGKILLed -- no orphan running on next to the
    rerun -- removing its pid file and keeping its checkpoint for the rerun."""
    _, pfile, base, ref = bidisperse_job
    out = tmp_path / "run"
    parent_code = (
        "import os, subprocess, sys, time\n"
        "from granflow.cli import WORKFLOW_ENV, workflow_token\n"
        "os.environ[WORKFLOW_ENV] = workflow_token()\n"
        "p = subprocess.Popen([sys.executable, '-m', 'granflow.cli', 'simulate', sys.argv[1],"
        " '--out', sys.argv[2], '--base', sys.argv[3]])\n"
        "print(p.pid, flush=True)\n"
        "time.sleep(3600)\n")
    parent = subprocess.Popen([sys.executable, "-c", parent_code, str(pfile), str(out),
                               str(base)], stdout=subprocess.PIPE, text=True)
    child = int(parent.stdout.readline())
    try:
        ckpt = out / "checkpoint.npz"
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and checkpoint_time(ckpt) < 2.0:
            time.sleep(0.05)
        assert (out / "simulate.pid").read_text().strip() == str(child)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 10 and Path(f"/proc/{child}").exists():
            try:  # reaped by init once it exits; a zombie counts as stopped
                if Path(f"/proc/{child}/stat").read_text().split(")")[1].split()[0] == "Z":
                    break
            except OSError:
                break
            time.sleep(0.05)
        stopped = time.monotonic() - t0
    finally:
        if parent.poll() is None:
            parent.kill()
        try:
            os.kill(child, signal.SIGKILL)
        except ProcessLookupError:
            pass
    print(f"orphaned run stopped {stopped:.2f} s after its workflow process was killed")
    assert stopped < 5.0
    assert ckpt.exists() and not (out / "simulate.pid").exists()
    assert not (out / "summary.json").exists()
    res = run_cli(pfile, out, base)  # the rerun resumes to the undisturbed numbers
    assert res.returncode == 0, res.stderr
    assert_same_run(ref, out)


def test_second_run_in_a_busy_folder_is_refused(bidisperse_job, tmp_path):
    """Two `granflow simulate` on one folder: the second waits for the first (its pid file
    names a live run) and is refused with the pid if it does not stop."""
    import granflow.cli as cli

    _, pfile, base, _ = bidisperse_job
    out = tmp_path / "run"
    first = run_cli(pfile, out, base, wait=False)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not (out / "simulate.pid").exists():
            time.sleep(0.05)
        with pytest.raises(ValueError, match=rf"is in use: the run with pid {first.pid} is "
                                             r"still working on it"):
            cli.wait_for_previous_run(out / "simulate.pid", wait_s=0.5)
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait()
    cli.wait_for_previous_run(out / "simulate.pid", wait_s=0.5)  # stale pid file: ignored


def test_engine_guard_ends_the_run_undecided_not_the_campaign(bidisperse_job, tmp_path):
    """Particles far too soft for their fall (t_c = 0.2: impacts overlap ~20 % of a diameter)
    trip the engine's overlap guard: the job still exits 0 with all outputs, flow state
    'undecided' (left out of the fits), the guard's message in summary and series.nc; the same
    command gives the same stop."""
    tmp, _, base, _ = bidisperse_job
    params = dict(theta=24.0, H=4.0, lam=1.0, Lx=6.0, Ly=4.0, seed=3, t_end=30.0, t_c=0.2,
                  steps_per_collision=20, checkpoint_every_s=0.1)
    pfile = tmp_path / "soft.yaml"
    pfile.write_text(yaml.safe_dump(params))
    stops = []
    for k in range(2):
        out = tmp_path / f"soft{k}"
        res = run_cli(pfile, out, base)
        assert res.returncode == 0, res.stderr
        s = json.loads((out / "summary.json").read_text())
        assert s["flow_state"] == "undecided"
        assert "overlap" in s["engine_stop"] and "too soft" in s["engine_stop"]
        assert s["classification"].startswith("undecided: the engine stopped the run at t = ")
        assert s["stop_reason"].startswith("engine guard: overlap")
        assert s["t_final"] < params["t_end"]
        with xr.open_dataset(out / "series.nc") as ds:
            assert ds.attrs["flow_state"] == "undecided"
            assert ds.attrs["engine_stop"] == s["engine_stop"]
        assert not (out / "checkpoint.npz").exists()
        row = derive_row(out, rel="chute/linear/lambda~1/theta~24/H~4")["row"]
        # stopped while the layer fell in: no flow state yet, no evidence for hstop
        assert s["flow_state_before_engine_stop"] == "undecided"
        assert (row["state"], row["stop_reason"]) == ("undecided",
                                                      "engine guard before any flow state")
        stops.append((s["t_final"], s["engine_stop"]))
    assert stops[0] == stops[1]
    # numerics.max_overlap moves the guard: at 0.5 of a diameter the same run is not stopped
    pfile.write_text(yaml.safe_dump(dict(params, max_overlap=0.5)))
    res = run_cli(pfile, tmp_path / "soft_allowed", base)
    assert res.returncode == 0, res.stderr
    s = json.loads((tmp_path / "soft_allowed" / "summary.json").read_text())
    assert "engine_stop" not in s and s["t_final"] > stops[0][0]
    pfile.write_text(yaml.safe_dump(dict(params, max_overlap=0.7)))
    res = run_cli(pfile, tmp_path / "soft_bad", base)
    assert res.returncode != 0 and "max_overlap = 0.7 is out of range: allowed (0.0, 0.5]" in res.stderr
    assert not (tmp_path / "soft_bad").exists() or not any((tmp_path / "soft_bad").iterdir())
