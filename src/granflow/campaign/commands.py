"""``granflow campaign <command>``: the steps the Snakemake workflow runs (and users may too).

=============  ======================================================================
command        what it does
=============  ======================================================================
check-config   validate campaign configuration file(s) (merged in order) against the schema
expand         list the run directories a configuration defines
run-params     write one run's ``params.yaml`` (input of ``granflow simulate``)
warm-engine    compile the campaign's kernels by tiny runs (beside the base job; no results)
row            one campaign-table row from a finished run (+ Ps fit for bidisperse runs)
hstop-step     one step of the adaptive hstop search
hstop-bisect   one step of an hstop bisection chain at one filling height
collect        rows -> campaign table (netCDF + CSV), excluded runs, segregation fits
fit            every closure fit of the table -> fits.json + closures.csv
library        write (or reuse) the versioned closure library; copy it to a fixed path
report         execute the report notebook into HTML
=============  ======================================================================
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def _merged_config(paths):
    from .config import load_yaml

    cfg: dict = {}
    for p in paths:
        _merge(cfg, load_yaml(p))
    return cfg


def _merge(a: dict, b: dict):
    """Snakemake's config merge: nested mappings merged, everything else replaced."""
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(a.get(k), dict):
            _merge(a[k], v)
        else:
            a[k] = v


def cmd_check_config(args):
    from .config import check_config, default_schema_path
    from .grid import expand_runs

    cfg = _merged_config(args.config)
    check_config(cfg, args.schema or default_schema_path())
    print(f"configuration OK: campaign {cfg['name']!r}, {len(expand_runs(cfg))} grid runs")


def cmd_expand(args):
    from .config import check_config, default_schema_path
    from .grid import base_path, expand_runs

    cfg = _merged_config(args.config)
    check_config(cfg, args.schema or default_schema_path())
    for p in expand_runs(cfg):
        print(f"results/{cfg['name']}/{p.path}" + (f"   (base {base_path(cfg, p)})"
                                                   if args.bases else ""))


def cmd_run_params(args):
    import yaml

    from ..provenance import atomic_write_bytes
    from ..simulate import checkpoint_identity, validate_params

    params = json.loads(args.json)
    validate_params(dict(params))  # fail here, before the job, with the key and its range
    text = yaml.safe_dump(params, sort_keys=True)
    out = Path(args.out)
    ckpt = out.parent / "checkpoint.npz"
    if out.exists() and out.read_text() != text and ckpt.exists():
        if checkpoint_identity(ckpt) is None:
            # written before checkpoints stored their run: other parameters, unverifiable
            ckpt.unlink()
            print(f"{out}: parameters changed; removed the stale {ckpt} (it does not say "
                  "which parameters wrote it)", file=sys.stderr)
        else:  # granflow simulate resumes it only if the physics is the same
            print(f"{out}: parameters changed; {ckpt} is kept for granflow simulate, which "
                  "resumes it only if just the stopping parameters changed "
                  "(granflow.simulate.keep_matching_checkpoint)", file=sys.stderr)
    atomic_write_bytes(out, text.encode())


def cmd_warm_engine(args):
    from .warm import warm_engine

    rec = warm_engine(json.loads(args.config_json), args.out)
    print("compile-warm: " + ", ".join(f"{r['run']} {r['seconds']:g} s" for r in rec["runs"]))


def cmd_row(args):
    from .collect import write_row

    res = write_row(args.run_dir, args.out, rel=args.rel,
                    segregation_window=args.segregation_window)
    row = res["row"]
    extra = f", Ps = {row['Ps']:.4g}" if res["segregation_fit"] is not None else ""
    print(f"{row['run']}: {row['state']}, h = {row['h']:.4g}, F = {row['F']:.4g}{extra}"
          + (f" (excluded: {res['excluded']})" if res["excluded"] else ""))


def cmd_hstop_step(args):
    from . import hstop as hs

    if args.state is None:
        state = hs.init_state(args.law, args.lam, json.loads(args.settings or "{}"))
    else:
        if args.summary is None:
            raise ValueError("hstop-step --state needs --summary of the proposed run")
        state = hs.step_state(hs.read_state(args.state), args.summary, args.run)
    hs.write_state(state, args.out)
    nxt = hs.next_point(state)
    last = state.get("last")
    print(f"hstop search {args.law} lambda={args.lam} step {state['step']}: "
          + (f"{last['run']} {last['flow_state']}; " if last else "")
          + (f"next {nxt.path}" if nxt else f"finished ({state['search']['done_reason']})"))


