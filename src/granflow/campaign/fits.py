"""Every closure fit of a campaign, stored as exact JSON and as a readable closure table.

:func:`run_fits` = :func:`granflow.fitting.fit_campaign` on the campaign table (hstop Eq. 45 and
38, flow rule Eq. 47, friction Eq. 50, alpha Eq. 54/55, density Eq. 52, K Eq. 53, Ps(sigma)
T-eq. 29) plus the per-run segregation fits (T-eq. 28) derived by ``granflow campaign row``,
each assessed for identifiability (:mod:`granflow.fitting.identify`).  Runs left ``undecided``
at their cap are rows of the campaign table; each closure states how it treats them.

:func:`closure_rows` gives the closure table (``closures.csv``): one row per parameter with its
value, stderr, per-parameter status and reason, and the closure's status, form, selection and
largest held-out |z|.
"""

from __future__ import annotations

import json
import math

import pandas as pd

from ..provenance import atomic_write_bytes
from .serialize import dumps, fit_from_dict, fit_to_dict, from_jsonable


def assess_segregation_runs(segregation, table=None) -> list:
    """Per-run Ps fits (T-eq. 28) with their identifiability and their run's states: a run not
    in a steady flow and a steady segregated state is ``unidentified`` (its profile is not the
    steady profile T-eq. 28 describes), with the states in the reason."""
    from ..fitting.identify import assess

    out = []
    for r in segregation:
        st = str(r.extra.get("segregation_state", "unknown"))
        flow = str(r.extra.get("flow_state", ""))
        if table is not None and "run" in table.columns and r.runs_used:
            row = table[table["run"].astype(str) == str(r.runs_used[0])]
            if len(row):
                flow = str(row["state"].iloc[0])
        a = assess(r)
        if a.ok and (st != "steady" or (flow and flow != "steady")):
            reason = (f"run not in a steady flow and a steady segregated state (flow: "
                      f"{flow or 'unknown'}, segregation: {st}): its phi(z) is not the steady "
                      "profile of T-eq. (28)")
            a = a.replace(status="unidentified", ok=False,
                          param_status={k: "unidentified" for k in a.params},
                          param_reason={k: reason for k in a.params},
                          message=a.message + "; " + reason)
        out.append(a)
    return out


def run_fits(table, segregation=(), n_bootstrap: int = 200, seed: int = 0, excluded=None,
             windows=None) -> list:
    """All closure fits of a campaign (see module docstring).  ``excluded`` (runs that could not
    enter the table) is accepted for the record; no fit uses those runs.  ``windows``: the
    configuration's ``library.disordered_window`` ({lambda: {delta3, delta_acc}}, Eq. 46, 48)."""
    from ..fitting import fit_campaign

    fits = (list(fit_campaign(table, windows=windows, n_bootstrap=n_bootstrap, seed=seed))
            if len(table) else [])
    # one value per size ratio: several runs there (replicates, starts) are averaged, their
    # spread entering the stderr (granflow.fitting.segregation.combine_Ps_runs)
    from ..fitting.segregation import combine_Ps_runs

    fits += combine_Ps_runs(assess_segregation_runs(segregation, table))
    return fits


def closure_rows(fits) -> pd.DataFrame:
    """One row per fitted parameter: kind, coordinates, value, stderr, status and reason (per
    parameter and per closure), form, fit error, held-out max |z|, selection."""
    rows = []
    for r in fits:
        for p, v in r.params.items():
            pst = r.param_status.get(p, "")
            if pst == "not_in_form":
                continue
            rows.append({"kind": r.kind, "equation": r.equation,
                         "contact_law": r.coords.get("contact_law", ""),
                         "lambda": r.coords.get("lam", math.nan),
                         "sigma": r.coords.get("sigma", math.nan), "parameter": p,
                         "value": v, "stderr": r.stderr.get(p, math.nan),
                         "parameter_status": pst, "parameter_reason": r.param_reason.get(p, ""),
                         "status": r.state, "form": r.form, "ok": bool(r.ok),
                         "fit_error": r.error, "n_points": r.n_points,
                         "heldout_max_abs_z": r.diagnostics.get("heldout_max_abs_z", math.nan),
                         "between_seed_fraction": (r.diagnostics.get("uncertainty_split") or {})
                         .get(p, {}).get("between", math.nan),
                         "chi2_dof": (r.diagnostics.get("chi2", math.nan)
                                      / r.diagnostics["dof"]) if r.diagnostics.get("dof") else
                         math.nan,
                         "message": r.message, "selection": r.selection})
    return pd.DataFrame(rows, columns=["kind", "equation", "contact_law", "lambda", "sigma",
                                       "parameter", "value", "stderr", "parameter_status",
                                       "parameter_reason", "status", "form", "ok", "fit_error",
                                       "n_points", "heldout_max_abs_z", "between_seed_fraction",
                                       "chi2_dof", "message", "selection"])


def write_fits(fits, out_json, out_csv=None):
    atomic_write_bytes(out_json, dumps([fit_to_dict(r) for r in fits]).encode())
    if out_csv is not None:
        atomic_write_bytes(out_csv, closure_rows(fits).to_csv(index=False, float_format="%.10g")
                           .encode())


def read_fits(path) -> list:
    with open(path) as fh:
        return [fit_from_dict(d) for d in from_jsonable(json.load(fh))]
