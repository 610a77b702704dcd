"""Not a timing: how a bidisperse run's Peclet number approaches its steady value, window by
window, and what that says about the steady Ps when the run ended before its segregated state
was shown steady (issue 14: the segregation reference's k needs 1/sigma = 1.1 and 1.25, whose
runs outlast a session).

For every full coarse-graining window of the run's ``profiles_history.nc`` (every window
from the start; a run older than that file: its ``profiles.nc``, the windows it averaged;
``cg_window`` long) Ps of
T-eq. (28) is fitted to that window's small-particle fraction phi(z) on the depth scaled over
that window's [b, s] of Eq. (42), exactly as :func:`granflow.campaign.collect.segregation_fit`
fits the mean profile of the last windows.  The series Ps(t) then says

* from which side the run approaches its steady Ps: a mixed start from below (Ps rises), a
  segregated start from above (Ps falls, the sharp interface broadening), so the last
  windows' Ps is a one-sided bound on the steady value (what the campaign fit uses for a
  ``drifting`` run, :func:`granflow.fitting.segregation.fit_Ps_law`'s ``one_sided``);
* whether the windows have stopped moving: over the last ``--flat-windows`` windows the
  linear trend (:func:`granflow.steady.timeseries.trend_test`, serial correlation allowed for)
  must change Ps by less than ``FLAT_REL_TOL`` of its mean, with its 90 % interval (an
  equivalence test, as the steady detector's).  A flat tail is a pause at least, not a
  proof of a plateau: at 1/sigma = 1.25 of the paper's set-up (2026-12-07) the run from above
  was flat at 5.83 over 550 time units and then fell to 5.66 within 150, the run from below
  rose to 5.59 and fell back to 5.39 (its 200-unit means scatter by 0.07, ten times the
  standard error of one such mean from its four windows): Ps wanders by 0.1-0.2 over hundreds
  of time units, so a tail's mean +- sem understates what it knows, and a "bound" from the
  last windows holds only to that wander;
* and, as an *extrapolation* (not a measurement), the plateau of a (stretched) exponential
  relaxation Ps(t) = Ps_inf + a exp(-((t - t_1) / tau)^beta) fitted to the windows after
  ``--t-from``
  (:func:`granflow.steady.segregation.relaxation_projection`, the steady detector's own
  projection, covariance inflated by the residuals' statistical inefficiency):
  ``Ps_inf +- stderr``, with the change still to come and its one-sided 95 % bound.

    .venv/bin/python benchmarks/segregation_approach.py RUN_DIR [--t-from 100] [--json OUT]
        [--checkpoint]   # every window so far, from the run's checkpoint.npz
        [--parent PARENT [--parent-time T]]   # a continuation (simulate --from): the
                                              # parent's windows first, this run's after T
        [--parent P0 --parent P1 ...]         # a chain of continuations, oldest first
        [--verdicts]   # the steady detector (this code's rule) replayed on series.nc

A run continued with ``granflow simulate --from STATE`` (same inclination, clock reset to 0)
is one approach in two pieces: ``--parent`` (the parent's run folder, read like RUN_DIR, or a
checkpoint ``.npz`` of it) puts the parent's windows first and shifts this run's by the
parent's end time (``--parent-time``, by default the ``parent_time`` this run's summary.json
records).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np


PREFIX = "extra__obs__profiles__"


def checkpoint_profiles(checkpoint):
    """Every coarse-graining window of a run so far, as a profiles dataset, from its
    ``checkpoint.npz`` (the profile observer's accumulator state: the final ``profiles.nc`` of
    a run whose segregated state is still drifting keeps only its last averaging time)."""
    from granflow.coarse.profiles import DepthProfileAccumulator

    with np.load(checkpoint, allow_pickle=False) as f:
        state = {k[len(PREFIX):]: f[k] for k in f.files if k.startswith(PREFIX)}
    if not state:
        raise ValueError(f"{checkpoint} holds no profile accumulator ({PREFIX}*)")
    state.pop("observer_calls", None)
    return DepthProfileAccumulator.from_state_dict(state).to_dataset()


def window_peclets(run_dir, sigma: float | None = None, min_fill: float = 0.5,
                   from_checkpoint: bool = False) -> dict:
    """Ps of T-eq. (28) per coarse-graining window of ``run_dir/profiles.nc`` (or, with
    ``from_checkpoint``, of every window so far in ``run_dir/checkpoint.npz``): arrays
    ``t_start``, ``t_mid`` (the windows' mean snapshot time), ``Ps``, ``Ps_stderr`` (the fit's), ``depth`` (s - b) over the
    windows holding at least ``min_fill`` of the fullest window's snapshots; a window whose
    fit fails gets NaN."""
    import xarray as xr

    from granflow.coarse.derived import flow_height
    from granflow.fitting import fit_Ps

    if Path(run_dir).suffix == ".npz":  # a checkpoint file itself
        ds = checkpoint_profiles(run_dir)
    elif from_checkpoint:
        ck = Path(run_dir) / "checkpoint.npz"
        if not ck.exists():
            done = (Path(run_dir) / "summary.json").exists()
            raise FileNotFoundError(
                f"{ck} does not exist" + (": the run has finished, which removes its "
                                          "checkpoint (leave out --checkpoint: its "
                                          "profiles_history.nc keeps every window, an "
                                          "older run's profiles.nc the last averaging time)"
                                          if done else ""))
        ds = checkpoint_profiles(ck)
    else:
        # a finished bidisperse run keeps every window in profiles_history.nc (granflow since
        # 2026-12-07); an older one only the windows its profiles.nc averaged
        path = Path(run_dir) / "profiles_history.nc"
        path = path if path.exists() else Path(run_dir) / "profiles.nc"
        with xr.open_dataset(path) as src:
            ds = src.load()
    small = int(ds.attrs.get("cg_small_species", 0))
    z = np.asarray(ds["z"].values, dtype=float)
    nu = np.asarray(ds["species_volume_fraction_window"].values, dtype=float)  # (w, s, z)
    szz = np.asarray(ds["stress_zz_window"].values, dtype=float)               # (w, z)
    counts = np.asarray(ds["window_n_snapshots"].values, dtype=float)
    starts = np.asarray(ds["window_time_start"].values, dtype=float)
    mean_t = (np.asarray(ds["window_mean_time"].values, dtype=float)
              if "window_mean_time" in ds else None)
    width = float(ds.attrs.get("cg_window_length", math.nan))
    width = width if width > 0 else math.nan
    use = counts >= min_fill * counts.max()
    out = {k: [] for k in ("t_start", "t_mid", "Ps", "Ps_stderr", "depth")}
    for w in np.nonzero(use)[0]:
        tot = nu[w].sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            phi = np.where(tot > 0, nu[w, small] / np.where(tot > 0, tot, 1.0), np.nan)
        b, s, _, _ = flow_height(z, szz[w])
        Ps = se = depth = math.nan
        if np.isfinite(b) and np.isfinite(s):
            inside = (z >= b) & (z <= s)
            fit = fit_Ps((z[inside] - b) / (s - b), phi[inside], sigma=sigma)
            if fit.ok:
                Ps, se, depth = fit.params["Ps"], fit.stderr["Ps"], s - b
        out["t_start"].append(float(starts[w]))
        out["t_mid"].append(float(mean_t[w]) if mean_t is not None
                            else float(starts[w]) + 0.5 * width)
        out["Ps"].append(Ps)
        out["Ps_stderr"].append(se)
        out["depth"].append(depth)
    return {k: np.asarray(v, dtype=float) for k, v in out.items()} | {"window": width}


def join_windows(parent: dict, child: dict, parent_time: float) -> dict:
    """The windows of a run continued from its parent's final state (clock reset to 0) on
    the parent's clock: the parent's windows, then the child's shifted by ``parent_time``
    (the parent's time at the saved state); ``piece`` says which run each window is from
    (0 parent, 1 continuation)."""
    return join_chain([parent, child], [parent_time])


def join_chain(pieces: list, parent_times: list) -> dict:
    """The windows of a chain of continuations on the first run's clock: ``pieces[0]`` the
    first run's windows, ``pieces[k]`` those of the run continued from ``pieces[k - 1]``'s
    saved state at that run's time ``parent_times[k - 1]`` (each continuation's clock reset
    to 0), so piece k is shifted by the sum of the first k parent times; ``piece`` is each
    window's k."""
    if len(parent_times) != len(pieces) - 1:
        raise ValueError(f"{len(pieces)} pieces need {len(pieces) - 1} parent times, "
                         f"got {len(parent_times)}")
    for t in parent_times:
        if not (math.isfinite(t) and t > 0):
            raise ValueError(f"parent_time = {t!r} is out of range: allowed a finite time > 0 "
                             "(the parent's time at the state the run continued from)")
    offsets = np.concatenate([[0.0], np.cumsum(np.asarray(parent_times, dtype=float))])
    out = {}
    for k in ("t_start", "t_mid", "Ps", "Ps_stderr", "depth"):
        out[k] = np.concatenate([np.asarray(w[k], dtype=float)
                                 + (off if k in ("t_start", "t_mid") else 0.0)
                                 for w, off in zip(pieces, offsets)])
    out["piece"] = np.concatenate([np.full(len(w["Ps"]), float(i))
                                   for i, w in enumerate(pieces)])
    out["window"] = pieces[-1]["window"]
    return out


