"""The papers' closure values at their reference parameters, for comparison only.

Weinhart et al. (2012) Table 1 (hstop Eq. 45 and the flow rule Eq. 47 per basal roughness
lambda), Table 2 (shape factor: d_lambda of Eq. 54 or a constant alpha), Eq. (52) (bulk
density), Eq. (53) (stress ratio; Thornton et al. quote d1 = 21.30), and Thornton et al. T-eq.
(29) (Ps(sigma): Pmax, k).  Their species: t_c = 0.005, e = 0.88, mu_c = 0.5, k_t = 2/7 k_n,
gamma_t = gamma_n, box 20 x 10 (segregation: 83.3 x 5, depth 24, 25 degrees).  These numbers
are never used to make a closure; :func:`compare_with_paper` sets a campaign's fits against them.
"""

from __future__ import annotations

import math

import numpy as np

#: (kind, lambda or None, parameter) -> paper value
PAPER = {
    ("hstop", 0.5, "delta1"): 17.913, ("hstop", 0.5, "delta2"): 21.357, ("hstop", 0.5, "A"): 11.959,
    ("flow_rule", 0.5, "beta"): 0.300, ("flow_rule", 0.5, "gamma"): -0.236,
    ("alpha", 0.5, "alpha_constant"): 1.142,
    ("hstop", 2 / 3, "delta1"): 17.217, ("hstop", 2 / 3, "delta2"): 24.302,
    ("hstop", 2 / 3, "A"): 11.088,
    ("flow_rule", 2 / 3, "beta"): 0.215, ("flow_rule", 2 / 3, "gamma"): -0.143,
    ("alpha", 2 / 3, "alpha_constant"): 1.201,
    ("hstop", 5 / 6, "delta1"): 17.425, ("hstop", 5 / 6, "delta2"): 26.828,
    ("hstop", 5 / 6, "A"): 7.465,
    ("flow_rule", 5 / 6, "beta"): 0.203, ("flow_rule", 5 / 6, "gamma"): 0.039,
    ("alpha", 5 / 6, "d_lambda"): 5.105,
    ("hstop", 1.0, "delta1"): 17.708, ("hstop", 1.0, "delta2"): 32.780, ("hstop", 1.0, "A"): 3.355,
    ("flow_rule", 1.0, "beta"): 0.196, ("flow_rule", 1.0, "gamma"): 0.040,
    ("alpha", 1.0, "d_lambda"): 6.678,
    ("hstop", 2.0, "delta1"): 17.518, ("hstop", 2.0, "delta2"): 29.712, ("hstop", 2.0, "A"): 5.290,
    ("flow_rule", 2.0, "beta"): 0.189, ("flow_rule", 2.0, "gamma"): 0.080,
    ("alpha", 2.0, "d_lambda"): 13.75,
    ("density", None, "c0"): 0.5985, ("density", None, "c1"): 4.8,
    ("density", None, "c2"): 40.85,
    ("stress_ratio", None, "d0"): 132.0, ("stress_ratio", None, "d1"): 21.50,
    ("Ps_law", None, "Pmax"): 7.35, ("Ps_law", None, "k"): 5.21,
}


#: (kind, lambda) -> the paper's fit error, Eq. (49) of the residuals over its steady runs:
#: Table 1's err(F) of the flow rule (Eq. 47) and Table 2's error of the shape factor alpha
#: (Eq. 54 for lambda >= 5/6, a constant for lambda <= 2/3).  A campaign's ``fit_error`` near
#: these says its misfit is the closure form's own (the paper's data scatter about it as much),
#: however small each run's own standard error makes chi2/dof.
PAPER_FIT_ERROR = {
    ("flow_rule", 0.0): 0.886, ("flow_rule", 0.5): 0.229, ("flow_rule", 2 / 3): 0.104,
    ("flow_rule", 5 / 6): 0.113, ("flow_rule", 1.0): 0.121, ("flow_rule", 2.0): 0.137,
    ("alpha", 0.0): 0.012, ("alpha", 0.5): 0.01919, ("alpha", 2 / 3): 0.02741,
    ("alpha", 5 / 6): 0.02558, ("alpha", 1.0): 0.01763, ("alpha", 2.0): 0.04479,
}


def paper_fit_error(kind: str, lam) -> float:
    """The paper's Eq. (49) fit error of a closure at basal roughness ``lam`` (NaN if none)."""
    if lam is None or not math.isfinite(float(lam)):
        return math.nan
    for (k, lm), v in PAPER_FIT_ERROR.items():
        if k == kind and abs(lm - float(lam)) < 1e-6:
            return v
    return math.nan


def paper_value(kind: str, parameter: str, lam=None) -> float:
    """The paper's value of a closure parameter (NaN when the paper gives none)."""
    for (k, lm, p), v in PAPER.items():
        if k != kind or p != parameter:
            continue
        if lm is None and lam is None:
            return v
        if lm is not None and lam is not None and abs(lm - float(lam)) < 1e-6:
            return v
    return math.nan


def compare_with_paper(fits, n_sigma: float = 2.0, rel: float = 0.05) -> list[dict]:
    """One row per fitted parameter with a paper value: value, stderr, paper value, the
    difference in stderr units, and whether it agrees -- within ``n_sigma`` of its own stderr,
    or within ``rel`` relative where that is the looser (the issue's "or within 5 % where the
    data allow no better")."""
    rows = []
    for r in fits:
        lam = r.coords.get("lam")
        for p, v in r.params.items():
            ref = paper_value(r.kind, p, lam)
            if not math.isfinite(ref) or r.param_status.get(p) in ("not_in_form", "not_fitted"):
                continue
            se = r.stderr.get(p, math.nan)
            z = (v - ref) / se if math.isfinite(se) and se > 0 else math.nan
            tol = max(n_sigma * se if math.isfinite(se) else 0.0, rel * abs(ref))
            status = r.param_status.get(p, "")
            rows.append({"kind": r.kind, "lambda": lam, "parameter": p, "value": v,
                         "stderr": se, "paper": ref, "z": z,
                         # a parameter the data do not identify agrees with nothing (its
                         # stderr is no measure of it, however close its value)
                         "agrees": bool(math.isfinite(v) and abs(v - ref) <= tol
                                        and status in ("identified", "")),
                         "status": r.state, "parameter_status": status})
    return rows


def paper_law_errors(fits, runs) -> list[dict]:
    """The paper's own law on a campaign's runs: for the flow rule (Eq. 47 with Table 1's beta,
    gamma at the closure's lambda and Table 1's hstop(theta; 1)) and the shape factor (Table 2:
    Eq. 54 with d_lambda, or the constant), the Eq. (49) error of run - paper law over the runs
    each closure of ``fits`` used, against the paper's own fit error (:data:`PAPER_FIT_ERROR`).

    Where the runs span too little of the law's input to separate its parameters (beta and
    gamma from a few angles), single parameters can disagree while the law describes the runs
    as well as it described the paper's (ratio <= 1).  ``fits``: FitResults or their dicts
    (``fits.json``); ``runs``: the campaign table (DataFrame with run, theta, h, F, alpha).
    Returns one dict per closure: closure, lambda, n, error, paper, ratio, mean and worst
    relative deviation."""
    import numpy as np

    from .fitting.flow_rule import froude_eq47
    from .fitting.hstop import hstop_eq45
    from .fitting.shape_factor import alpha_eq54

    by_run = runs.set_index("run")
    hs1 = {k: paper_value("hstop", k, 1.0) for k in ("delta1", "delta2", "A")}
    rows = []
    for f in fits:
        if not isinstance(f, dict):
            f = {"kind": f.kind, "coords": f.coords, "runs_used": list(f.runs_used)}
        kind, lam = f.get("kind"), (f.get("coords") or {}).get("lam")
        used = [r for r in f.get("runs_used") or [] if r in by_run.index]
        if kind not in ("flow_rule", "alpha") or lam is None or len(used) < 2:
            continue
        ref = paper_fit_error(kind, lam)
        if not math.isfinite(ref):
            continue
        t = by_run.loc[used]
        h, theta = t["h"].to_numpy(float), t["theta"].to_numpy(float)
        if kind == "flow_rule":
            beta, gamma = (paper_value("flow_rule", p, lam) for p in ("beta", "gamma"))
            law = froude_eq47(h, theta, beta, gamma, **hs1)
            y = t["F"].to_numpy(float)
        else:
            y = t["alpha"].to_numpy(float)
            const = paper_value("alpha", "alpha_constant", lam)
            if math.isfinite(const):
                law = np.full(y.shape, const)
            else:
                law = alpha_eq54(h, hstop_eq45(theta, **hs1),
                                 paper_value("alpha", "d_lambda", lam))
        res = y - law
        err = float(np.sqrt(np.sum(res ** 2) / (res.size - 1)))
        rows.append({"closure": kind, "lambda": float(lam), "n": len(used), "error": err,
                     "paper": ref, "ratio": err / ref,
                     "worst": float(np.max(np.abs(res / law))),
                     "mean": float(np.mean(res / law))})
    return rows


