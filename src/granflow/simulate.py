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

Engine guards (the numba engine's overlap and non-finite checks, :class:`SimulationError`): a run
whose contacts leave the range its species was validated for (an overlap above ``max_overlap``,
by default 5 %, of the smallest diameter: too soft for the load, e.g. a fast flow on a base of
half-size particles) is
not a result.  It ends there with its outputs written and flow state ``undecided`` (left out of
every fit, listed in ``excluded_runs.csv``), ``engine_stop`` naming the guard, what the
classifier said until then in the explanation and in ``flow_state_before_engine_stop``, instead
of failing the whole campaign.  For an hstop bracket it is flowing only if the classifier had
seen it flow (steady, accelerating, ...) before the stop; a run stopped before it had any flow
state (an impact while the layer falls in) is no evidence either way: the hstop fit leaves it
out and a bisection chain stops at it (:data:`granflow.campaign.collect.ENGINE_STOP_NO_STATE`).  Rerunning the same command resumes from the checkpoint and stops identically.

All outputs are written atomically; the checkpoint is removed only after they exist.  A
checkpoint stores the run's identity (:func:`run_identity`: every parameter but those of
:data:`RESUME_FREE_PARAMETERS`, the base file's and the parent state's SHA-256); one written by
a run of other physics is moved aside and the run starts afresh (:func:`keep_matching_checkpoint`).
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from . import cfconventions
from . import units as U
from .engine.chute import (DEFAULT_INSERTION_GROWTH, BaseConfig, ChuteConfig, build_chute,
                           prepare_rough_base, top_up_flow)
from .engine.run import ChuteRun, cpu_seconds
from .engine.system import ParticleSystem, SimulationError
from .engine.species import LAWS, REFERENCE, ContactSpecies, check_range
from .provenance import (atomic_to_netcdf, atomic_write_bytes, provenance_attrs,
                         remove_stale_temporaries)
from .steady.classify import layered_state

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
    "insertion_growth": ("height added to the flow's insertion domain per rejected trial, "
                         "(0, 10] (default 0.01, the paper's text; MercuryDPM's code: 5e-5)"),
    "sigma": "size ratio d_small/d_large, (0, 1]", "phi0": "small-particle volume fraction, [0, 1]",
    "initial_mixing": ("how a mixture starts: mixed (default: one random insertion order) | "
                       "segregated (small particles below, large above: the steady segregated "
                       "state approached from above) | profile (stratified as T-eq. 28's steady "
                       "profile at initial_Ps: approached from that side)"),
    "initial_Ps": ("Peclet number of a 'profile' start's T-eq. 28 profile, (0, 1000]; only with "
                   "initial_mixing = profile (absent otherwise)"),
    "base_layers": "settled base thickness in lambda, [3, 100] (paper 12)",
    "sample_interval": "time between samples (default t_c/2)",
    "checkpoint_every_s": "wall-clock seconds between checkpoints",
    "early_stop": "stop when arrested / accelerating / steady long enough (default true)",
    "stop_when_flowing": "stop as soon as the run is decisively not arresting, flow state "
                         "'flowing' (hstop brackets; default false)",
    "averaging_time": "averaging time after the steady onset, > 0 (paper 100)",
    "check_every": "time between steady-state checks, > 0",
    "min_accelerating_time": "earliest time an accelerating stop is allowed (default t_end/4)",
    "max_overlap": ("engine guard: the largest contact overlap allowed, as a fraction of the "
                    "smallest diameter, (0, 0.5] (default 0.05; numba engine)"),
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


#: Allowed interval of every numeric parameter: (low, high, low open, high open).  Checked
#: here, independently of the engine's own checks, so that a bad value is always refused with
#: the parameter's name and this interval, before any compute.
RANGES = {
    "theta": (0.0, 90.0, True, True), "H": (0.0, 1e4, True, False), "lam": (0.0, 10.0, False, False),
    "Lx": (0.0, 1e4, True, False), "Ly": (0.0, 1e4, True, False), "seed": (0, 2**63 - 1, False, False),
    "t_end": (0.0, 1e7, True, False), "t_c": (0.0, 1.0, True, False), "e": (0.0, 1.0, True, False),
    "mu_c": (0.0, math.inf, False, False), "kt_over_kn": (0.0, 10.0, False, False),
    "gt_over_gn": (0.0, 10.0, False, False), "v_ref": (0.0, 1e3, True, False),
    "base_t_c": (0.0, 1.0, True, False), "base_e": (0.0, 1.0, True, False),
    "base_mu_c": (0.0, math.inf, False, False), "steps_per_collision": (10.0, 1e6, False, False),
    "skin": (0.0, 10.0, True, False), "sigma": (0.0, 1.0, True, False), "phi0": (0.0, 1.0, False, False),
    "insertion_growth": (0.0, 10.0, True, False), "initial_Ps": (0.0, 1e3, True, False),
    "base_layers": (3.0, 100.0, False, False), "sample_interval": (0.0, 1e6, True, False),
    "checkpoint_every_s": (0.0, 1e7, False, False), "averaging_time": (0.0, 1e7, True, False),
    "check_every": (0.0, 1e7, True, False), "min_accelerating_time": (0.0, 1e7, False, False),
    "max_overlap": (0.0, 0.5, True, False),
    "cg_width": (0.0, 100.0, True, False), "cg_dz": (0.0, 10.0, True, False),
    "cg_window": (0.0, 1e7, True, False), "cg_every": (1, 10**6, False, False),
}
#: parameters that must be integers, true/false, or one of a few names
INTEGER_PARAMETERS = ("seed", "cg_every")
BOOLEAN_PARAMETERS = ("early_stop", "stop_when_flowing")
CHOICE_PARAMETERS = ("contact_law", "cg_base_line", "initial_mixing")
#: parameters that may be null (their default is derived from others)
OPTIONAL_PARAMETERS = ("sample_interval", "min_accelerating_time", "base_t_c", "base_e", "base_mu_c",
                       "max_overlap")
