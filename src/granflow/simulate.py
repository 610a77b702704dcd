"""One chute job: parameter file -> validated configuration -> run -> atomic outputs.

This is the orchestration layer used by the command line (``granflow simulate``) and by the
Snakemake workflow.  It validates every parameter *before* any compute is spent (bad input names
the field and its allowed range), builds the chute of Weinhart et al. (2012) §5 (or loads a
prepared rough base), runs it with checkpoints (a killed job resumes where it stopped and ends
with the same numbers), and writes

* ``series.nc`` — the energy time series (E_kin, E_ela, E_grav, E_kin/E_ela, mean velocity) with
  CF attributes and provenance;
* ``profiles.nc`` — coarse-grained depth profiles (density, velocity, stress, species) averaged
  over the steady window only (or the last ``averaging_time`` of a run that is not steady);
* ``summary.json`` — flow state, steady-window start, depth averages (h, u_bar, F, alpha, K,
  rho_bar, rho_c with time-window spreads) and the parameters: one campaign-table row;
* ``final_state.npz`` — the complete final particle state (restartable).

Early stopping (issue 5): the run ends when the :class:`~granflow.steady.SteadyStateMonitor`
says it is arrested, clearly accelerating, or steady with ``averaging_time`` of data after the
steady onset; ``t_end`` is the hard cap.

Restart at a new inclination (``from_state``, ``granflow simulate run.yaml --from STATE``): the
run starts from a saved ``final_state.npz`` (positions, velocities, contact history) with the
gravity tilted to the new ``theta`` and the clock reset to t = 0 (the switch); the state must
belong to the same chute (box, particle count, collision time), and the outputs name the parent
run (``parent_state``, its sha256 and the parent's summary provenance).

All outputs are written atomically; the checkpoint is removed only after they exist.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from . import cfconventions
from . import units as U
from .engine.chute import BaseConfig, ChuteConfig, build_chute, prepare_rough_base
from .engine.run import ChuteRun
from .engine.system import ParticleSystem
from .engine.species import LAWS, REFERENCE, ContactSpecies, check_range
from .provenance import atomic_to_netcdf, atomic_write_bytes, provenance_attrs

log = logging.getLogger(__name__)

#: Every accepted key of a run parameter file, with its meaning (defaults: the paper's values).
PARAMETERS = {
    "theta": "inclination in degrees, (0, 90)",
    "H": "filling height (flow volume / (Lx Ly pi/6)), > 0",
    "lam": "base roughness lambda = base / flow particle diameter, [0, 10]; 0 = flat wall",
    "Lx": "box length downslope, > 0", "Ly": "box width, > 0",
    "seed": "random seed (base and flow insertion), integer >= 0",
    "t_end": "hard cap on the simulated time, > 0 (paper: 2000)",
    "contact_law": "linear | hertz | plastic (flow-flow and flow-base)",
    "t_c": "collision time, > 0 (paper 0.005)", "e": "restitution, (0, 1] (paper 0.88)",
    "mu_c": "contact friction, >= 0 (paper 0.5)",
    "kt_over_kn": "tangential/normal stiffness (paper 2/7)",
    "gt_over_gn": "tangential/normal damping (paper 1)",
    "v_ref": "Hertz reference impact velocity, > 0",
    "base_t_c": "flow-base collision time (default t_c)", "base_e": "flow-base restitution (default e)",
    "base_mu_c": "flow-base friction (default mu_c)",
    "steps_per_collision": "t_c / dt, >= 10 (paper 50)", "skin": "Verlet skin, > 0",
    "sigma": "size ratio d_small/d_large, (0, 1]", "phi0": "small-particle volume fraction, [0, 1]",
    "base_layers": "settled base thickness in lambda, [3, 100] (paper 12)",
    "sample_interval": "time between samples (default t_c/2)",
    "checkpoint_every_s": "wall-clock seconds between checkpoints",
    "early_stop": "stop when arrested / accelerating / steady long enough (default true)",
    "stop_when_flowing": "stop as soon as the run is decisively not arresting, flow state "
                         "'flowing' (hstop brackets; default false)",
    "averaging_time": "averaging time after the steady onset, > 0 (paper 100)",
    "check_every": "time between steady-state checks, > 0",
    "min_accelerating_time": "earliest time an accelerating stop is allowed (default t_end/4)",
    "cg_width": "coarse-graining width w, > 0 (paper 0.25)",
    "cg_dz": "z spacing of the depth profiles, > 0",
    "cg_window": "time-window length for profile spreads, > 0",
    "cg_every": "coarse-grain every n-th sample (default 1: every t_c/2)",
    "engine": "numba (default: granflow's DEM engine) | lammps (the same run by LAMMPS "
              "pair_style granular, granflow.lammps; linear and hertz laws, lam > 0)",
    "cg_base_line": "where a flow-base contact's stress goes: contact_then_down (default) | "
                    "down | through_contact (the paper's literal half-line; see "
                    "granflow.coarse.profiles.BASE_LINES)",
}


#: Engines that run a chute job (``engine`` parameter; absent = numba).
ENGINES = ("numba", "lammps")


def validate_params(params: dict) -> dict:
    """Check names and ranges of a run parameter mapping; return it with defaults filled in."""
    if not isinstance(params, dict):
        raise ValueError("run parameters must be a mapping of names to values")
    unknown = sorted(set(params) - set(PARAMETERS))
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}: allowed keys are {sorted(PARAMETERS)}")
    p = dict(theta=24.0, H=10.0, lam=1.0, Lx=20.0, Ly=10.0, seed=1, t_end=2000.0,
             contact_law="linear", t_c=REFERENCE["t_c"], e=REFERENCE["e"], mu_c=REFERENCE["mu_c"],
             kt_over_kn=REFERENCE["kt_over_kn"], gt_over_gn=REFERENCE["gt_over_gn"], v_ref=1.0,
             steps_per_collision=50.0, skin=0.2, sigma=1.0, phi0=1.0, base_layers=12.0,
             sample_interval=None, checkpoint_every_s=60.0, early_stop=True,
             averaging_time=100.0, check_every=10.0, min_accelerating_time=None, cg_width=0.25,
             cg_dz=0.05, cg_window=10.0, cg_every=1, cg_base_line="contact_then_down",
             stop_when_flowing=False)
    p.update(params)
    for key in ("base_t_c", "base_e", "base_mu_c"):
        p.setdefault(key, None)
    check_range("theta", p["theta"], 0.0, 90.0, lo_open=True, hi_open=True)
    check_range("H", p["H"], 0.0, 1e4, lo_open=True)
    check_range("lam", p["lam"], 0.0, 10.0)
    check_range("t_end", p["t_end"], 0.0, 1e7, lo_open=True)
    check_range("seed", p["seed"], 0, 2**63 - 1)
    if p["contact_law"] not in LAWS:
        raise ValueError(f"contact_law = {p['contact_law']!r} is unknown: allowed {sorted(LAWS)}")
    if p["sample_interval"] is not None:
        check_range("sample_interval", p["sample_interval"], 0.0, 1e6, lo_open=True)
    check_range("checkpoint_every_s", p["checkpoint_every_s"], 0.0, 1e7)
    check_range("averaging_time", p["averaging_time"], 0.0, 1e7, lo_open=True)
    check_range("check_every", p["check_every"], 0.0, 1e7, lo_open=True)
    if p["min_accelerating_time"] is not None:
        check_range("min_accelerating_time", p["min_accelerating_time"], 0.0, 1e7)
    check_range("cg_width", p["cg_width"], 0.0, 100.0, lo_open=True)
    check_range("cg_dz", p["cg_dz"], 0.0, 10.0, lo_open=True)
    check_range("cg_window", p["cg_window"], 0.0, 1e7, lo_open=True)
    check_range("cg_every", p["cg_every"], 1, 1e6)
    from .coarse.profiles import BASE_LINES
    if p["cg_base_line"] not in BASE_LINES:
        raise ValueError(f"cg_base_line = {p['cg_base_line']!r} is unknown: allowed "
                         f"{sorted(BASE_LINES)}")
    if not isinstance(p["stop_when_flowing"], bool):
        raise ValueError(f"stop_when_flowing = {p['stop_when_flowing']!r} must be true or false")
    if "engine" in p:
        if p["engine"] not in ENGINES:
            raise ValueError(f"engine = {p['engine']!r} is unknown: allowed {list(ENGINES)}")
        if p["engine"] == "lammps":
            from .lammps.species import check_supported

            check_supported(p["contact_law"], p["lam"])
    if not isinstance(p["early_stop"], bool):
        raise ValueError(f"early_stop = {p['early_stop']!r} must be true or false")
    cfg = chute_config(p)
    cfg.validate()
    BaseConfig(lam=p["lam"], Lx=p["Lx"], Ly=p["Ly"], base_layers=p["base_layers"]).validate()
    return p


def chute_config(p: dict) -> ChuteConfig:
    flow = ContactSpecies(t_c=p["t_c"], e=p["e"], kt_over_kn=p["kt_over_kn"],
                          gt_over_gn=p["gt_over_gn"], mu_c=p["mu_c"], law=p["contact_law"],
                          v_ref=p["v_ref"])
    base = ContactSpecies(
        t_c=p["base_t_c"] if p.get("base_t_c") is not None else p["t_c"],
        e=p["base_e"] if p.get("base_e") is not None else p["e"],
        kt_over_kn=p["kt_over_kn"], gt_over_gn=p["gt_over_gn"],
        mu_c=p["base_mu_c"] if p.get("base_mu_c") is not None else p["mu_c"],
        law=p["contact_law"], v_ref=p["v_ref"])
    return ChuteConfig(theta=p["theta"], H=p["H"], lam=p["lam"], Lx=p["Lx"], Ly=p["Ly"],
                       seed=int(p["seed"]), flow=flow, base=base,
                       steps_per_collision=p["steps_per_collision"], skin=p["skin"],
                       sigma=p["sigma"], phi0=p["phi0"])


def load_params(path) -> dict:
    """Read a YAML/JSON run parameter file and validate it."""
    import yaml

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"parameter file {os.fspath(path)!r} does not exist")
    with open(path) as fh:
        data = yaml.safe_load(fh) or {}
    return validate_params(data)


def set_threads(threads: int | None):
    """Pass the job's thread count to numba (Snakemake does not set NUMBA_NUM_THREADS)."""
    if threads is None:
        return
    import numba

    threads = int(check_range("threads", threads, 1, 1024))
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


