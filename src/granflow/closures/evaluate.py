"""Vectorised evaluation of the closures stored in a library, with their uncertainty.

All evaluators take the library Dataset (from :func:`granflow.closures.open_library`) first,
then the flow variables as scalars, numpy arrays or xarray DataArrays (DataArrays are broadcast
by dimension name and the result is a DataArray), then keyword options:

* ``lam`` -- basal roughness lambda, for the lambda-dependent closures (matched to the stored
  ``lambda`` coordinate within 1e-6); may be omitted when the library holds a single lambda;
* ``contact_law`` -- may be omitted when the library holds a single contact law;
* ``uncertainty`` -- False (default): the value only.  True: an :class:`xarray.Dataset` with
  ``value``, ``std`` (standard deviation over the closure's stored ensemble: bootstrap refits
  or covariance draws, so correlations between parameters and, for mu(h, F), between the hstop
  and flow-rule fits are carried) and ``low``/``high`` (16th/84th percentiles);
* ``extrapolate`` -- by default a ValueError is raised when an input lies outside the range of
  the data the closure was fitted to (stored ``<kind>_<var>_min/_max``), and, for closures of
  two inputs (froude(h, theta), mu(h, F), alpha(theta, h)), when the *combination* lies outside
  the region the fitted runs cover (their convex hull, widened by 10 % of each range): no run came
  near it.  True evaluates anyway;
* ``allow_unidentified`` -- a closure whose status is not ``ok`` or ``reduced`` (its parameters
  are not identified by the data, or held-out runs contradict it) raises ValueError naming the
  reason; True evaluates it anyway (for inspection, never for production use).

* ``impossible`` -- ``"raise"`` (default) refuses a physically impossible value (below);
  ``"nan"`` returns NaN there instead (e.g. to draw a curve over a range).

A reduced form (``<kind>_form``) is evaluated as stored: e.g. a linear bulk density over the
fitted range when the curvature of Eq. (52) is not identified.  An evaluation that is
physically impossible -- a negative or above-random-close-packing density, a negative stopping
height, a negative Froude number or friction, K <= 0, alpha < 1 -- is refused (ValueError), even
with ``extrapolate=True`` (unless ``impossible="nan"``).

=============================================  ==============================================
evaluator                                      closure
=============================================  ==============================================
hstop(lib, theta, lam)                         Eq. (45), d = 1 (inf below delta1, 0 above delta2)
froude(lib, h, theta, lam)                     Eq. (47) with hstop(theta; 1)
mu(lib, h, F, lam)                             Eq. (50)
alpha(lib, theta, h, lam)                      Eq. (54) (d_lambda) or constant (Eq. 55)
K(lib, theta)                                  Eq. (53)
density(lib, theta)                            Eq. (52), bulk density rho_c in m d-3
Ps(lib, sigma)                                 T-eq. (29)
mu_I(lib, I)                                   seed 001 Eq. (2.13)
diffusivity(lib, u_bar, h, d_mean)             D = c_D (u_bar/h) d^2 (self-diffusion in z)
=============================================  ==============================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import xarray as xr

from .. import units as U
from ..fitting.bulk import density_eq52, stress_ratio_eq53
from ..fitting.flow_rule import mu_eq50
from ..fitting.hstop import hstop_eq45
from ..fitting.rheology import mu_of_I
from ..fitting.segregation import Ps_teq29
from ..fitting.shape_factor import alpha_eq54
from ..units import RHO_PARTICLE
from .schema import CAMPAIGN_PREFIX, CONTACT_LAW_DIM, KINDS, LAMBDA_DIM

_LAM_TOL = 1e-6
#: random close packing: a bulk volume fraction above it is refused
MAX_VOLUME_FRACTION = 0.74
#: widening of the fitted runs' convex hull about its centroid (fraction) for joint checks
HULL_MARGIN = 0.10


@dataclass
class Closure:
    """One stored closure cell: parameters, form, status, ensemble and where it lives."""

    kind: str
    params: dict
    form: str
    status: str
    sel: dict
    ensemble: list

    def samples(self, names):
        """Ensemble rows (as dicts) whose ``names`` are all finite."""
        return [e for e in self.ensemble if all(math.isfinite(e[n]) for n in names)]


def _resolve_contact_law(lib, contact_law):
    if CONTACT_LAW_DIM not in lib.coords:
        raise ValueError("library has no contact_law coordinate")
    laws = [str(x) for x in lib[CONTACT_LAW_DIM].values]
    if contact_law is None:
        if len(laws) != 1:
            raise ValueError(f"library holds several contact laws {laws}; pass contact_law=")
        return laws[0]
    if contact_law not in laws:
        raise ValueError(f"contact law {contact_law!r} not in library (has {laws})")
    return contact_law


def _selection(lib, kind, lam=None, contact_law=None):
    if f"{kind}_ok" not in lib:
        raise ValueError(f"library has no {kind} closure")
    sel = {CONTACT_LAW_DIM: _resolve_contact_law(lib, contact_law)}
    if LAMBDA_DIM in KINDS[kind].dims:
        lams = np.asarray(lib[LAMBDA_DIM].values, dtype=float)
        if lam is None:
            if lams.size != 1:
                raise ValueError(f"{kind} depends on the basal roughness and the library holds "
                                 f"several lambda {lams.tolist()}: pass lam=")
            lam = float(lams[0])
        hit = np.flatnonzero(np.abs(lams - float(lam)) <= _LAM_TOL)
        if hit.size == 0:
            raise ValueError(f"no closures for lambda = {lam} (library has {lams.tolist()})")
        sel[LAMBDA_DIM] = int(hit[0])
    return sel


def _cell(lib, name, sel):
    idx = {k: v for k, v in sel.items() if k in lib[name].dims}
    label = {k: v for k, v in idx.items() if isinstance(v, str)}
    pos = {k: v for k, v in idx.items() if not isinstance(v, str)}
    da = lib[name].sel(label) if label else lib[name]
    return da.isel(pos) if pos else da


def _scalar(lib, name, sel):
    return _cell(lib, name, sel).item()


def _closure(lib, kind, lam=None, contact_law=None, allow_unidentified=False) -> Closure:
    sel = _selection(lib, kind, lam, contact_law)
    status = str(_scalar(lib, f"{kind}_status", sel)) if f"{kind}_status" in lib else (
        "ok" if int(_scalar(lib, f"{kind}_ok", sel)) else "failed")
    if status == "failed" or (status not in ("ok", "reduced") and not allow_unidentified):
        reasons = []
        for p in KINDS[kind].params:
            name = f"{kind}_{p}_status"
            if name in lib and str(_scalar(lib, name, sel)) == "unidentified":
                reasons.append(f"{p}: {_scalar(lib, f'{kind}_{p}_reason', sel)}")
        detail = "; ".join(reasons) or str(_scalar(lib, f"{kind}_message", sel))
        hint = "" if status == "failed" else " (pass allow_unidentified=True to inspect it anyway)"
        raise ValueError(f"{kind} closure (lambda={lam}, contact_law={sel[CONTACT_LAW_DIM]}) is "
                         f"{status}: {detail}{hint}")
    params = {p: float(_scalar(lib, f"{kind}_{p}", sel)) for p in KINDS[kind].params}
    form = str(_scalar(lib, f"{kind}_form", sel)) if f"{kind}_form" in lib else "full"
    ens = []
    names = list(KINDS[kind].params)
    cols = [f"{kind}_ensemble_{p}" for p in names]
    if all(c in lib for c in cols):
        arr = np.stack([np.asarray(_cell(lib, c, sel).values, dtype=float) for c in cols], axis=-1)
        for row in arr.reshape(-1, len(names)):
            if np.isfinite(row).any():
                ens.append(dict(zip(names, map(float, row))))
    return Closure(kind, params, form, status, sel, ens)


def closure_parameters(lib, kind, lam=None, contact_law=None, *,
                       allow_unidentified=False) -> Closure:
    """The stored cell of one closure: parameters, form, status and parameter ensemble.

    For consumers that evaluate a closure many times with the same parameters (the continuum
    models of :mod:`granflow.continuum`), after checking their inputs once with the evaluators
    above.  Refuses a closure that is not ``ok``/``reduced`` exactly like the evaluators
    (``allow_unidentified=True`` to inspect it).
    """
    return _closure(lib, kind, lam, contact_law, allow_unidentified)


def _check_range(lib, kind, var, values, sel, extrapolate):
    if extrapolate:
        return
    lo_name, hi_name = f"{kind}_{var}_min", f"{kind}_{var}_max"
    if lo_name not in lib:
        return
    lo, hi = float(_scalar(lib, lo_name, sel)), float(_scalar(lib, hi_name, sel))
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    tol = 1e-9 * max(1.0, abs(lo), abs(hi))
    if v.size and (v.min() < lo - tol or v.max() > hi + tol):
        raise ValueError(f"{var} in [{v.min():.6g}, {v.max():.6g}] is outside the fitted range "
                         f"[{lo:.6g}, {hi:.6g}] of the {kind} closure; pass extrapolate=True "
                         f"to evaluate anyway")


def support_points(lib, kind, variables, sel):
    """(n, len(variables)) values of the runs that entered ``kind`` at this cell, or None."""
    used = f"{CAMPAIGN_PREFIX}used_by_{kind}"
    if used not in lib:
        return None
    mask = np.asarray(lib[used].values, dtype=bool)
    if LAMBDA_DIM in sel and f"{CAMPAIGN_PREFIX}lam" in lib:
        lam = float(lib[LAMBDA_DIM].values[sel[LAMBDA_DIM]])
        mask &= np.abs(np.asarray(lib[f"{CAMPAIGN_PREFIX}lam"].values, float) - lam) <= _LAM_TOL
    if f"{CAMPAIGN_PREFIX}contact_law" in lib:
        mask &= np.asarray(lib[f"{CAMPAIGN_PREFIX}contact_law"].values).astype(str) == \
            sel[CONTACT_LAW_DIM]
    cols = []
    for v in variables:
        name = f"{CAMPAIGN_PREFIX}{v}"
        if name not in lib:
            return None
        cols.append(np.asarray(lib[name].values, dtype=float)[mask])
    pts = np.column_stack(cols) if cols else None
    return pts[np.all(np.isfinite(pts), axis=1)] if pts is not None else None


def _check_joint(lib, kind, names, vals, sel, extrapolate):
    """Refuse input combinations outside the fitted runs' widened convex hull."""
    if extrapolate:
        return
    pts = support_points(lib, kind, names, sel)
    if pts is None or len(pts) < 3:
        return
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    scale = np.where(hi > lo, hi - lo, 1.0)
    q = (pts - lo) / scale
    x = np.column_stack([np.asarray(v, dtype=float).ravel() for v in vals])
    x = x[np.all(np.isfinite(x), axis=1)]
    if not x.size:
        return
    xq = (x - lo) / scale
    from scipy.spatial import Delaunay, QhullError

    c = q.mean(axis=0)
    try:
        hull = Delaunay(c + (q - c) * (1.0 + HULL_MARGIN))
    except (QhullError, ValueError):
        return  # collinear support (a single theta, say): the per-variable ranges apply
    outside = hull.find_simplex(xq) < 0
    if outside.any():
        bad = x[outside][0]
        raise ValueError(
            f"({', '.join(f'{n} = {v:.4g}' for n, v in zip(names, bad))}) lies outside the "
            f"region of ({', '.join(names)}) covered by the runs the {kind} closure was fitted "
            "to (each value may be inside its own range, but no run came near this "
            "combination); pass extrapolate=True to evaluate anyway")


