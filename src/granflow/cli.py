"""Command line interface: ``granflow <command>``.

Commands
--------
simulate      run one chute from a parameter file (YAML) into an output folder (resumable;
              --from STATE restarts a saved final_state.npz at a new inclination)
prepare-base  prepare and freeze a rough base for one lambda (reused by every run over it)
demo          a short chute demonstration run (engine smoke demo for the quick start)
ingest        ingest lammps DUMPS... --out DIR: series.nc, profiles.nc, summary.json of a
              user's own LAMMPS chute run (coarse-grained and classified as granflow's runs)
campaign      the campaign workflow's steps (check-config, expand, run-params, row, collect,
              fit, library, report, hstop-step; Snakemake calls them, `granflow campaign -h`)

A running ``granflow simulate`` names itself ``granflow-sim`` (process name, Linux) and writes
its pid to ``<out>/simulate.pid`` while it runs, so runs can be stopped cleanly with
``pkill -x granflow-sim`` (all) or ``kill $(cat <out>/simulate.pid)`` (one); a stopped run
resumes from its checkpoint when started again.
"""

from __future__ import annotations

import argparse
import logging
import sys


def _setup_logging(verbose: bool):
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")


#: process name of a running `granflow simulate` (at most 15 characters: Linux comm)
PROCESS_NAME = "granflow-sim"


