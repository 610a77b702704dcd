"""Steady segregated state (issue 8): the small-particle centre-of-mass rule on synthetic series
with known answers, its incremental monitor (exactly the batch verdict, checkpoint round trip),
and the tagged sigma = 1 control species."""

import math

import numpy as np
import pytest

from granflow.engine.chute import ChuteConfig
from granflow.steady.segregation import SegregationMonitor, segregation_steadiness
from granflow.steady.timeseries import ar1_noise


def _ar1(n, rng, phi=0.8, scale=0.02):
    return ar1_noise(n, rng, phi, scale)


def test_relaxation_to_plateau_is_steady_with_onset_near_the_true_one():
    """s(t) = -2 (1 - exp(-t/20)) + noise: the plateau is reached (to within the noise) at
    t ~ 20 ln(2/0.02) ~ 92; the detected onset must lie in [60, 140] and the verdict be steady."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 400.0, 1.0)
    s = -2.0 * (1.0 - np.exp(-t / 20.0)) + _ar1(t.size, rng)
    st = segregation_steadiness(t, s, averaging_time=100.0)
    assert st.steady
    assert 60.0 <= st.onset <= 140.0
    assert st.plateau == pytest.approx(-2.0, abs=0.02)
    assert st.total == pytest.approx(-2.0, abs=0.25)  # from the first 1 % of the run


def test_still_drifting_series_is_not_steady():
    """A centre of mass still sinking linearly (by 1 d over the run, noise 0.02) is not steady."""
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 300.0, 1.0)
    s = -t / 300.0 + _ar1(t.size, rng)
    st = segregation_steadiness(t, s, averaging_time=100.0)
    assert not st.steady
    assert st.drift < -0.2  # per averaging_time: -1/300 x 100


def test_short_early_plateau_is_not_kept_once_the_series_drifts_on():
    """The sweep's 1/sigma = 2 run: a start-up jump, then a slow sink of the small particles
    (-0.8 -> -2.3 over 300).  Judged at t = 40 with the start-up excluded, the 40-unit tail is
    not shown flat; judged at the end (tail after the onset), it is; never steady from t ~ 0."""
    rng = np.random.default_rng(8)
    t = np.arange(0.0, 300.0, 1.0)
    s = -0.8 - 1.5 * (1.0 - np.exp(-t / 70.0)) + _ar1(t.size, rng, scale=0.03)
    s[0] = -1.55  # the insertion geometry before landing
    early = segregation_steadiness(t[:41], s[:41], averaging_time=40.0, min_onset=5.0)
    assert not early.steady
    late = segregation_steadiness(t, s, averaging_time=40.0, min_onset=5.0)
    assert late.steady and late.onset > 100.0


def test_stationary_series_is_steady_from_the_start_and_needs_averaging_time():
    """A flat series (no segregation, as the sigma = 1 control) is steady from the start once
    its whole-series drift is shown within the absolute tolerance (no relaxation to identify);
    with AR(1) noise of 0.02 that takes more than 150 samples, fewer than 300."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 300.0, 1.0)
    s = -1.0 + _ar1(t.size, rng)
    st = segregation_steadiness(t, s, averaging_time=100.0)
    assert st.steady and st.onset <= 100.0
    assert abs(st.remaining) < 0.03 and st.remaining_bound <= 0.03
    short = segregation_steadiness(t[:60], s[:60], averaging_time=100.0)
    assert not short.steady  # less than averaging_time of plateau


