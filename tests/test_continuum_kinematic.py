"""Local-equilibrium (kinematic/diffusive-wave) layer against exact and linear solutions.

The equilibrium inversion against Eq. (47)'s closed form, exact mass conservation and uniform
flow, the kinematic shock's Rankine-Hugoniot speed, and a small mode of the diffusive wave
travelling at c = dq/dh and decaying at D k^2 (linear theory of the flux q(h, dh/dx) in closed
form), all with the paper's lambda = 1 friction parameters (Table 1).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from granflow.continuum import FlowClosures, equilibrium_froude, local_equilibrium_layer
from granflow.fitting.flow_rule import mu_eq50

P1 = dict(delta1=17.708, delta2=32.780, A=3.355, beta=0.196, gamma=0.040)
MU1, MU2 = (math.tan(math.radians(P1[k])) for k in ("delta1", "delta2"))


def eq50(theta, K=1.0):
    return FlowClosures(theta=theta, mu=lambda h, F: mu_eq50(h, F, **P1), K=K)


def froude_closed_form(h, mu):
    """Eq. (50) solved for F: F = beta h (mu - mu1) / (A (mu2 - mu)) - gamma (Eq. 47 with
    hstop(mu) of Eq. 45)."""
    return P1["beta"] * h * (mu - MU1) / (P1["A"] * (MU2 - mu)) - P1["gamma"]


def flux_closed_form(theta, K, h, grad):
    gc = math.cos(math.radians(theta))
    mu = math.tan(math.radians(theta)) - K * grad
    return h * froude_closed_form(h, mu) * np.sqrt(gc * h)


def test_equilibrium_froude_inverts_eq50():
    c = eq50(26.0)
    h = np.array([4.0, 6.0, 10.0, 20.0, 6.0, 6.0])
    mu = np.array([0.45, 0.50, 0.48, 0.40, 0.33, 0.30])
    F, arrested, accel = equilibrium_froude(c, h, mu)
    exact = froude_closed_form(h, mu)
    # mu(h, 0) > target: arrested (F = 0) exactly where the closed form is negative
    assert np.array_equal(arrested, exact <= 0) and not accel.any()
    ok = ~arrested
    assert np.allclose(F[ok], exact[ok], rtol=1e-12, atol=0)
    assert np.all(F[arrested] == 0.0)


@pytest.mark.parametrize("diffusive", [True, False])
def test_mass_conserved_to_round_off_and_uniform_flow_stays_uniform(diffusive):
    c = eq50(26.0)
    # the diffusive wave's D (~130 d^2 per time unit here) limits its time step to dx^2 / D
    x = 2.0 * np.arange(100) + 1.0
    h0 = 7.0 + 2.0 * np.exp(-((x - 60.0) / 12.0) ** 2)
    res = local_equilibrium_layer(c, x, h0, 2.0 if diffusive else 10.0, diffusive=diffusive,
                                  n_out=6)
    m = res.mass.values
    assert np.max(np.abs(m - m[0])) <= 1e-12 * m[0]
    uni = local_equilibrium_layer(c, x, np.full(x.shape, 8.0), 2.0, diffusive=diffusive, n_out=3)
    assert np.all(uni.h.values == 8.0)
    u_exact = froude_closed_form(8.0, math.tan(math.radians(26.0))) * math.sqrt(
        8.0 * math.cos(math.radians(26.0)))
    assert np.allclose(uni.u_bar.values, u_exact, rtol=1e-12)


def test_kinematic_shock_moves_at_the_rankine_hugoniot_speed():
    theta, hl, hr = 26.0, 8.0, 5.0
    c = eq50(theta)
    dx = 0.25
    x = np.arange(0.0, 300.0, dx) + 0.5 * dx
    h0 = np.where(x < 150.0, hl, hr)
    t_end = 20.0
    res = local_equilibrium_layer(c, x, h0, t_end, diffusive=False, n_out=2)
    s = (flux_closed_form(theta, 1.0, hl, 0.0) - flux_closed_form(theta, 1.0, hr, 0.0)) / (hl - hr)
    h = res.h.values[-1]
    level = 0.5 * (hl + hr)
    # the shock: the downward crossing of the mid level past the initial step
    j = np.nonzero((h[:-1] >= level) & (h[1:] < level) & (x[:-1] > 140.0))[0][0]
    x_shock = x[j] + dx * (h[j] - level) / (h[j] - h[j + 1])
    assert s * t_end > 40.0  # it travels 160 cells
    assert abs(x_shock - (150.0 + s * t_end)) <= 2 * dx, (x_shock, 150.0 + s * t_end)
    # and the profile behind it is the upstream state
    assert np.allclose(h[(x > x_shock - 20) & (x < x_shock - 4)], hl, rtol=1e-6)


@pytest.mark.parametrize("theta, h_mean", [(26.0, 8.0), (24.0, 12.0)])
def test_small_diffusive_mode_travels_at_dq_dh_and_decays_at_D_k2(theta, h_mean):
    """Linear theory of dh/dt + dq(h, h_x)/dx = 0: a mode eps sin(k x) moves at c = dq/dh and
    decays at D k^2, D = -dq/dh_x (both from the closed-form flux)."""
    K = 1.02
    c = eq50(theta, K=K)
    L = 400.0
    x = np.arange(0.0, L, 2.0) + 1.0
    k = 2 * math.pi / L
    eps = 1e-3
    h0 = h_mean + eps * np.sin(k * x)
    t_end = 4.0
    res = local_equilibrium_layer(c, x, h0, t_end, n_out=2)
    e = 1e-6
    q_h = (flux_closed_form(theta, K, h_mean + e, 0.0)
           - flux_closed_form(theta, K, h_mean - e, 0.0)) / (2 * e)
    D = -(flux_closed_form(theta, K, h_mean, e) - flux_closed_form(theta, K, h_mean, -e)) / (2 * e)
    assert D > 0
    dh = res.h.values[-1] - h_mean
    # amplitude and phase of the mode (least squares on sin, cos)
    a = 2 * np.mean(dh * np.sin(k * x))
    b = 2 * np.mean(dh * np.cos(k * x))
    amp = math.hypot(a, b) / eps
    shift = -math.atan2(b, a) / k  # dh = amp sin(k (x - shift))
    assert amp == pytest.approx(math.exp(-D * k * k * t_end), rel=0.01)
    assert shift == pytest.approx(q_h * t_end, rel=0.01)


def test_local_equilibrium_layer_rejects_bad_input():
    c = eq50(26.0)
    x = np.arange(10) + 0.5
    with pytest.raises(ValueError, match="h0"):
        local_equilibrium_layer(c, x, np.zeros(10), 1.0)
    with pytest.raises(ValueError, match="t_end"):
        local_equilibrium_layer(c, x, np.full(10, 5.0), -1.0)
    with pytest.raises(ValueError, match="cfl"):
        local_equilibrium_layer(c, x, np.full(10, 5.0), 1.0, cfl=2.0)
    with pytest.raises(ValueError, match="theta"):
        local_equilibrium_layer(eq50(-5.0), x, np.full(10, 5.0), 1.0)
    with pytest.raises(ValueError, match="uniformly spaced"):
        local_equilibrium_layer(c, x ** 2, np.full(10, 5.0), 1.0)


def test_long_chute_comparison_refuses_bad_model_choices_before_reading_anything(tmp_path):
    from granflow.continuum import experiments as ex

    missing = tmp_path / "no_such_columns.nc"
    with pytest.raises(ValueError, match="model"):
        ex.compare_long_chute(None, missing, 0.58, 25.0, model="bore")
    with pytest.raises(ValueError, match="viscosity"):
        ex.compare_long_chute(None, missing, 0.58, 25.0, model="kinematic_wave",
                              viscosity="gray_edwards")
    with pytest.raises(ValueError, match="n_ensemble"):
        ex.compare_long_chute(None, missing, 0.58, 25.0, n_ensemble=10)
    with pytest.raises(ValueError, match="n_ensemble"):
        ex.compare_long_chute(None, missing, 0.58, 25.0, model="kinematic_wave", n_ensemble=-1)

def test_compare_long_chute_command_names_bad_values_before_reading(tmp_path, capsys):
    from granflow.continuum import experiments as ex

    (tmp_path / "columns.nc").write_bytes(b"")  # present, never read
    for bad, name in ((["--viscosity", "thick"], "--viscosity"),
                      (["--n-ensemble", "-3"], "--n-ensemble")):
        with pytest.raises(SystemExit) as exc:
            ex.main(["compare-long-chute", str(tmp_path), "--closures", "paper", *bad])
        assert exc.value.code == 2
        assert name in capsys.readouterr().err


def test_ensemble_band_error_is_zero_inside_and_the_nearer_edge_outside():
    from granflow.continuum.experiments import _band_err

    row = {"front_travel_particles": 50.0, "front_travel_solver_lo": 40.0,
           "front_travel_solver_hi": 55.0}
    assert _band_err(row, "front") == 0.0
    assert _band_err(dict(row, front_travel_particles=80.0), "front") == pytest.approx(
        1 - 55.0 / 80.0)
    assert _band_err(dict(row, front_travel_particles=20.0), "front") == pytest.approx(1.0)
    assert math.isnan(_band_err(dict(row, front_travel_particles=0.0), "front"))


def test_paper_closures_are_table1_table2_and_eq53():
    c = FlowClosures.paper(26.0)
    hs = float(P1["A"] * (MU2 - math.tan(math.radians(26.0)))
               / (math.tan(math.radians(26.0)) - MU1))  # Eq. (45)
    for h in (5.0, 10.0, 20.0):
        assert c.steady_froude(h) == pytest.approx(P1["beta"] * h / hs - P1["gamma"], rel=1e-10)
    assert c.K == pytest.approx(1 + (26.0 - 21.50) / 132.0, rel=1e-14)
    assert c.status == {"friction": "paper", "alpha": "paper", "stress_ratio": "paper"}
    # lambda = 1/2: Table 2's constant alpha
    assert float(FlowClosures.paper(24.0, 0.5).alpha(np.array([8.0]))[0]) == 1.142
    with pytest.raises(ValueError, match="lam"):
        FlowClosures.paper(26.0, 0.0)


def test_bump_amplitude_is_the_smoothed_height_above_the_layer():
    """A Gaussian bump of height 3 and width 10 cells on h = 6: the 5-cell running mean lowers
    its top by the factor sqrt(s^2 / (s^2 + (5^2 - 1)/12)) of a Gaussian convolved with a box."""
    from granflow.continuum.experiments import bump_amplitude

    x = np.arange(200.0)
    h = 6.0 + 3.0 * np.exp(-0.5 * ((x - 100.0) / 10.0) ** 2)
    assert bump_amplitude(h) == pytest.approx(3.0 * math.sqrt(100.0 / 102.0), rel=2e-3)
    assert abs(bump_amplitude(np.full(50, 6.0))) < 1e-14
