"""Replicates (issue 19 §1): deterministic seed fan-out, the between-seed scatter against the
within-run standard errors, and each parameter's uncertainty split into the two."""

import math

import numpy as np
import pandas as pd
import pytest

from granflow.campaign import grid as G
from granflow.fitting import campaign_table_from_records, fit_stress_ratio, stress_ratio_eq53
from granflow.fitting.campaign import between_seed_scatter, run_uncertainty
from granflow.fitting.lsq import variance_split


def test_replicates_fan_out_seeds_and_paths():
    cfg = {"numerics": {"seed": 7, "replicates": 3},
           "campaigns": {"chute": {"enabled": True, "Lx": 10.0, "Ly": 5.0,
                                   "grids": [{"theta": [24.0], "H": [10.0]},
                                             {"theta": [26.0], "H": [4.0], "replicates": 1}]},
                         "segregation": {"enabled": True, "theta": 25.0, "H": 8.0,
                                         "sigma": [0.5], "numerics": {"replicates": 2}}}}
    runs = G.expand_runs(cfg)
    paths = sorted(r.path for r in runs)
    assert paths == ["chute/linear/lambda~1/theta~24/H~10",
                     "chute/linear/lambda~1/theta~24/H~10/seed~1",
                     "chute/linear/lambda~1/theta~24/H~10/seed~2",
                     "chute/linear/lambda~1/theta~26/H~4",
                     "segregation/linear/lambda~1/theta~25/H~8/sigma~0.5",
                     "segregation/linear/lambda~1/theta~25/H~8/sigma~0.5/seed~1"]
    for r in runs:
        assert G.parse_run_path(r.path) == r
        assert G.run_params(cfg, r)["seed"] == 7 + r.replicate
    # replicates share the base of their (lambda, box)
    assert len({G.base_path(cfg, r) for r in runs if r.kind == "chute"}) == 1


def test_between_seed_scatter_recovers_a_known_spread():
    """Replicate groups of 3 runs whose values scatter with std 0.03 about the group mean and
    whose own standard errors are 0.01: tau = sqrt(0.03^2 - 0.01^2) ... here the values are
    drawn with total std sqrt(tau^2 + sem^2), tau = 0.02, so the estimate must be 0.02 within
    15 % (200 groups)."""
    rng = np.random.default_rng(19)
    recs = []
    for g in range(200):
        for k in range(3):
            recs.append(dict(contact_law="linear", lam=1.0, theta=20.0 + g * 0.01, H=10.0,
                             sigma=1.0, K=1.0 + rng.normal(0, math.hypot(0.02, 0.01)),
                             K_sem=0.01))
    tau, n, within = between_seed_scatter(pd.DataFrame(recs), "K")
    assert n == 200 and within == pytest.approx(1e-4)
    assert tau == pytest.approx(0.02, rel=0.15)
    sigma, parts, note = run_uncertainty(pd.DataFrame(recs), "K")
    assert np.allclose(sigma ** 2, parts["within"] ** 2 + parts["between"] ** 2)
    assert "between-seed scatter" in note
    # without replicates: the within-run part alone, and it says so
    one = pd.DataFrame(recs[::3])
    assert math.isnan(between_seed_scatter(one, "K")[0])
    assert "no replicates" in run_uncertainty(one, "K")[2]


def test_variance_split_of_a_mean_is_the_variance_ratio():
    """A constant fitted to n runs with variances a (within) + b (between): the parameter's
    variance is (a + b)/n, a share a/(a + b) of it within runs -- exactly."""
    n = 12
    split = variance_split(lambda x, c: c + 0.0 * x, np.arange(n, dtype=float), {"c": 1.0},
                           {"within": np.full(n, 0.03), "between": np.full(n, 0.04)})
    assert split["c"]["within"] == pytest.approx(0.09 / 0.25, rel=1e-9)
    assert split["c"]["between"] == pytest.approx(0.16 / 0.25, rel=1e-9)


