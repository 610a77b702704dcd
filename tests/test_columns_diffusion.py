"""x-resolved depth-integrated coarse-graining (granflow.coarse.columns) and the self-diffusion
measurement and closure (granflow.coarse.diffusion, library kind ``diffusivity``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import erf

import granflow.closures as gc
from granflow.coarse.columns import ColumnAccumulator, ColumnObserver, column_fields
from granflow.coarse.diffusion import fit_diffusivity, msd_z, self_diffusivity


def test_columns_conserve_mass_and_momentum_exactly():
    rng = np.random.default_rng(1)
    n, Lx, Ly = 500, 40.0, 3.0
    pos = np.column_stack([rng.uniform(-5, 45, n), rng.uniform(0, Ly, n), rng.uniform(0, 5, n)])
    vel = rng.normal(1.0, 0.3, (n, 3))
    mass = rng.uniform(0.5, 2.0, n)
    fixed = np.zeros(n, bool)
    fixed[:50] = True  # base particles carry no mass
    acc = ColumnAccumulator(Lx, Ly, 80, width=0.75)
    acc.add_snapshot(0.0, pos, vel, mass, fixed)
    ds = acc.to_dataset()
    M = ds.mass_per_area.values[0]
    P = ds.momentum_per_area.values[0]
    assert np.sum(M) * acc.dx * Ly == pytest.approx(mass[~fixed].sum(), rel=1e-13)
    assert np.sum(P) * acc.dx * Ly == pytest.approx((mass * vel[:, 0])[~fixed].sum(), rel=1e-12)


def test_columns_are_bin_averages_of_the_periodic_gaussian():
    Lx, Ly, nx, w = 20.0, 2.0, 40, 0.8
    acc = ColumnAccumulator(Lx, Ly, nx, width=w, cutoff=4.0)
    x0 = 19.9  # next to the periodic boundary
    acc.add_snapshot(1.0, np.array([[x0, 1.0, 1.0]]), np.array([[2.0, 0, 0]]), np.array([3.0]),
                     np.array([False]))
    ds = acc.to_dataset()
    edges = np.arange(nx + 1) * acc.dx
    norm = erf(4.0 / math.sqrt(2))
    G = 0.0
    for shift in (-Lx, 0.0, Lx):
        a = np.clip((edges - x0 + shift) / w, -4, 4)
        G = G + 0.5 * (erf(a / math.sqrt(2)) / norm + 1.0)
    expected = 3.0 * np.diff(G) / (acc.dx * Ly)
    assert np.allclose(ds.mass_per_area.values[0], expected, atol=1e-12)
    assert np.allclose(ds.u_bar.values[0][expected > 1e-6], 2.0)
    h = column_fields(ds, rho_bar=0.5)
    assert np.allclose(h.h.values, ds.mass_per_area.values / 0.5)


def test_column_observer_round_trips_its_state():
    acc = ColumnAccumulator(10.0, 2.0, 10)
    obs = ColumnObserver(acc, every=2)

    class S:  # minimal system
        time = 0.0
        pos = np.array([[1.0, 0.5, 1.0], [7.0, 0.2, 2.0]])
        vel = np.ones((2, 3))
        mass = np.ones(2)
        fixed = np.zeros(2, bool)
    for k in range(5):
        S.time = float(k)
        obs.sample(S)
    state = obs.state_dict()
    again = ColumnObserver(ColumnAccumulator(10.0, 2.0, 10))
    again.load_state_dict(state)
    assert again.acc.times == [0.0, 2.0, 4.0]
    assert np.array_equal(np.asarray(again.acc.mass), np.asarray(acc.mass))


def test_self_diffusivity_of_a_random_walk():
    rng = np.random.default_rng(7)
    D, dt, n = 0.03, 0.5, 400
    t = np.arange(0, 200.0, dt)
    z = 5.0 + np.cumsum(rng.normal(0, math.sqrt(2 * D * dt), (t.size, n)), axis=0)
    res = self_diffusivity(t, z, t_from=20.0, tau_fit=(2.0, 10.0))
    assert res["D"] == pytest.approx(D, abs=3 * res["D_stderr"])
    assert res["D_stderr"] < 0.1 * D
    m = msd_z(t, z, 20.0, [4.0])
    assert m.mean() == pytest.approx(2 * D * 4.0, rel=0.05)


def test_diffusivity_closure_in_a_library(tmp_path):
    rng = np.random.default_rng(3)
    c_D = 0.05
    u = np.array([0.5, 0.8, 1.1, 1.4, 0.9])
    h = np.array([6.0, 8.0, 10.0, 10.0, 7.0])
    sd = 0.03 * c_D * u / h
    D = c_D * u / h + rng.normal(0, sd)
    fit = fit_diffusivity(D, sd, u, h, theta=[24, 25, 26, 27, 25], contact_law="linear",
                          ids=[f"r{i}" for i in range(5)])
    assert fit.ok and fit.params["c_D"] == pytest.approx(c_D, rel=0.05)
    lib = gc.open_library(gc.write_library(tmp_path, "d", [fit]))
    assert str(lib.diffusivity_status.values.item()) in ("ok", "reduced")
    val = lib.closures.diffusivity(1.0, 8.0, d_mean=1.5, uncertainty=True)
    assert float(val["value"]) == pytest.approx(fit.params["c_D"] / 8.0 * 1.5 ** 2, rel=1e-12)
    assert 0 < float(val["std"]) < 0.1 * float(val["value"])
    with pytest.raises(ValueError, match="outside the fitted range"):
        lib.closures.diffusivity(1.0, 30.0)
