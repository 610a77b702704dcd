"""Fit every closure of Weinhart et al. (2012) §9 and Thornton et al. §6 to a campaign table.

:func:`fit_campaign` runs, for each contact law in the table:

* per basal roughness lambda (monodisperse runs, sigma = 1): hstop Eq. (45) and, for comparison,
  Eq. (38) from the (theta, H, state) brackets -- every state but "arrested" counts as flowing,
  "undecided" included (the paper's binary rule, §6); the flow rule Eq. (47) with hstop(theta; 1)
  and the shape factor alpha (Eq. 54 for lambda > 2/3, constant for lambda <= 2/3) from the
  steady runs inside (delta1, delta2) of lambda = 1, with standard errors unconditional on the
  hstop fit (joint bootstrap, :func:`granflow.fitting.flow_rule.joint_bootstrap`); the friction
  closure Eq. (50) composed from both (joined ensembles);
* pooled over steady runs with lambda > 0 (as in the paper): bulk density Eq. (52) and stress
  ratio Eq. (53);
* where a basal roughness has a :class:`DisorderedWindow` (Eq. 46 and 48), its steady closures
  (flow rule, friction, alpha, density, K) use only the runs of the disordered regime
  delta3(H) < theta < delta_acc, as the paper's do (§9.1: Eq. 47 and 50 hold "for delta3 < theta <
  delta_acc"; §9.2: "the layered and oscillating flow regimes are thus excluded"); the hstop
  brackets are never cut;
* over bidisperse runs in a steady flow *and* a steady segregated state with a measured Ps: the
  size-ratio law T-eq. (29).

Every fit is weighted by the runs' decorrelated standard errors (``<col>_sem``) when the table has
them, is assessed for identifiability with stated reduced forms (:mod:`.identify`,
:mod:`.forms`), carries held-out z-scores, and says in ``selection`` which runs it used and why the
others were left out (generated from the selection actually applied, never written by hand).
Fits that cannot be made come back with status ``failed`` (they are still returned, so a library
records that they were attempted).  The result is a flat list ready for
:func:`granflow.closures.write_library`.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .bulk import fit_bulk_density, fit_stress_ratio
from .flow_rule import fit_flow_rule, friction_closure
from .hstop import ENGINE_STOP_NO_STATE, fit_hstop, fit_hstop_eq38, hstop_eq45
from .result import FitResult, failed_fit
from .segregation import fit_Ps_law
from .shape_factor import fit_alpha
from .table import select_runs, validate_campaign_table

#: how each closure treats runs left "undecided" at their cap (stored with the closure)
UNDECIDED_TREATMENT = {
    "hstop": "undecided runs count as flowing (binary arrested/flowing rule, §6: they did not "
             "arrest within their cap)",
    "steady": "undecided runs are left out (the closure needs a steady flow)",
    "segregation": "only runs in a steady flow and a steady segregated state enter",
}


@dataclass(frozen=True)
class DisorderedWindow:
    """The disordered steady regime of one basal roughness, delta3(H) < theta < delta_acc
    (Weinhart et al. 2012 Eq. 46 and 48), in which its steady closures are defined.

    ``delta3``: steps ``((H_max, theta), ...)`` in increasing H_max: a run of filling height H
    takes the theta of the first step with H <= H_max (``math.inf`` for "every thicker layer");
    heights above the last H_max have no delta3.  Eq. (48) at lambda = 1/2 is
    ``((10, 25.5), (inf, 24.5))``: layered and oscillating flows up to 25.5 deg at H = 10 and
    24.5 deg at H > 10 (the paper gives no value below H = 10, where its grid stops; thinner
    layers order at least as readily, so the H = 10 value is the conservative one).
    ``delta_acc``: the smallest angle of accelerating flow (Eq. 46; None: no upper cut)."""

    delta3: tuple = ()
    delta_acc: float | None = None

    def __post_init__(self):
        steps = tuple((float(h), float(t)) for h, t in self.delta3)
        if any(b[0] <= a[0] for a, b in zip(steps, steps[1:])):
            raise ValueError(f"delta3 steps {steps}: H_max must increase from step to step")
        for h, t in steps:
            if not (h > 0 and 0 < t < 90):
                raise ValueError(f"delta3 step (H_max {h:g}, theta {t:g}): allowed H_max > 0 "
                                 "and theta in (0, 90) deg")
        if self.delta_acc is not None and not 0 < float(self.delta_acc) < 90:
            raise ValueError(f"delta_acc {self.delta_acc}: allowed (0, 90) deg")
        object.__setattr__(self, "delta3", steps)

    def delta3_at(self, H) -> np.ndarray:
        """delta3 (deg) for each filling height; NaN where no step covers it."""
        H = np.asarray(H, dtype=float)
        out = np.full(H.shape, np.nan)
        for h_max, theta in reversed(self.delta3):
            out = np.where(H <= h_max, theta, out)
        return out

    def describe(self) -> str:
        parts = []
        lo = None
        for h_max, theta in self.delta3:
            where = (f"H > {lo:g}" if math.isinf(h_max) and lo is not None else
                     "every H" if math.isinf(h_max) else
                     f"H <= {h_max:g}" if lo is None else f"{lo:g} < H <= {h_max:g}")
            parts.append(f"{theta:g} deg for {where}")
            lo = h_max
        s = "delta3 = " + ", ".join(parts) if parts else "no delta3"
        if self.delta_acc is not None:
            s += f", delta_acc = {float(self.delta_acc):g} deg"
        return s + " (Eq. 46, 48)"

    @classmethod
    def from_config(cls, d: dict) -> "DisorderedWindow":
        """From a configuration entry ``{delta3: [{H_max, theta}, ..., {theta}], delta_acc}``
        (a step without H_max covers every thicker layer)."""
        steps = [(float(s.get("H_max", math.inf)), float(s["theta"]))
                 for s in (d.get("delta3") or [])]
        acc = d.get("delta_acc")
        return cls(tuple(steps), None if acc is None else float(acc))

    def to_config(self) -> dict:
        out = {"delta3": [({"H_max": h} if math.isfinite(h) else {}) | {"theta": t}
                          for h, t in self.delta3]}
        if self.delta_acc is not None:
            out["delta_acc"] = float(self.delta_acc)
        return out


def _window_for(windows: dict, lam: float):
    return next((w for k, w in windows.items() if abs(float(k) - float(lam)) < 1e-9), None)


def _apply_window(pool: pd.DataFrame, use: np.ndarray, left: Counter, windows: dict) -> np.ndarray:
    """Cut ``use`` to each run's disordered window (its lambda's); counts the cut runs."""
    if not windows:
        return use
    use = use.copy()
    lam = pool["lam"].to_numpy(float)
    th = pool["theta"].to_numpy(float)
    H = pool["H"].to_numpy(float)
    for value in np.unique(lam):
        w = _window_for(windows, value)
        if w is None:
            continue
        at = use & (lam == value)
        d3 = w.delta3_at(H)
        below = at & np.isfinite(d3) & (th <= d3)
        if below.any():
            left[f"at or below delta3 at lambda = {value:g} (layered/oscillating regime; "
                 f"{w.describe()})"] += int(below.sum())
        above = at & (w.delta_acc is not None) & (th >= (w.delta_acc or 0.0))
        if above.any():
            left[f"at or above delta_acc at lambda = {value:g} ({w.describe()})"] += int(
                above.sum())
        use &= ~(below | above)
    return use


def _ids(runs: pd.DataFrame) -> np.ndarray:
    if "run" in runs.columns:
        return runs["run"].astype(str).to_numpy()
    return np.array([f"theta={t:g},H={h:g},lam={lam:g},sigma={s:g}" for t, h, lam, s in
                     zip(runs["theta"], runs["H"], runs["lam"], runs["sigma"])])


#: the columns that identify a run point (replicates share them and differ in seed)
POINT_COLUMNS = ("contact_law", "lam", "theta", "H", "sigma")


def between_seed_scatter(runs: pd.DataFrame, col: str) -> tuple[float, int, float]:
    """(tau, number of replicate groups, pooled within-run variance) of ``col``.

    Runs of one point with different seeds (replicates) scatter by more than each run's own
    decorrelated standard error shows: tau^2 = max(0, pooled variance of the replicates about
    their group means - pooled mean of their squared standard errors).  NaN (and 0 groups)
    without replicates."""
    if col not in runs.columns or not len(runs):
        return math.nan, 0, math.nan
    v = pd.to_numeric(runs[col], errors="coerce")
    se = pd.to_numeric(runs.get(f"{col}_sem", pd.Series(np.nan, index=runs.index)),
                       errors="coerce")
    frame = runs.loc[:, [c for c in POINT_COLUMNS if c in runs.columns]].copy()
    frame["_v"], frame["_se2"] = v, se ** 2
    frame = frame[np.isfinite(frame["_v"])]
    dof = var = within = 0.0
    n_groups = 0
    for _, g in frame.groupby(list(c for c in POINT_COLUMNS if c in frame.columns)):
        if len(g) < 2:
            continue
        n_groups += 1
        k = len(g) - 1
        dof += k
        var += k * float(np.var(g["_v"], ddof=1))
        w = g["_se2"].to_numpy(float)
        within += k * float(np.nanmean(w)) if np.isfinite(w).any() else 0.0
    if not n_groups:
        return math.nan, 0, math.nan
    return math.sqrt(max(0.0, (var - within) / dof)), n_groups, within / dof


def run_uncertainty(runs: pd.DataFrame, col: str):
    """(sigma, sigma_parts, note) for fitting ``col``: each run's decorrelated standard error
    (missing ones: the largest of the others) combined with the between-seed scatter of the
    replicates when there are any -- sigma^2 = sem^2 + tau^2 -- and the two parts for the
    variance split of the fitted parameters (:func:`granflow.fitting.lsq.variance_split`)."""
    sem = _col(runs, f"{col}_sem")
    if sem is None:
        return None, None, "unweighted (no per-run standard errors in the table)"
    good = np.isfinite(sem) & (sem > 0)
    if not good.any():
        return None, None, "unweighted (no per-run standard errors in the table)"
    sem = np.where(good, sem, sem[good].max())
    tau, n_groups, _ = between_seed_scatter(runs, col)
    if n_groups == 0 or not math.isfinite(tau):
        return sem, None, ("weighted by the runs' decorrelated standard errors (within-run "
                           "only: no replicates, so the scatter between seeds is not measured)")
    total = np.sqrt(sem ** 2 + tau ** 2)
    return total, {"within": sem, "between": np.full(sem.shape, tau)}, (
        f"weighted by the runs' decorrelated standard errors combined with the between-seed "
        f"scatter {tau:.3g} of {n_groups} replicate group(s)")


def _col(runs: pd.DataFrame, name: str):
    """A numeric column, or None when absent or all-NaN (e.g. no ``_sem`` in an old table)."""
    if name not in runs.columns:
        return None
    v = pd.to_numeric(runs[name], errors="coerce").to_numpy(float)
    return v if np.isfinite(v).any() else None


def _range(values) -> str:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return "none"
    u = np.unique(v)
    return ", ".join(f"{x:g}" for x in u) if u.size <= 8 else f"{u.min():g}-{u.max():g}"


def describe_selection(what: str, pool: pd.DataFrame, used: np.ndarray, left_out: Counter,
                       weighting: str) -> str:
    """One generated sentence: which runs a closure used, their H and theta, why the others of
    ``pool`` were left out, and how the runs were weighted."""
    used_runs = pool[used]
    parts = [f"{what}: {int(used.sum())} of {len(pool)} runs used (H = {_range(used_runs['H'])}; "
             f"theta = {_range(used_runs['theta'])} deg)"]
    if "replicate" in used_runs.columns and (used_runs["replicate"].fillna(0) > 0).any():
        parts[0] += f", {int((used_runs['replicate'].fillna(0) > 0).sum())} of them replicates"
    if left_out:
        parts.append("left out: " + ", ".join(f"{n} {why}" for why, n in sorted(left_out.items())))
    parts.append(weighting)
    creeping = creeping_steady_runs(used_runs)
    if creeping:
        parts.append(
            f"{len(creeping)} of the used runs were called steady while their tail still trended "
            f"(state_confidence < {CREEP_CONFIDENCE:g}, so a tail-trend p-value below "
            f"{CREEP_CONFIDENCE:g}, inside the monitor's +-20 % equivalence margin: "
            f"{', '.join(creeping)}); their means may carry a creep bias of a few per cent that "
            "their stderrs do not include")
    return "; ".join(parts)


#: A run called steady with a state confidence below this is flagged as still creeping.  The
#: classifier's steady confidence is min(1, N_eff / 50) * min(1, p / 0.2) with N_eff >= 10
#: (:mod:`granflow.steady.classify`), so a confidence below c implies a tail-trend p-value below
#: c: the trend is significant but smaller than the 20 % equivalence margin that let the run
#: stop.  Continuing such runs moved their 100-unit means by up to about 5 % (README: the
#: stricter early stop measured on ten runs with continuations).
CREEP_CONFIDENCE = 0.01


def creeping_steady_runs(runs: pd.DataFrame) -> list[str]:
    """The ids of the steady runs of ``runs`` whose steady call has a significant tail trend
    (``state_confidence`` < :data:`CREEP_CONFIDENCE`); empty without that column."""
    conf = _col(runs, "state_confidence")
    if conf is None or "state" not in runs.columns:
        return []
    flag = (runs["state"].astype(str).to_numpy() == "steady") & (conf < CREEP_CONFIDENCE)
    return [str(i) for i in _ids(runs[flag])]


def _state_counts(runs: pd.DataFrame, keep_states=("steady",)) -> Counter:
    c = Counter()
    for st in runs["state"].astype(str):
        if st not in keep_states:
            c[f"{st} (state not {'/'.join(keep_states)})"] += 1
    return c


def fit_campaign(table, *, windows=None, theta_min=None, theta_max=None, n_bootstrap: int = 200,
                 seed: int = 0, include_eq38: bool = True) -> list[FitResult]:
    """All closure fits for a validated campaign table (see module docstring).

    ``windows``: optional ``{lambda: DisorderedWindow}`` (or its configuration dict) cutting
    each roughness's steady closures -- flow rule, friction, alpha, and its runs' share of the
    pooled density and K -- to delta3(H) < theta < delta_acc (Eq. 46, 48).  ``theta_min`` /
    ``theta_max``: ``{lambda: angle}`` shorthands for an H-independent delta3 / delta_acc.  By
    default all steady runs inside (delta1, delta2) of lambda = 1 are used.
    """
    validate_campaign_table(table)
    windows = {float(k): (w if isinstance(w, DisorderedWindow) else DisorderedWindow.from_config(w))
               for k, w in dict(windows or {}).items()}
    for k, v in dict(theta_min or {}).items():
        w = _window_for(windows, k) or DisorderedWindow()
        windows[float(k)] = DisorderedWindow(((math.inf, float(v)),), w.delta_acc)
    for k, v in dict(theta_max or {}).items():
        w = _window_for(windows, k) or DisorderedWindow()
        windows[float(k)] = DisorderedWindow(w.delta3, float(v))
    results: list[FitResult] = []
    for law in sorted(set(table["contact_law"])):
        mono = select_runs(table, contact_law=law, sigma=1.0)
        lams = sorted(set(mono["lam"].astype(float)))
        hstops = {}
        for lam in lams:
            runs = select_runs(mono, lam=lam)
            no_state = (runs["stop_reason"].astype(str) == ENGINE_STOP_NO_STATE
                        if "stop_reason" in runs.columns else np.zeros(len(runs), bool))
            n_und = int(((runs["state"] == "undecided") & ~no_state).sum())
            sel = (f"hstop brackets at lambda = {lam:g}, contact law {law}: all {len(runs)} "
                   f"monodisperse runs (H = {_range(runs['H'])}), arrested vs flowing; "
                   f"{UNDECIDED_TREATMENT['hstop']} ({n_und} such runs)")
            if int(no_state.sum()):
                sel += (f"; {int(no_state.sum())} runs ended by an engine guard before they had "
                        f"a flow state are left out (no evidence either way)")
            seeds = (sorted({int(v) for v in runs["base_seed"].to_numpy(float)
                             if math.isfinite(v)}) if "base_seed" in runs.columns else [])
            if lam > 0 and len(seeds) > 1:
                sel += (f"; the brackets lie on {len(seeds)} base realisations (base seeds "
                        f"{', '.join(map(str, seeds))}: hstop_bisection.replicate_bases), so the "
                        "scatter between bases enters the fit's residuals, and an offset common "
                        "to one base's brackets enters its stderrs as a random effect (each "
                        "bootstrap refit shifts each base's brackets by a draw of it; "
                        "extra base_scatter)")
            elif lam > 0:  # a flat wall (lambda = 0) has no realisation
                from ..reference import base_realisation_note

                sel += "; " + base_realisation_note()
            for fn in ((fit_hstop, fit_hstop_eq38) if include_eq38 else (fit_hstop,)):
                r = fn(runs=runs, lam=lam, contact_law=law, n_bootstrap=n_bootstrap, seed=seed)
                r = r.replace(runs_used=tuple(_ids(runs)), selection=sel)
                results.append(r)
                if fn is fit_hstop:
                    hstops[lam] = r
        hstop1 = next((r for lam, r in hstops.items() if abs(lam - 1.0) < 1e-9), None)
        for lam in lams:
            pool = select_runs(mono, lam=lam)
            results.extend(_steady_closures(pool, lam, law, hstop1, windows, n_bootstrap, seed))
        rough_pool = mono[mono["lam"] > 0]
        results.extend(_bulk_closures(rough_pool, law, seed, windows))
        seg = select_runs(table, contact_law=law)
        seg = seg[np.isfinite(seg["Ps"].to_numpy(float))]
        if len(seg):
            results.append(_ps_law(seg, law, seed))
    return results


def _steady_closures(pool, lam, law, hstop1, windows, n_bootstrap, seed):
    out = []
    left = _state_counts(pool)
    use = (pool["state"] == "steady").to_numpy().copy()
    th = pool["theta"].to_numpy(float)
    use = _apply_window(pool, use, left, windows)
    if hstop1 is not None and hstop1.state != "failed":
        hs = hstop_eq45(th, **{k: hstop1.params[k] for k in ("delta1", "delta2", "A")})
        outside = use & ~(np.isfinite(hs) & (hs > 0))
        if outside.any():
            left["outside (delta1, delta2) of hstop(theta; 1)"] += int(outside.sum())
        use &= np.isfinite(hs) & (hs > 0)
    for col in ("h", "F", "alpha"):
        bad = use & ~np.isfinite(pool[col].to_numpy(float))
        if bad.any():
            left[f"no measured {col}"] += int(bad.sum())
            use &= ~bad
    steady = pool[use]
    ids = _ids(steady)
    theta, h, F = (steady[c].to_numpy(float) for c in ("theta", "h", "F"))
    F_sem, F_parts, F_note = run_uncertainty(steady, "F")
    a_sem, a_parts, a_note = run_uncertainty(steady, "alpha")
    what = f"steady runs at lambda = {lam:g}, sigma = 1, contact law {law}"
    sel_F = describe_selection(f"flow rule from {what}", pool, use, left, F_note)
    sel_F += "; " + UNDECIDED_TREATMENT["steady"]
    if hstop1 is None:
        flow = failed_fit("flow_rule", "Weinhart et al. 2012 Eq. (47)", ("beta", "gamma"),
                          "no lambda = 1 runs: hstop(theta; 1) unavailable", 0,
                          lam=lam, contact_law=law)
    else:
        flow = fit_flow_rule(theta, h, F, hstop1, lam=lam, contact_law=law, sigma=F_sem,
                             ids=ids, selection=sel_F, n_bootstrap=n_bootstrap, seed=seed,
                             sigma_parts=F_parts)
    flow = _with_selection(flow, sel_F, ids)
    out.append(flow)
    if hstop1 is not None:
        out.append(_with_selection(friction_closure(hstop1, flow, theta=theta, h=h, F=F),
                                   sel_F, ids))
    sel_a = describe_selection(f"shape factor from {what}", pool, use, left, a_note)
    sel_a += "; " + UNDECIDED_TREATMENT["steady"]
    out.append(_with_selection(
        fit_alpha(theta, h, steady["alpha"].to_numpy(float), lam,
                  hstop1 if hstop1 is not None and hstop1.state != "failed" else None,
                  contact_law=law, sigma=a_sem, ids=ids, selection=sel_a,
                  n_bootstrap=n_bootstrap, seed=seed, sigma_parts=a_parts), sel_a, ids))
    return out


def _with_selection(r: FitResult, selection: str, ids) -> FitResult:
    """A fit that could not be made still says which runs were available and why."""
    if r.selection:
        return r
    return r.replace(selection=selection, runs_used=tuple(ids) if r.ok else r.runs_used)


def _bulk_closures(pool, law, seed, windows=None):
    out = []
    for kind, col, fn in (("density", "rho_c", fit_bulk_density),
                          ("stress_ratio", "K", fit_stress_ratio)):
        left = _state_counts(pool)
        use = (pool["state"] == "steady").to_numpy().copy()
        use = _apply_window(pool, use, left, windows or {})
        bad = use & ~np.isfinite(pool[col].to_numpy(float))
        if bad.any():
            left[f"no measured {col} (flow too thin for the bulk window)" if col == "rho_c"
                 else f"no measured {col}"] += int(bad.sum())
            use &= ~bad
        runs = pool[use]
        sem, parts, note = run_uncertainty(runs, col)
        sel = describe_selection(
            f"{'bulk density' if kind == 'density' else 'stress ratio'} from steady runs with "
            f"lambda > 0 (lambda = {_range(pool['lam'])}), sigma = 1, contact law {law}", pool,
            use, left, note) + "; " + UNDECIDED_TREATMENT["steady"]
        out.append(_with_selection(
            fn(runs["theta"].to_numpy(float), runs[col].to_numpy(float), sigma=sem,
               contact_law=law, ids=_ids(runs), selection=sel, seed=seed, sigma_parts=parts),
            sel, _ids(runs)))
    return out


def approach_side(start: str, Ps: float) -> float:
    """+1 when a run that started ``start`` approaches its steady Ps from below (its Ps a
    lower bound), -1 from above: a mixed start from below, a segregated one from above, and
    a ``profile<Ps0>`` start (T-eq. 28's profile at Ps0) from the side of Ps0: a Ps below Ps0
    means the profile broadened from a sharper start (from above), a Ps above Ps0 that it
    sharpened (from below); the relaxation does not overshoot (T-eq. 27)."""
    if start == "segregated":
        return -1.0
    if start in ("mixed", "", "nan"):
        return 1.0
    from ..campaign.grid import start_initial_Ps

    ps0 = start_initial_Ps(start)
    return -1.0 if Ps < ps0 else 1.0


def _ps_law(seg, law, seed):
    left = _state_counts(seg)
    use = (seg["state"] == "steady").to_numpy().copy()
    if "segregation_state" in seg.columns:
        ss = seg["segregation_state"].astype(str).to_numpy()
        drifting = use & (ss != "steady")
        if drifting.any():
            left["segregated state not steady (drifting)"] += int(drifting.sum())
        use &= ss == "steady"
    mono = use & (seg["sigma"].to_numpy(float) >= 1.0 - 1e-9)
    if mono.any():
        left["sigma = 1 (no-segregation control)"] += int(mono.sum())
        use &= ~mono
    runs = seg[use]
    sem, parts, note = run_uncertainty(runs, "Ps")
    sel = describe_selection(
        f"Ps(sigma) law from bidisperse runs of contact law {law} (sigma = {_range(seg['sigma'])})",
        seg, use, left, note) + "; " + UNDECIDED_TREATMENT["segregation"]
    # runs whose segregated state is still drifting bound their steady Ps from one side: from
    # below after a mixed start, from above after a segregated one, and after a profile<Ps0>
    # start from the side of Ps0 on which the run's Ps still lies (granflow.engine.chute)
    one_sided, sides = None, None
    if "segregation_state" in seg.columns:
        drift = ((seg["state"] == "steady").to_numpy()
                 & (seg["segregation_state"].astype(str).to_numpy() == "drifting")
                 & (seg["sigma"].to_numpy(float) < 1.0 - 1e-9))
        start = (seg["initial_mixing"].astype(str).to_numpy() if "initial_mixing" in seg.columns
                 else np.full(len(seg), "mixed"))
        sides = np.array([approach_side(str(st), float(ps)) for st, ps in
                          zip(start[drift], seg["Ps"].to_numpy(float)[drift])])
        d = seg[drift]
        if len(d):
            one_sided = (d["sigma"].to_numpy(float), d["Ps"].to_numpy(float),
                         pd.to_numeric(d.get("Ps_sem"), errors="coerce").to_numpy(float), sides)
            sel += (f"; {len(d)} drifting run(s) bound k only, as one-sided bounds on their "
                    f"steady Ps ({int((sides > 0).sum())} from below, mixed or broader "
                    f"start; {int((sides < 0).sum())} from above, segregated or sharper start)")
    return _with_selection(
        fit_Ps_law(runs["sigma"].to_numpy(float), runs["Ps"].to_numpy(float), sem,
                   contact_law=law, ids=_ids(runs), selection=sel, seed=seed,
                   sigma_parts=parts, one_sided=one_sided), sel, _ids(runs))