#: parameters that stay absent from a run's parameters unless the run file gives them
ABSENT_UNLESS_GIVEN = ("engine", "initial_Ps")
#: most time steps a run may take (t_end / dt): 500 times the paper's protocol (2e7 steps)
MAX_STEPS = 1e10


def _interval(key) -> str:
    lo, hi, lo_open, hi_open = RANGES[key]
    return f"{'(' if lo_open else '['}{lo}, {hi}{')' if hi_open or hi == math.inf else ']'}"


def _check_value(key, value):
    """Type and range of one parameter; returns the value (ints as int)."""
    if key in BOOLEAN_PARAMETERS:
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{key} = {value!r} must be true or false")
        return bool(value)
    if key in CHOICE_PARAMETERS:
        from .coarse.profiles import BASE_LINES

        from .engine.chute import INITIAL_MIXINGS

        allowed = {"contact_law": sorted(LAWS), "cg_base_line": sorted(BASE_LINES),
                   "initial_mixing": list(INITIAL_MIXINGS)}[key]
        if not isinstance(value, str) or value not in allowed:
            raise ValueError(f"{key} = {value!r} is unknown: allowed {allowed}")
        return value
    if value is None and key in OPTIONAL_PARAMETERS:
        return None
    what = "an integer" if key in INTEGER_PARAMETERS else "a number"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
        raise ValueError(f"{key} = {value!r} must be {what} in {_interval(key)}"
                         + (" or null" if key in OPTIONAL_PARAMETERS else ""))
    v = float(value)
    lo, hi, lo_open, hi_open = RANGES[key]
    if (math.isnan(v) or v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi)
            or (math.isinf(v) and hi != math.inf)):
        raise ValueError(f"{key} = {value!r} is out of range: allowed {_interval(key)}")
    if key in INTEGER_PARAMETERS:
        if not v.is_integer():
            raise ValueError(f"{key} = {value!r} must be an integer in {_interval(key)}")
        return int(value)
    return float(value) if isinstance(value, (np.integer, np.floating)) else value


def validate_params(params: dict, *, check_machine: bool = True) -> dict:
    """Check names, types and ranges of a run parameter mapping and the size of the run it
    describes; return it with defaults filled in.

    Every problem raises ValueError naming the parameter and its allowed range, before any
    compute.  The run's memory and disk needs are estimated (:func:`estimate_run_size`); a run
    of more than :data:`MAX_STEPS` time steps is refused, and with ``check_machine`` one whose
    memory estimate exceeds this machine's memory (:func:`machine_memory`) too.
    """
    if not isinstance(params, dict):
        raise ValueError(f"run parameters must be a mapping of names to values, not "
                         f"{type(params).__name__}")
    unknown = sorted((k for k in params if k not in PARAMETERS), key=repr)
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}: allowed keys are {sorted(PARAMETERS)}")
    p = dict(theta=24.0, H=10.0, lam=1.0, Lx=20.0, Ly=10.0, seed=1, t_end=2000.0,
             contact_law="linear", t_c=REFERENCE["t_c"], e=REFERENCE["e"], mu_c=REFERENCE["mu_c"],
             kt_over_kn=REFERENCE["kt_over_kn"], gt_over_gn=REFERENCE["gt_over_gn"], v_ref=1.0,
             steps_per_collision=50.0, skin=0.2, sigma=1.0, phi0=1.0, initial_mixing="mixed",
             base_layers=12.0,
             insertion_growth=DEFAULT_INSERTION_GROWTH,
             sample_interval=None, checkpoint_every_s=60.0, early_stop=True,
             averaging_time=100.0, check_every=10.0, min_accelerating_time=None, max_overlap=None,
             cg_width=0.25,
             cg_dz=0.05, cg_window=10.0, cg_every=1, cg_base_line="contact_then_down",
             stop_when_flowing=False)
    p.update(params)
    for key in ("base_t_c", "base_e", "base_mu_c"):
        p.setdefault(key, None)
    for key in PARAMETERS:
        # engine and initial_Ps are absent unless given (older runs' parameters, and so their
        # checkpoints' identity, unchanged)
        if key not in ABSENT_UNLESS_GIVEN:
            p[key] = _check_value(key, p[key])
        elif key in p and key != "engine":
            p[key] = _check_value(key, p[key])
    if p["initial_mixing"] == "profile" and "initial_Ps" not in p:
        raise ValueError("initial_mixing = 'profile' needs initial_Ps, the Peclet number of its "
                         f"T-eq. 28 profile: allowed {_interval('initial_Ps')}")
    if "engine" in p:
        if not isinstance(p["engine"], str) or p["engine"] not in ENGINES:
            raise ValueError(f"engine = {p['engine']!r} is unknown: allowed {list(ENGINES)}")
        if p["engine"] == "lammps":
            from .lammps.species import check_supported

            check_supported(p["contact_law"], p["lam"])
    if p["contact_law"] == "plastic":
        for key in ("e", "base_e"):
            if p[key] is not None and p[key] >= 1.0:
                raise ValueError(f"{key} = {p[key]!r} is out of range for the plastic law: "
                                 "allowed (0, 1)")
    cfg = chute_config(p)
    cfg.validate()
    BaseConfig(lam=p["lam"], Lx=p["Lx"], Ly=p["Ly"], base_layers=p["base_layers"]).validate()
    d_large = 1.0 / p["sigma"] if p["phi0"] < 1.0 else 1.0
    if min(p["Lx"], p["Ly"]) < d_large:
        raise ValueError(f"Lx, Ly = {p['Lx']:g}, {p['Ly']:g} is smaller than a large particle "
                         f"(diameter 1/sigma = {d_large:g}): allowed Lx, Ly >= 1/sigma")
    n_small, n_large = flow_particle_counts(p)
    if n_small + n_large < 1:
        raise ValueError(f"H = {p['H']!r} puts no flow particle into the {p['Lx']:g} x "
                         f"{p['Ly']:g} box (N = H Lx Ly rounds to 0): allowed H >= "
                         f"{0.5 / (p['Lx'] * p['Ly']):.3g}")
    size = estimate_run_size(p)
    if size["n_steps"] > MAX_STEPS:
        raise ValueError(
            f"t_end = {p['t_end']:g} is {size['n_steps']:.3g} time steps of dt = t_c / "
            f"steps_per_collision = {size['dt']:.3g}: allowed at most {MAX_STEPS:.0e} steps "
            f"(t_end <= {MAX_STEPS * size['dt']:.3g}; or a larger t_c, fewer steps_per_collision)")
    if check_machine:
        limit = machine_memory()
        if size["memory_bytes"] > limit:
            raise ValueError(
                f"run too large for this machine: it needs about {_fmt_bytes(size['memory_bytes'])}"
                f" of memory ({size['explanation']}), the machine has {_fmt_bytes(limit)}; "
                "allowed: a run whose estimate fits, i.e. fewer particles (H, Lx, Ly, a larger lam: "
                f"{size['n_particles']:.3g} now), fewer samples (t_end / sample_interval: "
                f"{size['n_samples']:.3g} now) or a coarser profile grid (cg_dz, cg_window: "
                f"{size['n_profile_values']:.3g} stored values now)")
    return p