def parent_time_of(run) -> float | None:
    """The parent's time at the state a continuation started from (its summary.json's
    ``parent.parent_time``), None when the run records none."""
    f = Path(run) / "summary.json"
    if Path(run).suffix == ".npz" or not f.exists():
        return None
    return json.loads(f.read_text()).get("parent", {}).get("parent_time")


#: a tail is flat when the 90 % interval of its fitted change lies within this fraction of its
#: mean Ps (Ps moves about twice as much, relatively, as the detector's indicator s, whose
#: tolerance is 3 % of the change since the start: granflow.steady.segregation)
FLAT_REL_TOL = 0.02
#: windows of the tail the flatness test uses (500 time units of 50-unit windows)
FLAT_WINDOWS = 10


def flat_tail(t, Ps, *, windows: int = FLAT_WINDOWS, rel_tol: float = FLAT_REL_TOL,
              alpha: float = 0.05) -> dict:
    """Whether the last ``windows`` windows of Ps(t) have stopped moving (module docstring).

    Returns ``flat`` (the (1 - 2 alpha) interval of the fitted change over the tail within
    +- ``rel_tol`` x its mean), ``change`` and ``change_stderr`` (slope x span and its
    serial-correlation-corrected standard error), ``p_value`` of the trend, ``mean`` and
    ``sem`` (spread / sqrt(n)) over the tail, ``t_from`` and ``span``."""
    from granflow.steady.timeseries import trend_test
    from scipy import stats

    t, Ps = np.asarray(t, dtype=float), np.asarray(Ps, dtype=float)
    ok = np.isfinite(t) & np.isfinite(Ps)
    t, Ps = t[ok][-windows:], Ps[ok][-windows:]
    if t.size < max(windows, 4):
        raise ValueError(f"{t.size} windows: the flatness test needs {max(windows, 4)}")
    tr = trend_test(Ps, t)
    span = float(t[-1] - t[0])
    change, se = float(tr.slope * span), float(tr.stderr * span)
    half = float(stats.t.ppf(1.0 - alpha, max(tr.dof, 1.0))) * se
    mean = float(Ps.mean())
    tol = rel_tol * abs(mean)
    flat = bool(math.isfinite(change) and math.isfinite(half) and abs(change) + half <= tol)
    return {"flat": flat, "change": change, "change_stderr": se, "tolerance": tol,
            "p_value": float(tr.p_value), "mean": mean,
            "sem": float(Ps.std(ddof=1) / math.sqrt(Ps.size)), "t_from": float(t[0]),
            "span": span, "windows": int(t.size)}


