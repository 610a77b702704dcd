"""The adaptive hstop search (Weinhart et al. 2012 §6) as a chain of Snakemake checkpoint steps.

Step 0 writes the initial :class:`granflow.steady.hstop_search.HstopSearch` state; step i
(i >= 1) reads state i - 1, takes the run at the point it proposed (an ordinary campaign run
``chute/<law>/lambda~L/theta~T/H~H``, simulated by the shared ``simulate`` rule and therefore
reused if the grid already has it), records that run's flow state and writes state i.  The
workflow follows the chain until a state has no next point.  Every state file is plain JSON
(``HstopSearch.state_dict`` plus the law and lambda), so the walk resumes after any
interruption at the last finished step.
"""

from __future__ import annotations

import json

from ..provenance import atomic_write_bytes
from ..steady.bisection import FAILED
from ..steady.hstop_search import HstopSearch
from .grid import RunPoint, parse_run_path

#: HstopSearch keyword arguments that a configuration may set
SEARCH_KEYS = ("theta0", "H0", "dtheta_up", "dtheta_down", "dH", "H_max", "theta_max",
               "theta_min", "max_runs")


def search_settings(cfg: dict) -> dict:
    return {k: cfg[k] for k in SEARCH_KEYS if cfg.get(k) is not None}


def init_state(law: str, lam: float, settings: dict) -> dict:
    s = HstopSearch(**settings)
    return {"law": law, "lam": float(lam), "step": 0, "search": s.state_dict()}


def next_point(state: dict) -> RunPoint | None:
    nxt = state["search"]["next"]
    if nxt is None:
        return None
    return RunPoint("chute", state["law"], float(state["lam"]), float(nxt[0]), float(nxt[1]))


def _read_flow_state(run_summary_path) -> tuple[dict, str]:
    """(summary, flow state) of a finished run for an hstop chain: FAILED for a run that an
    engine guard ended before it had any flow state (no evidence either way)."""
    from .collect import engine_stop_without_flow_state

    with open(run_summary_path) as fh:
        summary = json.load(fh)
    if engine_stop_without_flow_state(summary):
        return summary, FAILED
    return summary, summary["flow_state"]


def step_state(state: dict, run_summary_path, run_rel: str | None = None) -> dict:
    """Record the flow state of the run at the proposed point; return the next state."""
    point = next_point(state)
    if point is None:
        raise ValueError("the hstop search is already finished; no further step")
    if run_rel is not None:
        got = parse_run_path(run_rel)
        if (abs(got.theta - point.theta) > 1e-9 or abs(got.H - point.H) > 1e-9
                or got.law != point.law or abs(got.lam - point.lam) > 1e-9):
            raise ValueError(f"run {run_rel} is not the proposed point {point.path}")
    summary, flow_state = _read_flow_state(run_summary_path)
    search = HstopSearch.from_state_dict(state["search"])
    if flow_state == FAILED:  # no evidence either way: the walk ends
        search.record_failed(point.theta, point.H, f"engine guard: {summary['engine_stop']}")
    else:
        search.record(point.theta, point.H, flow_state)
    return {"law": state["law"], "lam": state["lam"], "step": int(state["step"]) + 1,
            "search": search.state_dict(),
            "last": {"theta": point.theta, "H": point.H, "flow_state": flow_state,
                     "run": point.path}}


def read_state(path) -> dict:
    with open(path) as fh:
        return json.load(fh)


def write_state(state: dict, out):
    atomic_write_bytes(out, json.dumps(state, indent=1, sort_keys=True).encode())


def search_runs(state: dict) -> list[RunPoint]:
    """The simulated runs of a (final) search state."""
    return [RunPoint("chute", state["law"], float(state["lam"]), float(t), float(h))
            for t, h, _ in state["search"]["runs"]]


def intervals(state: dict):
    """[(H, theta_arrested, theta_flowing)] of a search state (complete brackets only)."""
    return HstopSearch.from_state_dict(state["search"]).intervals()


