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


# --------------------------------------------------------------------------- top-up (staircase)
def _by_identity(system):
    order = system.id_order()
    return {k: np.array(getattr(system, k)[order]) for k in ("pos", "vel", "omega", "radius",
                                                              "mass", "fixed", "ptype")}


def _pair_history(system):
    """{(identity i, identity j): tangential spring} of the listed pairs with a spring."""
    ids = system.ids
    out = {}
    for p in range(len(system.pi)):
        if np.any(system.hist_t[p] != 0.0):
            a, b = int(ids[system.pi[p]]), int(ids[system.pj[p]])
            out[(min(a, b), max(a, b))] = system.hist_t[p].copy()
    return out


def test_top_up_keeps_every_particle_and_contact(parent):
    """`ParticleSystem.add_particles` via `top_up_flow` (the staircase's 2 more particle
    heights): the exact number of missing particles is added, at rest, above the old flow;
    every old particle keeps its state bit for bit (by identity), every contact spring is
    carried over unchanged and the elastic energy of the state is unchanged (the new
    particles touch nothing)."""
    from granflow.engine.chute import ChuteConfig, top_up_flow
    from granflow.engine.system import ParticleSystem
    from granflow.simulate import chute_config, validate_params

    system, _ = ParticleSystem.load(parent / "parent" / "final_state.npz")
    before = _by_identity(system)
    springs = _pair_history(system)
    reference, _ = ParticleSystem.load(parent / "parent" / "final_state.npz")
    reference.compute_forces()  # the unchanged state's forces, as the top-up evaluates them
    nm0 = int((~system.fixed).sum())  # flow particles before
    cfg = chute_config(validate_params(dict(BASE, theta=26.0, H=5.0)))
    added = top_up_flow(system, cfg)
    assert added == round(5.0 * 6.0 * 4.0) - round(3.0 * 6.0 * 4.0) == 48
    assert system.n == len(before["pos"]) + added
    after = _by_identity(system)
    # identities: old flow 0..nm0-1, new nm0..nm0+k-1, then the base
    old = np.r_[0:nm0, nm0 + added:system.n]
    for key, value in before.items():
        assert np.array_equal(after[key][old], value), key
    new = slice(nm0, nm0 + added)
    assert not after["fixed"][new].any() and np.all(after["radius"][new] == 0.5)
    assert np.all(after["vel"][new] == 0.0) and np.all(after["omega"][new] == 0.0)
    assert after["pos"][new][:, 2].min() > before["pos"][:nm0, 2].max()
    moved = {(a if a < nm0 else a + added, b if b < nm0 else b + added): v
             for (a, b), v in springs.items()}
    assert springs and _pair_history(system).keys() == moved.keys()
    for key, v in _pair_history(system).items():
        assert np.array_equal(v, moved[key])
    assert system.e_elastic == reference.e_elastic
    assert system.max_overlap == reference.max_overlap
    assert top_up_flow(system, cfg) == 0  # full: nothing more
    with pytest.raises(ValueError, match="more than the 72"):
        top_up_flow(system, ChuteConfig(**dict(cfg.as_dict(), H=3.0, flow=cfg.flow,
                                               base=cfg.base)))