def approach(t, Ps, *, t_from: float = -math.inf, last: int = 4) -> dict:
    """What the series Ps(t) says about its steady value.

    ``side``: +1 when Ps rose over the series (the first ``last`` windows after ``t_from``
    against the last ``last``: a lower bound, as after a mixed start), -1 when it fell (an
    upper bound, as after a segregated start); ``Ps_last``: mean of the last ``last`` windows,
    ``Ps_last_sem`` their standard error (spread / sqrt(n)).  ``Ps_inf``, ``Ps_inf_stderr``,
    ``tau``, ``beta``, ``remaining``, ``remaining_bound``, ``identified``: the (stretched)
    exponential relaxation fitted to the windows after ``t_from`` (an extrapolation; NaN where
    no relaxation is identified)."""
    from granflow.steady.segregation import SEGREGATION_ALPHA, relaxation_projection
    from scipy import stats

    t, Ps = np.asarray(t, dtype=float), np.asarray(Ps, dtype=float)
    ok = np.isfinite(t) & np.isfinite(Ps) & (t >= t_from)
    t, Ps = t[ok], Ps[ok]
    if t.size < max(2 * last, 6):
        raise ValueError(f"{t.size} windows after t_from = {t_from:g}: need at least "
                         f"{max(2 * last, 6)}")
    head, tail = Ps[:last], Ps[-last:]
    side = 1.0 if tail.mean() > head.mean() else -1.0
    out = {"side": side, "Ps_first": float(head.mean()), "Ps_last": float(tail.mean()),
           "Ps_last_sem": float(tail.std(ddof=1) / math.sqrt(tail.size)),
           "t_last_from": float(t[-last]), "t_end": float(t[-1]), "n_windows": int(t.size)}
    rx = relaxation_projection(t, Ps)
    z = float(stats.norm.ppf(1.0 - SEGREGATION_ALPHA))
    if rx.identified:
        se = (rx.bound - abs(rx.remaining)) / z
        # Ps_inf = fitted value now + remaining; its stderr is that of the remaining change
        out.update(Ps_inf=float(rx.s_inf), Ps_inf_stderr=float(se), tau=float(rx.tau),
                   beta=float(rx.beta),
                   remaining=float(rx.remaining), remaining_bound=float(rx.bound),
                   identified=True, how=rx.how)
    else:
        out.update(Ps_inf=math.nan, Ps_inf_stderr=math.nan, tau=math.nan, beta=math.nan,
                   remaining=float(rx.remaining), remaining_bound=float(rx.bound),
                   identified=False, how=rx.how)
    return out