def test_fit_reports_the_split_per_parameter():
    rng = np.random.default_rng(53)
    theta = np.repeat(np.linspace(21.0, 29.0, 5), 3)
    K = stress_ratio_eq53(theta, 132.0, 21.5) + rng.normal(0, math.hypot(0.01, 0.005),
                                                            theta.size)
    within, between = np.full(theta.size, 0.005), np.full(theta.size, 0.01)
    fit = fit_stress_ratio(theta, K, sigma=np.hypot(within, between),
                           sigma_parts={"within": within, "between": between})
    split = fit.diagnostics["uncertainty_split"]
    for p in ("d0", "d1"):
        assert split[p]["within"] + split[p]["between"] == pytest.approx(1.0, abs=1e-9)
        assert split[p]["between"] == pytest.approx(0.8, abs=1e-6)  # 0.01^2 / (0.01^2+0.005^2)


def _profile_fit(Ps, sigma, run, sem, noise_seed):
    """A per-run T-eq. (28) fit of an exact profile at Ps (a little noise), as
    granflow.campaign.collect.segregation_fit tags it: run name, steady segregated state,
    the stderr of its windows' mean."""
    from granflow.fitting import assess, fit_Ps, phi_teq28

    z = np.linspace(0.0, 1.0, 41)
    phi = phi_teq28(z, Ps, 0.5) + np.random.default_rng(noise_seed).normal(0, 1e-3, z.size)
    f = fit_Ps(z, phi, 0.5, sigma=sigma, contact_law="linear")
    f = f.replace(stderr={"Ps": sem}, runs_used=(run,),
                  extra=dict(f.extra, segregation_state="steady", scaled_depth=7.0))
    return assess(f)


def test_runs_at_one_size_ratio_become_one_library_value_with_their_spread(tmp_path):
    """Replicates at one size ratio used to stop the library ("two segregation fits for the
    same coordinates").  Three runs at sigma = 0.6 with Ps 5.0, 5.6, 6.2 (spread 0.6) and own
    errors 0.05 give Ps 5.6 with stderr 0.6 / sqrt(3), not the runs' 0.05 / sqrt(3); three at
    0.75 that agree better than their errors (4.00, 4.01, 4.02, errors 0.2) keep the errors:
    0.2 / sqrt(3); an unidentified run is left out of the mean and named; a ratio with one run
    is that run's fit, unchanged."""
    import granflow.closures as gc
    from granflow.fitting import campaign_table_from_records, combine_Ps_runs
    from granflow.fitting.segregation import fit_Ps_law

    fits = [_profile_fit(p, 0.6, f"s06/seed~{k}", 0.05, k) for k, p in enumerate((5.0, 5.6, 6.2))]
    fits += [_profile_fit(p, 0.75, f"s075/seed~{k}", 0.2, 10 + k)
             for k, p in enumerate((4.0, 4.01, 4.02))]
    bad = _profile_fit(9.0, 0.75, "s075/seed~9", 0.2, 20)
    fits.append(bad.replace(ok=False, status="unidentified"))
    one = _profile_fit(2.0, 0.9, "s09", 0.1, 30)
    fits.append(one)
    out = combine_Ps_runs(fits)
    assert [f.coords["sigma"] for f in out] == [0.6, 0.75, 0.9]
    a, b, c = out
    assert a.params["Ps"] == pytest.approx(5.6, abs=2e-3)
    assert a.stderr["Ps"] == pytest.approx(0.6 / math.sqrt(3), rel=0.01)
    assert a.extra["Ps_between_run_sd"] == pytest.approx(0.6, rel=0.01)
    assert a.extra["Ps_within_run_sem"] == pytest.approx(0.05 / math.sqrt(3))
    half = float(__import__("scipy").stats.t.ppf(0.975, 2)) * a.stderr["Ps"]
    assert a.extra["ci95"] == pytest.approx((a.params["Ps"] - half, a.params["Ps"] + half))
    assert a.ok and a.param_status["Ps"] == "identified" and a.extra["runs_combined"] == 3
    assert b.params["Ps"] == pytest.approx(4.01, abs=2e-3) and b.extra["runs_combined"] == 3
    assert b.stderr["Ps"] == pytest.approx(0.2 / math.sqrt(3))
    assert "s075/seed~9" in b.message and "s075/seed~9" not in b.runs_used
    assert c.params == one.params and c.stderr == one.stderr
    assert "wander" in c.selection and "not measured" in c.selection
    table = campaign_table_from_records([
        dict(theta=25.0, H=8.0, lam=1.0, sigma=s, contact_law="linear", state="steady", Ps=p,
             run_id=f"r{i}") for i, (s, p) in enumerate(((0.6, 5.6), (0.75, 4.01), (0.9, 2.0)))])
    law = fit_Ps_law([0.6, 0.75, 0.9], [5.6, 4.01, 2.0], contact_law="linear")
    ds = gc.build_library_dataset(out + [law], table, name="rep", version=1)
    sel = dict(contact_law="linear")
    assert ds["segregation_Ps"].sel(sel).values.tolist() == [f.params["Ps"] for f in out]
    assert ds["segregation_Ps_stderr"].sel(sel).values[0] == pytest.approx(0.6 / math.sqrt(3),
                                                                           rel=0.01)
    assert ds["segregation_runs_combined"].sel(sel).values[:2].tolist() == [3, 3]
    assert math.isnan(float(ds["segregation_runs_combined"].sel(sel).values[2]))
    assert ds["segregation_Ps_between_run_sd"].attrs["units"] == "1"