def prepare_base_file(lam, Lx, Ly, seed, out, base_layers=12.0, settle_time=30.0):
    """Prepare a rough base and write its positions atomically to ``out`` (.npy)."""
    cfg = BaseConfig(lam=lam, Lx=Lx, Ly=Ly, seed=seed, base_layers=base_layers,
                     settle_time=settle_time).validate()
    pos = prepare_rough_base(cfg)
    import io

    buf = io.BytesIO()
    np.save(buf, pos)
    atomic_write_bytes(out, buf.getvalue())
    return pos


def series_dataset(arrays: dict, attrs: dict):
    """xarray Dataset of a run's time series with CF attributes (attached last)."""
    import xarray as xr

    t = arrays["time"]
    ratio = np.divide(arrays["e_kin"], arrays["e_ela"], out=np.full_like(t, np.inf),
                      where=arrays["e_ela"] > 0)
    # the coordinate is ``t``, not ``time``: CF tools take a variable named time for a calendar
    # time axis ("<unit> since <epoch>"), which a nondimensional simulated time is not
    ds = xr.Dataset(
        {
            "e_kin": ("t", arrays["e_kin"]),
            "e_ela": ("t", arrays["e_ela"]),
            "e_grav": ("t", arrays["e_grav"]),
            "energy_ratio": ("t", ratio),
            "u_mean": ("t", arrays["u_mean"]),
        },
        coords={"t": t},
    )
    ds["t"].attrs = U.cf(U.TIME, "simulated time t (not a calendar time)")
    ds["e_kin"].attrs = U.cf(U.ENERGY, "kinetic energy (translational + rotational) of the flow")
    ds["e_ela"].attrs = U.cf(U.ENERGY, "elastic energy stored in contacts")
    ds["e_grav"].attrs = U.cf(U.ENERGY, "slope-normal gravitational energy sum m g cos(theta) z")
    ds["energy_ratio"].attrs = U.cf(U.DIMENSIONLESS, "ratio of kinetic to elastic energy")
    ds["u_mean"].attrs = U.cf(U.VELOCITY, "mean downslope velocity of the flow particles")
    ds.attrs.update(attrs)
    return ds