# ----------------------------------------------------------------------------- bisection chains
#: Bisection keyword arguments a configuration may set (campaigns.chute.hstop_bisection)
BISECTION_KEYS = ("step", "tolerance", "max_runs", "theta_min", "theta_max", "resolution")
#: How a chain's bracket runs start (``hstop_bisection.protocol``):
#:
#: * ``fresh_fall`` (default): every bracket run is a fresh fall onto the base, stopped as soon as
#:   it is arrested or decisively flowing, and arrested only if it arrests within
#:   ``arrest_horizon`` (the paper's §6 rule, as MercuryDPM's hstop driver: ``setTimeMax(500)``;
#:   until 2026-11-27 a fresh fall ran to t_end, and one lambda = 1, H = 16 run at 21.08 deg that
#:   arrested at t = 601 counted as arrested);
#: * ``continuation``: the paper's §6 reading ("initial conditions determined by the following
#:   algorithm ... from this initial flowing state ... the angle decreased by 1/2 deg"): a bracket
#:   run starts from the final state of the chain's flowing run at the nearest angle above it
#:   (a fresh fall while the chain has none), and is arrested only if it arrests within
#:   ``arrest_horizon`` (500 time units), otherwise flowing.  Measured on the lambda = 1/2 base
#:   (H = 16, 10 x 5, paper species, 2026-11-26): a fresh fall arrests at 20.40 deg, while the
#:   flow continued from 20.65 deg stays steady at 20.40 (u_bar 4.8) and still flows at 19.90
#:   -- a hysteresis of the thick layers that the fresh falls put above Table 1's hstop curve.
BISECTION_PROTOCOLS = ("fresh_fall", "continuation")
#: Paper §6: arrested when E_kin/<E_ela> falls below 1e-5 within 500 time units (both protocols).
ARREST_HORIZON = 500.0
#: keys of ``hstop_bisection`` that are not :class:`Bisection` settings (not passed to step 0)
BISECTION_RUN_KEYS = ("protocol", "arrest_horizon", "cg_every")


def bisection_protocol(cfg: dict) -> tuple[str, float]:
    """(protocol, arrest horizon) of an ``hstop_bisection`` block (defaults: fresh falls, 500)."""
    proto = str(cfg.get("protocol") or "fresh_fall")
    if proto not in BISECTION_PROTOCOLS:
        raise ValueError(f"config key campaigns.chute.hstop_bisection.protocol = {proto!r}: "
                         f"allowed {list(BISECTION_PROTOCOLS)}")
    horizon = float(cfg.get("arrest_horizon") or ARREST_HORIZON)
    if not horizon > 0:
        raise ValueError("config key campaigns.chute.hstop_bisection.arrest_horizon = "
                         f"{horizon:g}: allowed > 0")
    return proto, horizon


def bisection_guess(cfg: dict, H: float, lam: float | None = None) -> float:
    """Where the chain at height H starts: theta_stop(H) of the configured prior curve (Eq. 45
    with the prior's delta1, delta2, A -- ``priors: {lambda: {...}}`` per basal roughness, else
    ``prior``; only a starting point, it never enters a fit), or an explicit per-height guess
    ``guess: {H: theta}``."""
    from ..fitting.hstop import theta_stop_eq45

    guess = {float(k): float(v) for k, v in (cfg.get("guess") or {}).items()}
    for h, t in guess.items():
        if abs(h - H) < 1e-9:
            return t
    prior = cfg.get("prior") or {}
    for lm, pr in (cfg.get("priors") or {}).items():
        if lam is not None and abs(float(lm) - float(lam)) < 1e-9:
            prior = pr
    return float(theta_stop_eq45(float(H), float(prior.get("delta1", 17.708)),
                                 float(prior.get("delta2", 32.780)), float(prior.get("A", 3.355))))