def flow_particle_counts(p: dict) -> tuple[int, int]:
    """Numbers of small (species 0) and large flow particles of a run, as the chute set-up
    (:meth:`~granflow.engine.chute.ChuteConfig.flow_particles`) makes them, without making them
    (floats: an absurd size must not overflow)."""
    area = p["Lx"] * p["Ly"]
    if p["phi0"] >= 1.0:
        return float(round(p["H"] * area)), 0.0
    v_total = p["H"] * area * math.pi / 6.0
    d_l = 1.0 / p["sigma"]
    return (float(round(p["phi0"] * v_total / (math.pi / 6))),
            float(round((1 - p["phi0"]) * v_total / (math.pi / 6 * d_l**3))))


#: Coefficients of the memory estimate (bytes), measured against the peak resident memory of
#: real runs (tests/test_robustness_size.py): the interpreter with numpy, numba, scipy and
#: xarray loaded; per particle (positions, velocities, forces, wall history, cell lists); per
#: neighbour pair (indices, tangential history, per-pair output); per stored sample of the
#: time series (Python lists of the energy series, monitors); per stored profile value.
MEMORY_BASELINE = 400e6
BYTES_PER_PARTICLE = 1000.0
PAIRS_PER_PARTICLE = 40.0
BYTES_PER_PAIR = 2 * 19 * 8.0
BYTES_PER_SAMPLE = 400.0
BYTES_PER_PROFILE_VALUE = 3 * 8.0


def estimate_run_size(p: dict) -> dict:
    """Memory (peak resident, bytes) and output size (bytes) a run will need, from validated
    parameters: particles from H, Lx, Ly, sigma, phi0 and lambda (flow, base band and the base
    preparation fill); neighbour pairs (~40 per particle); samples of the time series
    (t_end / sample_interval); and the coarse-graining grid (depth bins x columns x time
    windows).  All in floats, so that an absurd size gives a huge number, not an overflow."""
    n_small, n_large = flow_particle_counts(p)
    n_flow = n_small + n_large
    area = p["Lx"] * p["Ly"]
    lam = p["lam"]
    n_base = n_prep = 0.0
    if lam > 0:
        # the kept band is 1.7 lambda thick, the preparation fill base_layers lambda (packing 0.6)
        # (divided by lambda twice, not by lambda**3: a tiny lambda gives inf, never 0 / 0)
        n_base = 1.7 * area * 0.6 / (math.pi / 6) / lam / lam
        n_prep = p["base_layers"] * area * 0.6 / (math.pi / 6) / lam / lam
    n_particles = max(n_flow + n_base, n_prep)
    t_c = min(x for x in (p["t_c"], p.get("base_t_c")) if x is not None)
    dt = t_c / p["steps_per_collision"]
    n_steps = p["t_end"] / dt
    interval = p["sample_interval"] if p["sample_interval"] is not None else 0.5 * t_c
    n_samples = min(p["t_end"] / max(interval, dt), n_steps) + 1.0
    # the depth grid of simulate._observers and its columns (coarse.profiles)
    d_max = 1.0 / p["sigma"] if p["phi0"] < 1.0 else 1.0
    z_span = 2.0 * p["H"] + 10.0 * d_max + 2.0 * max(lam, 1.0)
    n_z = z_span / p["cg_dz"] + 1.0
    n_species = 2 if p["phi0"] < 1.0 else 1
    n_columns = 10 + 2 * n_species + 12
    n_windows = min(p["t_end"] / p["cg_window"], n_samples / p["cg_every"]) + 2.0
    n_profile_values = n_z * n_columns * n_windows
    pairs = PAIRS_PER_PARTICLE * n_particles
    memory = (MEMORY_BASELINE + BYTES_PER_PARTICLE * n_particles + BYTES_PER_PAIR * pairs
              + BYTES_PER_SAMPLE * n_samples + BYTES_PER_PROFILE_VALUE * n_profile_values)
    # outputs: final state and checkpoint (x2 while it is replaced), profiles, series
    state_bytes = 40 * 8.0 * (n_flow + n_base) + 19 * 8.0 * pairs / 2
    output = (3 * state_bytes + 2 * 8.0 * n_profile_values + 2 * 6 * 8.0 * n_samples + 2e6)
    explanation = (f"{n_flow:.3g} flow + {n_base:.3g} base particles"
                   + (f" ({n_prep:.3g} while the base settles)" if n_prep > n_flow + n_base
                      else "")
                   + f", ~{PAIRS_PER_PARTICLE:g} neighbour pairs each, {n_samples:.3g} samples, "
                   f"{n_z:.3g} depth bins x {n_columns} columns x {n_windows:.3g} windows")
    return {"n_particles": n_particles, "n_flow": n_flow, "n_base": n_base, "n_steps": n_steps,
            "dt": dt, "n_samples": n_samples, "n_profile_values": n_profile_values,
            "memory_bytes": memory, "output_bytes": output, "explanation": explanation}