def test_monitor_matches_batch_rule_and_round_trips_through_a_checkpoint():
    rng = np.random.default_rng(6)
    t_fine = np.arange(0.0, 300.0, 0.25)
    s_fine = -1.5 * (1.0 - np.exp(-t_fine / 15.0)) + rng.normal(0, 0.01, t_fine.size)
    mon = SegregationMonitor(averaging_time=100.0, check_every=10.0, sample_interval=1.0)
    half = t_fine.size // 2
    for tt, ss in zip(t_fine[:half], s_fine[:half]):
        mon.update(tt, ss)
    state = {k: np.asarray(v) for k, v in mon.state_dict().items()}  # as np.savez would keep it
    mon2 = SegregationMonitor.from_state_dict(state)
    for m in (mon, mon2):
        for tt, ss in zip(t_fine[half:], s_fine[half:]):
            m.update(tt, ss)
        m.flush()
    assert mon.time == mon2.time and mon.value == mon2.value
    assert mon.state == mon2.state
    # the binned series equals block means of 4 samples, and the verdict the batch rule's
    blocks = s_fine.reshape(-1, 4).mean(axis=1)
    np.testing.assert_allclose(mon.value, blocks, rtol=0, atol=1e-12)
    batch = segregation_steadiness(mon.time, mon.value, averaging_time=100.0)
    assert mon.check() == batch and batch.steady
    # the remaining relaxation 1.5 exp(-t0/15) at the onset is within the tolerance 0.2
    assert batch.onset >= 30.0


def test_sigma_one_control_has_two_identical_tagged_species():
    cfg = ChuteConfig(theta=25.0, H=10.0, Lx=10.0, Ly=5.0, sigma=1.0, phi0=0.5)
    assert cfg.bidisperse
    d, species = cfg.flow_particles()
    assert np.all(d == 1.0)
    assert (species == 0).sum() == (species == 1).sum() == 250
    assert cfg.interactions().type_names == ["small", "large", "base"]
    assert not ChuteConfig(sigma=1.0, phi0=1.0).bidisperse


def test_bidisperse_run_records_the_indicator_and_the_segregation_verdict(tmp_path):
    """A small bidisperse chute: series.nc carries the indicator (units d) binned per time unit;
    the indicator of the final state, recomputed here from the saved particles, lies within the
    spread of the last bins; summary.json and the profile attributes carry the verdict, and a
    steady segregated state moves the profile window to its onset or later."""
    import json

    import xarray as xr

    from granflow.engine.system import ParticleSystem
    from granflow.simulate import simulate

    out = tmp_path / "run"
    res = simulate(dict(theta=26.0, H=3.0, lam=1.0, Lx=4.0, Ly=4.0, sigma=0.5, phi0=0.5,
                        t_c=0.02, t_end=8.0, base_layers=4.0, averaging_time=2.0, check_every=1.0,
                        cg_window=2.0), out)
    summ = json.loads((out / "summary.json").read_text())
    seg = summ["segregation"]
    assert set(seg) >= {"steady", "onset", "plateau", "drift", "p_value", "message"}
    with xr.open_dataset(out / "series.nc") as ds:
        s = ds["segregation_indicator"].values
        ts = ds["segregation_time"].values
        assert ds["segregation_indicator"].attrs["units"] == "1"  # a length, in d
        assert ds["segregation_indicator"].attrs["nondimensional_unit"] == "particle_diameter"
        state = ds.attrs["segregation_state"]
    assert state == ("steady" if seg["steady"] else "drifting")
    assert np.all(np.diff(ts) > 0.5) and ts[-1] <= res["t_final"] + 1e-9
    final, _ = ParticleSystem.load(out / "final_state.npz")
    flow = ~final.fixed
    small = flow & (final.ptype == 0)
    large = flow & (final.ptype == 1)
    assert small.sum() == round(0.5 * 3 * 16) and large.sum() == round(0.5 * 3 * 16 / 8)
    z = final.pos[:, 2]
    s_end = z[small].mean() - (final.mass[flow] @ z[flow]) / final.mass[flow].sum()
    lo, hi = s[-3:].min(), s[-3:].max()
    assert lo - 0.2 <= s_end <= hi + 0.2
    if seg["steady"] and summ["flow_state"] in ("steady", "layered"):
        assert summ["profile_time_from"] >= seg["onset"] - 1e-9


