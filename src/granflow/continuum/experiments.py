"""Particle runs that test the continuum models, and their comparisons with the predictions.

The closure library is fitted to steady uniform runs; these runs are *not* in it:

* **Change of inclination** (:func:`run_switch`, :func:`compare_switch`): a steady campaign run
  at theta1 restarted from its ``final_state.npz`` at theta2 (``granflow simulate --from``),
  with tracer heights recorded for the self-diffusivity.  Compared with the uniform-layer ODE
  (:func:`granflow.continuum.switch_prediction`) started from the parent's h and u_bar: the new
  steady u_bar and the e-folding time of the transient (the same exponential fit on both);
  and with the depth-resolved column of :mod:`granflow.continuum.column` (the same friction
  law as a local rheology: the profile has to adjust by shear, 1.28x the ODE's linear
  e-folding time; ``column_*`` fields).  ``tau_dilation``: the e-folding time of the layer's
  centre of mass (slope-normal potential energy) after the switch, against u_bar's ``tau``.
* **Long chute** (:func:`build_long_chute`, :func:`run_long_chute`, :func:`compare_long_chute`):
  steady states of small periodic boxes on the same rough base tiled along x (a few tiles of a
  thicker flow make a bump), run with x-resolved depth-integrated coarse-graining
  (:mod:`granflow.coarse.columns`), and the shallow-layer solver started from the same h(x),
  u_bar(x): positions of the peak and of the front over time; Eq. (34) as the paper writes it
  (``long_chute``), with the depth-averaged viscous stress of Gray & Edwards (2014), nu from
  the library's flow rule at the mean depth (``long_chute_viscous``), and its local-equilibrium
  limits, the kinematic wave (``long_chute_kinematic``) and the diffusive wave
  (``long_chute_diffusive``) of :mod:`granflow.continuum.kinematic`.
* **Segregation** (:func:`compare_segregation`): the campaign's bidisperse runs' indicator s(t)
  against T-eq. (27) with the library's Ps and the measured diffusivity D (both flux models);
  the half-time counts from the run's s0 at its flow start t0 in both, the model's clock shifted
  to where it reaches s0 (:func:`aligned_half_time`): the particles segregate part-way while
  they fall in, before the sheared state the model assumes exists.
* **Diffusivity** (:func:`diffusivity_fit`): D of the switch runs' steady windows ->
  a ``diffusivity`` closure, added to a new version of the campaign's library
  (:func:`library_with_diffusivity`).
* **Diffusivity where segregation acts** (:func:`run_segregation_tracers`,
  :func:`transient_diffusivity`): each bidisperse run simulated again from its start (same
  parameters and seed, so the same trajectory) with tracer heights, and D measured over its
  segregation transient (from its start-up t0 to twice its half-time), all particles and per
  species.  It chose the closure's length scale for a mixture: measured 2026-11-26 on
  continuum-soft (sigma 0.5-0.9), D over the transient is 0.0088-0.0117 at every ratio, the
  closure at the *small* diameter 0.78-1.05x of it, while the volume-weighted mean diameter (as
  Fan et al. 2014's local mean) gave 1.5-1.8x at sigma 0.5-0.7; so :func:`compare_segregation`
  uses ``d_mean = 1`` (:data:`SEGREGATION_D_LENGTH`).

* **Segregation at the paper's set-up** (:func:`compare_segregation_reference`): a run of the
  segregation reference (depth 24, where the steady interface is ~3 d wide and resolved)
  simulated in its campaign folder with tracers (``segregation-run``); Ps from its steady
  profile (its library cell) or a T-eq. (29) law, D from its own steady window
  (:func:`steady_diffusivity`) or its transient.

Command line: ``python -m granflow.continuum.experiments [-v] {switch,long-chute,diffusivity,
segregation-tracers,segregation-run,compare-segregation,compare-long-chute,compare} ...``
(``-h`` for the arguments); the slow tests in ``tests/test_continuum_slow.py`` and
``tests/test_continuum_paper_slow.py`` run the comparisons with the issue's tolerances.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
from pathlib import Path

import numpy as np
import xarray as xr

from .. import units as U
from ..provenance import atomic_to_netcdf, atomic_write_bytes

#: tolerances of the comparisons (issue 17)
TOL_STEADY_U = 0.05
TOL_TAU = 0.25
TOL_POSITION = 0.15
TOL_HALF_TIME = 0.20

#: models of the long-chute comparison (:func:`compare_long_chute`)
LONG_CHUTE_MODELS = ("shallow", "kinematic_wave", "diffusive_wave")

#: length scale of the diffusivity closure D = c_D (u_bar/h) d^2 in a bidisperse layer, in
#: small-particle diameters: "small" (d = 1, as measured over the segregation transients by
#: :func:`transient_diffusivity`) or "volume_mean" (phi0 + (1 - phi0)/sigma)
SEGREGATION_D_LENGTH = "small"


def _summary(run_dir) -> dict:
    return json.loads((Path(run_dir) / "summary.json").read_text())


def _json_write(path, obj):
    def default(x):
        if isinstance(x, (np.floating, np.integer)):
            return x.item()
        if isinstance(x, np.ndarray):
            return x.tolist()
        return str(x)
    atomic_write_bytes(path, json.dumps(obj, indent=1, default=default).encode())


# ----------------------------------------------------------------------------- switches
def run_switch(parent_dir, theta2: float, out_dir, *, t_end: float = 250.0,
               tracer_interval: float = 0.5, threads: int = 1, **overrides) -> dict:
    """Restart the steady run in ``parent_dir`` at ``theta2`` (its parameters otherwise);
    records tracer heights every ``tracer_interval`` into ``tracers.npz``."""
    parent_dir = Path(parent_dir)
    params = dict(_summary(parent_dir)["params"])
    params.update(theta=float(theta2), t_end=float(t_end), **overrides)
    return _simulate_with_tracers(params, out_dir, tracer_interval, threads,
                                  from_state=parent_dir / "final_state.npz")


def _simulate_with_tracers(params, out_dir, tracer_interval, threads, **kw) -> dict:
    """:func:`granflow.simulate.simulate` with a :class:`TracerObserver` every
    ``tracer_interval``; the heights go to ``out_dir/tracers.npz``."""
    from ..coarse.diffusion import TracerObserver
    from ..simulate import simulate

    out_dir = Path(out_dir)
    sample = params["t_c"] / 2.0 if params.get("sample_interval") is None else \
        params["sample_interval"]
    tracer = TracerObserver(every=max(1, int(round(tracer_interval / sample))))
    res = simulate(params, out_dir, threads=threads, extra_observers=[tracer], **kw)
    t, z, d = tracer.arrays()
    np.savez(out_dir / "tracers.npz", time=t, z=z, diameter=d)
    return res


def _unidentified_relaxation(fit: dict, t_run: float) -> str:
    """Why an exponential fit (:func:`granflow.continuum.fit_relaxation`) identifies no
    e-folding time ('' when it does): tau must lie inside the run and its stderr below half of
    it (noise that hides the approach gives tau +- more than tau)."""
    tau, se = fit["tau"], fit["tau_stderr"]
    if 0 < tau < t_run and se < 0.5 * tau:
        return ""
    return f"unidentified: tau {tau:.4g} +- {se:.2g} over a run of {t_run:.4g}"


def switch_measurement(parent_dir, child_dir) -> dict:
    """Particle-run numbers of one switch: parent h, u_bar; child steady u_bar (if steady),
    the u_mean(t) transient and its exponential fit."""
    from .uniform import fit_relaxation

    ps, cs = _summary(parent_dir), _summary(child_dir)
    series = xr.open_dataset(Path(child_dir) / "series.nc")
    t = series["t"].values
    u = series["u_mean"].values
    # bin to 1 time unit (u_mean fluctuates on the collision scale)
    edges = np.arange(0.0, t[-1] + 1.0, 1.0)
    idx = np.digitize(t, edges) - 1
    bins = [k for k in range(len(edges)) if np.any(idx == k)]
    tb = np.array([t[idx == k].mean() for k in bins])
    ub = np.array([u[idx == k].mean() for k in bins])
    pu = xr.open_dataset(Path(parent_dir) / "series.nc")["u_mean"].values
    u0_mean = float(np.mean(pu[-int(0.2 * len(pu)):]))     # parent's steady u_mean
    out = {"parent": os.fspath(parent_dir), "child": os.fspath(child_dir),
           "H": ps["params"]["H"], "theta1": ps["params"]["theta"],
           "theta2": cs["params"]["theta"], "h": ps["depth_averages"]["flow_height"],
           "u0": ps["depth_averages"]["u_bar"], "u0_mean_particles": u0_mean,
           "child_state": cs["flow_state"], "child_steady_start": cs["steady_start"],
           "u_steady": cs["depth_averages"].get("u_bar") if cs["flow_state"] == "steady"
           else math.nan, "u_steady_sem": cs["depth_averages"].get("u_bar_sem", math.nan),
           "h2": cs["depth_averages"].get("flow_height", math.nan),
           "t": tb.tolist(), "u_mean": ub.tolist(), "t_final": cs["t_final"]}
    early = (t > 0) & (t <= 5.0)       # initial acceleration: slope over the first 5 units
    out["accel0"] = float(np.polyfit(t[early], u[early], 1)[0]) if early.sum() > 3 else math.nan
    try:
        fit = fit_relaxation(tb, ub, u0_mean)
        out.update(tau_fitted=fit["tau"], tau_fitted_stderr=fit["tau_stderr"],
                   fit_u_inf=fit["u_inf"], fit_rms=fit["rms"])
        why = _unidentified_relaxation(fit, t[-1])
        if why:   # not a result: the comparison has no particle e-folding time
            out.update(tau=math.nan, tau_stderr=math.nan, fit_error=why)
        else:
            out.update(tau=fit["tau"], tau_stderr=fit["tau_stderr"])
    except (ValueError, RuntimeError) as exc:
        out.update(tau=math.nan, tau_stderr=math.nan, fit_error=str(exc))
    # dilation: the slope-normal potential energy sum m g cos(theta) z is the layer's centre of
    # mass times a constant after the switch; its e-folding time against u_bar's says whether
    # the density adjusts on the transient's time scale (a constant-density model cannot)
    out["tau_dilation"] = out["tau_dilation_stderr"] = math.nan
    if "e_grav" in series:
        eg = series["e_grav"].values
        gb = np.array([eg[idx == k].mean() for k in bins])
        try:
            fit = fit_relaxation(tb, gb)
            why = _unidentified_relaxation(fit, t[-1])
            if why:   # no relaxation the data identify (a flat or drifting centre of mass)
                out["dilation_fit"] = why
            else:
                out.update(tau_dilation=fit["tau"], tau_dilation_stderr=fit["tau_stderr"],
                           dilation_rel=float(fit["u_inf"] / gb[0] - 1.0))
        except (ValueError, RuntimeError) as exc:
            out["dilation_fit"] = f"failed: {exc}"
    return out


def compare_switch(lib, parent_dir, child_dir, *, allow_unidentified=True, extrapolate=False,
                   n_ensemble=100) -> dict:
    """Particle run vs uniform-layer ODE for one switch (module docstring)."""
    from .uniform import switch_prediction

    m = switch_measurement(parent_dir, child_dir)
    t_end = max(float(m["t"][-1]), 1.0)
    # Eq. (34) conserves rho_bar h: at theta2 the layer holds the same mass at the density of
    # theta2 (library density closure, Eq. 52 or its reduced form); the ODE keeps that h
    try:
        rho1, rho2 = (float(lib.closures.density(th, extrapolate=True,
                                                 allow_unidentified=allow_unidentified))
                      for th in (m["theta1"], m["theta2"]))
        h_ode = m["h"] * rho1 / rho2
    except ValueError:
        h_ode = m["h"]
    m["h_ode"] = h_ode
    try:
        pred = switch_prediction(lib, h=h_ode, u0=m["u0"], theta=m["theta2"], t_end=t_end,
                                 allow_unidentified=allow_unidentified, extrapolate=extrapolate,
                                 n_ensemble=n_ensemble, fit_t_max=t_end)
        refused = ""
    except ValueError as exc:   # outside the fitted range/hull: say so, then extrapolate
        refused = str(exc)
        pred = switch_prediction(lib, h=h_ode, u0=m["u0"], theta=m["theta2"], t_end=t_end,
                                 allow_unidentified=allow_unidentified, extrapolate=True,
                                 n_ensemble=n_ensemble, fit_t_max=t_end)
    g = pred.sel(stat="value")
    out = dict(m)
    out.update(ode_u_steady=float(g.u_steady), ode_u_steady_std=float(
        pred.u_steady.sel(stat="std")), ode_tau=float(g.tau),
        ode_tau_std=float(pred.tau.sel(stat="std")), ode_tau_linear=float(g.tau_linear),
        ode_t=pred.t.values.tolist(), ode_u=g.u_bar.values.tolist(),
        ode_u_low=pred.u_bar.sel(stat="low").values.tolist(),
        ode_u_high=pred.u_bar.sel(stat="high").values.tolist(),
        closure_status={k[len("closure_status_"):]: v for k, v in pred.attrs.items()
                        if k.startswith("closure_status_")},
        extrapolated=refused, ode_n_ensemble=int(pred.attrs["n_ensemble"]),
        ode_n_ensemble_dropped=int(pred.attrs["n_ensemble_dropped"]))
    tt, uu = pred.t.values, g.u_bar.values
    early = (tt > 0) & (tt <= 5.0)
    out["ode_accel0"] = float(np.polyfit(tt[early], uu[early], 1)[0])
    out["err_u_steady"] = (out["ode_u_steady"] / out["u_steady"] - 1.0
                           if math.isfinite(out["u_steady"]) else math.nan)
    out["err_tau"] = (out["ode_tau"] / out["tau"] - 1.0
                      if math.isfinite(out.get("tau", math.nan)) else math.nan)
    out["pass_u_steady"] = bool(abs(out["err_u_steady"]) <= TOL_STEADY_U)
    out["pass_tau"] = bool(abs(out["err_tau"]) <= TOL_TAU)
    # the same closures as a depth-resolved column (granflow.continuum.column): same h, u0 and
    # ensemble; its steady state is the ODE's, its transient has the profile to adjust
    col = switch_prediction(lib, h=h_ode, u0=m["u0"], theta=m["theta2"], t_end=t_end,
                            allow_unidentified=allow_unidentified, extrapolate=True,
                            n_ensemble=n_ensemble, fit_t_max=t_end, model="column")
    gc = col.sel(stat="value")
    out.update(column_tau=float(gc.tau), column_tau_std=float(col.tau.sel(stat="std")),
               column_tau_linear=float(gc.tau_linear), column_u=gc.u_bar.values.tolist(),
               column_u_steady=float(gc.u_steady),
               column_n_ensemble=int(col.attrs["n_ensemble"]))
    out["err_tau_column"] = (out["column_tau"] / out["tau"] - 1.0
                             if math.isfinite(out.get("tau", math.nan)) else math.nan)
    out["pass_tau_column"] = bool(abs(out["err_tau_column"]) <= TOL_TAU)
    return out


# ----------------------------------------------------------------------------- diffusivity
def diffusivity_measurements(child_dirs) -> list[dict]:
    """D of every switch run that ended steady (tracers over its steady window)."""
    from ..coarse.diffusion import self_diffusivity

    rows = []
    for d in child_dirs:
        d = Path(d)
        s = _summary(d)
        if s["flow_state"] != "steady" or not (d / "tracers.npz").exists():
            continue
        with np.load(d / "tracers.npz") as f:
            t, z = f["time"], f["z"]
        t_from = float(s["profile_time_from"])
        if t[-1] - t_from < 20.0:
            continue
        r = self_diffusivity(t, z, t_from, tau_fit=(2.0, min(10.0, 0.5 * (t[-1] - t_from))))
        da = s["depth_averages"]
        rows.append(dict(run=os.fspath(d), theta=s["params"]["theta"], H=s["params"]["H"],
                         h=da["flow_height"], u_bar=da["u_bar"], D=r["D"],
                         D_stderr=r["D_stderr"], c_D=r["D"] * da["flow_height"] / da["u_bar"],
                         t_from=t_from, t_to=r["t_to"], n_particles=r["n_particles"]))
    return rows


def diffusivity_fit(rows, contact_law="linear"):
    from ..coarse.diffusion import fit_diffusivity

    return fit_diffusivity([r["D"] for r in rows], [r["D_stderr"] for r in rows],
                           [r["u_bar"] for r in rows], [r["h"] for r in rows],
                           theta=[r["theta"] for r in rows], contact_law=contact_law,
                           ids=[r["run"] for r in rows],
                           selection=f"{len(rows)} steady switch runs (tracers over the steady "
                                     "window; not in the campaign's fits)")


def library_with_diffusivity(campaign_dir, fit, out) -> dict:
    """A new version of the campaign's library with the diffusivity closure added (every other
    closure as fitted by the campaign); copied to ``out``."""
    from ..campaign.collect import read_table
    from ..campaign.fits import read_fits
    from ..campaign.library import publish_library
    from ..closures import open_library

    campaign_dir = Path(campaign_dir)
    manifest = json.loads((campaign_dir / "closures.json").read_text())
    lib_path = Path(manifest["path"])
    if not lib_path.is_absolute() and not lib_path.exists():
        lib_path = campaign_dir.parent.parent / lib_path
    old = open_library(lib_path)
    fits = _flatten_fits(read_fits(campaign_dir / "fits.json"))
    table = read_table(campaign_dir / "campaign_table.nc")
    attrs = {k: old.attrs[k] for k in ("campaign", "excluded_runs_json", "library_note")
             if k in old.attrs}
    attrs["library_note"] = (attrs.get("library_note", "") + " diffusivity closure added from "
                             "the continuum-comparison switch runs "
                             "(granflow.continuum.experiments)").strip()
    config = json.loads(old.attrs["config_json"]) if "config_json" in old.attrs else None
    return publish_library(lib_path.parent, manifest["name"], fits + [fit], table, out=out,
                           config=config, reductions=old.attrs.get("reductions_vs_paper"),
                           attrs=attrs)


def _flatten_fits(fits):
    from ..fitting.result import FitResult

    out, stack = [], [fits]
    while stack:
        it = stack.pop()
        if isinstance(it, FitResult):
            out.append(it)
        elif isinstance(it, dict):
            stack.extend(it.values())
        elif isinstance(it, (list, tuple)):
            stack.extend(it)
    return out


# ----------------------------------------------------------------------------- long chute
def build_long_chute(tiles, base_file, Lx_tile: float, Ly: float, params: dict):
    """ParticleSystem of a long periodic chute: the flow particles of the states in ``tiles``
    (final_state.npz of runs over the same base ``base_file``, one per tile, in order along x)
    shifted by k Lx_tile, on the base tiled len(tiles) times.  Flow particles overlapping
    across a tile junction by more than 2 % of d are removed (reported).  Contact history
    starts empty."""
    from ..engine.system import ParticleSystem
    from ..simulate import chute_config

    cfg = chute_config(dict(params, Lx=Lx_tile * len(tiles), Ly=Ly))
    base = np.load(base_file)
    pos, vel, omega, diam = [], [], [], []
    for k, st in enumerate(tiles):
        s, _ = ParticleSystem.load(st)
        flow = ~s.fixed
        p = s.pos[flow].copy()
        p[:, 0] = np.mod(p[:, 0], Lx_tile) + k * Lx_tile
        pos.append(p)
        vel.append(s.vel[flow])
        omega.append(s.omega[flow])
        diam.append(2 * s.radius[flow])
    pos, vel, omega, diam = (np.concatenate(a) for a in (pos, vel, omega, diam))
    L = Lx_tile * len(tiles)
    # remove overlaps across the junctions (brute force near each junction)
    drop = np.zeros(len(pos), bool)
    for k in range(len(tiles)):
        xj = k * Lx_tile
        dxp = np.mod(pos[:, 0] - xj + 0.5 * L, L) - 0.5 * L
        near = np.nonzero(np.abs(dxp) < 1.5)[0]
        left, right = near[dxp[near] < 0], near[dxp[near] >= 0]
        for i in right:
            if drop[i]:
                continue
            d = pos[left] - pos[i]
            d[:, 0] = np.mod(d[:, 0] + 0.5 * L, L) - 0.5 * L
            d[:, 1] = np.mod(d[:, 1] + 0.5 * Ly, Ly) - 0.5 * Ly
            r = np.sqrt((d ** 2).sum(axis=1))
            if np.any((r < 0.5 * (diam[left] + diam[i]) - 0.02) & ~drop[left]):
                drop[i] = True
    keep = ~drop
    pos, vel, omega, diam = pos[keep], vel[keep], omega[keep], diam[keep]
    bpos = np.concatenate([base + [k * Lx_tile, 0.0, 0.0] for k in range(len(tiles))])
    tab = cfg.interactions()
    base_type = len(tab.type_names) - 1
    sys_ = ParticleSystem(L, Ly, tab, gvec=cfg.gravity, skin=cfg.skin, use_wall=False,
                          wall_type=base_type, steps_per_collision=cfg.steps_per_collision)
    allpos = np.concatenate([pos, bpos])
    alld = np.concatenate([diam, np.full(len(bpos), cfg.lam)])
    ptype = np.concatenate([np.zeros(len(pos), np.int64), np.full(len(bpos), base_type)])
    fixed = np.concatenate([np.zeros(len(pos), bool), np.ones(len(bpos), bool)])
    sys_.set_particles(allpos, alld, density=U.RHO_PARTICLE, ptype=ptype, fixed=fixed)
    sys_.vel[: len(pos)] = vel
    sys_.omega[: len(pos)] = omega
    sys_.initialize()
    return sys_, int(drop.sum())


def run_long_chute(tiles, base_file, Lx_tile, Ly, params, out_dir, *, t_end=60.0,
                   dx=1.0, width=1.0, interval=1.0):
    """Run the tiled chute to ``t_end`` with column coarse-graining every ``interval``."""
    from ..coarse.columns import ColumnAccumulator, ColumnObserver
    from ..engine.run import ChuteRun
    from ..provenance import provenance_attrs

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    system, dropped = build_long_chute(tiles, base_file, Lx_tile, Ly, params)
    L = system.Lx
    acc = ColumnAccumulator(L, Ly, int(round(L / dx)), width=width)
    sample = 0.5 * params["t_c"]
    obs = ColumnObserver(acc, every=max(1, int(round(interval / sample))))
    run = ChuteRun(system, t_end=t_end, checkpoint=out_dir / "checkpoint.npz",
                   checkpoint_every_s=120.0, progress=False, observers=[obs])
    run.try_resume()
    run.run()
    attrs = provenance_attrs(config={"tiles": [os.fspath(t) for t in tiles],
                                     "Lx_tile": Lx_tile, "Ly": Ly, "t_end": t_end, **params},
                             theta=params["theta"], Lx=L, Ly=Ly)
    attrs.update(tiles=json.dumps([os.fspath(t) for t in tiles]), junction_overlaps_removed=dropped,
                 n_flow=int((~system.fixed).sum()))
    ds = run.observers[-1].acc.to_dataset(attrs)
    atomic_to_netcdf(ds, out_dir / "columns.nc")
    if (out_dir / "checkpoint.npz").exists():
        (out_dir / "checkpoint.npz").unlink()
    return ds


def _smooth_periodic(h, n=5):
    k = np.ones(n) / n
    pad = np.concatenate([h[-n:], h, h[:n]])
    return np.convolve(pad, k, mode="same")[n:-n]


def bump_amplitude(h) -> float:
    """Height of a bump above its layer: the smoothed maximum of h (as
    :func:`feature_positions` finds the peak) minus the median of h."""
    h = np.asarray(h, float)
    return float(np.max(_smooth_periodic(h)) - np.median(h))


def feature_positions(x, h, x_prev=None, L=None):
    """Peak position (max of the smoothed h) and front position (downstream crossing of the
    level halfway between the smoothed minimum and maximum), unwrapped against ``x_prev``."""
    hs = _smooth_periodic(np.asarray(h, float))
    L = L if L is not None else float(x[-1] - x[0] + (x[1] - x[0]))
    k = int(np.argmax(hs))
    level = 0.5 * (hs.max() + np.percentile(hs, 20))
    n = len(hs)
    j = k
    for step in range(n):
        a, b = (k + step) % n, (k + step + 1) % n
        if hs[a] >= level > hs[b]:
            frac = (hs[a] - level) / (hs[a] - hs[b])
            j = x[a] + frac * (x[1] - x[0]) + (L if b < a else 0.0) + (L if a < k else 0.0)
            break
    peak, front = float(x[k]), float(j)
    if x_prev is not None:
        peak += L * round((x_prev[0] - peak) / L)
        front += L * round((x_prev[1] - front) / L)
    return peak, front


def compare_long_chute(lib, columns_nc, rho_bar: float, theta: float, *,
                       allow_unidentified=True, extrapolate=True, out_nc=None,
                       viscosity=None, model="shallow", n_ensemble: int = 0) -> dict:
    """Shallow-layer solver from the particle run's initial h(x), u_bar(x); positions of peak
    and front over time, particle vs solver.  ``lib``: a closure library, or a
    :class:`FlowClosures` to use as it is (e.g. :meth:`FlowClosures.paper`, the paper's own
    closures).  ``viscosity``: None (Eq. 34 as the paper
    writes it), ``"gray_edwards"`` (with the depth-averaged viscous stress, nu from the
    closures' steady flow rule at the layer's mean depth,
    :meth:`FlowClosures.gray_edwards_viscosity`) or a number nu.  ``model``: ``"shallow"``
    (Eq. 34, :func:`shallow_layer`) or its local-equilibrium limits ``"kinematic_wave"`` /
    ``"diffusive_wave"`` (:func:`granflow.continuum.local_equilibrium_layer`, from h(x)
    alone: u follows h).  ``n_ensemble`` > 0 (local-equilibrium models only): the same
    prediction for that many members of the friction closure's parameter ensemble; each row
    gets the members' 16-84 % range of the distances travelled (``*_travel_solver_lo/hi``) and
    ``worst_err_after_quarter_band`` the worst error of the band's nearer edge (0 where the
    particles lie inside it)."""
    from ..coarse.columns import column_fields
    from .closures import FlowClosures
    from .kinematic import local_equilibrium_layer
    from .shallow import shallow_layer

    if model not in LONG_CHUTE_MODELS:
        raise ValueError(f"model = {model!r} is not one of {LONG_CHUTE_MODELS}")
    if model != "shallow" and viscosity is not None:
        raise ValueError(f"viscosity is a term of the shallow-layer model, not of {model!r}")
    if not (isinstance(n_ensemble, (int, np.integer)) and n_ensemble >= 0):
        raise ValueError(f"n_ensemble = {n_ensemble!r} is out of range: allowed integers >= 0")
    if n_ensemble and model == "shallow":
        raise ValueError("n_ensemble is implemented for the local-equilibrium models only "
                         "(the shallow-layer solver takes minutes per member)")

    part = column_fields(xr.open_dataset(columns_nc), rho_bar)
    x = part.x.values
    times = part.t.values - part.t.values[0]
    c = lib if isinstance(lib, FlowClosures) else FlowClosures.from_library(
        lib, theta, allow_unidentified=allow_unidentified)
    h0 = part.h.values[0]
    u0 = np.nan_to_num(part.u_bar.values[0])
    rng = c.fitted_ranges()
    h_mean = float(np.mean(h0))
    if viscosity is None:
        nu = 0.0
    elif viscosity == "gray_edwards":
        nu = c.gray_edwards_viscosity(h_mean)
    else:
        nu = float(viscosity)
    if model == "shallow":
        sol = shallow_layer(c, x, h0, u0, float(times[-1]), times=times, check=True,
                            extrapolate=extrapolate, viscosity=nu)
    else:
        sol = local_equilibrium_layer(c, x, h0, float(times[-1]), times=times, check=True,
                                      extrapolate=extrapolate,
                                      diffusive=model == "diffusive_wave")
    if out_nc is not None:
        atomic_to_netcdf(sol, out_nc)
    L = float(part.attrs.get("cg_Lx", x[-1] + x[0]))
    rows = []
    prev_p = prev_s = None
    for k, t in enumerate(times):
        fp = feature_positions(x, part.h.values[k], prev_p, L)
        fs = feature_positions(x, sol.h.values[k], prev_s, L)
        prev_p, prev_s = fp, fs
        rows.append(dict(t=float(t), peak_particles=fp[0], front_particles=fp[1],
                         peak_solver=fs[0], front_solver=fs[1],
                         amplitude_particles=bump_amplitude(part.h.values[k]),
                         amplitude_solver=bump_amplitude(sol.h.values[k])))
    r0 = rows[0]
    for r in rows:
        for f in ("peak", "front"):
            dp = r[f"{f}_particles"] - r0[f"{f}_particles"]
            ds_ = r[f"{f}_solver"] - r0[f"{f}_solver"]
            r[f"{f}_travel_particles"] = dp
            r[f"{f}_travel_solver"] = ds_
            r[f"{f}_err"] = ds_ / dp - 1.0 if abs(dp) > 1e-9 else math.nan
    snap = np.unique(np.linspace(0, len(times) - 1, 5).round().astype(int))
    profiles = {"x": x.tolist(), "t": [float(times[k]) for k in snap],
                "h_particles": [part.h.values[k].tolist() for k in snap],
                "h_solver": [sol.h.values[k].tolist() for k in snap]}
    late = [r for r in rows if r["t"] >= 0.25 * times[-1]]
    worst = {f: max(abs(r[f"{f}_err"]) for r in late) for f in ("peak", "front")}
    band = None
    if n_ensemble and model != "shallow":
        members = c.ensemble(int(n_ensemble))
        travel = {f: [] for f in ("peak", "front")}
        for cm in members:
            try:
                sm = local_equilibrium_layer(cm, x, h0, float(times[-1]), times=times,
                                             check=False, diffusive=model == "diffusive_wave")
            except RuntimeError:  # a member that arrests or accelerates the layer: dropped
                continue
            prev = None
            tr = {f: [] for f in travel}
            for k in range(len(times)):
                prev = feature_positions(x, sm.h.values[k], prev, L)
                tr["peak"].append(prev[0])
                tr["front"].append(prev[1])
            for f in travel:
                travel[f].append(np.asarray(tr[f]) - tr[f][0])
        n_used = len(travel["peak"])
        band = {"n_members": n_used, "n_members_dropped": len(members) - n_used
                + int(getattr(members, "ensemble_dropped", 0))}
        if n_used >= 10:
            for f in travel:
                lo, hi = np.percentile(np.array(travel[f]), [16, 84], axis=0)
                for r, a, b in zip(rows, lo, hi):
                    r[f"{f}_travel_solver_lo"] = float(a)
                    r[f"{f}_travel_solver_hi"] = float(b)
            band["worst_err_after_quarter_band"] = {
                f: max(_band_err(r, f) for r in late) for f in ("peak", "front")}
    return {"rows": rows, "profiles": profiles, "worst_err_after_quarter": worst,
            "rho_bar": rho_bar, "closure_K": c.K, "shallow_layer_attrs": {
                k: v for k, v in sol.attrs.items() if k.startswith(("closure_", "scheme", "n_"))},
            "theta": theta, "closure_status": {k[len("closure_status_"):]: v
                                               for k, v in sol.attrs.items()
                                               if k.startswith("closure_status_")},
            "fraction_outside_fitted_range_max": float(np.nanmax(
                sol.fraction_outside_fitted_range.values)) if rng else math.nan,
            "viscosity": nu, "viscosity_model": viscosity or "none", "h_mean": h_mean,
            "model": model, "ensemble_band": band,
            "pass": bool(max(worst.values()) <= TOL_POSITION)}


def _band_err(row, f) -> float:
    """|error| of the nearer edge of the ensemble's 16-84 % band of distances travelled against
    the particles' distance (0 inside the band)."""
    dp = row[f"{f}_travel_particles"]
    lo, hi = row[f"{f}_travel_solver_lo"], row[f"{f}_travel_solver_hi"]
    if abs(dp) <= 1e-9:
        return math.nan
    if lo <= dp <= hi:
        return 0.0
    return min(abs(lo / dp - 1.0), abs(hi / dp - 1.0))


