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
