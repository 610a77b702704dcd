"""The segregation flux and T-eq. (27)'s two rates measured from a transient
(granflow.coarse.segregation_flux, granflow.continuum.segregation.fit_segregation_transient),
checked on transients whose S and D_r are known: T-eq. (27)'s own solution."""

import math

import numpy as np
import pytest

from granflow.coarse.segregation_flux import (
    concentration_fields,
    fit_segregation_flux,
    segregation_flux_from_tracers,
)
from granflow.continuum.segregation import (
    fit_segregation_transient,
    segregation_layer,
    steady_profile,
    steady_profile_shaped,
)

H, PHI0, S_TRUE, D_TRUE = 24.0, 0.5, 0.0069, 0.024


@pytest.fixture(scope="module")
def model_transient():
    """T-eq. (27) from a mixed start: phi on 400 cells every time unit up to t = 300."""
    ds = segregation_layer(Ps=S_TRUE * H / D_TRUE, D=D_TRUE, h=H, phi0=PHI0, t_end=300.0,
                           n=400, n_out=301)
    return ds.t.values, ds.z.values, ds.phi.values


def test_flux_regression_recovers_S_and_D_of_an_exact_transient(model_transient):
    """On a noise-free transient the flux J = -dC/dt regressed on (-phi(1-phi), -dphi/dz)
    returns T-eq. (27)'s S and D_r (within 1 %: the central time difference and the
    face/cell interpolation are the only errors), and explains the flux (r2 > 0.999)."""
    t, zc, phi = model_transient
    n = zc.size
    dz = H / n
    c = 0.6                                                   # uniform solid fraction
    faces = np.arange(1, n) * dz
    C = c * np.cumsum(phi, axis=1)[:, :-1] * dz                # small volume below each face
    phi_f = 0.5 * (phi[:, 1:] + phi[:, :-1])
    inner = (faces > 2.0) & (faces < H - 2.0)
    r = fit_segregation_flux(t, faces[inner], C[:, inner], c * phi_f[:, inner],
                             np.full_like(phi_f[:, inner], c), lag=1.0, t_from=5.0, t_to=200.0)
    assert r["S"] == pytest.approx(S_TRUE, rel=0.01)
    assert r["D_r"] == pytest.approx(D_TRUE, rel=0.01)
    assert r["r2"] > 0.999


def test_transient_fit_recovers_S_and_D_from_a_partly_segregated_start(model_transient):
    """The model fitted to phi(z, t) from t = 20 (a start that has segregated part-way, on a
    coarser set of levels; its start unsmoothed, as it is exact) returns S and D_r within 1 %
    and Ps = S h / D_r."""
    t, zc, phi = model_transient
    keep = (t >= 20.0) & (np.arange(t.size) % 5 == 0)
    levels = np.arange(0, zc.size, 8)
    r = fit_segregation_transient(t[keep], zc[levels], phi[keep][:, levels], h=H, phi0=PHI0,
                                  z_range=(1.0, H - 1.0), init_smoothing=0.0)
    assert r["S"] == pytest.approx(S_TRUE, rel=0.01)
    assert r["D_r"] == pytest.approx(D_TRUE, rel=0.01)
    assert r["Ps"] == pytest.approx(S_TRUE * H / D_TRUE, rel=0.01)
    assert r["r2"] > 0.999


def test_transient_fit_with_noise_is_unbiased():
    """Gaussian noise of 0.03 on every level, the start included (a coarse-grained profile of a
    few hundred particles): S within 10 %, D_r within 30 % of the truth, both within 4 of their
    stated stderrs (over seeds 0-3 the errors were 1-9 % for S, 2-28 % for D_r, at most 3.7
    stderrs: D_r is the weaker-identified rate; without the fitted start modes S was off by up
    to 12 %)."""
    ds = segregation_layer(Ps=S_TRUE * H / D_TRUE, D=D_TRUE, h=H, phi0=PHI0, t_end=300.0,
                           n=200, n_out=61)
    rng = np.random.default_rng(0)
    levels = np.arange(4, 200, 4)
    phi = ds.phi.values[:, levels] + rng.normal(0.0, 0.03, (61, levels.size))
    r = fit_segregation_transient(ds.t.values[2:], ds.z.values[levels], phi[2:], h=H,
                                  phi0=PHI0)
    for key, true, tol in (("S", S_TRUE, 0.10), ("D_r", D_TRUE, 0.30)):
        assert r[key] == pytest.approx(true, rel=tol)
        assert 0 < r[f"{key}_stderr"] and abs(r[key] - true) < 4 * r[f"{key}_stderr"]


