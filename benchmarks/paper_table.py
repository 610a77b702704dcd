"""A campaign's closure table against the papers' values (Table 1, Table 2, Eq. 52-53, T-eq. 29).

Reads ``closures.csv`` of a finished campaign and prints, per parameter with a paper value, the
fitted value +- stderr, the paper's value, the difference in stderr units and whether it agrees
by the reference campaigns' rule (issue 14): within twice its own stderr, or within 5 % of the
paper's value where that is the looser (a density reduced to its linear form is compared
with Eq. 52's value and slope at the fit's reference angle).  The parameter's identifiability status is the
library's own; a parameter that is not identified is listed but never counts as agreeing.
A closure the campaign has no runs for (``parameter_status`` ``not_fitted``: e.g. the lambda = 1
flow rule of the lambda = 1/2 reference, which runs only lambda = 1 brackets) is outside the
configuration's scope: it is left out of the table and of the count, and named below it.
A second table sets each closure's fit error (Eq. 49 of its residuals) against the paper's
(Table 1's err(F), Table 2's error of alpha): a misfit the size of the paper's is the closure
form's own scatter, not a defect of the campaign.  A third table applies the paper's own law
(Table 1's beta, gamma at the run's lambda with Table 1's hstop(theta; 1); Table 2's alpha) to
the runs each closure was fitted on: its Eq. (49) error on them against the paper's fit error.
Where a campaign's runs span too little of the law's input to separate its parameters (beta
and gamma from a few angles), the marginal z-scores above can disagree while the paper's law
describes the runs as well as it described the paper's own (ratio <= 1): that is agreement of
the law, not of each parameter, and is printed as such.  The converse is printed too: hstop's
delta1 and A (and Eq. 52's c0, c1, c2) are so correlated that each can agree within its wide
stderr while the curve, which the data pin far better, lies off the paper's everywhere
(:func:`granflow.reference.paper_curves`: the mean difference of ours - the paper's over the
bracket heights or the fitted angles / size ratios, its stderr from the fit's ensemble, and
which rule it meets).

    .venv/bin/python benchmarks/paper_table.py results/reference-lambda1
"""

from __future__ import annotations

import argparse
import json
import math
import re
from pathlib import Path

import pandas as pd

from granflow.reference import paper_fit_error, paper_curves, paper_law_errors, paper_value

#: closure kinds whose parameters the papers give (hstop_eq38 has no paper value)
KINDS = ("hstop", "flow_rule", "alpha", "density", "stress_ratio", "Ps_law")


def _no_runs(r) -> bool:
    """A row of a closure the campaign has no runs for (a fit that failed on data is in scope)."""
    return r.parameter_status == "not_fitted" and int(getattr(r, "n_points", 0) or 0) == 0


def not_fitted(table: pd.DataFrame) -> list[tuple[str, float]]:
    """(closure, lambda) of the paper's closures the campaign did not fit (no runs for them)."""
    t = table.rename(columns={"lambda": "lam"})
    out = set()
    for r in t.itertuples(index=False):
        if r.kind in KINDS and _no_runs(r):
            out.add((r.kind, None if pd.isna(r.lam) else float(r.lam)))
    return sorted(out, key=lambda k: (k[0], -1.0 if k[1] is None else k[1]))


def paper_rows(table: pd.DataFrame, n_sigma: float = 2.0, rel: float = 0.05) -> list[dict]:
    rows = []
    for r in table.rename(columns={"lambda": "lam"}).itertuples(index=False):
        if r.kind not in KINDS or _no_runs(r):
            continue
        lam = None if pd.isna(r.lam) else float(r.lam)
        ref = paper_value(r.kind, r.parameter, lam)
        if r.kind == "density" and r.parameter in ("nu_ref", "dnu_dtheta"):
            # the reduced linear form: Eq. (52) with the paper's c0, c1, c2 at the fit's theta_ref
            m = re.search(r"theta - ([0-9.]+)", str(r.message))
            if m:
                c0, c1, c2 = (paper_value("density", p) for p in ("c0", "c1", "c2"))
                e = math.exp((float(m.group(1)) - c2) / c1)
                ref = c0 - e if r.parameter == "nu_ref" else -e / c1
        if not math.isfinite(ref):
            continue
        v, se = float(r.value), float(r.stderr)
        z = (v - ref) / se if math.isfinite(se) and se > 0 else math.nan
        tol = max(n_sigma * se if math.isfinite(se) else 0.0, rel * abs(ref))
        identified = r.parameter_status == "identified"
        rows.append({"closure": r.kind, "parameter": r.parameter, "value": v, "stderr": se,
                     "paper": ref, "z": z, "status": r.parameter_status,
                     "agrees": bool(identified and math.isfinite(v) and abs(v - ref) <= tol)})
    return rows