def set_process_name(name: str) -> bool:
    """Set this process's name (``/proc/<pid>/comm``, what ``pkill -x``/``top`` show); Linux
    only, False elsewhere."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(15, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0) == 0  # PR_SET_NAME
    except (OSError, AttributeError):
        return False


def _running_simulation(pid: int) -> bool:
    """True if ``pid`` is a live ``granflow simulate`` (named PROCESS_NAME) other than us."""
    import os

    if pid == os.getpid():
        return False
    try:
        with open(f"/proc/{pid}/comm") as fh:
            return fh.read().strip() == PROCESS_NAME
    except OSError:
        return False


#: seconds a new run waits for a previous run of the same folder to stop (after its workflow
#: was killed, the previous run notices within a second and stops: see watch_workflow)
PREVIOUS_RUN_WAIT_S = 15.0


def wait_for_previous_run(pid_file, wait_s: float = PREVIOUS_RUN_WAIT_S):
    """Refuse to start a run in a folder another live run is working on (its pid file names a
    running ``granflow-sim``), after waiting ``wait_s`` for it to stop.  A stale pid file (the
    run was killed) is ignored."""
    import time

    try:
        pid = int(open(pid_file).read().strip())
    except (OSError, ValueError):
        return
    deadline = time.monotonic() + wait_s
    while _running_simulation(pid):
        if time.monotonic() > deadline:
            raise ValueError(f"{pid_file.parent} is in use: the run with pid {pid} is still "
                             f"working on it ({pid_file}); stop it first (kill {pid}) or wait "
                             "for it to finish")
        time.sleep(0.2)


#: environment variable naming the workflow process a granflow command belongs to
#: ("<host>:<pid>:<start time>", set by the workflow, workflow/rules/common.smk)
WORKFLOW_ENV = "GRANFLOW_WORKFLOW_PROCESS"


def process_start_time(pid: int):
    """Start time of process ``pid`` (clock ticks since boot, /proc/<pid>/stat), or None."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            stat = fh.read()
        return int(stat.rsplit(")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def workflow_token(pid: int | None = None) -> str:
    """The value of WORKFLOW_ENV for process ``pid`` (default: this one)."""
    import os
    import socket

    pid = os.getpid() if pid is None else pid
    return f"{socket.gethostname()}:{pid}:{process_start_time(pid)}"


def watch_workflow(interval_s: float = 0.5):
    """Stop this process (SIGTERM) when the workflow that started it is gone.

    Snakemake killed with SIGKILL cannot stop its jobs; without this they would run on as
    orphans next to the jobs of the rerun.  The workflow names itself in WORKFLOW_ENV; a job
    on the same host watches that process (pid and start time, so a reused pid does not count)
    from a daemon thread.  Not set, another host, or no /proc: nothing is watched.
    """
    import os
    import signal
    import socket
    import threading
    import time

    token = os.environ.get(WORKFLOW_ENV, "")
    try:
        host, pid, start = token.rsplit(":", 2)
        pid = int(pid)
    except ValueError:
        return None
    if host != socket.gethostname() or start == "None" or process_start_time(pid) is None:
        return None

    def gone():
        return process_start_time(pid) != int(start)

    if gone():
        os.kill(os.getpid(), signal.SIGTERM)

    def watch():
        while True:
            time.sleep(interval_s)
            if gone():
                logging.getLogger("granflow").warning(
                    "the workflow process %d is gone: stopping (a rerun resumes)", pid)
                os.kill(os.getpid(), signal.SIGTERM)
                return

    thread = threading.Thread(target=watch, name="granflow-workflow-watch", daemon=True)
    thread.start()
    return thread


def cmd_simulate(args):
    import os
    import signal
    from pathlib import Path

    from .provenance import atomic_write_bytes
    from .simulate import check_output_folder, estimate_run_size, load_params, simulate

    if args.top_up and not args.from_state:
        raise SystemExit("--top-up: allowed only with --from STATE (it adds particles to a "
                         "saved state)")
    params = load_params(args.params)
    check_output_folder(args.out, estimate_run_size(params)["output_bytes"])
    set_process_name(PROCESS_NAME)
    pid_file = Path(args.out) / "simulate.pid"
    wait_for_previous_run(pid_file)
    atomic_write_bytes(pid_file, f"{os.getpid()}\n".encode())
    def remove_pid_file():
        try:
            if pid_file.read_text().strip() == str(os.getpid()):
                pid_file.unlink()
        except OSError:
            pass

    def stop(signum, frame):
        # SIGTERM/SIGINT (kill, pkill, Ctrl-C, Slurm's scancel): remove the pid file, then die
        # of the signal as before; the last checkpoint (written atomically) stays for the rerun
        remove_pid_file()
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, stop)
    try:
        summary = simulate(params, args.out, base_file=args.base, threads=args.threads,
                           from_state=args.from_state or args.from_if_steady,
                           restart_if=("steady",) if args.from_if_steady else None,
                           max_threads=args.max_threads,
                           core_lease=args.core_lease, top_up=args.top_up)
    finally:
        remove_pid_file()
    cost = summary["cost"]
    # benchmarks/campaign_cost.py reads this line: keep its form
    print(f"{args.out}: {summary['flow_state']} ({summary['stop_reason']}) at t = {summary['t_final']:.4g} "
          f"({summary['n_flow']} flow particles, {summary['wall_s']:.1f} s wall; whole run "
          f"{cost['cpu_s']:.1f} s cpu, {cost['wall_s']:.1f} s wall, {cost['segments']} segments)")


def cmd_prepare_base(args):
    from pathlib import Path

    from .simulate import check_output_folder, prepare_base_file

    check_output_folder(Path(args.out).parent, 64e6, what="the base preparation")

    pos = prepare_base_file(args.lam, args.Lx, args.Ly, args.seed, args.out,
                            base_layers=args.base_layers, settle_time=args.settle_time,
                            **{k: v for k, v in (("prep_mu_c", args.settle_mu_c),
                                                 ("fill_packing", args.fill_packing),
                                                 ("band", args.band)) if v is not None})
    print(f"{args.out}: {len(pos)} base particles (lambda = {args.lam})")


def cmd_demo(args):
    import numpy as np

    from .simulate import simulate

    params = dict(theta=24.0, H=args.H, lam=1.0, Lx=10.0, Ly=5.0, t_end=args.t_end, t_c=0.02,
                  base_layers=5.0, seed=1)
    summary = simulate(params, args.out, threads=args.threads, progress=None)
    run = summary["run"]
    s = run.series.arrays()
    print(f"demo chute theta=24 deg, H={args.H}, lambda=1, box 10x5, soft particles t_c=0.02")
    print(f"{'t':>8} {'E_kin':>12} {'E_ela':>12} {'u_mean':>10}")
    for k in np.linspace(0, len(s['time']) - 1, 11).astype(int):
        print(f"{s['time'][k]:8.2f} {s['e_kin'][k]:12.5g} {s['e_ela'][k]:12.5g} {s['u_mean'][k]:10.4f}")
    print(f"outputs in {args.out}/ (series.nc, final_state.npz)")


def cmd_ingest_lammps(args):
    from .lammps.ingest import ingest_lammps

    analysis = {k: getattr(args, k) for k in ("averaging_time", "check_every",
                                               "min_accelerating_time", "cg_width", "cg_dz",
                                               "cg_window", "cg_every", "cg_base_line")
                if getattr(args, k) is not None}
    kwargs = {}
    if args.pair_columns:
        kwargs["pair_columns"] = tuple(args.pair_columns.split(","))
    summary = ingest_lammps(args.dumps, args.out, args.theta, base_types=args.base_types,
                            dt=args.dt, gravity=args.gravity, kn=args.kn, t_c=args.t_c, e=args.e,
                            kt_over_kn=args.kt_over_kn, t_start=args.t_start,
                            z_origin=args.z_origin, **kwargs,
                            **analysis)
    da = summary.get("depth_averages") or {}
    print(f"{args.out}: {summary['flow_state']} ({summary['n_flow']} flow particles, "
          f"t in [{da.get('t_from', summary['profile_time_from']):.4g}, {summary['t_final']:.4g}]"
          f" averaged): u_bar = {da.get('u_bar', float('nan')):.4g}, "
          f"F = {da.get('froude', float('nan')):.4g}, h = {da.get('flow_height', float('nan')):.4g}")


def main(argv=None):
    parser = argparse.ArgumentParser(prog="granflow", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("simulate", help="run one chute from a parameter file")
    p.add_argument("params", help="YAML parameter file (see granflow.simulate.PARAMETERS)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--base", default=None, help="prepared base positions (.npy) to reuse")
    p.add_argument("--threads", type=int, default=1, help="numba threads (default 1)")
    p.add_argument("--max-threads", type=int, default=None,
                   help="take up to this many threads while the machine has idle cores (no "
                        "number changes; default $GRANFLOW_MAX_THREADS, set by the workflow)")
    p.add_argument("--core-lease", default=None, metavar="DIR",
                   help="lock folder shared with other runs, so that together they take at "
                        "most --max-threads threads (default $GRANFLOW_CORE_LEASE)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--from", dest="from_state", default=None, metavar="STATE",
                     help="restart from a saved final_state.npz at the inclination of the "
                          "parameter file (clock reset to 0; outputs name the parent run)")
    src.add_argument("--from-if-steady", dest="from_if_steady", default=None, metavar="STATE",
                     help="as --from when the parent run (summary.json beside STATE) ended "
                          "steady; otherwise a fresh fall onto --base, and the outputs say why")
    p.add_argument("--top-up", action="store_true",
                   help="with --from: pour the flow particles that the state lacks for the "
                        "parameter file's H on top of it, at rest, its contacts kept (the "
                        "paper's §6 staircase adds 2 particle heights to an arrested pile)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("prepare-base", help="prepare a rough base for one lambda")
    p.add_argument("--lam", type=float, required=True)
    p.add_argument("--Lx", type=float, default=20.0)
    p.add_argument("--Ly", type=float, default=10.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--base-layers", type=float, default=12.0)
    p.add_argument("--settle-time", type=float, default=30.0)
    p.add_argument("--settle-mu-c", type=float, default=None,
                   help="sliding friction of the settling species (default 0.5; MercuryDPM's "
                        "ChuteBottom 0)")
    p.add_argument("--fill-packing", type=float, default=None,
                   help="solid fraction the pile is sized for (default 0.6)")
    p.add_argument("--band", default=None, choices=("paper", "top"),
                   help="slice of the settled pile kept: paper ([layers - 2.7, layers - 1] "
                        "lambda, default) or top (MercuryDPM's ChuteBottom)")
    p.add_argument("--out", required=True, help="output .npy file")
    p.set_defaults(func=cmd_prepare_base)

    p = sub.add_parser("demo", help="short demonstration chute run")
    p.add_argument("--out", default="results/demo")
    p.add_argument("--H", type=float, default=6.0)
    p.add_argument("--t-end", type=float, default=20.0)
    p.add_argument("--threads", type=int, default=1)
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser("ingest", help="bring another code's chute run into granflow")
    isub = p.add_subparsers(dest="source", required=True)
    p = isub.add_parser(
        "lammps", help="a LAMMPS chute run: per-atom and pair dumps -> series.nc, profiles.nc, "
                       "summary.json (see granflow.lammps.ingest for the dump commands)")
    p.add_argument("dumps", nargs="+", help="per-atom dump file(s) and pair (dump local) file(s), "
                                           "any order; .gz allowed")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--theta", type=float, required=True, help="inclination in degrees (gravity "
                   "(sin theta, 0, -cos theta), x downslope)")
    p.add_argument("--base-types", type=int, nargs="+", default=None,
                   help="atom types of the frozen base (default: types that do not move)")
    p.add_argument("--dt", type=float, default=None, help="time step (dump units) when the dumps "
                   "have no ITEM: TIME")
    p.add_argument("--gravity", type=float, default=1.0, help="|g| of the run (dump units)")
    p.add_argument("--kn", type=float, default=None, help="normal contact stiffness of every "
                   "pair (dump units), for the elastic energy E_ela")
    p.add_argument("--t-c", type=float, default=None, help="or: the flow species' collision "
                   "time (granflow units) ...")
    p.add_argument("--e", type=float, default=None, help="... and restitution (default 0.88)")
    p.add_argument("--kt-over-kn", type=float, default=2.0 / 7.0)
    p.add_argument("--pair-columns", default=None, help="comma-separated names of the pair "
                   "dump's columns (default id1,id2,dist,dx,dy,dz,fx,fy,fz,ftx,fty,ftz)")
    p.add_argument("--t-start", type=float, default=None, help="ignore snapshots before this "
                   "time (granflow units)")
    p.add_argument("--z-origin", type=float, default=None, help="height (dump units) that "
                   "becomes z = 0 (default: the highest base-particle centre)")
    for name, kind, what in (("averaging-time", float, "averaging time after the steady onset "
                                                       "(default 100)"),
                             ("check-every", float, "time between steady-state checks (10)"),
                             ("min-accelerating-time", float, "earliest accelerating verdict"),
                             ("cg-width", float, "coarse-graining width (0.25)"),
                             ("cg-dz", float, "z spacing of the profiles (0.05)"),
                             ("cg-window", float, "time window of the spreads (10)"),
                             ("cg-every", int, "coarse-grain every n-th snapshot (1)"),
                             ("cg-base-line", str, "flow-base stress path (contact_then_down)")):
        p.add_argument(f"--{name}", type=kind, default=None, help=what)
    p.set_defaults(func=cmd_ingest_lammps)
    from .campaign.commands import register as _register_campaign
    _register_campaign(sub)

    args = parser.parse_args(argv)
    _setup_logging(args.verbose)
    if argv is None:  # a command-line process (not a call from Python): stop with its workflow
        watch_workflow()
    try:
        args.func(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"granflow {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # permission denied, no space left, ...: the message names the file
        print(f"granflow {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
