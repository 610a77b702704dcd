"""Tests of granflow.coarse.derived: flow height (Eq. 42), depth averages (Eq. 33, 51), rheology."""

import math

import numpy as np
import pytest
import xarray as xr

from granflow.coarse import (
    depth_average_summary,
    depth_averages,
    flow_height,
    interval_mean,
    local_profiles,
)
from granflow.units import RHO_PARTICLE

B, S = 1.37, 11.83  # off-grid base and surface
H = S - B
THETA = 24.0


def synthetic(z, u0=2.0, rho0=0.58 * RHO_PARTICLE, k_ratio=0.8, scale=1.0):
    """Steady-flow-like profiles: linear sigma_zz, Bagnold velocity, constant bulk density."""
    zeta = np.clip((z - B) / H, 0.0, 1.0)
    szz = scale * 5.0 * (1.0 - zeta)
    u = u0 * (1.0 - (1.0 - zeta) ** 1.5)
    rho = np.where((z > B) & (z < S), rho0, 0.0)
    base_layer = (z > B) & (z < B + 2)
    rho = np.where(base_layer, rho0 * (0.9 + 0.05 * (z - B)), rho)
    return {
        "density": rho, "velocity_x": u, "stress_zz": szz, "stress_xx": k_ratio * szz,
        "stress_xz": -math.tan(math.radians(THETA)) * szz,
    }


def dataset(z, prof, windows=None):
    ds = xr.Dataset({k: ("z", v, {"units": "1", "long_name": k}) for k, v in prof.items()},
                    coords={"z": z}, attrs={"param_theta_deg": THETA, "granflow_version": "x"})
    if windows is not None:
        for k in prof:
            ds[k + "_window"] = (("time_window", "z"), np.stack([w[k] for w in windows]))
        ds["window_n_snapshots"] = ("time_window", np.full(len(windows), 10))
    return ds


def test_flow_height_linear_stress():
    z = np.arange(-2.0, 15.0, 0.05)
    prof = synthetic(z)
    b, s, z1, z2 = flow_height(z, prof["stress_zz"])
    assert b == pytest.approx(B, abs=1e-10)
    assert s == pytest.approx(S, abs=1e-10)
    assert z1 == pytest.approx(B + 0.01 * H, abs=1e-10)
    assert z2 == pytest.approx(S - 0.01 * H, abs=1e-10)
    assert all(math.isnan(v) for v in flow_height(z, np.zeros_like(z)))


def test_depth_averages_bagnold():
    z = np.arange(-2.0, 15.0, 0.002)
    prof = synthetic(z)
    res = depth_averages(dataset(z, prof))
    assert float(res.flow_height) == pytest.approx(H, abs=1e-9)
    assert float(res.alpha) == pytest.approx(1.25, abs=1e-3)  # Bagnold: 5/4
    assert float(res.u_bar) == pytest.approx(0.6 * 2.0, abs=1e-3)  # 3/5 u_s
    assert float(res.K) == pytest.approx(0.8, abs=1e-10)
    assert float(res.mu_bar) == pytest.approx(math.tan(math.radians(THETA)), abs=1e-10)
    rho0 = 0.58 * RHO_PARTICLE
    assert float(res.rho_c) == pytest.approx(rho0, rel=1e-3)  # Eq. 51 skips the base layer
    assert float(res.nu_c) == pytest.approx(0.58, rel=1e-3)
    # rho_bar includes the lighter basal layer: (h - 2) rho0 + 2 * 0.95 rho0
    assert float(res.rho_bar) == pytest.approx(rho0 * (H - 0.1) / H, rel=1e-3)
    froude = 1.2 / math.sqrt(math.cos(math.radians(THETA)) * H)
    assert float(res.froude) == pytest.approx(froude, rel=1e-3)
    assert res.attrs["granflow_version"] == "x"
    for name, var in res.data_vars.items():
        assert "units" in var.attrs and "long_name" in var.attrs, name
    summary = depth_average_summary(dataset(z, prof), theta_deg=30.0)
    assert summary["froude"] == pytest.approx(1.2 / math.sqrt(math.cos(math.radians(30)) * H),
                                              rel=1e-3)
    assert summary["theta_deg"] == 30.0