def test_the_wander_at_the_runs_particle_number_accounts_for_the_seeds_scatter():
    """The record behind a run's Ps stderr (granflow.reference.SEGREGATION_WANDER_SCALING):
    the relative spread of profile-window means falls as 1 / sqrt(N) -- the paper set-up's
    runs (7560 flow particles, 22x the default's) give C = rel sd * sqrt(N) within 25 % of the
    default's -- and with it the default campaign's seeds (SEGREGATION_DEFAULT_REPLICATES,
    all nine steady under today's trend rule) scatter 0.5-2x what their per-run stderrs say
    (0.8x, 1.7x, 1.4x), where their windows' stderrs alone were 1.8-9.4x too small."""
    from granflow.fitting.segregation import wander_sd
    from granflow.reference import (SEGREGATION_DEFAULT_N_FLOW, SEGREGATION_DEFAULT_REPLICATES,
                                    SEGREGATION_DEFAULT_REPLICATES_STATE_NOW,
                                    SEGREGATION_WANDER_C, SEGREGATION_WANDER_SCALING)

    c = {}
    for setup, _, n, _, rel, _, _ in SEGREGATION_WANDER_SCALING["points"]:
        c.setdefault(setup.split()[0], []).append((rel * math.sqrt(n)) ** 2)
    rms = {k: math.sqrt(sum(v) / len(v)) for k, v in c.items()}
    assert rms["paper"] / rms["default"] == pytest.approx(1.0, abs=0.25)
    assert SEGREGATION_WANDER_C == pytest.approx(1.63, abs=0.005)
    for sigma, runs in SEGREGATION_DEFAULT_REPLICATES.items():
        states = SEGREGATION_DEFAULT_REPLICATES_STATE_NOW[sigma]
        steady = [(p, se) for (p, se, _, _), st in zip(runs, states) if st == "steady"]
        if len(steady) < 2:
            continue
        sd = float(np.std([p for p, _ in steady], ddof=1))
        windows = math.sqrt(np.mean([se ** 2 for _, se in steady]))
        total = math.sqrt(np.mean([max(se, wander_sd(p, SEGREGATION_DEFAULT_N_FLOW[sigma])) ** 2
                                   for p, se in steady]))
        assert sd / windows >= 1.7, sigma
        assert 0.5 <= sd / total <= 2.0, (sigma, sd, total)