def machine_memory() -> float:
    """Memory this process may use (bytes): the physical memory, or a smaller cgroup limit
    (containers, Slurm jobs) or address-space limit."""
    limits = []
    try:
        limits.append(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        pass
    for f in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(f).read_text().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < 2**60:
            limits.append(int(text))
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY and soft > 0:
            limits.append(soft)
    except (ImportError, ValueError, OSError):
        pass
    return float(min(limits)) if limits else math.inf


def _fmt_bytes(n: float) -> str:
    if not math.isfinite(n):
        return f"{n} bytes"
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.3g} {unit}"
        n /= 1024.0
    return f"{n:.3g} EiB"  # pragma: no cover


class OutputFolderError(ValueError):
    """The output folder cannot take a run's outputs (read-only, not a folder, too full)."""


def check_output_folder(out_dir, need_bytes: float = 0.0, what: str = "the run") -> Path:
    """Fail before any compute unless ``out_dir`` (or, if it does not exist yet, the folder it
    would be made in) is a writable folder with at least ``need_bytes`` free.

    The check writes and removes a small probe file (permissions alone do not show a
    read-only file system, nor root's rights) and compares the free space with the estimate.
    Nothing is created when the folder does not exist yet.
    """
    import shutil
    import socket

    out_dir = Path(out_dir)
    where = out_dir
    while not where.exists() and where != where.parent:
        where = where.parent
    if not where.is_dir():
        raise OutputFolderError(f"output folder {os.fspath(out_dir)!r}: {os.fspath(where)!r} "
                                "exists and is not a folder")
    probe = where / f".granflow-write-probe-{socket.gethostname()}-{os.getpid()}"
    try:
        with open(probe, "wb") as fh:
            fh.write(b"\0" * 4096)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        raise OutputFolderError(
            f"output folder {os.fspath(out_dir)!r} is not writable: writing in "
            f"{os.fspath(where)!r} failed ({exc.strerror or exc}); {what} was not started") from None
    finally:
        try:
            probe.unlink()
        except OSError:
            pass
    free = shutil.disk_usage(where).free
    if free < need_bytes:
        raise OutputFolderError(
            f"output folder {os.fspath(out_dir)!r} has {_fmt_bytes(free)} free, {what} needs "
            f"about {_fmt_bytes(need_bytes)} (outputs and checkpoint): allowed at least that "
            "much free space; free some space or choose another folder")
    return where


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
                       sigma=p["sigma"], phi0=p["phi0"],
                       initial_mixing=p.get("initial_mixing", "mixed"),
                       initial_Ps=float(p.get("initial_Ps") or 0.0),
                       insertion_growth=p["insertion_growth"])


def load_params(path) -> dict:
    """Read a YAML/JSON run parameter file and validate it."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"parameter file {os.fspath(path)!r} does not exist"
                                + (" (it is a folder)" if path.is_dir() else ""))
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
    except yaml.YAMLError as exc:
        text = str(exc)
        raise ValueError(f"parameter file {os.fspath(path)!r} is not valid YAML: "
                         f"{text if len(text) < 400 else text[:397] + '...'}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"parameter file {os.fspath(path)!r} is not UTF-8 text ({exc.reason} "
                         f"at byte {exc.start})") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"parameter file {os.fspath(path)!r} holds a {type(data).__name__}, "
                         "not a mapping of parameter names to values")
    try:
        return validate_params(data)
    except ValueError as exc:
        raise ValueError(f"parameter file {os.fspath(path)!r}: {exc}") from None


def set_threads(threads: int | None):
    """Pass the job's thread count to numba (Snakemake does not set NUMBA_NUM_THREADS)."""
    if threads is None:
        return
    import numba

    threads = int(check_range("threads", threads, 1, 1024))
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


def prepare_base_file(lam, Lx, Ly, seed, out, base_layers=12.0, settle_time=30.0, **settling):
    """Prepare a rough base and write its positions atomically to ``out`` (.npy).

    ``settling``: ``prep_t_c``, ``prep_e``, ``prep_mu_c`` (the species the pile settles with;
    default a soft, strongly damped, frictional one), ``fill_packing`` and ``band`` of
    :class:`~granflow.engine.chute.BaseConfig`."""
    cfg = BaseConfig(lam=lam, Lx=Lx, Ly=Ly, seed=seed, base_layers=base_layers,
                     settle_time=settle_time, **settling).validate()
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