def _inputs(arrays):
    """Broadcast inputs; returns (numpy values, DataArray template or None)."""
    if any(isinstance(a, xr.DataArray) for a in arrays):
        das = xr.broadcast(*[a if isinstance(a, xr.DataArray) else xr.DataArray(a)
                             for a in arrays])
        return [np.asarray(d.values, dtype=float) for d in das], das[0]
    return list(np.broadcast_arrays(*[np.asarray(a, dtype=float) for a in arrays])), None


def _wrap(arr, template, attrs):
    arr = np.asarray(arr, dtype=float)
    if template is not None:
        return xr.DataArray(arr, dims=template.dims, coords=template.coords, attrs=attrs)
    return arr[()] if arr.ndim == 0 else arr


def _evaluate(lib, c: Closure, model, inputs: dict, *, extrapolate, uncertainty, physical,
              free, units, long_name, joint=None, impossible="raise"):
    names = list(inputs)
    vals, template = _inputs(list(inputs.values()))
    for n, v in zip(names, vals):
        _check_range(lib, c.kind, n, v, c.sel, extrapolate)
    if joint:
        _check_joint(lib, c.kind, names, vals, c.sel, extrapolate)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        value = np.asarray(model(c.params, *vals), dtype=float)
    bad = physical(value)
    if impossible not in ("raise", "nan"):
        raise ValueError(f"impossible = {impossible!r}: allowed 'raise' or 'nan'")
    if np.any(bad) and impossible == "nan":
        value = np.where(bad, np.nan, value)
    elif np.any(bad):
        v = value[bad] if value.ndim else value
        where = ", ".join(f"{n} = {np.asarray(x)[bad].ravel()[0] if np.ndim(x) else x:.4g}"
                          for n, x in zip(names, vals))
        raise ValueError(f"the {c.kind} closure gives a physically impossible {long_name} "
                         f"{np.ravel(v)[0]:.4g} at {where}: refused")
    attrs = U.cf(units, long_name, closure_kind=c.kind, closure_status=c.status,
                 closure_form=c.form)
    if not uncertainty:
        return _wrap(value, template, attrs)
    rows = c.samples(free)
    if len(rows) < 10:
        raise ValueError(f"the {c.kind} closure stores no usable ensemble ({len(rows)} samples)")
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        samples = np.stack([np.asarray(model(p, *vals), dtype=float) for p in rows])
    finite = np.where(np.isfinite(samples) & ~physical(samples), samples, np.nan)
    if np.ndim(value):
        finite[:, ~np.isfinite(value)] = np.nan
    std = np.nanstd(finite, axis=0, ddof=1)
    lo, hi = np.nanpercentile(finite, [15.865, 84.135], axis=0)
    dims = template.dims if template is not None else tuple(f"dim_{i}" for i in
                                                            range(value.ndim))
    coords = template.coords if template is not None else None
    ds = xr.Dataset(
        {"value": (dims, value, attrs),
         "std": (dims, std, U.cf(units, f"standard deviation of {long_name} over the closure's "
                                 f"ensemble ({len(rows)} samples)")),
         "low": (dims, lo, U.cf(units, f"16th percentile of {long_name} over the ensemble")),
         "high": (dims, hi, U.cf(units, f"84th percentile of {long_name} over the ensemble"))},
        coords=coords)
    ds.attrs.update(closure_kind=c.kind, closure_status=c.status, closure_form=c.form,
                    n_ensemble=len(rows),
                    uncertainty_method="parameter ensemble stored in the library (bootstrap "
                                       "refits or covariance draws) propagated through the "
                                       "closure")
    return ds


