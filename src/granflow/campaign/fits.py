"""Every closure fit of a campaign, stored as exact JSON and as a readable closure table.

:func:`run_fits` = :func:`granflow.fitting.fit_campaign` on the campaign table (hstop Eq. 45 and
38, flow rule Eq. 47, friction Eq. 50, alpha Eq. 54/55, density Eq. 52, K Eq. 53, Ps(sigma)
T-eq. 29) plus the per-run segregation fits (T-eq. 28) derived by ``granflow campaign row``.

Undecided runs and hstop.  The arrested/flowing demarcation of Weinhart et al. (2012) §6 is
binary: a run is arrested when E_kin/<E_ela> falls below 1e-5, "otherwise flowing" -- which is
also how :func:`granflow.steady.hstop_search.is_flowing` reads every state but "arrested".  A run
that the classifier left ``undecided`` at its cap (steady or still accelerating could not be
shown; common in small, noisy boxes) cannot enter the campaign table, but it *is* a flowing run
for the demarcation.  When there are such runs, :func:`run_fits` therefore refits hstop (Eq. 45
and 38) from the brackets of every classified run with undecided runs counted as flowing, and
redoes the fits that use hstop(theta; 1) -- flow rule, friction, alpha -- with it (same data as
:func:`fit_campaign`: steady runs only).  The hstop messages state how many undecided runs
entered; density, K and Ps(sigma) are unaffected.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pandas as pd

from ..provenance import atomic_write_bytes
from .serialize import dumps, fit_from_dict, fit_to_dict, from_jsonable

HSTOP_DEPENDENT = ("hstop", "hstop_eq38", "flow_rule", "friction", "alpha")


def binary_intervals(runs: pd.DataFrame) -> pd.DataFrame:
    """Brackets [largest arrested theta, smallest flowing theta] per filling height H, where
    every state but "arrested" (including "undecided") is flowing (§6); columns as
    :func:`granflow.fitting.hstop_intervals_from_runs`."""
    rows = []
    flowing = (runs["state"].astype(str) != "arrested").to_numpy()
    theta, H = runs["theta"].to_numpy(float), runs["H"].to_numpy(float)
    for h in np.unique(H[np.isfinite(H)]):
        sel = H == h
        arr, flo = theta[sel & ~flowing], theta[sel & flowing]
        lo = float(arr.max()) if arr.size else -math.inf
        hi = float(flo.min()) if flo.size else math.inf
        inverted = lo > hi
        if inverted:
            lo, hi = hi, lo
        rows.append({"H": float(h), "theta_arrested_max": lo, "theta_flowing_min": hi,
                     "inverted": bool(inverted)})
    return pd.DataFrame(rows, columns=["H", "theta_arrested_max", "theta_flowing_min", "inverted"])


def _refit_hstop_with_undecided(fits, table, undecided, n_bootstrap, seed):
    from ..fitting import (fit_alpha, fit_flow_rule, fit_hstop, fit_hstop_eq38, friction_closure,
                           select_runs)
    from ..fitting.result import failed_fit

    cols = ["theta", "H", "lam", "sigma", "contact_law", "state"]
    runs = pd.concat([table[cols], undecided[cols]], ignore_index=True)
    runs = runs[np.isclose(runs["sigma"].to_numpy(float), 1.0)]
    out = [r for r in fits if r.kind not in HSTOP_DEPENDENT]
    for law in sorted(set(runs["contact_law"])):
        mono_all = runs[runs["contact_law"] == law]
        mono = select_runs(table, contact_law=law, sigma=1.0)
        lams = sorted(set(mono_all["lam"].astype(float)))
        hstops = {}
        for lam in lams:
            sub = mono_all[np.isclose(mono_all["lam"].to_numpy(float), lam)]
            n_und = int((sub["state"] == "undecided").sum())
            iv = binary_intervals(sub)
            note = (f"; brackets from {len(sub)} classified runs, {n_und} of them undecided "
                    "and counted as flowing (binary arrested/flowing rule, §6)")
            for fn in (fit_hstop, fit_hstop_eq38):
                r = fn(iv, lam=lam, contact_law=law, n_bootstrap=n_bootstrap, seed=seed)
                r = dataclasses.replace(r, message=r.message + note)
                out.append(r)
                if fn is fit_hstop:
                    hstops[lam] = r
        hstop1 = next((r for lam, r in hstops.items() if abs(lam - 1.0) < 1e-9), None)
        for lam in lams:
            steady = select_runs(mono, lam=lam, states="steady")
            theta, h = steady["theta"].to_numpy(float), steady["h"].to_numpy(float)
            F = steady["F"].to_numpy(float)
            if hstop1 is None:
                flow = failed_fit("flow_rule", "Weinhart et al. 2012 Eq. (47)", ("beta", "gamma"),
                                  "no lambda = 1 runs: hstop(theta; 1) unavailable", 0,
                                  lam=lam, contact_law=law)
            else:
                flow = fit_flow_rule(theta, h, F, hstop1, lam=lam, contact_law=law)
            out.append(flow)
            if hstop1 is not None:
                out.append(friction_closure(hstop1, flow, theta=theta, h=h, F=F))
            out.append(fit_alpha(theta, h, steady["alpha"].to_numpy(float), lam,
                                 hstop1 if hstop1 is not None and hstop1.ok else None,
                                 contact_law=law))
    return out


def run_fits(table, segregation=(), n_bootstrap: int = 200, seed: int = 0, excluded=None) -> list:
    """All closure fits of a campaign (see module docstring); ``excluded``: the excluded-runs
    frame of :func:`granflow.campaign.collect.read_excluded` (its undecided runs enter hstop)."""
    from ..fitting import fit_campaign

    fits = list(fit_campaign(table, n_bootstrap=n_bootstrap, seed=seed)) if len(table) else []
    if excluded is not None and len(excluded) and "state" in excluded:
        undecided = excluded[(excluded["state"] == "undecided")
                             & np.isfinite(pd.to_numeric(excluded["theta"], errors="coerce"))]
        if len(undecided):
            fits = _refit_hstop_with_undecided(fits, table, undecided, n_bootstrap, seed)
    fits += list(segregation)
    return fits


def closure_rows(fits) -> pd.DataFrame:
    """One row per fitted parameter: kind, coordinates, value, stderr, fit error, status."""
    rows = []
    for r in fits:
        for p, v in r.params.items():
            rows.append({"kind": r.kind, "equation": r.equation,
                         "contact_law": r.coords.get("contact_law", ""),
                         "lambda": r.coords.get("lam", math.nan),
                         "sigma": r.coords.get("sigma", math.nan), "parameter": p,
                         "value": v, "stderr": r.stderr.get(p, math.nan), "fit_error": r.error,
                         "n_points": r.n_points, "ok": bool(r.ok), "message": r.message})
    return pd.DataFrame(rows, columns=["kind", "equation", "contact_law", "lambda", "sigma",
                                       "parameter", "value", "stderr", "fit_error", "n_points",
                                       "ok", "message"])


def write_fits(fits, out_json, out_csv=None):
    atomic_write_bytes(out_json, dumps([fit_to_dict(r) for r in fits]).encode())
    if out_csv is not None:
        atomic_write_bytes(out_csv, closure_rows(fits).to_csv(index=False, float_format="%.10g")
                           .encode())


def read_fits(path) -> list:
    with open(path) as fh:
        return [fit_from_dict(d) for d in from_jsonable(json.load(fh))]