def bisection_replicates(cfg: dict, H: float) -> int:
    """Chains at height H: ``replicates: n`` gives every height n chains (insertion seeds seed ..
    seed + n - 1); ``replicates: {H: n}`` gives the named heights n chains and the others one
    (where the seed scatter of one arrest is what limits a fit, e.g. thin layers for delta2)."""
    reps = cfg.get("replicates", 1)
    if isinstance(reps, dict):
        for h, n in reps.items():
            if abs(float(h) - float(H)) < 1e-9:
                return int(n)
        return 1
    return int(reps)


def bisection_replicate_errors(cfg: dict) -> list[str]:
    """Problems of a per-height ``replicates`` mapping: heights that no chain brackets."""
    reps = cfg.get("replicates", 1)
    if not isinstance(reps, dict):
        return []
    heights = [float(h) for h in cfg.get("H") or []]
    bad = [h for h in reps if not any(abs(float(h) - x) < 1e-9 for x in heights)]
    if not bad:
        return []
    return [f"config key campaigns.chute.hstop_bisection.replicates names heights {bad} that are "
            f"not in campaigns.chute.hstop_bisection.H = {heights}: allowed keys are those heights"]


def init_bisection(law: str, lam: float, H: float, cfg: dict, replicate: int = 0) -> dict:
    """Step 0 of the bisection chain of (law, lambda, H, replicate): :class:`Bisection` from
    ``cfg``.  Replicate k brackets the same height with runs of insertion seed + k."""
    from ..steady.bisection import Bisection

    b = Bisection(float(H), bisection_guess(cfg, float(H), float(lam)),
                  **{k: cfg[k] for k in BISECTION_KEYS if cfg.get(k) is not None})
    return {"law": law, "lam": float(lam), "H": float(H), "replicate": int(replicate),
            "step": 0, "bisection": b.state_dict()}


def bisection_next_point(state: dict) -> RunPoint | None:
    nxt = state["bisection"]["next"]
    if nxt is None:
        return None
    return RunPoint("bracket", state["law"], float(state["lam"]), float(nxt), float(state["H"]),
                    replicate=int(state.get("replicate", 0)))


def bisection_parent(state: dict) -> RunPoint | None:
    """Continuation protocol: the run whose final state the bracket run that ``state`` proposes
    starts from -- the chain's flowing (not arrested) run at the smallest angle above the
    proposed one; None while the chain has none (a fresh fall) or when it is finished."""
    nxt = bisection_next_point(state)
    if nxt is None:
        return None
    above = [float(t) for t, s in state["bisection"]["runs"]
             if s not in ("arrested", FAILED) and float(t) > nxt.theta + 1e-9]
    if not above:
        return None
    return RunPoint("bracket", state["law"], float(state["lam"]), min(above), float(state["H"]),
                    replicate=int(state.get("replicate", 0)))


def bisection_step(state: dict, run_summary_path, run_rel: str | None = None) -> dict:
    """Record the flow state of the run the chain proposed; return the next state."""
    from ..steady.bisection import Bisection

    point = bisection_next_point(state)
    if point is None:
        raise ValueError("this hstop bisection is already finished; no further step")
    if run_rel is not None:
        got = parse_run_path(run_rel)
        if got != point:
            raise ValueError(f"run {run_rel} is not the proposed point {point.path}")
    _, flow_state = _read_flow_state(run_summary_path)  # FAILED: the chain stops
    b = Bisection.from_state_dict(state["bisection"])
    b.record(point.theta, flow_state)
    return {"law": state["law"], "lam": state["lam"], "H": state["H"],
            "replicate": int(state.get("replicate", 0)),
            "step": int(state["step"]) + 1, "bisection": b.state_dict(),
            "last": {"theta": point.theta, "flow_state": flow_state, "run": point.path}}


def bisection_runs(state: dict) -> list[RunPoint]:
    """The simulated runs of a (final) bisection state."""
    return [RunPoint("bracket", state["law"], float(state["lam"]), float(t), float(state["H"]),
                     replicate=int(state.get("replicate", 0)))
            for t, _ in state["bisection"]["runs"]]