def _never(value):
    return np.zeros(np.shape(value), dtype=bool)


def _negative(value):
    return np.isfinite(value) & (value < 0)


# ---------------------------------------------------------------------------- evaluators
def hstop(lib, theta, lam=None, *, contact_law=None, extrapolate=False, uncertainty=False,
          allow_unidentified=False, impossible="raise"):
    """Eq. (45) stopping height hstop(theta; lambda) (d = 1), theta in degrees."""
    c = _closure(lib, "hstop", lam, contact_law, allow_unidentified)
    return _evaluate(lib, c, lambda p, th: hstop_eq45(th, p["delta1"], p["delta2"], p["A"]),
                     {"theta": theta}, extrapolate=extrapolate, uncertainty=uncertainty, impossible=impossible,
                     physical=_negative, free=("delta1", "delta2", "A"), units=U.LENGTH,
                     long_name="stopping height hstop")


def _hstop_params(lib, law, allow_unidentified):
    return _closure(lib, "hstop", 1.0, law, allow_unidentified)


def froude(lib, h, theta, lam=None, *, contact_law=None, extrapolate=False, uncertainty=False,
           allow_unidentified=False, impossible="raise"):
    """Eq. (47) Froude number of steady flow F = beta h/hstop(theta; 1) - gamma.

    The uncertainty joins the friction closure's ensemble (hstop refits paired with the flow
    rule's joint bootstrap) when the library has it, else the flow rule's alone."""
    c = _closure(lib, "flow_rule", lam, contact_law, allow_unidentified)
    law = c.sel[CONTACT_LAW_DIM]
    fr = _closure(lib, "friction", lam, law, True) if "friction_ok" in lib else None
    hs = _hstop_params(lib, law, allow_unidentified or c.status in ("ok", "reduced"))
    params = dict(c.params)
    params.update({k: hs.params[k] for k in ("delta1", "delta2", "A")})
    ens = fr.ensemble if fr is not None and fr.ensemble else [
        dict(e, **{k: hs.params[k] for k in ("delta1", "delta2", "A")}) for e in c.ensemble]
    joint = Closure("flow_rule", params, c.form, c.status, c.sel, ens)

    def model(p, hh, th):
        return p["beta"] * hh / np.asarray(hstop_eq45(th, p["delta1"], p["delta2"], p["A"]),
                                           dtype=float) - p["gamma"]
    return _evaluate(lib, joint, model, {"h": h, "theta": theta}, extrapolate=extrapolate,
                     uncertainty=uncertainty, impossible=impossible, physical=_negative,
                     free=("beta", "gamma", "delta1", "delta2", "A"), units=U.DIMENSIONLESS,
                     long_name="Froude number of steady flow", joint=True)