def _curve_specs():
    """closure kind -> (law of (x, params), parameter names, x variable, description)."""
    from .fitting.bulk import stress_ratio_eq53
    from .fitting.hstop import theta_stop_eq45
    from .fitting.segregation import Ps_teq29

    return {
        "hstop": (lambda x, p: theta_stop_eq45(x, p["delta1"], p["delta2"], p["A"]),
                  ("delta1", "delta2", "A"), "H",
                  "theta_stop(H) (deg) at the fit's two-sided bracket heights"),
        "density": (lambda x, p: p["c0"] - np.exp((x - p["c2"]) / p["c1"]), ("c0", "c1", "c2"),
                    "theta", "rho_c/rho_p (Eq. 52) over the fitted angles"),
        "stress_ratio": (lambda x, p: stress_ratio_eq53(x, p["d0"], p["d1"]), ("d0", "d1"),
                         "theta", "K (Eq. 53) over the fitted angles"),
        "Ps_law": (lambda x, p: Ps_teq29(x, p["Pmax"], p["k"]), ("Pmax", "k"), "sigma",
                   "Ps (T-eq. 29) over the fitted size ratios"),
    }


def paper_curves(fits, n_sigma: float = 2.0, rel: float = 0.05, n_grid: int = 9) -> list[dict]:
    """The papers' closure curves against the fitted ones, in the variable a user reads off.

    Per-parameter agreement can hide a curve that lies off the paper's everywhere: hstop's
    delta1 and A are strongly anticorrelated (bootstrap correlation -0.9 and beyond), so each
    can sit within 2 of its wide stderr while the curve, which the data pin far better, does
    not (and likewise c0, c1, c2 of Eq. 52).  For every fit of a full form with paper values
    (hstop: theta_stop(H) at its two-sided bracket heights; density, K: at ``n_grid`` angles
    over its fitted range; Ps law: over its size ratios) the mean over those points of ours -
    the paper's, its stderr from the fit's ensemble (half the central 68 % range of each
    sample's mean difference over the same points), z, the difference relative to the paper's
    mean value, the largest pointwise |z| (each point against the ensemble's spread there), and
    ``agrees`` by the rule of :func:`compare_with_paper` (within ``n_sigma`` stderr, or within
    ``rel`` of the value where that is looser) with ``within_stderr`` saying which rule it met.
    ``fits``: FitResults or their dicts (``fits.json``)."""
    from .campaign.serialize import fit_from_dict
    from .fitting.result import bootstrap_stderr

    specs = _curve_specs()
    rows = []
    for f in fits:
        if isinstance(f, dict):
            f = fit_from_dict(f)
        if f.kind not in specs or f.state == "failed" or f.form not in ("full", ""):
            continue
        law, names, xname, what = specs[f.kind]
        lam = f.coords.get("lam") if f.kind == "hstop" else None  # Eq. 52, 53, T-eq. 29: none
        if f.kind == "hstop" and lam is None:
            continue
        ref = {k: paper_value(f.kind, k, lam) for k in names}
        ours = {k: f.params.get(k, math.nan) for k in names}
        if not all(math.isfinite(v) for v in (*ref.values(), *ours.values())):
            continue
        if f.kind == "hstop":
            iv = (f.extra or {}).get("intervals") or {}
            lo, hi = (np.asarray(iv.get(k, []), dtype=float) for k in ("lo", "hi"))
            x = np.unique(np.asarray(iv.get("H", []), dtype=float)[np.isfinite(lo)
                                                                   & np.isfinite(hi)])
        else:
            rng = (f.valid_range or {}).get(xname)
            x = (np.linspace(float(rng[0]), float(rng[1]), n_grid) if rng is not None
                 and all(math.isfinite(float(v)) for v in rng) else np.zeros(0))
        ens = f.ensemble_array()
        if x.size == 0 or len(ens) < 10:
            continue
        cols = list(f.params)
        samples = [dict(zip(cols, e)) for e in ens]
        y_ours, y_paper = law(x, ours), law(x, ref)
        curves = np.array([law(x, smp) for smp in samples])
        curves = curves[np.all(np.isfinite(curves), axis=1)]
        if len(curves) < 10:
            continue
        diff = float(np.mean(y_ours - y_paper))
        se = bootstrap_stderr(curves.mean(axis=1))
        se_x = np.array([bootstrap_stderr(curves[:, j]) for j in range(x.size)])
        z_x = (y_ours - y_paper) / np.where(se_x > 0, se_x, np.nan)
        scale = float(np.mean(np.abs(y_paper)))
        within_se = bool(abs(diff) <= n_sigma * se)
        rows.append({"closure": f.kind, "lambda": lam,
                     "contact_law": f.coords.get("contact_law", ""), "variable": what,
                     "x": xname, "points": x.tolist(), "mean_difference": diff, "stderr": se,
                     "z": diff / se if se > 0 else math.nan, "relative": diff / scale,
                     "max_abs_z_pointwise": float(np.nanmax(np.abs(z_x))),
                     "agrees": within_se or abs(diff) <= rel * scale,
                     "within_stderr": within_se, "status": f.state})
    return rows


#: Measured effect of the soft species t_c = 0.02 (the embedded default's) against the paper's
#: t_c = 0.005, everything else equal (e = 0.88, mu_c = 0.5, lambda = 1, box 10 x 5, 5-layer base,
#: same seeds and base; granflow at commit 4b678ff, 2026-11-23).  (soft, paper) per theta at
#: H = 10, value +- within-run sem: F, nu_c (bulk packing fraction), K, alpha; hstop brackets
#: [arrested, flowing] in degrees per H.  This is granflow's own measurement, not the paper's.
SOFT_SPECIES_EFFECT = {
    "t_c": (0.02, 0.005),
    "steady_H10": {
        23.0: {"F": (0.1761, 0.1250), "nu_c": (0.5713, 0.5756), "K": (1.0420, 1.0510),
               "alpha": (1.5055, 1.5737)},
        25.0: {"F": (0.4059, 0.3675), "nu_c": (0.5572, 0.5585), "K": (1.0193, 1.0208),
               "alpha": (1.3898, 1.4166)},
        27.0: {"F": (0.7912, 0.6057), "nu_c": (0.5364, 0.5464), "K": (1.0053, 1.0358),
               "alpha": (1.3357, 1.3766)},
    },
    "hstop_brackets": {2.0: ((28.1, 28.6), (28.6, 29.1)), 4.0: ((25.55, 26.05), (25.05, 25.55)),
                       8.0: ((23.05, 23.55), (22.55, 23.05))},
}


