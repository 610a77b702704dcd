"""Campaign configuration checks with messages that name the key and its allowed range.

:func:`check_config` validates a configuration mapping against the workflow's JSON schema
(``workflow/schemas/config.schema.yaml``; the Snakefile then also runs
``snakemake.utils.validate`` on it) and adds the cross-field checks a schema cannot express
(box at least 3 lambda wide, hstop search bounds ordered, averaging time and segregation
profile window within t_end, at least three size ratios for the Ps(sigma) law, at least one
run, ``engine: lammps`` only with the laws and bases LAMMPS runs and LAMMPS installed).  Every error reads
like ``config key campaigns.chute.grids[0].theta[1] = 95: must be < 90; allowed: inclination
theta in degrees, in (0, 90)``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import yaml

from .grid import campaign_cfg, enabled, expand_runs

#: the Ps(sigma) law T-eq. (29) has two parameters: at least three size ratios in (0, 1)
MIN_PS_LAW_RATIOS = 3


def load_yaml(path) -> dict:
    """Read a YAML configuration file (a mapping); errors name the file and what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"configuration file {str(path)!r} does not exist"
                                + (" (it is a folder)" if path.is_dir() else ""))
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
    except yaml.YAMLError as exc:
        raise ValueError(f"configuration file {str(path)!r} is not valid YAML: "
                         f"{_short(str(exc), 400)}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"configuration file {str(path)!r} is not UTF-8 text ({exc.reason} at "
                         f"byte {exc.start})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f"configuration file {str(path)!r} holds a {type(data).__name__}, not "
                         "a mapping of configuration keys")
    return data


def _short(text: str, n: int = 200) -> str:
    return text if len(text) <= n else text[: n - 3] + "..."


def _key(path) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "<top level>"


def _describe(err) -> str:
    v = err.validator
    s = err.schema if isinstance(err.schema, dict) else {}
    desc = s.get("description", "")
    if v == "additionalProperties":
        allowed = sorted((s.get("properties") or {}).keys())
        extra = (sorted(set(err.instance) - set(allowed), key=repr)
                 if isinstance(err.instance, dict) else [])
        return (f"unknown key(s) {extra} in {_key(err.absolute_path)}; allowed keys: {allowed}")
    if v == "required":
        return f"{_key(err.absolute_path)}: {err.message}"
    where = _key(err.absolute_path)
    what = {
        "exclusiveMinimum": f"must be > {err.validator_value}",
        "minimum": f"must be >= {err.validator_value}",
        "exclusiveMaximum": f"must be < {err.validator_value}",
        "maximum": f"must be <= {err.validator_value}",
        "enum": f"must be one of {err.validator_value}",
        "type": f"must be of type {err.validator_value}",
    }.get(v, err.message)
    return (f"config key {where} = {_short(repr(err.instance))}: {what}"
            + (f"; allowed: {desc}" if desc else ""))


def schema_errors(config: dict, schema) -> list[str]:
    """All schema violations of ``config`` as readable one-line messages (empty if valid)."""
    import jsonschema

    if not isinstance(schema, dict):
        schema = load_yaml(schema)
    cls = jsonschema.validators.validator_for(schema)
    validator = cls(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: list(map(str, e.absolute_path)))
    return [_describe(e) for e in errors]


def non_finite_errors(config, path=()) -> list[str]:
    """NaN and infinite numbers anywhere in ``config`` (JSON schema range checks let NaN
    through: every comparison with NaN is false)."""
    out = []
    if isinstance(config, dict):
        for k, v in config.items():
            out += non_finite_errors(v, (*path, k))
    elif isinstance(config, (list, tuple)):
        for i, v in enumerate(config):
            out += non_finite_errors(v, (*path, i))
    elif isinstance(config, float) and not math.isfinite(config):
        out.append(f"config key {_key(path)} = {config!r}: not a finite number; allowed: a "
                   "finite number in the range the schema states for this key")
    return out


def run_errors(config: dict, check_machine: bool = True) -> list[str]:
    """Every grid run of ``config`` (and the first and largest points of the adaptive hstop
    search) checked as ``granflow simulate`` will check it (:func:`granflow.simulate.
    validate_params`: ranges of derived values, number of time steps, memory), so that a run
    that would be refused is refused before any job starts.  The memory limit is
    ``cluster.resources.simulate.mem_mb`` when the configuration sets it (the job's share of a
    cluster node), otherwise this machine's memory."""
    from ..simulate import validate_params
    from .grid import RunPoint, run_params

    points = list(expand_runs(config))
    chute = campaign_cfg(config, "chute")
    search = chute.get("hstop_search") or {}
    if enabled(config, "chute") and search.get("enabled"):
        for law in chute.get("contact_law") or ["linear"]:
            for lam in search.get("lambda") or chute.get("lambda") or [1.0]:
                for theta, H in ((search.get("theta0", 21.0), search.get("H0", 4.0)),
                                 (search.get("theta_max", 40.0), search.get("H_max", 40.0))):
                    points.append(RunPoint("chute", str(law), float(lam), float(theta), float(H)))
    mem_mb = (((config.get("cluster") or {}).get("resources") or {}).get("simulate") or {}
              ).get("mem_mb")
    first, count = {}, {}  # message -> first run with it, number of runs
    for p in points:
        params = run_params(config, p)
        try:
            checked = validate_params(dict(params), check_machine=check_machine and mem_mb is None)
            if check_machine and mem_mb is not None:
                from ..simulate import estimate_run_size

                need = estimate_run_size(checked)["memory_bytes"]
                if need > mem_mb * 1e6:
                    raise ValueError(f"the run needs about {need / 1e6:.0f} MB of memory, more "
                                     f"than cluster.resources.simulate.mem_mb = {mem_mb}; allowed:"
                                     " a mem_mb request at least the run's estimate")
        except ValueError as exc:
            first.setdefault(str(exc), p.path)
            count[str(exc)] = count.get(str(exc), 0) + 1
    return [f"run {first[m]}: {m}" + (f" (and {count[m] - 1} more runs)" if count[m] > 1 else "")
            for m in first]


def semantic_errors(config: dict) -> list[str]:
    """Cross-field checks the schema cannot express."""
    out = []
    for kind in ("chute", "segregation"):
        c = campaign_cfg(config, kind)
        if not enabled(config, kind):
            continue
        Lx, Ly = float(c.get("Lx", 20.0)), float(c.get("Ly", 10.0))
        lams = []
        if kind == "chute":
            lams = list(c.get("lambda") or [1.0])
            for block in (c.get("grids") or []) + (c.get("points") or []):
                lams += list(block.get("lambda") or [])
            lams += list((c.get("hstop_search") or {}).get("lambda") or [])
        else:
            lams = [c.get("lambda", 1.0)]
        for lam in lams:
            if lam > 0 and (Lx < 3 * lam or Ly < 3 * lam):
                out.append(f"config key campaigns.{kind}.Lx/Ly = {Lx}, {Ly}: the box must be at "
                           f"least 3 lambda = {3 * lam} wide for lambda = {lam}")
        if kind == "segregation" and "sigma" not in c:
            out.append("config key campaigns.segregation.sigma is missing: give the size ratios")
        if kind == "segregation" and "sigma" in c:
            ratios = sorted({float(x) for x in c["sigma"] if 0 < float(x) < 1})
            if len(ratios) < MIN_PS_LAW_RATIOS:
                out.append(f"config key campaigns.segregation.sigma = {list(c['sigma'])}: the "
                           f"Ps(sigma) law (Thornton et al. T-eq. 29, two parameters) needs at "
                           f"least {MIN_PS_LAW_RATIOS} distinct size ratios in (0, 1), got "
                           f"{len(ratios)}; allowed: sigma in (0, 1], sigma = 1 is the "
                           "no-segregation control and does not count")
        if kind == "segregation" and any(k not in c for k in ("theta", "H")):
            out.append("config keys campaigns.segregation.theta and .H are required when the "
                       "segregation campaign is enabled")
        if c.get("engine") == "lammps":
            out += _lammps_errors(kind, c, lams)
            if kind == "chute" and c.get("restart_from_neighbour"):
                out.append("config key campaigns.chute.restart_from_neighbour = true with engine "
                           "'lammps': neighbour restarts (--from-if-steady) are run by the "
                           "numba engine only (a LAMMPS restart does not carry the tangential "
                           "springs); allowed: false, or engine 'numba'")
        if kind == "chute":
            b = c.get("hstop_bisection") or {}
            if b.get("enabled"):
                from .hstop import bisection_replicate_errors
                out += bisection_replicate_errors(b)
                bx, by = float(b.get("Lx", Lx)), float(b.get("Ly", Ly))
                for lam in list(b.get("lambda") or c.get("lambda") or [1.0]):
                    if ("Lx" in b or "Ly" in b) and lam > 0 and (bx < 3 * lam or by < 3 * lam):
                        out.append(f"config key campaigns.chute.hstop_bisection.Lx/Ly = {bx}, "
                                   f"{by}: the box must be at least 3 lambda = {3 * lam} wide "
                                   f"for lambda = {lam}")
            if b.get("enabled") and b.get("replicate_bases"):
                from .grid import replicates

                blocks = (c.get("grids") or []) + (c.get("points") or [])
                n_grid = max([replicates(config, "chute")]
                             + [int(x.get("replicates", 1)) for x in blocks])
                if n_grid > 1:
                    out.append("config key campaigns.chute.hstop_bisection.replicate_bases = true "
                               f"with chute grid replicates ({n_grid}): a grid run of replicate "
                               "k lies on the campaign's base, the bracket chain k on base "
                               "seed + k, and the hstop fit would join them into one bracket; "
                               "allowed: replicate_bases false, or unreplicated grid runs")
            s = c.get("hstop_search") or {}
            if s.get("enabled") and s.get("theta_min", 5.0) >= s.get("theta_max", 40.0):
                out.append("config keys campaigns.chute.hstop_search.theta_min/theta_max: "
                           "theta_min must be below theta_max")
    out += _window_errors(config)
    out += _time_errors(config)
    search_on = enabled(config, "chute") and bool(
        (campaign_cfg(config, "chute").get("hstop_search") or {}).get("enabled"))
    if not out and not expand_runs(config) and not search_on:
        out.append("the configuration defines no runs: enable a campaign with a non-empty grid")
    return out


def _window_errors(config: dict) -> list[str]:
    """``library.disordered_window``: steps in increasing H_max, only the last without one, and
    delta_acc above every delta3 (the schema has checked each number's range)."""
    out = []
    for lam, w in ((config.get("library") or {}).get("disordered_window") or {}).items():
        key = f"config key library.disordered_window.{lam}"
        try:
            lam_v = float(lam)
        except (TypeError, ValueError):
            out.append(f"{key}: the key must be a basal roughness lambda (a number in [0, 10])")
            continue
        if not 0 <= lam_v <= 10:
            out.append(f"{key}: lambda {lam_v:g} outside the allowed range [0, 10]")
        steps = list((w or {}).get("delta3") or [])
        if any("H_max" not in s for s in steps[:-1]):
            out.append(f"{key}.delta3: only the last step may omit H_max (it covers every "
                       "thicker layer)")
            continue
        h = [float(s["H_max"]) for s in steps if "H_max" in s]
        if any(b <= a for a, b in zip(h, h[1:])):
            out.append(f"{key}.delta3: H_max must increase from step to step (got {h})")
        acc = (w or {}).get("delta_acc")
        thetas = [float(s["theta"]) for s in steps if "theta" in s]
        if acc is not None and thetas and float(acc) <= max(thetas):
            out.append(f"{key}.delta_acc = {float(acc):g}: must lie above every delta3 "
                       f"(largest {max(thetas):g} deg), or no run could enter the steady "
                       "closures")
    return out


def _lammps_errors(kind: str, c: dict, lams) -> list[str]:
    """``engine: lammps``: the laws and bases LAMMPS can run, and LAMMPS installed."""
    from ..lammps.runner import LammpsNotFound, find_lammps
    from ..lammps.species import SUPPORTED_LAWS

    out = []
    laws = list(c.get("contact_law") or ["linear"])
    for block in (c.get("grids") or []) + (c.get("points") or []):
        laws += list(block.get("contact_law") or [])
    bad = sorted({str(x) for x in laws} - set(SUPPORTED_LAWS))
    if bad:
        out.append(f"config key campaigns.{kind}.engine = 'lammps' with contact_law {bad}: "
                   f"allowed with LAMMPS: {list(SUPPORTED_LAWS)} (no Walton-Braun plastic law "
                   "in LAMMPS pair_style granular)")
    if any(float(x) == 0 for x in lams):
        out.append(f"config key campaigns.{kind}.engine = 'lammps' with lambda = 0 (flat "
                   "wall): allowed with LAMMPS: lambda in (0, 10] (a rough base)")
    try:
        find_lammps()
    except LammpsNotFound as exc:
        out.append(f"config key campaigns.{kind}.engine = 'lammps': {exc}")
    return out


def _time_errors(config: dict) -> list[str]:
    """averaging_time (and the segregation profile_window) must fit into t_end, per campaign
    (top-level numerics overridden by the campaign's own numerics)."""
    out = []
    top = config.get("numerics") or {}
    for kind in ("chute", "segregation"):
        if not enabled(config, kind):
            continue
        c = campaign_cfg(config, kind)
        own = c.get("numerics") or {}

        def where(key):
            return f"campaigns.{kind}.numerics.{key}" if key in own else f"numerics.{key}"

        t_end = own.get("t_end", top.get("t_end"))
        checks = [("averaging_time", own.get("averaging_time", top.get("averaging_time")),
                   where("averaging_time"))]
        if kind == "segregation" and c.get("profile_window") is not None:
            checks.append(("profile_window", c["profile_window"],
                           "campaigns.segregation.profile_window"))
        for _, value, key in checks:
            if t_end is not None and value is not None and float(value) > float(t_end):
                out.append(f"config key {key} = {value} is longer than the run, "
                           f"{where('t_end')} = {t_end}; allowed: at most t_end (the average "
                           f"is taken over the last {key.split('.')[-1]} time units of a run)")
    return out


def check_config(config: dict, schema, check_machine: bool = True) -> dict:
    """Raise ValueError listing every problem of ``config`` (non-finite numbers, schema,
    cross-field checks, then every run as ``granflow simulate`` checks it: :func:`run_errors`).
    """
    if not isinstance(config, dict):
        raise ValueError("invalid campaign configuration:\n  the configuration is a "
                         f"{type(config).__name__}, not a mapping of keys")
    errors = non_finite_errors(config)
    if not errors:
        errors = schema_errors(config, schema)
    if not errors:
        errors = semantic_errors(config)
    if not errors:
        errors = run_errors(config, check_machine=check_machine)
    if errors:
        raise ValueError("invalid campaign configuration:\n  " + "\n  ".join(errors))
    return config


def shadowed_numerics(config: dict, default: dict) -> list[str]:
    """Global ``numerics`` keys a configuration changed that never reach some of its runs.

    A campaign's own ``numerics`` block overrides the global one key by key
    (:func:`granflow.campaign.grid.run_params`), and Snakemake merges a ``--configfile`` over
    the embedded default (``config/config.yaml``), whose campaign blocks set keys of their own
    (the segregation block's ``t_end``, ``averaging_time``, ``cg_window``).  A key the merged
    ``config`` sets globally to something other than ``default`` does, while an enabled
    campaign keeps the default's own override of it, is silently not applied to that
    campaign's runs: one message per such key and campaign, naming the key to set instead.
    """
    g_new = config.get("numerics") or {}
    g_old = default.get("numerics") or {}
    out = []
    for kind in ("chute", "segregation"):
        if not enabled(config, kind):
            continue
        c_new = campaign_cfg(config, kind).get("numerics") or {}
        c_old = campaign_cfg(default, kind).get("numerics") or {}
        for key in sorted(set(g_new) & set(c_new)):
            changed = key not in g_old or g_old[key] != g_new[key]
            kept = key in c_old and c_old[key] == c_new[key]
            if changed and kept and c_new[key] != g_new[key]:
                out.append(f"numerics.{key} = {g_new[key]!r} does not reach the {kind} runs: "
                           f"the default's campaigns.{kind}.numerics.{key} = {c_new[key]!r} "
                           f"overrides it; set campaigns.{kind}.numerics.{key} to change it")
    return out


def default_schema_path() -> Path:
    """The workflow schema next to the source tree (for checks outside Snakemake)."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        cand = parent / "workflow" / "schemas" / "config.schema.yaml"
        if cand.is_file():
            return cand
    raise FileNotFoundError("workflow/schemas/config.schema.yaml not found above "
                            f"{here.parent}; pass the schema path explicitly")


def check_results_folder(config: dict, results) -> float:
    """Fail unless the campaign's results folder is writable and has room for the outputs of
    the runs that are not finished yet (:func:`granflow.simulate.estimate_run_size`, summed;
    runs with a ``summary.json`` count as done).  Creates nothing.  Returns the estimate."""
    from ..simulate import check_output_folder, estimate_run_size, validate_params
    from .grid import run_params

    need, left = 0.0, 0
    for p in expand_runs(config):
        if os.path.exists(os.path.join(results, p.path, "summary.json")):
            continue
        params = validate_params(dict(run_params(config, p)), check_machine=False)
        need += estimate_run_size(params)["output_bytes"]
        left += 1
    check_output_folder(results, need, what=f"the campaign ({left} runs left)")
    return need