def test_the_library_says_which_part_of_a_ratios_Ps_error_is_wander():
    """Each run's Ps error is the larger of its windows' and the wander at its particle number;
    both parts reach the library (segregation_Ps_windows_sem, segregation_Ps_wander_sd, with
    CF units and long names), for several runs at a ratio as rms / sqrt(n): two runs with
    windows' errors 0.03 and 0.04 and wander 0.4 and 0.5 give sqrt((0.03^2 + 0.04^2) / 2) /
    sqrt(2) and sqrt((0.4^2 + 0.5^2) / 2) / sqrt(2)."""
    import granflow.closures as gc
    from granflow.fitting import campaign_table_from_records, combine_Ps_runs

    fits = []
    for k, (p, w_sem, wander) in enumerate(((4.0, 0.03, 0.4), (4.6, 0.04, 0.5))):
        f = _profile_fit(p, 0.9, f"s09/seed~{k}", wander, 40 + k)
        fits.append(f.replace(extra=dict(f.extra, Ps_windows_sem=w_sem, Ps_wander_sd=wander)))
    one = _profile_fit(9.0, 0.75, "s075", 0.8, 50)
    fits.append(one.replace(extra=dict(one.extra, Ps_windows_sem=0.1, Ps_wander_sd=0.8)))
    out = combine_Ps_runs(fits)
    both = next(f for f in out if f.coords["sigma"] == 0.9)
    assert both.extra["Ps_windows_sem"] == pytest.approx(math.sqrt((0.03 ** 2 + 0.04 ** 2) / 4))
    assert both.extra["Ps_wander_sd"] == pytest.approx(math.sqrt((0.4 ** 2 + 0.5 ** 2) / 4))
    table = campaign_table_from_records([
        dict(theta=25.0, H=8.0, lam=1.0, sigma=s, contact_law="linear", state="steady", Ps=p,
             run_id=f"r{i}") for i, (s, p) in enumerate(((0.9, 4.3), (0.75, 9.0)))])
    ds = gc.build_library_dataset(out, table, name="rep", version=1)
    sel = dict(contact_law="linear")
    w = ds["segregation_Ps_wander_sd"].sel(sel)
    assert w.sel(sigma=0.75).item() == 0.8
    assert w.sel(sigma=0.9).item() == pytest.approx(both.extra["Ps_wander_sd"])
    assert ds["segregation_Ps_windows_sem"].sel(sel).sel(sigma=0.75).item() == 0.1
    for v in ("segregation_Ps_wander_sd", "segregation_Ps_windows_sem"):
        assert ds[v].attrs["units"] == "1" and "long_name" in ds[v].attrs


def test_the_wander_scaling_predicted_two_held_out_boxes():
    """C (1.631) was fixed before two runs in 20 x 5 and 40 x 5 boxes (569 and 1138 flow
    particles, sigma = 0.75, the default's depth and species) had passed their approach; the
    relative spread of their 60-unit Ps means over t >= 900 came out within 30 % of
    C / sqrt(N) (1.28x and 0.96x), where a spread that did not fall with N (the default's
    rms 9.4 %) is 2x off in the 40 x 5 box."""
    from granflow.reference import (SEGREGATION_WANDER_C, SEGREGATION_WANDER_HELD_OUT,
                                    SEGREGATION_WANDER_SCALING)

    default = [p[4] for p in SEGREGATION_WANDER_SCALING["points"] if p[0].startswith("default")]
    flat = math.sqrt(np.mean(np.square(default)))
    assert flat == pytest.approx(0.094, abs=0.001)
    for box, h in SEGREGATION_WANDER_HELD_OUT.items():
        pred = SEGREGATION_WANDER_C / math.sqrt(h["n_flow"])
        assert pred == pytest.approx(h["predicted"], abs=5e-5), box
        for key in ("rel_sd_60", "rel_sd_60_from_1000", "rel_sd_60_from_800"):
            assert abs(h[key] / pred - 1.0) <= 0.30, (box, key, h[key] / pred)
    big = SEGREGATION_WANDER_HELD_OUT[(40.0, 5.0)]
    assert flat / big["rel_sd_60"] > 1.9