def soft_species_note(t_c: float) -> str:
    """What the measured :data:`SOFT_SPECIES_EFFECT` says a campaign at ``t_c`` inherits ('' when
    ``t_c`` is the paper's or not the measured soft value)."""
    soft, paper = SOFT_SPECIES_EFFECT["t_c"]
    if not math.isclose(float(t_c), soft, rel_tol=1e-6):
        return ""
    rows = SOFT_SPECIES_EFFECT["steady_H10"]
    dF = [100.0 * (r["F"][0] / r["F"][1] - 1.0) for r in rows.values()]
    dnu = [r["nu_c"][0] - r["nu_c"][1] for r in rows.values()]
    dal = [100.0 * (r["alpha"][0] / r["alpha"][1] - 1.0) for r in rows.values()]
    shifts = [0.5 * (s[0] + s[1]) - 0.5 * (p[0] + p[1])
              for s, p in SOFT_SPECIES_EFFECT["hstop_brackets"].values()]
    return (f"measured bias of t_c = {soft:g} against the paper's {paper:g} (lambda = 1, H = 10, "
            f"theta = 23-27 deg, 10 x 5 box): Froude number {min(dF):+.0f} to {max(dF):+.0f} %, "
            f"packing fraction {min(dnu):+.3f} to {max(dnu):+.3f}, alpha {min(dal):+.0f} to "
            f"{max(dal):+.0f} %, hstop bracket centres {min(shifts):+.2f} to {max(shifts):+.2f} deg "
            "(granflow.reference.SOFT_SPECIES_EFFECT); larger than most stated stderrs: use the "
            "paper's species (config/reference-lambda1.yaml) for numbers to compare with the paper")


#: Measured effect of the segregation set-up's reductions on Ps (T-eq. 28 fitted to one run's
#: steady phi(z), stderr of the mean over decorrelated windows) at sigma = 0.6, 25 deg, the
#: paper's species, rough base of fixed small particles (granflow at commit ef27ba9,
#: 2026-11-23): (box length, filling height, t_c) -> Ps.  The paper's law at sigma = 0.6 gives
#: 7.12 (83.3 x 5 box, depth 24).  Depth is what moves Ps; box length and stiffness little.
#: The depth-16 run was integrated to t = 800 (its segregated state levels off at t ~ 590); the
#: segregated-state stop rule had stopped it at t = 361 with Ps 5.89, still segregating.
SEGREGATION_REDUCTION_EFFECT = {
    "sigma": 0.6,
    "Ps": {(10.0, 8.0, 0.005): (14.06, 0.55), (40.0, 8.0, 0.005): (12.35, 0.55),
           (10.0, 16.0, 0.005): (8.41, 0.10), (10.0, 8.0, 0.02): (14.4, None)},
    # runs whose segregated state the stop rule (granflow.steady.segregation) did not show
    # steady by their end: their Ps is a lower bound (Ps grows while the layer segregates:
    # 5.89 at t = 361, 8.41 at t = 800 in the depth-16 run, 0.09 d of the indicator to come)
    "lower_bounds": {(10.0, 16.0, 0.005), (40.0, 8.0, 0.005)},
}

