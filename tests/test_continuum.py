"""Continuum models (granflow.continuum) against exact solutions and conservation laws.

Fast tests: the uniform-layer ODE (steady state = the flow rule of Eq. 47, linearised e-folding
time, Coulomb arrest time), the shallow-layer solver (mass conserved to round-off, steady
uniform flow stays steady, uniform limit = the ODE, small waves = linearised Eq. 34, Coulomb
dam break against Mangeney et al. 2000 and tilupy's implementation of it), the segregation model (conservation, steady state =
T-eq. 28 / the asymmetric profile, the diffusive decay rate pi^2 D/h^2), and library-driven
closures (the same numbers as the library's evaluators, status refusals, ensemble spread).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from granflow.continuum import (FlowClosures, dam_break_front, fit_relaxation,
                                linear_relaxation_time, local_equilibrium_layer,
                                mangeney_dam_break, segregation_layer, shallow_layer,
                                switch_prediction, uniform_layer)
from granflow.continuum.segregation import half_time, steady_profile
from granflow.fitting.flow_rule import mu_eq50
from granflow.fitting.hstop import hstop_eq45
from granflow.fitting.segregation import phi_asymmetric, phi_teq28

#: the paper's lambda = 1 friction parameters (Table 1): a synthetic Eq. (50)
P1 = dict(delta1=17.708, delta2=32.780, A=3.355, beta=0.196, gamma=0.040)


def eq50(theta, K=1.0, alpha=1.0):
    return FlowClosures(theta=theta, mu=lambda h, F: mu_eq50(h, F, **P1), K=K,
                        alpha=lambda h: np.full(np.shape(h), alpha))


# ----------------------------------------------------------------------------- uniform ODE
def test_steady_velocity_is_the_flow_rule():
    for theta, h in ((22.0, 6.0), (25.0, 10.0), (28.0, 4.0)):
        c = eq50(theta)
        F = beta_rule = P1["beta"] * h / float(hstop_eq45(theta, P1["delta1"], P1["delta2"],
                                                           P1["A"])) - P1["gamma"]
        assert c.steady_froude(h) == pytest.approx(beta_rule, rel=1e-10)
        ode = uniform_layer(c, h, 0.1, 400.0)
        assert float(ode.u_steady) == pytest.approx(F * math.sqrt(c.g_cos * h), rel=1e-10)
        assert ode.u_bar.values[-1] == pytest.approx(float(ode.u_steady), rel=1e-6)


def test_small_perturbation_decays_with_the_linearised_time():
    c = eq50(25.0)
    h = 10.0
    u_s = c.steady_froude(h) * math.sqrt(c.g_cos * h)
    tau = linear_relaxation_time(c, h)
    ode = uniform_layer(c, h, 1.01 * u_s, 6 * tau, n_out=601)
    fit = fit_relaxation(ode.t.values, ode.u_bar.values, 1.01 * u_s)
    assert fit["tau"] == pytest.approx(tau, rel=5e-3)
    assert fit["u_inf"] == pytest.approx(u_s, rel=1e-5)


def test_coulomb_layer_arrests_at_the_exact_time():
    mu = math.tan(math.radians(25.0))
    c = FlowClosures.coulomb(theta=20.0, mu=mu)
    u0 = 1.5
    t_exact = u0 / (c.g_cos * (mu - c.tan_theta))
    ode = uniform_layer(c, 5.0, u0, 3 * t_exact, n_out=301)
    assert float(ode.t_rest) == pytest.approx(t_exact, rel=1e-8)
    assert np.all(ode.u_bar.values[ode.t.values > t_exact] == 0.0)
    assert math.isnan(float(ode.u_steady))


def test_uniform_layer_rejects_bad_input_before_compute():
    with pytest.raises(ValueError, match="h = -1"):
        uniform_layer(eq50(25.0), -1.0, 0.5, 10.0)
    with pytest.raises(ValueError, match="t_end"):
        uniform_layer(eq50(25.0), 5.0, 0.5, 0.0)


# ----------------------------------------------------------------------------- shallow layer
def test_mass_is_conserved_to_round_off_on_a_periodic_domain():
    c = eq50(26.0, K=1.05, alpha=1.25)
    x = np.arange(200) * 0.5 + 0.25
    h0 = 6.0 + 3.0 * np.exp(-((x - 30.0) / 5.0) ** 2)
    res = shallow_layer(c, x, h0, 0.6, t_end=40.0, n_out=9)
    m = res.mass.values
    assert np.max(np.abs(m - m[0])) <= 1e-13 * m[0]
    assert res.attrs["n_steps"] > 50
    # the bump moved downslope
    peak = res.x.values[np.argmax(res.h.values, axis=1)]
    assert peak[-1] > peak[0] + 10.0


def test_steady_uniform_flow_stays_steady():
    c = eq50(25.0, K=1.02, alpha=1.3)
    h = 8.0
    u_s = c.steady_froude(h) * math.sqrt(c.g_cos * h)
    x = np.arange(32) + 0.5
    res = shallow_layer(c, x, h, u_s, t_end=100.0, n_out=11)
    assert np.max(np.abs(res.h.values - h)) == 0.0
    assert np.max(np.abs(res.u_bar.values - u_s)) <= 1e-13


def test_uniform_limit_is_the_ode():
    c = eq50(25.0, K=1.02, alpha=1.3)
    h, u0 = 10.0, 0.3
    ode = uniform_layer(c, h, u0, 100.0, n_out=101)
    fv = shallow_layer(c, np.arange(8) + 0.5, h, u0, t_end=100.0, n_out=101)
    assert np.max(np.abs(fv.u_bar.values - ode.u_bar.values[:, None])) < 1e-7


def _linear_modes(c, h, u, alpha, k, nu=0.0):
    """Linearised Eq. (34) about the steady uniform state (h, u), constant alpha, wavenumber
    k: the two complex frequencies omega of exp(i (k x - omega t)), the kinematic speed
    -S_h/S_q = dq/dh and the gravity-wave characteristic alpha u + c.  ``nu``: with the
    viscous stress d(nu h^(3/2) du/dx)/dx, whose linearisation -k^2 nu h^(1/2) (q' - u h')
    adds -k^2 nu h^(1/2) to S_q and +k^2 nu h^(1/2) u to S_h."""
    def source(hh, qq):
        return hh * float(c.acceleration(hh, qq / hh))
    q, e = h * u, 1e-6
    s_h = (source(h + e, q) - source(h - e, q)) / (2 * e)
    s_q = (source(h, q + e) - source(h, q - e)) / (2 * e)
    visc = k * k * nu * math.sqrt(h)
    s_h, s_q = s_h + visc * u, s_q - visc
    f_h, f_q = c.K * c.g_cos * h - alpha * u * u, 2 * alpha * u
    omega = np.roots([1.0, -f_q * k - 1j * s_q, -f_h * k * k - 1j * s_h * k])
    c_plus = alpha * u + math.sqrt(alpha * (alpha - 1) * u * u + c.K * c.g_cos * h)
    return omega, -s_h / s_q, c_plus


@pytest.mark.parametrize("wavelength, regime", [(100.0, "gravity"), (4000.0, "kinematic")])
def test_small_wave_follows_the_linearised_eq34(wavelength, regime):
    """A small Fourier mode on a steady uniform layer (h = 8, Eq. 50 of Table 1 at 25 deg)
    travels and decays as linearised Eq. (34) says: phase speed within 1 %, decay rate within
    5 % (100 cells a wavelength).  The least-damped mode is a gravity wave (alpha u + c,
    within 2 %) at wavelength 100, the long chute's length (k tau (alpha u + c - dq/dh) = 1.39
    with the relaxation time tau = 14.3), and the kinematic wave dq/dh (within 1 %) at
    wavelength 4000 (k tau (alpha u + c - dq/dh) = 0.035)."""
    alpha = 1.3
    c = eq50(25.0, K=1.02, alpha=alpha)
    h = 8.0
    u = c.steady_froude(h) * math.sqrt(c.g_cos * h)
    k = 2 * math.pi / wavelength
    omega, c_kin, c_plus = _linear_modes(c, h, u, alpha, k)
    w = omega[np.argmax(omega.imag)]                      # the least-damped mode
    speed, rate = w.real / k, -w.imag
    x = (np.arange(100) + 0.5) * wavelength / 100
    eps = 1e-3 * h
    h0 = h + eps * np.cos(k * x)
    q0 = h * u + eps * np.real(w / k * np.exp(1j * k * x))   # its eigenvector
    t_end = 0.5 * wavelength / speed
    res = shallow_layer(c, x, h0, q0 / h0, t_end, n_out=2)
    ratio = np.sum((res.h.values[1] - h) * np.exp(-1j * k * x)) / \
        np.sum((res.h.values[0] - h) * np.exp(-1j * k * x))
    phase = -np.angle(ratio)
    phase += 2 * math.pi * round((w.real * t_end - phase) / (2 * math.pi))
    assert phase / k / t_end == pytest.approx(speed, rel=1e-2)
    assert -math.log(abs(ratio)) / t_end == pytest.approx(rate, rel=5e-2)
    if regime == "gravity":
        assert speed == pytest.approx(c_plus, rel=2e-2)
    else:
        assert speed == pytest.approx(c_kin, rel=1e-2)


@pytest.mark.parametrize("wavelength", [25.0, 50.0])
def test_small_wave_with_viscosity_follows_the_linearised_equations(wavelength):
    """With the Gray-Edwards viscous stress (nu of Table 1's closure at 25 deg, h = 8: 2.28)
    a small Fourier mode decays at the rate of the linearised equations (within 5 %), which
    the viscous term raises 11.9x (wavelength 25) and 3.9x (50) over Eq. (34) alone."""
    alpha = 1.3
    c = eq50(25.0, K=1.02, alpha=alpha)
    h = 8.0
    nu = c.gray_edwards_viscosity(h)
    u = c.steady_froude(h) * math.sqrt(c.g_cos * h)
    k = 2 * math.pi / wavelength
    omega, _, _ = _linear_modes(c, h, u, alpha, k, nu=nu)
    w = omega[np.argmax(omega.imag)]
    rate = -w.imag
    omega0, _, _ = _linear_modes(c, h, u, alpha, k)
    rate0 = -omega0[np.argmax(omega0.imag)].imag
    assert rate > 3 * rate0            # the term dominates at these wavelengths
    x = (np.arange(100) + 0.5) * wavelength / 100
    eps = 1e-3 * h
    h0 = h + eps * np.cos(k * x)
    q0 = h * u + eps * np.real(w / k * np.exp(1j * k * x))
    t_end = 1.0 / rate
    res = shallow_layer(c, x, h0, q0 / h0, t_end, n_out=2, viscosity=nu)
    ratio = np.sum((res.h.values[1] - h) * np.exp(-1j * k * x)) / \
        np.sum((res.h.values[0] - h) * np.exp(-1j * k * x))
    assert -math.log(abs(ratio)) / t_end == pytest.approx(rate, rel=5e-2)
    assert res.attrs["viscosity"] == nu and "Gray & Edwards" in res.attrs["equation"]


def test_viscous_term_conserves_mass_and_momentum_and_keeps_uniform_flow():
    """The viscous stress only moves momentum between cells: with friction balancing gravity
    (Coulomb mu = tan theta, u > 0) the total momentum sum(h u) dx is conserved to round-off,
    as is the mass; a steady uniform flow stays steady bit for bit (du/dx = 0)."""
    c = FlowClosures.coulomb(theta=25.0, mu=math.tan(math.radians(25.0)), alpha=1.2)
    x = np.arange(200) * 0.5 + 0.25
    h0 = 6.0 + 3.0 * np.exp(-((x - 30.0) / 5.0) ** 2)
    u0 = 2.0 + 0.5 * np.sin(2 * math.pi * x / 100.0)
    res = shallow_layer(c, x, h0, u0, t_end=20.0, n_out=5, viscosity=2.0)
    mom = (res.h * res.u_bar).sum("x").values * 0.5
    assert np.all(res.u_bar.values > 0)
    assert np.max(np.abs(mom - mom[0])) <= 1e-12 * mom[0]
    assert np.max(np.abs(res.mass.values - res.mass.values[0])) <= 1e-13 * res.mass.values[0]
    inviscid = shallow_layer(c, x, h0, u0, t_end=20.0, n_out=5)
    # the viscous run smooths the velocity: its spread shrinks faster
    assert np.ptp(res.u_bar.values[-1]) < 0.8 * np.ptp(inviscid.u_bar.values[-1])
    e = eq50(25.0, K=1.02, alpha=1.3)
    u_s = e.steady_froude(8.0) * math.sqrt(e.g_cos * 8.0)
    steady = shallow_layer(e, np.arange(32) + 0.5, 8.0, u_s, t_end=100.0, n_out=11,
                           viscosity=e.gray_edwards_viscosity(8.0))
    assert np.max(np.abs(steady.h.values - 8.0)) == 0.0
    assert np.max(np.abs(steady.u_bar.values - u_s)) <= 1e-13


def test_viscous_flux_converges_at_second_order():
    """The viscous part of the momentum right-hand side against d(nu h^(3/2) du/dx)/dx of
    smooth periodic h(x), u(x) (exact derivative): error falls 4x per halving of dx."""
    from granflow.continuum.shallow import ShallowLayerSolver

    c = FlowClosures.coulomb(theta=25.0, mu=0.4)
    L, nu = 40.0, 1.7
    errs = []
    for n in (64, 128, 256):
        dx = L / n
        x = (np.arange(n) + 0.5) * dx
        kx = 2 * math.pi / L
        h = 5.0 + np.cos(kx * x)
        u = 1.0 + 0.3 * np.sin(kx * x)
        hx = -kx * np.sin(kx * x)
        ux = 0.3 * kx * np.cos(kx * x)
        uxx = -0.3 * kx * kx * np.sin(kx * x)
        exact = nu * (1.5 * np.sqrt(h) * hx * ux + h ** 1.5 * uxx)
        with_v = ShallowLayerSolver(c, dx, n, viscosity=nu).rhs(h, h * u)[1]
        without = ShallowLayerSolver(c, dx, n).rhs(h, h * u)[1]
        errs.append(np.max(np.abs(with_v - without - exact)))
    assert errs[0] / errs[1] > 3.5 and errs[1] / errs[2] > 3.5, errs
    assert errs[-1] < 1e-3 * np.max(np.abs(exact))


def test_gray_edwards_viscosity_is_their_closed_form():
    """With gamma = 0 the coefficient is Gray & Edwards' (2/9) (L sqrt(g)/beta) sin/sqrt(cos)
    (tan zeta2 - tan)/(tan - tan zeta1) at every depth (L = A d); bad depths are refused."""
    p = dict(P1, gamma=0.0)
    c = FlowClosures(theta=25.0, mu=lambda h, F: mu_eq50(h, F, **p))
    t, t1, t2 = (math.tan(math.radians(a)) for a in (25.0, p["delta1"], p["delta2"]))
    ge = 2 / 9 * p["A"] / p["beta"] * math.sin(math.radians(25.0)) / \
        math.sqrt(math.cos(math.radians(25.0))) * (t2 - t) / (t - t1)
    for h in (4.0, 8.0, 20.0):
        assert c.gray_edwards_viscosity(h) == pytest.approx(ge, rel=1e-9)
    with pytest.raises(ValueError, match="h_ref"):
        c.gray_edwards_viscosity(-1.0)
    with pytest.raises(ValueError, match="no steady flow"):
        eq50(18.0).gray_edwards_viscosity(2.0)        # arrested there
    for bad, why in ((-1.0, "out of range: allowed \\[0.0, inf\\)"), (math.inf, "out of range"),
                     (math.nan, "out of range"), ("abc", "not a number"), (None, "not a number")):
        with pytest.raises(ValueError, match=f"viscosity = .* {why}"):
            shallow_layer(c, np.arange(8) + 0.5, 8.0, 1.0, 1.0, viscosity=bad)
    with pytest.raises(ValueError, match="cfl = 'x' is not a number"):
        shallow_layer(c, np.arange(8) + 0.5, 8.0, 1.0, 1.0, cfl="x")


@pytest.mark.parametrize("theta, delta", [(30.0, 20.0), (35.0, 25.0)])
def test_coulomb_dam_break_matches_mangeney_2000(theta, delta):
    c = FlowClosures.coulomb(theta=theta, mu=math.tan(math.radians(delta)))
    dx = 0.125
    x = np.arange(-60.0, 40.0, dx) + 0.5 * dx
    h0 = 4.0
    t = 5.0
    res = shallow_layer(c, x, np.where(x < 0, h0, 0.0), 0.0, t_end=t, bc="open", n_out=2)
    h_ex, u_ex = mangeney_dam_break(x, t, h0, theta, delta)
    h = res.h.isel(t=-1).values
    region = x > -40.0   # away from the open upstream boundary
    err = np.sum(np.abs(h - h_ex)[region]) / np.sum(h_ex[region])
    assert err < 0.005, err
    # velocity inside the fan (where h > 5 % of h0) within 2 %
    fan = region & (h_ex > 0.05 * h0) & (x > -c.g_cos ** 0.5 * 2 * t)
    u = res.u_bar.isel(t=-1).values
    assert np.max(np.abs(u[fan] - u_ex[fan]) / np.abs(u_ex[fan]).max()) < 0.02
    # the front: where h falls below 5 % of h0, within two cells of the exact position (the
    # vanishing tip beyond it converges at first order only: within 15 % here)
    def contour(hh):
        return x[np.nonzero(hh > 0.05 * h0)[0][-1]]
    assert abs(contour(h) - contour(h_ex)) <= 2 * dx
    tip = x[np.nonzero(h > 1e-4 * h0)[0][-1]]
    assert tip == pytest.approx(dam_break_front(t, h0, theta, delta), rel=0.15)


def test_mangeney_transcription_matches_tilupy():
    A = pytest.importorskip("tilupy.analytic_sol")
    x = np.linspace(-30.0, 40.0, 141)
    for theta, delta, t in ((30.0, 20.0, 3.0), (35.0, 25.0, 5.0), (25.0, 25.0, 2.0)):
        sol = A.Mangeney_dry(x_0=0.0, h_0=4.0, theta=theta, delta=delta)
        # tilupy uses g = 9.81; the solution with g = 1 at time t is tilupy's at t / sqrt(g)
        sol.compute_h(x, [t / math.sqrt(9.81)])
        sol.compute_u(x, [t / math.sqrt(9.81)])
        h, u = mangeney_dam_break(x, t, 4.0, theta, delta)
        assert np.max(np.abs(sol._h[0] - h)) < 1e-12
        fan = np.isfinite(sol._u[0])
        assert np.allclose(sol._u[0][fan] / math.sqrt(9.81), u[fan], rtol=1e-12, atol=1e-12)


def test_shallow_layer_rejects_bad_input():
    c = eq50(25.0)
    x = np.arange(10) + 0.5
    with pytest.raises(ValueError, match="h0"):
        shallow_layer(c, x, -1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="bc"):
        shallow_layer(c, x, 1.0, 0.0, 1.0, bc="wall")
    with pytest.raises(ValueError, match="uniformly"):
        shallow_layer(c, x ** 2, 1.0, 0.0, 1.0)


# ----------------------------------------------------------------------------- segregation
@pytest.mark.parametrize("flux, kappa", [("symmetric", 0.0), ("asymmetric", 0.6)])
def test_segregation_conserves_and_reaches_the_steady_profile(flux, kappa):
    Ps, D, h = 8.0, 0.05, 6.0
    res = segregation_layer(Ps, D, h, 0.5, t_end=6 * h * h / D, flux=flux, kappa=kappa, n=200,
                            n_out=61)
    phi = res.phi.values
    assert np.max(np.abs(phi.mean(axis=1) - 0.5)) < 1e-12
    zeta = res.zeta.values
    exact = (phi_teq28(zeta, Ps, 0.5) if flux == "symmetric"
             else phi_asymmetric(zeta, Ps, 0.5, kappa))
    assert np.max(np.abs(phi[-1] - exact)) < 2e-4
    # the discrete steady state: second order in the cell size (1/200)
    assert np.max(np.abs(phi[-1] - steady_profile(Ps, 0.5, 200, flux=flux, kappa=kappa))) < 3e-5
    assert float(res.indicator[-1]) == pytest.approx(float(res.indicator_steady), rel=1e-4)
    assert 0 < float(res.t_half) < 6 * h * h / D


def test_pure_diffusion_decays_at_pi_squared_D_over_h_squared():
    n, D, h = 400, 0.1, 5.0
    zeta = (np.arange(n) + 0.5) / n
    eps = 0.1   # Ps = 0: the equation is linear, any amplitude decays at the same rate
    start = 0.5 + eps * np.cos(math.pi * zeta)
    t = 0.5 * h * h / D
    res = segregation_layer(0.0, D, h, 0.5, t_end=t, phi_initial=start, n=n, n_out=2)
    amp = 2 * np.mean((res.phi.values[-1] - 0.5) * np.cos(math.pi * zeta))
    # the discrete mode decays at (4 n^2 sin^2(pi/2n)) D/h^2 -> pi^2 D/h^2
    assert amp == pytest.approx(eps * math.exp(-math.pi ** 2 * D * t / h ** 2), rel=1e-4)


def test_a_start_on_a_nearer_profile_bounds_the_steady_peclet_number_sooner():
    """The lever of ``initial_mixing: profile<Ps>`` (granflow.engine.chute), in T-eq. 27 itself
    (Ps 5, D 0.039, depth 22: the paper's set-up at 1/sigma = 1.25 with the remixing
    diffusivity measured at 1/sigma = 2): the Ps of T-eq. 28 fitted to phi(z) at t = 600 is
    5.79 and 4.22 from starts on the steady profiles at Ps 7 and 3.5, where the fully
    segregated and the mixed starts give 7.51 and 1.97 (the README's numbers); each start
    approaches Ps 5 monotonically from its own side (a one-sided bound at every time)."""
    from scipy.optimize import minimize_scalar

    from granflow.continuum import segregation_layer

    n = 200

    def fitted(phi):
        return minimize_scalar(lambda P: float(np.sum((steady_profile(P, 0.5, n) - phi) ** 2)),
                               bounds=(0.05, 200.0), method="bounded",
                               options={"xatol": 1e-6}).x

    starts = {"sharp": np.where((np.arange(n) + 0.5) / n < 0.5, 1.0, 0.0),
              "profile7": steady_profile(7.0, 0.5, n), "profile3.5": steady_profile(3.5, 0.5, n),
              "mixed": None}
    expect = {"sharp": 7.51, "profile7": 5.79, "profile3.5": 4.22, "mixed": 1.97}
    for name, init in starts.items():
        ds = segregation_layer(5.0, 0.039, 22.0, 0.5, t_end=600.0, phi_initial=init, n=n,
                               n_out=7)
        ps = np.array([fitted(p) for p in ds.phi.values[1:]])
        assert ps[-1] == pytest.approx(expect[name], abs=0.006), name
        side = np.sign(ps - 5.0)
        assert np.all(side == side[0]) and np.all(np.diff(np.abs(ps - 5.0)) < 0), (name, ps)


def test_segregation_time_scales_with_h_squared_over_D():
    a = segregation_layer(6.0, 0.02, 8.0, 0.5, t_end=2000.0, n=100)
    b = segregation_layer(6.0, 0.04, 8.0, 0.5, t_end=1000.0, n=100)
    assert float(a.t_half) == pytest.approx(2 * float(b.t_half), rel=1e-3)


def test_half_time_interpolates_the_crossing():
    assert half_time([0, 1, 2, 3], [0, -0.2, -0.6, -1.0], 0.0, -1.0) == pytest.approx(1.75)
    assert math.isnan(half_time([0, 1], [0, -0.1], 0.0, -1.0))


# ----------------------------------------------------------------------------- from a library
@pytest.fixture(scope="module")
def library(tmp_path_factory):
    from test_identify import _campaign

    import granflow.closures as gc
    from granflow.fitting import fit_campaign

    table = _campaign(np.random.default_rng(2012))
    fits = fit_campaign(table, n_bootstrap=40)
    return gc.open_library(gc.write_library(tmp_path_factory.mktemp("lib"), "c", fits, table))


def test_library_closures_are_the_evaluators(library):
    st = library.closures.status()
    status = dict(zip(st["kind"], st["status"]))
    kw = dict(allow_unidentified=True)
    c = FlowClosures.from_library(library, 25.0, **kw)
    for kind in ("friction", "alpha", "stress_ratio"):
        assert c.status[kind] == status[kind]
    not_ok = [k for k in ("friction", "alpha", "stress_ratio")
              if status[k] not in ("ok", "reduced")]
    if not_ok:  # refused without allow_unidentified, naming the closure
        with pytest.raises(ValueError, match=not_ok[0]):
            FlowClosures.from_library(library, 25.0)
    h = np.array([12.0, 20.0, 30.0])
    F = np.array([0.3, 0.6, 1.0])
    assert np.allclose(c.mu(h, F), library.closures.mu(h, F, extrapolate=True, **kw),
                       rtol=1e-12)
    assert np.allclose(c.alpha(h), library.closures.alpha(25.0, h, extrapolate=True, **kw),
                       rtol=1e-12)
    assert c.K == pytest.approx(float(library.closures.K(25.0)), rel=1e-12)
    # the steady state of the ODE is the library's flow rule (Eq. 50 is built from it)
    F_rule = float(library.closures.froude(20.0, 25.0, extrapolate=True,
                                           allow_unidentified=True))
    assert c.steady_froude(20.0) == pytest.approx(F_rule, rel=1e-8)


def test_switch_prediction_carries_the_ensemble_spread(library):
    pred = switch_prediction(library, h=20.0, u0=1.0, theta=26.0, t_end=150.0,
                             allow_unidentified=True, n_ensemble=30, extrapolate=True)
    v = pred.u_steady.sel(stat="value").item()
    sd = pred.u_steady.sel(stat="std").item()
    lo, hi = pred.u_steady.sel(stat="low").item(), pred.u_steady.sel(stat="high").item()
    assert sd > 0 and lo < v < hi
    assert pred.attrs["n_ensemble"] == 30
    assert pred.u_bar.attrs["units"] == "1" and "nondimensional_unit" in pred.u_bar.attrs
    assert pred.attrs["Conventions"].startswith("CF-1.8")
    assert pred.attrs["closure_status_friction"] in ("ok", "reduced", "unidentified", "misfit")


def test_switch_prediction_refuses_unfitted_states(library):
    with pytest.raises(ValueError, match="outside"):
        switch_prediction(library, h=200.0, u0=1.0, theta=26.0, t_end=10.0,
                          allow_unidentified=True, uncertainty=False)


# ----------------------------------------------------------------------------- column
def _steady_u(c, h):
    return c.steady_froude(h) * math.sqrt(c.g_cos * h)


def test_column_slowest_modes_are_the_zeros_of_bessel_j_minus_one_third():
    """The discretised linear column (viscosity ~ sqrt(1 - z/h), no slip below, free surface
    above) against the exact modes s^(1/4) J_(-1/3)((4/3) sqrt(lambda) s^(3/4)): lambda_k =
    (3 j_k / 4)^2 with j_k the zeros of J_(-1/3), found here from scipy's Bessel function
    (1.8664, 4.9879, 8.1243; the column code never sees them)."""
    from scipy import optimize, special

    from granflow.continuum.column import (LINEAR_TAU_RATIO, linear_column_eigenvalues,
                                           slowest_mode_eigenvalue)

    zeros = [optimize.brentq(lambda x: special.jv(-1.0 / 3.0, x), a, b)
             for a, b in ((1.0, 2.5), (4.0, 6.0), (7.0, 9.0))]
    exact = [(0.75 * j) ** 2 for j in zeros]
    assert exact[0] == pytest.approx(1.95934, abs=1e-5)
    for n, tol in ((64, 3e-3), (512, 1e-4)):
        assert linear_column_eigenvalues(n) == pytest.approx(exact, rel=tol)
    # second order in the cell size: 8x finer cells, ~64x smaller error on the slowest mode
    e64, e512 = (abs(linear_column_eigenvalues(n)[0] - exact[0]) for n in (64, 512))
    assert 30 < e64 / e512 < 130
    assert slowest_mode_eigenvalue() == pytest.approx(exact[0], rel=1e-12)
    assert LINEAR_TAU_RATIO == pytest.approx(2.5 / exact[0], rel=1e-12)


@pytest.mark.parametrize("gamma", [0.0, 0.04, 0.2])
def test_column_small_switch_relaxes_1_276_times_slower_than_the_ode(gamma):
    """The nonlinear column solver, a small change of inclination: after the fast modes have
    gone, u_bar approaches its steady value at the slowest mode's rate, 5 / (2 lambda1) =
    1.276 times the linearised ODE's e-folding time, for any friction law (here Eq. 50 with
    three gammas)."""
    from granflow.continuum.column import LINEAR_TAU_RATIO, column_layer

    p = dict(P1, gamma=gamma)

    def law(theta):
        return FlowClosures(theta=theta, mu=lambda h, F: mu_eq50(h, F, **p))

    h = 10.0
    c1, c2 = law(25.0), law(25.02)
    tau_ode = linear_relaxation_time(c2, h)
    col = column_layer(c1.at(25.02), h, _steady_u(c1, h), 8 * tau_ode, n_z=128, n_out=801,
                       rtol=1e-10, atol=1e-13)
    # the rate from du_bar/dt (free of the discrete steady state's O(dz^1.5) offset)
    t = col.t.values
    dudt = np.gradient(col.u_bar.values, t)
    late = (t > 2 * tau_ode) & (t < 6 * tau_ode)
    rate = -np.polyfit(t[late], np.log(dudt[late]), 1)[0]
    assert 1.0 / rate == pytest.approx(LINEAR_TAU_RATIO * tau_ode, rel=5e-3)
    assert float(col.tau_linear) == pytest.approx(LINEAR_TAU_RATIO * tau_ode, rel=1e-12)
    assert col.u_bar.values[-1] == pytest.approx(float(col.u_steady), rel=2e-4)


def test_column_steady_state_is_bagnold_at_the_closures_steady_froude_number():
    from granflow.continuum.column import column_layer

    c = eq50(26.0)
    h = 8.0
    u_s = _steady_u(c, h)
    col = column_layer(c, h, u_s, 200.0, n_z=128)
    z = col.z.values
    bagnold = (5.0 / 3.0) * u_s * (1.0 - (1.0 - z / h) ** 1.5)
    assert np.abs(col.u.values[-1] - bagnold).max() < 1e-3 * u_s
    assert abs(col.u_bar.values[-1] / u_s - 1.0) < 1e-4
    # from far away too (a fast start relaxes to the same state)
    fast = column_layer(c, h, 2.0 * u_s, 800.0, n_z=64)
    assert fast.u_bar.values[-1] == pytest.approx(u_s, rel=1e-3)


def test_column_momentum_balance_is_exact():
    """h du_bar/dt = h g sin(theta) - tau_base: the finite-volume fluxes telescope, so the
    column's depth-integrated momentum changes only by gravity and the base's stress."""
    from granflow.continuum import column

    c = eq50(27.0)
    h = 6.0
    col = column.column_layer(c, h, 0.3, 40.0, n_z=32, n_out=4001, rtol=1e-10, atol=1e-13)
    u = col.u.values
    dz = h / u.shape[1]
    shear_base = u[:, 0] / (0.5 * dz)
    F_base = shear_base * 0.4 * h / np.sqrt(c.g_cos * h)
    tau_b = c.g_cos * h * mu_eq50(np.full_like(F_base, h), F_base, **P1) * np.tanh(
        shear_base / (column.EPS_SHEAR * 0.3 / h))
    t = col.t.values
    lhs = h * (col.u_bar.values[-1] - col.u_bar.values[0])
    rhs = h * c.g_cos * c.tan_theta * t[-1] - np.trapezoid(tau_b, t)
    assert lhs == pytest.approx(rhs, rel=2e-4)


def test_column_and_switch_model_reject_bad_input():
    from granflow.continuum.column import column_layer

    c = eq50(26.0)
    for kw, field in ((dict(h=-1.0), "h"), (dict(t_end=0.0), "t_end"), (dict(u0=math.nan), "u0"),
                      (dict(n_z=4), "n_z")):
        args = dict(h=8.0, u0=0.5, t_end=10.0) | kw
        with pytest.raises(ValueError, match=field):
            column_layer(c, **args)
    with pytest.raises(ValueError, match="model = 'depth'.*allowed"):
        switch_prediction(c, h=8.0, u0=0.5, theta=26.0, t_end=10.0, model="depth")


def test_switch_prediction_runs_the_column_over_the_ensemble(library):
    kw = dict(h=20.0, u0=1.0, theta=26.0, t_end=150.0, allow_unidentified=True, n_ensemble=20,
              extrapolate=True)
    ode = switch_prediction(library, **kw)
    col = switch_prediction(library, model="column", **kw)
    assert col.attrs["continuum_layer_model"] == "column" and col.attrs["n_ensemble"] == 20
    # same closures, same steady state; the column's transient is slower
    assert float(col.u_steady.sel(stat="value")) == pytest.approx(
        float(ode.u_steady.sel(stat="value")), rel=1e-12)
    assert float(col.tau.sel(stat="value")) > 1.1 * float(ode.tau.sel(stat="value"))
    assert float(col.tau.sel(stat="std")) > 0


# ----------------------------------------------------------------------------- CF outputs
def test_model_results_are_cf_compliant(tmp_path):
    from cf_compliance import check

    from granflow.provenance import atomic_to_netcdf

    c = eq50(26.0, K=1.05, alpha=1.25)
    x = np.arange(40) + 0.5
    from granflow.continuum.column import column_layer

    results = {"uniform": uniform_layer(c, 8.0, 0.3, 20.0, n_out=21),
               "column": column_layer(c, 8.0, 0.3, 20.0, n_z=16, n_out=21),
               "shallow": shallow_layer(c, x, 6.0 + np.exp(-((x - 10) / 3) ** 2), 0.5, 5.0,
                                        n_out=3),
               "segregation": segregation_layer(6.0, 0.02, 8.0, 0.5, 50.0, n=40, n_out=6),
               "kinematic": local_equilibrium_layer(c, x, 6.0 + np.exp(-((x - 10) / 3) ** 2),
                                                    2.0, diffusive=False, n_out=3)}
    for name, ds in results.items():
        path = tmp_path / f"{name}.nc"
        atomic_to_netcdf(ds, path)
        for var in ds.data_vars.values():
            assert var.attrs["units"] in ("1", "degree") and var.attrs["long_name"]
        s = check(path)
        assert not s["cf:1.8"].high_failures, (name, s["cf:1.8"].high_failures)
        assert not s["acdd:1.3 applicable"].high_failures, (name, s["acdd:1.3 applicable"])


def test_segregation_Ps_follows_the_library_status_rules():
    import xarray as xr

    from granflow.continuum.experiments import segregation_Ps_at

    lib = xr.Dataset(
        {"segregation_Ps": (("contact_law", "sigma"), [[16.4, 9.3, np.nan]]),
         "segregation_status": (("contact_law", "sigma"),
                                np.array([["ok", "unidentified", "failed"]], dtype=object))},
        coords={"contact_law": ["linear"], "sigma": [0.5, 0.7, 0.9]})
    assert segregation_Ps_at(lib, 0.5) == (16.4, "ok")
    with pytest.raises(ValueError, match="sigma = 0.7 is unidentified"):
        segregation_Ps_at(lib, 0.7)
    assert segregation_Ps_at(lib, 0.7, allow_unidentified=True) == (9.3, "unidentified")
    with pytest.raises(ValueError, match="failed"):  # failed: refused even when allowed
        segregation_Ps_at(lib, 0.9, allow_unidentified=True)
    with pytest.raises(ValueError, match="sigma = 0.6 has no segregation closure"):
        segregation_Ps_at(lib, 0.6)


def test_aligned_half_time_of_an_exponential_approach_is_tau_ln2_from_any_start():
    # s(t) = s_inf (1 - exp(-t / tau)) is memoryless: from any start level the time to half
    # the remaining way is tau ln 2 (the model's clock shifted to a partly segregated start)
    from granflow.continuum.experiments import aligned_half_time, level_time

    tau, s_inf = 37.0, -1.7
    t = np.linspace(0.0, 400.0, 40001)
    s = s_inf * (1.0 - np.exp(-t / tau))
    for start in (0.0, 0.3, 0.57, 0.8):
        s0 = start * s_inf
        th, shift = aligned_half_time(t, s, s_inf, s0)
        assert shift == pytest.approx(-tau * np.log1p(-start), abs=1e-3)
        assert th == pytest.approx(tau * np.log(2.0), rel=1e-5)
    # a particle run that starts beyond the model's final state cannot be aligned
    assert all(math.isnan(v) for v in aligned_half_time(t, s, s_inf, 1.1 * s_inf))
    assert all(math.isnan(v) for v in aligned_half_time(t, s, s_inf, 0.2))
    assert level_time(t, s, 0.0) == 0.0 and math.isnan(level_time(t, s, 2.0 * s_inf))


def test_eq50_below_minus_gamma_is_its_arrest_limit_without_a_pole():
    # gamma < 0 (the paper's fits have both signs): the formula has a pole at
    # F = -gamma - beta h / A for thin layers; below F = -gamma mu is tan(delta1)
    p = dict(delta1=21.0, delta2=33.0, A=3.0, beta=0.6, gamma=-0.2)
    h = 0.5  # pole of the raw formula at F = 0.2 - 0.1 = 0.1
    F = np.linspace(0.0, 3.0, 3001)
    mu = mu_eq50(h, F, **p)
    t1 = math.tan(math.radians(21.0))
    assert np.all(mu[F <= 0.2] == t1)
    assert np.all(np.diff(mu) >= 0) and np.all(mu < math.tan(math.radians(33.0)))
    assert mu[F > 0.2][0] - t1 < 1e-2  # continuous at F = -gamma
    # above -gamma it is the paper's formula unchanged
    raw = t1 + (math.tan(math.radians(33.0)) - t1) / (0.6 * h / (3.0 * (F[-1] - 0.2)) + 1.0)
    assert mu[-1] == pytest.approx(raw, rel=1e-14)


def test_uniform_layer_stops_with_an_error_on_a_law_that_jumps_inside_the_flow():
    # mu jumps across tan(theta) at F = 0.2: the ODE would chatter at the jump without end
    theta = 25.0
    jump = FlowClosures(theta=theta, mu=lambda h, F: np.where(np.asarray(F) < 0.2, 0.1, 0.9),
                        K=1.0, alpha=lambda h: np.ones(np.shape(h)))
    with pytest.raises(RuntimeError, match="stalled"):
        uniform_layer(jump, 6.0, 0.3, 100.0)
    from granflow.continuum.column import column_layer

    with pytest.raises(RuntimeError, match="column model stalled"):
        column_layer(jump, 6.0, 0.3, 100.0, n_z=16)


def test_ensemble_members_that_are_no_friction_law_are_dropped():
    from granflow.continuum.closures import _physical_friction

    ok = dict(delta1=20.0, delta2=33.0, A=3.0, beta=0.2, gamma=-0.1)
    assert _physical_friction(ok)
    for bad in (dict(delta1=0.0), dict(delta2=19.0), dict(A=-1.0), dict(beta=0.0),
                dict(gamma=float("nan"))):
        assert not _physical_friction({**ok, **bad}), bad


def test_transient_diffusivity_recovers_each_species_and_the_window(tmp_path):
    """Synthetic tracers with known answers: small particles random-walk with D = 0.01 and large
    ones with 0.03 inside [50, 150], all at D = 0.5 outside it; the window [50, 150] gives each
    species' D within 10 % and the population its particle-weighted mean."""
    from granflow.continuum.experiments import transient_diffusivity

    rng = np.random.default_rng(3)
    dt, n_s, n_l = 0.5, 600, 300
    t = np.arange(0.0, 200.0 + 1e-9, dt)
    D = np.where((t[1:] > 50.0) & (t[1:] <= 150.0), 1.0, 0.0)
    d = np.r_[np.ones(n_s), np.full(n_l, 1.6)]
    Dp = np.r_[np.full(n_s, 0.01), np.full(n_l, 0.03)]
    steps = rng.standard_normal((t.size - 1, d.size)) * np.sqrt(
        2.0 * dt * (D[:, None] * Dp[None, :] + (1.0 - D[:, None]) * 0.5))
    z = np.vstack([np.zeros(d.size), np.cumsum(steps, axis=0)])
    np.savez(tmp_path / "tracers.npz", time=t, z=z, diameter=d)
    r = transient_diffusivity(tmp_path, 50.0, 150.0)
    assert (r["n_small"], r["n_particles"]) == (n_s, n_s + n_l)
    assert r["D_small"] == pytest.approx(0.01, rel=0.1)
    assert r["D_large"] == pytest.approx(0.03, rel=0.1)
    assert r["D"] == pytest.approx((n_s * 0.01 + n_l * 0.03) / (n_s + n_l), rel=0.1)
    assert 0 < r["D_stderr"] < 0.1 * r["D"]
    with pytest.raises(ValueError, match="too little"):
        transient_diffusivity(tmp_path, 195.0, 260.0)


def test_matching_peclet_recovers_the_peclet_number_of_a_model_run():
    """Round trip: the aligned half-time of T-eq. (27) at Ps = 12 (from s0 = a fifth of the way)
    gives back Ps = 12 from a start at Ps = 6."""
    from granflow.continuum.experiments import aligned_half_time, matching_peclet

    h, D, phi0 = 8.0, 0.01, 0.5
    res = segregation_layer(Ps=12.0, D=D, h=h, phi0=phi0, t_end=600.0, n=200, n_out=401)
    s0 = 0.2 * float(res.indicator_steady)
    th, _ = aligned_half_time(res.t.values, res.indicator.values,
                              float(res.indicator_steady), s0)
    assert matching_peclet(th, s0, D=D, h=h, phi0=phi0, Ps_from=6.0, t_end=600.0) == \
        pytest.approx(12.0, rel=0.01)


def test_switch_measurement_recovers_the_velocity_and_dilation_time_scales(tmp_path):
    """Synthetic parent and child runs with known answers: after the switch u_mean relaxes from
    1.5 to 2.5 with tau = 30 and the slope-normal potential energy (the centre of mass) from
    1000 to 1040 with tau = 45, both with collision-scale noise; the measurement recovers both
    e-folding times within 5 % and the dilation (+4 %)."""
    import json

    import xarray as xr

    from granflow.continuum.experiments import switch_measurement

    rng = np.random.default_rng(5)
    dt = 0.01
    t = np.arange(dt, 300.0 + 1e-9, dt)
    u = 2.5 - 1.0 * np.exp(-t / 30.0) + 0.02 * rng.standard_normal(t.size)
    eg = 1040.0 - 40.0 * np.exp(-t / 45.0) + 0.5 * rng.standard_normal(t.size)
    dirs = {}
    for name, theta, useries, egseries in (("parent", 26.0, np.full(t.size, 1.5), None),
                                           ("child", 27.5, u, eg)):
        d = tmp_path / name
        d.mkdir()
        data = {"u_mean": ("t", useries)}
        if egseries is not None:
            data["e_grav"] = ("t", egseries)
        xr.Dataset(data, coords={"t": t}).to_netcdf(d / "series.nc")
        (d / "summary.json").write_text(json.dumps({
            "params": {"H": 10.0, "theta": theta}, "flow_state": "steady",
            "steady_start": 200.0, "t_final": 300.0,
            "depth_averages": {"flow_height": 10.0, "u_bar": 1.5, "u_bar_sem": 0.01}}))
        dirs[name] = d
    m = switch_measurement(dirs["parent"], dirs["child"])
    assert m["tau"] == pytest.approx(30.0, rel=0.05)
    assert m["tau_dilation"] == pytest.approx(45.0, rel=0.05)
    assert m["dilation_rel"] == pytest.approx(0.04, rel=0.05)
    # a centre of mass that does not move, and a u_bar that moves by less than its noise: no
    # e-folding time is reported for either, and each says why
    flat = xr.Dataset({"u_mean": ("t", 1.5 + 0.01 * (1 - np.exp(-t / 30.0))
                                  + 0.1 * rng.standard_normal(t.size)),
                       "e_grav": ("t", 1000.0 + 0.5 * rng.standard_normal(t.size))},
                      coords={"t": t})
    (dirs["child"] / "series.nc").unlink()
    flat.to_netcdf(dirs["child"] / "series.nc")
    m = switch_measurement(dirs["parent"], dirs["child"])
    assert math.isnan(m["tau_dilation"]) and m["dilation_fit"].startswith(("unidentified",
                                                                           "failed"))
    assert math.isnan(m["tau"]) and m["fit_error"].startswith(("unidentified", "too few"))


def test_segregation_against_model_recovers_a_model_run_and_scales_its_half_time_with_D():
    """Round trip: a 'particle run' that is T-eq. (27) itself (Ps 6.8, D 0.02, h 22, measured
    from a fifth of the way, its steady profile as the fit's) gives a half-time error below 1 %
    and a profile error below 1e-3 with the same Ps and D, and -50 % (exactly 1/D) with twice D;
    the asymmetric flux at kappa = 0 is the symmetric one."""
    from granflow.continuum.experiments import aligned_half_time, segregation_against_model
    from granflow.continuum.segregation import segregation_layer

    Ps, D, h = 6.8, 0.02, 22.0
    res = segregation_layer(Ps=Ps, D=D, h=h, phi0=0.5, t_end=4000.0, n=200, n_out=4001)
    t, s = res.t.values, res.indicator.values
    s_inf = float(res.indicator_steady)
    s0 = 0.2 * s_inf
    th, t_shift = aligned_half_time(t, s, s_inf, s0)
    after = t >= t_shift
    m = {"run": "model", "sigma": 0.5, "phi0": 0.5, "h": h, "u_bar": 10.0, "t0": 0.0,
         "s0": s0, "plateau": s_inf, "t_half": th, "segregation_steady": True,
         "t": (t[after] - t_shift).tolist(), "s": (s[after] - s0).tolist()}
    zeta = res.zeta.values
    fit = {"fit": {"extra": {"asymmetric_Ps": Ps, "asymmetric_kappa": 0.0}},
           "profile": {"zeta": zeta.tolist(), "phi": res.phi.values[-1].tolist()}}
    out = segregation_against_model(m, fit, Ps=Ps, Ps_status="ok", D=D, D_std=0.1 * D)
    for flux in ("symmetric", "asymmetric"):
        assert abs(out[flux]["err_t_half"]) < 0.01, out[flux]["err_t_half"]
        assert out[flux]["phi_rms_vs_particles"] < 1e-3
        assert out[flux]["pass_t_half"]
        assert out[flux]["t_half_std"] == pytest.approx(0.1 * out[flux]["t_half"], rel=1e-12)
    fast = segregation_against_model(m, fit, Ps=Ps, Ps_status="ok", D=2 * D, D_std=0.0)
    assert fast["symmetric"]["err_t_half"] == pytest.approx(-0.5, abs=0.01)
    assert not fast["symmetric"]["pass_t_half"]


def test_steady_diffusivity_measures_the_steady_window_and_scales_it_to_c_D(tmp_path):
    """Synthetic tracers: D = 0.5 before the run's steady window (t < 100) and 0.02 in it; the
    steady window's D within 10 % and c_D = D h / u_bar exactly from it (h 20, u_bar 8)."""
    import json

    from granflow.continuum.experiments import steady_diffusivity

    rng = np.random.default_rng(11)
    dt, n = 0.5, 800
    t = np.arange(0.0, 300.0 + 1e-9, dt)
    Dt = np.where(t[1:] > 100.0, 0.02, 0.5)
    steps = rng.standard_normal((t.size - 1, n)) * np.sqrt(2.0 * dt * Dt)[:, None]
    z = np.vstack([np.zeros(n), np.cumsum(steps, axis=0)])
    np.savez(tmp_path / "tracers.npz", time=t, z=z, diameter=np.ones(n))
    (tmp_path / "summary.json").write_text(json.dumps(
        {"profile_time_from": 100.0, "depth_averages": {"flow_height": 20.0, "u_bar": 8.0}}))
    r = steady_diffusivity(tmp_path)
    assert (r["t_from"], r["t_to"]) == (100.0, 300.0)
    assert r["D"] == pytest.approx(0.02, rel=0.1)
    assert r["c_D"] == pytest.approx(r["D"] * 20.0 / 8.0, rel=1e-12)
    assert r["c_D_stderr"] == pytest.approx(r["D_stderr"] * 2.5, rel=1e-12)


def test_segregation_run_cli_writes_tracers_and_the_campaign_row(tmp_path):
    """``python -m granflow.continuum.experiments segregation-run`` (the README's command for the
    segregation reference, here on a 6 x 4 box to t = 2): the run's params.yaml simulated in its
    folder with tracer heights every 0.5 of every flow particle, and the campaign's row step
    written beside it (row.json names the run's size ratio and kind)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    import yaml

    rel = "segregation/linear/lambda~1/theta~25/H~5/sigma~0.5"
    run = tmp_path / rel
    run.mkdir(parents=True)
    params = dict(theta=25.0, H=5.0, lam=1.0, Lx=6.0, Ly=4.0, sigma=0.5, phi0=0.5, t_c=0.02,
                  t_end=2.0, base_layers=4.0, early_stop=False, seed=3)
    (run / "params.yaml").write_text(yaml.safe_dump(params))
    bin_ = Path(sys.executable).parent
    subprocess.run([str(bin_ / "granflow"), "prepare-base", "--lam", "1", "--Lx", "6", "--Ly",
                    "4", "--base-layers", "4", "--settle-time", "5", "--out",
                    str(tmp_path / "base.npy")], check=True, capture_output=True, timeout=600)
    proc = subprocess.run([sys.executable, "-m", "granflow.continuum.experiments",
                           "segregation-run", str(run), "--base", str(tmp_path / "base.npy"),
                           "--rel", rel, "--tracer-interval", "0.5"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((run / "summary.json").read_text())
    with np.load(run / "tracers.npz") as f:
        t, z, d = f["time"], f["z"], f["diameter"]
    assert np.allclose(np.diff(t), 0.5) and t[-1] == pytest.approx(2.0, abs=0.01)
    assert z.shape == (t.size, summary["n_flow"]) == (t.size, d.size)
    assert sorted(set(np.round(d, 9))) == [1.0, 2.0]  # small d = 1, large 1 / sigma
    row = json.loads((run / "row.json").read_text())["row"]
    assert (row["kind"], row["sigma"], row["run"]) == ("segregation", 0.5, rel)


def test_relaxation_plateau_of_a_run_cut_short_recovers_the_plateau_and_half_time():
    """s(t) = s_inf (1 - exp(-t / tau)) with noise, tau = 300, cut at t = 600 (86 % of the way):
    the relaxation fit gives the plateau within 3 % and the half-time crossing within 5 % of
    tau ln 2; a series with no relaxation in it is refused with the reason."""
    from granflow.continuum.experiments import relaxation_plateau

    rng = np.random.default_rng(2)
    tau, s_inf, s0 = 300.0, -2.4, -0.3
    t = np.arange(0.0, 600.0 + 1e-9, 2.0)
    ds = s_inf * -np.expm1(-t / tau) + 0.01 * rng.standard_normal(t.size)
    m = {"run": "synthetic", "t0": 50.0, "s0": s0, "plateau": s0 + ds[-20:].mean(),
         "t_half": math.nan, "t": t.tolist(), "s": ds.tolist()}
    r = relaxation_plateau(m)
    assert r["plateau"] - s0 == pytest.approx(s_inf, rel=0.03)
    assert r["t_half"] == pytest.approx(tau * math.log(2.0), rel=0.05)
    assert r["relaxation_tau"] == pytest.approx(tau, rel=0.1)
    assert r["fraction_reached"] == pytest.approx(-math.expm1(-2.0), abs=0.03)
    assert "t = 650" in r["plateau_source"]
    flat = dict(m, s=(0.01 * rng.standard_normal(t.size)).tolist())
    with pytest.raises(ValueError, match="not identified"):
        relaxation_plateau(flat)


def test_segregation_commands_name_missing_inputs_before_any_compute(tmp_path):
    """segregation-run without params.yaml or base, compare-segregation on a folder that is not
    a finished segregation-run, compare-long-chute without its run or library: exit 2
    (argparse) naming each missing file, no output written."""
    import subprocess
    import sys

    for args, names in (
            (["segregation-run", str(tmp_path), "--base", str(tmp_path / "b.npy"), "--rel", "x"],
             ["params.yaml", "b.npy"]),
            (["compare-segregation", str(tmp_path), "--out", str(tmp_path / "o.json")],
             ["summary.json", "series.nc", "row.json", "tracers.npz"]),
            (["compare-long-chute", str(tmp_path), "--closures", str(tmp_path / "lib.nc"),
              "--out", str(tmp_path / "o.json")], ["columns.nc", "lib.nc"])):
        proc = subprocess.run([sys.executable, "-m", "granflow.continuum.experiments", *args],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2
        assert all(n in proc.stderr for n in names), proc.stderr
    assert list(tmp_path.iterdir()) == []