def test_concentration_fields_of_a_known_arrangement():
    """Small spheres (d = 1) in the lower half, large (d = 2) in the upper: the small volume
    below a level far above all of them is their total volume per area exactly, zero far
    below; phi = 1 among the small and 0 among the large."""
    rng = np.random.default_rng(0)
    z = np.concatenate([rng.uniform(1.0, 5.0, 400), rng.uniform(8.0, 12.0, 50)])
    d = np.concatenate([np.ones(400), np.full(50, 2.0)])
    grid = np.array([-10.0, 3.0, 10.0, 30.0])
    C, cs, ca = concentration_fields(z[None, :], d, grid, area=20.0, width=0.5)
    v_small = 400 * math.pi / 6.0 / 20.0
    assert C[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert C[0, 3] == pytest.approx(v_small, rel=1e-12)
    assert cs[0, 1] / ca[0, 1] == pytest.approx(1.0, abs=1e-9)
    assert cs[0, 2] / ca[0, 2] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("kw, field", [
    (dict(lag=0.1), "lag"), (dict(n_blocks=1), "n_blocks"), (dict(t_from=296.0), "samples")])
def test_flux_fit_refuses_bad_input(model_transient, kw, field):
    t, zc, phi = model_transient
    f = np.ones_like(phi)
    args = dict(lag=1.0, t_from=0.0, t_to=300.0)
    args.update(kw)
    with pytest.raises(ValueError, match=field):
        fit_segregation_flux(t, zc, f, f, f, **args)


def test_fits_refuse_bad_input():
    with pytest.raises(ValueError, match="area"):
        concentration_fields(np.zeros((1, 2)), np.ones(2), [0.0], area=0.0)
    with pytest.raises(ValueError, match="z_from"):
        segregation_flux_from_tracers([0, 1, 2], np.zeros((3, 2)), np.ones(2), area=1.0,
                                      z_from=1.0, z_to=1.5, t_from=0, t_to=2)
    with pytest.raises(ValueError, match="z_range"):
        fit_segregation_transient([0, 1, 2], [0.5, 1.0], np.zeros((3, 2)), h=2.0, phi0=0.5)
    for kw, field in ((dict(phi0=1.0), "phi0"), (dict(n=4), "n = "),
                      (dict(init_modes=-1), "init_modes")):
        args = dict(h=2.0, phi0=0.5)
        args.update(kw)
        with pytest.raises(ValueError, match=field):
            fit_segregation_transient([0, 1, 2], [0.5, 1.0, 1.5], np.zeros((3, 3)), **args)
    with pytest.raises(ValueError, match="h = "):
        fit_segregation_transient([0, 1, 2], [0.5, 1.0, 1.5], np.zeros((3, 3)), h=-1.0,
                                  phi0=0.5)


def test_level_fluxes_of_a_uniform_drift():
    """Small particles spread uniformly over 0 < z < 40 all drift down at v = 0.01 (no large
    ones): at interior levels the measured J / c is -v (to 0.1 %: J counts the particles that
    cross the level, c is their kernel-averaged density there, and the random layer's density
    fluctuates), phi = 1 and dphi/dz = 0."""
    from granflow.coarse.segregation_flux import level_fluxes

    rng = np.random.default_rng(1)
    z0 = rng.uniform(0.0, 40.0, 20000)
    t = np.arange(0.0, 50.0, 0.5)
    z = z0[None, :] - 0.01 * t[:, None]
    d = np.ones(z0.size)
    rows = level_fluxes(t, z, d, area=100.0, levels=[15.0, 20.0, 25.0], windows=[(0.0, 49.5)])
    assert len(rows) == 3
    for r in rows:
        assert r["J_over_c"] == pytest.approx(-0.01, rel=1e-3)
        assert r["phi"] == pytest.approx(1.0, abs=1e-12)
        assert abs(r["dphi_dz"]) < 1e-9


def test_self_diffusivity_profile_of_random_walks():
    """Independent Gaussian random walks with D = 0.02 in z: every 4-d band returns D within
    5 % (4000 walkers, 400 samples)."""
    from granflow.coarse.diffusion import self_diffusivity_profile

    rng = np.random.default_rng(2)
    dt, D = 0.5, 0.02
    steps = rng.normal(0.0, math.sqrt(2 * D * dt), (400, 4000))
    z = rng.uniform(0.0, 20.0, 4000)[None, :] + np.cumsum(steps, axis=0)
    t = np.arange(400) * dt
    rows = self_diffusivity_profile(t, z, 0.0, [2.0, 6.0, 10.0, 14.0, 18.0])
    assert [r["z_from"] for r in rows] == [2.0, 6.0, 10.0, 14.0]
    for r in rows:
        assert r["D"] == pytest.approx(D, rel=0.05)
    with pytest.raises(ValueError, match="tau_fit"):
        self_diffusivity_profile(t, z, 0.0, [0.0, 10.0], tau_fit=(0.1, 10.0))


def test_transient_fit_says_when_the_rates_are_not_pinned(model_transient):
    """Compared only in the mixed interior while the fronts at base and surface have not
    reached it (phi = 0.5 there, whatever S and D_r), the fit flags both rates unidentified."""
    t, zc, phi = model_transient
    keep = t <= 40.0
    levels = (zc > 8.0) & (zc < 16.0)
    r = fit_segregation_transient(t[keep], zc[levels], phi[keep][:, levels], h=H, phi0=PHI0)
    assert not r["identified"]
    assert "S" in r["unidentified"]


def test_shaped_rates_of_one_are_the_constant_model():
    """S_shape = D_shape = 1 gives the constant-rate model bit for bit, and the shaped steady
    profile is T-eq. (28) (to 1e-6 per cell)."""
    from granflow.continuum.segregation import steady_profile, steady_profile_shaped

    one = lambda zeta: np.ones_like(zeta)  # noqa: E731
    a = segregation_layer(Ps=6.8, D=0.024, h=H, t_end=200.0, n=100, n_out=11)
    b = segregation_layer(Ps=6.8, D=0.024, h=H, t_end=200.0, n=100, n_out=11, S_shape=one,
                          D_shape=one)
    assert np.array_equal(a.phi.values, b.phi.values)
    np.testing.assert_allclose(steady_profile_shaped(6.8, 0.5, 100, one, one),
                               steady_profile(6.8, 0.5, 100), atol=1e-6)


def test_shaped_model_conserves_mass_and_reaches_its_steady_profile():
    """A segregation velocity growing fivefold towards the surface and a diffusivity halved at
    the base: the mean of phi is kept to 1e-10 and by t = 40 h^2 / D the layer is its exact
    shaped steady profile (max difference 1e-4)."""
    S_shape = lambda zeta: 1.0 / (1.05 - zeta)  # noqa: E731
    D_shape = lambda zeta: 0.5 + 0.5 * np.minimum(zeta / 0.1, 1.0)  # noqa: E731
    h, D = 10.0, 0.02
    ds = segregation_layer(Ps=3.0, D=D, h=h, t_end=40.0 * h * h / D, n=100, n_out=5,
                           S_shape=S_shape, D_shape=D_shape)
    assert np.abs(ds.phi.mean("z").values - 0.5).max() < 1e-10
    assert np.abs(ds.phi.values[-1] - ds.phi_steady.values).max() < 1e-4
    with pytest.raises(ValueError, match="S_shape"):
        segregation_layer(Ps=3.0, D=D, h=h, S_shape=lambda zeta: -np.ones_like(zeta))


@pytest.mark.parametrize("kappa", [0.5, 0.9])
def test_shaped_asymmetric_model_reaches_its_steady_profile(kappa):
    """The asymmetric flux with depth-dependent rates: mass kept to 1e-10, and by
    t = 40 h^2 / D the finite-volume layer converges on the shaped steady profile that
    steady_profile_shaped integrates, at second order (max difference at n = 200 below 1e-4,
    falling at least 3.5x from n = 100); with both shapes 1 that profile is the unshaped
    asymmetric one."""
    S_shape = lambda zeta: 1.0 / (1.05 - zeta)  # noqa: E731
    h, D = 10.0, 0.02
    err = []
    for n in (100, 200):
        ds = segregation_layer(Ps=3.0, D=D, h=h, t_end=40.0 * h * h / D, n=n, n_out=5,
                               flux="asymmetric", kappa=kappa, S_shape=S_shape)
        assert np.abs(ds.phi.mean("z").values - 0.5).max() < 1e-10
        err.append(np.abs(ds.phi.values[-1] - ds.phi_steady.values).max())
    assert err[1] < 1e-4 and err[0] / err[1] > 3.5, err
    one = lambda zeta: np.ones_like(zeta)  # noqa: E731
    np.testing.assert_allclose(
        steady_profile_shaped(6.8, 0.5, 100, S_shape=one, flux="asymmetric", kappa=kappa),
        steady_profile(6.8, 0.5, 100, flux="asymmetric", kappa=kappa), atol=1e-6)
    with pytest.raises(ValueError, match="flux"):
        steady_profile_shaped(6.8, 0.5, 100, flux="none")


def test_local_segregation_velocity_inverts_the_flux():
    """Level fluxes made from T-eq. (27)'s flux with a known S(z) and banded D(z) give that
    S(z) back exactly (two windows: their mean, zero scatter); nearly pure levels are left
    out."""
    from granflow.continuum.experiments import local_segregation_velocity

    bands = [{"z_from": 0.0, "z_to": 5.0, "D": 0.01}, {"z_from": 5.0, "z_to": 10.0, "D": 0.03}]
    S_of = lambda z: 0.005 * (1.0 + z)  # noqa: E731
    rows = []
    for t0 in (0.0, 10.0):
        for z, phi, g in ((2.0, 0.6, -0.05), (7.0, 0.4, -0.1), (9.0, 0.01, -0.01)):
            D = 0.01 if z < 5 else 0.03
            rows.append({"t_from": t0, "z": z, "phi": phi, "dphi_dz": g,
                         "J_over_c": -(S_of(z) * phi * (1 - phi) + D * g)})
    out = local_segregation_velocity({"levels": rows, "D_profile": bands})
    assert [r["z"] for r in out] == [2.0, 7.0]
    for r in out:
        assert r["S"] == pytest.approx(S_of(r["z"]), rel=1e-12)
        assert r["n_windows"] == 2 and r["S_stderr"] == pytest.approx(0.0, abs=1e-15)


def test_pressure_scaling_finds_an_inverse_pressure_law(tmp_path):
    """Level fluxes made with S = 0.1 / p on a layer with p = 12 - z and u = 3 (1 - (1 -
    z / 12)^1.5) (Bagnold-like shear rate): S p is constant (coefficient of variation < 1e-3:
    the profiles' +-1 d averages of p are exact for a linear p), S / gamma_dot is not, and the
    inverse-pressure scaling is named the best."""
    import xarray as xr

    from granflow.continuum.experiments import segregation_pressure_scaling

    zg = np.linspace(-2.0, 14.0, 321)
    p = np.clip(12.0 - zg, 0.0, None)
    u = 3.0 * (1.0 - np.clip(1.0 - zg / 12.0, 0.0, None) ** 1.5)
    nc = tmp_path / "profiles.nc"
    xr.Dataset({"velocity_x": ("z", u), "stress_zz": ("z", -p)}, coords={"z": zg}).to_netcdf(nc)
    rows = []
    for z in (4.0, 6.0, 8.0, 10.0):
        phi, g = 0.5, -0.02
        rows.append({"t_from": 0.0, "z": z, "phi": phi, "dphi_dz": g,
                     "J_over_c": -(0.1 / (12.0 - z) * phi * (1 - phi) + 0.02 * g)})
    rates = {"levels": rows, "D_profile": [{"z_from": 0.0, "z_to": 12.0, "D": 0.02}]}
    r = segregation_pressure_scaling(rates, nc, base=0.0, z_from=0.0)
    assert r["cv"]["S_p"] < 1e-3
    assert r["cv"]["S_over_gamma_dot"] > 0.1
    assert r["best"] == "S_p"
    # one level above z_from: no scaling can be told
    assert segregation_pressure_scaling(rates, nc, base=0.0, z_from=9.0)["best"] is None


def test_profile_peclet_recovers_the_Ps_of_a_steady_profile():
    """A T-eq. (28) profile (with noise 0.01) gives back its Ps to 3 %; a mixed layer's Ps is
    at the lower bound, and a flagged one."""
    from granflow.continuum.experiments import profile_peclet
    from granflow.fitting.segregation import phi_teq28

    h = 24.0
    z = np.arange(0.25, h, 0.25)
    rng = np.random.default_rng(3)
    for Ps in (3.0, 6.8, 25.0):
        phi = phi_teq28(z / h, Ps, 0.5) + rng.normal(0.0, 0.01, z.size)
        r = profile_peclet(z, phi, h=h, phi0=0.5, z_range=(1.0, h - 1.0))
        assert r["Ps"] == pytest.approx(Ps, rel=0.03)
        assert not r["at_bound"]
    flat = profile_peclet(z, np.full(z.size, 0.5), h=h, phi0=0.5)
    assert flat["at_bound"] and flat["rms"] < 5e-3
    with pytest.raises(ValueError, match="z_range"):
        profile_peclet(z, z * 0 + 0.5, h=h, phi0=0.5, z_range=(5.0, 5.2))


def test_transient_fit_with_a_depth_shape_recovers_its_rates():
    """T-eq. (27) with S ~ 1 / p (hydrostatic p, capped) from a partly segregated start: the
    fit given the same S_shape gets S and D_r back to 2 %; an unknown flux is refused."""
    from granflow.continuum.segregation import fit_segregation_transient, segregation_layer

    h = 20.0
    shape = lambda zeta: 0.5 / np.maximum(1.0 - np.asarray(zeta), 0.05)  # noqa: E731
    n = 100
    zc = (np.arange(n) + 0.5) / n
    start = np.clip(0.5 + 0.1 * np.cos(np.pi * zc), 0.01, 0.99)
    S, D = 0.01, 0.03
    res = segregation_layer(Ps=S * h / D, D=D, h=h, phi0=0.5, t_end=200.0, n=n, n_out=21,
                            phi_initial=start, S_shape=shape)
    levels = zc * h
    f = fit_segregation_transient(res.t.values, levels, res.phi.values, h=h, phi0=0.5,
                                  z_range=(1.0, h - 1.0), n=n, init_smoothing=0.0,
                                  init_modes=0, S_shape=shape)
    assert f["identified"]
    assert f["S"] == pytest.approx(S, rel=0.02) and f["D_r"] == pytest.approx(D, rel=0.02)
    with pytest.raises(ValueError, match="flux"):
        fit_segregation_transient(res.t.values, levels, res.phi.values, h=h, phi0=0.5,
                                  flux="none", S_shape=shape)


def test_inverse_pressure_shape_of_a_hydrostatic_layer(tmp_path):
    """p = (h - z) (hydrostatic, stored as sigma_zz = -p): the shape is p(h/2) / p(z), 1 at
    mid-depth, 2/3 at a quarter of the depth, capped at p_min near the surface."""
    import xarray as xr

    from granflow.continuum.experiments import inverse_pressure_shape

    h, base = 20.0, 0.5
    z = np.linspace(0.0, h, 401) + base
    xr.Dataset({"stress_zz": ("z", -(h - (z - base)))}, coords={"z": z}).to_netcdf(
        tmp_path / "profiles.nc")
    shape, p_mid = inverse_pressure_shape(tmp_path / "profiles.nc", base, h, p_min=1.0)
    assert p_mid == pytest.approx(10.0, rel=1e-6)
    assert shape(0.5) == pytest.approx(1.0, rel=1e-6)
    assert shape(0.25) == pytest.approx(2.0 / 3.0, rel=1e-6)
    assert shape(0.99) == pytest.approx(10.0, rel=1e-6)     # capped: p(0.99 h) = 0.2 < 1
    for bad in (50.0, 0.0, -1.0):
        with pytest.raises(ValueError, match="p_min"):
            inverse_pressure_shape(tmp_path / "profiles.nc", base, h, p_min=bad)


def test_transient_fit_r2_change_sees_a_window_that_does_not_evolve():
    """A steady profile sampled 20 times with noise 0.01: r2 (against phi's total variance,
    which holds the profile's shape) is above 0.99 although nothing evolves, r2_change
    (against the change since the start) is not above 0.6; on an exact transient both are
    above 0.999."""
    from granflow.fitting.segregation import phi_teq28

    h = 20.0
    z = np.arange(0.25, h, 0.25)
    rng = np.random.default_rng(11)
    t = np.arange(20.0) * 5.0
    phi = phi_teq28(z / h, 6.0, 0.5)[None, :] + rng.normal(0.0, 0.01, (t.size, z.size))
    f = fit_segregation_transient(t, z, phi, h=h, phi0=0.5, z_range=(1.0, h - 1.0))
    assert f["r2"] > 0.99 and f["r2_change"] <= 0.6, (f["r2"], f["r2_change"])
    res = segregation_layer(Ps=6.0, D=0.02, h=h, t_end=300.0, n=100, n_out=16)
    zc = res.z.values
    g = fit_segregation_transient(res.t.values, zc, res.phi.values, h=h, phi0=0.5, n=100,
                                  init_smoothing=0.0, init_modes=0)
    assert g["r2"] > 0.999 and g["r2_change"] > 0.999, (g["r2"], g["r2_change"])
