"""The command line: `granflow --help` lists every command; a running `granflow simulate` can be
found by its process name and its pid file and stopped cleanly (SIGTERM), keeping its
checkpoint for the rerun."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from granflow.cli import PROCESS_NAME
from granflow.simulate import prepare_base_file

GRANFLOW = [sys.executable, "-m", "granflow.cli"]


def test_help_lists_every_command():
    out = subprocess.run([*GRANFLOW, "--help"], capture_output=True, text=True, timeout=60).stdout
    listed = {line.split()[0] for line in out.split("Commands\n--------\n")[1].splitlines()
              if line and not line.startswith(" ")}
    assert {"simulate", "prepare-base", "demo", "campaign"} <= listed, out
    sub = subprocess.run([*GRANFLOW, "campaign", "--help"], capture_output=True, text=True,
                         timeout=60).stdout
    for command in ("check-config", "expand", "run-params", "row", "hstop-step", "collect",
                    "fit", "library", "report"):
        assert command in sub


def test_prepare_base_makes_the_base_its_options_name(tmp_path):
    """`granflow prepare-base --settle-mu-c --fill-packing --band` writes exactly the base that
    BaseConfig with those settings gives (here MercuryDPM's: a frictionless pile, its top
    slice), not the default one; a bad value is refused naming the option's range."""
    import numpy as np

    from granflow.engine.chute import BaseConfig, prepare_rough_base

    out = tmp_path / "base.npy"
    opts = ["--lam", "1", "--Lx", "4", "--Ly", "4", "--seed", "2", "--base-layers", "5",
            "--settle-time", "5"]
    proc = subprocess.run([*GRANFLOW, "prepare-base", *opts, "--settle-mu-c", "0",
                           "--fill-packing", "0.648", "--band", "top", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    common = dict(lam=1.0, Lx=4.0, Ly=4.0, seed=2, base_layers=5.0, settle_time=5.0)
    expected = prepare_rough_base(BaseConfig(prep_mu_c=0.0, fill_packing=0.648, band="top",
                                             **common))
    default = prepare_rough_base(BaseConfig(**common))
    made = np.load(out)
    assert np.array_equal(made, expected)
    assert made.shape != default.shape or not np.array_equal(made, default)
    bad = subprocess.run([*GRANFLOW, "prepare-base", *opts, "--settle-mu-c", "-1", "--out",
                          str(tmp_path / "bad.npy")], capture_output=True, text=True, timeout=300)
    assert bad.returncode != 0 and "prep_mu_c = -1" in bad.stderr and "out of range" in bad.stderr
    assert not (tmp_path / "bad.npy").exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process names: Linux")
def test_running_simulation_has_a_name_and_a_pid_file_and_stops_cleanly(tmp_path):
    base = tmp_path / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 3, base, base_layers=4.0, settle_time=5.0)
    params = tmp_path / "run.yaml"
    params.write_text(yaml.safe_dump(dict(theta=26.0, H=4.0, lam=1.0, Lx=6.0, Ly=4.0, seed=5,
                                          t_end=2000.0, t_c=0.02, base_layers=4.0,
                                          checkpoint_every_s=0.2, early_stop=False)))
    out = tmp_path / "run"
    # `granflow -v simulate`: the form `pkill -f "granflow.cli simulate"` used to miss
    proc = subprocess.Popen([*GRANFLOW, "-v", "simulate", str(params), "--base", str(base),
                             "--out", str(out)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    pid_file = out / "simulate.pid"
    try:
        deadline = time.monotonic() + 240
        while not (pid_file.exists() and (out / "checkpoint.npz").exists()):
            assert proc.poll() is None and time.monotonic() < deadline, "run ended or hung"
            time.sleep(0.1)
        pid = int(pid_file.read_text())
        assert pid == proc.pid
        assert Path(f"/proc/{pid}/comm").read_text().strip() == PROCESS_NAME
        if shutil.which("pgrep"):
            found = subprocess.run(["pgrep", "-x", PROCESS_NAME], capture_output=True,
                                   text=True).stdout.split()
            assert str(pid) in found
        os.kill(pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGTERM, err[-3000:]  # died of the signal
    assert not pid_file.exists()
    assert (out / "checkpoint.npz").exists() and not (out / "summary.json").exists()