def cmd_bisect_step(args):
    from . import hstop as hs

    if args.state is None:
        state = hs.init_bisection(args.law, args.lam, args.H, json.loads(args.settings or "{}"),
                                  replicate=args.replicate)
    else:
        if args.summary is None:
            raise ValueError("hstop-bisect --state needs --summary of the proposed run")
        state = hs.bisection_step(hs.read_state(args.state), args.summary, args.run)
    hs.write_state(state, args.out)
    nxt = hs.bisection_next_point(state)
    last = state.get("last")
    print(f"hstop bisection {args.law} lambda={args.lam} H={args.H} replicate "
          f"{state.get('replicate', 0)} step {state['step']}: "
          + (f"{last['run']} {last['flow_state']}; " if last else "")
          + (f"next {nxt.path}" if nxt else f"finished ({state['bisection']['note']})"))


def cmd_collect(args):
    from .collect import collect_table

    rows = list(args.rows)
    if args.rows_from:
        rows += [line.strip() for line in Path(args.rows_from).read_text().splitlines()
                 if line.strip()]
    attrs = {"title": f"granflow campaign table {args.campaign}", "campaign": args.campaign}
    config = json.loads(args.config_json) if args.config_json else None
    table = collect_table(rows, args.out_nc, args.out_csv, args.excluded, args.segregation,
                          attrs=attrs, config=config)
    print(f"campaign table: {len(table)} runs -> {args.out_nc}, {args.out_csv}")


def cmd_fit(args):
    from .collect import read_excluded, read_table, segregation_fits
    from .fits import run_fits, write_fits

    table = read_table(args.table)
    seg = segregation_fits(args.segregation) if args.segregation else []
    excluded = read_excluded(args.excluded) if args.excluded else None
    windows = ({float(k): v for k, v in json.loads(args.windows_json).items()}
               if args.windows_json else None)
    fits = run_fits(table, seg, n_bootstrap=args.n_bootstrap, seed=args.seed, excluded=excluded,
                    windows=windows)
    if not fits:
        raise ValueError(f"{args.table} has no run with a decided flow state (see "
                         "excluded_runs.csv next to it): there is nothing to fit")
    write_fits(fits, args.out_json, args.out_csv)
    for r in fits:
        where = ", ".join(f"{k}={v}" for k, v in sorted(r.coords.items()))
        vals = ", ".join(f"{k}={v:.4g}+-{r.stderr.get(k, float('nan')):.2g}"
                         f" [{r.param_status.get(k, '')}]" for k, v in r.params.items()
                         if r.param_status.get(k) not in ("not_in_form", "not_fitted"))
        print(f"{r.kind:>22} [{where}] {r.state} ({r.form}): {vals or r.message}")


def cmd_library(args):
    from .collect import read_table
    from .fits import read_fits
    from .library import publish_library

    fits = read_fits(args.fits)
    table = read_table(args.table)
    config = json.loads(args.config_json) if args.config_json else None
    attrs = {"campaign": args.campaign} if args.campaign else {}
    if args.excluded:
        from .collect import read_excluded

        ex = read_excluded(args.excluded)
        keep = [c for c in ("run", "theta", "H", "lam", "sigma", "contact_law", "state", "reason")
                if c in ex]
        attrs["excluded_runs_json"] = ex[keep].to_json(orient="records")
    from .reductions import reductions_vs_paper

    if args.reductions:
        attrs["library_note"] = args.reductions
    info = publish_library(args.dir, args.name, fits, table, out=args.out,
                           manifest=args.manifest, config=config,
                           reductions=reductions_vs_paper(config, fits), attrs=attrs)
    print(f"closure library {info['name']} v{info['version']} "
          f"({'reused: same content' if info['reused'] else 'new version'}) {info['path']}")


def cmd_report(args):
    from .report import render_report

    params = {"RESULTS": str(Path(args.results).resolve()), "CAMPAIGN": args.campaign,
              "FIGURES": str(Path(args.figures).resolve()) if args.figures else None}
    if args.figures:
        Path(args.figures).mkdir(parents=True, exist_ok=True)
    render_report(args.notebook, args.out_html, params, out_ipynb=args.out_ipynb,
                  cwd=args.results, timeout=args.timeout)
    print(f"report: {args.out_html}")