def mu(lib, h, F, lam=None, *, contact_law=None, extrapolate=False, uncertainty=False,
       allow_unidentified=False, impossible="raise"):
    """Eq. (50) basal friction mu(h, F; lambda) (stored ``friction`` closure)."""
    c = _closure(lib, "friction", lam, contact_law, allow_unidentified)

    def model(p, hh, FF):
        return mu_eq50(hh, FF, p["delta1"], p["delta2"], p["A"], p["beta"], p["gamma"])
    return _evaluate(lib, c, model, {"h": h, "F": F}, extrapolate=extrapolate,
                     uncertainty=uncertainty, impossible=impossible, physical=_negative,
                     free=("delta1", "delta2", "A", "beta", "gamma"), units=U.DIMENSIONLESS,
                     long_name="basal friction coefficient mu", joint=True)


def alpha(lib, theta, h, lam=None, *, contact_law=None, extrapolate=False, uncertainty=False,
          allow_unidentified=False, impossible="raise"):
    """Shape factor: constant alpha(lambda) (Eq. 55 or the reduced form) or the Eq. (54)
    basal-layer model."""
    c = _closure(lib, "alpha", lam, contact_law, allow_unidentified)
    if math.isfinite(c.params["alpha_constant"]) and not math.isfinite(c.params["d_lambda"]):
        def model(p, th, hh):
            return np.full(np.broadcast(th, hh).shape, p["alpha_constant"])
        free = ("alpha_constant",)
    else:
        hs = _hstop_params(lib, c.sel[CONTACT_LAW_DIM], True)
        hp = {k: hs.params[k] for k in ("delta1", "delta2", "A")}

        def model(p, th, hh):
            return alpha_eq54(hh, hstop_eq45(th, **hp), p["d_lambda"])
        free = ("d_lambda",)
    return _evaluate(lib, c, model, {"theta": theta, "h": h}, extrapolate=extrapolate,
                     uncertainty=uncertainty, impossible=impossible,
                     physical=lambda v: np.isfinite(v) & (v < 1.0 - 1e-9), free=free,
                     units=U.DIMENSIONLESS, long_name="velocity shape factor alpha", joint=True)


