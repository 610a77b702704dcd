"""`granflow simulate run.yaml --from STATE`: restart a saved state at a new inclination.

A restart at the *same* inclination continues the parent run bit for bit (the clock reset to 0
is only a relabelling); at a new inclination the layer feels the new gravity from the first
step; a state of another chute is refused before any compute; the outputs name the parent.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import xarray as xr
import yaml

from granflow.cli import main
from granflow.simulate import simulate

BASE = dict(H=3.0, lam=1.0, Lx=6.0, Ly=4.0, seed=5, t_c=0.02, base_layers=4.0,
            early_stop=False, checkpoint_every_s=1e6, cg_every=4)


@pytest.fixture(scope="module")
def parent(tmp_path_factory):
    d = tmp_path_factory.mktemp("restart")
    simulate(dict(BASE, theta=26.0, t_end=6.0), d / "parent", threads=1)
    return d


def test_restart_at_the_same_inclination_continues_bit_for_bit(parent):
    long = simulate(dict(BASE, theta=26.0, t_end=9.0), parent / "long", threads=1)
    child = simulate(dict(BASE, theta=26.0, t_end=3.0), parent / "same",
                     from_state=parent / "parent" / "final_state.npz", threads=1)
    a = long["run"].series.arrays()
    b = child["run"].series.arrays()
    k = np.searchsorted(a["time"], 6.0 - 1e-9)
    n = len(b["time"])
    assert np.array_equal(a["u_mean"][k:k + n], b["u_mean"])
    assert np.array_equal(a["e_kin"][k:k + n], b["e_kin"])
    assert b["time"][0] == 0.0
    assert np.allclose(a["time"][k:k + n] - 6.0, b["time"], atol=1e-9)


def test_restart_at_a_new_inclination_names_its_parent(parent, tmp_path):
    state = parent / "parent" / "final_state.npz"
    run = tmp_path / "run.yaml"
    run.write_text(yaml.safe_dump(dict(BASE, theta=30.0, t_end=2.0)))
    out = tmp_path / "child"
    assert main(["simulate", str(run), "--out", str(out), "--from", str(state)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["parent"]["parent_state"] == str(state.resolve())
    assert summary["parent"]["parent_theta"] == 26.0
    assert summary["parent"]["parent_time"] == pytest.approx(6.0)
    assert len(summary["parent"]["parent_state_sha256"]) == 64
    ds = xr.open_dataset(out / "series.nc")
    assert ds.attrs["parent_state"] == str(state.resolve())
    assert ds.attrs["param_theta"] == 30.0
    parent_series = xr.open_dataset(parent / "parent" / "series.nc")
    # the first sample is the parent's last one; then the steeper slope accelerates the layer
    assert float(ds.u_mean[0]) == float(parent_series.u_mean[-1])
    t = ds.t.values
    # fitted over the first 0.1 time units, before the layer's friction has responded: over
    # t <= 1 the difference depends on the trajectory's last bits (0.17-0.92 of the gravity
    # term over 15 parent seeds, 4 of them below the 50 % bound), over t <= 0.1 it is 0.73-0.91
    early = t <= 0.1 + 1e-9
    slope = np.polyfit(t[early], ds.u_mean.values[early], 1)[0]
    same = simulate(dict(BASE, theta=26.0, t_end=0.1), tmp_path / "same26", from_state=state)
    s26 = same["run"].series.arrays()
    slope26 = np.polyfit(s26["time"], s26["u_mean"], 1)[0]
    # extra downslope gravity g (sin 30 - sin 26) = 0.06 speeds the layer up at once
    assert slope - slope26 == pytest.approx(math.sin(math.radians(30)) - math.sin(math.radians(26)),
                                            rel=0.5)


def test_a_state_of_another_chute_is_refused(parent, tmp_path):
    state = parent / "parent" / "final_state.npz"
    with pytest.raises(ValueError, match="flow particles"):
        simulate(dict(BASE, theta=26.0, H=4.0, t_end=1.0), tmp_path / "x", from_state=state)
    with pytest.raises(ValueError, match="box"):
        simulate(dict(BASE, theta=26.0, Lx=8.0, t_end=1.0), tmp_path / "y", from_state=state)
    assert not (tmp_path / "x" / "series.nc").exists()
    with pytest.raises(FileNotFoundError):
        simulate(dict(BASE, theta=26.0, t_end=1.0), tmp_path / "z",
                 from_state=tmp_path / "missing.npz")


@pytest.mark.parametrize("parent_state", ["steady", "arrested", None])
def test_from_if_steady_restarts_only_from_a_steady_parent(parent, tmp_path, parent_state):
    """`--from-if-steady` (the workflow's neighbour restarts): a steady parent is restarted
    from; an arrested parent, or one without a summary, gives a fresh fall bit-identical to a
    run without any restart, and the outputs say why the parent was not used."""
    import shutil

    src = tmp_path / "parent"
    src.mkdir()
    shutil.copy(parent / "parent" / "final_state.npz", src / "final_state.npz")
    if parent_state is not None:
        s = json.loads((parent / "parent" / "summary.json").read_text())
        (src / "summary.json").write_text(json.dumps(dict(s, flow_state=parent_state)))
    run = tmp_path / "run.yaml"
    run.write_text(yaml.safe_dump(dict(BASE, theta=28.0, t_end=1.0)))
    out = tmp_path / "child"
    assert main(["simulate", str(run), "--out", str(out),
                 "--from-if-steady", str(src / "final_state.npz")]) == 0
    summary = json.loads((out / "summary.json").read_text())
    child = np.load(out / "final_state.npz")
    if parent_state == "steady":
        assert summary["parent"]["parent_state"] == str((src / "final_state.npz").resolve())
        assert "restart_skipped" not in summary["parent"]
        return
    assert "parent_state" not in summary["parent"]
    why = summary["parent"]["restart_skipped"]
    assert ("'arrested'" in why) if parent_state else ("no readable summary.json" in why)
    with xr.open_dataset(out / "series.nc") as ds:
        assert ds.attrs["restart_skipped"] == why
    fresh = simulate(dict(BASE, theta=28.0, t_end=1.0), tmp_path / "fresh", threads=1)
    ref = np.load(tmp_path / "fresh" / "final_state.npz")
    for key in ("pos", "vel", "omega"):
        assert np.array_equal(child[key], ref[key]), key
    assert fresh["t_final"] == summary["t_final"]