def detector_verdicts(run, every: float = 50.0, averaging_time: float | None = None) -> list:
    """The steady detector's verdict replayed on a run's recorded indicator s(t)
    (``series.nc``: ``segregation_indicator``) at every ``every`` time units, by the rule of
    *this* code (:func:`granflow.steady.segregation.segregation_steadiness`, the run's own
    ``averaging_time`` and start-up ``steady_min_onset``): how a rule change would have judged
    a run already made.  The detector sees one run: a continuation's parents are not joined.
    Returns dicts (t, steady, plateau, total, remaining, remaining_bound, message)."""
    import xarray as xr

    from granflow.steady.segregation import segregation_steadiness

    with xr.open_dataset(Path(run) / "series.nc") as ds:
        t = np.asarray(ds["segregation_time"].values, dtype=float)
        s = np.asarray(ds["segregation_indicator"].values, dtype=float)
        min_onset = float(ds.attrs.get("steady_min_onset", 0.0))
        if averaging_time is None:
            averaging_time = float(json.loads(ds.attrs["config_json"])["averaging_time"])
    out = []
    for end in np.arange(float(t[0]) + averaging_time, float(t[-1]) + 1e-9, every):
        k = t <= end
        st = segregation_steadiness(t[k], s[k], averaging_time=averaging_time,
                                    min_onset=min_onset)
        out.append({"t": float(end), "steady": bool(st.steady), "plateau": st.plateau,
                    "total": st.total, "remaining": st.remaining,
                    "remaining_bound": st.remaining_bound, "message": st.message})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir")
    ap.add_argument("--t-from", type=float, default=100.0,
                    help="windows starting before this are left out of the approach fit")
    ap.add_argument("--last", type=int, default=4, help="windows of the one-sided bound")
    ap.add_argument("--flat-windows", type=int, default=FLAT_WINDOWS,
                    help="windows of the tail whose flatness is tested")
    ap.add_argument("--json", help="write the series and the approach to this file")
    ap.add_argument("--checkpoint", action="store_true",
                    help="every window so far from the run's checkpoint.npz (a run still going, "
                         "or stopped before its end) instead of its profiles.nc")
    ap.add_argument("--parent", action="append",
                    help="the run this one continued from (granflow simulate --from): its "
                         "folder (profiles_history.nc or profiles.nc, checkpoint.npz with "
                         "--checkpoint) or a checkpoint .npz; its windows come first.  Repeat "
                         "it for a chain of continuations, oldest first (each later one a "
                         "folder whose summary.json names its parent_time)")
    ap.add_argument("--parent-time", type=float, default=None,
                    help="the parent's time at the state this run continued from (default: "
                         "parent_time in this run's summary.json)")
    ap.add_argument("--verdicts", action="store_true",
                    help="also replay the steady detector (this code's rule) on the run's "
                         "recorded indicator every 50 time units (series.nc)")
    args = ap.parse_args(argv)
    if args.last < 2:
        ap.error(f"--last = {args.last} is out of range: allowed >= 2")
    run = Path(args.run_dir)
    params = {}
    if (run / "summary.json").exists():
        params = json.loads((run / "summary.json").read_text()).get("params", {})
    elif (run / "params.yaml").exists():
        import yaml

        params = yaml.safe_load((run / "params.yaml").read_text()) or {}
    w = window_peclets(run, params.get("sigma"), from_checkpoint=args.checkpoint)
    if args.parent:
        t0 = args.parent_time if args.parent_time is not None else parent_time_of(run)
        if t0 is None:
            ap.error("--parent needs --parent-time (this run has no summary.json naming it)")
        # the parents oldest first; each later parent names its own parent's time
        times = []
        for par in args.parent[1:]:
            tp = parent_time_of(par)
            if tp is None:
                ap.error(f"--parent {par}: not the first parent, so it must be a continuation "
                         "whose summary.json names its parent_time")
            times.append(float(tp))
        # --checkpoint is for a run still going: a finished parent is read from its outputs
        pieces = [window_peclets(par, params.get("sigma"), from_checkpoint=args.checkpoint
                                 and not (Path(par) / "summary.json").exists())
                  for par in args.parent]
        w = join_chain(pieces + [w], times + [float(t0)])
        print(f"continued from {' -> '.join(args.parent)} (at their t = "
              f"{', '.join(f'{t:g}' for t in times + [float(t0)])}): "
              f"{int((w['piece'] < len(pieces)).sum())} parent windows first")
    print(f"{run}: sigma = {params.get('sigma', '?')}, start "
          f"{params.get('initial_mixing', 'mixed')}, {w['Ps'].size} windows of {w['window']:g}")
    print("   t_start   Ps (T-eq. 28)  fit stderr   depth s - b")
    for a, p, s, d in zip(w["t_start"], w["Ps"], w["Ps_stderr"], w["depth"]):
        print(f"  {a:8.1f}   {p:12.4f}  {s:10.4f}   {d:10.3f}")
    verdicts = None
    if args.verdicts:
        verdicts = detector_verdicts(run)
        first = next((v for v in verdicts if v["steady"]), None)
        print("detector replayed on this run's indicator (this code's rule):")
        print("   t      steady   plateau s   change to come   95 % bound")
        for v in verdicts:
            print(f"  {v['t']:7.1f}  {str(v['steady']):6s}  {v['plateau']:9.4f}  "
                  f"{v['remaining']:+14.4f}  {v['remaining_bound']:11.4f}")
        print("first shown steady at t = "
              + (f"{first['t']:g} (plateau s {first['plateau']:.4f})" if first else "never"))
    try:
        res = approach(w["t_mid"], w["Ps"], t_from=args.t_from, last=args.last)
    except ValueError as exc:
        # too few windows for an approach: the windows (and verdicts) are still written
        print(f"no approach fitted: {exc}")
        write_json(args.json, run, params, args.parent, w, {"error": str(exc)}, verdicts)
        return 0
    kind = "lower" if res["side"] > 0 else "upper"
    print(f"approach from {'below' if res['side'] > 0 else 'above'}: Ps {res['Ps_first']:.3f} "
          f"-> {res['Ps_last']:.3f} +- {res['Ps_last_sem']:.3f} over the last {args.last} "
          f"windows (t >= {res['t_last_from']:g}): a one-sided ({kind}) bound on the steady Ps")
    try:
        flat = flat_tail(w["t_mid"], w["Ps"], windows=args.flat_windows)
    except ValueError as exc:
        flat = {"error": str(exc)}
        print(f"no flatness test: {exc}")
    else:
        print(f"tail of {flat['windows']} windows (t >= {flat['t_from']:g}): change "
              f"{flat['change']:+.3f} +- {flat['change_stderr']:.3f} (trend p = "
              f"{flat['p_value']:.2g}), "
              + (f"flat (90 % within +-{flat['tolerance']:.3f}) at Ps = {flat['mean']:.3f} "
                 f"+- {flat['sem']:.3f}: a plateau or a pause (Ps can wander by 0.1-0.2 over "
                 "hundreds of time units)" if flat["flat"] else
                 f"not shown flat within +-{flat['tolerance']:.3f}: still moving, or too "
                 "noisy to tell"))
    res["flat_tail"] = flat
    if res["identified"]:
        print(f"extrapolated (relaxation fit, t >= {args.t_from:g}): Ps_inf = "
              f"{res['Ps_inf']:.3f} +- {res['Ps_inf_stderr']:.3f}, tau = {res['tau']:.4g}, beta = "
              f"{res['beta']:.2f}; "
              f"change still to come {res['remaining']:+.3f} (95 % bound {res['remaining_bound']:.3f})")
    else:
        print(f"no relaxation identified ({res['how']})")
    write_json(args.json, run, params, args.parent, w, res, verdicts)
    return 0


def write_json(path, run, params, parent, w, approach_result, verdicts):
    """The windows, the approach (or why there is none) and the verdicts, to ``path``."""
    if not path:
        return
    Path(path).write_text(json.dumps(
        {"run": str(run), "params": params, "parent": parent,
         "windows": {k: v.tolist() for k, v in w.items() if k != "window"},
         "window": w["window"], "approach": approach_result, "verdicts": verdicts}, indent=1))


if __name__ == "__main__":
    sys.exit(main())