def restart_state(state_file, cfg: ChuteConfig, top_up: bool = False, pour: bool = True):
    """The particle system of a saved state, tilted to ``cfg.theta`` with the clock at t = 0,
    and the parent's provenance.  Raises ValueError if the state is not of this chute (box,
    flow-particle count, time step) -- checked before any compute.  ``top_up``: a state with
    fewer flow particles than ``cfg.H`` gives gets the rest poured on top, at rest, its contacts
    kept (:func:`granflow.engine.chute.top_up_flow`; the paper's §6 staircase, which adds 2
    particle heights to an arrested pile); the provenance records how many (``topped_up``).
    ``pour=False``: the same checks and provenance (``topped_up`` the number that a top-up
    adds), but the particles are not poured -- the caller pours them with ``top_up_flow`` only
    if it does not resume a checkpoint, which holds the topped-up system already."""
    import hashlib
    import json

    state_file = Path(state_file)
    system, _ = ParticleSystem.load(state_file)
    n_flow = int((~system.fixed).sum())
    n_expected = len(cfg.flow_particles()[0])
    problems = []
    if abs(system.Lx - cfg.Lx) > 1e-9 or abs(system.Ly - cfg.Ly) > 1e-9:
        problems.append(f"box {system.Lx:g} x {system.Ly:g} (run file: {cfg.Lx:g} x {cfg.Ly:g})")
    if top_up and cfg.bidisperse:
        problems.append(f"a top-up needs one flow species (run file phi0 = {cfg.phi0:g})")
    elif n_flow > n_expected or (n_flow != n_expected and not top_up):
        problems.append(f"{n_flow} flow particles (run file H = {cfg.H:g}, sigma, phi0 give "
                        f"{n_expected}{'' if top_up else '; --top-up adds missing ones'})")
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
    if not top_up:
        added = 0
    elif pour:
        added = top_up_flow(system, cfg)
    else:
        added = n_expected - n_flow
    parent_time = float(system.time)
    system.time = 0.0
    system.step_count = 0
    parent = {"parent_state": os.fspath(state_file.resolve()),
              "parent_state_sha256": hashlib.sha256(state_file.read_bytes()).hexdigest(),
              "parent_time": parent_time}
    if added:
        parent["topped_up"] = int(added)
    summary = state_file.parent / "summary.json"
    if summary.exists():
        ps = json.loads(summary.read_text())
        parent.update(parent_theta=ps.get("params", {}).get("theta"),
                      parent_flow_state=ps.get("flow_state"),
                      parent_git_commit=ps.get("provenance", {}).get("git_commit"),
                      parent_config_hash=ps.get("provenance", {}).get("config_hash"),
                      parent_base_sha256=ps.get("provenance", {}).get("base_sha256"))
    return system, {k: v for k, v in parent.items() if v is not None}


def restart_decision(state_file, restart_if) -> tuple[bool, str]:
    """Whether a restart from ``state_file`` goes ahead under ``restart_if`` (flow states the
    parent run must have ended in, read from the summary.json beside the state; None: always).
    Returns (go, reason); a parent without a summary, or in another state, is not used."""
    if restart_if is None:
        return True, ""
    import json

    summary = Path(state_file).parent / "summary.json"
    try:
        state = json.loads(summary.read_text()).get("flow_state")
    except (OSError, ValueError):
        return False, f"parent {os.fspath(state_file)!r} has no readable summary.json"
    if state in restart_if:
        return True, ""
    return False, (f"parent {os.fspath(state_file)!r} ended {state!r}, not "
                   f"{' or '.join(map(repr, restart_if))}")