def fit_error_rows(table: pd.DataFrame) -> list[dict]:
    """One row per closure (kind, lambda) the paper gives a fit error for: ours and the paper's
    Eq. (49) error, their ratio, the runs used and the closure's status."""
    rows = []
    t = table.rename(columns={"lambda": "lam"})
    for (kind, lam), g in t.groupby(["kind", "lam"], dropna=True, sort=True):
        ref = paper_fit_error(kind, lam)
        if not math.isfinite(ref):
            continue
        r = g.iloc[0]
        if int(r.n_points) == 0:
            continue
        ours = float(r.fit_error)
        rows.append({"closure": kind, "lambda": float(lam), "fit_error": ours, "paper": ref,
                     "ratio": ours / ref if math.isfinite(ours) else math.nan,
                     "n_points": int(r.n_points), "status": r.status})
    return rows


def print_paper_rows(rows, closure: bool = True):
    """The rows of :func:`paper_rows` as a Markdown table (``closure``: with that column)."""
    head = "| closure " if closure else ""
    print(f"{head}| parameter | value +- stderr | paper | z | status | agrees |")
    print("|---" * (7 if closure else 6) + "|")
    for r in rows:
        vs = "n/a" if not math.isfinite(r["value"]) else f"{r['value']:.4g} +- {r['stderr']:.2g}"
        z = "" if not math.isfinite(r["z"]) else f"{r['z']:+.1f}"
        first = f"| {r['closure']} " if closure else ""
        print(f"{first}| {r['parameter']} | {vs} | {r['paper']:g} | {z} | "
              f"{r['status']} | {'yes' if r['agrees'] else 'no'} |")


def print_curve_rows(rows):
    """The rows of :func:`granflow.reference.paper_curves` as a Markdown table."""
    if not rows:
        return
    print("\nThe papers' curves against the fitted ones (ours - the paper's, mean over the "
          "points)")
    print("| closure | lambda | curve | points | mean difference | z | relative "
          "| max pointwise abs z | agrees |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        how = ("yes (within 2 stderr)" if r["within_stderr"] else
               "within 5 % only" if r["agrees"] else "no")
        lam = "" if r["lambda"] is None else f"{r['lambda']:g}"
        print(f"| {r['closure']} | {lam} | {r['variable']} | {r['x']} "
              f"{min(r['points']):.4g}-{max(r['points']):.4g} ({len(r['points'])}) | "
              f"{r['mean_difference']:+.3g} +- {r['stderr']:.2g} | {r['z']:+.1f} | "
              f"{100 * r['relative']:+.1f} % | {r['max_abs_z_pointwise']:.1f} | {how} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path)
    args = ap.parse_args()
    table = pd.read_csv(args.results / "closures.csv")
    rows = paper_rows(table)
    print_paper_rows(rows)
    n_ok = sum(r["agrees"] for r in rows)
    print(f"\n{n_ok} of {len(rows)} paper parameters agree (2 stderr or 5 %, identified only)")
    skipped = not_fitted(table)
    if skipped:
        print("not fitted by this campaign (no runs; outside its scope): "
              + ", ".join(k if lam is None else f"{k} (lambda = {lam:g})" for k, lam in skipped))
    errs = fit_error_rows(table)
    if errs:
        print("\n| closure | lambda | fit error (Eq. 49) | paper | ratio | runs | status |")
        print("|---|---|---|---|---|---|---|")
        for r in errs:
            print(f"| {r['closure']} | {r['lambda']:g} | {r['fit_error']:.4g} | {r['paper']:g} | "
                  f"{r['ratio']:.2f} | {r['n_points']} | {r['status']} |")
    fits_file, runs_file = args.results / "fits.json", args.results / "campaign_table.csv"
    if fits_file.exists():
        print_curve_rows(paper_curves(json.loads(fits_file.read_text())))
    if fits_file.exists() and runs_file.exists():
        law = paper_law_errors(json.loads(fits_file.read_text()), pd.read_csv(runs_file))
        if law:
            print("\nThe paper's law on this campaign's runs (the runs each closure used):")
            print("| closure | lambda | runs | Eq. 49 error of run - paper law | paper's fit error "
                  "| ratio | mean, worst relative deviation |")
            print("|---|---|---|---|---|---|---|")
            for r in law:
                print(f"| {r['closure']} | {r['lambda']:g} | {r['n']} | {r['error']:.4g} | "
                      f"{r['paper']:g} | {r['ratio']:.2f} | {100 * r['mean']:+.1f} %, "
                      f"{100 * r['worst']:.1f} % |")


if __name__ == "__main__":
    main()