def K(lib, theta, *, contact_law=None, extrapolate=False, uncertainty=False,
      allow_unidentified=False, impossible="raise"):
    """Eq. (53) normal stress ratio K(theta), theta in degrees (or the constant reduced form)."""
    c = _closure(lib, "stress_ratio", None, contact_law, allow_unidentified)
    if c.form == "constant":
        def model(p, th):
            return np.full(np.shape(th), p["K_ref"])
        free = ("K_ref",)
    else:
        def model(p, th):
            return stress_ratio_eq53(th, p["d0"], p["d1"])
        free = ("d0", "d1")
    return _evaluate(lib, c, model, {"theta": theta}, extrapolate=extrapolate,
                     uncertainty=uncertainty, impossible=impossible, physical=lambda v: np.isfinite(v) & (v <= 0),
                     free=free, units=U.DIMENSIONLESS, long_name="normal stress ratio K")


def density(lib, theta, *, contact_law=None, extrapolate=False, uncertainty=False,
            allow_unidentified=False, impossible="raise", rho_p: float = RHO_PARTICLE):
    """Eq. (52) bulk density rho_c(theta) in m d-3 (divide by rho_p for the volume fraction),
    or its stored reduced form (linear or constant volume fraction over the fitted range)."""
    c = _closure(lib, "density", None, contact_law, allow_unidentified)
    theta_ref = (float(_scalar(lib, "density_theta_ref", c.sel))
                 if "density_theta_ref" in lib else math.nan)
    if c.form == "linear":
        def model(p, th):
            return rho_p * (p["nu_ref"] + p["dnu_dtheta"] * (th - theta_ref))
        free = ("nu_ref", "dnu_dtheta")
    elif c.form == "constant":
        def model(p, th):
            return np.full(np.shape(th), rho_p * p["nu_ref"])
        free = ("nu_ref",)
    else:
        def model(p, th):
            return density_eq52(th, p["c0"], p["c1"], p["c2"], rho_p=rho_p)
        free = ("c0", "c1", "c2")
    return _evaluate(lib, c, model, {"theta": theta}, extrapolate=extrapolate,
                     uncertainty=uncertainty, impossible=impossible,
                     physical=lambda v: np.isfinite(v) & ((v <= 0) |
                                                          (v > MAX_VOLUME_FRACTION * rho_p)),
                     free=free, units=U.DENSITY, long_name="bulk density rho_c")