def simulate(params: dict, out_dir, base_file=None, threads: int | None = 1,
             progress=None, extra_observers=(), from_state=None, max_threads: int | None = None,
             core_lease=None, restart_if=None, top_up: bool = False) -> dict:
    """Run one chute job into ``out_dir`` (resuming from its checkpoint if there is one that
    a run of the same parameters, base and parent wrote: :func:`keep_matching_checkpoint`).

    ``extra_observers`` (each with a unique ``name``) are sampled and checkpointed with the
    run, after the built-in ones (e.g. a second :class:`~granflow.observers.ProfileObserver`
    with another coarse-graining choice).  ``from_state``: start from this saved state at the
    inclination of ``params`` (:func:`restart_state`; ``base_file`` is not used);
    ``restart_if`` (e.g. ``("steady",)``): only when the parent run ended in one of these flow
    states, else a fresh fall onto ``base_file`` whose outputs record why
    (``restart_skipped``) -- the workflow's neighbour restarts
    (``campaigns.chute.restart_from_neighbour``) never start a run from an arrested layer.
    ``top_up``: a ``from_state`` with fewer flow particles than ``H`` gives gets the rest
    poured on top (:func:`restart_state`; a resumed run continues from its checkpoint).
    ``max_threads`` (default: ``$GRANFLOW_MAX_THREADS``, which the workflow sets to its
    ``--cores`` on a local machine): the numba engine takes up to this many threads while the
    machine has idle cores (:mod:`granflow.engine.threads`, shared with the campaign's other
    jobs through the lock folder ``core_lease`` or ``$GRANFLOW_CORE_LEASE``); no number
    depends on it (the log records the wall time per thread count).  Returns a
    summary dict (flow state, stop reason, final time, particle count, wall time, and the
    ChuteRun under ``run``).
    """
    import json
    import time as _time

    from .coarse.derived import depth_average_summary

    p = validate_params(params)
    out_dir = Path(out_dir)
    check_output_folder(out_dir, estimate_run_size(p)["output_bytes"])
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(out_dir)
    set_threads(threads)
    cfg = chute_config(p)
    engine = p.get("engine", "numba")
    spare = None
    if engine == "numba":  # LAMMPS' ranks are fixed at its start
        from .engine.threads import from_environment

        spare = from_environment(threads, max_threads, core_lease)  # checks its bounds
    ckpt = out_dir / "checkpoint.npz"
    wall0, cpu0 = _time.monotonic(), cpu_seconds()
    parent = {}
    if from_state is not None and restart_if is not None:
        go, why = restart_decision(from_state, tuple(restart_if))
        if not go:
            log.info("restart skipped (%s): a fresh fall", why)
            parent = {"restart_skipped": why}
            from_state = None
    if p["max_overlap"] is not None and engine != "numba":
        raise ValueError(f"max_overlap = {p['max_overlap']:g}: the {engine} engine's overlap "
                         "guard is fixed at 0.05 of the smallest diameter; leave it null")
    if from_state is not None:  # checked before any compute, also when resuming
        if engine != "numba" and top_up:
            raise ValueError(f"engine: a restart with --top-up needs the numba engine, not "
                             f"{engine!r} (it pours the missing particles with granflow's "
                             "engine)")
        # LAMMPS takes the state's positions, velocities and spins (not its tangential
        # springs, which restart from zero: the provenance says so)
        # the top-up is poured below, only when no checkpoint is resumed
        system, parent = restart_state(from_state, cfg, top_up=top_up, pour=False)
        if engine == "lammps":
            parent["parent_contact_history"] = ("not carried: LAMMPS restarts the tangential "
                                                "springs from zero")
    identity = run_identity(p, base_file, parent, top_up)
    if ckpt.exists() and engine == "numba":  # a checkpoint of other physics is moved aside
        keep_matching_checkpoint(ckpt, identity)
    if ckpt.exists() and engine == "numba":  # resume: the run restores system and observers
        system, _ = load_state(ckpt, kind="checkpoint", remove_if_corrupt=True)
    elif from_state is not None:  # a restart: its system is loaded; pour a top-up's particles
        if top_up:
            added = top_up_flow(system, cfg)
            if added != parent.get("topped_up", 0):  # restart_state counted them before
                raise RuntimeError(f"top-up poured {added} particles, "
                                   f"{parent.get('topped_up', 0)} expected")
    else:  # a fresh run: build the chute
        if base_file is not None:
            base = load_base_file(base_file)
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
                       checkpoint_every_s=p["checkpoint_every_s"], progress=progress,
                       checkpoint_identity=json.dumps(identity, sort_keys=True))
    run.segment_start = (wall0, cpu0)  # the set-up above counts in the run's cost
    if spare is not None:
        # a borrowed thread stays only if the run's steps per second show it pays
        spare.progress = lambda: run.system.step_count
        run.tick_hooks.append(spare.poll)
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
    engine_stop = None
    if lammps is None:
        try:
            run.try_resume()
        except Exception as exc:  # observer states missing or unreadable: same as a corrupt file
            raise _corrupt(ckpt, f"its observer states do not restore ({type(exc).__name__}: "
                                 f"{exc})", "checkpoint", remove=True) from None
        if p["max_overlap"] is not None:  # after the resume: the run's own system
            run.system.max_overlap_fraction = float(p["max_overlap"])
        # the resume-free parameters are this invocation's, not the checkpoint's: a resumed
        # monitor would otherwise keep the cap (and stop rule) of the run that wrote it
        monitor_obs.monitor.t_cap = float(p["t_end"])
        monitor_obs.monitor.stop_when_flowing = bool(p["stop_when_flowing"])
        try:
            if spare is None:
                run.run()
            else:
                spare.start()
                try:
                    run.run()
                finally:
                    spare.close()
                    set_threads(threads)
                log.info("spare cores: %s", spare.summary())  # the log only: outputs identical
        except SimulationError as exc:  # an engine guard: the run ends, not the campaign
            engine_stop = str(exc)
            run.stop_reason = f"engine guard: {exc}"
            log.error("%s: the run stops here, flow state undecided", exc)
    else:
        try:
            lammps.start()
            run.run()
        finally:
            lammps.close()
        extra_attrs = lammps_attrs(lammps)
    # the base the run stands on: its file's, or for a restart its parent's (None: prepared
    # from the parameters, or a parent run that did not record it)
    base_sha256 = identity["base_sha256"] or (parent or {}).get("parent_base_sha256")
    out = write_outputs(p, out_dir, run, monitor_obs, profile_obs, seg_obs, extra_attrs,
                        parent=parent, engine_stop=engine_stop, base_sha256=base_sha256)
    if ckpt.exists():
        ckpt.unlink()
    # wall_s: this process; cost: the whole run (all segments of a resumed run, CPU of all threads)
    return dict(out, wall_s=_time.monotonic() - wall0, cost=run.cost(), run=run)


#: Run parameters that only say when a run stops or how often it checkpoints: a checkpoint
#: written under other values of these is resumed (a run continued to a later ``t_end``, or
#: ended at the arrest horizon); a difference in any other parameter, in the base file or in
#: the parent state starts the run afresh (:func:`keep_matching_checkpoint`).
RESUME_FREE_PARAMETERS = ("t_end", "early_stop", "stop_when_flowing", "checkpoint_every_s")


def run_identity(p: dict, base_file=None, parent: dict | None = None,
                 top_up: bool = False) -> dict:
    """What a checkpoint must share with a run to be resumed by it: the validated run
    parameters ``p`` except :data:`RESUME_FREE_PARAMETERS`, the engine, the SHA-256 of the
    base file (None: a base prepared from the parameters) and, for a restart, the parent
    state's SHA-256 (``parent`` from :func:`restart_state`) and whether it was topped up."""
    import hashlib

    ident = {k: p[k] for k in sorted(p) if k not in RESUME_FREE_PARAMETERS}
    ident["engine"] = p.get("engine", "numba")
    ident["base_sha256"] = (None if base_file is None
                            else hashlib.sha256(Path(base_file).read_bytes()).hexdigest())
    parent = parent or {}
    ident["parent_state_sha256"] = parent.get("parent_state_sha256")
    ident["top_up"] = bool(top_up) if parent.get("parent_state_sha256") else False
    return ident


