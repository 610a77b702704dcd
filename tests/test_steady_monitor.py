"""Tests of granflow.steady.monitor.SteadyStateMonitor on synthetic runs."""

import io
from pathlib import Path

import numpy as np
import pytest

from granflow.steady.monitor import SteadyStateMonitor


def ar1(n, phi, seed):
    rng = np.random.default_rng(seed)
    e = rng.normal(0.0, np.sqrt(1.0 - phi**2), n)
    x = np.empty(n)
    x[0] = rng.normal()
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


DT = 0.5  # sampling interval of the synthetic "simulation"
T = np.arange(0.0, 2000.0, DT)
N = T.size
E_ELA = 2.0


def noise(seed, amp=0.03):
    return 1.0 + amp * ar1(N, 0.8, seed)  # correlation time ~4.5 time units


def spin_up(seed, onset=300.0):
    return 0.1 * E_ELA * noise(seed) * np.clip(T / onset, 0.02, 1.0)


def accelerating(seed):
    return 0.1 * E_ELA * noise(seed) * (1.0 + (T / 300.0) ** 2)


def arresting(seed):
    return 0.1 * E_ELA * noise(seed) * np.exp(-T / 30.0)


def feed(mon, e_kin, start=0, stop=None, u_bar=None):
    decisions = []
    for i in range(start, N if stop is None else stop):
        mon.update(T[i], e_kin[i], E_ELA * (1.0 + 0.01 * np.sin(T[i])), None if u_bar is None else u_bar[i])
        d = mon.decision()
        decisions.append(d)
        if d.stop:
            break
    return decisions


@pytest.mark.parametrize("seed", range(4))
def test_steady_series_stops_after_averaging_time(seed):
    onset, avg, every = 300.0, 100.0, 10.0
    mon = SteadyStateMonitor(t_cap=2000, averaging_time=avg, check_every=every)
    d = feed(mon, spin_up(seed, onset))[-1]
    assert d.stop and d.reason == "steady" and d.state == "steady"
    assert mon.steady_start == d.steady_start
    assert d.steady_start == pytest.approx(onset, rel=0.1)
    # stops once averaging_time lies after the (detected) onset; the onset estimate and the
    # equivalence test may need a few more checks: allow 5 check intervals (2.5 % of the cap)
    assert d.t - d.steady_start >= avg
    assert onset + avg - 0.1 * onset <= d.t <= onset + avg + 5 * every
    assert "steady window" in d.explain()


@pytest.mark.parametrize("seed", range(3))
def test_accelerating_series_stops_early(seed):
    mon = SteadyStateMonitor(t_cap=2000, averaging_time=100, check_every=10)
    d = feed(mon, accelerating(seed))[-1]
    assert d.stop and d.reason == "accelerating"
    # not before min_accelerating_time (default t_cap/4 = 500), well before the cap
    assert 500.0 <= d.t <= 600.0
    assert d.steady_start is None


@pytest.mark.parametrize("seed", range(3))
def test_arrested_series_stops_below_threshold(seed):
    e_kin = arresting(seed)
    mon = SteadyStateMonitor(t_cap=2000, averaging_time=100, check_every=10)
    d = feed(mon, e_kin)[-1]
    assert d.stop and d.reason == "arrested" and d.state == "arrested"
    # E_kin/<E_ela> ~ 0.1 exp(-t/30) crosses 1e-5 at t = 30 ln(1e4) = 276.3; the monitor confirms
    # after ARREST_HOLD_TIME = 5 (plus the 1-unit sample bin)
    t_cross = 30.0 * np.log(1e4)
    assert t_cross <= d.t <= t_cross + 5.0 + 3.0


def test_mixed_campaign_total_time_well_below_cap():
    series = [spin_up(0), accelerating(1), arresting(2), spin_up(3, onset=150.0), arresting(4)]
    total = 0.0
    for e_kin in series:
        mon = SteadyStateMonitor(t_cap=2000, averaging_time=100, check_every=10)
        d = feed(mon, e_kin)[-1]
        assert d.stop and d.reason in ("steady", "accelerating", "arrested")
        total += d.t
    assert total < 0.25 * 2000 * len(series)