def test_window_spreads():
    z = np.arange(-2.0, 15.0, 0.01)
    wins = [synthetic(z, u0=u0, scale=sc) for u0, sc in ((1.9, 1.0), (2.0, 1.1), (2.1, 0.9))]
    ds = dataset(z, synthetic(z), windows=wins)
    res = depth_averages(ds)
    ubars = [depth_averages(dataset(z, w))["u_bar"].item() for w in wins]
    assert float(res.u_bar_std) == pytest.approx(np.std(ubars, ddof=1), rel=1e-12)
    assert float(res.flow_height_std) == pytest.approx(0.0, abs=1e-9)  # scale-free heights
    assert int(res.n_windows) == 3
    loc = local_profiles(ds)
    assert "friction_std" in loc and "inertial_number_std" in loc


def test_local_profiles():
    z = np.arange(-2.0, 15.0, 0.01)
    prof = synthetic(z)
    loc = local_profiles(dataset(z, prof))
    inside = (z > B + 0.1) & (z < S - 0.1)
    np.testing.assert_allclose(loc.friction.values[inside], math.tan(math.radians(THETA)),
                               rtol=1e-12)
    zeta = (z - B) / H
    shear = 2.0 * 1.5 * np.sqrt(np.clip(1 - zeta, 0, None)) / H
    np.testing.assert_allclose(loc.shear_rate.values[inside], shear[inside], rtol=1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):
        expected_i = shear * 1.0 / np.sqrt(prof["stress_zz"] / RHO_PARTICLE)
    np.testing.assert_allclose(loc.inertial_number.values[inside], expected_i[inside], rtol=1e-3)
    # Bagnold: I is constant in the bulk
    mid = (z > B + 1) & (z < S - 1)
    assert np.ptp(loc.inertial_number.values[mid]) < 1e-3 * loc.inertial_number.values[mid].mean()
    assert np.isnan(loc.friction.values[z > S + 0.1]).all()


def test_interval_mean_exact_for_linear():
    z = np.linspace(0, 10, 101)
    assert interval_mean(z, 3 * z + 1, 2.34, 7.71) == pytest.approx(3 * (2.34 + 7.71) / 2 + 1,
                                                                 rel=1e-13)
    assert math.isnan(interval_mean(z, z, -1.0, 5.0))


def test_end_to_end_from_particles():
    """A static layered column coarse-grained and fed to depth_averages: rho_c, K and h."""
    from granflow.coarse import coarse_grain_profiles

    rng = np.random.default_rng(0)
    L, n_layers = 6, 16
    gx, gy = np.meshgrid(np.arange(L) + 0.5, np.arange(L) + 0.5, indexing="ij")
    pos, masses = [], []
    for k in range(n_layers):
        xy = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.2, 0.2, (L * L, 2))
        pos.append(np.column_stack([xy % L, np.full(L * L, k + 0.5)]))
    pos = np.vstack(pos)
    n = len(pos)
    # each particle rests on the one below (same column) or on the base: exact equilibrium
    col = np.tile(np.arange(L * L), n_layers)
    lay = np.repeat(np.arange(n_layers), L * L)
    ci, cj, f, cp = [], [], [], []
    base = np.column_stack([pos[:L * L, :2], np.full(L * L, -0.5)])
    for i in range(n):
        j = i - L * L if lay[i] > 0 else n + col[i]
        ci.append(i)
        cj.append(j)
        f.append([0.0, 0.0, float(n_layers - lay[i])])
        cp.append(pos[i] - [0, 0, 0.5])
    allpos = np.vstack([pos, base])
    rij = allpos[ci] - allpos[cj]
    snap = {"time": 0.0, "pos": allpos, "vel": np.zeros_like(allpos),
            "mass": np.ones(len(allpos)), "diameter": np.ones(len(allpos)),
            "species": np.zeros(len(allpos), np.int32),
            "fixed": np.r_[np.zeros(n, bool), np.ones(L * L, bool)],
            "contact_i": np.array(ci), "contact_j": np.array(cj), "contact_force": np.array(f),
            "contact_rij": rij, "contact_point": np.array(cp)}
    ds = coarse_grain_profiles([snap], -3, 20, 0.02, width=1.0, Lx=L, Ly=L)
    res = depth_averages(ds, theta_deg=0.0)
    # sigma_zz is lithostatic (rho = 1 per unit volume); centres span [0.5, 15.5], and w = 1
    # smears the stress ends, so the extrapolated base/surface lie a little outside
    assert float(res.base) < 0.5 and float(res.surface) > 15.5
    assert float(res.flow_height) == pytest.approx(16.0, abs=2.0)
    assert float(res.rho_c) == pytest.approx(1.0, rel=1e-2)  # edge smearing at w = 1
    assert float(res.K) == pytest.approx(0.0, abs=1e-12)  # vertical forces only