def checkpoint_identity(ckpt) -> dict | None:
    """The run identity stored in a checkpoint (None: written before checkpoints kept one, or
    unreadable -- :func:`load_state` then says what is wrong with the file)."""
    import json

    try:
        with np.load(ckpt, allow_pickle=False) as data:
            if "extra__run_identity" not in data.files:
                return None
            return json.loads(str(data["extra__run_identity"]))
    except Exception:  # a truncated or foreign file: the resume path reports it
        return None


def keep_matching_checkpoint(ckpt, identity: dict) -> bool:
    """Keep ``ckpt`` for a resume only if it was written by a run with this ``identity``
    (:func:`run_identity`); otherwise move it aside, to ``checkpoint.superseded-<hash>.npz``
    in the same folder (nothing is deleted), and log which parameters differ: the run then
    starts at t = 0 instead of continuing another run's physics under these parameters.
    A checkpoint without a stored identity (older granflow) is resumed, with a warning.
    Returns True when the checkpoint is kept."""
    import hashlib
    import json

    ckpt = Path(ckpt)
    stored = checkpoint_identity(ckpt)
    if stored is None:
        log.warning("checkpoint %s stores no run parameters (written before granflow kept "
                    "them): resumed without checking that they are this run's", ckpt)
        return True
    if stored == identity:
        return True
    keys = sorted(set(stored) | set(identity))
    diff = [f"{k} {stored.get(k)!r} -> {identity.get(k)!r}" for k in keys
            if stored.get(k) != identity.get(k)]
    tag = hashlib.sha256(json.dumps(stored, sort_keys=True).encode()).hexdigest()[:12]
    aside = ckpt.with_name(f"checkpoint.superseded-{tag}.npz")
    os.replace(ckpt, aside)
    log.warning("checkpoint %s was written by a run with other parameters (%s): moved to %s; "
                "this run starts at t = 0", ckpt, "; ".join(diff), aside.name)
    return False


def lammps_attrs(lammps) -> dict:
    """Provenance of a LAMMPS-engine run (stored in every output and the summary)."""
    return {"engine": "lammps", "lammps_ranks": int(lammps.ranks),
            "lammps_input": os.fspath(lammps.folder / "in.granflow"),
            "lammps_max_overlap": float(lammps.max_overlap_seen)}


def write_outputs(p: dict, out_dir, run, monitor_obs, profile_obs, seg_obs=None,
                  extra_attrs=None, parent=None, engine_stop: str | None = None,
                  base_sha256: str | None = None) -> dict:
    """Classify the run and write series.nc, profiles.nc, final_state.npz and summary.json.

    ``run`` offers ``system`` (``time``, ``fixed``, ``dt``, ``save(path)``; ``save`` may be
    None: no final state), ``stop_reason`` and ``series.arrays()``; the observers are the
    run's (any engine, or an ingest of dumps); ``parent``: the restart provenance of
    :func:`restart_state`; ``engine_stop``: the message of an engine guard that ended the run
    (the flow state is then ``undecided``); ``base_sha256``: SHA-256 of the base file the run
    fell onto, recorded in the provenance (attribute and ``summary["provenance"]``) so that runs
    can be grouped by base realisation.  Returns the summary (plus ``profiles``).
    """
    import json

    from .coarse.derived import depth_average_summary

    out_dir = Path(out_dir)
    final = monitor_obs.final()
    seg = seg_obs.final() if seg_obs is not None else None
    t_now = run.system.time
    state_before_stop = None
    if engine_stop is not None:
        state_before_stop = str(final["flow_state"])
        final = dict(final, flow_state="undecided", steady_start=math.nan, confidence=0.0,
                     explanation=(f"undecided: the engine stopped the run at t = {t_now:.6g} "
                                  f"({engine_stop}); until then the classifier said "
                                  f"{final['flow_state']}: {final['explanation']}"))
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
    if base_sha256:
        attrs["base_sha256"] = base_sha256
    attrs.update(extra_attrs or {})
    if engine_stop is not None:
        attrs["engine_stop"] = engine_stop
        attrs["flow_state_before_engine_stop"] = state_before_stop
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
    # a bidisperse run also keeps every window from its start (profiles.nc averages only the
    # steady or last ones): how its segregated state approached its end is the evidence for
    # a run still drifting (a one-sided bound on its steady Ps), and its checkpoint, which
    # held the windows while it ran, is removed when it finishes
    history = profile_obs.dataset(t_from=None, attrs=attrs) if seg is not None else None
    # a steady run layered in z (paper §8) is "layered": the energy ratio cannot tell
    state, layering, note = layered_state(final["flow_state"], profiles["z"].values,
                                          profiles["volume_fraction"].values)
    if state != final["flow_state"]:
        final = dict(final, flow_state=state, explanation=final["explanation"] + note)
    for d in (ds, profiles) + ((history,) if history is not None else ()):
        d.attrs.update(flow_state=final["flow_state"], classification=final["explanation"],
                       layering_amplitude=layering)
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
        "layering_amplitude": layering,
        "params": {k: v for k, v in p.items() if v is not None},
        "depth_averages": averages,
        "segregation": None if seg is None else {
            k: v for k, v in seg.items() if k not in ("time", "value")},
        "provenance": {k: attrs[k] for k in ("granflow_version", "git_commit", "config_hash")},
    }
    summary["provenance"]["base_sha256"] = base_sha256 or None
    if parent:
        summary["parent"] = dict(parent)
    if engine_stop is not None:
        summary["engine_stop"] = engine_stop
        summary["flow_state_before_engine_stop"] = state_before_stop
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
    written = [name for name in RUN_OUTPUTS if name != "final_state.npz"]
    if history is not None:
        if engine != "numba":
            history.attrs["source"] = profiles.attrs["source"]
        cfconventions.apply(
            history, kind="profiles", config=p,
            title=f"granflow chute run depth profiles, every window ({where})",
            summary=("Coarse-grained depth profiles of one bidisperse periodic-chute discrete "
                     f"particle simulation ({where}){source}, per time window from the run's "
                     "start (profiles.nc averages the windows from t = "
                     f"{t_from:g} only): how the segregated state approached its end."))
        starts = history["window_time_start"].values if "window_time_start" in history else []
        history.attrs.update(profile_time_from=float(min(starts)) if len(starts) else 0.0,
                             profiles_nc_time_from=t_from)
        atomic_to_netcdf(history, out_dir / PROFILES_HISTORY)
        written.append(PROFILES_HISTORY)
    atomic_to_netcdf(ds, out_dir / "series.nc")
    atomic_to_netcdf(profiles, out_dir / "profiles.nc")
    save = getattr(run.system, "save", None)
    if save is not None:
        save(out_dir / "final_state.npz")
        written.append("final_state.npz")
    # what the run wrote, so that a reader can tell a truncated or modified output
    summary["outputs"] = {name: file_record(out_dir / name) for name in written}
    atomic_write_bytes(out_dir / "summary.json",
                       json.dumps(_finite_or_none(summary), indent=2, default=_json_default,
                                  allow_nan=False).encode())
    log.info("%s: %s", out_dir, final["explanation"])
    return dict(summary, profiles=profiles)


