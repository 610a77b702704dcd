"""Quantities derived from coarse-grained depth profiles: flow height, depth averages, rheology.

Implements Weinhart et al. (2012):

* Eq. (42): base b and surface s from the normal-stress profile.  With kappa = 1 %,
  z1 = min{z : sigma_zz < (1 - kappa) max sigma_zz}, z2 = max{z : sigma_zz > kappa max sigma_zz},
  b = z1 - kappa/(1 - 2 kappa) (z2 - z1), s = z2 + kappa/(1 - 2 kappa) (z2 - z1), h = s - b.
  z1 and z2 are located to sub-grid accuracy by linear interpolation between grid points, and
  the search for z1 starts at the maximum of sigma_zz.
* Eq. (33): depth averages (1/h) int_b^s () dz (trapezoid rule on the grid, end values linearly
  interpolated): rho_bar, u_bar (of the velocity V_x = p_x/rho), shape factor
  alpha = mean(u^2)/u_bar^2 (Thornton T-eq. 21), stress ratio K = sigma_xx_bar / sigma_zz_bar,
  friction mu_bar = -sigma_xz_bar / sigma_zz_bar, Froude number F = u_bar / sqrt(g cos(theta) h).
* Eq. (51): bulk density rho_c = mean of rho over [b + 2 d, s - 4 d].
* Local rheology (Jop/Forterre; 001 Eq. 2.13): friction mu(z) = -sigma_xz / sigma_zz (stresses are
  compressive positive, so sigma_xz < 0 for flow down +x and mu > 0), shear rate du/dz and
  inertial number I = (du/dz) d / sqrt(sigma_zz / rho_p), rho_p = 6/pi.

When the profile dataset carries per-window profiles (``<name>_window``, dim ``time_window``),
every quantity is also computed per window and its spread reported as ``<name>_std`` (standard
deviation over windows, ddof = 1; windows with fewer than half the snapshots of the fullest
window are ignored), and the standard error of the run's mean as ``<name>_sem`` = sqrt(g var/N)
over the N window values with their statistical inefficiency g (batch means; the uncertainty a
fit should give the run).  ``_sem`` is the within-run part only: runs with other seeds scatter
more than one run's windows show, above all near hstop and in small boxes.
"""

from __future__ import annotations

import math
import warnings
from typing import Mapping

import numpy as np
import xarray as xr

from .. import units as U

KAPPA = 0.01

_SCALAR_ATTRS = {
    "base": U.cf(U.LENGTH, "flow base b (stress extrapolation, Eq. 42)"),
    "surface": U.cf(U.LENGTH, "free surface s (stress extrapolation, Eq. 42)"),
    "flow_height": U.cf(U.LENGTH, "flow height h = s - b"),
    "rho_bar": U.cf(U.DENSITY, "depth-averaged density (Eq. 33)"),
    "nu_bar": U.cf(U.DIMENSIONLESS, "depth-averaged volume fraction rho_bar / rho_p"),
    "rho_c": U.cf(U.DENSITY, "bulk density, mean over [b+2, s-4] (Eq. 51)"),
    "nu_c": U.cf(U.DIMENSIONLESS, "bulk volume fraction rho_c / rho_p"),
    "u_bar": U.cf(U.VELOCITY, "depth-averaged downslope velocity (Eq. 33)"),
    "alpha": U.cf(U.DIMENSIONLESS, "velocity shape factor mean(u^2) / u_bar^2"),
    "K": U.cf(U.DIMENSIONLESS, "normal stress ratio sigma_xx_bar / sigma_zz_bar"),
    "mu_bar": U.cf(U.DIMENSIONLESS, "friction -sigma_xz_bar / sigma_zz_bar"),
    "froude": U.cf(U.DIMENSIONLESS, "Froude number u_bar / sqrt(g cos(theta) h)"),
}

_PROFILE_ATTRS = {
    "friction": U.cf(U.DIMENSIONLESS, "local friction -sigma_xz / sigma_zz"),
    "shear_rate": U.cf(U.SHEAR_RATE, "shear rate d(velocity_x)/dz"),
    "inertial_number": U.cf(U.DIMENSIONLESS,
                            "local inertial number shear_rate d / sqrt(sigma_zz / rho_p)"),
}