#: Ps measured at the paper's segregation set-up itself (config/reference-segregation.yaml at
#: 80e1669, 2026-11-29: 83.3 x 5 box, 5000 small particles, depth 24, 25 deg, the paper's
#: species, 12-layer base of fixed small particles): 1/sigma = 2, two insertion seeds, each
#: stopped once its segregated state was shown steady (t = 1221 and 1251), T-eq. (28) on the
#: steady phi(z), stderr of the mean over decorrelated windows; flow height h of each run.
#: The law T-eq. (29) gives 7.35 (1 - e^-5.21) = 7.31: both seeds lie 6.8 % below it, 0.15 %
#: apart, so the difference is not the seed (it is 2.0x the 95 % interval's half-width of one
#: run's fit, +-0.25, and 1.8 points beyond the issue's 5 %).  Not tested: the paper's base (fixed
#: small particles added randomly to a flat surface).
#:
#: ``window``: the depth over which z is scaled to [0, 1] (measured 2026-11-29 on the same two
#: runs' steady profiles, T-eq. 28 refitted with phi0 the profile's mean; seed 1, seed 2 within
#: 0.2 %): window name -> (its depth in d, Ps).  Ps is per unit *scaled* depth, so it grows with
#: the window: Ps / depth = 0.308-0.314 per d over windows 19.9-24.0 d deep (the sharp interface,
#: 1 / 0.312 = 3.2 d wide, is what the profile fixes).  The paper does not say how it scaled
#: depth (002 Fig. 8: "scaled depth"); the law's 7.31 is this profile scaled by 23.5 d.  A 5 %
#: comparison of Ps therefore needs the paper's depth definition to 1.1 d; fixing phi0 = 0.5
#: instead of the profile's mean moves Ps by < 0.1 %.
SEGREGATION_PAPER_SETUP = {
    "sigma": 0.5, "law": 7.35 * (1.0 - math.exp(-5.21)),
    "Ps": {1: (6.821, 0.032), 2: (6.811, 0.013)},  # seed -> (Ps, stderr)
    "h": {1: 21.87, 2: 21.88},
    "window": {
        "[b, s] of Eq. (42) (granflow's)": (21.87, 6.821),
        "[z1, z2] of Eq. (42) (its thresholds)": (21.43, 6.662),
        "[b + 1, s - 1]": (19.87, 6.120),
        "total volume fraction above half its bulk value": (21.55, 6.708),
        "[b, b + 24.01] (the nominal filling height)": (24.01, 7.551),
    },
    # the size-ratio sweep at the same set-up, one run per (1/sigma, seed), each stopped once
    # its segregated state was shown steady: 1/sigma -> [(Ps, stderr, scaled depth h, t at the
    # stop, CPU seconds)]; law T-eq. 29 with the paper's Pmax 7.35, k 5.21.  "Shown steady"
    # by the exponential projection of the change to come (before 2026-12-07), not re-checked
    # with the stretched one that replaced it (the runs' series are not kept)
    "sweep": {
        2.0: [(6.821, 0.032, 21.87, 1221.0, 2788.0), (6.811, 0.013, 21.88, 1251.0, 2940.0)],
        1.75: [(7.345, 0.037, 22.11, 1522.0, 3797.0)],
        1.5: [(6.539, 0.054, 22.28, 2051.0, 5413.0)],
    },
    # T-eq. 29 fitted to the sweep as recorded here (fit_Ps_law, runs weighted by their
    # stderrs): every ratio on the plateau, k not identified (stderr 9.2 on 8.0), the plateau
    # form kept (weighted chi-square 222 for 3 dof: the runs scatter 8.6x their stderrs,
    # 1/sigma = 1.75 lying 7 % above its neighbours); Pmax = plateau +- stderr (Birge-inflated),
    # one-sided 95 % bounds
    "fit": {"form": "plateau", "Pmax": (6.849, 0.096), "Pmax_lower_bound": 6.821,
            "k_lower_bound": 3.005,
            # with the two one-sided runs of "bounds" at 1/sigma = 1.25 (fit_Ps_law's
            # k_interval, 95 % jointly)
            "k_interval_with_bounds": (5.129, 9.661),
            # T-eq. 29 fitted to every start's latest reading (2026-12-07 evening): the seed-2
            # mixed start of "sweep" at 2, the seed-1 mixed start continued (bounds[2.0][2]),
            # the run from above at 2, the 1.75 and 1.5 runs, and both starts at 1.25 with
            # their tail means +- wander (bounds[1.25]); runs weighted by their stderrs,
            # Birge-inflated (9.6x): Pmax 5.1 % below the paper's 7.35 (z -3.9), k agrees
            # (z +0.9, +30 %) with a 26 % stderr
            "all_starts": {"Pmax": (6.979, 0.095), "k": (6.751, 1.760)},
            # the same points, each stderr at least the wander at its number of flow particles
            # (granflow.fitting.segregation.wander_sd: 5625-7560 particles, 0.10-0.16; the
            # floor measured on the 1.25 tails accounts for most of the other ratios' scatter,
            # Birge 9.6 -> 1.75): Pmax 4.2 % below the paper's (z -2.3), k 22 % above (z +2.2)
            "all_starts_with_wander": {"Pmax": (7.043, 0.132), "k": (6.374, 0.518),
                                       "birge": 1.75,
                                       # leave-one-out z of the 7 points (fit_Ps_law's
                                       # heldout_z; 1/sigma 2, 2, 2, 1.75, 1.5, 1.25, 1.25):
                                       # max |z| 2.04 at 1.75 against its limit 3.55
                                       "heldout_z": (-1.08, -0.28, 0.75, 2.04, -1.04, -0.89,
                                                     1.22),
                                       # its prediction at 1/sigma = 1.1 (delta method; one
                                       # run there adds its wander at 8757 particles, 0.058)
                                       "Ps_at_1.1": (3.319, 0.158)}},
    # runs stopped while their segregated state still drifted, each a one-sided bound on its
    # steady Ps (2026-12-07, seed 1, one core each on a 2-vCPU Zen 3 host): at 1/sigma = 1.25,
    # started on T-eq. 28's profiles at Ps 3.5 and 7 (start~profile3.5, start~profile7), run to
    # t = 477 and 478 (4103 and 4081 s of CPU), then continued from their final states
    # (granflow simulate --from, same inclination, early_stop false): the profile3.5 run four
    # times, for 600, 600, 297 and 1044 time units (to t = 3018.8, 9708 + 4149 + 2080 + 8632 s
    # of CPU in all; the fourth read from its checkpoint at t = 1044.2 while it goes on), the
    # profile7 run twice, for 600 and 103.3 (to t = 1181.0, 9716 + 744 s); Ps and its stderr
    # over the last 200 time units (the mean and standard error of the chain's last four
    # 50-unit windows, benchmarks/segregation_approach.py with --parent; until 2026-12-07 noon
    # the profile3.5 bound was the campaign row's, 5.129 +- 0.035 at t = 1974.6); side +1 a
    # lower bound, -1 an upper bound.  The bracket was [4.079 +- 0.038, 6.324 +- 0.062] at
    # t = 477, [4.507, 5.831] at t = 1077, [5.129, 5.807] at t = 1975, [5.395, 5.807] at
    # t = 2675, [5.559, 5.807] at t = 3019 (not bounds beyond the wander found later: below):
    # the profile3.5 run rose 4.58 -> 4.98 over its second continuation, 5.01 -> 5.22 over its
    # third and 5.22 -> 5.54 over its fourth (5.31-5.38 for t = 2073-2573, 5.40-5.45 to
    # t = 2773, then 5.52, 5.56, 5.56, 5.57, 5.54: slowing, not stopped), the profile7 run
    # fell 6.97 -> 5.80, by 0.01 per 50 units at the end.  The paper's law gives 5.35 here: the run from below has passed it.  Exponential relaxations fitted to the two series disagreed
    # at t = 1077 (4.77 +- 0.06 rising, 5.60 +- 0.06 falling); a stretched one (the steady
    # detector's since 2026-12-07) gave 5.08 +- 0.90 (beta 0.81) and 5.27 +- 0.69 (beta 0.78)
    # then; the rising series since rose nearly linearly and extrapolates to nothing useful
    # (16 +- 54 at t = 1975): the approach is not a relaxation that extrapolates, and only the
    # bracket is a measurement.  At 1/sigma = 2 a run started on the profile at Ps 8.5
    # (start~profile8.5) fell 8.33 -> 7.18 by t = 600 (3356 s of CPU) and, continued for 499.5
    # (3146 s), stayed at 7.10-7.28: its segregated state is shown steady (steady: True) at
    # Ps 7.205 +- 0.018 over its last 200 units (t = 1099.5), while the two mixed starts of
    # "sweep" were shown steady at 6.821 and 6.811: two states 5.6 % apart that each pass the
    # steady test, so a single run's steady Ps carries a start-dependent error of that size
    # (the paper's law gives 7.31 here, 1.5 % above the run from above).  Rerun under today's
    # detector the seed-1 mixed start stops later (t = 1350.5, 8362 s of CPU) at 6.886 +-
    # 0.009, still 4.6 % below the run from above; continued (early_stop false) it rose on,
    # windows 6.89, 6.93, 6.97, 7.04, 6.92 over t = 1350-1600 (to t = 1644 in 3540 s of wall
    # on one core; its checkpoint read 2026-12-07): 6.965 +- 0.027 over its last four windows,
    # 3.4 % below the run from above: that verdict came early for Ps, and whether the two
    # starts meet is not decided
    "bounds": {
        # the evening of 2026-12-07 both runs were continued again (the profile3.5 run to
        # t = 4021, the profile7 run to t = 1965): neither approach is monotone.  The run from
        # below rose to 5.59 (t = 3100) and fell back to 5.22-5.28 (t = 3874-4021); the run
        # from above, flat at 5.80-5.87 for 550 units, fell to 5.65-5.77 (t = 1500-1965); the
        # indicator s moved with Ps (-3.85 -> -3.98 -> -3.92), u_bar did not: the segregated
        # state itself wanders by 0.1-0.4 in Ps over hundreds of time units.  So the last four
        # windows' mean +- sem (the bounds above: 5.559 +- 0.006 at t = 3019) are not bounds
        # beyond that wander; recorded now: each run's mean since it reached its level
        # (t >= 2799 and t >= 903: 24 and 21 50-unit windows), stderr the standard deviation of
        # its 200-unit means (6 and 5 blocks: 5.56, 5.58, 5.54, 5.44, 5.36, 5.27 and 5.81, 5.84,
        # 5.78, 5.66, 5.72; not divided by their number: the wander outlasts a block).  The
        # paper's 5.35 lies inside the run from below's range (5.22-5.59), 0.3-0.5 below the
        # run from above's (5.65-5.87).  (Read 2026-12-07 20:10 from the runs' last checkpoints;
        # until then 5.490 +- 0.099 to t = 3874 and 5.779 +- 0.074 to t = 1824.)
        1.25: [dict(start="profile3.5", Ps=5.459, stderr=0.123, side=1.0, t_end=4021.0,
                    cpu_s=34510.0),
               dict(start="profile7", Ps=5.768, stderr=0.071, side=-1.0, t_end=1965.0,
                    cpu_s=18210.0)],
        2.0: [dict(start="profile8.5", Ps=7.205, stderr=0.018, side=-1.0, t_end=1099.5,
                   cpu_s=6502.0, steady=True),
              # the sweep's seed-1 mixed start rerun under the detector of 2026-12-07
              # (early_stop true; the same trajectory up to the sweep's stop at t = 1221: its
              # windows there average 6.821, the old run's value): shown steady at t = 1350.5
              # (s plateau -4.27, change to come 0.073 within 0.107); windows 6.84, 6.89, 6.90, 6.89, 6.86 over
              # t = 1100-1350; continued with early_stop false in results/seg-mixed2-continue
              dict(start="mixed", Ps=6.886, stderr=0.009, side=1.0, t_end=1350.5,
                   cpu_s=8362.0, steady=True),
              # the same run continued past that verdict (early_stop false; cpu_s adds the
              # continuation's wall time on one core): still a lower bound
              dict(start="mixed", Ps=6.965, stderr=0.027, side=1.0, t_end=1600.5,
                   cpu_s=11902.0, steady=False)],
    },
}