class _Series:
    """Stand-in for the run's EnergySeries: the last sample the MonitorObserver reads."""

    def __init__(self):
        self.data = {"time": [0.0], "e_kin": [0.0], "e_ela": [1.0], "u_mean": [0.0]}


def _segregating_run(growth_to, seg_tau, t_end=800.0, dt=0.5, seed=3, gate=True):
    """Feed a MonitorObserver + SegregationObserver pair with a mixture whose kinetic energy
    settles from a start-up transient, then rises by ``growth_to`` over t = 120 ... 320 (then
    flat) while its indicator relaxes
    towards -5 with time constant ``seg_tau``.  ``gate=False``: the earlier rule
    (only the steady stop deferred).  Returns (stop time, reason)."""
    from granflow.observers import MonitorObserver, SegregationObserver
    from granflow.steady.monitor import SteadyStateMonitor

    rng = np.random.default_rng(seed)
    series = _Series()
    energy = MonitorObserver(SteadyStateMonitor(t_cap=t_end, averaging_time=60.0, check_every=10.0,
                                                min_accelerating_time=200.0), series)
    seg = SegregationObserver(SegregationMonitor(averaging_time=60.0, check_every=10.0),
                              energy=energy if gate else None)
    if not gate:  # the earlier rule: only the steady stop waits for the segregated state
        energy_stop = energy.should_stop

        def steady_deferred(system):
            stop, reason = energy_stop(system)
            return (False, "") if stop and reason.startswith("steady") else (stop, reason)
        energy.should_stop = steady_deferred
    for t in np.arange(0.0, t_end + dt, dt):
        ramp = np.clip((t - 120.0) / 200.0, 0.0, 1.0)
        e_kin = (100.0 * (1.0 + np.exp(-t / 25.0)) * (1.0 + (growth_to - 1.0) * ramp)
                 * (1.0 + 0.02 * rng.normal()))
        for k, v in (("time", t), ("e_kin", e_kin), ("e_ela", 1.0), ("u_mean", np.sqrt(e_kin))):
            series.data[k].append(v)
        energy.sample(None)
        seg.monitor.update(t, -5.0 * (1.0 - np.exp(-t / seg_tau))
                           + 0.01 * rng.normal())
        stop, reason = energy.should_stop(None)
        if not stop:
            stop, reason = seg.should_stop(type("S", (), {"time": t})())
        if stop:
            return t, reason
    return t_end, "t_end"


def test_mixture_speeding_up_while_it_segregates_is_not_stopped_as_accelerating():
    """E_kin x2.5 while the large particles rise (x1.55 by t = 240 at the paper's species, sigma
    0.75): the run goes on until the segregated state is steady and stops as steady."""
    t_alone, reason_alone = _segregating_run(growth_to=2.5, seg_tau=120.0, gate=False)
    assert reason_alone.startswith("accelerating") and t_alone < 400.0, reason_alone
    t, reason = _segregating_run(growth_to=2.5, seg_tau=120.0)
    # the change still to come, 5 exp(-t/120), falls below 3 % of the total + 0.03
    # (SEGREGATION_REL_TOL, _ABS_TOL) at t = 120 ln(5 / 0.18) = 399; its bound a little later
    assert reason.startswith("steady"), reason
    assert 399.0 < t < 700.0


def test_mixture_still_segregating_at_the_cap_is_never_called_steady():
    """The defect of the 10 % drift rule: with tau = 800 the drift per averaging window fell below
    10 % of the total + 0.05 at t = 800 ln(0.875 / 0.55) = 371 and the run stopped as steady with
    63 % of its segregation to come at t = 800.  The change still to come is now projected, so
    the run reaches its cap with the segregated state drifting."""
    t, reason = _segregating_run(growth_to=2.5, seg_tau=800.0)
    assert reason == "t_end" and t == 800.0