def test_topped_up_pile_flows_on_as_one_layer(parent, tmp_path):
    """`--from STATE --top-up` at the parent's inclination: the summary records the particles
    added and counts H = 5 worth of flow particles; the flow keeps its mass (an exact count)
    and the new particles end up inside the layer they joined (their mean height below the
    old layer's top + 2), and `--top-up` alone, or a state with too few particles without
    it, is refused naming the option."""
    state = parent / "parent" / "final_state.npz"
    run = tmp_path / "run.yaml"
    run.write_text(yaml.safe_dump(dict(BASE, theta=26.0, H=5.0, t_end=4.0)))
    out = tmp_path / "child"
    assert main(["simulate", str(run), "--out", str(out), "--from", str(state),
                 "--top-up"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["parent"]["topped_up"] == 48
    assert summary["n_flow"] == 120
    child = np.load(out / "final_state.npz")
    assert int((~child["fixed"]).sum()) == 120
    top0 = np.load(state)["pos"][~np.load(state)["fixed"], 2].max()
    ids = child["ids"]
    z_new = child["pos"][(ids >= 72) & (ids < 120), 2]
    assert z_new.mean() < top0 + 2.0
    with pytest.raises(SystemExit, match="--top-up: allowed only with --from"):
        main(["simulate", str(run), "--out", str(tmp_path / "x"), "--top-up"])
    with pytest.raises(ValueError, match="--top-up adds missing ones"):
        simulate(dict(BASE, theta=26.0, H=5.0, t_end=1.0), tmp_path / "y", from_state=state)
    with pytest.raises(ValueError, match="one flow species"):
        simulate(dict(BASE, theta=26.0, H=5.0, t_end=1.0, sigma=0.8, phi0=0.5),
                 tmp_path / "z", from_state=state, top_up=True)


def test_top_up_never_overlaps_and_counts_exactly(parent):
    """Property (hypothesis): for any larger filling height the top-up adds exactly the missing
    flow particles, none of them overlapping any particle (centre distances >= the sum of the
    radii, in the periodic box), every old particle unchanged by identity, and the forces of
    the state unchanged (the new particles touch nothing: same elastic energy and overlap)."""
    from hypothesis import given, settings, strategies as st

    from granflow.engine.chute import top_up_flow
    from granflow.engine.system import ParticleSystem
    from granflow.simulate import chute_config, validate_params

    state = parent / "parent" / "final_state.npz"
    reference, _ = ParticleSystem.load(state)
    reference.compute_forces()
    before = _by_identity(reference)

    @settings(max_examples=15, deadline=None, derandomize=True)
    @given(H=st.floats(3.05, 9.0), seed=st.integers(1, 10**6))  # at least one particle
    def check(H, seed):
        system, _ = ParticleSystem.load(state)
        cfg = chute_config(validate_params(dict(BASE, theta=26.0, H=H, seed=seed)))
        added = top_up_flow(system, cfg)
        assert added == round(H * 24.0) - 72
        after = _by_identity(system)
        old = np.r_[0:72, 72 + added:system.n]
        for key, value in before.items():
            assert np.array_equal(after[key][old], value), key
        new = after["pos"][72:72 + added]
        d = new[:, None, :] - after["pos"][None, :, :]
        d[..., 0] -= system.Lx * np.round(d[..., 0] / system.Lx)
        d[..., 1] -= system.Ly * np.round(d[..., 1] / system.Ly)
        dist = np.sqrt((d**2).sum(-1))
        reach = after["radius"][72:72 + added, None] + after["radius"][None, :]
        dist[np.arange(added), 72 + np.arange(added)] = np.inf  # itself
        assert np.all(dist >= reach)
        assert system.e_elastic == reference.e_elastic
        assert system.max_overlap == reference.max_overlap

    check()


class _Interrupt:
    """Observer that stops the process (KeyboardInterrupt) once the run passes ``t_kill``;
    with ``t_kill = inf`` it only samples (so that a resumed run has the same observers)."""

    name = "interrupt"

    def __init__(self, t_kill):
        self.t_kill = t_kill

    def sample(self, system):
        if system.time > self.t_kill:
            raise KeyboardInterrupt

    def state_dict(self):
        return {}

    def load_state_dict(self, state):
        pass


def test_killed_top_up_run_resumes_to_identical_numbers(parent, tmp_path, monkeypatch):
    """A topped-up restart killed part-way resumes from its checkpoint (the top-up is not
    applied a second time, nor poured and thrown away: the checkpoint holds the topped-up
    system) and ends with exactly the numbers of an undisturbed run."""
    import granflow.simulate as gs

    state = parent / "parent" / "final_state.npz"
    params = dict(BASE, theta=26.0, H=5.0, t_end=3.0, checkpoint_every_s=0.0)
    whole = tmp_path / "whole"
    simulate(params, whole, from_state=state, top_up=True,
             extra_observers=(_Interrupt(math.inf),))
    killed = tmp_path / "killed"
    with pytest.raises(KeyboardInterrupt):
        simulate(params, killed, from_state=state, top_up=True,
                 extra_observers=(_Interrupt(1.5),))
    assert (killed / "checkpoint.npz").exists() and not (killed / "summary.json").exists()
    poured = []
    real_top_up = gs.top_up_flow
    monkeypatch.setattr(gs, "top_up_flow", lambda *a: poured.append(1) or real_top_up(*a))
    res = simulate(params, killed, from_state=state, top_up=True,
                   extra_observers=(_Interrupt(math.inf),))
    assert poured == []  # resumed: the checkpoint's particles, none poured
    assert res["run"].resumed_from >= 1.0 and res["cost"]["segments"] == 2  # it did resume
    a, b = np.load(whole / "final_state.npz"), np.load(killed / "final_state.npz")
    assert int((~b["fixed"]).sum()) == 120
    for key in ("pos", "vel", "omega", "hist_t", "ids"):
        assert np.array_equal(a[key], b[key]), key
    sa = json.loads((whole / "summary.json").read_text())
    sb = json.loads((killed / "summary.json").read_text())
    assert sb["parent"]["topped_up"] == sa["parent"]["topped_up"] == 48
    assert sb["t_final"] == sa["t_final"]


def test_outputs_name_the_base_a_run_fell_onto_and_a_restart_inherits_it(tmp_path):
    """summary.json's provenance and the netCDF attributes carry the SHA-256 of the base file
    (so that brackets can be grouped by base realisation without the campaign's config); a
    restart names its parent's base; a base prepared from the parameters records None."""
    import hashlib

    from granflow.simulate import prepare_base_file

    base = tmp_path / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 3, base, base_layers=4.0, settle_time=5.0)
    sha = hashlib.sha256(base.read_bytes()).hexdigest()
    simulate(dict(BASE, theta=26.0, t_end=1.0), tmp_path / "on_file", base_file=base)
    summary = json.loads((tmp_path / "on_file" / "summary.json").read_text())
    assert summary["provenance"]["base_sha256"] == sha
    assert xr.open_dataset(tmp_path / "on_file" / "profiles.nc").attrs["base_sha256"] == sha
    simulate(dict(BASE, theta=28.0, t_end=0.5), tmp_path / "child",
             from_state=tmp_path / "on_file" / "final_state.npz")
    child = json.loads((tmp_path / "child" / "summary.json").read_text())
    assert child["provenance"]["base_sha256"] == sha
    assert child["parent"]["parent_base_sha256"] == sha
    simulate(dict(BASE, theta=26.0, t_end=0.5), tmp_path / "own_base")
    own = json.loads((tmp_path / "own_base" / "summary.json").read_text())
    assert own["provenance"]["base_sha256"] is None


def test_a_resumed_run_takes_the_new_t_end(tmp_path):
    """t_end is resume-free (RESUME_FREE_PARAMETERS): a run killed part-way and resumed with a
    longer t_end runs to the new one (its steady-state monitor, restored from the checkpoint,
    no longer stops it at the old cap), with the numbers of a run given the longer t_end from
    the start."""
    params = dict(BASE, theta=26.0, t_end=1.0, checkpoint_every_s=0.0, early_stop=True)
    whole = tmp_path / "whole"
    simulate(dict(params, t_end=2.0), whole, extra_observers=(_Interrupt(math.inf),))
    killed = tmp_path / "killed"
    with pytest.raises(KeyboardInterrupt):
        simulate(params, killed, extra_observers=(_Interrupt(0.5),))
    res = simulate(dict(params, t_end=2.0), killed, extra_observers=(_Interrupt(math.inf),))
    assert res["run"].resumed_from >= 0.4
    sa = json.loads((whole / "summary.json").read_text())
    sb = json.loads((killed / "summary.json").read_text())
    assert sb["t_final"] == sa["t_final"] >= 2.0
    a, b = np.load(whole / "final_state.npz"), np.load(killed / "final_state.npz")
    for key in ("pos", "vel", "omega"):
        assert np.array_equal(a[key], b[key]), key