def register(subparsers):
    """Add ``granflow campaign ...`` to the top-level CLI's subparsers."""
    top = subparsers.add_parser("campaign", help="campaign workflow steps (used by Snakemake)",
                                description=__doc__,
                                formatter_class=__import__("argparse").RawDescriptionHelpFormatter)
    sub = top.add_subparsers(dest="campaign_command", required=True)

    p = sub.add_parser("check-config", help="validate campaign configuration file(s)")
    p.add_argument("config", nargs="+", help="YAML files, merged in order (as --configfile)")
    p.add_argument("--schema", default=None, help="JSON schema (default: workflow/schemas/...)")
    p.set_defaults(func=cmd_check_config)

    p = sub.add_parser("expand", help="list the run directories of a configuration")
    p.add_argument("config", nargs="+")
    p.add_argument("--schema", default=None)
    p.add_argument("--bases", action="store_true", help="also show each run's base file")
    p.set_defaults(func=cmd_expand)

    p = sub.add_parser("run-params", help="write one run's params.yaml")
    p.add_argument("--json", required=True, help="run parameters as a JSON object")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_run_params)

    p = sub.add_parser("warm-engine", help="compile the campaign's kernels (tiny runs)")
    p.add_argument("--config-json", required=True, help="the campaign configuration (JSON)")
    p.add_argument("--out", required=True, help="record of the warm-up runs (JSON)")
    p.set_defaults(func=cmd_warm_engine)

    p = sub.add_parser("row", help="campaign-table row of a finished run")
    p.add_argument("run_dir")
    p.add_argument("--rel", default=None, help="run directory relative to the campaign folder")
    p.add_argument("--segregation-window", type=float, default=100.0,
                   help="time window (end of run) of the segregation profile")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_row)

    p = sub.add_parser("hstop-step", help="one step of the adaptive hstop search")
    p.add_argument("--law", required=True)
    p.add_argument("--lam", type=float, required=True)
    p.add_argument("--settings", default=None, help="HstopSearch settings (JSON), step 0")
    p.add_argument("--state", default=None, help="previous state (omit for step 0)")
    p.add_argument("--summary", default=None, help="summary.json of the proposed run")
    p.add_argument("--run", default=None, help="that run's directory (checked)")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_hstop_step)

    p = sub.add_parser("hstop-bisect", help="one step of an hstop bisection chain (one H)")
    p.add_argument("--law", required=True)
    p.add_argument("--lam", type=float, required=True)
    p.add_argument("--H", type=float, required=True)
    p.add_argument("--replicate", type=int, default=0, help="replicate k (insertion seed + k)")
    p.add_argument("--settings", default=None, help="bisection settings (JSON), step 0")
    p.add_argument("--state", default=None, help="previous state (omit for step 0)")
    p.add_argument("--summary", default=None, help="summary.json of the proposed run")
    p.add_argument("--run", default=None, help="that run's directory (checked)")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_bisect_step)

    p = sub.add_parser("collect", help="campaign table from row files")
    p.add_argument("rows", nargs="*")
    p.add_argument("--rows-from", default=None, help="file listing row files, one a line")
    p.add_argument("--campaign", default="")
    p.add_argument("--out-nc", required=True)
    p.add_argument("--out-csv", required=True)
    p.add_argument("--excluded", default=None)
    p.add_argument("--segregation", default=None)
    p.add_argument("--config-json", default=None,
                   help="the campaign configuration (JSON): config hash, attribution")
    p.set_defaults(func=cmd_collect)

    p = sub.add_parser("fit", help="all closure fits of a campaign table")
    p.add_argument("--table", required=True)
    p.add_argument("--segregation", default=None, help="per-run segregation fits (collect)")
    p.add_argument("--excluded", default=None,
                   help="excluded runs (collect); undecided ones count as flowing for hstop")
    p.add_argument("--n-bootstrap", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--windows-json", default=None,
                   help="the disordered window per lambda (JSON {lambda: {delta3: [{H_max, "
                        "theta}, ...], delta_acc}}, Eq. 46, 48): the steady closures use only "
                        "runs inside it")
    p.add_argument("--out-json", required=True)
    p.add_argument("--out-csv", default=None)
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("library", help="versioned closure library (reused if same content)")
    p.add_argument("--fits", required=True)
    p.add_argument("--table", required=True)
    p.add_argument("--excluded", default=None, help="excluded runs (stored as an attribute)")
    p.add_argument("--dir", required=True, help="folder of the versioned files")
    p.add_argument("--name", required=True)
    p.add_argument("--out", default=None, help="fixed-path copy of the chosen version")
    p.add_argument("--manifest", default=None, help="JSON naming the chosen version")
    p.add_argument("--reductions", default=None,
                   help="free-text note stored as library_note (reductions_vs_paper is "
                        "generated from the configuration and the fits)")
    p.add_argument("--campaign", default=None)
    p.add_argument("--config-json", default=None)
    p.set_defaults(func=cmd_library)

    p = sub.add_parser("report", help="execute the report notebook into HTML")
    p.add_argument("--notebook", required=True, help="jupytext percent script")
    p.add_argument("--results", required=True, help="campaign results folder")
    p.add_argument("--campaign", default="")
    p.add_argument("--out-html", required=True)
    p.add_argument("--out-ipynb", default=None)
    p.add_argument("--figures", default=None, help="folder for the PNG figures")
    p.add_argument("--timeout", type=int, default=600)
    p.set_defaults(func=cmd_report)
    return top


if __name__ == "__main__":  # pragma: no cover
    from ..cli import main

    sys.exit(main(["campaign", *sys.argv[1:]]))