#: the outputs of a run whose size and SHA-256 summary.json records (``outputs``)
RUN_OUTPUTS = ("series.nc", "profiles.nc", "final_state.npz")
#: a bidisperse run's profiles per window from its start (recorded in ``outputs`` when written)
PROFILES_HISTORY = "profiles_history.nc"


def file_record(path) -> dict:
    """Size and SHA-256 of a file (recorded in summary.json for each run output)."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return {"bytes": Path(path).stat().st_size, "sha256": h.hexdigest()}


class CorruptFileError(ValueError):
    """A granflow file that cannot be read back (truncated, corrupt, of another format)."""

    def __init__(self, path, message: str, removed: bool = False):
        self.path = Path(path)
        self.removed = removed
        super().__init__(message)


def _corrupt(path, problem: str, kind: str, remove: bool = False) -> CorruptFileError:
    """The error for an unreadable ``kind`` file; with ``remove`` the file is deleted first (a
    checkpoint or run output that a rerun recomputes) and the message says so."""
    removed = False
    if remove:
        try:
            Path(path).unlink()
            removed = True
        except OSError:
            pass
    what = {"checkpoint": "checkpoint", "state": "particle state file"}.get(kind, f"{kind} file")
    tail = ""
    if removed and kind == "checkpoint":
        tail = "; removed it: run again to restart this run from t = 0"
    elif removed:
        tail = "; removed it: rerun the workflow to recompute this run"
    return CorruptFileError(path, f"{what} {os.fspath(path)!r} {problem}{tail}", removed)


def load_state(path, kind: str = "state", remove_if_corrupt: bool = False):
    """:meth:`ParticleSystem.load` with errors that name the file and say what is wrong.

    Returns (system, extra).  A missing file raises FileNotFoundError; an unreadable one
    (truncated, not a .npz archive, a member that fails its CRC, missing arrays or metadata)
    raises :class:`CorruptFileError` (a ValueError), after deleting it when
    ``remove_if_corrupt`` (a checkpoint: the rerun then starts the run afresh).
    """
    import zipfile
    import zlib

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{kind} file {os.fspath(path)!r} does not exist")
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if not magic:
        raise _corrupt(path, "is empty (0 bytes)", kind, remove_if_corrupt)
    if magic != b"PK\x03\x04":
        raise _corrupt(path, f"is not a .npz archive (it starts with {magic!r}, not a zip "
                             "header): truncated, overwritten or another format", kind,
                       remove_if_corrupt)
    try:
        with np.load(path, allow_pickle=False) as data:
            names = set(data.files)
            for name in names:  # reads every member: a truncated or corrupt one fails here
                data[name]
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError, zlib.error) as exc:
        problem = str(exc) or type(exc).__name__
        if isinstance(exc, zipfile.BadZipFile) or "zip" in problem.lower():
            problem = f"is truncated or not a .npz archive ({problem})"
        else:
            problem = f"is unreadable ({type(exc).__name__}: {problem})"
        raise _corrupt(path, problem, kind, remove_if_corrupt) from None
    missing = sorted({"meta_json", *ParticleSystem._ARRAYS} - names) \
        if hasattr(ParticleSystem, "_ARRAYS") else sorted({"meta_json"} - names)
    if missing:
        raise _corrupt(path, f"lacks the arrays {missing} of a particle state", kind,
                       remove_if_corrupt)
    try:
        return ParticleSystem.load(path)
    except Exception as exc:  # metadata that does not parse, arrays of the wrong shape, ...
        raise _corrupt(path, f"does not restore a particle system ({type(exc).__name__}: "
                             f"{exc})", kind, remove_if_corrupt) from None


def load_base_file(base_file) -> np.ndarray:
    """Positions (M, 3) of a prepared base (.npy), with errors naming the file."""
    base_file = Path(base_file)
    if not base_file.is_file():
        raise FileNotFoundError(f"base file {os.fspath(base_file)!r} does not exist")
    try:
        base = np.load(base_file, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise CorruptFileError(base_file, f"base file {os.fspath(base_file)!r} is truncated or "
                                          f"not a .npy array ({exc})") from None
    if not isinstance(base, np.ndarray) or base.ndim != 2 or base.shape[1] != 3 \
            or not np.issubdtype(base.dtype, np.floating) or not np.isfinite(base).all():
        raise ValueError(f"base file {os.fspath(base_file)!r} does not hold an (M, 3) array of "
                         "finite positions")
    return base


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