def Ps(lib, sigma, *, contact_law=None, extrapolate=False, uncertainty=False,
       allow_unidentified=False, impossible="raise"):
    """T-eq. (29) segregation Peclet number Ps(sigma), sigma = d_small/d_large (or a reduced
    form over the fitted range: linear, Ps = slope (1/sigma - 1), or saturated, Ps = Pmax)."""
    c = _closure(lib, "Ps_law", None, contact_law, allow_unidentified)
    if c.form == "linear":
        def model(p, s):
            return p["slope"] * (1.0 / s - 1.0)
        free = ("slope",)
    elif c.form == "plateau":
        def model(p, s):
            return p["Pmax"] * np.ones_like(np.asarray(s, dtype=float))
        free = ("Pmax",)
    else:
        def model(p, s):
            return Ps_teq29(s, p["Pmax"], p["k"])
        free = ("Pmax", "k")
    return _evaluate(lib, c, model, {"sigma": sigma}, extrapolate=extrapolate,
                     uncertainty=uncertainty, impossible=impossible, physical=_never, free=free,
                     units=U.DIMENSIONLESS, long_name="segregation Peclet number Ps")


def mu_I(lib, I, *, contact_law=None, extrapolate=False, uncertainty=False,
         allow_unidentified=False, impossible="raise"):
    """mu(I) rheology, seed 001 Eq. (2.13)."""
    c = _closure(lib, "mu_I", None, contact_law, allow_unidentified)
    return _evaluate(lib, c, lambda p, i: mu_of_I(i, p["mu_s"], p["mu_d"], p["I0"]), {"I": I},
                     extrapolate=extrapolate, uncertainty=uncertainty, impossible=impossible, physical=_negative,
                     free=("mu_s", "mu_d", "I0"), units=U.DIMENSIONLESS,
                     long_name="local friction mu(I)")


