"""hstop(theta) of Eq. (45) from a campaign's finished bracket and chute runs, against Table 1.

Reads every ``summary.json`` under ``<results>/bracket`` and ``<results>/chute`` (also of a
campaign whose steady runs are still going: the bisection chains finish first), forms one
arrested/flowing bracket per (contact law, lambda, H, replicate) as the library's fit does
(:func:`granflow.fitting.hstop.hstop_intervals_from_runs`), fits Eq. (45) with the library's
settings (200 bootstrap refits requested, more until the identifiability tests are
decided; seed 1) and prints the brackets (beside Table 1's theta_stop at
each height) and the fit against Table 1 (per lambda) with the rule of ``paper_table.py`` (2 stderr or 5 %, identified only).  Later
results folders override earlier ones run by run (a chain rerun elsewhere replaces the
original's runs at the same angle and height), unless ``--realisations``: then each folder is
a campaign over another base realisation (its own ``base.seed`` or making), whose chains are
data of their own (replicate ``1000 i + k`` for insertion replicate k of folder i), so that the
fit's scatter and stderrs include the scatter between bases.  Every bracket is labelled with the
base it lies on (a fingerprint of the fixed particles' positions in the run's
``final_state.npz``: the same base in two folders is one base), and the fit models an offset
common to one base's brackets as a random effect (``granflow.fitting.hstop.base_scatter``).

    .venv/bin/python benchmarks/hstop_brackets.py results/reference-lambda1
    .venv/bin/python benchmarks/hstop_brackets.py --realisations results/base1 results/base2
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from granflow.campaign.collect import engine_stop_without_flow_state
from granflow.fitting.hstop import (ENGINE_STOP_NO_STATE, fit_hstop, hstop_intervals_from_runs,
                                    theta_stop_eq45)
from granflow.reference import paper_curves, paper_value

POINT = re.compile(r"(?P<law>[A-Za-z_]+)/lambda~(?P<lam>[0-9.]+)/theta~(?P<theta>[0-9.]+)/"
                   r"H~(?P<H>[0-9.]+)(?:/seed~(?P<seed>\d+))?/summary\.json$")


#: replicate index offset per results folder under ``--realisations`` (insertion replicates
#: of one campaign stay below it)
REALISATION_STRIDE = 1000


def base_fingerprint(state_file) -> str | None:
    """First 12 hex digits of the SHA-256 of the fixed (base) particles' positions in a run's
    final state: equal for every run on one base file, whatever the run's angle, height or
    insertion seed (None: no final state)."""
    state_file = Path(state_file)
    if not state_file.is_file():
        return None
    with np.load(state_file, allow_pickle=False) as data:
        pos = np.ascontiguousarray(data["pos"][data["fixed"].astype(bool)], dtype=np.float64)
    return hashlib.sha256(pos.tobytes()).hexdigest()[:12]


def bracket_runs(*roots, realisations: bool = False) -> pd.DataFrame:
    """theta, H, state, replicate (and ``realisation``, the folder's index) of the bracket and
    chute runs under the results folders.  ``realisations``: every folder's runs are kept apart
    (replicate + 1000 x folder index) instead of a later folder's run replacing an earlier's."""
    runs: dict[str, dict] = {}
    for i, root in enumerate(map(Path, roots)):
        for kind in ("bracket", "chute"):
            for f in sorted((root / kind).glob("**/summary.json")):
                m = POINT.search(f.as_posix())
                if not m:
                    continue
                summ = json.loads(f.read_text())
                # an engine stop before any flow state is no evidence (as in the library's fit)
                stop = ENGINE_STOP_NO_STATE if engine_stop_without_flow_state(summ) else ""
                rep = int(m["seed"] or 0)
                if rep >= REALISATION_STRIDE:
                    raise ValueError(f"{f}: replicate {rep} >= {REALISATION_STRIDE} is not "
                                     "supported")
                key = f.relative_to(root).as_posix()
                runs[(i, key) if realisations else key] = {
                    "theta": float(m["theta"]), "H": float(m["H"]), "state": summ["flow_state"],
                    "replicate": rep + (REALISATION_STRIDE * i if realisations else 0),
                    "realisation": i if realisations else 0, "lambda": float(m["lam"]),
                    "contact_law": m["law"], "stop_reason": stop,
                    "base": base_fingerprint(f.with_name("final_state.npz"))}
    return pd.DataFrame(list(runs.values()),
                        columns=["theta", "H", "state", "replicate", "realisation", "lambda",
                                 "contact_law", "stop_reason", "base"])


def _paper_table():
    spec = importlib.util.spec_from_file_location("paper_table",
                                                  Path(__file__).with_name("paper_table.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def hstop_table(runs: pd.DataFrame, lam: float = 1.0):
    """(brackets, fit, rows against Table 1) of the runs."""
    iv = hstop_intervals_from_runs(runs)
    law = str(runs["contact_law"].iloc[0]) if "contact_law" in runs and len(runs) else None
    fit = fit_hstop(iv, lam=lam, contact_law=law, n_bootstrap=200, seed=1)
    table = pd.DataFrame([{"kind": "hstop", "lambda": lam, "parameter": p, "value": v,
                           "stderr": fit.stderr.get(p, math.nan),
                           "parameter_status": fit.param_status.get(p, "not_fitted"),
                           "message": fit.message} for p, v in fit.params.items()])
    return iv, fit, _paper_table().paper_rows(table)


def with_paper_curve(iv: pd.DataFrame, lam: float) -> pd.DataFrame:
    """The brackets with Table 1's theta_stop(H; lambda) (Eq. 45 inverted at the filling height,
    as the fit reads it) and where it lies against each bracket: ``paper_offset`` is the
    bracket's midpoint minus the paper's angle (NaN for one-sided brackets or a lambda the
    paper does not list)."""
    p = [paper_value("hstop", k, lam) for k in ("delta1", "delta2", "A")]
    out = iv.copy()
    out["paper_theta_stop"] = (theta_stop_eq45(out["H"].to_numpy(float), *p)
                               if all(math.isfinite(v) for v in p) else math.nan)
    mid = 0.5 * (out["theta_arrested_max"] + out["theta_flowing_min"])
    out["paper_offset"] = (mid - out["paper_theta_stop"]).where(
        out["theta_arrested_max"].gt(-math.inf) & out["theta_flowing_min"].lt(math.inf))
    return out


def mean_offsets(iv: pd.DataFrame) -> dict:
    """Mean ``paper_offset`` (bracket midpoint - Table 1's angle, two-sided brackets only) of
    brackets from :func:`with_paper_curve`: ``{"all": m, realisation: m, ...}`` with the
    realisation ``replicate // REALISATION_STRIDE`` (0 for a single campaign)."""
    off = iv[["replicate", "paper_offset"]].dropna()
    out = {"all": float(off["paper_offset"].mean()) if len(off) else math.nan}
    for r, g in off.groupby(off["replicate"] // REALISATION_STRIDE):
        out[int(r)] = float(g["paper_offset"].mean())
    return out


def hstop_tables(runs: pd.DataFrame) -> dict:
    """{(contact law, lambda): (brackets, fit, rows against Table 1)}: one hstop curve per base
    (the brackets of different lambdas or contact laws never mix)."""
    return {(law, float(lam)): hstop_table(g, lam=float(lam))
            for (law, lam), g in runs.groupby(["contact_law", "lambda"], sort=True)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, nargs="+")
    ap.add_argument("--realisations", action="store_true",
                    help="each results folder is a campaign over another base realisation: "
                         "its chains are data of their own, never replaced by another's")
    args = ap.parse_args()
    runs = bracket_runs(*args.results, realisations=args.realisations)
    for (law, lam), (iv, fit, rows) in hstop_tables(runs).items():
        print(f"\n## contact law {law}, lambda = {lam:g}\n")
        curve = with_paper_curve(iv, lam)
        print(curve.sort_values(["H", "replicate"])
              .to_string(index=False, float_format=lambda v: f"{v:.2f}"))
        offsets = mean_offsets(curve)
        if math.isfinite(offsets["all"]):
            per = "".join(f", folder {k}: {v:+.2f}" for k, v in offsets.items()
                          if k != "all" and args.realisations)
            print(f"\nmean offset from Table 1's curve (two-sided brackets): "
                  f"{offsets['all']:+.2f} deg{per}")
        print(f"\nEq. (45) fit: {fit.status}; {len(iv)} brackets; held-out max |z| "
              f"{fit.diagnostics.get('heldout_max_abs_z', math.nan):.2f}")
        boot = fit.extra.get("bootstrap") or {}
        if boot:
            frac = boot.get("at_bound_fraction") or {}
            print(f"bootstrap: {boot.get('refits')} refits of {boot.get('attempted')} "
                  f"(requested {boot.get('requested')}; more until every identifiability test "
                  "is decided); stderr Monte Carlo ranges "
                  + ", ".join(f"{k} {lo:.3g}-{hi:.3g}" for k, (lo, hi)
                              in (boot.get("stderr_range") or {}).items())
                  + "; refits at an optimiser bound "
                  + ", ".join(f"{k} {100 * v:.1f} %" for k, v in frac.items()))
        sc = fit.extra.get("base_scatter")
        if sc:
            print(f"bases: {sc['n_bases']} (brackets {sc['brackets_per_base']}, mean offsets "
                  f"from the fit {', '.join(f'{v:+.2f}' for v in sc['mean_offsets'])} deg); "
                  f"between-base sigma_b {sc['sigma_between']:.2f} deg, within a base "
                  f"{sc['sigma_within']:.2f} ("
                  + ("drawn per base in the bootstrap)" if sc["sigma_between"] > 0 else
                     "not resolved above the scatter within a base)"))
        _paper_table().print_paper_rows(rows, closure=False)
        _paper_table().print_curve_rows(paper_curves([fit]))


if __name__ == "__main__":
    main()