def test_slow_percolation_is_not_steady_until_its_projected_change_is_small():
    """A depth-16 layer at the paper's species (sigma = 0.6): s relaxes from -1.3 to -3.3 with
    tau = 200 (noise AR(1) 0.03).  At t = 361 the drift per 60 is ~0.1 (the earlier rule's
    band 0.1 x 1.9 + 0.05 = 0.24 held it) but 0.33 is still to come: not steady.  At t = 1400,
    3 % of the segregation is ~0.002 away: steady, with the projection near the truth."""
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 1400.0, 1.0)
    true = -3.3 + 2.0 * np.exp(-t / 200.0)
    s = true + _ar1(t.size, rng, scale=0.03)
    early = segregation_steadiness(t[:362], s[:362], averaging_time=60.0, min_onset=20.0)
    assert abs(early.drift) <= 0.1 * abs(early.total) + 0.05  # the old band held the drift
    assert not early.steady
    assert early.remaining == pytest.approx(-2.0 * np.exp(-361 / 200.0), rel=0.5)
    late = segregation_steadiness(t, s, averaging_time=60.0, min_onset=20.0)
    assert late.steady, late.message
    assert late.relaxation_time == pytest.approx(200.0, rel=0.25)


@pytest.mark.parametrize("beta,steady_by", [(1.0, 1100.0), (0.7, 2000.0), (0.5, 4150.0)])
def test_an_approach_slower_than_exponential_is_not_called_steady_early(beta, steady_by):
    """Known answer: s relaxes from 0 to -4 as exp(-(t / 300)^beta) (AR(1) noise 0.03,
    samples every 2, checked every 50).  At the first steady verdict the change truly still
    to come is within the tolerance (3 % of the total + 0.03 = 3.75 % of it), whatever the
    stretch; an exponential projection alone called beta = 0.7 and 0.5 steady with 6.6 % and
    9.9 % to come (at t = 1250 and 1600).  Now: 2.6 %, 2.5 % and 2.5 % at t = 1100, 1950 and
    4100 for beta = 1, 0.7 and 0.5, with the fitted stretch within 0.05 of the true one.  (The
    stretched fit from the first sample after the start-up, t = 20, instead of the run's start
    biased beta to 0.60 for 0.5 and the change to come 25 % low: steady at t = 3350 with 3.5 %.)"""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 4400.0, 2.0)
    true = -4.0 * (1.0 - np.exp(-(t / 300.0) ** beta))
    s = true + _ar1(t.size, rng, phi=math.exp(-0.2), scale=0.03)
    for end in np.arange(300.0, 4400.0, 50.0):
        k = t <= end
        st = segregation_steadiness(t[k], s[k], averaging_time=200.0, min_onset=20.0)
        if st.steady:
            break
    assert st.steady, st.message
    to_come = abs(true[k][-1] + 4.0)
    assert to_come <= 0.03 * 4.0 + 0.03, (end, to_come)
    assert end <= steady_by
    assert st.relaxation_stretch == pytest.approx(beta, abs=0.05)
    print(f"beta {beta}: steady at t = {end:g} with {100 * to_come / 4:.1f} % to come, "
          f"fitted beta {st.relaxation_stretch:.2f}")


def test_runaway_mixture_still_stops_as_accelerating():
    """Growth x10 (velocity x3.2) is decisive whatever segregation does."""
    t, reason = _segregating_run(growth_to=40.0, seg_tau=600.0)
    assert reason.startswith("accelerating"), reason
    assert t < 500.0


