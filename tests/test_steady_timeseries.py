"""Tests of granflow.steady.timeseries on synthetic series with known answers."""

import numpy as np
import pytest

from granflow.steady.timeseries import (
    autocorrelation,
    curvature_test,
    detect_equilibration,
    statistical_inefficiency,
    subsample_indices,
    trend_test,
)


def ar1(n, phi, seed, sigma=1.0):
    """Stationary AR(1) with marginal standard deviation sigma."""
    rng = np.random.default_rng(seed)
    e = rng.normal(0.0, sigma * np.sqrt(1.0 - phi**2), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sigma)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


def test_autocorrelation_of_ar1_is_geometric():
    x = ar1(50_000, 0.8, seed=1)
    c = autocorrelation(x)
    assert c[0] == pytest.approx(1.0, abs=1e-12)
    # C(t) = phi^t, sampling error ~ sqrt((1+phi^2)/(1-phi^2)/N) ~ 0.01
    np.testing.assert_allclose(c[1:6], 0.8 ** np.arange(1, 6), atol=0.03)


def test_statistical_inefficiency_ar1_phi09():
    true_g = (1 + 0.9) / (1 - 0.9)  # = 19
    gs = [statistical_inefficiency(ar1(20_000, 0.9, seed=s)) for s in range(5)]
    assert np.mean(gs) == pytest.approx(true_g, rel=0.15)
    for g in gs:
        assert g == pytest.approx(true_g, rel=0.25)
    # pymbar's fast estimator is coarser (over-estimates by ~15 % here) but in the same range
    g_fast = statistical_inefficiency(ar1(20_000, 0.9, seed=0), fast=True)
    assert g_fast == pytest.approx(true_g, rel=0.3)


def test_statistical_inefficiency_white_noise_and_constant():
    assert statistical_inefficiency(ar1(20_000, 0.0, seed=3)) == pytest.approx(1.0, abs=0.1)
    assert statistical_inefficiency(np.ones(100)) == 1.0
    assert statistical_inefficiency([1.0]) == 1.0


def test_subsample_indices_are_decorrelated():
    x = ar1(40_000, 0.9, seed=4)
    g = statistical_inefficiency(x)
    idx = subsample_indices(x)
    assert np.all(np.diff(idx) >= np.floor(g))
    assert idx.size == pytest.approx(x.size / g, rel=0.01)
    sub = x[idx]
    # lag-1 correlation of the subsample ~ phi^g = 0.9^19 = 0.13 (+-0.05 sampling)
    assert abs(np.corrcoef(sub[:-1], sub[1:])[0, 1]) < 0.25
    np.testing.assert_array_equal(subsample_indices(n=10, g=3.0), [0, 3, 6, 9])


@pytest.mark.parametrize("seed", range(5))
def test_detect_equilibration_finds_onset(seed):
    n, onset = 2000, 400
    x = 1.0 + 0.1 * ar1(n, 0.5, seed=seed)
    x[:onset] += np.linspace(4.0, 0.0, onset)  # relaxation, then plateau
    t0, g, neff = detect_equilibration(x)
    assert abs(t0 - onset) <= 0.1 * onset
    assert g == pytest.approx(3.0, rel=0.3)  # (1 + 0.5)/(1 - 0.5) on the plateau
    assert neff == pytest.approx((n - t0 + 1) / g, rel=1e-12)


def test_detect_equilibration_constant_series():
    assert detect_equilibration(np.full(50, 2.0)) == (0, 1.0, 50.0)


def test_trend_test_detects_linear_trend():
    n, slope = 2000, 2e-4
    t = np.arange(n) * 0.5
    x = 1.0 + slope * t + 0.05 * ar1(n, 0.9, seed=7)
    res = trend_test(x, t)
    assert res.p_value < 1e-3
    assert res.p_increase < 1e-3
    assert res.slope == pytest.approx(slope, abs=3 * res.stderr)
    assert res.g == pytest.approx(19.0, rel=0.35)  # g of the residuals, not of the trend
    assert res.relative_change == pytest.approx(slope * t[-1] / np.mean(x), rel=0.3)


def test_trend_test_false_positive_rate_on_ar1():
    alpha = 0.05
    rejections = [trend_test(ar1(1000, 0.9, seed=100 + s)).p_value < alpha for s in range(60)]
    # nominal 5 %; allow up to 15 % (binomial sd at n=60 is ~3 %)
    assert np.mean(rejections) <= 0.15
    # a naive OLS (g ignored) would reject far more often: check the correction matters
    naive = []
    for s in range(20):
        x = ar1(1000, 0.9, seed=100 + s)
        b, a = np.polyfit(np.arange(1000), x, 1)
        r = x - (a + b * np.arange(1000))
        se = np.sqrt(r.var(ddof=2) / np.sum((np.arange(1000) - 499.5) ** 2))
        naive.append(abs(b / se) > 1.96)
    assert np.mean(naive) > 0.3


def test_curvature_test_sign():
    t = np.linspace(0, 100, 1000)
    noise = 0.02 * ar1(1000, 0.5, seed=9)
    rising_levelling = 1 - np.exp(-t / 30) + noise
    res = curvature_test(rising_levelling, t)
    assert res.p_decrease < 1e-3
    convex = (t / 100) ** 2 + noise
    res = curvature_test(convex, t)
    assert res.coefficient == pytest.approx(1e-4, rel=0.2)
    assert res.p_increase < 1e-3


def test_trend_test_degenerate_input():
    res = trend_test([1.0, 2.0])
    assert res.p_value == 1.0 and np.isnan(res.slope)
    with pytest.raises(ValueError):
        trend_test(np.ones(10), np.arange(5))


def test_ar1_noise_has_its_stationary_scale_and_statistical_inefficiency():
    """The known-answer noise model: standard deviation ``scale`` and g = (1 + phi) / (1 - phi)
    (9 at phi = 0.8) on a long series."""
    from granflow.steady.timeseries import ar1_noise, statistical_inefficiency

    x = ar1_noise(200_000, np.random.default_rng(5), 0.8, 0.02)
    assert x[0] == 0.0
    assert np.std(x) == pytest.approx(0.02, rel=0.02)
    assert statistical_inefficiency(x) == pytest.approx(9.0, rel=0.1)
