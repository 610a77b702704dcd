# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # granflow campaign report
#
# Closure relations for shallow granular flows from the discrete particle simulations of this
# campaign, following Weinhart, Thornton, Luding & Bokhove (2012) (equation numbers "Eq.") and
# Thornton, Weinhart, Ogarko & Luding (segregation, "T-eq.").  The notebook is executed by the
# workflow's `report` rule (`granflow campaign report`); it reads only the campaign's results
# folder: the campaign table, the fits, the versioned closure library and the run directories.
# All quantities are nondimensional (particle diameter d = 1, mass m = 1, gravity g = 1).

# %% tags=["parameters"]
# Parameters (the workflow injects the actual values in the next cell)
RESULTS = "results/default"   # campaign results folder
CAMPAIGN = "default"          # campaign name
FIGURES = None                # folder to save the figures as PNG (None: do not save)

# %%
import json
import math
from pathlib import Path
import textwrap

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import xarray as xr
from IPython.display import Markdown, display

import granflow.closures as gc
from granflow import units as U
from granflow.campaign.collect import read_table
from granflow.campaign.fits import closure_rows, read_fits
from granflow.closures import open_library
from granflow.reference import compare_with_paper, paper_law_errors
from granflow.reference import paper_curves as compare_curve
from granflow.reference import paper_value as _paper_value
from granflow.fitting import (Ps_teq29, alpha_eq54, density_eq52, hstop_eq38, hstop_eq45,
                              mu_eq50, phi_teq28, stress_ratio_eq53)

try:  # inline PNG figures in the executed notebook, whatever MPLBACKEND says
    get_ipython().run_line_magic("matplotlib", "inline")  # noqa: F821
except NameError:  # run as a plain script
    pass
matplotlib.rcParams.update({"figure.dpi": 90, "font.size": 9, "axes.grid": True,
                            "grid.alpha": 0.3})
R = Path(RESULTS)
table = read_table(R / "campaign_table.nc")
fits = read_fits(R / "fits.json")
manifest = json.loads((R / "closures.json").read_text())
lib = open_library(R / "closures.nc")
seg_runs = json.loads((R / "segregation_fits.json").read_text())
from granflow.campaign.collect import read_excluded

excluded = read_excluded(R / "excluded_runs.csv")
STATE_STYLE = {"arrested": ("s", "tab:blue"), "steady": ("o", "tab:green"),
               "accelerating": ("^", "tab:red"), "layered": ("D", "tab:purple"),
               "oscillating": ("v", "tab:orange"), "undecided": ("x", "0.3"),
               "flowing": (">", "tab:olive")}
OK_STATES = ("ok", "reduced")


def status_of(kind, **coords):
    r = fit_of(kind, **coords)
    return "absent" if r is None else r.state


def draw_closure(ax, x, evaluate, rng, colour, label, status, transform=None, xplot=None):
    """Closure curve from the library with its 16-84 % band (ensemble), solid inside the fitted
    range ``rng`` (of the evaluated ``x``) and dotted outside it (extrapolated); dashed grey when
    the closure is not identified (drawn for inspection only).  ``xplot``: abscissa to draw
    against (default ``x``)."""
    try:
        ds = evaluate(x)
    except ValueError as exc:
        ax.text(0.02, 0.02, f"{label}: {exc}"[:90], transform=ax.transAxes, fontsize=6)
        return
    tf = transform or (lambda v: v)
    val, lo, hi = (tf(np.asarray(ds[k].values, float)) for k in ("value", "low", "high"))
    ok = status in OK_STATES
    c = colour if ok else "0.5"
    inside = (x >= rng[0] - 1e-9) & (x <= rng[1] + 1e-9)
    xp = x if xplot is None else xplot
    ax.fill_between(xp, lo, hi, color=c, alpha=0.18 if ok else 0.08, lw=0)
    ax.plot(np.where(inside, xp, np.nan), np.where(inside, val, np.nan), "-" if ok else "--",
            color=c, lw=1.4, label=f"{label} [{status}]")
    ax.plot(np.where(inside, np.nan, xp), np.where(inside, np.nan, val), ":", color=c, lw=1.2)


def fitted_range(kind, var, **coords):
    r = fit_of(kind, **coords)
    return r.valid_range.get(var, (np.nan, np.nan)) if r is not None else (np.nan, np.nan)


def savefig(fig, name):
    fig.tight_layout()
    if FIGURES:
        Path(FIGURES).mkdir(parents=True, exist_ok=True)
        fig.savefig(Path(FIGURES) / f"{name}.png", dpi=110)
    display(fig)
    plt.close(fig)


def fit_of(kind, **coords):
    """The FitResult of a kind at the given coordinates (or None)."""
    for r in fits:
        if r.kind != kind:
            continue
        if all((abs(r.coords.get(k, math.nan) - v) < 1e-9) if isinstance(v, float)
               else r.coords.get(k) == v for k, v in coords.items()):
            return r
    return None


def fmt(r, p):
    if r is None or r.state == "failed" or not np.isfinite(r.params.get(p, math.nan)):
        return "n/a"
    return (f"{r.params[p]:.4g} ± {r.stderr.get(p, math.nan):.2g} "
            f"[{r.param_status.get(p, '')}]")


chute = (table[table["kind"].isin(["chute", "bracket"])] if "kind" in table
         else table[table["sigma"] == 1])
seg = table[table["kind"] == "segregation"] if "kind" in table else table[table["sigma"] < 1]
laws = sorted(set(table["contact_law"]))
lams = sorted(set(chute["lam"].astype(float)))
display(Markdown(
    f"**Campaign `{CAMPAIGN}`** — {len(table)} runs in the table ({len(chute)} chute, "
    f"{len(seg)} segregation), {len(excluded)} excluded; contact law(s) {', '.join(laws)}; "
    f"closure library **{manifest['name']} v{manifest['version']}** "
    f"(`{Path(manifest['path']).name}`, content {manifest['content_hash'][:19]}…, "
    f"{'reused existing version' if manifest['reused'] else 'new version'}); "
    f"granflow {lib.attrs.get('granflow_version')}, commit `{lib.attrs.get('git_commit')}`."))
display(Markdown("**Reductions versus the paper's protocol** (generated from the configuration "
                 "and the runs each fit used; stored in the library as `reductions_vs_paper`): "
                 + str(lib.attrs.get("reductions_vs_paper"))))