def diffusivity(lib, u_bar, h, *, d_mean=1.0, contact_law=None, extrapolate=False,
                uncertainty=False, allow_unidentified=False, impossible="raise"):
    """Self-diffusivity normal to the base D = c_D (u_bar/h) d_mean^2 (library kind
    ``diffusivity``; :mod:`granflow.coarse.diffusion`), e.g. for T-eq. (27).  ``d_mean``: the
    mean particle diameter of the flow (volume-weighted for a mixture)."""
    c = _closure(lib, "diffusivity", None, contact_law, allow_unidentified)
    dm = np.asarray(d_mean, dtype=float)
    return _evaluate(lib, c, lambda p, uu, hh: p["c_D"] * uu / hh * dm ** 2,
                     {"u_bar": u_bar, "h": h}, extrapolate=extrapolate, uncertainty=uncertainty,
                     impossible=impossible, physical=_negative, free=("c_D",),
                     units=U.DIFFUSIVITY, long_name="self-diffusivity D normal to the base")


def closure_status(lib) -> "pd.DataFrame":
    """One row per stored closure cell and parameter: value, stderr, status and reason."""
    import pandas as pd

    rows = []
    for kind, spec in KINDS.items():
        if f"{kind}_ok" not in lib:
            continue
        da = lib[f"{kind}_ok"]
        for idx in np.ndindex(da.shape):
            cell = dict(zip(da.dims, idx))
            coords = {d: lib[d].values[i] for d, i in cell.items()}
            for p in spec.params:
                st = str(lib[f"{kind}_{p}_status"].values[idx]) if \
                    f"{kind}_{p}_status" in lib else ""
                if st == "not_in_form":
                    continue
                rows.append({"kind": kind, **{str(k): (str(v) if isinstance(v, (str, bytes))
                                                        else float(v)) for k, v in coords.items()},
                             "parameter": p, "value": float(lib[f"{kind}_{p}"].values[idx]),
                             "stderr": float(lib[f"{kind}_{p}_stderr"].values[idx]),
                             "parameter_status": st,
                             "reason": str(lib[f"{kind}_{p}_reason"].values[idx])
                             if f"{kind}_{p}_reason" in lib else "",
                             "status": str(lib[f"{kind}_status"].values[idx])
                             if f"{kind}_status" in lib else "",
                             "form": str(lib[f"{kind}_form"].values[idx])
                             if f"{kind}_form" in lib else ""})
    return pd.DataFrame(rows)


@xr.register_dataset_accessor("closures")
class ClosuresAccessor:
    """``ds.closures.mu(h, F)`` etc. on a library Dataset (same signatures, lib implied)."""

    def __init__(self, ds: xr.Dataset):
        self._ds = ds

    def hstop(self, theta, lam=None, **kw):
        return hstop(self._ds, theta, lam, **kw)

    def froude(self, h, theta, lam=None, **kw):
        return froude(self._ds, h, theta, lam, **kw)

    def mu(self, h, F, lam=None, **kw):
        return mu(self._ds, h, F, lam, **kw)

    def alpha(self, theta, h, lam=None, **kw):
        return alpha(self._ds, theta, h, lam, **kw)

    def K(self, theta, **kw):
        return K(self._ds, theta, **kw)

    def density(self, theta, **kw):
        return density(self._ds, theta, **kw)

    def Ps(self, sigma, **kw):
        return Ps(self._ds, sigma, **kw)

    def mu_I(self, I, **kw):
        return mu_I(self._ds, I, **kw)

    def diffusivity(self, u_bar, h, **kw):
        return diffusivity(self._ds, u_bar, h, **kw)

    def status(self):
        return closure_status(self._ds)

    def campaign_table(self):
        from .library import campaign_table
        return campaign_table(self._ds)