# Seeds at the default campaign's segregation set-up (config/config.yaml merged with
# config/replicates-segregation.yaml: 10 x 5 box, filling height 8, 25 deg, the paper's
# species, mixed starts, early stop, cap t = 1500; three insertion seeds per ratio; run
# 2026-12-07 on a 2-vCPU AMD EPYC Zen 3 host, code of 0801f5b, 31.6 min on 2 cores, 7379 time
# units in 9 runs): sigma -> [(Ps, its within-run stderr (the standard error of its profile
# windows' mean), segregated state, t at the stop)], seed 1, 2, 3.  The seed-1 runs are the
# default campaign's own (the same numbers).  "drifting": the centre of mass was shown steady
# while Ps still moved over the windows (a lower bound after a mixed start).  Where the runs are
# steady they scatter 2.0x (sigma 0.6) and 9.4x (sigma 0.9) more than their own stderrs say.
#: flow particles of those runs per size ratio (summary.json ``n_flow``; the same for every seed)
SEGREGATION_DEFAULT_N_FLOW = {0.6: 243, 0.75: 284, 0.9: 346}
SEGREGATION_DEFAULT_REPLICATES = {
    0.6: [(14.023, 0.685, "drifting", 581.0), (14.206, 0.713, "steady", 381.0),
          (16.233, 0.689, "steady", 331.0)],
    0.75: [(8.966, 0.228, "drifting", 771.0), (12.642, 1.270, "steady", 641.0),
           (11.112, 0.239, "drifting", 791.0)],
    0.9: [(3.904, 0.029, "steady", 1421.0), (4.952, 0.026, "steady", 1311.0),
          (4.216, 0.091, "steady", 1151.0)],
}
#: the same runs' segregated states under today's rule (2026-12-08: a Ps trend counts only
#: beyond 3 C / sqrt(N), granflow.campaign.collect.ps_trend_tolerance): the three runs above
#: that were "drifting" (trends +20.2, +15.5 and -11.7 % against tolerances of 31, 29 and 29 %)
#: are steady (results/replicates-segregation-wander, library v4, re-derived with --forcerun row)
SEGREGATION_DEFAULT_REPLICATES_STATE_NOW = {
    0.6: ("steady", "steady", "steady"), 0.75: ("steady", "steady", "steady"),
    0.9: ("steady", "steady", "steady")}

# Is that scatter wander in time or a state each seed keeps?  Runs of seeds 1 and 2 continued
# from their final states (granflow simulate --from, early_stop false; results/seg-wander09,
# results/seg-wander075; 2026-12-07, one core each): at sigma = 0.9 (Ps 3.904 and 4.952 at their
# stop) for 2000 time units (1018 and 1030 s of CPU): seed 1 rose from 3.64 to 5.47 within 400
# units and both wandered over the same range; at sigma = 0.75 (8.966 drifting and 12.642
# steady at their stop) for 1500 (656 s each): the drifting run rose to 10-12 and both wandered
# over 8-15.  Over t >= 1000 (0.9) and t >= 900 (0.75) to the end of the chain: sigma -> seed ->
# (mean Ps of the 20-unit windows, its standard error with their autocorrelation, the standard
# deviation of 60-unit means (a profile window's Ps), smallest and largest 200-unit mean, the
# windows' autocorrelation time (1/e) in time units; benchmarks/segregation_wander.py).  At each ratio the two means agree: one
# state, whose Ps a 60-unit profile window samples with a spread of 8-10 % (0.9) and 9-10 %
# (0.75) of it; the default campaign's own runs stopped at 3.90 (0.6 below the long mean) and
# 8.97 (a lower bound that holds).
# sd_300: the same for 300-unit means (added 2026-12-07 late, SEGREGATION_WANDER_SCALING).
SEGREGATION_DEFAULT_WANDER = {
    0.9: {1: dict(Ps=4.638, stderr=0.193, sd_60=0.482, block_200=(3.90, 5.29), acf_time=260.0,
                  t=(1000.0, 3421.0), sd_300=0.465),
          2: dict(Ps=4.514, stderr=0.111, sd_60=0.360, block_200=(4.07, 5.06), acf_time=140.0,
                  t=(1000.0, 3311.0), sd_300=0.268)},
    0.75: {1: dict(Ps=10.630, stderr=0.326, sd_60=0.969, block_200=(9.13, 11.50), acf_time=80.0,
                   t=(900.0, 2271.0), sd_300=0.635),
           2: dict(Ps=10.482, stderr=0.272, sd_60=1.057, block_200=(9.66, 11.14), acf_time=40.0,
                   t=(900.0, 2141.0), sd_300=0.612)},
}


# Would a longer profile window make one run's stderr honest?  Over the same continued runs
# (SEGREGATION_DEFAULT_WANDER's spans), the means of consecutive windows of L time units
# scatter by more than each window's own autocorrelated standard error of the mean
# (granflow.steady.timeseries.standard_error_of_mean of its 20-unit windows' Ps) says:
# L -> (smallest, largest) ratio over the four runs (sigma 0.75 and 0.9, two seeds each;
# benchmarks/segregation_wander.py).
# Averaging five times longer only halves the understatement: the wander outlasts the window.
SEGREGATION_WINDOW_SEM_RATIO = {60.0: (2.0, 8.1), 120.0: (2.0, 6.9), 300.0: (1.4, 4.3)}


# How far one run's Ps (the mean over its profile window) lies from its state's long-time mean,
# against the number of flow particles N: the standard deviation of profile-window-length means
# of Ps, relative to the long mean, times sqrt(N).  A run cannot measure this itself (the
# wander's autocorrelation time, 40-300 time units, is as long as a whole profile window), so a
# run's Ps stderr takes the larger of its windows' own standard error and C Ps / sqrt(N)
# (granflow.fitting.segregation.wander_sd).  Measured 2026-12-07 (benchmarks/segregation_wander.py
# on the long runs of SEGREGATION_DEFAULT_WANDER and on the paper set-up's two 1/sigma = 1.25
# tails of SEGREGATION_PAPER_SETUP["bounds"]): (set-up, sigma, N flow particles, averaging length
# of one mean (the set-up's profile window) in time units, relative sd of those means, sd of
# 300-unit means relative, what).  C = rms of rel sd * sqrt(N) at the profile window: 1.63
# (1.12-1.93 over the six, the paper set-up's 20x more particles wandering 4.7x less, as
# 1 / sqrt(N) says); 300-unit means give an rms of 1.43 (0.98-2.01), 600-unit means at the
# default set-up about the same as 300 (the wander is not averaged away within a run), so C is
# kept for every window length.  Over Ps 4.5-15.2 (the default's sigma = 0.6 seeds, 2 steady,
# scatter by 9.4 % at N = 243: C 1.47, not in the rms).
SEGREGATION_WANDER_SCALING = {
    "points": [
        # the default set-up's four continued runs (SEGREGATION_DEFAULT_WANDER)
        *[("default 10 x 5, depth 8, 25 deg", sigma, SEGREGATION_DEFAULT_N_FLOW[sigma], 60.0,
           w["sd_60"] / w["Ps"], w["sd_300"] / w["Ps"],
           f"seed {seed} continued, t >= {w['t'][0]:g}")
          for sigma, seeds in SEGREGATION_DEFAULT_WANDER.items() for seed, w in seeds.items()],
        # the paper set-up's 1/sigma = 1.25 tails (SEGREGATION_PAPER_SETUP["bounds"][1.25])
        ("paper 83.3 x 5, depth 24, 25 deg", 0.8, 7560, 50.0, 0.118 / 5.459, 0.126 / 5.459,
         "from below (mixed), t >= 2799"),
        ("paper 83.3 x 5, depth 24, 25 deg", 0.8, 7560, 50.0, 0.074 / 5.768, 0.084 / 5.768,
         "from above (profile 7), t >= 903"),
    ],
}
SEGREGATION_WANDER_C = float(np.sqrt(np.mean(
    [(p[4] * np.sqrt(p[2])) ** 2 for p in SEGREGATION_WANDER_SCALING["points"]])))