# %% [markdown]
# ## What this library knows
# Every closure with its status: **ok** (every parameter of the full form identified by the
# data), **reduced** (a stated reduced form is what the data identify, and is what the library
# stores), **unidentified** (no form is: evaluators refuse it), **misfit** (a held-out run
# contradicts it), **failed** (no fit could be made).  A parameter is identified when its
# standard error is finite, it is not at an optimiser bound, its standard error is below the
# stated tolerance and no other parameter is correlated with it beyond 0.999
# (`granflow.fitting.identify`; the criterion is in the library's `identifiability_criterion`).
# Uncertainties are unconditional: the flow rule, alpha and mu(h, F) carry the hstop fit's
# uncertainty (joint bootstrap).

# %%
status_rows = []
for r in fits:
    if r.kind == "segregation":
        continue
    pars = "; ".join(f"{p} = {r.params[p]:.4g} ± {r.stderr.get(p, math.nan):.2g} "
                     f"[{r.param_status.get(p, '')}]" for p in r.params
                     if r.param_status.get(p) not in ("not_in_form", "not_fitted"))
    why = "; ".join(f"{p}: {r.param_reason.get(p, '')}" for p in r.params
                    if r.param_status.get(p) in ("unidentified", "fixed"))
    status_rows.append({"closure": r.kind, "law": r.coords.get("contact_law", ""),
                        "lambda": r.coords.get("lam", ""), "status": r.state, "form": r.form,
                        "parameters": pars or "-", "why": why or ("-" if r.ok else r.message),
                        "held-out max |z|": r.diagnostics.get("heldout_max_abs_z", math.nan),
                        "runs": len(r.runs_used)})
with pd.option_context("display.max_colwidth", 120):
    display(pd.DataFrame(status_rows))

# %% [markdown]
# ## Runs and flow states
# Counts of the classified flow states (Weinhart et al. 2012 §6: arrested when
# E_kin/<E_ela> < 1e-5; steady when the energy ratio is statistically constant; accelerating
# otherwise) per inclination.  Runs the classifier could not decide before their cap are
# "undecided": hstop counts them as flowing (the paper's binary rule), every other closure
# leaves them out (each closure's selection says so).

# %%
counts = pd.crosstab([chute["contact_law"], chute["lam"], chute["theta"]], chute["state"])
display(counts)
if len(excluded):
    display(Markdown("Excluded runs:"))
    display(excluded)

# %% [markdown]
# ## Flow-state map and hstop(theta) (Fig. 4 / 9)
# Every chute run at its inclination theta and filling height H, marked by its flow state, with
# the fitted stopping height hstop(theta; lambda) of Eq. (45) (solid) and the exponential form
# Eq. (38) (dash-dotted, comparison only), and the paper's Table 1 curve at that lambda
# (dotted red; the paper's species, so a comparison for campaigns at other species).  The fit minimises the horizontal distance of the curve to
# the arrested/flowing intervals of each height.  Runs the classifier left undecided at their
# cap (crosses) are flowing in the paper's binary sense (§6) and bracket hstop, but enter no
# other fit.

# %%
panels = [(law, lam) for law in laws for lam in lams] or [("none", 1.0)]
fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 5.0), squeeze=False)
for ax, (law, lam) in zip(axes[0], panels):
    sub = chute[(chute["contact_law"] == law) & np.isclose(chute["lam"], lam)]
    for state, (marker, colour) in STATE_STYLE.items():
        s = sub[sub["state"] == state]
        if len(s):
            ax.scatter(s["theta"], s["H"], marker=marker, color=colour, label=state, s=36,
                       zorder=3)
    th = np.linspace(max(sub["theta"].min() - 2, 1) if len(sub) else 15,
                     (sub["theta"].max() + 2) if len(sub) else 35, 200)
    r = fit_of("hstop", lam=lam, contact_law=law)
    if r is not None and r.state != "failed":
        draw_closure(ax, th, lambda x: gc.hstop(lib, x, lam, contact_law=law, uncertainty=True,
                                                extrapolate=True, allow_unidentified=True,
                                                impossible="nan"),
                     fitted_range("hstop", "theta", lam=lam, contact_law=law), "k",
                     f"Eq. (45): δ1={r.params['delta1']:.1f}°, δ2={r.params['delta2']:.1f}°, "
                     f"A={r.params['A']:.2f}", r.state)
    r38 = fit_of("hstop_eq38", lam=lam, contact_law=law)
    if r38 is not None and r38.state != "failed":
        h = hstop_eq38(th, r38.params["delta1"], r38.params["delta2"], r38.params["A"])
        ax.plot(th, np.where(np.isfinite(h) & (h > 0), h, np.nan), "k-.", lw=0.8,
                label=f"Eq. (38) (comparison) [{r38.state}]")
    # the paper's curve at this lambda (Table 1: its species, linear law), for comparison
    paper = {k: _paper_value("hstop", k, lam) for k in ("delta1", "delta2", "A")}
    if law == "linear" and all(np.isfinite(v) for v in paper.values()):
        hp = hstop_eq45(th, **paper)
        ax.plot(th, np.where(np.isfinite(hp) & (hp > 0), hp, np.nan), color="tab:red", ls=":",
                lw=1.2, label=f"Table 1, λ = {lam:g} (paper species)")
    top = (sub["H"].max() * 1.15) if len(sub) else 10
    ax.set_ylim(0, top)
    ax.set_xlabel("inclination θ (deg)")
    ax.set_ylabel("filling height H (d)")
    ax.set_title(f"{law}, λ = {lam:g}")
    # below the axes: inside, the legend hid the thick runs
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
savefig(fig, "flow_state_map")
rows = []
for law in laws:
    for lam in lams:
        for kind in ("hstop", "hstop_eq38"):
            r = fit_of(kind, lam=lam, contact_law=law)
            if r is not None:
                rows.append({"form": kind, "law": law, "lambda": lam, "status": r.state,
                             "delta1": fmt(r, "delta1"), "delta2": fmt(r, "delta2"),
                             "A": fmt(r, "A"), "error (deg)": r.error, "message": r.message})
display(pd.DataFrame(rows))
display(Markdown("Shaded: 16–84 % band of the bootstrap ensemble; dotted: extrapolated beyond "
                 "the fitted angles; grey dashed: a closure the data do not identify."))