def test_a_trend_within_the_wander_is_not_counted_as_drift_measured_on_long_runs():
    """The "Ps still moving" rule replayed on the long runs' steady tails
    (SEGREGATION_TREND_CALIBRATION): the 5 % rule flagged 15 % or more of the stretches at a
    few hundred particles, its trend pointing towards the long mean in 40-60 % of them (a
    one-sided bound that is a coin flip); with the tolerance at 3 C / sqrt(N) the default's
    tails (the multiple's fit) flag <= 5 % pooled at every stretch length, the other tails
    <= 5 % too, and the mixed starts' approaches keep over half the flags, >= 97 % of them
    pointing towards the plateau."""
    from granflow.campaign.collect import PS_TREND_WANDER_MULTIPLE, ps_trend_tolerance
    from granflow.reference import SEGREGATION_TREND_CALIBRATION as cal
    from granflow.reference import SEGREGATION_WANDER_C

    def pooled(rows, n):
        return np.sum([r[3][n] for r in rows], axis=0)

    default = [r for r in cal["steady"] if r[0].startswith("default")]
    others = [r for r in cal["steady"] if not r[0].startswith("default")]
    assert len(default) == 4 and len(others) == 4
    for n in (4, 6, 10):
        s, f5, t5, fw, tw = pooled(default, n)
        assert f5 / s >= 0.15 and 0.4 <= t5 / f5 <= 0.6, n
        assert fw / s <= 0.05, n
        s, f5, t5, fw, tw = pooled(others, n)
        assert fw / s <= 0.05 and f5 / s >= 0.1, n
        s, f5, t5, fw, tw = pooled(cal["approach"], n)
        assert fw >= 0.5 * f5 and tw / fw >= 0.97 and t5 / f5 >= 0.9, n
    # the tolerance those flags were replayed with, at the default's 346 particles: 26 %
    assert ps_trend_tolerance(4.6, 4.6 * SEGREGATION_WANDER_C / math.sqrt(346)) == \
        pytest.approx(PS_TREND_WANDER_MULTIPLE * 0.0877, rel=0.01)


def test_an_independent_engine_wanders_as_granflow_does():
    """LAMMPS (pair_style granular, the same species) continuing granflow's sigma = 0.75
    default-set-up state for 900 time units (SEGREGATION_WANDER_LAMMPS): its 60-unit means of
    Ps spread by C / sqrt(N) within 30 % of granflow's C (1.63), its windows' own stderrs
    understate that 2-3x as granflow's do, its mean lies within 2 combined stderrs of both
    granflow runs' long means, and the wander trend rule (chosen before this run) flags at
    most 10 % of its stretches where the 5 % rule flags half of the 10-window ones."""
    from granflow.reference import (SEGREGATION_DEFAULT_WANDER, SEGREGATION_WANDER_C,
                                    SEGREGATION_WANDER_LAMMPS as lmp)

    pred = SEGREGATION_WANDER_C / math.sqrt(lmp["n_flow"])
    assert lmp["rel_sd_60"] == pytest.approx(lmp["sd_60"] / lmp["Ps"], abs=5e-4)
    assert lmp["C_60"] == pytest.approx(lmp["rel_sd_60"] * math.sqrt(lmp["n_flow"]), abs=0.005)
    assert abs(lmp["rel_sd_60"] / pred - 1.0) <= 0.30
    assert 2.0 <= lmp["sem_ratio_60"] <= 3.0
    for seed, w in SEGREGATION_DEFAULT_WANDER[0.75].items():
        assert abs(lmp["Ps"] - w["Ps"]) < 2 * math.hypot(lmp["stderr"], w["stderr"]), seed
    for n, (s, f5, t5, fw, tw) in lmp["trend_flags"].items():
        assert fw / s <= 0.1, n
    s, f5, _, fw, _ = lmp["trend_flags"][10]
    assert f5 / s >= 0.5 and fw < f5