def flow_height(z, sigma_zz, kappa: float = KAPPA):
    """Base, surface and thresholds (b, s, z1, z2) of a sigma_zz(z) profile by Eq. (42).

    Returns NaNs when the profile has no positive maximum or no crossing.
    """
    z = np.asarray(z, dtype=float)
    sig = np.asarray(sigma_zz, dtype=float)
    nan4 = (math.nan,) * 4
    if sig.size < 2 or not np.isfinite(sig).any():
        return nan4
    sig = np.where(np.isfinite(sig), sig, -np.inf)
    kmax = int(np.argmax(sig))
    smax = sig[kmax]
    if not smax > 0:
        return nan4
    lev1 = (1.0 - kappa) * smax
    lev2 = kappa * smax
    below = np.nonzero(sig[kmax:] < lev1)[0]
    if below.size == 0:
        return nan4
    k = kmax + int(below[0])
    z1 = z[k - 1] + (lev1 - sig[k - 1]) / (sig[k] - sig[k - 1]) * (z[k] - z[k - 1])
    above = np.nonzero(sig > lev2)[0]
    k = int(above[-1])
    if k >= sig.size - 1:
        return nan4
    z2 = z[k] + (lev2 - sig[k]) / (sig[k + 1] - sig[k]) * (z[k + 1] - z[k])
    ext = kappa / (1.0 - 2.0 * kappa) * (z2 - z1)
    return float(z1 - ext), float(z2 + ext), float(z1), float(z2)


def interval_mean(z, f, lo, hi):
    """(1/(hi - lo)) int_lo^hi f dz, trapezoid rule with linearly interpolated end values."""
    z = np.asarray(z, dtype=float)
    f = np.asarray(f, dtype=float)
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo or lo < z[0] or hi > z[-1]:
        return math.nan
    inside = (z > lo) & (z < hi)
    zz = np.concatenate(([lo], z[inside], [hi]))
    ff = np.concatenate(([np.interp(lo, z, f)], f[inside], [np.interp(hi, z, f)]))
    return float(np.sum(0.5 * (ff[1:] + ff[:-1]) * np.diff(zz)) / (hi - lo))


def _theta_from_attrs(attrs: Mapping):
    for key in ("param_theta_deg", "param_theta", "theta_deg", "theta"):
        if key in attrs:
            try:
                return float(attrs[key])
            except (TypeError, ValueError):
                pass
    return None


def _scalars(z, prof, theta_deg, kappa, bulk_lo, bulk_hi):
    """Depth-averaged scalars from a dict of 1D profiles."""
    b, s, _, _ = flow_height(z, prof["stress_zz"], kappa)
    h = s - b
    out = {"base": b, "surface": s, "flow_height": h}
    mean = lambda f: interval_mean(z, f, b, s)  # noqa: E731
    u = prof["velocity_x"]
    rho_bar = mean(prof["density"])
    u_bar = mean(u)
    szz = mean(prof["stress_zz"])
    out["rho_bar"] = rho_bar
    out["nu_bar"] = rho_bar / U.RHO_PARTICLE
    rho_c = interval_mean(z, prof["density"], b + bulk_lo, s - bulk_hi)
    out["rho_c"] = rho_c
    out["nu_c"] = rho_c / U.RHO_PARTICLE
    out["u_bar"] = u_bar
    out["alpha"] = mean(np.asarray(u) ** 2) / u_bar ** 2 if u_bar != 0 else math.nan
    out["K"] = mean(prof["stress_xx"]) / szz if szz else math.nan
    out["mu_bar"] = -mean(prof["stress_xz"]) / szz if szz else math.nan
    if theta_deg is None or not np.isfinite(h) or h <= 0:
        out["froude"] = math.nan
    else:
        out["froude"] = u_bar / math.sqrt(math.cos(math.radians(theta_deg)) * h)
    return out


_NEEDED = ("stress_zz", "stress_xx", "stress_xz", "velocity_x", "density")


def _window_profiles(ds, names, min_fraction=0.5):
    """List of per-window profile dicts (windows with enough snapshots), or []."""
    if "time_window" not in ds.dims or any(n + "_window" not in ds for n in names):
        return []
    counts = np.asarray(ds["window_n_snapshots"].values, dtype=float)
    keep = np.nonzero(counts >= min_fraction * counts.max())[0]
    return [{n: np.asarray(ds[n + "_window"].values[k], dtype=float) for n in names}
            for k in keep]