def _observers(p: dict, cfg: ChuteConfig, series, min_onset: float = 0.0):
    d_flow, species = cfg.flow_particles()
    n_species = int(species.max()) + 1 if len(species) else 1
    return build_observers(p, n_species, float(d_flow.max(initial=1.0)), series, min_onset)


def build_observers(p: dict, n_species: int, d_max: float, series, min_onset: float = 0.0,
                    t_cap: float | None = None):
    """The run's coarse-graining and steady-state observers (one set for every engine and for
    the ingest of dumps): a :class:`ProfileObserver` on the depth grid and a
    :class:`MonitorObserver` on ``series``, configured from the run parameters ``p``."""
    from .coarse import DepthProfileAccumulator
    from .observers import MonitorObserver, ProfileObserver
    from .steady.monitor import SteadyStateMonitor

    # depth grid: from below the base to well above a dilated flow (saltating grains above the
    # grid top are simply not counted in the profiles)
    z_top = 2.0 * p["H"] + 10.0 * d_max
    acc = DepthProfileAccumulator(-2.0 * max(p["lam"], 1.0), z_top, p["cg_dz"], width=p["cg_width"],
                                  Lx=p["Lx"], Ly=p["Ly"], n_species=n_species,
                                  window_length=p["cg_window"], base_line=p["cg_base_line"])
    profile_obs = ProfileObserver(acc, every=int(p["cg_every"]))
    monitor = SteadyStateMonitor(t_cap=p["t_end"] if t_cap is None else t_cap,
                                 averaging_time=p["averaging_time"],
                                 check_every=p["check_every"],
                                 min_accelerating_time=p["min_accelerating_time"],
                                 min_onset=min_onset, stop_when_flowing=p["stop_when_flowing"])
    return profile_obs, MonitorObserver(monitor, series)