# replicate chains on bases of their own (hstop_bisection.replicate_bases): where each base's
# brackets lie against the fitted curve -- the scatter between base realisations
from granflow.fitting.hstop import bracket_offsets_by_base

for law in laws:
    for lam in lams:
        sub = chute[(chute["contact_law"] == law) & np.isclose(chute["lam"], lam)]
        r = fit_of("hstop", lam=lam, contact_law=law)
        if ("base_seed" not in sub or sub["base_seed"].nunique() < 2 or r is None
                or r.state == "failed"):
            continue
        display(Markdown(f"Brackets per base realisation ({law}, λ = {lam:g}): number, mean "
                         "and spread of (bracket midpoint − fitted Eq. 45 angle at H), deg"))
        display(bracket_offsets_by_base(sub, r.params["delta1"], r.params["delta2"],
                                        r.params["A"]))
        sc = (r.extra or {}).get("base_scatter")
        if sc:
            display(Markdown(
                f"Offset common to one base's brackets (random effect, in the stderrs): "
                f"σ_b = {sc['sigma_between']:.2f}° between {sc['n_bases']} bases, against "
                f"{sc['sigma_within']:.2f}° within one"))

# %% [markdown]
# ## Flow rule F(h/hstop) (Fig. 11)
# Froude number F = u_bar / sqrt(g cos(theta) h) of the steady runs against h / hstop(theta; 1)
# (hstop of lambda = 1 for every lambda, Eq. 47) with the fitted flow rule
# F = beta h/hstop - gamma; error bars are the spreads over the averaging window.  Right: the
# friction closure mu(h, F) of Eq. (50) at each steady run's h and F (circles) and the measured
# depth-averaged friction (crosses) against tan(theta), which both should equal in steady flow.

# %%
fig, (ax, axm) = plt.subplots(1, 2, figsize=(10, 3.8))
for law in laws:
    h1 = fit_of("hstop", lam=1.0, contact_law=law)
    if h1 is None or not h1.ok:
        ax.text(0.05, 0.9, "no hstop(θ; 1) fit: flow rule unavailable", transform=ax.transAxes)
        continue
    for k, lam in enumerate(lams):
        s = chute[(chute["contact_law"] == law) & np.isclose(chute["lam"], lam)
                  & (chute["state"] == "steady")]
        x = s["h"] / hstop_eq45(s["theta"], h1.params["delta1"], h1.params["delta2"],
                                h1.params["A"])
        ax.errorbar(x, s["F"], yerr=s["F_std"], fmt="o", ms=4, color=f"C{k}",
                    label=f"{law}, λ={lam:g} runs")
        r = fit_of("flow_rule", lam=lam, contact_law=law)
        if r is not None and r.state != "failed" and len(x):
            # band: the flow rule's ensemble joined with hstop's (friction ensemble)
            fr_ = fit_of("friction", lam=lam, contact_law=law)
            ens = fr_.ensemble_array() if fr_ is not None else np.zeros((0, 5))
            xx = np.linspace(0, float(np.nanmax(x)) * 1.1, 60)
            if len(ens):
                lines = ens[:, 3, None] * xx[None, :] - ens[:, 4, None]
                lo_, hi_ = np.nanpercentile(lines, [15.865, 84.135], axis=0)
                ax.fill_between(xx, lo_, hi_, color=f"C{k}" if r.ok else "0.5", alpha=0.18,
                                lw=0)
            ax.plot(xx, r.params["beta"] * xx - r.params["gamma"], "-" if r.ok else "--",
                    color=f"C{k}" if r.ok else "0.5",
                    label=f"β={r.params['beta']:.3f}, γ={r.params['gamma']:.3f} "
                          f"[{r.state}, {r.form}]")
        fr = fit_of("friction", lam=lam, contact_law=law)
        if fr is not None and fr.state != "failed" and len(s):
            mu_fit = mu_eq50(s["h"], s["F"], *(fr.params[p] for p in
                                               ("delta1", "delta2", "A", "beta", "gamma")))
            axm.plot(np.tan(np.radians(s["theta"])), mu_fit, "o", ms=4, color=f"C{k}",
                     label=f"μ(h, F) Eq. (50), {law}, λ={lam:g}")
            axm.plot(np.tan(np.radians(s["theta"])), s["mu_bar"], "x", ms=5, color=f"C{k}",
                     label="measured -σ̄xz/σ̄zz")
ax.set_xlabel("h / hstop(θ; 1)")
ax.set_ylabel("Froude number F")
ax.set_xlim(left=0)
ax.legend(fontsize=7)
lim = axm.get_xlim()
axm.plot(lim, lim, "k:", lw=0.8)
axm.set_xlabel("tan θ (steady flow: basal friction = tan θ)")
axm.set_ylabel("friction μ")
axm.legend(fontsize=7)
savefig(fig, "flow_rule")
display(pd.DataFrame([{"law": r.coords.get("contact_law"), "lambda": r.coords.get("lam"),
                       "status": r.state, "form": r.form,
                       "beta": fmt(r, "beta"), "gamma": fmt(r, "gamma"),
                       "error Eq. (49)": r.error, "n": r.n_points, "selection": r.selection}
                      for r in fits if r.kind == "flow_rule"]))

# %% [markdown]
# ## Depth profiles of representative runs (Fig. 6–8)
# Coarse-grained (Gaussian width w) profiles averaged over the steady window: density, downslope
# velocity, normal stress with the lithostatic check sigma_zz(z) = int_z rho g cos(theta) dz'
# (dotted), and the friction -sigma_xz/sigma_zz against tan(theta) (dotted).

# %%
steady = chute[chute["state"] == "steady"].sort_values(["H", "theta"])
reps = []
if len(steady):
    thick = steady[steady["H"] == steady["H"].max()]
    idx = np.unique(np.linspace(0, len(thick) - 1, min(3, len(thick))).round().astype(int))
    reps = list(thick.iloc[idx]["run"])