# Held out: C was fixed (1.631, written down 2026-12-07 22:58 UTC) before two new runs at the
# default's set-up in longer boxes had passed their approach: sigma = 0.75, mixed start, seed
# 1, early_stop false, one core each (results/seg-wander20x5/s0: 20 x 5, 569 flow particles,
# to t = 3000, 2532 s of CPU; results/seg-wander40x5/s0: 40 x 5, 1138, to t = 2200, 3520 s).
# Box -> (N, predicted C / sqrt(N), measured relative sd of 60-unit means of Ps over t >= 900
# (as the default's sigma = 0.75 records), mean Ps there, the same from t >= 1000 and 800).
# Measured / predicted: 1.28 (20 x 5; 1.03 from t = 1000, one 100-unit excursion to 12.2 at
# t = 940 in the stretch or not) and 0.96 (40 x 5); a relative spread that did not fall with
# N (the default's 9.4 %) would be 2.0x the 40 x 5 box's.
SEGREGATION_WANDER_HELD_OUT = {
    (20.0, 5.0): dict(n_flow=569, predicted=0.0684, rel_sd_60=0.862 / 9.824, Ps=9.824,
                      rel_sd_60_from_1000=0.682 / 9.707, rel_sd_60_from_800=0.837 / 9.839),
    (40.0, 5.0): dict(n_flow=1138, predicted=0.0484, rel_sd_60=0.461 / 9.872, Ps=9.872,
                      rel_sd_60_from_1000=0.431 / 9.930, rel_sd_60_from_800=0.476 / 9.847),
}


# Does a trend of Ps over a run's profile windows say the run is still moving?  The campaign
# counts a run as drifting (its Ps a one-sided bound on the side the trend points to) when the
# trend is significant and larger than a tolerance (granflow.campaign.collect.ps_still_moving).
# Replayed 2026-12-08 (benchmarks/segregation_trend_calibration.py) on every stretch of n
# consecutive windows (20 time units each at the default set-up and its longer boxes, 50 at the
# paper's) of the long runs of SEGREGATION_WANDER_SCALING and SEGREGATION_WANDER_HELD_OUT:
# (series, N flow particles, steady from t (chain time; the mean after it is the long mean),
# {n: (stretches, flags of the 5 % rule, of them pointing towards the long mean, flags of the
# rule with the wander tolerance 3 C / sqrt(N), of them towards)}).  On the steady tails the
# 5 % rule (before 2026-12-08) flagged 15-56 %, half of them pointing the wrong way; the wander
# rule 0-12 % (pooled 0.8, 2.6, 3.6 % at n = 4, 6, 10 on the four default tails, on which its
# multiple 3 was chosen as the smallest of 1.5, 2, 2.5, 3 with a pooled rate <= 5 %; the other
# four tails, seen at the same time, 0, 1.0, 4.5 %).  On the approaches of the two mixed starts
# it keeps 26 of 40, 35 of 54 and 42 of 55 of the 5 % rule's flags, all but one of them
# pointing towards the plateau.
SEGREGATION_TREND_CALIBRATION = {
    "steady": [
        ("default 10 x 5, sigma 0.9, seed 1 continued", 346, 1000.0,
         {4: (118, 20, 13, 0, 0), 6: (116, 38, 19, 0, 0), 10: (112, 55, 28, 0, 0)}),
        ("default 10 x 5, sigma 0.9, seed 2 continued", 346, 1000.0,
         {4: (113, 18, 9, 0, 0), 6: (111, 40, 16, 0, 0), 10: (107, 60, 25, 4, 0)}),
        ("default 10 x 5, sigma 0.75, seed 1 continued", 284, 900.0,
         {4: (65, 10, 4, 0, 0), 6: (63, 10, 5, 2, 1), 10: (59, 30, 15, 3, 0)}),
        ("default 10 x 5, sigma 0.75, seed 2 continued", 284, 900.0,
         {4: (59, 13, 6, 3, 1), 6: (57, 21, 13, 7, 4), 10: (53, 16, 8, 5, 4)}),
        ("20 x 5, sigma 0.75", 569, 900.0,
         {4: (102, 18, 9, 0, 0), 6: (100, 31, 19, 0, 0), 10: (96, 38, 20, 4, 4)}),
        ("40 x 5, sigma 0.75", 1138, 900.0,
         {4: (62, 12, 6, 0, 0), 6: (60, 19, 10, 2, 1), 10: (56, 22, 12, 4, 3)}),
        ("paper 83.3 x 5, 1/sigma 1.25, from below", 7560, 2799.0,
         {4: (21, 0, 0, 0, 0), 6: (19, 0, 0, 0, 0), 10: (15, 0, 0, 0, 0)}),
        ("paper 83.3 x 5, 1/sigma 1.25, from above", 7560, 903.0,
         {4: (18, 0, 0, 0, 0), 6: (16, 0, 0, 0, 0), 10: (12, 0, 0, 0, 0)}),
    ],
    "approach": [
        ("20 x 5, sigma 0.75, t < 900", 569, 900.0,
         {4: (42, 22, 22, 10, 10), 6: (40, 30, 27, 18, 18), 10: (36, 29, 29, 22, 22)}),
        ("40 x 5, sigma 0.75, t < 900", 1138, 900.0,
         {4: (42, 18, 17, 16, 16), 6: (40, 24, 23, 17, 16), 10: (36, 26, 24, 20, 20)}),
    ],
}


# Is the wander physics or granflow's engine?  An independent engine on the same state
# (2026-12-08): LAMMPS pair_style granular (engine: lammps, the same species pair by pair)
# continued granflow's sigma = 0.75 default-set-up state (results/seg-wander075/s0's final
# state, seed 1; granflow simulate --from, early_stop false, tangential springs restarted from
# zero) for 900 time units (results/seg-lammps075, 2438 s wall, 2979 s CPU on one core beside
# another run; its expectation written down first in prediction.md).  Over t >= 100 (40
# windows of 20): the mean Ps, its autocorrelated stderr, the sd of 60-unit means (relative,
# and times sqrt(N): C), the windows' autocorrelation time, how far 60-unit means scatter
# beyond their own stderrs -- against granflow's two continued runs of SEGREGATION_DEFAULT_WANDER
# (means 10.63 +- 0.33, 10.48 +- 0.27; C 1.54, 1.70; autocorrelation 80, 40; 2.65x, 2.00x).
# LAMMPS wanders as granflow does: C 1.38 against the 1.63 granflow assumes (0.84x, within
# the +-30 % that 13 means allow), mean 1.0 and 0.7 combined stderrs below granflow's.  The
# 5 % trend rule flags 5, 20, 52 % of its 4-, 6-, 10-window stretches, the wander rule 0, 0,
# 6.5 % (run after the multiple 3 was chosen: held out).
SEGREGATION_WANDER_LAMMPS = dict(
    n_flow=284, t=(100.0, 900.0), Ps=10.147, stderr=0.356, sd_60=0.829, rel_sd_60=0.0817,
    C_60=1.376, acf_time=80.0, sem_ratio_60=2.70, wall_s=2438.0, cpu_s=2979.0,
    trend_flags={4: (37, 2, 2, 0, 0), 6: (35, 7, 6, 0, 0), 10: (31, 16, 8, 2, 2)})


