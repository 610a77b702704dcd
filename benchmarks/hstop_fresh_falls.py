"""hstop brackets from fresh falls at chosen heights, with the base's species changed (issue 14).

The lambda = 1/2 reference (``config/reference-lambda-half.yaml``) brackets theta_stop(H) 1-2 deg
above Table 1 at H >= 12.  This script runs the campaign's own bisection chain
(:func:`granflow.campaign.hstop.init_bisection`, the configuration's ``hstop_bisection``
settings: first run at the prior's theta_stop(H), steps, bisection to ``tolerance``) at the
heights asked for, with one of two things about the base changed, so that each can be tested
as the cause:

* ``--base-species``: the flow-base contact species as a code with one set of *absolute*
  coefficients gives it (:func:`granflow.engine.species.flow_base_species`): ``per_pair``
  (granflow: every pair has t_c = 0.005, e = 0.88), ``absolute`` (absolute k_n and gamma_n of
  the flow-flow pair, as MercuryDPM's species: flow-base t_c = 0.00707, e = 0.914) or
  ``absolute_k_reduced_damping`` (Silbert et al. 2001, LAMMPS: t_c = 0.00708, e = 0.834);
* ``--base-prep-tc``, ``--base-prep-e``: the species the base's 12-layer pile settles with
  before its slice is cut (default: the engine's soft, strongly damped settling, t_c = 0.02
  sqrt(lambda), e = 0.2; the paper's own species would be 0.005, 0.88), with
  ``--base-settle-time`` (an elastic pile settles slowly), ``--base-prep-mu`` (its friction;
  MercuryDPM's ChuteBottom settles without) and ``--base-fill-packing`` (the solid fraction the
  pile is sized for, so that a denser settling still leaves ~12 layers); ``--base-band top``
  keeps MercuryDPM's slice (the 1.2 lambda below the highest centre minus lambda/2) instead of
  the paper's [9.3, 11] lambda.

The flow's insertion (``numerics.insertion_growth``, see :mod:`granflow.engine.chute`) is the
configuration's: pass a configuration file that sets it to test the initial column.

Every run is a fresh fall with the configuration's bracket-run parameters; runs are written as
campaign bracket runs (``<out>/bracket/<law>/lambda~L/theta~T/H~H``), so
``benchmarks/hstop_brackets.py <out>`` fits Eq. (45) to them; a rerun reuses finished runs.
Chains at different heights run side by side with ``--jobs``.

    .venv/bin/python benchmarks/hstop_fresh_falls.py --configfile config/reference-lambda-half.yaml \
        --lam 0.5 --H 16 24 --base-species absolute --out results/fresh-lambda-half-absolute

Prints each run (H, theta, flow state, stop time, wall time) and each height's bracket beside
Table 1's theta_stop(H).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from hstop_staircase import merged_config, table1_theta_stop  # noqa: E402


def configure(config: dict, base_species: str) -> dict:
    """``config`` with the flow-base species of ``base_species`` (a copy)."""
    from granflow.engine.species import ContactSpecies, flow_base_species

    cfg = json.loads(json.dumps(config))
    sp = cfg["species"]
    flow = ContactSpecies(t_c=float(sp["t_c"]), e=float(sp["e"]), mu_c=float(sp["mu_c"]),
                          kt_over_kn=float(sp["kt_over_kn"]), gt_over_gn=float(sp["gt_over_gn"]))
    if base_species != "per_pair":
        if any(sp.get(k) is not None for k in ("base_t_c", "base_e")):
            raise ValueError("--base-species replaces species.base_t_c and species.base_e, which "
                             "the configuration already sets: use one or the other")
        fb = flow_base_species(flow, base_species)
        sp["base_t_c"], sp["base_e"] = fb.t_c, fb.e
    return cfg


def run_chain(config: dict, law: str, lam: float, H: float, out: Path, base: Path,
              threads: int = 1) -> dict:
    """One height's bisection chain of fresh falls; returns its last chain state."""
    from granflow.campaign import grid as G
    from granflow.campaign import hstop as HS
    from granflow.simulate import simulate

    hb = G.campaign_cfg(config, "chute").get("hstop_bisection") or {}
    state = HS.init_bisection(law, lam, H, hb)
    while (point := HS.bisection_next_point(state)) is not None:
        run_dir = out / G.run_path(point)
        t0 = time.monotonic()
        if not (run_dir / "summary.json").exists():
            simulate(G.run_params(config, point), run_dir, base_file=base, threads=threads)
        state = HS.bisection_step(state, run_dir / "summary.json")
        s = json.loads((run_dir / "summary.json").read_text())
        print(f"H {H:5.1f} theta {point.theta:6.2f}: {s.get('flow_state'):>12} at t = "
              f"{s.get('t_final', math.nan):6.1f} ({time.monotonic() - t0:4.0f} s)", flush=True)
    return state


def _chain(job):
    return run_chain(*job)