def depth_averages(ds: xr.Dataset, theta_deg: float | None = None, kappa: float = KAPPA,
                   bulk_margins=(2.0, 4.0), window_min_fraction: float = 0.5) -> xr.Dataset:
    """Scalar Dataset of flow height and depth averages (Eq. 33, 42, 51) of a profile dataset.

    ``theta_deg`` (for the Froude number) defaults to the ``param_theta_deg``/``param_theta``
    global attribute.  With per-window profiles each scalar gets a ``<name>_std`` companion
    and ``n_windows`` records how many windows entered.  Global attrs are passed through.
    """
    if theta_deg is None:
        theta_deg = _theta_from_attrs(ds.attrs)
    z = ds["z"].values
    prof = {n: np.asarray(ds[n].values, dtype=float) for n in _NEEDED}
    vals = _scalars(z, prof, theta_deg, kappa, *bulk_margins)
    data = {k: ((), v, _SCALAR_ATTRS[k]) for k, v in vals.items()}
    wins = _window_profiles(ds, _NEEDED, window_min_fraction)
    if wins:
        from ..steady.timeseries import standard_error_of_mean

        per = [_scalars(z, w, theta_deg, kappa, *bulk_margins) for w in wins]
        for k in vals:
            arr = np.array([p[k] for p in per], dtype=float)
            std = float(np.std(arr, ddof=1)) if arr.size > 1 else math.nan
            a = dict(_SCALAR_ATTRS[k])
            a["long_name"] = a["long_name"] + ", std over time windows"
            data[k + "_std"] = ((), std, a)
            a = dict(_SCALAR_ATTRS[k])
            a["long_name"] = ("standard error of the run mean of " + a["long_name"]
                              + " (decorrelated time windows)")
            data[k + "_sem"] = ((), standard_error_of_mean(arr), a)
        data["n_windows"] = ((), len(wins), U.cf(U.DIMENSIONLESS, "time windows used for spreads"))
    out = xr.Dataset(data)
    out.attrs.update(ds.attrs)
    out.attrs["kappa"] = kappa
    out.attrs["theta_deg"] = math.nan if theta_deg is None else float(theta_deg)
    return out


def _local(z, prof, d, rho_p):
    szz = prof["stress_zz"]
    with np.errstate(invalid="ignore", divide="ignore"):
        pos = szz > 0
        mu = np.where(pos, -prof["stress_xz"] / np.where(pos, szz, 1.0), np.nan)
        u = prof["velocity_x"]
        shear = np.gradient(u, z) if z.size > 1 else np.full_like(u, np.nan)
        inertial = np.where(pos, shear * d / np.sqrt(np.where(pos, szz, 1.0) / rho_p), np.nan)
    return {"friction": mu, "shear_rate": shear, "inertial_number": inertial}


def local_profiles(ds: xr.Dataset, d: float = 1.0, rho_p: float = U.RHO_PARTICLE,
                   window_min_fraction: float = 0.5) -> xr.Dataset:
    """Local friction, shear rate and inertial number profiles (dim ``z``), with ``_std``
    companions (std over time windows) when per-window profiles are present."""
    z = ds["z"].values
    names = ("stress_zz", "stress_xz", "velocity_x")
    prof = {n: np.asarray(ds[n].values, dtype=float) for n in names}
    loc = _local(z, prof, d, rho_p)
    data = {k: ("z", v, _PROFILE_ATTRS[k]) for k, v in loc.items()}
    wins = _window_profiles(ds, names, window_min_fraction)
    if len(wins) > 1:
        per = [_local(z, w, d, rho_p) for w in wins]
        for k in loc:
            arr = np.stack([p[k] for p in per])
            a = dict(_PROFILE_ATTRS[k])
            a["long_name"] = a["long_name"] + ", std over time windows"
            with warnings.catch_warnings():  # all-NaN columns outside the flow
                warnings.simplefilter("ignore", RuntimeWarning)
                data[k + "_std"] = ("z", np.nanstd(arr, axis=0, ddof=1), a)
    out = xr.Dataset(data, coords={"z": ds["z"]})
    out.attrs.update(ds.attrs)
    return out


def depth_average_summary(ds: xr.Dataset, theta_deg: float | None = None, **kwargs) -> dict:
    """Plain dict of the :func:`depth_averages` scalars (and ``_std`` spreads) for tables."""
    res = depth_averages(ds, theta_deg, **kwargs)
    out = {k: float(res[k].values) for k in res.data_vars}
    out["theta_deg"] = res.attrs["theta_deg"]
    if "n_windows" in out:
        out["n_windows"] = int(out["n_windows"])
    return out
