"""The flow rule and alpha of a set of run folders, against Table 1 / Table 2 (issue 14).

For steady runs made outside a campaign (``granflow simulate`` in another box, restarts,
continuations), reads each folder's ``summary.json`` and prints, per run, theta, H, h, F, alpha
and h/hstop(theta; 1); then

* the flow rule Eq. (47), F = beta h/hstop(theta; 1) - gamma, fitted with the project's
  :func:`granflow.fitting.fit_flow_rule` (unweighted; stderrs conditional on the hstop curve),
  once with Table 1's hstop(theta; 1) and once with ``--hstop delta1 delta2 A`` if given;
* the paper's own law (Table 1's beta, gamma at the runs' lambda with Table 1's hstop(theta; 1))
  on the runs: Eq. (49) error of run - law against the paper's fit error (Table 1's err), and
  each run's relative deviation;
* alpha: mean and standard deviation of the runs against Table 2's constant (lambda <= 2/3).

Only runs whose ``flow_state`` is ``steady`` are used; the others are listed and left out.

    .venv/bin/python benchmarks/flow_rule_runs.py RUN_DIR [RUN_DIR ...] [--hstop D1 D2 A]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from granflow.fitting.flow_rule import fit_flow_rule, froude_eq47
from granflow.fitting.hstop import hstop_eq45
from granflow.reference import paper_fit_error, paper_value


def read_runs(dirs) -> list[dict]:
    """theta, H, lambda, h, F, alpha, state of each run folder (its summary.json)."""
    out = []
    for d in dirs:
        if not (Path(d) / "summary.json").is_file():
            raise SystemExit(f"{d}: no summary.json (not a finished run folder)")
        s = json.loads((Path(d) / "summary.json").read_text())
        a, p = s["depth_averages"], s["params"]
        out.append({"run": str(d), "theta": float(p["theta"]), "H": float(p["H"]),
                    "lam": float(p["lam"]), "h": float(a["flow_height"]), "F": float(a["froude"]),
                    "alpha": float(a["alpha"]), "state": s["flow_state"],
                    "box": f"{float(p['Lx']):g} x {float(p['Ly']):g}"})
    return out


def paper_law(runs, lam: float) -> dict:
    """Table 1's law on the runs: Eq. (49) error of F - law, the paper's own error, deviations."""
    hs1 = {k: paper_value("hstop", k, 1.0) for k in ("delta1", "delta2", "A")}
    beta, gamma = (paper_value("flow_rule", k, lam) for k in ("beta", "gamma"))
    h = np.array([r["h"] for r in runs])
    th = np.array([r["theta"] for r in runs])
    F = np.array([r["F"] for r in runs])
    law = froude_eq47(h, th, beta, gamma, **hs1)
    err = float(np.sqrt(np.sum((F - law) ** 2) / (len(F) - 1))) if len(F) > 1 else math.nan
    return {"error": err, "paper": paper_fit_error("flow_rule", lam),
            "deviation": (F / law - 1.0).tolist()}


def fit_with(runs, curve: dict):
    th = np.array([r["theta"] for r in runs])
    return fit_flow_rule(th, [r["h"] for r in runs], [r["F"] for r in runs], curve,
                         lam=runs[0]["lam"], min_points=3, n_bootstrap=0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="run folders (each with summary.json)")
    ap.add_argument("--hstop", type=float, nargs=3, metavar=("DELTA1", "DELTA2", "A"),
                    help="a second hstop(theta; 1) curve (degrees, degrees, d), e.g. a campaign's")
    args = ap.parse_args(argv)
    if args.hstop is not None:
        d1, d2, A = args.hstop
        if not (0 < d1 < d2 < 90 and A > 0):
            raise SystemExit(f"--hstop {d1:g} {d2:g} {A:g}: need 0 < delta1 < delta2 < 90 "
                             "(degrees) and A > 0")
    runs = read_runs(args.runs)
    lams = {r["lam"] for r in runs}
    if len(lams) != 1:
        raise SystemExit(f"runs of one basal roughness only, got lambda = {sorted(lams)}")
    lam = lams.pop()
    table1 = {k: paper_value("hstop", k, 1.0) for k in ("delta1", "delta2", "A")}
    steady = [r for r in runs if r["state"] == "steady"]
    print(f"lambda = {lam:g}, {len(steady)} steady of {len(runs)} runs")
    print("| run | box | theta | H | h | F | alpha | h/hstop (Table 1) | state |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in runs:
        x = r["h"] / hstop_eq45(r["theta"], **table1)
        print(f"| {r['run']} | {r['box']} | {r['theta']:g} | {r['H']:g} | {r['h']:.3f} | "
              f"{r['F']:.4f} | {r['alpha']:.4f} | {x:.2f} | {r['state']} |")
    if len(steady) < 3:
        raise SystemExit("fewer than 3 steady runs: no flow rule")
    curves = [("Table 1 hstop(theta; 1)", table1)]
    if args.hstop is not None:
        curves.append(("--hstop " + " ".join(f"{v:g}" for v in args.hstop),
                       dict(zip(("delta1", "delta2", "A"), args.hstop))))
    beta_p, gamma_p = (paper_value("flow_rule", k, lam) for k in ("beta", "gamma"))
    print(f"\nflow rule, Eq. 47 (Table 1 at lambda = {lam:g}: beta {beta_p:g}, gamma {gamma_p:g})")
    for name, curve in curves:
        f = fit_with(steady, curve)
        ps = ", ".join(f"{k} {f.params[k]:.4g} +- {f.stderr[k]:.2g}" for k in ("beta", "gamma"))
        print(f"- with {name}: {ps}; form {f.form}; Eq. 49 error {f.error:.4g}; {f.status}")
    law = paper_law(steady, lam)
    dev = ", ".join(f"{100 * d:+.1f} %" for d in law["deviation"])
    print(f"- Table 1's law on these runs: Eq. 49 error {law['error']:.4g} against the paper's "
          f"{law['paper']:g} (ratio {law['error'] / law['paper']:.2f}); deviations {dev}")
    al = np.array([r["alpha"] for r in steady])
    const = paper_value("alpha", "alpha_constant", lam)
    line = f"\nalpha: {al.mean():.4f} +- {al.std(ddof=1):.4f} (mean, sd of {al.size})"
    if math.isfinite(const):
        line += f" against Table 2's {const:g} ({100 * (al.mean() / const - 1):+.1f} %)"
    print(line)


if __name__ == "__main__":
    main()