def main(argv=None):
    from granflow.engine.species import FLOW_BASE_CONVENTIONS

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configfile", default=None, help="campaign configuration merged over "
                    "config/config.yaml (species, numerics, box, base, hstop_bisection)")
    ap.add_argument("--law", default="linear")
    ap.add_argument("--lam", type=float, required=True, help="basal roughness lambda")
    ap.add_argument("--H", type=float, nargs="+", required=True, help="filling heights")
    ap.add_argument("--out", required=True, help="results folder (runs under bracket/...)")
    ap.add_argument("--base-species", default="per_pair", choices=FLOW_BASE_CONVENTIONS)
    ap.add_argument("--base-prep-tc", type=float, default=None,
                    help="collision time the base pile settles with (x sqrt(lambda))")
    ap.add_argument("--base-prep-e", type=float, default=None,
                    help="restitution the base pile settles with")
    ap.add_argument("--base-prep-mu", type=float, default=None,
                    help="sliding friction the base pile settles with (MercuryDPM: 0)")
    ap.add_argument("--base-fill-packing", type=float, default=None,
                    help="solid fraction the base pile is sized for (its settled thickness is "
                    "base.layers lambda when it settles to it: ~0.6 frictional, ~0.65 frictionless)")
    ap.add_argument("--base-band", default=None, choices=("paper", "top"),
                    help="slice of the pile kept as the base: paper ([9.3, 11] lambda of the "
                    "nominal pile, default) or top (MercuryDPM: the 1.2 lambda below the "
                    "highest centre - lambda/2)")
    ap.add_argument("--base-settle-time", type=float, default=None,
                    help="longest settling of the base pile (x sqrt(lambda); default: the "
                    "configuration's base.settle_time)")
    ap.add_argument("--seed", type=int, default=None,
                    help="insertion seed of the flow (default: the configuration's numerics.seed)")
    ap.add_argument("--base-seed", type=int, default=None,
                    help="seed of the base realisation (default: the configuration's base.seed)")
    ap.add_argument("--jobs", type=int, default=1, help="chains run side by side")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs = {args.jobs}: must be at least 1")
    if args.base_species != "per_pair" and args.law != "linear":
        raise ValueError(f"--base-species {args.base_species} is defined for --law linear only "
                         f"(got --law {args.law}): allowed with other laws is per_pair")

    from granflow.campaign import grid as G
    from granflow.engine.chute import BaseConfig
    from granflow.simulate import prepare_base_file

    for name, value in (("--seed", args.seed), ("--base-seed", args.base_seed)):
        if value is not None and value < 0:
            raise ValueError(f"{name} = {value}: must be an integer >= 0")
    config = configure(merged_config(args.configfile), args.base_species)
    if args.seed is not None:
        config["numerics"] = dict(config.get("numerics") or {}, seed=args.seed)
    if args.base_seed is not None:
        config["base"] = dict(config.get("base") or {}, seed=args.base_seed)
    out = Path(args.out)
    Lx, Ly = G.box(config, "bracket")  # the runs are bracket runs: their box
    bcfg = G.base_settings(config)
    # the configuration's base (where it differs from BaseConfig's defaults), then the options
    defaults = BaseConfig()
    settling = {k: v for k, v in G.base_making(config).items() if v != getattr(defaults, k)}
    settling.update({k: v for k, v in (("prep_t_c", args.base_prep_tc),
                                       ("prep_e", args.base_prep_e),
                                       ("prep_mu_c", args.base_prep_mu),
                                       ("fill_packing", args.base_fill_packing),
                                       ("band", args.base_band)) if v is not None})
    settle_time = float(args.base_settle_time if args.base_settle_time is not None
                        else bcfg.get("settle_time", 30.0))
    BaseConfig(lam=args.lam, Lx=Lx, Ly=Ly, settle_time=settle_time,
               **settling).validate()  # bad input before any compute
    base = (out / "bases" / f"lambda~{G.format_value(args.lam)}"
            / f"box~{G.format_value(Lx)}x{G.format_value(Ly)}" / "base.npy")
    sp = config["species"]
    print(f"flow-base species ({args.base_species}): t_c = {sp.get('base_t_c') or sp['t_c']:.7g}, "
          f"e = {sp.get('base_e') or sp['e']:.6g}; base settled with "
          f"{settling or 'the default soft species'} for at most {settle_time:g} sqrt(lambda)",
          flush=True)
    # one results folder holds runs of one base and one flow-base species: refuse a mix
    made = {"base_species": args.base_species, "settling": settling, "settle_time": settle_time}
    made.update({k: v for k, v in (("seed", args.seed), ("base_seed", args.base_seed))
                 if v is not None})  # (older records, made without the options, stay valid)
    record = out / "fresh_falls.json"
    if record.exists() and json.loads(record.read_text()) != made:
        raise ValueError(f"{out} holds runs with {json.loads(record.read_text())}, not {made}: "
                         f"use another --out")
    out.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps(made))
    if not base.exists():
        prepare_base_file(args.lam, Lx, Ly, int(bcfg.get("seed", 1)), base,
                          base_layers=float(bcfg["layers"]),
                          settle_time=settle_time, **settling)
    jobs = [(config, args.law, args.lam, float(H), out, base, args.threads) for H in args.H]
    if args.jobs > 1 and len(jobs) > 1:
        from multiprocessing import get_context

        with get_context("spawn").Pool(min(args.jobs, len(jobs))) as pool:
            states = pool.map(_chain, jobs, chunksize=1)
    else:
        states = [_chain(j) for j in jobs]
    from granflow.steady.bisection import Bisection

    print(f"\n{'H':>5} {'theta_arr':>9} {'theta_flo':>9} {'consistent':>10} "
          f"{'Table 1 theta_stop':>18}  note")
    rows = []
    for st in states:
        b = Bisection.from_state_dict(st["bisection"])
        H, lo, hi, ok = b.interval()
        rows.append((H, lo, hi, ok))
        print(f"{H:5.1f} {lo:9.2f} {hi:9.2f} {ok!s:>10} {table1_theta_stop(args.lam, H):18.2f}"
              f"  {st['bisection'].get('note', '')}")
    return rows


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