def test_cap_stops_undecided_run():
    e_kin = 0.1 * E_ELA * noise(5) * np.exp(-T / 300.0)  # decays 28 % per 100: not steady,
    # and reaches 1e-5 only at t = 300 ln(1e4) = 2763, after the cap
    mon = SteadyStateMonitor(t_cap=600, averaging_time=100, check_every=20)
    d = feed(mon, e_kin)[-1]
    assert d.stop and d.reason == "t_cap"
    assert d.t == pytest.approx(600.0, abs=1.0)


def test_state_dict_round_trip_gives_identical_decisions():
    e_kin = spin_up(6)
    u = 1.0 + 0.01 * ar1(N, 0.5, 7)
    ref = SteadyStateMonitor(check_every=10)
    ref_dec = feed(ref, e_kin, u_bar=u)
    assert ref_dec[-1].stop

    split = 401  # mid-bin (T = 200.5) and between checks
    a = SteadyStateMonitor(check_every=10)
    first = feed(a, e_kin, stop=split, u_bar=u)
    # through np.savez, as a checkpoint would store it
    buf = io.BytesIO()
    np.savez(buf, **a.state_dict())
    buf.seek(0)
    with np.load(buf) as data:
        b = SteadyStateMonitor.from_state_dict(dict(data))
    assert b.decision() == a.decision()
    second = feed(b, e_kin, start=split, u_bar=u)
    assert first + second == ref_dec
    assert b.steady_start == ref.steady_start
    # in-memory round trip too
    c = SteadyStateMonitor.from_state_dict(a.state_dict())
    np.testing.assert_array_equal(c.series()["ratio"], a.series()["ratio"])


def test_update_is_cheap_and_bins_samples():
    mon = SteadyStateMonitor(sample_interval=1.0, check_every=1e9)
    for i in range(4000):  # 40 time units at dt = 0.01
        mon.update(i * 0.01, 1.0, 2.0)
    assert mon.n_samples == 39  # the 40th bin is still open
    mon.flush()
    s = mon.series()
    assert mon.n_samples == 40
    np.testing.assert_allclose(s["ratio"], 0.5)
    np.testing.assert_allclose(np.diff(s["time"]), 1.0)
    with pytest.raises(ValueError):
        mon.update(1.0, 1.0, 2.0)


def test_cap_sample_closes_bin_immediately():
    mon = SteadyStateMonitor(t_cap=150, averaging_time=100, check_every=1000)
    for t in np.arange(0.0, 150.01, 0.5):
        mon.update(t, 0.2 * (1.0 + 0.1 * np.sin(t)), 2.0)
    d = mon.decision()
    assert d.stop and d.t == pytest.approx(150.0)


# E_kin means of 5-unit blocks of the default's theta = 24, H = 10 run at 845f018 (a 10 x 5 box,
# 500 grains; E_ela ~ 0.7): a steady flow that wandered 288 (t ~ 110) -> 93 (t ~ 200) -> 244
# (t ~ 300).  It was stopped at t = 361 as "accelerating (growth x1.6)": the last window was
# measured against the dip at half the elapsed time.
WANDERING_EKIN = [1084, 348, 141, 156, 140, 147, 142, 160, 156, 162, 143, 130, 157, 192, 215, 246,
                  238, 207, 214, 253, 243, 288, 307, 287, 276, 267, 217, 187, 170, 174, 185, 198,
                  173, 149, 150, 162, 135, 113, 106, 95, 93, 128, 125, 144, 139, 153, 131, 133,
                  160, 168, 184, 193, 186, 173, 183, 199, 199, 196, 206, 232, 244, 237, 231, 240,
                  237, 232, 231, 225, 197, 198, 212, 232]


