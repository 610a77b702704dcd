"""Common result type and error measure for all closure fits.

Every fit in :mod:`granflow.fitting` returns a :class:`FitResult`. A fit that cannot be made
(too few points, no arrested/flowing bracket, non-convergence) returns ``ok=False``, NaN
parameters and a message saying why -- it never fills in numbers.

The error measure is the paper's standard error, Weinhart et al. (2012) Eq. (49):
``err({x_i}) = (sum_i x_i^2 / (N - 1))^(1/2)`` over the residuals ``x_i`` of a fit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

#: Coordinates a result may be tagged with (they become netCDF dimensions in a library).
COORD_NAMES = ("lam", "contact_law", "sigma")


def error_eq49(residuals) -> float:
    """Standard error of Weinhart et al. (2012) Eq. (49): sqrt(sum x_i^2 / (N - 1)); NaN if N < 2."""
    x = np.asarray(residuals, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if x.size < 2:
        return math.nan
    return float(math.sqrt(np.sum(x * x) / (x.size - 1)))


@dataclass(frozen=True)
class FitResult:
    """Outcome of one closure fit.

    Attributes
    ----------
    kind : str
        Which closure this is (e.g. ``"hstop"``, ``"flow_rule"``); names the variables in a library.
    equation : str
        The paper equation implemented, e.g. ``"Weinhart et al. 2012 Eq. (45)"``.
    params : dict
        Fitted parameter values (NaN when ``ok`` is False).
    stderr : dict
        One-standard-error uncertainty of each parameter; how it was obtained is ``stderr_method``
        (``"covariance"``: square root of the diagonal of the least-squares covariance matrix,
        scaled by the residual variance; ``"bootstrap"``: standard deviation of refits to
        resampled data; ``"standard error of the mean"``).
    error : float
        The paper's error measure of the fit (Eq. 49 of its residuals, see ``error_measure``).
    n_points : int
        Number of data points (or intervals) that entered the fit.
    ok : bool
        Whether the fit could be made; if False, params/stderr are NaN and ``message`` says why.
    message : str
        Human-readable status.
    stderr_method, error_measure : str
        How ``stderr`` and ``error`` were computed.
    valid_range : dict
        ``{variable: (min, max)}`` of the data the fit saw; evaluators refuse to go outside it
        unless asked to extrapolate.
    coords : dict
        Where the fit belongs: any of ``lam`` (basal roughness lambda), ``contact_law``, ``sigma``.
    extra : dict
        Fit-specific additions (confidence intervals, model comparisons, ...).
    status : str
        What the data identify (:mod:`granflow.fitting.identify`): ``"ok"`` (every parameter of
        the full form identified), ``"reduced"`` (a stated reduced form is identified and is
        what is stored), ``"unidentified"``, ``"misfit"`` (the fit does not describe its own
        data: held-out |z| > 3 or chi-square), ``"failed"`` (no fit could be made).  ``ok`` is
        True exactly for ``"ok"`` and ``"reduced"``.  Empty until assessed.
    form : str
        Which form of the closure the params belong to (``"full"`` or a reduced form's name).
    param_status, param_reason : dict
        Per parameter: ``identified`` / ``unidentified`` / ``fixed`` / ``not_in_form`` and why.
    ensemble : tuple
        Parameter samples (tuple of tuples, one per sample, in ``params`` order): a bootstrap
        ensemble or draws from the covariance (``stderr_method`` says which).  Evaluators
        propagate it to the uncertainty of an evaluated value.
    diagnostics : dict
        chi-square, dof, p-value, Birge ratio, largest parameter correlation, held-out z-scores.
    runs_used : tuple
        Identifiers of the runs that entered the fit.
    selection : str
        Which runs were used and why (generated from the selection actually applied).
    """

    kind: str
    equation: str
    params: dict
    stderr: dict
    error: float
    n_points: int
    ok: bool
    message: str
    stderr_method: str = "covariance"
    error_measure: str = "Weinhart et al. 2012 Eq. (49) of the residuals"
    valid_range: dict = field(default_factory=dict)
    coords: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    status: str = ""
    form: str = "full"
    param_status: dict = field(default_factory=dict)
    param_reason: dict = field(default_factory=dict)
    ensemble: tuple = ()
    diagnostics: dict = field(default_factory=dict)
    runs_used: tuple = ()
    selection: str = ""

    @property
    def state(self) -> str:
        """``status`` when assessed, else ``"ok"``/``"failed"`` from ``ok``."""
        return self.status or ("ok" if self.ok else "failed")

    def ensemble_array(self) -> np.ndarray:
        """The ensemble as an (n_samples, n_params) float array (params order)."""
        if not self.ensemble:
            return np.zeros((0, len(self.params)))
        return np.asarray(self.ensemble, dtype=float).reshape(len(self.ensemble), -1)

    def replace(self, **changes) -> "FitResult":
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def __getitem__(self, name: str) -> float:
        return self.params[name]

    def tagged(self, **coords) -> "FitResult":
        """Copy of this result with extra coordinates (``lam``, ``contact_law``, ``sigma``)."""
        unknown = set(coords) - set(COORD_NAMES)
        if unknown:
            raise ValueError(f"unknown coordinate(s) {sorted(unknown)}; allowed: {COORD_NAMES}")
        merged = dict(self.coords)
        merged.update({k: v for k, v in coords.items() if v is not None})
        return dataclasses.replace(self, coords=merged)


def failed_fit(kind: str, equation: str, param_names, message: str, n_points: int = 0,
               stderr_method: str = "covariance", **coords) -> FitResult:
    """A FitResult for a fit that could not be made: NaN parameters, ``ok=False``."""
    nan = {name: math.nan for name in param_names}
    return FitResult(kind=kind, equation=equation, params=dict(nan), stderr=dict(nan),
                     error=math.nan, n_points=int(n_points), ok=False, message=message,
                     stderr_method=stderr_method,
                     coords={k: v for k, v in coords.items() if v is not None},
                     status="failed", param_status={n: "not_fitted" for n in param_names},
                     param_reason={n: message for n in param_names})


def data_range(values) -> tuple[float, float]:
    """(min, max) of the finite entries of ``values``."""
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (math.nan, math.nan)
    return (float(v.min()), float(v.max()))


def covariance_stderr(pcov, names) -> dict:
    """Standard errors from a covariance matrix (NaN when the matrix is not finite)."""
    pcov = np.atleast_2d(np.asarray(pcov, dtype=float))
    diag = np.diag(pcov) if pcov.size else np.full(len(names), np.nan)
    out = {}
    for name, var in zip(names, diag):
        out[name] = float(math.sqrt(var)) if np.isfinite(var) and var >= 0 else math.nan
    return out


def finite_mask(*arrays) -> np.ndarray:
    """Boolean mask of entries finite in every array (arrays broadcast together)."""
    arrays = np.broadcast_arrays(*[np.asarray(a, dtype=float) for a in arrays])
    mask = np.ones(arrays[0].shape, dtype=bool)
    for a in arrays:
        mask &= np.isfinite(a)
    return mask


def bootstrap_stderr(samples) -> float:
    """Robust bootstrap standard error: half the central 68 % (16th-84th percentile) range of the
    finite samples (equal to the standard deviation for a normal distribution, and not blown
    up by the few resamples that leave out the data a parameter rests on); NaN for < 10."""
    x = np.asarray(samples, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if x.size < 10:
        return math.nan
    q16, q84 = np.percentile(x, [15.865, 84.135])
    return float(0.5 * (q84 - q16))


#: the quantiles whose half distance is :func:`bootstrap_stderr`
_Q_LOW, _Q_HIGH = 0.15865, 0.84135
#: at most this many times the requested refits are made (:func:`bootstrap_undecided`), and
#: at most BOOTSTRAP_MIN_CAP when that is more
BOOTSTRAP_MAX_FACTOR = 8
BOOTSTRAP_MIN_CAP = 400


def bootstrap_cap(requested: int) -> int:
    """The most refits a fit that asked for ``requested`` makes (0 for 0)."""
    return max(BOOTSTRAP_MAX_FACTOR * int(requested), BOOTSTRAP_MIN_CAP) if requested > 0 else 0
#: a parameter at an optimiser bound in more than this fraction of the bootstrap refits (the
#: percentile of :func:`bootstrap_stderr`) has an stderr that the bound sets, not the data: the
#: data limit it on one side only.  (Fewer refits at a bound are the resamples that leave out
#: the few brackets a parameter rests on -- about exp(-k) of them for k brackets -- which the
#: percentile stderr is meant to be robust to; they are reported, not judged.)
BOOTSTRAP_BOUND_FRACTION = 0.15865
#: level of the one-sided bound the data give a parameter that an optimiser bound limits on
#: its other side (:func:`data_bound`)
DATA_BOUND_LEVEL = 0.95


def data_bound(samples, at_bound_rows, level: float = DATA_BOUND_LEVEL) -> dict | None:
    """The one-sided bound the data give a parameter whose bootstrap refits sit at an
    optimiser bound in more than :data:`BOOTSTRAP_BOUND_FRACTION` of cases (None otherwise).

    The refits at the bound mark the side the optimiser, not the data, limits: where they lie
    below the others the data bound the parameter from above only, by the ``level`` quantile
    of all refits (those at the bound included: they are the resamples that push it there), and
    conversely.  Returns ``{"side": "upper" | "lower", "value": v, "level": level,
    "at_bound_fraction": f}``; ``value`` NaN when more than ``level`` of the refits sit at the
    bound (the data bound it from neither side).
    """
    x = np.asarray(samples, dtype=float).ravel()
    ab = np.asarray(at_bound_rows, dtype=bool).ravel()
    ok = np.isfinite(x)
    x, ab = x[ok], ab[ok]
    if x.size == 0 or not ab.any():
        return None
    frac = float(ab.mean())
    if frac <= BOOTSTRAP_BOUND_FRACTION:
        return None
    rest = x[~ab]
    low_side = bool(rest.size == 0 or np.median(x[ab]) <= np.median(rest))
    side = "upper" if low_side else "lower"
    if frac > level:
        value = math.nan
    else:
        value = float(np.quantile(x, level if low_side else 1.0 - level))
    return {"side": side, "value": value, "level": float(level), "at_bound_fraction": frac}


def _quantile_rank_range(n: int, q: float, z: float) -> tuple[int, int]:
    """0-based order-statistic ranks (lo, hi) that bracket the q-quantile of n samples with
    coverage ~ the normal z (binomial, normal approximation, continuity-corrected)."""
    half = z * math.sqrt(n * q * (1.0 - q)) + 0.5
    lo = int(math.floor(n * q - half))
    hi = int(math.ceil(n * q + half))
    return max(lo, 0), min(hi, n - 1)


#: normal quantile of each percentile's order-statistic bounds in :func:`bootstrap_stderr_range`:
#: the stderr range then covers the infinite-refit stderr of normal refits 95-97 % of the time
#: at 200-1600 refits (measured, tests/test_identify.py; 1.96 per percentile gives 99.7 %)
STDERR_RANGE_Z = 1.2


def bootstrap_stderr_range(samples, z: float = STDERR_RANGE_Z) -> tuple[float, float]:
    """Monte Carlo range of :func:`bootstrap_stderr`: where the stderr of infinitely many
    refits lies (about 95 %).  Distribution-free: the 16th and 84th percentiles each
    lie between two order statistics of the refits (binomial ranks), and the stderr range is
    half the narrowest and widest distance between them.  A bootstrap whose 84th percentile
    falls in a sparse tail (refits running off towards a bound) has a wide range even with
    thousands of refits: its stderr then changes with the bootstrap seed.  (NaN, NaN) for
    fewer than 10 finite samples."""
    x = np.sort(np.asarray(samples, dtype=float).ravel())
    x = x[np.isfinite(x)]
    n = x.size
    if n < 10:
        return (math.nan, math.nan)
    l_lo, l_hi = _quantile_rank_range(n, _Q_LOW, z)
    h_lo, h_hi = _quantile_rank_range(n, _Q_HIGH, z)
    return (float(max(0.0, 0.5 * (x[h_lo] - x[l_hi]))), float(0.5 * (x[h_hi] - x[l_lo])))


def _wilson(k: int, n: int) -> tuple[float, float]:
    """Wilson score 95 % interval of a binomial fraction k / n (scipy.stats.binomtest)."""
    if n <= 0:
        return (0.0, 1.0)
    from scipy.stats import binomtest

    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=0.95, method="wilson")
    return (float(ci.low), float(ci.high))


def bootstrap_undecided(samples, limits, at_bound_rows=None) -> list[int]:
    """Columns of ``samples`` (refits x parameters) whose identifiability the refits so far
    leave to chance: the stderr's Monte Carlo range (:func:`bootstrap_stderr_range`) contains
    the column's stderr limit (``limits``, NaN: none), or the Wilson 95 % interval of the
    fraction of refits at an optimiser bound (``at_bound_rows``) contains
    :data:`BOOTSTRAP_BOUND_FRACTION`.  A fit refits until this is empty (or its cap): its
    decisions then do not depend on the bootstrap seed except by a 5 % chance per test."""
    arr = np.asarray(samples, dtype=float)
    arr = arr.reshape(arr.shape[0], -1) if arr.size else arr.reshape(0, len(limits))
    ab = (np.asarray(at_bound_rows, dtype=bool).reshape(arr.shape[0], -1)
          if at_bound_rows is not None else None)
    out = []
    for j, lim in enumerate(limits):
        if arr.shape[0] < 10:
            out.append(j)
            continue
        lo, hi = bootstrap_stderr_range(arr[:, j])
        if math.isfinite(lim) and math.isfinite(lo) and lo <= lim < hi:
            out.append(j)
            continue
        if ab is not None and ab.shape[0]:
            f_lo, f_hi = _wilson(int(ab[:, j].sum()), ab.shape[0])
            if f_lo <= BOOTSTRAP_BOUND_FRACTION < f_hi:
                out.append(j)
    return out


def bootstrap_summary(samples, names, at_bound_rows=None, requested: int | None = None) -> dict:
    """What a fit's ``extra['bootstrap']`` holds, for :mod:`granflow.fitting.identify`:
    number of refits (and requested), each parameter's stderr Monte Carlo range
    (:func:`bootstrap_stderr_range`) and, with ``at_bound_rows`` (refits x parameters,
    boolean), the fraction of refits in which each parameter sat at an optimiser bound."""
    arr = np.asarray(samples, dtype=float).reshape(-1, len(names))
    out = {"refits": int(arr.shape[0]),
           "stderr_range": {n: [float(v) for v in bootstrap_stderr_range(arr[:, j])]
                            for j, n in enumerate(names)},
           "method": "stderr = half the 15.9-84.1 percentile range of the refits; its range: "
                     "order-statistic (binomial, z = 1.2) bounds of the two percentiles, "
                     "about 95 % coverage of the infinite-refit stderr"}
    if requested is not None:
        out["requested"] = int(requested)
    if at_bound_rows is not None:
        ab = np.asarray(at_bound_rows, dtype=bool).reshape(-1, len(names))
        out["at_bound_fraction"] = {n: float(ab[:, j].mean()) if ab.shape[0] else math.nan
                                    for j, n in enumerate(names)}
        out["at_bound_fraction_range"] = {n: [float(v) for v in _wilson(int(ab[:, j].sum()),
                                                                       ab.shape[0])]
                                          for j, n in enumerate(names)}
        bounds = {n: data_bound(arr[:, j], ab[:, j]) for j, n in enumerate(names)
                  if ab.shape[0] == arr.shape[0]}
        out["data_bound"] = {n: b for n, b in bounds.items() if b is not None}
    return out