fig, axes = plt.subplots(1, 4, figsize=(13, 3.8), sharey=True)
for k, run in enumerate(reps):
    ds = xr.open_dataset(R / run / "profiles.nc")
    row = steady[steady["run"] == run].iloc[0]
    z = ds["z"].values
    lab = f"θ={row['theta']:g}°, H={row['H']:g}"
    axes[0].plot(ds["density"] / U.RHO_PARTICLE, z, color=f"C{k}", label=lab)
    axes[1].plot(ds["velocity_x"], z, color=f"C{k}")
    szz = ds["stress_zz"].values
    rho = ds["density"].values
    litho = np.cumsum((rho * math.cos(math.radians(row["theta"])))[::-1])[::-1] * (z[1] - z[0])
    axes[2].plot(szz, z, color=f"C{k}")
    axes[2].plot(litho, z, ":", color=f"C{k}")
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = np.where(szz > 0.02 * np.nanmax(szz), -ds["stress_xz"].values / szz, np.nan)
    axes[3].plot(mu, z, color=f"C{k}")
    axes[3].axvline(math.tan(math.radians(row["theta"])), ls=":", color=f"C{k}")
axes[0].set_ylabel("z (d)")
axes[0].set_xlabel("volume fraction ρ/ρp")
axes[1].set_xlabel("velocity u_x (√(gd))")
axes[2].set_xlabel("σ_zz (mg/d²); dotted: ∫ρ g cosθ dz")
axes[3].set_xlabel("friction -σ_xz/σ_zz; dotted: tan θ")
axes[3].set_xlim(0, 1)
if reps:
    axes[0].legend(fontsize=7)
else:
    axes[0].text(0.1, 0.5, "no steady runs", transform=axes[0].transAxes)
savefig(fig, "profiles")

# %% [markdown]
# ## Bulk density, stress ratio and shape factor against inclination (Fig. 12–13)
# Bulk volume fraction rho_c/rho_p over [b + 2, s - 4] (Eq. 51) with Eq. (52); normal stress
# ratio K = sigma_xx/sigma_zz with Eq. (53); velocity shape factor alpha = <u^2>/u_bar^2 with the
# basal-layer model Eq. (54) evaluated at each run's h (crosses) or the constant of Eq. (55).
# Steady runs on rough bases (lambda > 0) only; error bars are window spreads.

# %%
fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
rough = chute[(chute["state"] == "steady") & (chute["lam"] > 0)]
th = np.linspace(rough["theta"].min() - 1, rough["theta"].max() + 1, 100) if len(rough) else None
for law in laws:
    s = rough[rough["contact_law"] == law]
    axes[0].errorbar(s["theta"], s["rho_c"] / U.RHO_PARTICLE, yerr=s["rho_c_std"] / U.RHO_PARTICLE,
                     fmt="o", ms=4, label=f"{law} runs")
    r = fit_of("density", contact_law=law)
    if r is not None and r.state != "failed" and th is not None:
        draw_closure(axes[0], th, lambda x: gc.density(lib, x, contact_law=law, uncertainty=True,
                                                       extrapolate=True, allow_unidentified=True,
                                                       impossible="nan"),
                     fitted_range("density", "theta", contact_law=law), "k",
                     f"density, {r.form} form", r.state,
                     transform=lambda v: v / U.RHO_PARTICLE)
    axes[1].errorbar(s["theta"], s["K"], yerr=s["K_std"], fmt="o", ms=4, label=f"{law} runs")
    r = fit_of("stress_ratio", contact_law=law)
    if r is not None and r.state != "failed" and th is not None:
        draw_closure(axes[1], th, lambda x: gc.K(lib, x, contact_law=law, uncertainty=True,
                                                 extrapolate=True, allow_unidentified=True,
                                                 impossible="nan"),
                     fitted_range("stress_ratio", "theta", contact_law=law), "k",
                     f"K, {r.form} form", r.state)
    h1 = fit_of("hstop", lam=1.0, contact_law=law)
    for k, lam in enumerate(sorted(set(s["lam"]))):
        sl = s[np.isclose(s["lam"], lam)]
        axes[2].errorbar(sl["theta"], sl["alpha"], yerr=sl["alpha_std"], fmt="o", ms=4,
                         color=f"C{k}", label=f"{law}, λ={lam:g}")
        r = fit_of("alpha", lam=lam, contact_law=law)
        if r is None or r.state == "failed":
            continue
        if np.isfinite(r.params.get("d_lambda", math.nan)) and h1 is not None \
                and h1.state != "failed":
            hs = hstop_eq45(sl["theta"], h1.params["delta1"], h1.params["delta2"], h1.params["A"])
            axes[2].plot(sl["theta"], alpha_eq54(sl["h"], hs, r.params["d_lambda"]), "x",
                         color=f"C{k}", ms=7, label=f"Eq. (54), d_λ={r.params['d_lambda']:.2f}"
                         f" [{r.state}]")
        elif np.isfinite(r.params.get("alpha_constant", math.nan)):
            a0, se = r.params["alpha_constant"], r.stderr["alpha_constant"]
            axes[2].axhspan(a0 - se, a0 + se, color=f"C{k}", alpha=0.15, lw=0)
            axes[2].axhline(a0, color=f"C{k}", ls="--",
                            label=f"constant α={a0:.3f} ± {se:.3f} [{r.state}, {r.form}]")
display(Markdown("Shaded: 16–84 % band of the closure's ensemble; dotted: extrapolated beyond "
                 "the fitted angles; grey dashed: not identified (inspection only)."))
axes[0].set_ylabel("bulk volume fraction ρc/ρp")
axes[1].set_ylabel("stress ratio K")
axes[2].set_ylabel("shape factor α")
for ax in axes:
    ax.set_xlabel("inclination θ (deg)")
    ax.legend(fontsize=7)
savefig(fig, "density_K_alpha")

# %% [markdown]
# ## Segregation: phi(z) profiles and Ps(sigma) (Thornton et al. Fig. 8)
# Small-particle volume fraction phi against the scaled height (z - b)/(s - b), averaged over
# the last window of each bidisperse run, with the fitted steady profile T-eq. (28) (lines);
# right: the fitted Peclet numbers Ps (error bars: spread of the per-window fits) against the
# size ratio 1/sigma with T-eq. (29), Ps = Pmax (1 - exp(-k (1/sigma - 1))).

