"""Uniform layer after a change of inclination: Weinhart et al. (2012) Eq. (34) as an ODE.

For a layer of constant height h on a flat periodic slope, Eq. (34a) is trivially satisfied and
Eq. (34b-c) reduces to an ordinary differential equation for the depth-averaged velocity,

    du/dt = g cos(theta) (tan(theta) - mu(h, F) sign(u)),    F = u / sqrt(g h cos(theta)),

with the friction law mu(h, F) of Eq. (50) from a closure library (or any
:class:`~granflow.continuum.FlowClosures`).  It is solved with ``scipy.integrate.solve_ivp``
(LSODA, rtol 1e-9); a decelerating layer that comes to rest (tan(theta) <= mu(h, 0)) stops there
(terminal event).

Steady state: mu(h, F) = tan(theta), i.e. the flow rule F = beta h/hstop(theta) - gamma of
Eq. (47) for Eq. (50).  Linearised about it, u - u_inf decays like exp(-t/tau) with

    1/tau = g cos(theta) dmu/du = sqrt(g cos(theta) / h) dmu/dF     (at F = F_inf),

:func:`linear_relaxation_time`.  The transient of a particle run is compared through the same
exponential fit applied to both curves (:func:`fit_relaxation`).

:func:`switch_prediction` runs the ODE over the closure's stored parameter ensemble and returns
value/std/low/high bands of u(t) and of the steady velocity and e-folding time.

Example (a library from ``snakemake --cores 2``)::

    import granflow
    from granflow.closures import open_library
    from granflow.continuum import switch_prediction

    lib = open_library("results/default/closures.nc")
    pred = switch_prediction(lib, h=8.0, u0=0.9, theta=25.0, t_end=200.0,
                             allow_unidentified=True)     # friction may be 'unidentified'
    pred.u_bar.sel(stat="value").plot()
    float(pred.u_steady.sel(stat="value")), float(pred.tau.sel(stat="std"))
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr
from scipy import optimize
from scipy.integrate import solve_ivp

from .. import units as U
from .closures import FlowClosures
from .output import finish

#: right-hand-side evaluations after which the uniform-layer ODE is declared stalled (a smooth
#: law needs a few thousand for t_end = 400)
MAX_RHS_CALLS = 200_000

EQ = "Weinhart et al. 2012 Eq. (34) for a uniform layer: du/dt = g cos(theta) (tan(theta) - mu(h, F))"


def stall_guard(model: str, max_calls: int, t_end: float):
    """A counter for a right-hand side: call it with t on every evaluation; past ``max_calls``
    it raises RuntimeError.  A friction law with a jump inside the flow makes an implicit or
    adaptive solver chatter at the jump with ever smaller steps: stop with an error instead of
    running without end."""
    calls = [0]

    def count(t):
        calls[0] += 1
        if calls[0] > max_calls:
            raise RuntimeError(f"{model} stalled ({max_calls} evaluations before t = {t:.4g} "
                               f"of {t_end:g}): mu(h, F) jumps inside the flow")
    return count


def _check_inputs(h, u0, t_end):
    for name, v, lo in (("h", h, 0.0), ("t_end", t_end, 0.0)):
        if not (math.isfinite(v) and v > lo):
            raise ValueError(f"{name} = {v!r} is out of range: allowed ({lo}, inf)")
    if not math.isfinite(u0):
        raise ValueError(f"u0 = {u0!r} is out of range: allowed finite values")


def uniform_layer(closures: FlowClosures, h: float, u0: float, t_end: float, *,
                  n_out: int = 401, rtol: float = 1e-9, atol: float = 1e-12) -> xr.Dataset:
    """Depth-averaged velocity u(t) of a uniform layer of height ``h`` started at ``u0``.

    Returns a Dataset with ``u_bar`` and ``froude`` on ``t`` (``n_out`` points in [0, t_end]),
    the scalars ``u_steady`` (NaN when the layer arrests or accelerates), ``tau_linear``
    (:func:`linear_relaxation_time`) and ``t_rest`` (time the layer stopped, NaN if never).
    """
    h, u0, t_end = float(h), float(u0), float(t_end)
    _check_inputs(h, u0, t_end)
    gc = closures.g_cos

    stalled = stall_guard("uniform-layer ODE", MAX_RHS_CALLS, t_end)

    def rhs(t, y):
        stalled(t)
        return [float(closures.acceleration(h, y[0]))]

    mu0 = float(closures.mu(h, 0.0))
    holds = abs(closures.tan_theta) <= mu0

    def rest(t, y):
        return y[0]
    rest.terminal = True
    rest.direction = -np.sign(u0) if u0 != 0 else 0
    t_eval = np.linspace(0.0, t_end, int(n_out))
    events = [rest] if (holds and u0 != 0) else None
    if u0 == 0 and holds:
        sol_t, sol_u, t_rest = t_eval, np.zeros_like(t_eval), 0.0
    else:
        sol = solve_ivp(rhs, (0.0, t_end), [u0], method="LSODA", t_eval=t_eval, rtol=rtol,
                        atol=atol, events=events)
        if sol.status < 0:
            raise RuntimeError(f"uniform-layer ODE failed: {sol.message}")
        sol_t, sol_u = sol.t, sol.y[0]
        t_rest = math.nan
        if events and sol.t_events[0].size:
            t_rest = float(sol.t_events[0][0])
            sol_t = t_eval
            sol_u = np.interp(t_eval, sol.t, sol.y[0], right=0.0)
            sol_u[t_eval >= t_rest] = 0.0
    F_inf = closures.steady_froude(h)
    u_inf = F_inf * math.sqrt(gc * h) if math.isfinite(F_inf) else math.nan
    ds = xr.Dataset(
        {"u_bar": ("t", sol_u, U.cf(U.VELOCITY, "depth-averaged downslope velocity u_bar")),
         "froude": ("t", sol_u / math.sqrt(gc * h),
                    U.cf(U.DIMENSIONLESS, "Froude number u_bar / sqrt(g h cos(theta))")),
         "u_steady": ((), u_inf, U.cf(U.VELOCITY, "steady velocity: mu(h, F) = tan(theta)")),
         "tau_linear": ((), linear_relaxation_time(closures, h), U.cf(
             U.TIME, "e-folding time of the ODE linearised about the steady state")),
         "t_rest": ((), t_rest, U.cf(U.TIME, "time the layer came to rest (NaN: never)"))},
        coords={"t": ("t", sol_t, U.cf(U.TIME, "time since the change of inclination"))})
    ds.attrs.update(closures.attrs(), h=h, u0=u0, equation=EQ, solver="scipy solve_ivp LSODA",
                    rtol=rtol, atol=atol)
    return finish(ds, "uniform_layer", "uniform layer after a change of inclination",
                  "Depth-averaged velocity of a uniform granular layer (Weinhart et al. 2012 "
                  "Eq. 34 reduced to an ODE) with the basal friction of a closure library.")


def linear_relaxation_time(closures: FlowClosures, h: float, dF: float = 1e-6) -> float:
    """1 / (g cos(theta) dmu/du) at the steady state (NaN when there is none)."""
    F = closures.steady_froude(h)
    if not math.isfinite(F):
        return math.nan
    lo = max(F - dF, 0.0)
    dmu_dF = (float(closures.mu(h, F + dF)) - float(closures.mu(h, lo))) / (F + dF - lo)
    if not dmu_dF > 0:
        return math.nan
    return 1.0 / (math.sqrt(closures.g_cos / h) * dmu_dF)


def fit_relaxation(t, u, u0: float | None = None, *, t_max: float | None = None) -> dict:
    """Fit u(t) = u_inf + (u0 - u_inf) exp(-t / tau) to a transient (least squares).

    ``u0`` fixed when given (the pre-switch steady velocity), else fitted.  Returns u_inf, tau,
    their standard errors (covariance scaled by the residual variance), u0 and the rms residual.
    The same fit is applied to particle runs and to ODE solutions so that the compared
    e-folding times have one definition.
    """
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    m = np.isfinite(t) & np.isfinite(u) & (t >= 0)
    if t_max is not None:
        m &= t <= t_max
    t, u = t[m], u[m]
    if t.size < 5:
        raise ValueError(f"too few points for a relaxation fit: {t.size}")
    tail = u[t >= t[0] + 0.7 * (t[-1] - t[0])]
    u_inf0 = float(np.mean(tail))
    u_start = float(u[0]) if u0 is None else float(u0)
    # start value of tau: first crossing of 1/e of the way
    target = u_inf0 + (u_start - u_inf0) / math.e
    cross = np.nonzero(np.sign(u - target) != np.sign(u_start - target))[0]
    tau0 = float(t[cross[0]]) if cross.size and t[cross[0]] > 0 else 0.2 * (t[-1] - t[0])
    if u0 is None:
        def model(tt, a, b, c):
            return a + (c - a) * np.exp(-tt / b)
        p0 = [u_inf0, tau0, u_start]
        bounds = ([-np.inf, 1e-6, -np.inf], [np.inf, np.inf, np.inf])
    else:
        def model(tt, a, b):
            return a + (u_start - a) * np.exp(-tt / b)
        p0 = [u_inf0, tau0]
        bounds = ([-np.inf, 1e-6], [np.inf, np.inf])
    popt, pcov = optimize.curve_fit(model, t, u, p0=p0, bounds=bounds, maxfev=20000)
    se = np.sqrt(np.clip(np.diag(pcov), 0, None))
    resid = u - model(t, *popt)
    return {"u_inf": float(popt[0]), "u_inf_stderr": float(se[0]), "tau": float(popt[1]),
            "tau_stderr": float(se[1]), "u0": float(popt[2]) if u0 is None else u_start,
            "rms": float(np.sqrt(np.mean(resid ** 2))), "n": int(t.size)}


def _uniform_model():
    return uniform_layer, EQ


def _column_model():
    from .column import EQ as COLUMN_EQ, column_layer

    return column_layer, COLUMN_EQ


#: the layer models :func:`switch_prediction` runs (name -> (solver, equation))
_MODELS = {"uniform": _uniform_model, "column": _column_model}


def switch_prediction(lib_or_closures, h: float, u0: float, theta: float, t_end: float, *,
                      lam=None, contact_law=None, allow_unidentified: bool = False,
                      extrapolate: bool = False, uncertainty: bool = True,
                      n_ensemble: int | None = 100, n_out: int = 401,
                      fit_t_max: float | None = None, model: str = "uniform") -> xr.Dataset:
    """Prediction for a steady layer (height h, velocity u0) switched to inclination ``theta``.

    ``lib_or_closures``: a closure library (Dataset) or a :class:`FlowClosures` (its theta is
    replaced).  The inputs are checked with the library's evaluators first (fitted range and the
    fitted runs' (h, F) hull for the initial and the predicted steady Froude number; unless
    ``extrapolate``).  Returns ``u_bar(stat, t)``, ``u_steady(stat)``, ``tau(stat)`` (e-folding
    time of the exponential fit, :func:`fit_relaxation`, to the ODE solution over
    [0, ``fit_t_max``]) and ``tau_linear(stat)`` with ``stat`` = value (central parameters),
    std, low, high (16th/84th percentiles over the ensemble; NaN without ``uncertainty``).
    ``model``: ``"uniform"`` (the ODE, :func:`uniform_layer`) or ``"column"`` (the
    depth-resolved column of :mod:`granflow.continuum.column`, same closures, started from a
    Bagnold profile with depth average ``u0``).
    """
    if model not in _MODELS:
        raise ValueError(f"model = {model!r} is out of range: allowed {sorted(_MODELS)}")
    layer, equation = _MODELS[model]()
    if isinstance(lib_or_closures, FlowClosures):
        central = lib_or_closures.at(theta)
    else:
        central = FlowClosures.from_library(lib_or_closures, theta, lam, contact_law=contact_law,
                                            allow_unidentified=allow_unidentified)
    h, u0 = float(h), float(u0)
    _check_inputs(h, u0, float(t_end))
    F0 = u0 / math.sqrt(central.g_cos * h)
    F_inf = central.steady_froude(h)
    central.check(h, [F0] + ([F_inf] if math.isfinite(F_inf) else []), extrapolate=extrapolate)
    ens = central.ensemble(n_ensemble) if uncertainty else []
    members = [central] + list(ens)
    curves, u_st, taus, tl = [], [], [], []
    stalled = 0
    for k, c in enumerate(members):
        try:
            ds = layer(c, h, u0, t_end, n_out=n_out)
        except RuntimeError:
            if k == 0:
                raise
            stalled += 1  # this member is left out of the statistics (counted in the attributes)
            continue
        curves.append(ds.u_bar.values)
        u_st.append(float(ds.u_steady))
        tl.append(float(ds.tau_linear))
        try:
            taus.append(fit_relaxation(ds.t.values, ds.u_bar.values, u0, t_max=fit_t_max)["tau"]
                        if math.isfinite(float(ds.u_steady)) else math.nan)
        except (ValueError, RuntimeError):
            taus.append(math.nan)

    def stats(values):
        v = np.asarray(values, float)
        ens = v[1:]
        if ens.size < 2:
            nan = np.full(v.shape[1:], np.nan)
            return np.stack([v[0], nan, nan, nan])
        with np.errstate(invalid="ignore"):
            import warnings
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                lo, hi = np.nanpercentile(ens, [15.865, 84.135], axis=0)
                sd = np.nanstd(ens, axis=0, ddof=1)
        return np.stack([v[0], sd, lo, hi])

    stat = ["value", "std", "low", "high"]
    out = xr.Dataset(
        {"u_bar": (("stat", "t"), stats(curves), U.cf(U.VELOCITY, "depth-averaged velocity "
                                                       f"u_bar predicted by the {model} model")),
         "u_steady": ("stat", stats(u_st), U.cf(U.VELOCITY, "predicted steady velocity")),
         "tau": ("stat", stats(taus), U.cf(U.TIME, "predicted e-folding time (exponential fit "
                                                   f"to the {model} model's u_bar)")),
         "tau_linear": ("stat", stats(tl), U.cf(U.TIME, f"e-folding time of the linearised "
                                                        f"{model} model"))},
        coords={"t": ("t", np.linspace(0.0, float(t_end), int(n_out)),
                      U.cf(U.TIME, "time since the change of inclination")),
                "stat": ("stat", np.array(stat, dtype=object),
                         {"long_name": "statistic: value (central parameters), std, low/high "
                                       "(16th/84th percentile over the closure ensemble)"})})
    out.attrs.update(central.attrs(), h=h, u0=u0, froude0=F0, equation=equation,
                     continuum_layer_model=model,
                     n_ensemble=len(members) - 1 - stalled,
                     n_ensemble_dropped=int(getattr(ens, "ensemble_dropped", 0)) + stalled,
                     extrapolate=int(bool(extrapolate)),
                     uncertainty_method=f"{model} model solved for every stored parameter "
                                        "sample of the friction closure (joint hstop/flow-rule "
                                        "ensemble)")
    what = ("the uniform-layer ODE of Weinhart et al. 2012 Eq. 34" if model == "uniform" else
            "a depth-resolved column whose local friction is the library's mu(h, F)")
    return finish(out, f"{model}_layer_prediction", f"{model}-layer prediction after a change "
                  "of inclination", "Depth-averaged velocity after a change of inclination from "
                  f"{what} with the closure library's friction law, with its spread over the "
                  "library's parameter ensemble.")
