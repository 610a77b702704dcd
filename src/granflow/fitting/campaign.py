"""Fit every closure of Weinhart et al. (2012) §9 and Thornton et al. §6 to a campaign table.

:func:`fit_campaign` runs, for each contact law in the table:

* per basal roughness lambda (monodisperse runs, sigma = 1): hstop Eq. (45) and, for comparison,
  Eq. (38) from the (theta, H, state) runs; the flow rule Eq. (47) with hstop(theta; 1); the
  friction closure Eq. (50); the shape factor alpha (Eq. 54 for lambda > 2/3, constant for
  lambda <= 2/3);
* pooled over steady runs with lambda > 0 (as in the paper): bulk density Eq. (52) and stress
  ratio Eq. (53);
* over runs with a measured Ps: the size-ratio law T-eq. (29), weighted by ``Ps_std`` when given.

Fits that cannot be made come back with ``ok=False`` (they are still returned, so a library
records that they were attempted). The result is a flat list ready for
:func:`granflow.closures.write_library`.
"""

from __future__ import annotations

import numpy as np

from .bulk import fit_bulk_density, fit_stress_ratio
from .flow_rule import fit_flow_rule, friction_closure
from .hstop import fit_hstop, fit_hstop_eq38
from .result import FitResult, failed_fit
from .segregation import fit_Ps_law
from .shape_factor import fit_alpha
from .table import select_runs, validate_campaign_table


def fit_campaign(table, *, theta_min=None, theta_max=None, n_bootstrap: int = 200, seed: int = 0,
                 include_eq38: bool = True) -> list[FitResult]:
    """All closure fits for a validated campaign table (see module docstring).

    ``theta_min`` / ``theta_max``: optional ``{lambda: angle}`` maps of delta3 and delta_acc
    (Eq. 46, 48) restricting the flow-rule, friction and alpha fits; by default all steady runs
    inside (delta1, delta2) of lambda = 1 are used.
    """
    validate_campaign_table(table)
    theta_min, theta_max = dict(theta_min or {}), dict(theta_max or {})
    results: list[FitResult] = []
    for law in sorted(set(table["contact_law"])):
        mono = select_runs(table, contact_law=law, sigma=1.0)
        lams = sorted(set(mono["lam"].astype(float)))
        hstops = {}
        for lam in lams:
            runs = select_runs(mono, lam=lam)
            hstops[lam] = fit_hstop(runs=runs, lam=lam, contact_law=law,
                                    n_bootstrap=n_bootstrap, seed=seed)
            results.append(hstops[lam])
            if include_eq38:
                results.append(fit_hstop_eq38(runs=runs, lam=lam, contact_law=law,
                                              n_bootstrap=n_bootstrap, seed=seed))
        hstop1 = next((r for lam, r in hstops.items() if abs(lam - 1.0) < 1e-9), None)
        for lam in lams:
            steady = select_runs(mono, lam=lam, states="steady")
            tmin = next((v for k, v in theta_min.items() if abs(k - lam) < 1e-9), None)
            tmax = next((v for k, v in theta_max.items() if abs(k - lam) < 1e-9), None)
            if tmin is not None:
                steady = steady[steady["theta"] > tmin]
            if tmax is not None:
                steady = steady[steady["theta"] < tmax]
            theta, h = steady["theta"].to_numpy(float), steady["h"].to_numpy(float)
            if hstop1 is None:
                flow = failed_fit("flow_rule", "Weinhart et al. 2012 Eq. (47)", ("beta", "gamma"),
                                  "no lambda = 1 runs: hstop(theta; 1) unavailable", 0,
                                  lam=lam, contact_law=law)
            else:
                flow = fit_flow_rule(theta, h, steady["F"].to_numpy(float), hstop1,
                                     lam=lam, contact_law=law)
            results.append(flow)
            if hstop1 is not None:
                results.append(friction_closure(hstop1, flow, theta=theta, h=h,
                                                F=steady["F"].to_numpy(float)))
            results.append(fit_alpha(theta, h, steady["alpha"].to_numpy(float), lam,
                                     hstop1 if hstop1 is not None and hstop1.ok else None,
                                     contact_law=law))
        rough = mono[(mono["state"] == "steady") & (mono["lam"] > 0)]
        results.append(fit_bulk_density(rough["theta"], rough["rho_c"], contact_law=law))
        results.append(fit_stress_ratio(rough["theta"], rough["K"], contact_law=law))
        seg = select_runs(table, contact_law=law)
        seg = seg[np.isfinite(seg["Ps"].to_numpy(float))]
        if len(seg):
            std = seg["Ps_std"].to_numpy(float)
            results.append(fit_Ps_law(seg["sigma"], seg["Ps"],
                                      std if np.all(np.isfinite(std) & (std > 0)) else None,
                                      contact_law=law))
    return results