# %%
fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
for k, item in enumerate(sorted(seg_runs, key=lambda d: d["fit"]["coords"].get("sigma", 1))):
    f, prof = item["fit"], item["profile"]
    sig = f["coords"].get("sigma")
    zeta, phi = np.asarray(prof["zeta"]), np.asarray(prof["phi"])
    axes[0].plot(phi, zeta, ".", ms=3, color=f"C{k}")
    if f["ok"]:
        zz = np.linspace(0, 1, 100)
        axes[0].plot(phi_teq28(zz, f["params"]["Ps"], f["extra"]["phi0"]), zz, "-",
                     color=f"C{k}", label=f"σ={sig:g}: Ps={f['params']['Ps']:.2f}")
axes[0].set_xlabel("small-particle fraction φ")
axes[0].set_ylabel("scaled height (z - b)/(s - b)")
axes[0].set_xlim(0, 1)
if seg_runs:
    axes[0].legend(fontsize=7)
for law in laws:
    s = seg[(seg["contact_law"] == law) & np.isfinite(seg["Ps"])]
    rps = fit_of("Ps_law", contact_law=law)
    used = s["run"].isin(rps.runs_used if rps is not None else ()) if "run" in s else \
        np.ones(len(s), bool)
    yerr = s["Ps_sem"] if "Ps_sem" in s and np.isfinite(s["Ps_sem"]).any() else s["Ps_std"]
    axes[1].errorbar(1 / s["sigma"][used], s["Ps"][used], yerr=yerr[used], fmt="o", ms=5,
                     label=f"{law} runs used (error: windows' stderr or wander at N)")
    if (~used).any():
        # a drifting run bounds its steady Ps: from below after a mixed start (^), from above
        # after a segregated one (v)
        start = (s["initial_mixing"].astype(str) if "initial_mixing" in s
                 else pd.Series("mixed", index=s.index))
        for mark, which, what in (("^", start != "segregated", "mixed start: lower bound"),
                                  ("v", start == "segregated", "segregated start: upper bound")):
            sel = ~used & which
            if sel.any():
                axes[1].errorbar(1 / s["sigma"][sel], s["Ps"][sel], yerr=yerr[sel], fmt=mark,
                                 ms=5, mfc="none", color="0.5",
                                 label=f"runs left out (not steady; {what})")
    r = fit_of("Ps_law", contact_law=law)
    if r is not None and r.state != "failed":
        xs = np.linspace(1.01, max(2.0, float((1 / s["sigma"]).max()) + 0.1), 100)
        lo_s, hi_s = fitted_range("Ps_law", "sigma", contact_law=law)
        draw_closure(axes[1], 1 / xs, lambda x: gc.Ps(lib, x, contact_law=law,
                                                     uncertainty=True, extrapolate=True,
                                                     allow_unidentified=True),
                     (lo_s, hi_s), "k", f"Ps law, {r.form} form", r.state, xplot=xs)
        lb = r.extra.get("Pmax_lower_bound")
        if r.form == "linear" and lb is not None:
            axes[1].axhline(lb, color="0.4", ls="-.", lw=0.8,
                            label=f"Pmax ≥ {lb:.2f} (95 % lower bound from the data)")
        kb = r.extra.get("k_lower_bound")
        ku = r.extra.get("k_upper_bound")
        if r.form in ("plateau", "linear") and (kb or (ku is not None and np.isfinite(ku))):
            what = "saturated" if r.form == "plateau" else "not saturated"
            rng_k = (f"{kb or 0:.2f} ≤ k ≤ {ku:.2f}" if ku is not None and np.isfinite(ku)
                     else f"k ≥ {kb:.2f}")
            axes[1].plot([], [], " ", label=f"{what}: {rng_k} (95 %)")
    else:
        axes[1].text(0.02, 0.9, "Ps(σ) law: " + (r.message if r is not None else "not fitted"),
                     transform=axes[1].transAxes, fontsize=7, wrap=True)
if len(seg):
    xs = np.linspace(1, max(2.0, float((1 / seg["sigma"]).max()) + 0.1), 100)
    axes[1].plot(xs, Ps_teq29(1 / xs, 7.35, 5.21), "k:", lw=1,
                 label="paper: Pmax=7.35, k=5.21 (83.3 × 5 box)")
axes[1].set_xlabel("size ratio 1/σ = d_large/d_small")
axes[1].set_ylabel("Péclet number Ps")
axes[1].legend(fontsize=7)
savefig(fig, "segregation")

# %% [markdown]
# ### Symmetric vs asymmetric segregation flux, per run
# The same phi profile fitted with T-eq. (28) (flux Sr phi (1 - phi), one parameter Ps) and with
# the asymmetric flux of seed 001 Eq. (2.9) (A phi (1 - phi)(1 - kappa phi), parameters Ps and
# kappa): rms residuals and Gaussian AIC (lower is better; the extra parameter costs 2).
# "kappa status" is the fit's own: "fixed" where the profile does not identify kappa (its best
# value at the bound 0, no asymmetry), and the asymmetric row is then the symmetric fit again.
# "segregated state" says whether the small-particle centre of mass had stopped drifting
# (steady: the profile is averaged over the steady window; drifting: over the last window).
# "Ps stderr" is the larger of the run's decorrelated windows' standard error ("windows' sem")
# and the wander of a profile window's Ps in time at the run's N flow particles, C Ps / sqrt(N)
# with C measured on long runs ("wander at N"; granflow.fitting.segregation.wander_sd): the
# segregated state wanders over 40-300 time units, which one run's windows do not see.
# "Ps trend" is the linear change of Ps over the profile's windows (relative to its mean, with
# its p-value); a run counts as drifting only when it is significant and beyond "trend
# tolerance", 3 C / sqrt(N) or 5 % (granflow.campaign.collect.ps_trend_tolerance): a smaller
# trend is what the wander alone makes, pointing away from the long mean as often as towards it.

# %%
cmp_rows = []
for item in sorted(seg_runs, key=lambda d: d["fit"]["coords"].get("sigma", 1)):
    ex = item["fit"].get("extra", {})
    cmp_rows.append({
        "1/sigma": 1 / item["fit"]["coords"].get("sigma", 1.0),
        "Ps (sym.)": ex.get("symmetric_Ps"), "rms (sym.)": ex.get("symmetric_rms_residual"),
        "AIC (sym.)": ex.get("symmetric_aic"),
        "Ps (asym.)": ex.get("asymmetric_Ps"), "kappa": ex.get("asymmetric_kappa"),
        "kappa status": ex.get("asymmetric_kappa_status", "n/a"),
        "rms (asym.)": ex.get("asymmetric_rms_residual"), "AIC (asym.)": ex.get("asymmetric_aic"),
        "segregated state": ex.get("segregation_state", "n/a"),
        "profile from t": ex.get("profile_time_from"),
        "Ps stderr": (item["fit"].get("stderr") or {}).get("Ps"),
        "windows' sem": ex.get("Ps_windows_sem"), "wander at N": ex.get("Ps_wander_sd"),
        "Ps trend": ex.get("Ps_trend_change"), "trend p": ex.get("Ps_trend_p"),
        "trend tolerance": ex.get("Ps_trend_tolerance"),
    })
