"""Vectorised evaluation of the closures stored in a library.

All evaluators take the library Dataset (from :func:`granflow.closures.open_library`) first,
then the flow variables as scalars, numpy arrays or xarray DataArrays (DataArrays are broadcast
by dimension name and the result is a DataArray), then keyword options:

* ``lam`` -- basal roughness lambda, for the lambda-dependent closures (matched to the stored
  ``lambda`` coordinate within 1e-6); may be omitted when the library holds a single lambda;
* ``contact_law`` -- may be omitted when the library holds a single contact law;
* ``extrapolate`` -- by default a ValueError is raised when any input lies outside the range of
  the data the closure was fitted to (stored ``<kind>_<var>_min/_max``); True evaluates anyway.

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
=============================================  ==============================================

A closure whose fit failed (``<kind>_ok == 0``) raises ValueError.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from ..fitting.bulk import density_eq52, stress_ratio_eq53
from ..fitting.flow_rule import mu_eq50
from ..fitting.hstop import hstop_eq45
from ..fitting.rheology import mu_of_I
from ..fitting.segregation import Ps_teq29
from ..fitting.shape_factor import alpha_eq54
from ..units import RHO_PARTICLE
from .schema import CONTACT_LAW_DIM, KINDS, LAMBDA_DIM

_LAM_TOL = 1e-6


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
        lams = lib[LAMBDA_DIM].values
        if lam is None:  # like contact_law: may be omitted when the library holds one lambda
            if lams.size != 1:
                raise ValueError(f"{kind} depends on the basal roughness and the library holds "
                                 f"several lambda {lams.tolist()}: pass lam=")
            lam = float(lams[0])
        hit = np.flatnonzero(np.abs(lams - float(lam)) <= _LAM_TOL)
        if hit.size == 0:
            raise ValueError(f"no closures for lambda = {lam} (library has {lams.tolist()})")
        sel[LAMBDA_DIM] = int(hit[0])
    return sel


def _scalar(lib, name, sel):
    idx = {k: v for k, v in sel.items() if k in lib[name].dims}
    label = {k: v for k, v in idx.items() if isinstance(v, str)}
    pos = {k: v for k, v in idx.items() if not isinstance(v, str)}
    da = lib[name].sel(label) if label else lib[name]
    return da.isel(pos).item() if pos else da.item()


def _params(lib, kind, lam=None, contact_law=None):
    sel = _selection(lib, kind, lam, contact_law)
    if not int(_scalar(lib, f"{kind}_ok", sel)):
        raise ValueError(f"{kind} closure (lambda={lam}, contact_law={sel[CONTACT_LAW_DIM]}) was "
                         f"not fitted: {_scalar(lib, f'{kind}_message', sel)}")
    return {p: float(_scalar(lib, f"{kind}_{p}", sel)) for p in KINDS[kind].params}, sel


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


def _apply(func, *args):
    """Call func on numpy arrays; with any DataArray input, broadcast by dims via apply_ufunc."""
    if any(isinstance(a, xr.DataArray) for a in args):
        return xr.apply_ufunc(func, *args)
    out = func(*[np.asarray(a, dtype=float) for a in args])
    return out[()] if np.ndim(out) == 0 else out


# ---------------------------------------------------------------------------- evaluators
def hstop(lib, theta, lam=None, *, contact_law=None, extrapolate=False):
    """Eq. (45) stopping height hstop(theta; lambda) (d = 1), theta in degrees."""
    p, sel = _params(lib, "hstop", lam, contact_law)

    def f(th):
        _check_range(lib, "hstop", "theta", th, sel, extrapolate)
        return np.asarray(hstop_eq45(th, **p), dtype=float)
    return _apply(f, theta)


def froude(lib, h, theta, lam=None, *, contact_law=None, extrapolate=False):
    """Eq. (47) Froude number of steady flow F = beta h/hstop(theta; 1) - gamma."""
    fr, sel = _params(lib, "flow_rule", lam, contact_law)
    hs, _ = _params(lib, "hstop", 1.0, sel[CONTACT_LAW_DIM])

    def f(hh, th):
        _check_range(lib, "flow_rule", "h", hh, sel, extrapolate)
        _check_range(lib, "flow_rule", "theta", th, sel, extrapolate)
        return fr["beta"] * hh / np.asarray(hstop_eq45(th, **hs), dtype=float) - fr["gamma"]
    return _apply(f, h, theta)


def mu(lib, h, F, lam=None, *, contact_law=None, extrapolate=False):
    """Eq. (50) basal friction mu(h, F; lambda).

    Uses the stored ``friction`` closure at ``lam`` when present, otherwise composes delta1,
    delta2, A of hstop(lambda = 1) with beta, gamma of the ``flow_rule`` at ``lam``.
    """
    try:
        p, sel = _params(lib, "friction", lam, contact_law)
        kind = "friction"
    except ValueError:
        fr, sel = _params(lib, "flow_rule", lam, contact_law)
        hs, _ = _params(lib, "hstop", 1.0, sel[CONTACT_LAW_DIM])
        p = {**{k: hs[k] for k in ("delta1", "delta2", "A")}, **fr}
        kind = "flow_rule"

    def f(hh, FF):
        _check_range(lib, kind, "h", hh, sel, extrapolate)
        _check_range(lib, kind, "F", FF, sel, extrapolate)
        return np.asarray(mu_eq50(hh, FF, **p), dtype=float)
    return _apply(f, h, F)


def alpha(lib, theta, h, lam=None, *, contact_law=None, extrapolate=False):
    """Shape factor: constant alpha(lambda) (Eq. 55) or the Eq. (54) basal-layer model."""
    p, sel = _params(lib, "alpha", lam, contact_law)
    constant = p["alpha_constant"]
    hs = None
    if not math.isfinite(constant):
        hs, _ = _params(lib, "hstop", 1.0, sel[CONTACT_LAW_DIM])

    def f(th, hh):
        _check_range(lib, "alpha", "theta", th, sel, extrapolate)
        _check_range(lib, "alpha", "h", hh, sel, extrapolate)
        th, hh = np.broadcast_arrays(np.asarray(th, float), np.asarray(hh, float))
        if hs is None:
            return np.full(th.shape, constant)
        return np.asarray(alpha_eq54(hh, hstop_eq45(th, **hs), p["d_lambda"]), dtype=float)
    return _apply(f, theta, h)


def K(lib, theta, *, contact_law=None, extrapolate=False):
    """Eq. (53) normal stress ratio K(theta), theta in degrees."""
    p, sel = _params(lib, "stress_ratio", None, contact_law)

    def f(th):
        _check_range(lib, "stress_ratio", "theta", th, sel, extrapolate)
        return np.asarray(stress_ratio_eq53(th, **p), dtype=float)
    return _apply(f, theta)


def density(lib, theta, *, contact_law=None, extrapolate=False, rho_p: float = RHO_PARTICLE):
    """Eq. (52) bulk density rho_c(theta) in m d-3 (divide by rho_p for the volume fraction)."""
    p, sel = _params(lib, "density", None, contact_law)

    def f(th):
        _check_range(lib, "density", "theta", th, sel, extrapolate)
        return np.asarray(density_eq52(th, rho_p=rho_p, **p), dtype=float)
    return _apply(f, theta)


def Ps(lib, sigma, *, contact_law=None, extrapolate=False):
    """T-eq. (29) segregation Peclet number Ps(sigma), sigma = d_small/d_large."""
    p, sel = _params(lib, "Ps_law", None, contact_law)

    def f(s):
        _check_range(lib, "Ps_law", "sigma", s, sel, extrapolate)
        return np.asarray(Ps_teq29(s, **p), dtype=float)
    return _apply(f, sigma)


def mu_I(lib, I, *, contact_law=None, extrapolate=False):
    """mu(I) rheology, seed 001 Eq. (2.13)."""
    p, sel = _params(lib, "mu_I", None, contact_law)

    def f(i):
        _check_range(lib, "mu_I", "I", i, sel, extrapolate)
        return np.asarray(mu_of_I(i, **p), dtype=float)
    return _apply(f, I)


@xr.register_dataset_accessor("closures")
class ClosuresAccessor:
    """``ds.closures.mu(h, F, lam=1)`` etc. on a library Dataset (same signatures, lib implied)."""

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

    def campaign_table(self):
        from .library import campaign_table
        return campaign_table(self._ds)
