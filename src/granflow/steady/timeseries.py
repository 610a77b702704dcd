"""Time-series statistics for steady-state detection (Weinhart et al. 2012 §6).

The paper decides that a chute flow is steady when the energy ratio E_kin/<E_ela> "becomes time
independent" (§6, Fig. 3; judged by eye over t in [1800, 2000]).  This module supplies the
statistics that replace the eye judgement, modelled on pymbar's ``timeseries`` module
(Chodera et al. 2007; Chodera 2016, "A simple method for automated equilibration detection"):

* :func:`statistical_inefficiency` -- g = 1 + 2 sum_t (1 - t/N) C(t), the integrated
  autocorrelation time in units of the sampling interval, with the normalised autocorrelation
  C(t) computed for all lags at once by FFT and summed up to its first non-positive value after
  ``mintime`` lags (pymbar's rule; ``fast=True`` uses pymbar's growing lag increments).
* :func:`subsample_indices` -- indices of (approximately) uncorrelated samples, spaced by g.
* :func:`detect_equilibration` -- pymbar's rule: the equilibration time t0 is the origin that
  maximises the effective number of uncorrelated samples N_eff = (N - t0 + 1)/g(t0) of the tail.
* :func:`trend_test` -- OLS slope of a series against time whose standard error accounts for
  serial correlation (the OLS variance is multiplied by the statistical inefficiency of the
  residuals, and the Student-t test uses N_eff - 2 degrees of freedom); :func:`curvature_test`
  does the same for the quadratic coefficient ("is the growth levelling off?").

Pure numpy/scipy; every function is O(N log N) or better (detect_equilibration is
O(M N log N) for M trial origins).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import math

import numpy as np
from scipy import stats

__all__ = [
    "standard_error_of_mean",
    "autocorrelation",
    "statistical_inefficiency",
    "subsample_indices",
    "detect_equilibration",
    "TrendResult",
    "trend_test",
    "curvature_test",
    "ar1_noise",
]

#: Lags always included in the g sum before a non-positive C(t) may stop it (pymbar: mintime=3).
MINTIME = 3

#: Default number of trial origins scanned by :func:`detect_equilibration` (pymbar scans every
#: sample; ~200 evenly spaced origins resolve t0 to 0.5 % of the series at a fraction of the cost).
DEFAULT_EQUILIBRATION_ORIGINS = 200

#: Smallest tail (samples) that :func:`detect_equilibration` considers; shorter tails give
#: meaningless g estimates.
MIN_TAIL_SAMPLES = 10


def _as_1d(x) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"expected a 1-D series, got shape {x.shape}")
    return x


def autocorrelation(x, y=None) -> np.ndarray:
    """Normalised (cross-)autocorrelation C(t), t = 0..N-1, as pymbar defines it.

    C(t) = sum_{n<N-t} (dx_n dy_{n+t} + dy_n dx_{n+t}) / (2 (N-t) <dx dy>) with dx = x - mean(x);
    computed for all lags by zero-padded FFT.  Returns zeros when the series is constant.
    """
    x = _as_1d(x)
    y = x if y is None else _as_1d(y)
    if y.shape != x.shape:
        raise ValueError("x and y must have the same length")
    n = x.size
    if n == 0:
        return np.zeros(0)
    dx = x - x.mean()
    dy = y - y.mean()
    var = float(np.mean(dx * dy))
    if not np.isfinite(var) or var <= 0.0:
        return np.zeros(n)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    fx = np.fft.rfft(dx, nfft)
    if y is x:
        raw = np.fft.irfft(fx * np.conj(fx), nfft)[:n]
    else:
        fy = np.fft.rfft(dy, nfft)
        # sum_n dx_n dy_{n+t}  and  sum_n dy_n dx_{n+t}
        xy = np.fft.irfft(np.conj(fx) * fy, nfft)[:n]
        yx = np.fft.irfft(np.conj(fy) * fx, nfft)[:n]
        raw = 0.5 * (xy + yx)
    return raw / ((n - np.arange(n)) * var)


def statistical_inefficiency(x, y=None, *, fast: bool = False, mintime: int = MINTIME) -> float:
    """Statistical inefficiency g >= 1 of a series (pymbar's ``statisticalInefficiency``).

    g = 1 + 2 sum_{t>=1} (1 - t/N) C(t), summed until C(t) <= 0 for some t > ``mintime``.
    For an AR(1) process x_n = phi x_{n-1} + noise, g = (1 + phi)/(1 - phi).  N/g is the
    effective number of uncorrelated samples.  ``fast=True`` reproduces pymbar's fast estimator
    (lag increments 1, 2, 3, ... with weights equal to the increment).  Returns 1.0 for a constant
    or too short (N < 2) series.
    """
    x = _as_1d(x)
    n = x.size
    if n < 2:
        return 1.0
    c = autocorrelation(x, y)
    if not np.any(c):
        return 1.0
    if not fast:
        lags = np.arange(1, n - 1)
        cl = c[1 : n - 1]
        stop = np.nonzero((cl <= 0.0) & (lags > mintime))[0]
        end = stop[0] if stop.size else cl.size
        g = 1.0 + 2.0 * float(np.sum(cl[:end] * (1.0 - lags[:end] / n)))
    else:
        g = 1.0
        t = 1
        inc = 1
        while t < n - 1:
            ct = c[t]
            if ct <= 0.0 and t > mintime:
                break
            g += 2.0 * ct * (1.0 - t / n) * inc
            t += inc
            inc += 1
    return max(g, 1.0)


def standard_error_of_mean(x) -> float:
    """Standard error of the mean of a serially correlated series: sqrt(g var(x) / N), with the
    statistical inefficiency g >= 1 (N/g decorrelated samples).  NaN for fewer than 2 finite
    values.  For block (time-window) means this is the batch-means error estimate, corrected for
    any correlation left between the blocks."""
    x = np.asarray(x, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if x.size < 2:
        return math.nan
    g = statistical_inefficiency(x)
    return float(math.sqrt(g * np.var(x, ddof=1) / x.size))


def subsample_indices(x=None, g: float | None = None, *, n: int | None = None) -> np.ndarray:
    """Indices of effectively uncorrelated samples: round(k g) for k = 0, 1, ... (pymbar rule).

    Give the series ``x`` (g is then estimated) or its length ``n`` and a known ``g``.
    """
    if x is not None:
        x = _as_1d(x)
        n = x.size
        if g is None:
            g = statistical_inefficiency(x)
    if n is None or g is None:
        raise ValueError("give the series x, or its length n together with g")
    g = max(float(g), 1.0)
    idx = np.unique(np.round(np.arange(0.0, n, g)).astype(int))
    return idx[idx < n]


def detect_equilibration(
    x, *, fast: bool = False, n_origins: int = DEFAULT_EQUILIBRATION_ORIGINS,
    min_tail: int = MIN_TAIL_SAMPLES,
) -> tuple[int, float, float]:
    """Equilibration index by maximum effective sample size (pymbar's ``detectEquilibration``).

    For trial origins t (``n_origins`` evenly spaced indices in [0, N - min_tail]) computes
    g(t) of x[t:] and N_eff(t) = (N - t + 1)/g(t); returns (t0, g(t0), N_eff(t0)) at the maximum.
    Discarding x[:t0] removes the initial transient: a transient inflates both the variance and
    the correlation time of the tail, so N_eff is largest when it is just excluded.
    A constant series gives (0, 1.0, N).
    """
    x = _as_1d(x)
    n = x.size
    if n == 0:
        return 0, 1.0, 0.0
    if n < 2 or np.ptp(x) == 0.0:
        return 0, 1.0, float(n)
    last = max(n - max(int(min_tail), 2), 0)
    origins = np.unique(np.linspace(0, last, min(int(n_origins), last + 1)).round().astype(int))
    best = (0, 1.0, -np.inf)
    for t in origins:
        tail = x[t:]
        g = statistical_inefficiency(tail, fast=fast) if np.ptp(tail) > 0 else float(tail.size)
        neff = (n - t + 1) / g
        if neff > best[2]:
            best = (int(t), float(g), float(neff))
    return best


@dataclass(frozen=True)
class TrendResult:
    """Result of :func:`trend_test` / :func:`curvature_test`.

    coefficient: the tested OLS coefficient (slope per time unit, or quadratic coefficient);
    stderr: its standard error corrected for serial correlation; t_stat = coefficient/stderr;
    p_value: two-sided p; p_increase / p_decrease: one-sided p for coefficient > 0 / < 0;
    g: statistical inefficiency of the residuals; n: samples; n_eff = n/g; dof: t-test degrees of
    freedom; mean: mean of the series; span: time span covered; relative_change: fitted change of
    the linear trend over the span divided by |mean| (nan if mean == 0, trend test only).
    """

    coefficient: float
    stderr: float
    t_stat: float
    p_value: float
    p_increase: float
    p_decrease: float
    g: float
    n: int
    n_eff: float
    dof: float
    mean: float
    span: float
    relative_change: float

    @property
    def slope(self) -> float:
        return self.coefficient

    def significant(self, alpha: float) -> bool:
        """Two-sided test at level ``alpha``."""
        return bool(self.p_value < alpha)

    def as_dict(self, prefix: str = "") -> dict:
        return {prefix + k: v for k, v in asdict(self).items()}


def _poly_test(x, t, degree: int, method: str) -> TrendResult:
    x = _as_1d(x)
    n = x.size
    t = np.arange(n, dtype=float) if t is None else _as_1d(t)
    if t.shape != x.shape:
        raise ValueError("t and x must have the same length")
    ok = np.isfinite(x) & np.isfinite(t)
    x, t = x[ok], t[ok]
    n = x.size
    nan = float("nan")
    mean = float(np.mean(x)) if n else nan
    span = float(t[-1] - t[0]) if n else 0.0
    if n < degree + 3 or span <= 0.0:
        return TrendResult(nan, nan, nan, 1.0, 1.0, 1.0, 1.0, n, float(n), 0.0, mean, span, nan)
    # centred, scaled time keeps the normal equations well conditioned
    tc = 0.5 * (t[0] + t[-1])
    s = (t - tc) / span
    design = np.vander(s, degree + 1, increasing=True)
    coef, *_ = np.linalg.lstsq(design, x, rcond=None)
    resid = x - design @ coef
    g = statistical_inefficiency(resid) if np.ptp(resid) > 0 else 1.0
    if method == "subsample":
        idx = subsample_indices(n=n, g=g)
        if idx.size < degree + 3:
            idx = np.arange(n)
        design_s, x_s = design[idx], x[idx]
        coef, *_ = np.linalg.lstsq(design_s, x_s, rcond=None)
        resid_s = x_s - design_s @ coef
        m = idx.size
        dof = float(m - (degree + 1))
        sigma2 = float(resid_s @ resid_s) / dof
        cov = sigma2 * np.linalg.inv(design_s.T @ design_s)
        n_eff = float(m)
    elif method == "inflate":
        n_eff = n / g
        dof = max(n_eff - (degree + 1), 1.0)
        # residual variance with the usual dof correction, then the OLS covariance inflated by g
        sigma2 = float(resid @ resid) / max(n - (degree + 1), 1)
        cov = g * sigma2 * np.linalg.inv(design.T @ design)
    else:
        raise ValueError(f"unknown method {method!r} (use 'inflate' or 'subsample')")
    # back to physical time units: coefficient of s^k -> coefficient of (t - tc)^k
    scale = span ** degree
    c = float(coef[degree]) / scale
    se = float(np.sqrt(max(cov[degree, degree], 0.0))) / scale
    if se == 0.0:
        tstat = 0.0 if c == 0.0 else np.sign(c) * np.inf
    else:
        tstat = c / se
    p_inc = float(stats.t.sf(tstat, dof))
    p_dec = float(stats.t.cdf(tstat, dof))
    p_two = float(min(1.0, 2.0 * min(p_inc, p_dec)))
    rel = nan
    if degree == 1 and mean != 0.0:
        rel = c * span / abs(mean)
    return TrendResult(c, se, float(tstat), p_two, p_inc, p_dec, float(g), int(n), float(n_eff),
                       float(dof), mean, span, float(rel))


def trend_test(x, t=None, *, method: str = "inflate") -> TrendResult:
    """Test for a linear trend of ``x`` against time ``t`` (sample index if None).

    OLS fit x = a + b t.  Serial correlation makes the naive OLS standard error far too small, so
    the statistical inefficiency g of the *residuals* (the trend itself would inflate g of the raw
    series) is estimated and

    * ``method="inflate"`` (default): Var(b) = g s^2 / sum (t - tbar)^2, Student t with N/g - 2
      degrees of freedom (uses every sample; Var of a slowly varying regressor's coefficient under
      correlated noise is g times the white-noise value);
    * ``method="subsample"``: refit on the decorrelated subsample (indices spaced by g) with the
      ordinary OLS error.

    Returns a :class:`TrendResult`; the slope is ``result.slope`` (units of x per unit t).
    """
    return _poly_test(x, t, 1, method)


def curvature_test(x, t=None, *, method: str = "inflate") -> TrendResult:
    """Test the quadratic coefficient c of the OLS fit x = a + b t + c t^2 (same error model as
    :func:`trend_test`).  A significantly negative c on a rising series means the growth is levelling
    off (spin-up towards a plateau), not a flow that keeps accelerating."""
    return _poly_test(x, t, 2, method)


def ar1_noise(n: int, rng, phi: float, scale: float) -> np.ndarray:
    """AR(1) noise x_i = phi x_(i-1) + e_i of stationary standard deviation ``scale``, started
    at 0 (statistical inefficiency (1 + phi) / (1 - phi)): the noise model of the known-answer
    series the steady detectors are tested and calibrated on."""
    x = np.empty(n)
    x[0] = 0.0
    e = rng.normal(0.0, scale * math.sqrt(1 - phi**2), n)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x