def wandering(seed):
    t_mid = 2.5 + 5.0 * np.arange(len(WANDERING_EKIN))
    return np.interp(T, t_mid, WANDERING_EKIN) * noise(seed, amp=0.05)


@pytest.mark.parametrize("seed", range(4))
def test_return_from_a_dip_is_not_acceleration(seed):
    """Measured against the highest earlier level (after the start-up window), not the level at
    half the elapsed time, the wandering steady run is not stopped as accelerating (the
    default's monitor settings and start-up time, fed as far as the measured series goes)."""
    mon = SteadyStateMonitor(t_cap=400, averaging_time=40, check_every=10,
                             min_accelerating_time=200, min_onset=15.6)
    e_kin = wandering(seed)
    old_growth, states = [], []
    for i in range(int(361.0 / DT)):
        mon.update(T[i], e_kin[i], 0.7 * (1.0 + 0.01 * np.sin(T[i])))
        d = mon.decision()
        assert d.reason != "accelerating", d.explain()
        if T[i] >= 200.0 and T[i] % 10.0 == 0.0:
            s = mon.series()
            t, r = s["time"], s["ratio"]
            old_growth.append(np.median(r[t >= t[-1] - 40.0])
                              / np.median(r[np.abs(t - 0.5 * t[-1]) <= 20.0]))
            states.append(mon.classify().state)
    # what made the old rule stop: a significant rise (the classifier's verdict) and a growth
    # beyond ACCEL_MIN_GROWTH = 1.5 against the window at half the elapsed time
    assert "accelerating" in states
    assert max(old_growth) >= 1.45
    s = mon.series()
    assert mon._growth(s["ratio"], s["time"]) < 1.0


# A real run that overshoots and relaxes (lambda = 1/2, 28 deg, H = 10, the paper's 20 x 10
# box and species; README "Why gamma is off at lambda = 1/2"): its series binned to 1 time unit,
# 0-471 from the run, which the engine stopped as steady at t = 470.5 over [52.5, 470.5], and
# 471-971 from its continuation without early stopping (`granflow simulate --from`), where it
# settled at u_mean 6.797 over the last 100 units.
HUMP = Path(__file__).parent / "data" / "hump_lambda_half_20x10_theta28_H10.csv"


def _replay_hump():
    import pandas as pd

    d = pd.read_csv(HUMP)
    m = SteadyStateMonitor(t_cap=2000.0, averaging_time=100.0, check_every=10.0,
                           min_accelerating_time=1500.0)
    for r in d.itertuples():
        m.update(r.t, r.e_kin, r.e_ela, r.u_mean)
        if m.decision().stop:
            break
    return d, m.decision()


def test_replayed_hump_reproduces_the_engines_steady_stop():
    """The binned series through the monitor gives the engine's decision (steady at t = 470.5,
    window from 52.5) to within one check interval (10 time units; the verdict is marginal --
    N_eff at its minimum -- so binning moves it by one check): the data file is the run's."""
    _, dec = _replay_hump()
    assert dec.stop and dec.reason == "steady"
    assert dec.t == pytest.approx(470.5, abs=10.0)
    assert dec.steady_start == pytest.approx(52.5, abs=3.0)


@pytest.mark.xfail(strict=True, reason=(
    "known defect (README, early stopping): the monitor stops on a relaxing overshoot -- N_eff "
    "at its minimum 10, linear trend p 0.6, curvature p 0.1 -- with the window's mean u 6.8 % "
    "above the level the run settles to; the equivalence test bounds only the linear trend"))
def test_monitor_does_not_stop_on_a_relaxing_overshoot():
    d, dec = _replay_hump()
    settled = float(d[d["t"] >= d["t"].max() - 100.0]["u_mean"].mean())
    assert settled == pytest.approx(6.797, abs=1e-3)
    if dec.stop and dec.reason == "steady":
        w = d[(d["t"] >= dec.steady_start) & (d["t"] <= dec.t)]["u_mean"].mean()
        assert abs(w / settled - 1.0) < 0.03, (dec.t, dec.steady_start, w)