display(pd.DataFrame(cmp_rows).round(4) if cmp_rows else Markdown("no segregation runs"))

# %% [markdown]
# ## Snapshot of a chute (Fig. 2)
# The final particle configuration of a representative steady run, seen from the side (x
# downslope, z normal to the base; all particles across the width projected), coloured by
# speed |v|; the fixed rough-base particles are grey.

# %%
pick = reps[-1] if reps else (chute.iloc[-1]["run"] if len(chute) else None)
if pick is not None:
    st = np.load(R / pick / "final_state.npz")
    pos, vel, rad, fixed = st["pos"], st["vel"], st["radius"], st["fixed"].astype(bool)
    speed = np.linalg.norm(vel, axis=1)
    order = np.argsort(-pos[:, 1])  # paint back (large y) to front (small y)
    pos, speed, rad, fixed = pos[order], speed[order], rad[order], fixed[order]
    Lx = float(json.loads((R / pick / "summary.json").read_text())["params"]["Lx"])
    xw = np.mod(pos[:, 0], Lx)
    z0, z1 = pos[:, 2].min() - 1, pos[:, 2].max() + 1
    fig, ax = plt.subplots(figsize=(min(14.0, 0.6 * Lx + 2.5), min(8.0, 0.6 * (z1 - z0) + 1.0)))
    ax.set_aspect("equal")
    ax.set_xlim(0, Lx)
    ax.set_ylim(z0, z1)
    fig.tight_layout()
    fig.canvas.draw()
    # marker area in points^2 so that each disc has the particle's diameter on screen
    ppd = (ax.transData.transform((1, 0))[0] - ax.transData.transform((0, 0))[0]) * 72 / fig.dpi
    ax.scatter(xw[fixed], pos[fixed, 2], s=(2 * rad[fixed] * ppd) ** 2, c="0.6",
               edgecolors="none")
    sc = ax.scatter(xw[~fixed], pos[~fixed, 2], s=(2 * rad[~fixed] * ppd) ** 2, c=speed[~fixed],
                    cmap="viridis", edgecolors="k", linewidths=0.2)
    fig.colorbar(sc, ax=ax, label="speed |v| (√(gd))", shrink=0.8)
    ax.set_xlabel("x (downslope, d)")
    ax.set_ylabel("z (d)")
    ax.set_title(f"{pick}, t = {json.loads((R / pick / 'summary.json').read_text())['t_final']:.0f}")
else:
    fig, ax = plt.subplots(figsize=(4, 2))
    ax.text(0.1, 0.5, "no chute runs", transform=ax.transAxes)
savefig(fig, "snapshot")

# %% [markdown]
# ## Held-out check
# Each run in turn is left out, the closure is refitted to the others and predicts it;
# z = (measured - predicted) / sqrt(run's standard error^2 + prediction variance + the closure's
# intrinsic scatter estimated without the run).  A closure whose largest |z| exceeds the limit
# (3 for one run; the Bonferroni-equivalent for n runs, same 0.27 % false-alarm probability) is
# flagged `misfit`.  hstop's z compares the refitted curve with each bracket's midpoint.

# %%
zrows = []
for r in fits:
    for run, z in (r.diagnostics.get("heldout_z") or {}).items():
        zrows.append({"closure": r.kind, "lambda": r.coords.get("lam", ""), "run": run, "z": z})
if zrows:
    zt = pd.DataFrame(zrows)
    kinds = list(dict.fromkeys(zt["closure"]))
    fig, ax = plt.subplots(figsize=(max(5.0, 1.3 * len(kinds)), 3.4))
    for k, kind in enumerate(kinds):
        zk = zt[zt["closure"] == kind]["z"].to_numpy(float)
        ax.plot(np.full(zk.size, k) + np.linspace(-0.15, 0.15, zk.size), zk, "o", ms=4,
                color=f"C{k}")
    ax.axhspan(-3, 3, color="tab:green", alpha=0.08, lw=0)
    ax.axhline(3, color="k", ls=":", lw=0.8)
    ax.axhline(-3, color="k", ls=":", lw=0.8)
    ax.set_xticks(range(len(kinds)))
    ax.set_xticklabels(kinds, rotation=30, fontsize=8)
    ax.set_ylabel("held-out z")
    savefig(fig, "heldout_z")
    summary = zt.assign(absz=zt["z"].abs()).groupby(["closure", "lambda"]).agg(
        runs=("z", "size"), max_abs_z=("absz", "max")).reset_index()
    summary["status"] = [status_of(k, **({"lam": float(l)} if l != "" else {}))
                         for k, l in zip(summary["closure"], summary["lambda"])]
    display(summary)
else:
    fig, ax = plt.subplots(figsize=(5.0, 2.0))
    ax.text(0.05, 0.5, "no closure could be held out (too few runs)", transform=ax.transAxes)
    ax.set_axis_off()
    savefig(fig, "heldout_z")

# %% [markdown]
# ## Replicates: scatter between seeds against the runs' own uncertainty
# Runs of one point with different insertion seeds (`replicates`) scatter by more than one
# run's time windows show, most of all near hstop and in small boxes.  tau is the between-seed
# standard deviation beyond the runs' decorrelated standard errors (pooled over the replicate
# groups); the fits weight each run by sqrt(stderr^2 + tau^2) and split every parameter's
# variance into the two parts (closure table: `between_seed_fraction`).  In the plots above,
# replicates are the points that share an inclination and height.

# %%
from granflow.fitting.campaign import between_seed_scatter