# ----------------------------------------------------------------------------- segregation
def segregation_measurement(run_dir, smooth_bins: int = 3) -> dict:
    """s(t), its start after the insertion fall (t0 = the run's startup time), plateau and
    half-time of one bidisperse run."""
    from .segregation import half_time

    s = _summary(run_dir)
    ser = xr.open_dataset(Path(run_dir) / "series.nc")
    t = ser["segregation_time"].values
    v = ser["segregation_indicator"].values
    t0 = float(ser.attrs.get("steady_min_onset", 0.0))
    k = np.ones(smooth_bins) / smooth_bins
    vs = np.convolve(np.pad(v, (smooth_bins // 2,), mode="edge"), k, mode="valid")
    after = t >= t0
    s0 = float(vs[after][0])
    plateau = float(s["segregation"]["plateau"])
    th = half_time(t[after], vs[after], s0, plateau)
    return {"run": os.fspath(run_dir), "sigma": s["params"]["sigma"], "phi0": s["params"]["phi0"],
            "h": s["depth_averages"]["flow_height"], "u_bar": s["depth_averages"]["u_bar"],
            "t0": t0, "s0": s0, "plateau": plateau, "t_half": th - t0,
            "segregation_steady": bool(s["segregation"]["steady"]),
            "t": (t[after] - t0).tolist(), "s": (vs[after] - s0).tolist()}


def run_segregation_tracers(run_dir, out_dir, *, t_end: float = 250.0,
                            tracer_interval: float = 0.5, threads: int = 1) -> dict:
    """Simulate the bidisperse run in ``run_dir`` again from its start (its parameters and seed:
    the same trajectory as far as it goes) to ``t_end`` without early stop, recording tracer
    heights every ``tracer_interval`` into ``out_dir/tracers.npz``."""
    params = dict(_summary(run_dir)["params"])
    params.update(t_end=float(t_end), early_stop=False)
    return _simulate_with_tracers(params, out_dir, tracer_interval, threads)


def transient_diffusivity(tracer_dir, t_from: float, t_to: float, *,
                          tau_fit=(2.0, 10.0)) -> dict:
    """Self-diffusivity in z over [t_from, t_to] of a run with ``tracers.npz``: all flow
    particles (``D``, ``D_stderr``) and per species (``D_small``, ``D_large`` and stderrs; the
    small ones are those of the smallest diameter)."""
    from ..coarse.diffusion import self_diffusivity

    with np.load(Path(tracer_dir) / "tracers.npz") as f:
        t, z, d = f["time"], f["z"], f["diameter"]
    w = (t >= t_from - 1e-9) & (t <= t_to + 1e-9)
    if t[w].size < 3 or t[w][-1] - t[w][0] < tau_fit[1]:
        raise ValueError(f"tracers of {tracer_dir} cover too little of [{t_from:g}, {t_to:g}]")
    small = d <= d.min() + 1e-9
    out = {"t_from": float(t_from), "t_to": float(t[w][-1]), "n_particles": int(d.size),
           "n_small": int(small.sum())}
    for name, m in (("", np.ones(d.shape, bool)), ("_small", small), ("_large", ~small)):
        if m.sum() < 10:
            out[f"D{name}"], out[f"D{name}_stderr"] = math.nan, math.nan
            continue
        r = self_diffusivity(t[w], z[w][:, m], float(t_from), tau_fit=tau_fit)
        out[f"D{name}"], out[f"D{name}_stderr"] = r["D"], r["D_stderr"]
    return out


def level_time(t, s, level: float) -> float:
    """First time s(t) reaches ``level`` from its start s[0] (linear interpolation; t[0] if it
    starts there, NaN if never)."""
    s = np.asarray(s, float)
    if abs(level - s[0]) <= 1e-12 * max(1.0, abs(level)):
        return float(np.asarray(t, float)[0])
    from .segregation import half_time

    return half_time(t, s, float(s[0]), 2.0 * level - float(s[0]))


def aligned_half_time(t, s, s_final: float, s_start: float) -> tuple[float, float]:
    """Half-time of a model curve s(t) counted from where it reaches ``s_start`` (a particle
    run's segregation when its shear flow has started) to half the way from there to
    ``s_final``; returns (half-time, the model time at s_start).  NaN for both when s_start
    lies beyond s_final (or on the other side of zero): the model never passes through it."""
    if not abs(s_final) > abs(s_start) or s_final * s_start < 0:
        return math.nan, math.nan
    t_shift = level_time(t, s, s_start)
    return level_time(t, s, s_start + 0.5 * (s_final - s_start)) - t_shift, t_shift


def segregation_Ps_at(lib, sigma, *, contact_law=None, allow_unidentified=False):
    """Ps of the library's per-size-ratio ``segregation`` closure at ``sigma`` and its status.

    The library has no evaluator for this per-run kind (``Ps(lib, sigma)`` evaluates the fitted
    law ``Ps_law``), so the status rules of :mod:`granflow.closures.evaluate` are applied here:
    a ``failed`` cell always raises, one that is not ``ok``/``reduced`` raises unless
    ``allow_unidentified`` (the status is returned and recorded by the caller)."""
    from ..closures.evaluate import _resolve_contact_law

    sigmas = np.asarray(lib["sigma"].values, dtype=float)
    hit = np.flatnonzero(np.abs(sigmas - float(sigma)) <= 1e-9)
    if hit.size == 0:
        raise ValueError(f"sigma = {sigma:g} has no segregation closure (library sigma "
                         f"{sigmas.tolist()})")
    sel = {"contact_law": _resolve_contact_law(lib, contact_law)}
    cell = {k: v for k, v in sel.items() if k in lib["segregation_Ps"].dims}
    Ps = float(lib["segregation_Ps"].sel(cell).isel(sigma=int(hit[0])).item())
    status = str(lib["segregation_status"].sel(cell).isel(sigma=int(hit[0])).item())
    if status == "failed" or (status not in ("ok", "reduced") and not allow_unidentified):
        raise ValueError(f"segregation closure at sigma = {sigma:g} is {status}"
                         + ("" if status == "failed"
                            else " (pass allow_unidentified=True to use it anyway)"))
    return Ps, status


def compare_segregation(lib, run_dir, seg_fits, *, allow_unidentified=True,
                        n_ensemble: int = 50, tracer_dir=None,
                        d_length: str = SEGREGATION_D_LENGTH) -> dict:
    """One bidisperse run vs T-eq. (27) with both fluxes: Ps (symmetric, library) and
    (Ps, kappa) (asymmetric, the run's fit in ``segregation_fits.json``), D from the library's
    diffusivity at the run's u_bar, h and the length scale ``d_length`` (:data:`SEGREGATION_D_LENGTH`).

    ``tracer_dir``: the run simulated again with tracers (:func:`run_segregation_tracers`):
    then D measured over the run's transient (t0 to t0 + 2 half-times,
    :func:`transient_diffusivity`) is recorded beside the closure's (``D_transient``,
    ``D_closure_over_transient``) and the model is run with it too (``<flux>_D_transient``):
    it separates the diffusivity closure's error from the rest of the model's; and T-eq. (27)'s
    rates are measured on the transient itself (``transient_rates``: :func:`transient_rates`).

    Non-ok closures: with ``allow_unidentified=True`` (the default here, as the comparison is
    meant to show how such closures predict) an ``unidentified`` Ps or diffusivity is used and
    its status is recorded (``Ps_status``); ``failed`` closures always raise."""
    m = segregation_measurement(run_dir)
    sigma, phi0 = m["sigma"], m["phi0"]
    if d_length not in ("small", "volume_mean"):
        raise ValueError(f"d_length = {d_length!r} is unknown: allowed 'small', 'volume_mean'")
    d_mean = 1.0 if d_length == "small" else phi0 * 1.0 + (1.0 - phi0) / sigma
    Dds = lib.closures.diffusivity(m["u_bar"], m["h"], d_mean=d_mean, uncertainty=True,
                                   allow_unidentified=allow_unidentified)
    D, D_std = float(Dds["value"]), float(Dds["std"])
    Ps, Ps_status = segregation_Ps_at(lib, sigma, allow_unidentified=allow_unidentified)
    fit = next(f for f in seg_fits if abs(f["fit"]["coords"].get("sigma", -1) - sigma) < 1e-9)
    out = segregation_against_model(m, fit, Ps=Ps, Ps_status=Ps_status, D=D, D_std=D_std,
                                    d_mean=d_mean, d_length=d_length, tracer_dir=tracer_dir)
    if tracer_dir is not None:
        out["transient_rates"] = transient_rates(m, tracer_dir, Ps=Ps, D=out["D_transient"])
    return out


def segregation_against_model(m: dict, fit: dict, *, Ps: float, Ps_status: str, D: float,
                              D_std: float, d_mean: float = 1.0, d_length: str = "small",
                              tracer_dir=None, transient=None) -> dict:
    """The core of :func:`compare_segregation` with Ps and D given: ``m`` the run's
    :func:`segregation_measurement`, ``fit`` its entry of ``segregation_fits.json`` (or of its
    ``row.json``: ``{"fit": row["segregation_fit"], "profile": row["segregation_profile"]}``;
    the asymmetric flux's (Ps, kappa) and the steady profile come from it).  Used where Ps and D
    come from a closure that is not a per-size-ratio cell of a library (a law, a measured D).
    ``transient``: :func:`transient_of` of the run, when the caller has it already."""
    from .segregation import segregation_layer

    phi0 = m["phi0"]
    ex = fit["fit"]["extra"]
    prof = fit["profile"]
    t_end = max(m["t"][-1], 1.0)
    out = dict(m)
    out.update(d_mean=d_mean, d_length=d_length, D=D, D_std=D_std, Ps=Ps, Ps_status=Ps_status,
               Ps_asym=ex.get("asymmetric_Ps"), kappa=ex.get("asymmetric_kappa"))
    variants = [("", D, D_std)]
    if tracer_dir is not None:
        tr = transient if transient is not None else transient_of(m, tracer_dir)
        out["transient"] = tr
        out["D_transient"], out["D_transient_stderr"] = tr["D"], tr["D_stderr"]
        out["D_closure_over_transient"] = D / tr["D"]
        variants.append(("_D_transient", tr["D"], tr["D_stderr"]))
    zeta = np.asarray(prof["zeta"], float)
    phi_p = np.asarray(prof["phi"], float)
    s0 = float(m["s0"])  # the particle run's s when its flow has started (t0)
    for (flux, kw), (suffix, D, D_std) in itertools.product(
            (("symmetric", dict(Ps=Ps, flux="symmetric")),
             ("asymmetric", dict(Ps=ex.get("asymmetric_Ps", Ps), flux="asymmetric",
                                 kappa=min(max(float(ex.get("asymmetric_kappa", 0.0)), 0.0),
                                           0.99)))), variants):
        name = flux + suffix
        # the model starts mixed under steady shear; the particle run has segregated part-way
        # during its insertion fall before its shear is established (t0, s0).  Both clocks start
        # where s = s0: the model's at t_shift, where it reaches the particle run's s0; each
        # half-time runs from there to half the way to its own final segregation.
        # the model runs over twice the particle run, longer (up to 32x) where it is too slow
        # to pass its half-way point within that: a slow model's half-time is measured, not NaN
        t_model = 2.0 * t_end
        for _ in range(5):
            res = segregation_layer(D=D, h=m["h"], phi0=phi0, t_end=t_model, n=200, n_out=401,
                                    **kw)
            t_mod, s_mod = res.t.values, res.indicator.values
            s_inf = float(res.indicator_steady)
            th, t_shift = aligned_half_time(t_mod, s_mod, s_inf, s0)
            if math.isfinite(th) or not abs(s_inf) > abs(s0) or s_inf * s0 < 0:
                break
            t_model *= 2.0
        start = t_shift if math.isfinite(t_shift) else 0.0  # unaligned: from the mixed start
        keep = t_mod >= start
        # the final profile at the particle run's end on the shifted clock
        k_end = int(np.argmin(np.abs(t_mod - (start + t_end))))
        phi_model = np.interp(zeta, res.zeta.values, res.phi.values[k_end])
        # D's uncertainty: t_half scales as 1/D exactly (time scale h^2/D)
        out[name] = {"t_half": th, "t_half_std": th * D_std / D,
                     "t_half_from_mixed": float(res.t_half), "t_shift": t_shift,
                     "s_final": float(s_mod[-1]), "s_steady": s_inf,
                     "t": (t_mod[keep] - t_mod[keep][0]).tolist(),
                     "s": (s_mod[keep] - (s0 if math.isfinite(t_shift) else 0.0)).tolist(),
                     "err_t_half": th / m["t_half"] - 1.0 if m["t_half"] > 0 else math.nan,
                     "phi_rms_vs_particles": float(np.sqrt(np.mean((phi_model - phi_p) ** 2))),
                     "phi_model": phi_model.tolist()}
        out[name]["pass_t_half"] = bool(abs(out[name]["err_t_half"]) <= TOL_HALF_TIME)
    if tracer_dir is not None and math.isfinite(out["symmetric_D_transient"]["t_half"]):
        out["Ps_matching_half_time"] = matching_peclet(
            m["t_half"], s0, D=out["D_transient"], h=m["h"], phi0=phi0, Ps_from=Ps,
            t_end=2.0 * t_end)
    out["zeta"] = zeta.tolist()
    out["phi_particles"] = phi_p.tolist()
    return out


def transient_of(m: dict, tracer_dir) -> dict:
    """:func:`transient_diffusivity` over a run's segregation transient: from its start of shear
    t0 to two particle half-times after it (100 time units where it has none)."""
    th_p = m["t_half"] if math.isfinite(m["t_half"]) and m["t_half"] > 0 else 100.0
    return transient_diffusivity(tracer_dir, m["t0"], m["t0"] + 2.0 * th_p)


def steady_diffusivity(run_dir, *, tau_fit=(2.0, 10.0)) -> dict:
    """Self-diffusivity in z over a run's steady window (``profile_time_from`` of its summary to
    its end) from its ``tracers.npz``: all flow particles and per species, as
    :func:`transient_diffusivity`, with c_D = D h / u_bar (the closure's D = c_D (u_bar/h) d^2 at
    the small diameter d = 1)."""
    s = _summary(run_dir)
    with np.load(Path(run_dir) / "tracers.npz") as f:
        t_last = float(f["time"][-1])
    out = transient_diffusivity(run_dir, float(s["profile_time_from"]), t_last, tau_fit=tau_fit)
    da = s["depth_averages"]
    out.update(h=da["flow_height"], u_bar=da["u_bar"],
               c_D=out["D"] * da["flow_height"] / da["u_bar"],
               c_D_stderr=out["D_stderr"] * da["flow_height"] / da["u_bar"])
    return out


#: a cut-short run's s(t) must be explained this well by its relaxation fit (R^2)
RELAXATION_MIN_R2 = 0.9


def relaxation_plateau(m: dict) -> dict:
    """The plateau of a run stopped before its segregated state was shown steady: the
    exponential relaxation s = s_inf + a exp(-t / tau) fitted to its s(t) after the start of
    shear (:func:`granflow.steady.segregation.relaxation_projection`, the steady detector's own
    projection), and the measurement ``m`` redone with s_inf as the plateau (``t_half`` the
    crossing of half the way to it; ``tau_ln2`` the fit's)."""
    from ..steady.segregation import relaxation_projection
    from .segregation import half_time

    t, ds = np.asarray(m["t"], float), np.asarray(m["s"], float)
    rx = relaxation_projection(t, ds)
    r2 = math.nan
    if rx.identified:  # how much of s(t) the relaxation explains (noise fits a short tau too)
        e = np.exp(-(t - t[0]) / rx.tau)
        a = float(np.sum((ds - rx.s_inf) * e) / np.sum(e * e))
        r2 = 1.0 - float(np.sum((ds - rx.s_inf - a * e) ** 2) / np.sum((ds - ds.mean()) ** 2))
    if not (rx.identified and r2 >= RELAXATION_MIN_R2):
        raise ValueError(f"{m['run']}: the relaxation of s(t) is not identified ({rx.how}; "
                         f"explains {r2:.2f} of its variance, needs {RELAXATION_MIN_R2}); "
                         "run it until its segregated state is shown steady")
    plateau = float(m["s0"]) + rx.s_inf
    out = dict(m, plateau=plateau, t_half=half_time(t, ds, 0.0, rx.s_inf),
               plateau_source=f"relaxation fit ({rx.how}; run ended at t = "
                              f"{m['t0'] + t[-1]:.5g} before its segregated state was shown steady)",
               relaxation_tau=rx.tau, tau_ln2=rx.tau * math.log(2.0), relaxation_r2=r2,
               fraction_reached=float(ds[-1] / rx.s_inf))
    return out


def compare_segregation_reference(run_dir, *, Ps_laws=None, Ps=None) -> dict:
    """A bidisperse run of a campaign folder (``summary.json``, ``series.nc``, ``row.json``)
    simulated with tracer heights (``tracers.npz``, ``python -m granflow.continuum.experiments
    segregation-run``) against T-eq. (27), both fluxes.

    For the segregation reference (``config/reference-segregation.yaml``), whose depth (24 d,
    interface ~3 d wide) is what the shallow default's profile cannot resolve: Ps is the run's
    steady-profile fit (the value its library's per-size-ratio cell holds), D the
    self-diffusivity of its steady window (:func:`steady_diffusivity`: a closure measured in
    steady flow, not on the transient it predicts; ``Ps_status`` / the D variant
    ``_D_transient`` as in :func:`compare_segregation`).  ``Ps_laws``: {name: Ps} further Ps
    values (e.g. a fitted T-eq. (29) law, the paper's) with which the symmetric model is also
    run (``law:<name>`` entries: half-time and its error against the run).

    A run stopped before its segregated state was shown steady (a ``t_end`` cut) gets its
    plateau from the relaxation fit (:func:`relaxation_plateau`; ``plateau_source`` says so)
    and D from its transient (``D_source``); its profile is not steady, so give ``Ps`` (e.g. the
    same configuration's steady value, recorded in :mod:`granflow.reference`)."""
    run_dir = Path(run_dir)
    row = json.loads((run_dir / "row.json").read_text())
    if row.get("segregation_fit") is None:
        raise ValueError(f"{run_dir}/row.json holds no segregation fit")
    fit = {"fit": row["segregation_fit"], "profile": row["segregation_profile"]}
    m = segregation_measurement(run_dir)
    if m["segregation_steady"]:
        st = steady_diffusivity(run_dir)
        D, D_std, D_source = st["D"], st["D_stderr"], "steady window"
    else:
        # stopped early (e.g. a run cut short by its t_end): plateau by the relaxation fit; no
        # steady window, so D is the transient's; Ps should be given (the profile is not steady)
        m = relaxation_plateau(m)
        st = None
        tr = transient_of(m, run_dir)
        D, D_std, D_source = tr["D"], tr["D_stderr"], "transient (no steady window)"
    Ps_status = str(fit["fit"].get("status")) if Ps is None else "given"
    Ps_stderr = float(fit["fit"]["stderr"]["Ps"]) if Ps is None else math.nan
    Ps = float(fit["fit"]["params"]["Ps"]) if Ps is None else float(Ps)
    out = segregation_against_model(m, fit, Ps=Ps, Ps_status=Ps_status, D=D, D_std=D_std,
                                    tracer_dir=run_dir, transient=None if st else tr)
    out["steady"] = st
    out["D_source"] = D_source
    out["D_steady_over_transient"] = st["D"] / out["D_transient"] if st else math.nan
    out["Ps_stderr"] = Ps_stderr
    out["Ps_profile_fit"] = float(fit["fit"]["params"]["Ps"])
    for name, ps in (Ps_laws or {}).items():
        res = segregation_against_model(m, fit, Ps=float(ps), Ps_status="law", D=D, D_std=D_std)
        out[f"law:{name}"] = {"Ps": float(ps), **res["symmetric"]}
    # S and D_r measured on the transient itself: does T-eq. (27) with constant rates describe
    # it, and with which Ps, against the steady profile's?
    rates = transient_rates(m, run_dir, Ps=Ps, D=out["D_transient"])
    f = rates["fit"]
    res = segregation_against_model(m, fit, Ps=f["Ps"], Ps_status="transient fit", D=f["D_r"],
                                    D_std=f["D_r_stderr"])
    rates["model"] = {k: res["symmetric"][k] for k in ("t_half", "err_t_half", "s_steady",
                                                        "phi_rms_vs_particles")}
    rates["measured_profiles"] = measured_profile_prediction(m, rates)
    if (run_dir / "profiles.nc").exists():
        rates["pressure_scaling"] = segregation_pressure_scaling(
            rates, run_dir / "profiles.nc", float(_summary(run_dir)["depth_averages"]["base"]))
    rates["windows"] = transient_windows(m, run_dir)
    if st is not None and (run_dir / "profiles.nc").exists():
        out["pressure_scaled"] = pressure_scaled_segregation(m, run_dir, D=D)
    out["transient_rates"] = rates
    return out


def _transient_profiles(m: dict, tracer_dir, *, every: float, average: float, width: float,
                        t_to=None) -> dict:
    """The tracers of a bidisperse run (heights above its base) and phi(z, t) on levels 0.25 d
    apart every ``every`` time units from its start of shear t0 to ``t_to`` (default two
    particle half-times after t0; the end of the tracers at most), each the coarse-grained
    small-particle share (Gaussian ``width``) averaged over +-``average``."""
    from ..coarse.segregation_flux import concentration_fields

    s = _summary(m["run"])
    da, pr = s["depth_averages"], s["params"]
    base, surface = float(da["base"]), float(da["surface"])
    h = surface - base
    area = float(pr["Lx"]) * float(pr["Ly"])
    with np.load(Path(tracer_dir) / "tracers.npz") as f:
        t, z, d = f["time"], f["z"] - base, f["diameter"]
    th = m["t_half"] if math.isfinite(m["t_half"]) and m["t_half"] > 0 else 100.0
    t0 = m["t0"]
    t1 = min(float(t[-1]) - average, t0 + 2.0 * th if t_to is None else float(t_to))
    times = np.arange(t0, t1 + 1e-9, every)
    levels = np.arange(0.25, h - 0.2, 0.25)
    prof = []
    for tt in times:
        w = np.abs(t - tt) <= average + 1e-9
        _, cs, ca = concentration_fields(z[w], d, levels, area=area, width=width)
        prof.append(cs.mean(axis=0) / ca.mean(axis=0))
    return {"t": t, "z": z, "diameter": d, "h": h, "area": area, "base": base,
            "times": times, "levels": levels, "phi": np.asarray(prof), "t_half": th,
            "t0": t0, "t1": t1}


def transient_rates(m: dict, tracer_dir, *, Ps: float, D: float, every: float = 2.0,
                    average: float = 1.0, width: float = 0.5, margin: float = 1.0,
                    t_to=None) -> dict:
    """T-eq. (27)'s S and D_r measured on a run's own segregation transient (its tracers), not
    from its steady profile and self-diffusivity (``Ps``, ``D``: those, for the comparison).

    phi(z, t) every ``every`` time units from the start of shear t0 to ``t_to`` (default two
    particle half-times after t0; the end of the tracers at most), each the coarse-grained
    small-particle share (:func:`granflow.coarse.segregation_flux.concentration_fields`, Gaussian
    ``width``) averaged over +-``average``.  Then

    * ``fit``: the model fitted to it over the levels more than ``margin`` from base and surface
      (:func:`granflow.continuum.segregation.fit_segregation_transient`), and ``fit_first`` /
      ``fit_second`` the same over the two halves of the window split at the particle
      half-time: constant rates should give the same S and D_r in both;
    * ``flux_regression``: the flux J = -dC/dt regressed on T-eq. (27)'s form sample by sample
      (:func:`granflow.coarse.segregation_flux.segregation_flux_from_tracers`; its D_r is
      attenuated by the noise of dphi/dz);
    * ``levels``: the mean flux J / c at levels 2 d apart over the window's four quarters
      (:func:`granflow.coarse.segregation_flux.level_fluxes`) beside what T-eq. (27) gives with
      the window-mean phi and dphi/dz there, with the steady (Ps, D) and with the fitted rates;
    * ``D_profile``: the self-diffusivity of displacements starting in 2-d bands over the window
      (:func:`granflow.coarse.diffusion.self_diffusivity_profile`);
    * ``steady_model_from_measured_start``: T-eq. (27) with the steady (Ps, D) started from the
      particles' own profile at t0 (not from a mixed start aligned on s0): its half-time from
      there to half its own steady indicator."""
    from ..coarse.diffusion import self_diffusivity_profile
    from ..coarse.segregation_flux import level_fluxes, segregation_flux_from_tracers
    from .segregation import fit_segregation_transient

    tp = _transient_profiles(m, tracer_dir, every=every, average=average, width=width,
                             t_to=t_to)
    t, z, d, h, area = tp["t"], tp["z"], tp["diameter"], tp["h"], tp["area"]
    times, levels, prof, th, t0, t1 = (tp[k] for k in ("times", "levels", "phi", "t_half",
                                                       "t0", "t1"))
    kw = dict(h=h, phi0=m["phi0"], z_range=(margin, h - margin))
    fit = fit_segregation_transient(times, levels, prof, **kw)
    half = times <= t0 + th + 1e-9
    fits = {"fit_first": fit_segregation_transient(times[half], levels, prof[half], **kw),
            "fit_second": fit_segregation_transient(times[~half], levels, prof[~half], **kw)
            if (~half).sum() >= 3 else None}
    reg = segregation_flux_from_tracers(t, z, d, area=area, z_from=margin, z_to=h - margin,
                                        t_from=t0, t_to=t1, width=width)
    quarters = [(t0 + i * (t1 - t0) / 4, t0 + (i + 1) * (t1 - t0) / 4) for i in range(4)]
    rows = level_fluxes(t, z, d, area=area, levels=np.arange(4.0, h - 3.0, 2.0),
                        windows=quarters, width=width)
    S_model = Ps * D / h
    for r in rows:
        q, g = r["phi"] * (1.0 - r["phi"]), r["dphi_dz"]
        r["J_over_c_steady_model"] = -(S_model * q + D * g)
        r["J_over_c_fitted_model"] = -(fit["S"] * q + fit["D_r"] * g)
    # the steady (Ps, D) model started from the particles' own profile at t0 instead of from
    # a mixed start aligned on s0: does the comparison protocol make the gap?
    from .segregation import segregation_layer

    n = 200
    start = np.interp((np.arange(n) + 0.5) / n * h, levels, prof[0])
    start = np.clip(start * (m["phi0"] / start.mean()), 1e-9, 1.0 - 1e-9)
    t_model = 4.0 * max(float(m["t"][-1]), 1.0)
    res = segregation_layer(Ps=Ps, D=D, h=h, phi0=m["phi0"], t_end=t_model, n=n, n_out=801,
                            phi_initial=start)
    th_start = float(res.t_half)
    from_start = {"t_half": th_start, "err_t_half": th_start / m["t_half"] - 1.0
                  if m["t_half"] > 0 else math.nan, "s_start": float(res.indicator[0]),
                  "s_steady": float(res.indicator_steady)}
    edges = np.arange(0.0, h + 1e-9, 2.0)
    return {"fit": fit, **fits, "flux_regression": reg, "levels": rows,
            "steady_model_from_measured_start": from_start,
            "D_profile": self_diffusivity_profile(t, z, t0, edges), "h": h, "every": every,
            "average": average, "width": width, "margin": margin, "Ps_steady": Ps,
            "D_self": D, "S_steady_model": S_model,
            "Ps_transient_over_steady": fit["Ps"] / Ps, "D_r_over_D_self": fit["D_r"] / D,
            "S_over_model_S": fit["S"] / S_model}


def profile_peclet(z, phi, *, h: float, phi0: float, z_range=None) -> dict:
    """The Ps of T-eq. (28) whose steady profile is nearest (least squares over ``z_range``) to
    one measured profile phi(z) (heights above the base): how sharp a profile is in the steady
    model's terms, for profiles that are not (yet) steady too.  Returns Ps and the rms
    residual."""
    from scipy.optimize import minimize_scalar

    from ..fitting.segregation import phi_teq28

    z, phi = np.asarray(z, float), np.asarray(phi, float)
    lo, hi = (0.0, h) if z_range is None else z_range
    sel = (z >= lo) & (z <= hi)
    if sel.sum() < 3:
        raise ValueError(f"z_range = [{lo:g}, {hi:g}] holds {int(sel.sum())} levels: need >= 3")

    def cost(log_ps):
        return float(np.mean((phi_teq28(z[sel] / h, math.exp(log_ps), phi0) - phi[sel]) ** 2))

    r = minimize_scalar(cost, bounds=(math.log(0.05), math.log(1000.0)), method="bounded")
    return {"Ps": float(math.exp(r.x)), "rms": math.sqrt(r.fun),
            "at_bound": bool(r.x < math.log(0.06) or r.x > math.log(900.0))}


def transient_windows(m: dict, tracer_dir, *, n_windows: int = 8, every: float = 2.0,
                      average: float = 1.0, width: float = 0.5, margin: float = 1.0) -> dict:
    """How T-eq. (27)'s rates change over a run's segregation, and what changes with them: the
    tracers' span from the start of shear t0 to their end cut into ``n_windows`` equal windows,
    and per window

    * ``s``: the mean segregation indicator (from s0; ``m``'s s(t)) and ``u_mean`` (the
      flow's mean velocity, ``series.nc``): is the flow itself still changing;
    * ``D``, ``D_small``, ``D_large``: the self-diffusivity in z over the window
      (:func:`transient_diffusivity`);
    * ``fit``: S, D_r (and Ps = S h / D_r) of T-eq. (27) fitted to the window's phi(z, t) from
      its own start (:func:`granflow.continuum.segregation.fit_segregation_transient`; its
      ``identified`` flag says whether the window pins them);
    * ``Ps_profile``: the T-eq. (28) Ps nearest the window's last profile
      (:func:`profile_peclet`): the profile's sharpness in T-eq. (28)'s terms (measured
      2026-12-04 at the paper's set-up: 3.0 rising to 6.8, the steady value, with no
      overshoot).

    Constant rates would give one S and D_r in every window."""
    from .segregation import fit_segregation_transient

    if n_windows < 2:
        raise ValueError(f"n_windows = {n_windows} is out of range: allowed >= 2")
    with np.load(Path(tracer_dir) / "tracers.npz") as f:
        t_last = float(f["time"][-1]) - average
    tp = _transient_profiles(m, tracer_dir, every=every, average=average, width=width,
                             t_to=t_last)
    times, levels, prof, h = tp["times"], tp["levels"], tp["phi"], tp["h"]
    edges = np.linspace(tp["t0"], float(times[-1]), int(n_windows) + 1)
    with xr.open_dataset(Path(m["run"]) / "series.nc") as ser:
        ts, us = ser["t"].values, ser["u_mean"].values
    ms_t = np.asarray(m["t"], float) + m["t0"]
    ms_s = np.asarray(m["s"], float)
    kw = dict(h=h, phi0=m["phi0"], z_range=(margin, h - margin))
    rows = []
    for a, b in zip(edges[:-1], edges[1:]):
        w = (times >= a - 1e-9) & (times <= b + 1e-9)
        fit = fit_segregation_transient(times[w], levels, prof[w], **kw)
        D = transient_diffusivity(tracer_dir, float(a), float(b))
        ws = (ms_t >= a) & (ms_t <= b)
        wu = (ts >= a) & (ts <= b)
        pe = profile_peclet(levels, prof[w][-1], **kw)
        rows.append({"t_from": float(a), "t_to": float(b),
                     "s": float(ms_s[ws].mean()) if ws.any() else math.nan,
                     "u_mean": float(us[wu].mean()) if wu.any() else math.nan,
                     "D": D["D"], "D_stderr": D["D_stderr"], "D_small": D["D_small"],
                     "D_large": D["D_large"],
                     "fit": {k: fit[k] for k in ("S", "S_stderr", "D_r", "D_r_stderr", "Ps",
                                                 "Ps_stderr", "r2", "r2_change", "identified",
                                                 "unidentified")},
                     "Ps_profile": pe["Ps"], "Ps_profile_rms": pe["rms"]})
    return {"windows": rows, "h": h, "t0": tp["t0"], "every": every, "average": average,
            "width": width, "margin": margin}


def inverse_pressure_shape(profiles_nc, base: float, h: float, *, p_min: float = 1.0):
    """S_shape(zeta) = p(h / 2) / max(p(z), p_min) of a run's coarse-grained pressure profile
    (``profiles.nc``: p = -sigma_zz, heights above ``base``): a segregation velocity S ~ 1 / p,
    normalised to 1 at mid-depth, capped where the overburden falls below ``p_min`` (the top
    layer of particles; the result hardly depends on it, the top being pure large there).
    Returns (shape, p_mid)."""
    if not (math.isfinite(p_min) and p_min > 0):
        raise ValueError(f"p_min = {p_min!r} is out of range: allowed (0, inf)")
    with xr.open_dataset(profiles_nc) as ds:
        z = ds["z"].values - base
        szz = ds["stress_zz"].values
    p = -szz if np.nanmean(szz) < 0 else szz
    ok = np.isfinite(p)
    z, p = z[ok], p[ok]
    p_mid = float(np.interp(0.5 * h, z, p))
    if not p_mid > p_min:
        raise ValueError(f"pressure at mid-depth {p_mid:g} is not above p_min = {p_min:g}")
    return (lambda zeta: p_mid / np.maximum(np.interp(np.asarray(zeta) * h, z, p), p_min)), p_mid


def _bulk_centre(phi, zc, z_from: float) -> float:
    """Centre of mass height of the small particles' volume above ``z_from`` (cells zc)."""
    k = zc >= z_from
    return float((phi[k] * zc[k]).sum() / phi[k].sum())


def pressure_scaled_segregation(m: dict, run_dir, *, D: float, z_bulk: float = 4.0,
                                every: float = 5.0, n: int = 200,
                                kappas=(0.25, 0.5, 0.75, 0.9)) -> dict:
    """T-eq. (27) with a segregation velocity that scales as 1 / p (S(z) = S_mid p_mid / p(z),
    :func:`inverse_pressure_shape`; what the transient's local S(z) shows,
    :func:`segregation_pressure_scaling`) against a bidisperse run, on the bulk above
    ``z_bulk`` (the basal layers fill with small particles within ~70 time units at the rough
    base, a wall effect outside T-eq. (27)):

    * ``steady``: the run's steady profile (``row.json``) at z >= z_bulk fitted with the 1 / p
      law's exact steady state (one parameter, Ps_mid = S_mid h / D) beside T-eq. (28)'s
      constant-rate fit: rms of each;
    * ``transient``: S_mid and D_r of the 1 / p model fitted to the transient phi(z, t) (t0 to
      two particle half-times; z_bulk to h - 1; :func:`fit_segregation_transient`), D_r
      against the self-diffusivity ``D``;
    * ``prediction`` / ``prediction_transient_rates``: the bulk's half-time (centre of mass of
      the small particles above z_bulk, from the particles' own profile at t0) of the 1 / p
      model with the steady profile's Ps_mid and D (a closure measured in steady flow), and
      with the transient's fitted rates, against the particles';
    * ``asymmetric``: the same two fits with seed 001's asymmetric flux for each of ``kappas``
      (``scan``), and ``kappa_consistent``, the kappa at which the transient's Ps_mid equals
      the steady profile's (log-linear interpolation in the scan; None where it does not
      cross): there one set of rates has both the transient and the steady state, and its
      D_r against the self-diffusivity says what the closure D_r = D_self misses
      (``at_kappa``, with the predictions from the steady Ps_mid there and D, or the
      transient's D_r: the one model that has both, checked on its own half-time)."""
    from scipy.optimize import minimize_scalar

    from ..fitting.segregation import phi_teq28
    from .segregation import (
        _smooth_reflecting,
        fit_segregation_transient,
        half_time,
        segregation_layer,
        steady_profile_shaped,
    )

    run_dir = Path(run_dir)
    row = json.loads((run_dir / "row.json").read_text())
    sp = row["segregation_profile"]
    zeta_p, phi_p = np.asarray(sp["zeta"], float), np.asarray(sp["phi"], float)
    tp = _transient_profiles(m, run_dir, every=every, average=1.0, width=0.5)
    h, phi0 = tp["h"], m["phi0"]
    if not 0.0 <= z_bulk < 0.5 * h:
        raise ValueError(f"z_bulk = {z_bulk!r} is out of range: allowed [0, h / 2 = {h / 2:g})")
    if not all(0.0 <= k < 1.0 for k in kappas):
        raise ValueError(f"kappas = {list(kappas)} are out of range: allowed [0, 1)")
    shape, p_mid = inverse_pressure_shape(run_dir / "profiles.nc", tp["base"], h)
    sel = zeta_p * h >= z_bulk
    zc_n = (np.arange(400) + 0.5) / 400
    bounds = (math.log(0.1), math.log(200.0))

    def steady_fit(flux, kappa):
        def rms(log_ps):
            prof = steady_profile_shaped(math.exp(log_ps), phi0, 400, S_shape=shape, flux=flux,
                                         kappa=kappa)
            return float(np.sqrt(np.mean((np.interp(zeta_p[sel], zc_n, prof) - phi_p[sel])
                                         ** 2)))

        r = minimize_scalar(rms, bounds=bounds, method="bounded", options={"xatol": 1e-4})
        return float(math.exp(r.x)), float(r.fun)

    def transient_fit(flux, kappa):
        f = fit_segregation_transient(tp["times"], tp["levels"], tp["phi"], h=h, phi0=phi0,
                                      z_range=(z_bulk, h - 1.0), S_shape=shape, flux=flux,
                                      kappa=kappa)
        out = {k: f[k] for k in ("S", "S_stderr", "D_r", "D_r_stderr", "Ps", "Ps_stderr", "r2",
                                 "r2_change", "rms", "identified", "unidentified", "t_from",
                                 "t_to")}
        out.update(A=f["S"] * p_mid, D_r_over_D_self=f["D_r"] / D)
        return out

    Ps_mid, rms_1p = steady_fit("symmetric", 0.0)
    rc = minimize_scalar(lambda lp: float(np.sqrt(np.mean(
        (phi_teq28(zeta_p[sel], math.exp(lp), phi0) - phi_p[sel]) ** 2))), bounds=bounds,
        method="bounded")
    steady = {"Ps_mid": Ps_mid, "rms": rms_1p, "A": Ps_mid * D / h * p_mid,
              "Ps_constant": float(math.exp(rc.x)), "rms_constant": float(rc.fun)}
    transient = transient_fit("symmetric", 0.0)
    transient["Ps_over_steady"] = transient["Ps"] / Ps_mid
    # the particles' bulk centre of mass over the whole run, and the models from their t0
    full = _transient_profiles(m, run_dir, every=every, average=1.0, width=0.5,
                               t_to=math.inf)
    zc = (np.arange(n) + 0.5) / n * h
    meas = np.array([np.interp(zc, full["levels"], q) for q in full["phi"]])
    cm = np.array([_bulk_centre(q, zc, z_bulk) for q in meas])
    t_rel = full["times"] - full["t0"]
    th_particles = half_time(t_rel, cm, cm[0], cm[-1])
    start = _smooth_reflecting(meas[0], 0.5 * n / h)
    start = np.clip(start * (phi0 / start.mean()), 1e-9, 1.0 - 1e-9)

    def predict(Ps, Dm, flux="symmetric", kappa=0.0):
        res = segregation_layer(Ps=Ps, D=Dm, h=h, phi0=phi0, t_end=4.0 * max(t_rel[-1], 1.0),
                                n=n, n_out=1601, phi_initial=start, S_shape=shape, flux=flux,
                                kappa=kappa)
        c = np.array([_bulk_centre(q, zc, z_bulk) for q in res.phi.values])
        c_inf = _bulk_centre(res.phi_steady.values, zc, z_bulk)
        th = half_time(res.t.values, c, c[0], c_inf)
        return {"Ps_mid": float(Ps), "D": float(Dm), "flux": flux, "kappa": float(kappa),
                "t_half": th, "err_t_half": th / th_particles - 1.0, "centre_steady": c_inf,
                "centre_at_particles_end": float(np.interp(t_rel[-1], res.t.values, c))}

    scan = [{"kappa": 0.0, "Ps_mid_steady": Ps_mid, "rms_steady": rms_1p,
             "Ps_mid_transient": transient["Ps"], "D_r_over_D_self": transient["D_r_over_D_self"],
             "r2": transient["r2"]}]
    for k in kappas:
        if k == 0.0:
            continue
        ps_s, rms_s = steady_fit("asymmetric", float(k))
        tr = transient_fit("asymmetric", float(k))
        scan.append({"kappa": float(k), "Ps_mid_steady": ps_s, "rms_steady": rms_s,
                     "Ps_mid_transient": tr["Ps"], "D_r_over_D_self": tr["D_r_over_D_self"],
                     "r2": tr["r2"]})
    scan.sort(key=lambda r: r["kappa"])
    gap = [math.log(r["Ps_mid_transient"] / r["Ps_mid_steady"]) for r in scan]
    k_star = None
    for i in range(len(scan) - 1):
        if gap[i] == 0.0 or gap[i] * gap[i + 1] < 0:
            k0, k1 = scan[i]["kappa"], scan[i + 1]["kappa"]
            k_star = k0 + (k1 - k0) * gap[i] / (gap[i] - gap[i + 1])
            break
    at_kappa = None
    if k_star is not None:
        flux_k = "asymmetric" if k_star > 0 else "symmetric"
        ps_s, rms_s = steady_fit(flux_k, k_star)
        tr = transient_fit(flux_k, k_star)
        at_kappa = {"kappa": k_star, "Ps_mid_steady": ps_s, "rms_steady": rms_s,
                    "transient": tr, "Ps_over_steady": tr["Ps"] / ps_s,
                    "prediction": predict(ps_s, D, flux_k, k_star),
                    "prediction_fitted_D_r": predict(ps_s, tr["D_r"], flux_k, k_star)}
    return {"z_bulk": z_bulk, "p_mid": p_mid, "h": h, "D_self": D, "steady": steady,
            "transient": transient, "t_half_particles": th_particles,
            "centre_particles_start": float(cm[0]), "centre_particles_end": float(cm[-1]),
            "prediction": predict(Ps_mid, D),
            "prediction_transient_rates": predict(transient["Ps"], transient["D_r"]),
            "asymmetric": {"scan": scan, "kappa_consistent": k_star, "at_kappa": at_kappa}}


def local_segregation_velocity(rates: dict) -> list[dict]:
    """S(z) at each level of :func:`transient_rates`' ``levels`` table: from the measured mean
    flux and the self-diffusivity of the level's 2-d band (``D_profile``), S = -(J / c + D
    dphi/dz) / (phi (1 - phi)) -- T-eq. (27)'s flux solved for a local S, one value per
    (window, level); and their mean over the windows per level with the windows' scatter
    (stderr of the mean).  Levels where phi (1 - phi) < 0.05 (nearly pure) are left out."""
    bands = rates["D_profile"]

    def D_at(z):
        for b in bands:
            if b["z_from"] <= z < b["z_to"]:
                return b["D"]
        return bands[-1]["D"]

    per = {}
    for r in rates["levels"]:
        q = r["phi"] * (1.0 - r["phi"])
        if q < 0.05:
            continue
        per.setdefault(r["z"], []).append(-(r["J_over_c"] + D_at(r["z"]) * r["dphi_dz"]) / q)
    out = []
    for z, v in sorted(per.items()):
        v = np.asarray(v)
        out.append({"z": float(z), "S": float(v.mean()), "n_windows": int(v.size),
                    "S_stderr": float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1
                    else math.nan, "D_self": float(D_at(z))})
    return out


def segregation_pressure_scaling(rates: dict, profiles_nc, base: float, *,
                                 z_from: float = 5.0, half_width: float = 1.0) -> dict:
    """How :func:`local_segregation_velocity`'s S(z) scales with the local pressure and shear
    rate of the run's coarse-grained profiles (``profiles.nc``: p = -sigma_zz, shear rate
    du_x/dz, each averaged over +-``half_width`` of the level; heights above ``base``): per
    level S, p, gamma_dot and the three products S p (S ~ 1/p), S / gamma_dot (S ~ gamma_dot d,
    the Savage-Lun / Fan et al. scaling) and S p / gamma_dot (S ~ gamma_dot / p, Trewhela,
    Ancey & Gray 2021's), with each product's coefficient of variation over the levels at
    z >= ``z_from`` (the basal layers left out): the smallest says which scaling the depth
    profile follows (``best``; None where fewer than two levels lie there)."""
    with xr.open_dataset(profiles_nc) as ds:
        z = ds["z"].values - base
        u = ds["velocity_x"].values
        szz = ds["stress_zz"].values
    p = -szz if np.nanmean(szz) < 0 else szz
    gd = np.gradient(u, z)
    rows = []
    for e in local_segregation_velocity(rates):
        m = np.abs(z - e["z"]) <= half_width + 1e-9
        P, G = float(np.nanmean(p[m])), float(np.nanmean(gd[m]))
        rows.append({"z": e["z"], "S": e["S"], "p": P, "gamma_dot": G, "S_p": e["S"] * P,
                     "S_over_gamma_dot": e["S"] / G, "S_p_over_gamma_dot": e["S"] * P / G})
    cv = {}
    for key in ("S_p", "S_over_gamma_dot", "S_p_over_gamma_dot"):
        v = np.array([r[key] for r in rows if r["z"] >= z_from])
        cv[key] = float(np.std(v) / np.mean(v)) if v.size > 1 else math.nan
    finite = {k: v for k, v in cv.items() if math.isfinite(v)}
    return {"levels": rows, "cv": cv, "z_from": z_from,
            "best": min(finite, key=finite.get) if finite else None}


def measured_profile_prediction(m: dict, rates: dict, *, t_end=None) -> dict:
    """T-eq. (27) with depth-dependent rates taken from the transient's local measurements
    (:func:`local_segregation_velocity`'s S(z), the banded self-diffusivity D(z); both
    interpolated in z, held constant beyond the outermost levels), from the particle run's
    start of shear as :func:`segregation_against_model` aligns it: its half-time against the
    particles', and its steady state (exact, :func:`granflow.continuum.segregation.
    steady_profile_shaped`) as the Ps of T-eq. (28) with the same indicator -- what the
    transient's rates say the steady profile should be, against the steady Ps the comparison
    uses (``rates["Ps_steady"]``)."""
    from scipy.optimize import brentq

    from .segregation import indicator, segregation_layer, steady_profile

    h = rates["h"]
    S_rows = local_segregation_velocity(rates)
    zS = np.array([r["z"] for r in S_rows]) / h
    S_v = np.array([r["S"] for r in S_rows])
    if S_v.size < 2 or not np.all(S_v > 0):
        raise ValueError(f"local segregation velocities not all positive: {S_v.tolist()}")
    zD = np.array([0.5 * (b["z_from"] + b["z_to"]) for b in rates["D_profile"]]) / h
    D_v = np.array([b["D"] for b in rates["D_profile"]])
    D_ref = float(np.mean(D_v))
    S_ref = float(np.mean(S_v))
    S_shape = lambda zeta: np.interp(zeta, zS, S_v) / S_ref  # noqa: E731
    D_shape = lambda zeta: np.interp(zeta, zD, D_v) / D_ref  # noqa: E731
    Ps_ref = S_ref * h / D_ref
    phi0 = m["phi0"]
    t_model = 2.0 * max(m["t"][-1], 1.0) if t_end is None else float(t_end)
    res = segregation_layer(Ps=Ps_ref, D=D_ref, h=h, phi0=phi0, t_end=t_model, n=200, n_out=801,
                            S_shape=S_shape, D_shape=D_shape)
    th, t_shift = aligned_half_time(res.t.values, res.indicator.values,
                                    float(res.indicator_steady), float(m["s0"]))
    s_inf = float(res.indicator_steady)
    zeta = res.zeta.values

    def gap(log_ps):
        return float(indicator(steady_profile(math.exp(log_ps), phi0, zeta.size), zeta, h,
                               phi0)) - s_inf

    try:
        Ps_equiv = float(math.exp(brentq(gap, math.log(0.05), math.log(500.0))))
    except ValueError:
        Ps_equiv = math.nan
    return {"S_profile": S_rows, "S_ref": S_ref, "D_ref": D_ref, "Ps_ref": Ps_ref,
            "t_half": th, "t_shift": t_shift,
            "err_t_half": th / m["t_half"] - 1.0 if m["t_half"] > 0 else math.nan,
            "s_steady": s_inf, "Ps_equivalent_steady": Ps_equiv,
            "Ps_steady_measured": float(rates["Ps_steady"])}


def matching_peclet(t_half, s0, *, D, h, phi0, Ps_from, t_end, factor_max=20.0) -> float:
    """The Peclet number Ps at which T-eq. (27) (symmetric flux, diffusivity D) gives the
    particle run's aligned half-time ``t_half`` (from s0): what the run's segregation speed
    S = Ps D / h says, independently of the steady profile's Ps.  NaN if no Ps in
    [Ps_from / factor_max, Ps_from * factor_max] does."""
    from scipy.optimize import brentq

    from .segregation import segregation_layer

    def err(log_ps):
        res = segregation_layer(Ps=math.exp(log_ps), D=D, h=h, phi0=phi0, t_end=t_end, n=200,
                                n_out=401)
        th, _ = aligned_half_time(res.t.values, res.indicator.values,
                                  float(res.indicator_steady), s0)
        return (th if math.isfinite(th) else t_end) - t_half

    lo, hi = math.log(Ps_from / factor_max), math.log(Ps_from * factor_max)
    try:
        if err(lo) * err(hi) > 0:
            return math.nan
        return float(math.exp(brentq(err, lo, hi, xtol=1e-3)))
    except ValueError:
        return math.nan


# ----------------------------------------------------------------------------- all comparisons
def parent_of(child_dir) -> Path:
    """The parent run folder of a switch run (from its summary's provenance)."""
    return Path(_summary(child_dir)["parent"]["parent_state"]).parent


def compare_all(lib_path, campaign_dir, switch_dirs, long_chute_dir, out_json, figures=None,
                *, long_chute_theta=None, n_ensemble=100, segregation_tracers=None) -> dict:
    """Every comparison of the module docstring into one JSON (and PNG figures).
    ``segregation_tracers``: folder with ``sigma~<sigma>`` runs of
    :func:`run_segregation_tracers` (the transient diffusivity; optional)."""
    from ..closures import open_library

    lib = open_library(lib_path)
    st = lib.closures.status()
    status = {k: sorted(set(g["status"])) for k, g in st.groupby("kind")}
    res = {"library": os.fspath(lib_path), "library_content_hash": lib.attrs["content_hash"],
           "closure_status": status, "switches": [], "long_chute": None, "segregation": []}
    for d in switch_dirs:
        try:
            res["switches"].append(compare_switch(lib, parent_of(d), d, n_ensemble=n_ensemble))
        except Exception as exc:  # keep the others; the failure is reported
            res["switches"].append({"child": os.fspath(d), "error": f"{type(exc).__name__}: {exc}"})
    if long_chute_dir is not None and (Path(long_chute_dir) / "columns.nc").exists():
        cols = xr.open_dataset(Path(long_chute_dir) / "columns.nc")
        tiles = json.loads(cols.attrs["tiles"])
        base_run = Path(tiles[-1]).parent
        rho = _summary(base_run)["depth_averages"]["rho_bar"]
        theta = long_chute_theta or _summary(base_run)["params"]["theta"]
        res["long_chute"] = compare_long_chute(lib, Path(long_chute_dir) / "columns.nc", rho,
                                               theta, out_nc=Path(long_chute_dir) /
                                               "shallow_layer.nc")
        # the same with the depth-averaged viscous stress of Gray & Edwards (2014)
        try:
            res["long_chute_viscous"] = compare_long_chute(
                lib, Path(long_chute_dir) / "columns.nc", rho, theta,
                out_nc=Path(long_chute_dir) / "shallow_layer_viscous.nc",
                viscosity="gray_edwards")
        except ValueError as exc:  # no steady flow at the mean depth: reported
            res["long_chute_viscous"] = {"error": f"{type(exc).__name__}: {exc}"}
        # and in local equilibrium: the kinematic wave (u = the steady flow rule's u_s(h))
        for key, model in (("long_chute_kinematic", "kinematic_wave"),
                           ("long_chute_diffusive", "diffusive_wave")):
            try:
                res[key] = compare_long_chute(
                    lib, Path(long_chute_dir) / "columns.nc", rho, theta, model=model,
                    out_nc=Path(long_chute_dir) / f"{model}.nc",
                    n_ensemble=n_ensemble if model == "kinematic_wave" else 0)
            except (ValueError, RuntimeError) as exc:
                res[key] = {"error": f"{type(exc).__name__}: {exc}"}
    seg_fits = json.loads((Path(campaign_dir) / "segregation_fits.json").read_text())
    for run in sorted(Path(campaign_dir).glob("segregation/**/summary.json")):
        try:
            tr = None
            if segregation_tracers is not None:
                sig = _summary(run.parent)["params"]["sigma"]
                cand = Path(segregation_tracers) / f"sigma~{sig:g}"
                tr = cand if (cand / "tracers.npz").exists() else None
            res["segregation"].append(compare_segregation(lib, run.parent, seg_fits,
                                                          tracer_dir=tr))
        except Exception as exc:
            res["segregation"].append({"run": os.fspath(run.parent),
                                       "error": f"{type(exc).__name__}: {exc}"})
    _json_write(out_json, res)
    if figures is not None:
        plot_all(res, figures)
    return res


def plot_all(res: dict, figures) -> list:
    """PNG figures of the comparisons (switches, long chute, segregation)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures = Path(figures)
    figures.mkdir(parents=True, exist_ok=True)
    out = []
    sw = [s for s in res["switches"] if "error" not in s]
    if sw:
        fig, axes = plt.subplots(1, len(sw), figsize=(3.2 * len(sw), 2.8), squeeze=False)
        for ax, s in zip(axes[0], sw):
            scale = s["u0"] / s["u0_mean_particles"]
            ax.plot(s["t"], np.asarray(s["u_mean"]) * scale, ".", ms=2, color="k",
                    label="particles (u_mean, scaled)")
            ax.fill_between(s["ode_t"], s["ode_u_low"], s["ode_u_high"], color="C0", alpha=0.3)
            ax.plot(s["ode_t"], s["ode_u"], color="C0", label="ODE (library)")
            if "column_u" in s:
                ax.plot(s["ode_t"], s["column_u"], color="C3", ls="--",
                        label="column (same closures)")
            if math.isfinite(s["u_steady"]):
                ax.axhline(s["u_steady"], color="k", ls=":", lw=0.8)
            ax.set_title(f"H={s['H']:g}: {s['theta1']:g} -> {s['theta2']:g} deg", fontsize=8)
            ax.set_xlabel("t since switch")
        axes[0][0].set_ylabel("u_bar")
        axes[0][0].legend(fontsize=6)
        fig.tight_layout()
        p = figures / "switch_transients.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        out.append(p)
    lc = res.get("long_chute")
    lv = res.get("long_chute_viscous")
    lv = lv if lv and "error" not in lv else None
    if lc:
        rows = lc["rows"]
        t = [r["t"] for r in rows]
        fig, (ax, ax2) = plt.subplots(1, 2, figsize=(9.5, 3.2))
        pr = lc.get("profiles")
        if pr:
            for k, tk in enumerate(pr["t"]):
                col = plt.cm.viridis(k / max(len(pr["t"]) - 1, 1))
                ax2.plot(pr["x"], pr["h_particles"][k], ".", ms=2, color=col)
                ax2.plot(pr["x"], pr["h_solver"][k], "-", lw=1, color=col, label=f"t = {tk:g}")
            ax2.set_xlabel("x")
            ax2.set_ylabel("h (points: particles, lines: solver)")
            ax2.legend(fontsize=6)
        for f, c in (("peak", "C1"), ("front", "C2")):
            ax.plot(t, [r[f"{f}_travel_particles"] for r in rows], "o", ms=3, color=c,
                    label=f"{f}: particles")
            ax.plot(t, [r[f"{f}_travel_solver"] for r in rows], "-", color=c,
                    label=f"{f}: shallow-layer solver")
            if lv:
                ax.plot([r["t"] for r in lv["rows"]],
                        [r[f"{f}_travel_solver"] for r in lv["rows"]], "--", color=c,
                        label=f"{f}: with viscous stress (nu = {lv['viscosity']:.2f})")
            lk = res.get("long_chute_kinematic")
            if lk and "error" not in lk:
                ax.plot([r["t"] for r in lk["rows"]],
                        [r[f"{f}_travel_solver"] for r in lk["rows"]], ":", color=c,
                        label=f"{f}: kinematic wave")
        ax.set_xlabel("t")
        ax.set_ylabel("distance travelled (d)")
        ax.legend(fontsize=7)
        fig.tight_layout()
        p = figures / "long_chute_positions.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        out.append(p)
    seg = [s for s in res["segregation"] if "error" not in s]
    if seg:
        fig, axes = plt.subplots(2, len(seg), figsize=(2.8 * len(seg), 5.0), squeeze=False)
        for k, s in enumerate(seg):
            ax = axes[0][k]
            ax.plot(s["t"], s["s"], ".", ms=2, color="k", label="particles")
            for name, c in (("symmetric", "C0"), ("asymmetric", "C3")):
                ax.plot(s[name]["t"], s[name]["s"], color=c, label=name)
            ax.set_title(f"sigma = {s['sigma']:g}", fontsize=8)
            ax.set_xlabel("t - t0")
            ax = axes[1][k]
            ax.plot(s["phi_particles"], s["zeta"], "k.", ms=2)
            ax.plot(s["symmetric"]["phi_model"], s["zeta"], "C0")
            ax.plot(s["asymmetric"]["phi_model"], s["zeta"], "C3--")
            ax.set_xlabel("phi")
        axes[0][0].set_ylabel("s(t) - s(t0)")
        axes[1][0].set_ylabel("z / h")
        axes[0][0].legend(fontsize=6)
        fig.tight_layout()
        p = figures / "segregation.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        out.append(p)
    return out


def plot_long_chute(lc: dict, path, label: str) -> Path:
    """PNG of one long-chute comparison (:func:`compare_long_chute`): distances travelled by
    peak and front (particles: points; the model, ``label``: line; the closure ensemble's
    16-84 % band where it was computed) and the h(x) profiles at five times."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = lc["rows"]
    t = [r["t"] for r in rows]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(9.5, 3.2))
    for f, c in (("peak", "C1"), ("front", "C2")):
        ax.plot(t, [r[f"{f}_travel_particles"] for r in rows], "o", ms=3, color=c,
                label=f"{f}: particles")
        ax.plot(t, [r[f"{f}_travel_solver"] for r in rows], "-", color=c, label=f"{f}: {label}")
        if f"{f}_travel_solver_lo" in rows[0]:
            ax.fill_between(t, [r[f"{f}_travel_solver_lo"] for r in rows],
                            [r[f"{f}_travel_solver_hi"] for r in rows], color=c, alpha=0.2,
                            lw=0, label=f"{f}: closure ensemble 16-84 %")
    ax.set_xlabel("t")
    ax.set_ylabel("distance travelled (d)")
    ax.legend(fontsize=6)
    pr = lc["profiles"]
    for k, tk in enumerate(pr["t"]):
        col = plt.cm.viridis(k / max(len(pr["t"]) - 1, 1))
        ax2.plot(pr["x"], pr["h_particles"][k], ".", ms=2, color=col)
        ax2.plot(pr["x"], pr["h_solver"][k], "-", lw=1, color=col, label=f"t = {tk:g}")
    ax2.set_xlabel("x")
    ax2.set_ylabel(f"h (points: particles, lines: {label})")
    ax2.legend(fontsize=6)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- command line
def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m granflow.continuum.experiments",
                                 description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-v", "--verbose", action="store_true",
                    help="log the simulations' progress (INFO) to stderr")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("switch", help="restart a steady run at a new inclination")
    p.add_argument("parent")
    p.add_argument("theta2", type=float)
    p.add_argument("--out", required=True)
    p.add_argument("--t-end", type=float, default=250.0)
    p = sub.add_parser("long-chute", help="tiled long chute with column coarse-graining")
    p.add_argument("--tiles", nargs="+", required=True, help="run folders, one per tile")
    p.add_argument("--base", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--t-end", type=float, default=60.0)
    p = sub.add_parser("diffusivity", help="fit D over switch runs; add it to the library")
    p.add_argument("--runs", nargs="+", required=True)
    p.add_argument("--campaign", required=True, help="campaign results folder")
    p.add_argument("--out", required=True, help="path of the library copy")
    p = sub.add_parser("segregation-tracers",
                       help="simulate a bidisperse run again from its start with tracers")
    p.add_argument("run")
    p.add_argument("--out", required=True)
    p.add_argument("--t-end", type=float, default=250.0)
    p = sub.add_parser("segregation-run",
                       help="simulate a campaign's bidisperse run (RUN/params.yaml) in its folder "
                            "with tracers, then write its row.json as the campaign's row step")
    p.add_argument("run", help="the run's campaign folder, holding params.yaml")
    p.add_argument("--base", required=True)
    p.add_argument("--rel", required=True, help="the run's path inside the campaign folder")
    p.add_argument("--segregation-window", type=float, default=200.0)
    p.add_argument("--tracer-interval", type=float, default=0.5)
    p.add_argument("--threads", type=int, default=1)
    p = sub.add_parser("compare-segregation",
                       help="a segregation-run folder against T-eq. (27) -> JSON")
    p.add_argument("run")
    p.add_argument("--out", required=True, help="comparison JSON")
    p.add_argument("--Ps", type=float, default=None,
                   help="Ps for the model (default: the run's own steady-profile fit)")
    p = sub.add_parser("compare-long-chute",
                       help="a long-chute run against one model -> table (and JSON)")
    p.add_argument("long_chute", help="long-chute folder (columns.nc)")
    p.add_argument("--closures", required=True,
                   help="closure library (.nc), or 'paper' for the paper's own Table 1-2 and "
                        "Eq. 53 closures (FlowClosures.paper)")
    p.add_argument("--lam", type=float, default=1.0, help="lambda of the paper's closures")
    p.add_argument("--model", choices=LONG_CHUTE_MODELS, default="shallow")
    p.add_argument("--viscosity", default=None,
                   help="shallow model only: 'gray_edwards' or a number nu")
    p.add_argument("--n-ensemble", type=int, default=0,
                   help="local-equilibrium models: members of the friction ensemble")
    p.add_argument("--out", default=None, help="comparison JSON")
    p.add_argument("--figure", default=None, help="PNG of the comparison (plot_long_chute)")
    p = sub.add_parser("compare", help="all comparisons -> JSON and figures")
    p.add_argument("--lib", required=True, help="closure library (with the diffusivity)")
    p.add_argument("--campaign", required=True)
    p.add_argument("--switch-runs", nargs="*", default=[])
    p.add_argument("--long-chute", default=None)
    p.add_argument("--out", required=True, help="comparison JSON")
    p.add_argument("--figures", default=None)
    p.add_argument("--segregation-tracers", default=None,
                   help="folder of sigma~<sigma> runs of segregation-tracers")
    a = ap.parse_args(argv)
    need = {"segregation-run": lambda: [Path(a.run) / "params.yaml", Path(a.base)],
            "compare-segregation": lambda: [Path(a.run) / f for f in (
                "summary.json", "series.nc", "row.json", "tracers.npz")],
            "compare-long-chute": lambda: [Path(a.long_chute) / "columns.nc"] + (
                [] if a.closures == "paper" else [Path(a.closures)])}
    if a.cmd in need:  # before any compute: name what is missing and what makes it
        missing = [os.fspath(f) for f in need[a.cmd]() if not f.is_file()]
        if missing:
            ap.error(f"{a.cmd}: missing {', '.join(missing)} ("
                     + ("the run's params.yaml comes from `granflow campaign run-params`, the "
                        "base from `granflow prepare-base`" if a.cmd == "segregation-run" else
                        "a finished `segregation-run` folder holds all four"
                        if a.cmd == "compare-segregation" else
                        "the long chute comes from `long-chute`; --closures names a library "
                        "or 'paper'") + ")")
    if a.cmd == "compare-long-chute":  # the choices' values, before reading anything
        if a.viscosity not in (None, "gray_edwards"):
            try:
                float(a.viscosity)
            except ValueError:
                ap.error(f"--viscosity {a.viscosity!r}: allowed 'gray_edwards' or a number")
        if a.n_ensemble < 0:
            ap.error(f"--n-ensemble {a.n_ensemble}: allowed integers >= 0")
    if a.verbose:
        import logging

        logging.basicConfig(level=logging.INFO,
                            format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    if a.cmd == "switch":
        res = run_switch(a.parent, a.theta2, a.out, t_end=a.t_end)
        print(f"{a.out}: {res['flow_state']} at t = {res['t_final']:.4g} ({res['wall_s']:.0f} s)")
    elif a.cmd == "long-chute":
        ps = _summary(a.tiles[0])["params"]
        run_long_chute([Path(t) / "final_state.npz" for t in a.tiles], a.base, ps["Lx"],
                       ps["Ly"], ps, a.out, t_end=a.t_end)
        print(f"{a.out}/columns.nc")
    elif a.cmd == "diffusivity":
        rows = diffusivity_measurements(a.runs)
        fit = diffusivity_fit(rows)
        info = library_with_diffusivity(a.campaign, fit, a.out)
        _json_write(Path(a.out).with_suffix(".diffusivity.json"),
                    {"runs": rows, "c_D": fit.params["c_D"], "c_D_stderr": fit.stderr["c_D"],
                     "status": fit.state, "library": info})
        print(f"c_D = {fit.params['c_D']:.4g} +- {fit.stderr['c_D']:.2g} ({fit.state}); "
              f"library {info['path']}")
    elif a.cmd == "segregation-tracers":
        res = run_segregation_tracers(a.run, a.out, t_end=a.t_end)
        print(f"{a.out}/tracers.npz: t = {res['t_final']:.4g} ({res['wall_s']:.0f} s)")
    elif a.cmd == "segregation-run":
        import yaml

        from ..campaign.collect import write_row

        params = yaml.safe_load((Path(a.run) / "params.yaml").read_text())
        res = _simulate_with_tracers(params, a.run, a.tracer_interval, a.threads,
                                     base_file=a.base)
        write_row(a.run, Path(a.run) / "row.json", rel=a.rel,
                  segregation_window=a.segregation_window)
        print(f"{a.run}: {res['flow_state']} at t = {res['t_final']:.4g} ({res['wall_s']:.0f} s)"
              f"; tracers.npz, row.json")
    elif a.cmd == "compare-segregation":
        from ..reference import SEGREGATION_PAPER_SETUP

        sig = _summary(a.run)["params"]["sigma"]
        fit = SEGREGATION_PAPER_SETUP["fit"]
        laws = {"paper T-eq. 29": 7.35 * -math.expm1(-5.21 * (1.0 / sig - 1.0))}
        if fit["form"] == "plateau":
            laws["reference plateau"] = fit["Pmax"][0]
        res = compare_segregation_reference(a.run, Ps_laws=laws, Ps=a.Ps)
        _json_write(a.out, res)
        print(format_segregation_reference(res))
    elif a.cmd == "compare-long-chute":
        from ..closures import open_library
        from .closures import FlowClosures

        cols = xr.open_dataset(Path(a.long_chute) / "columns.nc")
        base_run = Path(json.loads(cols.attrs["tiles"])[-1]).parent
        summ = _summary(base_run)
        theta = summ["params"]["theta"]
        lib = (FlowClosures.paper(theta, a.lam) if a.closures == "paper"
               else open_library(a.closures))
        visc = a.viscosity
        if visc is not None and visc != "gray_edwards":
            visc = float(visc)
        res = compare_long_chute(lib, Path(a.long_chute) / "columns.nc",
                                 summ["depth_averages"]["rho_bar"], theta, model=a.model,
                                 viscosity=visc, n_ensemble=a.n_ensemble)
        if a.out:
            _json_write(a.out, res)
        if a.figure:
            plot_long_chute(res, a.figure, f"{a.model.replace('_', ' ')} ({a.closures} closures)")
        w = res["worst_err_after_quarter"]
        print("\n".join(_long_chute_lines(
            f"{a.long_chute}: {a.model} with {a.closures} closures (theta {theta:g}); worst "
            f"|error| after a quarter of the run: peak {w['peak']:.1%}, front {w['front']:.1%}",
            res)))
    elif a.cmd == "compare":
        res = compare_all(a.lib, a.campaign, a.switch_runs, a.long_chute, a.out, a.figures,
                          segregation_tracers=a.segregation_tracers)
        print(format_tables(res))
    return 0


def format_segregation_reference(r: dict) -> str:
    """:func:`compare_segregation_reference`'s result as table lines."""
    st = r["steady"]
    tr = r["transient"]
    lines = [f"{r['run']}: sigma {r['sigma']:g}, h {r['h']:.4g}, u_bar {r['u_bar']:.4g}, "
             f"t0 {r['t0']:.4g}, s0 {r['s0']:.4g}, plateau {r['plateau']:.4g}, "
             f"particle half-time {r['t_half']:.4g}"
             + (f" (plateau from a {r['plateau_source']}; tau ln 2 = {r['tau_ln2']:.4g}, "
                f"{100 * r['fraction_reached']:.0f} % of the way reached)"
                if "plateau_source" in r else ""),
             (f"D steady {st['D']:.4g} +- {st['D_stderr']:.2g} (c_D {st['c_D']:.4g} +- "
              f"{st['c_D_stderr']:.2g}; small {st['D_small']:.4g}, large {st['D_large']:.4g}), "
              if st else "no steady window; ")
             + f"D transient {r['D_transient']:.4g} +- {r['D_transient_stderr']:.2g} (small "
               f"{tr['D_small']:.4g}, large {tr['D_large']:.4g}; t {tr['t_from']:.4g}-"
               f"{tr['t_to']:.4g}); model D: {r['D_source']}; Ps {r['Ps']:.4g} ({r['Ps_status']}; "
               f"profile fit {r['Ps_profile_fit']:.4g})",
             f"{'model':<34} {'Ps':>7} {'D':>8} {'t_half':>8} {'err':>8} {'phi rms':>8}"]
    rows = [("symmetric", r["Ps"], r["D"]), ("asymmetric", r["Ps_asym"], r["D"]),
            ("symmetric_D_transient", r["Ps"], r["D_transient"]),
            ("asymmetric_D_transient", r["Ps_asym"], r["D_transient"])]
    rows += [(k, r[k]["Ps"], r["D"]) for k in r if k.startswith("law:")]
    for name, ps, d in rows:
        v = r[name]
        lines.append(f"{name:<34} {ps:7.4g} {d:8.4g} {v['t_half']:8.4g} "
                     f"{100 * v['err_t_half']:+7.1f}% {v['phi_rms_vs_particles']:8.4f}")
    if "transient_rates" in r:
        tr_ = r["transient_rates"]
        f, g = tr_["fit"], tr_["flux_regression"]
        lines.append(
            f"T-eq. (27) fitted to the transient phi(z, t) (t {f['t_from']:.4g}-{f['t_to']:.4g}, "
            f"{f['n_levels']} levels): S {f['S']:.4g} +- {f['S_stderr']:.2g}, D_r {f['D_r']:.4g} "
            f"+- {f['D_r_stderr']:.2g}, Ps = S h / D_r {f['Ps']:.4g} +- {f['Ps_stderr']:.2g} "
            f"(r2 {f['r2']:.3f}, of the change {f['r2_change']:.3f}, rms {f['rms']:.3g}); "
            f"D_r / D_self "
            f"{tr_['D_r_over_D_self']:.3g}, S / (Ps D / h) {tr_['S_over_model_S']:.3g}, "
            f"Ps / steady {tr_['Ps_transient_over_steady']:.3g}; its half-time "
            f"{tr_['model']['t_half']:.4g} ({100 * tr_['model']['err_t_half']:+.1f} %)")
        for key in ("fit_first", "fit_second"):
            h_ = tr_[key]
            if h_ is not None:
                lines.append(f"  {key} (t {h_['t_from']:.4g}-{h_['t_to']:.4g}): S {h_['S']:.4g} "
                             f"+- {h_['S_stderr']:.2g}, D_r {h_['D_r']:.4g} +- "
                             f"{h_['D_r_stderr']:.2g}, Ps {h_['Ps']:.4g} (r2 {h_['r2']:.3f}"
                             + ("" if h_["identified"] else
                                f"; unidentified: {', '.join(h_['unidentified'])}") + ")")
        lines.append(f"flux regression J = -c (S phi (1-phi) + D_r dphi/dz): S {g['S']:.4g} +- "
                     f"{g['S_stderr']:.2g}, D_r {g['D_r']:.4g} +- {g['D_r_stderr']:.2g} "
                     f"(r2 {g['r2']:.3f})")
        lines.append(f"{'t window':>13} {'z':>5} {'phi':>5} {'dphi/dz':>8} {'J/c particles':>19} "
                     f"{'steady model':>12} {'fitted':>9}")
        for row in tr_["levels"]:
            lines.append(f"{row['t_from']:6.0f}-{row['t_to']:<6.0f} {row['z']:5.1f} "
                         f"{row['phi']:5.2f} {row['dphi_dz']:+8.4f} {row['J_over_c']:+10.5f} +- "
                         f"{row['J_over_c_stderr']:.1e} {row['J_over_c_steady_model']:+12.5f} "
                         f"{row['J_over_c_fitted_model']:+9.5f}")
        fs = tr_["steady_model_from_measured_start"]
        lines.append(f"steady (Ps, D) model from the particles' own profile at t0: half-time "
                     f"{fs['t_half']:.4g} ({100 * fs['err_t_half']:+.1f} %)")
        if "measured_profiles" in tr_:
            mp = tr_["measured_profiles"]
            lines.append("local S(z) = -(J/c + D(z) dphi/dz) / (phi (1-phi)): " + ", ".join(
                f"z {p['z']:.0f}: {p['S']:.4f}" for p in mp["S_profile"]))
            lines.append(f"T-eq. (27) with that S(z) and the banded D(z): half-time "
                         f"{mp['t_half']:.4g} ({100 * mp['err_t_half']:+.1f} %), its steady "
                         f"state as T-eq. (28)'s Ps {mp['Ps_equivalent_steady']:.4g} (the run's "
                         f"profile: {mp['Ps_steady_measured']:.4g})")
        if "pressure_scaling" in tr_:
            ps_ = tr_["pressure_scaling"]
            lines.append("S(z) against the profiles' pressure p and shear rate: " + ", ".join(
                f"z {q['z']:.0f}: S p {q['S_p']:.3f}, S/gdot {q['S_over_gamma_dot']:.3f}"
                for q in ps_["levels"]))
            lines.append(f"  coefficient of variation over z >= {ps_['z_from']:g}: " + ", ".join(
                f"{k} {v:.2f}" for k, v in ps_["cv"].items()) + f" (best: {ps_['best']})")
        lines.append("D_self by starting height: " + ", ".join(
            f"{p['z_from']:.0f}-{p['z_to']:.0f}: {p['D']:.4f}" for p in tr_["D_profile"]))
        if "windows" in tr_:
            lines.append(f"{'t window':>13} {'s':>7} {'u_mean':>7} {'D_self':>7} {'S':>8} "
                         f"{'D_r':>8} {'Ps fit':>7} {'r2':>5} {'r2 chg':>6} "
                         f"{'Ps of profile':>13}")
            for w in tr_["windows"]["windows"]:
                f_ = w["fit"]
                lines.append(f"{w['t_from']:6.0f}-{w['t_to']:<6.0f} {w['s']:7.4f} "
                             f"{w['u_mean']:7.3f} {w['D']:7.4f} {f_['S']:8.5f} {f_['D_r']:8.5f} "
                             f"{f_['Ps']:7.3g} {f_['r2']:5.2f} {f_['r2_change']:6.2f} "
                             f"{w['Ps_profile']:13.3g}"
                             + ("" if f_["identified"] else
                                " (unidentified: " + ", ".join(f_["unidentified"]) + ")"))
    if "pressure_scaled" in r:
        q = r["pressure_scaled"]
        st_, tr2 = q["steady"], q["transient"]
        a, b = q["prediction"], q["prediction_transient_rates"]
        lines.append(f"S ~ 1 / p (S(z) = S_mid p_mid / p(z), p_mid {q['p_mid']:.3g}), bulk z >= "
                     f"{q['z_bulk']:g}: steady profile Ps_mid {st_['Ps_mid']:.4g} (rms "
                     f"{st_['rms']:.4f}; constant-rate T-eq. (28) Ps {st_['Ps_constant']:.4g}, rms "
                     f"{st_['rms_constant']:.4f}); fitted to the transient (t {tr2['t_from']:.4g}-"
                     f"{tr2['t_to']:.4g}): S_mid {tr2['S']:.4g} +- {tr2['S_stderr']:.2g} (A = S p "
                     f"{tr2['A']:.3g}), D_r {tr2['D_r']:.4g} +- {tr2['D_r_stderr']:.2g} "
                     f"({tr2['D_r_over_D_self']:.3g} x D_self), Ps_mid {tr2['Ps']:.4g} "
                     f"({tr2['Ps_over_steady']:.3g} x the steady profile's; r2 {tr2['r2']:.3f}, "
                     f"of the change {tr2['r2_change']:.3f})")
        lines.append(f"  bulk half-time: particles {q['t_half_particles']:.4g}; 1 / p model with "
                     f"the steady profile's Ps_mid and D_self {a['t_half']:.4g} "
                     f"({100 * a['err_t_half']:+.1f} %), with the transient's rates "
                     f"{b['t_half']:.4g} ({100 * b['err_t_half']:+.1f} %)")
        asy = q.get("asymmetric")
        if asy:
            lines.append("  asymmetric flux with 1 / p (kappa: steady Ps_mid / transient Ps_mid, "
                         "D_r / D_self): " + "; ".join(
                             f"{r['kappa']:.2f}: {r['Ps_mid_steady']:.3g} / "
                             f"{r['Ps_mid_transient']:.3g}, {r['D_r_over_D_self']:.2f}"
                             for r in asy["scan"]))
            ak = asy["at_kappa"]
            if ak:
                lines.append(f"  consistent at kappa {ak['kappa']:.3f}: Ps_mid "
                             f"{ak['Ps_mid_steady']:.4g} (steady rms {ak['rms_steady']:.4f}), D_r "
                             f"{ak['transient']['D_r']:.4g} = "
                             f"{ak['transient']['D_r_over_D_self']:.3g} x D_self; with D_self the "
                             f"bulk half-time {ak['prediction']['t_half']:.4g} "
                             f"({100 * ak['prediction']['err_t_half']:+.1f} %), with that D_r "
                             f"{ak['prediction_fitted_D_r']['t_half']:.4g} "
                             f"({100 * ak['prediction_fitted_D_r']['err_t_half']:+.1f} %)")
    if "Ps_matching_half_time" in r:
        lines.append(f"Ps that gives the particles' half-time (D transient): "
                     f"{r['Ps_matching_half_time']:.4g}")
    return "\n".join(lines)


def _long_chute_lines(title: str, lc: dict) -> list[str]:
    """A long-chute comparison as table lines (distances travelled, particles vs solver)."""
    lines = ["", title, f"{'t':>6} {'peak_p':>8} {'peak_s':>8} {'err':>7} {'front_p':>8} "
                        f"{'front_s':>8} {'err':>7} {'amp_p':>6} {'amp_s':>6}"]
    banded = "peak_travel_solver_lo" in lc["rows"][0] if lc["rows"] else False
    if banded:
        lines[-1] += f" {'peak_s 16-84 %':>15} {'front_s 16-84 %':>15}"
    for r in lc["rows"]:
        line = (f"{r['t']:6.1f} {r['peak_travel_particles']:8.2f} "
                f"{r['peak_travel_solver']:8.2f} {r['peak_err']:+7.1%} "
                f"{r['front_travel_particles']:8.2f} {r['front_travel_solver']:8.2f} "
                f"{r['front_err']:+7.1%} {r.get('amplitude_particles', math.nan):6.2f} "
                f"{r.get('amplitude_solver', math.nan):6.2f}")
        if banded:
            line += "".join(f" {r[f + '_travel_solver_lo']:7.2f}-{r[f + '_travel_solver_hi']:<7.2f}"
                            for f in ("peak", "front"))
        lines.append(line)
    band = lc.get("ensemble_band")
    if band and "worst_err_after_quarter_band" in band:
        w = band["worst_err_after_quarter_band"]
        lines.append(f"closure ensemble ({band['n_members']} members, "
                     f"{band['n_members_dropped']} dropped): worst error of the band's nearer "
                     f"edge after a quarter of the run: peak {w['peak']:.1%}, front "
                     f"{w['front']:.1%}")
    return lines


def format_tables(res: dict) -> str:
    """The comparison tables as plain text (the report's must-show tables)."""
    lines = ["closure status: " + ", ".join(f"{k} {'/'.join(v)}"
                                           for k, v in res["closure_status"].items()), "",
             "theta1 -> theta2 switches (particle run vs uniform-layer ODE and depth-resolved "
             "column)",
             f"{'H':>4} {'th1':>5} {'th2':>5} {'state':>9} {'u_part':>7} {'u_ODE':>13} {'err':>7}"
             f" {'tau_part':>12} {'tau_ODE':>12} {'err':>7} {'tau_column':>12} {'err':>7}"
             f" {'tau_dilation':>13} {'a0_part':>8} {'a0_ODE':>8}"]
    for s in res["switches"]:
        if "error" in s:
            lines.append(f"  {s['child']}: {s['error']}")
            continue
        lines.append(
            f"{s['H']:4g} {s['theta1']:5g} {s['theta2']:5g} {s['child_state']:>9} "
            f"{s['u_steady']:7.3f} {s['ode_u_steady']:6.3f}+-{s['ode_u_steady_std']:5.3f} "
            f"{s['err_u_steady']:+7.1%} {s.get('tau', math.nan):6.1f}+-{s.get('tau_stderr', math.nan):4.1f}"
            f" {s['ode_tau']:6.1f}+-{s['ode_tau_std']:4.1f} {s['err_tau']:+7.1%}"
            f" {s.get('column_tau', math.nan):6.1f}+-{s.get('column_tau_std', math.nan):4.1f}"
            f" {s.get('err_tau_column', math.nan):+7.1%}"
            f" {s.get('tau_dilation', math.nan):6.1f}+-{s.get('tau_dilation_stderr', math.nan):5.1f}"
            f" {s.get('accel0', math.nan):+8.4f} {s.get('ode_accel0', math.nan):+8.4f}"
            + ("  (extrapolated)" if s.get("extrapolated") else ""))
    lc = res.get("long_chute")
    if lc:
        lines += _long_chute_lines("long chute (distance travelled, particles vs solver)", lc)
    lv = res.get("long_chute_viscous")
    if lv and "error" in lv:
        lines += ["", f"long chute with the viscous stress: {lv['error']}"]
    elif lv:
        lines += _long_chute_lines(f"long chute with the Gray-Edwards viscous stress (nu = "
                                   f"{lv['viscosity']:.3f} at the mean depth "
                                   f"{lv['h_mean']:.2f})", lv)
    for key, title in (("long_chute_kinematic", "long chute, kinematic wave (local "
                                                "equilibrium u = u_s(h))"),
                       ("long_chute_diffusive", "long chute, diffusive wave (local equilibrium "
                                                "mu(h, F) = tan(theta) - K dh/dx)")):
        lk = res.get(key)
        if lk and "error" in lk:
            lines += ["", f"{title}: {lk['error']}"]
        elif lk:
            lines += _long_chute_lines(title, lk)
    lines += ["", "segregation (half-time after the start-up, final profile rms)",
              f"{'sigma':>5} {'t_half_p':>8} {'sym':>14} {'err':>7} {'asym':>14} {'err':>7} "
              f"{'rms_sym':>7} {'rms_asym':>8} {'D':>8} {'Ps':>6}"]
    for s in res["segregation"]:
        if "error" in s:
            lines.append(f"  {s['run']}: {s['error']}")
            continue
        a, b = s["symmetric"], s["asymmetric"]
        lines.append(f"{s['sigma']:5g} {s['t_half']:8.1f} {a['t_half']:7.1f}+-{a['t_half_std']:5.1f}"
                     f" {a['err_t_half']:+7.1%} {b['t_half']:7.1f}+-{b['t_half_std']:5.1f} "
                     f"{b['err_t_half']:+7.1%} {a['phi_rms_vs_particles']:7.3f} "
                     f"{b['phi_rms_vs_particles']:8.3f} {s['D']:8.4f} {s['Ps']:6.2f}")
    tr = [s for s in res["segregation"] if "error" not in s and "D_transient" in s]
    if tr:
        lines += ["", "segregation with D measured over each run's transient (t0 ... t0 + 2 "
                      "half-times)",
                  f"{'sigma':>5} {'D_trans':>15} {'D_closure':>9} {'ratio':>6} {'t_half_p':>8} "
                  f"{'sym':>14} {'err':>7} {'Ps':>6} {'Ps_match':>8}"]
        for s in tr:
            a = s["symmetric_D_transient"]
            lines.append(f"{s['sigma']:5g} {s['D_transient']:8.5f}+-{s['D_transient_stderr']:.5f}"
                         f" {s['D']:9.5f} {s['D_closure_over_transient']:6.2f} "
                         f"{s['t_half']:8.1f} {a['t_half']:7.1f}+-{a['t_half_std']:5.1f} "
                         f"{a['err_t_half']:+7.1%} {s['Ps']:6.2f} "
                         f"{s.get('Ps_matching_half_time', math.nan):8.2f}")
    rt = [s for s in tr if "transient_rates" in s]
    if rt:
        lines += ["", "T-eq. (27)'s rates fitted to each run's transient phi(z, t) (t0 ... t0 + 2 "
                      "half-times; first / second half: S of each)",
                  f"{'sigma':>5} {'S':>16} {'D_r':>16} {'Ps_fit':>7} {'Ps':>6} {'S/S_mod':>7} "
                  f"{'D_r/D':>6} {'r2':>5} {'S_1st':>7} {'S_2nd':>7}"]
        for s in rt:
            r = s["transient_rates"]
            f = r["fit"]
            halves = [r[k]["S"] if r.get(k) else math.nan for k in ("fit_first", "fit_second")]
            lines.append(f"{s['sigma']:5g} {f['S']:8.5f}+-{f['S_stderr']:.5f} "
                         f"{f['D_r']:8.5f}+-{f['D_r_stderr']:.5f} {f['Ps']:7.1f} {s['Ps']:6.2f} "
                         f"{r['S_over_model_S']:7.2f} {r['D_r_over_D_self']:6.2f} "
                         f"{f['r2']:5.2f} {halves[0]:7.4f} {halves[1]:7.4f}"
                         + ("" if f["identified"] else "  (unidentified)"))
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