def startup_time(system, theta_deg: float) -> float:
    """Twice the free-fall time of the inserted column onto the base: sqrt(2 dz / (g cos theta))
    with dz the height of the highest flow particle above the highest base particle (above z = 0
    on a flat wall).  The insertion fall, the landing and its rebound lie before it, so the steady
    onset is searched after it (statistical equilibration detection alone was seen to keep the
    fall: its short spike lowers the estimated correlation time of the whole series)."""
    flow = ~system.fixed
    if not flow.any():
        return 0.0
    z_base = float(system.pos[system.fixed, 2].max()) if system.fixed.any() else 0.0
    dz = max(float(system.pos[flow, 2].max()) - z_base, 0.0)
    return 2.0 * math.sqrt(2.0 * dz / math.cos(math.radians(theta_deg)))


def restart_state(state_file, cfg: ChuteConfig):
    """The particle system of a saved state, tilted to ``cfg.theta`` with the clock at t = 0,
    and the parent's provenance.  Raises ValueError if the state is not of this chute (box,
    flow-particle count, time step) -- checked before any compute."""
    import hashlib
    import json

    state_file = Path(state_file)
    system, _ = ParticleSystem.load(state_file)
    n_flow = int((~system.fixed).sum())
    n_expected = len(cfg.flow_particles()[0])
    problems = []
    if abs(system.Lx - cfg.Lx) > 1e-9 or abs(system.Ly - cfg.Ly) > 1e-9:
        problems.append(f"box {system.Lx:g} x {system.Ly:g} (run file: {cfg.Lx:g} x {cfg.Ly:g})")
    if n_flow != n_expected:
        problems.append(f"{n_flow} flow particles (run file H = {cfg.H:g}, sigma, phi0 give "
                        f"{n_expected})")
    dt = cfg.flow.t_c / cfg.steps_per_collision
    if abs(system.dt - dt) > 1e-12 * dt:
        problems.append(f"time step {system.dt:g} (run file t_c / steps_per_collision = {dt:g})")
    if problems:
        raise ValueError(f"--from {os.fspath(state_file)!r} is not a state of this chute: "
                         + "; ".join(problems))
    g_new = np.asarray(cfg.gravity, dtype=np.float64)
    mobile = ~system.fixed
    # the stored forces hold m g of the old inclination: swap it for the new one (contacts and
    # their history are kept; the first half kick then uses the new gravity)
    system.force[mobile] += system.mass[mobile, None] * (g_new - system.gvec)[None, :]
    system.gvec = g_new
    parent_time = float(system.time)
    system.time = 0.0
    system.step_count = 0
    parent = {"parent_state": os.fspath(state_file.resolve()),
              "parent_state_sha256": hashlib.sha256(state_file.read_bytes()).hexdigest(),
              "parent_time": parent_time}
    summary = state_file.parent / "summary.json"
    if summary.exists():
        ps = json.loads(summary.read_text())
        parent.update(parent_theta=ps.get("params", {}).get("theta"),
                      parent_flow_state=ps.get("flow_state"),
                      parent_git_commit=ps.get("provenance", {}).get("git_commit"),
                      parent_config_hash=ps.get("provenance", {}).get("config_hash"))
    return system, {k: v for k, v in parent.items() if v is not None}