rep_rows = []
for col in ("F", "rho_c", "K", "alpha", "h", "Ps"):
    sub = table[(table["state"] == "steady")]
    if col == "Ps" and "segregation_state" in sub.columns:
        # a drifting run's Ps is a one-sided bound, not a draw of the steady value
        sub = sub[sub["segregation_state"].astype(str) == "steady"]
    tau, n_groups, within = between_seed_scatter(sub, col)
    rep_rows.append({"quantity": col, "replicate groups": n_groups,
                     "between-seed std tau": tau,
                     "within-run stderr (pooled)": math.sqrt(within) if n_groups else math.nan,
                     "ratio": tau / math.sqrt(within) if n_groups and within > 0 else math.nan})
display(pd.DataFrame(rep_rows) if any(r["replicate groups"] for r in rep_rows)
        else Markdown("No replicates in this campaign (`replicates: 1`): the stated "
                      "uncertainties are within-run only and do not include the scatter "
                      "between seeds."))

# %% [markdown]
# ## Closure table
# Every fitted parameter of the library with its standard error (bootstrap for hstop and the
# closures that depend on it, weighted least-squares covariance otherwise), its status, the
# fit's error Eq. (49), the number of runs and the largest held-out |z|.  The
# paper's values (Weinhart et al. 2012 Table 1-2 at the reference parameters t_c = 0.005, box
# 20 x 10, t = 2000; Thornton et al. for Pmax, k) are shown for comparison only -- this
# campaign's reductions (above) shift them.

# %%
ct = closure_rows(fits)
ct = ct[ct["kind"] != "segregation"].copy()


def paper_value(r):
    lam = None if not np.isfinite(r["lambda"]) else float(r["lambda"])
    return _paper_value(r["kind"], r["parameter"], lam)


ct["paper"] = ct.apply(paper_value, axis=1)
with pd.option_context("display.max_rows", 200, "display.max_colwidth", 60):
    display(ct[["kind", "contact_law", "lambda", "parameter", "value", "stderr",
                "parameter_status", "status", "form", "paper", "fit_error", "n_points",
                "heldout_max_abs_z", "between_seed_fraction"]])
cmp_paper = pd.DataFrame(compare_with_paper(fits))
if len(cmp_paper):
    display(Markdown("**Against the paper** (agrees: within 2 of its own stderr, or within 5 % "
                     "where that is looser; meaningful only at the paper's species and "
                     "protocol -- see the reductions above):"))
    display(cmp_paper)
curve_rows = pd.DataFrame(compare_curve(fits))
if len(curve_rows):
    display(Markdown("**The papers' curves against the fitted ones** (ours − the paper's, mean "
                     "over the bracket heights or the fitted range, stderr from the fit's "
                     "ensemble): correlated parameters can each agree within their stderrs "
                     "while the curve, which the data pin far better, lies off the paper's:"))
    display(curve_rows.drop(columns=["points"]))
law_rows = pd.DataFrame(paper_law_errors(fits, table) if "run" in table else [])
if len(law_rows):
    display(Markdown("**The paper's own law on this campaign's runs** (Eq. 47 with Table 1, "
                     "Table 2's alpha; the runs each closure used): its Eq. (49) error against "
                     "the paper's fit error.  A ratio near 1 says the law describes these runs as "
                     "well as it described the paper's, even where single parameters differ:"))
    display(law_rows)

# %% [markdown]
# ## Continuum consumers: the closures in use (granflow.continuum)
# The library drives three continuum models; each is checked against particle runs the
# library was not fitted on when those exist (`results/continuum/comparison.json`, written by
# `python -m granflow.continuum.experiments compare`, see the package docstring).  Closures
# that are not `ok`/`reduced` are used with `allow_unidentified=True` and marked so.

# %%
from granflow.continuum import FlowClosures, segregation_layer, shallow_layer, switch_prediction
from granflow.continuum.experiments import format_tables

COMPARISON = R.parent / "continuum" / "comparison.json"
comparison = json.loads(COMPARISON.read_text()) if COMPARISON.exists() else None
cst = lib.closures.status()
used = cst[cst["kind"].isin(["friction", "alpha", "stress_ratio", "segregation",
                             "diffusivity"])]
display(used.groupby("kind")["status"].agg(lambda s: "/".join(sorted(set(s)))).to_frame())
if comparison is not None:
    print(format_tables(comparison))
else:
    display(Markdown(f"No particle comparison at `{COMPARISON}`: predictions only below."))

# %% [markdown]
# ### 1. Uniform layer after a change of inclination (Eq. 34 as an ODE)
# du/dt = g cos(theta) (tan(theta) - mu(h, F)): the steady runs of this campaign switched by
# +-1.5 degrees, with the 16-84 % band over the friction closure's ensemble (dotted: outside the
# fitted (h, F) region, extrapolated); thin dashed: the same closures as a depth-resolved column
# (`model="column"`, granflow.continuum.column: the profile adjusts by shear, 1.28x the ODE's
# linear e-folding time).  With particle switch runs: the table below.

# %%
steady_runs = table[(table["state"] == "steady") & (table["kind"] == "chute")
                    if "kind" in table else (table["state"] == "steady")]
steady_runs = steady_runs.sort_values("H").drop_duplicates("H", keep="last")
fig, axes = plt.subplots(1, max(len(steady_runs), 1), figsize=(3.0 * max(len(steady_runs), 1),
                                                                2.6), squeeze=False)
for ax, (_, r) in zip(axes[0], steady_runs.iterrows()):
    for dth, colour in ((1.5, "C3"), (-1.5, "C0")):
        kw = dict(h=r["h"], u0=r["u_bar"], theta=r["theta"] + dth, t_end=150.0,
                  allow_unidentified=True, n_ensemble=40)
        try:
            pred, ls = switch_prediction(lib, **kw), "-"
        except ValueError:
            try:
                pred, ls = switch_prediction(lib, extrapolate=True, **kw), ":"
            except ValueError as err:  # e.g. a failed friction closure: say so, no prediction
                ax.text(0.02, 0.5, textwrap.fill(str(err), 50), fontsize=5,
                        transform=ax.transAxes)
                continue
        ax.fill_between(pred.t, pred.u_bar.sel(stat="low"), pred.u_bar.sel(stat="high"),
                        color=colour, alpha=0.25)
        ax.plot(pred.t, pred.u_bar.sel(stat="value"), ls, color=colour,
                label=f"-> {r['theta'] + dth:g} deg")
        try:
            col = switch_prediction(lib, extrapolate=True, uncertainty=False, model="column",
                                    **kw)
            ax.plot(col.t, col.u_bar.sel(stat="value"), "--", lw=0.8, color=colour)
        except (ValueError, RuntimeError) as err:   # e.g. a stalled column: say so, go on
            ax.text(0.02, 0.1, textwrap.fill(f"column: {err}", 50), fontsize=5,
                    transform=ax.transAxes)
    ax.set_title(f"H = {r['H']:g}, from {r['theta']:g} deg", fontsize=8)
    ax.set_xlabel("t since switch")
    ax.legend(fontsize=6)