def test_a_continuation_of_a_slow_approach_is_judged_on_its_own_change_not_the_plateau():
    """A slow approach as at the paper's set-up (s from 0 to -4 as exp(-(t / 500)^0.8), AR(1)
    noise 0.04) continued from t = 1500 of its parent (7.6 % still to come; the clock restarts
    at 0, the parent's history unseen).  The tolerance scales with the change since the run's
    own start, so a continuation is judged conservatively: first shown steady 1950 units in,
    with 0.9 % truly to come (its mixed start: t = 2350, 3.2 %).  Scaled by the plateau (tried
    2026-12-07 to judge both sides of a bracket alike) the short series identifies no slow
    relaxation and its projection passed 300 units in, with 6.2 % still to come (3.75 %
    allowed); on the paper set-up's continuations it called series still rising steady."""
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 4000.0, 1.0)
    true = -4.0 * (1.0 - np.exp(-(t / 500.0) ** 0.8))
    s = true + _ar1(t.size, rng, phi=math.exp(-0.5), scale=0.04)
    cont = t >= 1500.0
    tc, sc, truec = t[cont] - 1500.0, s[cont], true[cont]
    first = None
    for end in np.arange(200.0, tc[-1], 50.0):
        k = tc <= end
        st = segregation_steadiness(tc[k], sc[k], averaging_time=200.0, min_onset=20.0)
        if end == 300.0:  # the plateau-scaled tolerance would have passed its projection here
            assert st.remaining_bound <= 0.03 * abs(st.plateau) + 0.03
            assert abs(truec[k][-1] + 4.0) > 0.06 * 4.0
            assert not st.steady
        if st.steady:
            first = end
            break
    assert first == 1950.0, first
    assert abs(truec[tc <= first][-1] + 4.0) <= 0.01 * 4.0


def test_a_drift_too_slow_to_show_a_relaxation_is_judged_over_the_whole_series():
    """s = -4 - 0.02 t / 200 (0.5 % of the segregation per averaging window; 0.3 over the run,
    twice the tolerance): no relaxation is identified (tau at its bound), and the fallback
    judges the linear change over the whole series, not per averaging window (0.02, which
    the rule before 2026-12-07 called steady)."""
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 3000.0, 2.0)
    s = -4.0 - 0.02 * t / 200.0 + _ar1(t.size, rng, phi=math.exp(-0.2), scale=0.03)
    st = segregation_steadiness(t, s, averaging_time=200.0, min_onset=20.0)
    assert "no relaxation identified" in st.message
    assert st.remaining == pytest.approx(-0.02 * (t[-1] - 20.0) / 200.0, rel=0.1)
    assert not st.steady
    assert abs(st.drift) + 0.0 <= 0.03 * 4.0 + 0.03  # per window it is inside the band


@pytest.mark.xfail(strict=True, reason="known limitation (2026-12-07): a slow mode under a fast "
                   "start-up transient; the one-relaxation projection fits the fast one")
def test_a_slow_mode_under_a_fast_start_up_transient_is_not_called_steady_early():
    """Known limitation, as seen at the paper's set-up: a run started above its steady state
    (1/sigma = 1.25, profile start) first rearranges fast, then relaxes slowly the other way
    (s -4.25 at t = 300, -4.07 by t = 1180); replayed with ``segregation_approach.py
    --verdicts`` it is shown steady at t = 300 on a tau = 21 relaxation fit (change to come
    1e-7 +- 0) and not again.  Synthetic: s = -4.25 - 0.3 exp(-t/20) + 0.2 (1 - exp(-t/500)),
    AR(1) noise 0.04: seed 4 is called steady at t = 450 with 0.081 still to come, against a
    tolerance of 0.035 (2 of 6 seeds are called steady early; the stretched fit, beta at its
    bound 0.3, keeps 2 others from it).  The single (stretched) relaxation cannot see a second,
    slower mode that the noise hides; a start from a mixed state has no fast mode of the
    opposite sign."""
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 1500.0, 1.0)
    true = -4.25 - 0.3 * np.exp(-t / 20.0) + 0.2 * (1.0 - np.exp(-t / 500.0))
    s = true + _ar1(t.size, rng, phi=math.exp(-0.5), scale=0.04)
    for end in np.arange(250.0, 1500.0, 50.0):
        k = t <= end
        st = segregation_steadiness(t[k], s[k], averaging_time=200.0, min_onset=34.0)
        if st.steady:
            to_come = abs(-4.05 - true[k][-1])  # s_inf = -4.25 + 0.2
            assert to_come <= 0.03 * abs(st.total) + 0.03, (end, to_come)
            break