def segregation_seed_scatter() -> dict:
    """sigma -> (steady runs, their standard deviation, rms of their windows' stderrs, ratio,
    ratio against their stderrs with the wander at their number of particles: the per-run
    stderr since 2026-12-07, granflow.fitting.segregation.wander_sd) of
    :data:`SEGREGATION_DEFAULT_REPLICATES` (ratios with two or more runs steady under today's
    rule, :data:`SEGREGATION_DEFAULT_REPLICATES_STATE_NOW`)."""
    out = {}
    for sigma, runs in SEGREGATION_DEFAULT_REPLICATES.items():
        states = SEGREGATION_DEFAULT_REPLICATES_STATE_NOW[sigma]
        steady = [(p, se) for (p, se, _, _), st in zip(runs, states) if st == "steady"]
        if len(steady) < 2:
            continue
        ps = np.array([p for p, _ in steady])
        sd = float(ps.std(ddof=1))
        rms = float(np.sqrt(np.mean([se ** 2 for _, se in steady])))
        rel = SEGREGATION_WANDER_C / math.sqrt(SEGREGATION_DEFAULT_N_FLOW[sigma])
        total = float(np.sqrt(np.mean([max(se, rel * p) ** 2 for p, se in steady])))
        out[sigma] = (len(steady), sd, rms, sd / rms, sd / total)
    return out


def segregation_seed_scatter_note() -> str:
    """What one run per size ratio does not know (stated where a ratio has a single run)."""
    parts = [f"sigma = {s:g}: {n} seeds scatter by {sd:.2g} against their windows' stderrs "
             f"{rms:.2g} ({r:.1f}x; {rw:.1f}x against their stderrs with the wander)"
             for s, (n, sd, rms, r, rw) in segregation_seed_scatter().items()]
    runs = []
    for sigma, seeds in SEGREGATION_DEFAULT_WANDER.items():
        means = " and ".join(f"{w['Ps']:.2f}" for w in seeds.values())
        rel = sorted(w["sd_60"] / w["Ps"] for w in seeds.values())
        runs.append(f"sigma = {sigma:g}: means {means}, a profile window's Ps spreading by "
                    f"{100 * rel[0]:.0f}-{100 * rel[-1]:.0f} %")
    return ("one run per size ratio: its Ps stderr is the larger of its profile windows' "
            f"and the wander in time measured at its number of flow particles N (C Ps / sqrt(N), "
            f"C = {SEGREGATION_WANDER_C:.2f}, granflow.reference.SEGREGATION_WANDER_SCALING: "
            "about 9 % at the default set-up's 280-350 particles, 2 % at the paper's 7560); the "
            "scatter between this campaign's insertion seeds is not measured; at the default set-up (depth 8, "
            "10 x 5, 25 deg) " + "; ".join(parts) + " (granflow.reference."
            "SEGREGATION_DEFAULT_REPLICATES; config/replicates-segregation.yaml); it is wander "
            "in time: two runs per ratio continued for 1500-2000 time units agree in mean "
            "while a profile window's Ps wanders about it (" + "; ".join(runs) + "; "
            "SEGREGATION_DEFAULT_WANDER): set segregation numerics.replicates >= 3 for a "
            "stderr that measures it in this campaign")


def segregation_depth_note() -> str:
    """What :data:`SEGREGATION_PAPER_SETUP` measured about the depth Ps is scaled by (stated
    for every segregation campaign: it holds whatever the set-up)."""
    w = SEGREGATION_PAPER_SETUP["window"]
    per = [ps / h for h, ps in w.values()]
    hs = [h for h, _ in w.values()]
    law = SEGREGATION_PAPER_SETUP["law"]
    mean = sum(per) / len(per)
    return (f"Ps is per unit scaled depth, here Eq. (42)'s flow height (the paper does not say "
            f"which depth it scaled by): at the paper's set-up Ps / depth = {min(per):.3f}-"
            f"{max(per):.3f} per d over windows {min(hs):.1f}-{max(hs):.1f} d deep, so 1 d of "
            f"depth moves Ps by {100 / SEGREGATION_PAPER_SETUP['h'][1]:.1f} % and the law's "
            f"{law:.2f} at 1/sigma = 2 is that profile scaled by {law / mean:.1f} d "
            "(granflow.reference.SEGREGATION_PAPER_SETUP)")


def segregation_reduction_note(H: float) -> str:
    """What :data:`SEGREGATION_REDUCTION_EFFECT` says a segregation sweep at filling height ``H``
    inherits ('' at the paper's depth 24)."""
    if math.isclose(float(H), 24.0, rel_tol=1e-6):
        return ""
    ps = SEGREGATION_REDUCTION_EFFECT["Ps"]
    (p8, s8), (pl, sl) = ps[(10.0, 8.0, 0.005)], ps[(40.0, 8.0, 0.005)]
    deep = ps[(10.0, 16.0, 0.005)]
    return (f"measured at sigma = 0.6, 25 deg, the paper's species: Ps {p8:g} +- {s8:g} at depth 8 in a "
            f"10 x 5 box, >= {pl:g} +- {sl:g} in a 40 x 5 box, >= {deep[0]:g} +- {deep[1]:g} at depth 16 "
            "(both not shown steady by the present rule at their end, t = 351 and 800) "
            f"(paper law: 7.12 at depth 24, 83.3 x 5); {ps[(10.0, 8.0, 0.02)][0]:g} at depth 8 with "
            "t_c = 0.02: the depth sets Ps, not the box length or the stiffness "
            "(granflow.reference.SEGREGATION_REDUCTION_EFFECT); at the paper's set-up itself "
            f"(depth 24, 83.3 x 5) {paper_setup_sweep_text()} "
            "(granflow.reference.SEGREGATION_PAPER_SETUP); Ps and Pmax of a shallower sweep "
            "are not the paper's")


def paper_setup_sweep_text() -> str:
    """The measured Ps of :data:`SEGREGATION_PAPER_SETUP`'s sweep against T-eq. (29) with the
    paper's Pmax and k, one clause per size ratio (seeds' Ps, law, mean deviation)."""
    parts = []
    for inv in sorted(SEGREGATION_PAPER_SETUP["sweep"]):
        runs = SEGREGATION_PAPER_SETUP["sweep"][inv]
        law = 7.35 * -math.expm1(-5.21 * (inv - 1.0))
        mean = sum(r[0] for r in runs) / len(runs)
        seeds = " and ".join(f"{r[0]:g}" for r in runs)
        parts.append(f"1/sigma = {inv:g} gives Ps {seeds} ({len(runs)} seed"
                     f"{'s' if len(runs) > 1 else ''}; law {law:.2f}: "
                     f"{100 * (mean / law - 1):+.1f} %)")
    return ", ".join(parts)


#: Measured effect of the coarse-graining snapshot interval (granflow at fd7b2f5, 2026-11-27):
#: the default campaign's five steady runs (lambda = 1, 10 x 5 box, paper species; H = 10 at
#: 24, 26, 28 deg, H = 16 at 26, 28 deg) and its sigma = 0.6 segregation run, each rerun with
#: snapshots every t_c/2 (the paper's) and every 2 t_c: the same trajectories (the snapshots do
#: not act on the run), so the difference is the sampling alone.  Per interval (in t_c) against
#: every t_c: the largest |relative change| in % of the depth averages h, nu, u, alpha, K, mu, F
#: and the largest in units of their within-run stderrs, the largest change of the base level
#: (in d) and the CPU time of the run relative to every t_c.  At 2 t_c the snapshots undersample
#: the contact stress (a collision lasts t_c): the base level moves up in every chute run.
SNAPSHOT_INTERVAL_EFFECT = {
    "reference_interval": 1.0,
    0.5: {"max_rel_percent": 0.10, "max_stderr": 0.4, "max_base_shift": 0.0038,
          "cpu_ratio": (1.085, 1.159)},
    2.0: {"max_rel_percent": 0.50, "max_stderr": 3.8, "max_base_shift": 0.028,
          "cpu_ratio": (0.892, 0.928)},
}