axes[0][0].set_ylabel("u_bar")
if not len(steady_runs):
    axes[0][0].text(0.05, 0.5, "no steady run to switch", transform=axes[0][0].transAxes)
    axes[0][0].set_axis_off()
fig.tight_layout()
savefig(fig, "continuum_switch_predictions")
if comparison is not None and comparison["switches"]:
    sw = pd.DataFrame([{k: s.get(k) for k in ("H", "theta1", "theta2", "child_state", "u_steady",
                                               "ode_u_steady", "ode_u_steady_std",
                                               "err_u_steady", "tau", "tau_stderr", "ode_tau",
                                               "ode_tau_std", "err_tau", "column_tau",
                                               "column_tau_std", "err_tau_column",
                                               "extrapolated")}
                       for s in comparison["switches"] if "error" not in s])
    display(sw)

# %% [markdown]
# ### 2. Shallow-layer equations (Eq. 34) in one dimension
# A bump on the uniform steady flow of the thinnest steady thick run, on a periodic domain of
# length 100, with the library's mu(h, F), alpha and K; with a long-chute particle run: the
# distance travelled by the peak and the front, particles against the solver (solid) and its
# local-equilibrium limit, the kinematic wave u = u_s(h) (dotted).

# %%
flow_closures = None
if len(steady_runs):
    r = steady_runs.iloc[-1]
    try:
        flow_closures = FlowClosures.from_library(lib, float(r["theta"]), allow_unidentified=True)
    except ValueError as err:  # a failed closure is refused even for inspection: say so
        display(Markdown(f"No shallow-layer prediction: {err}"))
if flow_closures is not None:
    c = flow_closures
    x = np.arange(200) * 0.5 + 0.25
    h0 = r["h"] * (1.0 + 0.15 * np.exp(-((x - 20.0) / 6.0) ** 2))
    u0 = c.steady_froude(h0) * np.sqrt(c.g_cos * h0)
    sol = shallow_layer(c, x, h0, np.nan_to_num(u0), t_end=40.0, n_out=5, extrapolate=True)
    fig, axes = plt.subplots(1, 2, figsize=(8.0, 2.6))
    for k in range(sol.sizes["t"]):
        axes[0].plot(x, sol.h.isel(t=k), label=f"t = {float(sol.t[k]):g}")
    axes[0].set_xlabel("x")
    axes[0].set_ylabel("h")
    axes[0].legend(fontsize=6)
    axes[0].set_title(f"theta = {r['theta']:g}: bump on h = {r['h']:.3g} "
                      f"(mass drift {float(sol.mass[-1] / sol.mass[0] - 1):.1e})", fontsize=8)
    lc = comparison.get("long_chute") if comparison else None
    if lc:
        t = [q["t"] for q in lc["rows"]]
        for f, colour in (("peak", "C1"), ("front", "C2")):
            axes[1].plot(t, [q[f"{f}_travel_particles"] for q in lc["rows"]], "o", ms=3,
                         color=colour, label=f"{f}: particles")
            axes[1].plot(t, [q[f"{f}_travel_solver"] for q in lc["rows"]], "-", color=colour,
                         label=f"{f}: solver")
            lk = comparison.get("long_chute_kinematic")
            if lk and "error" not in lk:
                axes[1].plot([q["t"] for q in lk["rows"]],
                             [q[f"{f}_travel_solver"] for q in lk["rows"]], ":", color=colour,
                             label=f"{f}: kinematic wave")
        axes[1].set_xlabel("t")
        axes[1].set_ylabel("distance travelled")
        axes[1].legend(fontsize=6)
    else:
        axes[1].text(0.05, 0.5, "no long-chute particle run", transform=axes[1].transAxes)
        axes[1].set_axis_off()
    fig.tight_layout()
    savefig(fig, "continuum_shallow_layer")

# %% [markdown]
# ### 3. Segregation in depth (T-eq. 27)
# s(t) = z_com(small) - z_com(all) of the bidisperse runs from the start of the flow, and the
# model with the library's Ps (symmetric flux) or the run's asymmetric-flux fit (seed 001),
# with the diffusivity D = c_D (u_bar/h) d_mean^2 of the library (needs the `diffusivity`
# closure: the continuum comparison's library version has it, the campaign's alone does not).
# Both are drawn from the run's s(t0): the particles segregate part-way while they fall in, so
# the model's clock starts where its s reaches s(t0) (half-times from there, both).

# %%
seg_cmp = [s for s in (comparison or {}).get("segregation", []) if "error" not in s]
if seg_cmp:
    fig, axes = plt.subplots(1, len(seg_cmp), figsize=(2.6 * len(seg_cmp), 2.6), squeeze=False)
    for ax, s in zip(axes[0], seg_cmp):
        ax.plot(s["t"], s["s"], "k.", ms=2, label="particles")
        for name, colour in (("symmetric", "C0"), ("asymmetric", "C3")):
            ax.plot(s[name]["t"], s[name]["s"], color=colour,
                    label=f"{name}: t1/2 {s[name]['t_half']:.0f} ({s[name]['err_t_half']:+.0%})")
        ax.set_title(f"sigma = {s['sigma']:g}, t1/2 particles {s['t_half']:.0f}", fontsize=8)
        ax.set_xlabel("t - t0")
        ax.legend(fontsize=5)
    axes[0][0].set_ylabel("s - s(t0)")
    fig.tight_layout()
    savefig(fig, "continuum_segregation")
elif "diffusivity_ok" in lib:
    display(Markdown("The library has a diffusivity closure but no comparison was run."))
else:
    display(Markdown("This library has no `diffusivity` closure: the segregation time scale "
                     "h^2/D is not predicted here (see `granflow.continuum.experiments`)."))