def simulate(params: dict, out_dir, base_file=None, threads: int | None = 1,
             progress=None, extra_observers=(), from_state=None) -> dict:
    """Run one chute job into ``out_dir`` (resuming from its checkpoint if there is one).

    ``extra_observers`` (each with a unique ``name``) are sampled and checkpointed with the
    run, after the built-in ones (e.g. a second :class:`~granflow.observers.ProfileObserver`
    with another coarse-graining choice).  ``from_state``: start from this saved state at the
    inclination of ``params`` (:func:`restart_state`; ``base_file`` is not used).  Returns a
    summary dict (flow state, stop reason, final time, particle count, wall time, and the
    ChuteRun under ``run``).
    """
    import json
    import time as _time

    from .coarse.derived import depth_average_summary

    p = validate_params(params)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    set_threads(threads)
    cfg = chute_config(p)
    engine = p.get("engine", "numba")
    ckpt = out_dir / "checkpoint.npz"
    wall0 = _time.monotonic()
    parent = {}
    if from_state is not None:  # checked before any compute, also when resuming
        if engine != "numba":
            raise ValueError(f"engine: a restart from a saved state (--from) needs the numba "
                             f"engine, not {engine!r}")
        system, parent = restart_state(from_state, cfg)
    if ckpt.exists() and engine == "numba":  # resume: the run restores system and observers
        system, _ = ParticleSystem.load(ckpt)
    elif from_state is None:  # a fresh run: build the chute (a restart has its system already)
        if base_file is not None:
            base_file = Path(base_file)
            if not base_file.exists():
                raise FileNotFoundError(f"base file {os.fspath(base_file)!r} does not exist")
            base = np.load(base_file)
            if base.ndim != 2 or base.shape[1] != 3:
                raise ValueError(f"base file {os.fspath(base_file)!r} does not hold an (M, 3) position array")
        else:
            base = prepare_rough_base(BaseConfig(lam=p["lam"], Lx=p["Lx"], Ly=p["Ly"],
                                                 seed=int(p["seed"]), base_layers=p["base_layers"]))
        system = build_chute(cfg, base_positions=base)
    sample_every = None
    if p["sample_interval"] is not None:
        sample_every = max(1, int(round(p["sample_interval"] / (cfg.flow.t_c / cfg.steps_per_collision))))
    lammps = None
    if engine == "lammps":
        # the same particles, species and sampling, run by LAMMPS (granflow.lammps); its
        # snapshots feed the same observers through ChuteRun; no checkpoints
        from .lammps.runner import LammpsChute

        if sample_every is None:  # ChuteRun's default: t_c / 2
            sample_every = max(1, int(round(0.5 * system.interactions.min_collision_time()
                                            / system.dt)))
        n_total = int(round(p["t_end"] / system.dt))
        n_steps = -(-n_total // sample_every) * sample_every  # whole sample intervals
        lammps = LammpsChute(system, cfg, out_dir / "lammps", n_steps, sample_every,
                             ranks=threads or 1)
        run = ChuteRun(lammps, t_end=n_steps * system.dt, sample_every=sample_every,
                       checkpoint=None, progress=progress)
    else:
        run = ChuteRun(system, t_end=p["t_end"], sample_every=sample_every, checkpoint=ckpt,
                       checkpoint_every_s=p["checkpoint_every_s"], progress=progress)
    # a resumed run restores its monitor (and this value) from the checkpoint
    min_onset = (startup_time(system, p["theta"]) if system.time == 0.0 and from_state is None
                 else 0.0)
    profile_obs, monitor_obs = _observers(p, cfg, run.series, min_onset)
    run.observers.append(profile_obs)
    if p["early_stop"]:
        run.observers.append(monitor_obs)
    else:
        monitor_obs.name = "monitor_passive"  # still fed (for the final classification)
        monitor_obs.should_stop = lambda system: (False, "")
        run.observers.append(monitor_obs)
    seg_obs = None
    if cfg.bidisperse:  # hold steady runs until the segregated state is steady too (seed 002 §6)
        from .observers import SegregationObserver
        from .steady.segregation import SegregationMonitor
        seg_obs = SegregationObserver(
            SegregationMonitor(averaging_time=p["averaging_time"], check_every=p["check_every"],
                               min_onset=monitor_obs.monitor.min_onset),
            small_type=0, energy=monitor_obs if p["early_stop"] else None)
        run.observers.append(seg_obs)
    run.observers.extend(extra_observers)
    extra_attrs = {}
    if lammps is None:
        run.try_resume()
        run.run()
    else:
        try:
            lammps.start()
            run.run()
        finally:
            lammps.close()
        extra_attrs = lammps_attrs(lammps)
    out = write_outputs(p, out_dir, run, monitor_obs, profile_obs, seg_obs, extra_attrs,
                        parent=parent)
    if ckpt.exists():
        ckpt.unlink()
    return dict(out, wall_s=_time.monotonic() - wall0, run=run)


def lammps_attrs(lammps) -> dict:
    """Provenance of a LAMMPS-engine run (stored in every output and the summary)."""
    return {"engine": "lammps", "lammps_ranks": int(lammps.ranks),
            "lammps_input": os.fspath(lammps.folder / "in.granflow"),
            "lammps_max_overlap": float(lammps.max_overlap_seen)}


def write_outputs(p: dict, out_dir, run, monitor_obs, profile_obs, seg_obs=None,
                  extra_attrs=None, parent=None) -> dict:
    """Classify the run and write series.nc, profiles.nc, final_state.npz and summary.json.

    ``run`` offers ``system`` (``time``, ``fixed``, ``dt``, ``save(path)``; ``save`` may be
    None: no final state), ``stop_reason`` and ``series.arrays()``; the observers are the
    run's (any engine, or an ingest of dumps); ``parent``: the restart provenance of
    :func:`restart_state`.  Returns the summary (plus ``profiles``).
    """
    import json

    from .coarse.derived import depth_average_summary

    out_dir = Path(out_dir)
    final = monitor_obs.final()
    seg = seg_obs.final() if seg_obs is not None else None
    t_now = run.system.time
    if final["flow_state"] in ("steady", "layered") and math.isfinite(final["steady_start"]):
        t_from = final["steady_start"]
        if seg is not None:
            both = seg_obs.steady_start(final["steady_start"])
            # steady in energy and segregation: average from the later onset; a segregated state
            # still drifting at the end: the last averaging_time (flagged in the summary)
            t_from = both if both is not None else max(t_from, t_now - p["averaging_time"])
    else:
        t_from = max(0.0, t_now - p["averaging_time"])
    attrs = provenance_attrs(config=p, **{k: v for k, v in p.items() if v is not None})
    parent = dict(parent or {})
    attrs.update(parent)
    attrs.update(stop_reason=run.stop_reason, n_flow=int((~run.system.fixed).sum()),
                 n_base=int(run.system.fixed.sum()), dt=run.system.dt, t_final=t_now,
                 flow_state=final["flow_state"], steady_start=final["steady_start"],
                 state_confidence=final["confidence"], classification=final["explanation"],
                 classification_statistics=final["statistics_json"], profile_time_from=t_from,
                 steady_min_onset=monitor_obs.monitor.min_onset)
    attrs.update(extra_attrs or {})
    if seg is not None:
        attrs.update(segregation_state="steady" if seg["steady"] else "drifting",
                     segregation_onset=seg["onset"], segregation_explanation=seg["message"])
    ds = series_dataset(run.series.arrays(), attrs)
    if seg is not None:
        ds = ds.assign_coords(segregation_time=("segregation_time", seg["time"]))
        ds["segregation_indicator"] = ("segregation_time", seg["value"])
        ds["segregation_time"].attrs = U.cf(U.TIME, "simulated time (bins of the segregation monitor)")
        ds["segregation_indicator"].attrs = U.cf(
            U.LENGTH, "small-particle centre of mass height minus that of all flow particles")
    profiles = profile_obs.dataset(t_from=t_from, attrs=attrs)
    try:
        averages = depth_average_summary(profiles, theta_deg=p["theta"])
    except Exception as exc:  # e.g. a run with no material in the grid: keep the failure visible
        log.warning("depth averages failed: %s", exc)
        averages = {"error": str(exc)}
    summary = {
        "run_dir": os.fspath(out_dir), "flow_state": final["flow_state"],
        "steady_start": final["steady_start"], "state_confidence": final["confidence"],
        "classification": final["explanation"], "stop_reason": run.stop_reason,
        "t_final": t_now, "profile_time_from": t_from, "n_flow": attrs["n_flow"],
        "params": {k: v for k, v in p.items() if v is not None},
        "depth_averages": averages,
        "segregation": None if seg is None else {
            k: v for k, v in seg.items() if k not in ("time", "value")},
        "provenance": {k: attrs[k] for k in ("granflow_version", "git_commit", "config_hash")},
    }
    if parent:
        summary["parent"] = dict(parent)
    if extra_attrs:
        summary["engine"] = dict(extra_attrs)
    where = f"theta = {p['theta']:g} deg, H = {p['H']:g}, lambda = {p['lam']:g}" + (
        f", sigma = {p['sigma']:g}, phi0 = {p['phi0']:g}" if p.get("phi0", 1.0) < 1 else "")
    engine = (extra_attrs or {}).get("engine", "numba")
    source = "" if engine == "numba" else f" ({engine})"
    if engine != "numba":
        from . import __version__

        for d in (ds, profiles):  # kept by cfconventions.apply (it sets only missing ones)
            d.attrs["source"] = (f"granflow {__version__} coarse-graining of a {engine} "
                                 "discrete particle simulation")
    cfconventions.apply(
        ds, kind="series", config=p, title=f"granflow chute run time series ({where})",
        summary=("Energy time series of one periodic-chute discrete particle simulation "
                 f"({where}){source} and its flow-state classification ({final['flow_state']}; "
                 "Weinhart et al. 2012 §6)" + ("; small-particle segregation indicator"
                                               if seg is not None else "") + "."))
    cfconventions.apply(
        profiles, kind="profiles", config=p, title=f"granflow chute run depth profiles ({where})",
        summary=("Coarse-grained depth profiles (density, velocity, stress tensor with contact, "
                 "kinetic and base-contact parts; Weinhart et al. 2012 §3) of one periodic-chute "
                 f"discrete particle simulation ({where}){source}, averaged from t = {t_from:g}, "
                 "with per-time-window values for spreads."))
    atomic_to_netcdf(ds, out_dir / "series.nc")
    atomic_to_netcdf(profiles, out_dir / "profiles.nc")
    save = getattr(run.system, "save", None)
    if save is not None:
        save(out_dir / "final_state.npz")
    atomic_write_bytes(out_dir / "summary.json",
                       json.dumps(_finite_or_none(summary), indent=2, default=_json_default,
                                  allow_nan=False).encode())
    log.info("%s: %s", out_dir, final["explanation"])
    return dict(summary, profiles=profiles)


def _finite_or_none(obj):
    """Replace NaN/inf floats by None so that summary.json is strict JSON (null)."""
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_none(v) for v in obj]
    if isinstance(obj, (float, np.floating)) and not math.isfinite(float(obj)):
        return None
    return obj


def _json_default(x):
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)