def snapshot_interval_note(interval_tc: float) -> str:
    """What :data:`SNAPSHOT_INTERVAL_EFFECT` says about snapshots every ``interval_tc`` t_c
    ('' where nothing was measured)."""
    ref = SNAPSHOT_INTERVAL_EFFECT["reference_interval"]
    if math.isclose(float(interval_tc), ref, rel_tol=1e-6):
        e = SNAPSHOT_INTERVAL_EFFECT[0.5]
        return (f"; measured on the same runs with the paper's t_c/2 (granflow.reference."
                f"SNAPSHOT_INTERVAL_EFFECT): depth averages within {e['max_rel_percent']:g} % "
                f"({e['max_stderr']:g} within-run stderrs), base level within "
                f"{e['max_base_shift']:g} d")
    for key, e in SNAPSHOT_INTERVAL_EFFECT.items():
        if isinstance(key, float) and key != 0.5 and math.isclose(float(interval_tc), key,
                                                                   rel_tol=1e-6):
            return (f"; measured against every {ref:g} t_c on the same runs (granflow.reference."
                    f"SNAPSHOT_INTERVAL_EFFECT): depth averages move by up to "
                    f"{e['max_rel_percent']:g} % ({e['max_stderr']:g} within-run stderrs), the "
                    f"base level by up to {e['max_base_shift']:g} d: the snapshots undersample "
                    "the contact stress")
    return ""


#: The chute box against the paper's 20 x 10, measured on disordered layers (H = 10; at lambda =
#: 1/2 also H = 20, ``F_change_H20``: 27 deg against two 10 x 5 bases, 26 and 28 deg against the
#: reference's 10 x 5 runs continued to t = 2000, their 20 x 10 runs restarted from the 27 deg
#: state, session 33; and H = 30, ``F_change_H30``: 27 deg, the reference's 10 x 5 run continued
#: to its settled value against a 20 x 10 run topped up from the H = 20 state and run to t = 2000
#: in all, session 34) with
#: the paper's species and run parameters, one run per box and base (README "Why gamma is off at
#: lambda = 1/2"; lambda = 1: README, the lambda = 1 reference's flow rule).  ``F_change``: F in
#: 20 x 10 relative to 10 x 5 (at lambda = 1/2 against the mean of three 10 x 5 bases), per
#: angle; ``alpha``: the 10 x 5 runs' range and the 20 x 10 runs'; ``base_span``: the spread of F
#: over three 10 x 5 base realisations at one angle (27 deg, lambda = 1/2).
BOX_EFFECT = {
    "box": (10.0, 5.0),
    0.5: {"H": 10.0, "F_change": {27.0: -0.114, 28.0: -0.120}, "alpha": ((1.115, 1.129),
                                                                          (1.138, 1.142)),
          "base_span": 0.14, "F_change_H20": {26.0: -0.120, 27.0: -0.123, 28.0: -0.132},
          "F_change_H30": {27.0: -0.090}},
    1.0: {"H": 10.0, "F_change": {26.0: -0.055, 28.0: -0.019}},
}


def box_effect_note(Lx: float, Ly: float) -> str:
    """What :data:`BOX_EFFECT` says about a chute box of Lx x Ly ('' unless it is the measured
    10 x 5)."""
    bx, by = BOX_EFFECT["box"]
    if not (math.isclose(float(Lx), bx) and math.isclose(float(Ly), by)):
        return ""
    half, one = BOX_EFFECT[0.5], BOX_EFFECT[1.0]
    ch = sorted(half["F_change"].values())
    c1 = sorted(one["F_change"].values())
    (a_lo, a_hi), (b_lo, b_hi) = half["alpha"]
    h20 = sorted(half["F_change_H20"].values())
    h30 = half["F_change_H30"][27.0]
    return (f"; measured (granflow.reference.BOX_EFFECT) on layers of H = 10 at the paper's "
            f"species: in the paper's 20 x 10 box F is {100 * ch[-1]:+.0f} to {100 * ch[0]:+.0f} % "
            f"at lambda = 1/2 (27, 28 deg, against the mean of three 10 x 5 bases; "
            f"{100 * h20[-1]:+.0f} to {100 * h20[0]:+.0f} % at H = 20, 26-28 deg, "
            f"{100 * h30:+.0f} % at H = 30, 27 deg) and "
            f"{100 * c1[-1]:+.0f} to {100 * c1[0]:+.0f} % at lambda = 1, alpha {b_lo:g}-{b_hi:g} "
            f"against {a_lo:g}-{a_hi:g} at lambda = 1/2, and one 10 x 5 base moves F at "
            f"lambda = 1/2 by up to {100 * half['base_span']:.0f} % at H = 10: at lambda <= 1/2 "
            "this box biases the flow rule and alpha")


#: hstop brackets over other base realisations (measured 2026-11-27 at lambda = 1/2, the
#: paper's species and insertion column, 10 x 5, fresh-fall chains at H = 2 ... 24: a frictional
#: pile cut to the paper's band, a frictionless one cut to it and to MercuryDPM's top slice,
#: the frictional pile's top slice; README "Nor the base's making, beyond one realisation").
#: ``max_bracket_shift``: the largest move of one bracket between bases (H = 4);
#: ``mean_offset_range``: the brackets' mean offset from Table 1's curve on each full base;
#: ``typical_bracket_scatter``: what one base and one insertion seed place a bracket to;
#: ``common_offset_sigma``: the standard deviation of an offset common to all of one base's
#: brackets (random effect, :func:`granflow.fitting.hstop.base_scatter`, over the 25 brackets on
#: 4 bases, 2026-11-28), against ``within_base_sigma`` of the brackets about the curve on one
#: base: what a single-base fit's stderrs leave out is mostly the former.
BASE_REALISATION_EFFECT = {
    "lambda": 0.5, "max_bracket_shift": 1.75, "mean_offset_range": (0.05, 0.55),
    "typical_bracket_scatter": 0.5, "common_offset_sigma": 0.16, "within_base_sigma": 0.44,
}


def base_realisation_note() -> str:
    """What one base realisation leaves out of an hstop fit's stderrs
    (:data:`BASE_REALISATION_EFFECT`)."""
    e = BASE_REALISATION_EFFECT
    lo, hi = e["mean_offset_range"]
    return (f"all brackets of one lambda lie on one base realisation, whose own scatter is not "
            f"in these stderrs: measured at lambda = {e['lambda']:g} (granflow.reference."
            f"BASE_REALISATION_EFFECT), single brackets move by up to {e['max_bracket_shift']:g} "
            f"deg between bases (about +-{e['typical_bracket_scatter']:g} deg typical) and the "
            f"curve's mean offset from Table 1 by {lo:+.2f} ... {hi:+.2f} deg; an offset common "
            f"to all of one base's brackets has a standard deviation of "
            f"{e['common_offset_sigma']:g} deg (random effect over 4 bases, against "
            f"{e['within_base_sigma']:g} deg within one), which these stderrs leave out; "
            f"campaigns over other base.seed values, or hstop_bisection.replicate_bases, "
            f"measure it")
