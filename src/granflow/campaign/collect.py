"""Campaign-table rows from finished runs, and the campaign table itself.

Coarse-graining (Weinhart et al. 2012 Eq. 13-43) and flow-state classification (§6) happen
*inside* each ``granflow simulate`` job, on the fly; the job leaves ``summary.json`` (flow state,
depth averages h, u_bar, F, alpha, K, rho_bar, rho_c with their time-window spreads) and
``profiles.nc`` (depth profiles, per time window too).  :func:`derive_row` reads those into one
campaign-table row (:mod:`granflow.fitting.table`) and, for a bidisperse run, fits the Peclet
number Ps of T-eq. (28) to the small-particle fraction phi(z) over the last ``segregation_window``
time units (mean profile; ``Ps_std`` = spread of the per-window fits).  :func:`collect_table`
concatenates rows into the table (netCDF with CF attributes + CSV).

Runs whose state is ``undecided`` (the cap was reached before the classifier could decide)
enter the table with that state: the hstop fit counts them as *flowing* (the paper's binary
arrested/flowing rule, §6), the fits that need steady flow leave them out, and every closure
says so (its ``selection``).  A run that an engine guard ended before it had any flow state
(stop reason ``engine guard before any flow state``, :func:`engine_stop_without_flow_state`)
is no evidence for hstop either way and is left out of its brackets.  A run whose summary has
no known state at all is listed, with the reason, in ``excluded_runs.csv`` instead.

Per-run uncertainties: ``<col>_sem`` is the standard error of the run's mean from its
decorrelated time windows (:func:`granflow.steady.timeseries.standard_error_of_mean`); for Ps it
comes from the per-window fits of T-eq. (28), not from the covariance of the (correlated)
coarse-grained profile points, and is at least the wander of the segregated state measured at
the run's number of flow particles (:func:`granflow.fitting.segregation.wander_sd`).

Which base a run fell onto: ``base_seed`` (from the campaign's configuration) and
``base_sha256`` (what the run recorded, ``summary["provenance"]``); runs of one base file that
recorded two versions of it are refused (:func:`check_one_base_per_file`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from .. import units as U
from ..fitting.hstop import ENGINE_STOP_NO_STATE
from ..fitting.table import (COLUMN_ATTRS, FLOW_STATES, MEASURED_COLUMNS, STRING_COLUMNS,
                             campaign_table_from_records)
from ..provenance import atomic_to_netcdf, atomic_write_bytes
from ..steady.classify import FLOWING_STATES as CLASSIFIED_FLOWING
from .grid import parse_run_path
from .serialize import dumps, fit_from_dict, fit_to_dict, from_jsonable

#: summary.json depth-average names -> campaign-table columns
_AVERAGES = {"flow_height": "h", "u_bar": "u_bar", "froude": "F", "alpha": "alpha", "K": "K",
             "rho_bar": "rho_bar", "rho_c": "rho_c"}
#: extra (non-schema) columns every row carries
EXTRA_COLUMNS = ("kind", "run", "mu_bar", "t_final", "steady_start", "stop_reason", "n_flow",
                 "state_confidence", "segregation_state", "replicate", "base_sha256",
                 "initial_mixing")
_STRING_EXTRAS = ("kind", "run", "stop_reason", "segregation_state", "base_sha256",
                  "initial_mixing")
EXTRA_ATTRS = {
    "kind": {"long_name": "campaign the run belongs to (chute or segregation)"},
    "run": {"long_name": "run directory relative to the campaign results folder"},
    "mu_bar": U.cf(U.DIMENSIONLESS, "depth-averaged friction -sigma_xz_bar/sigma_zz_bar"),
    "t_final": U.cf(U.TIME, "simulated time at the end of the run"),
    "steady_start": U.cf(U.TIME, "onset of the steady window (NaN unless steady/layered)"),
    "stop_reason": {"long_name": "why the run stopped"},
    "n_flow": U.cf(U.DIMENSIONLESS, "number of flow particles"),
    "state_confidence": U.cf(U.DIMENSIONLESS, "confidence of the flow-state classification"),
    "segregation_state": {"long_name": "segregated state of a bidisperse run (steady, drifting; "
                                       "empty for monodisperse runs)"},
    "replicate": U.cf(U.DIMENSIONLESS, "replicate index k of the run point (insertion seed + k)"),
    "initial_mixing": {"long_name": "how a bidisperse run's species started: mixed (steady "
                                    "segregated state approached from below) or segregated "
                                    "(from above); empty for monodisperse runs"},
    "base_sha256": {"long_name": "SHA-256 of the base file the run fell onto, as the run "
                                 "recorded it (empty: not recorded, or a base prepared from the "
                                 "run's parameters)"},
    "base_seed": U.cf(U.DIMENSIONLESS, "seed of the rough base the run fell onto (base.seed; + k "
                                       "for bracket chain k under hstop_bisection."
                                       "replicate_bases)"),
}


#: flow states that show a run flowing before an engine stop (the classifier's, and the
#: bracket runs' "flowing")
_SEEN_FLOWING = CLASSIFIED_FLOWING + ("flowing",)


def engine_stop_without_flow_state(summary: dict) -> bool:
    """True for a run that an engine guard ended before the classifier had seen it flow
    (``flow_state_before_engine_stop`` not a flowing state; older summaries: the state named in
    the classification, "... until then the classifier said <state>: ...").  Such a run is no
    evidence for hstop: neither arrested nor flowing."""
    if not summary.get("engine_stop"):
        return False
    before = summary.get("flow_state_before_engine_stop")
    if before is None:
        text = str(summary.get("classification", ""))
        key = "until then the classifier said "
        before = text.split(key, 1)[1].split(":", 1)[0].strip() if key in text else "undecided"
    return str(before) not in _SEEN_FLOWING


def _f(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return math.nan
    return x


def small_fraction_profiles(ds, t_from: float):
    """(z, phi_mean, [phi per window], windows used) of the small-particle volume fraction
    phi = nu_small / (nu_small + nu_large), from the per-window profiles starting at or after
    ``t_from`` (all windows with enough snapshots if none qualifies)."""
    small = int(ds.attrs.get("cg_small_species", 0))
    nu = np.asarray(ds["species_volume_fraction_window"].values, dtype=float)  # (w, s, z)
    counts = np.asarray(ds["window_n_snapshots"].values, dtype=float)
    starts = np.asarray(ds["window_time_start"].values, dtype=float)
    full = counts >= 0.5 * counts.max()
    use = full & (starts >= t_from - 1e-9)
    if not use.any():
        use = full
    tot = nu.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        phi_w = np.where(tot > 0, nu[:, small, :] / np.where(tot > 0, tot, 1.0), np.nan)
    weights = counts[use]
    num = np.tensordot(weights, nu[use, small, :], axes=1)
    den = np.tensordot(weights, tot[use], axes=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)
    return ds["z"].values, phi, phi_w[use], np.nonzero(use)[0]


#: A run's Ps still moves over its profile windows when their linear trend is significant at
#: this level and changes Ps by more than the run's trend tolerance over them: the larger of
#: PS_TREND_TOLERANCE and PS_TREND_WANDER_MULTIPLE times the relative wander of Ps at the run's
#: number of flow particles (C / sqrt(N), :func:`granflow.fitting.segregation.wander_sd`).
#: Measured 2026-11-29 (depth 8, 10 x 5, sigma = 0.75, paper species): a mixed start shown
#: steady by the centre of mass at t = 771 gave Ps 8.97 with a trend of +15.5 % (p = 0.005) over
#: its windows; the same run continued to t = 2000 has 150-unit means of Ps between 9.2 and 12.1
#: (mean 10.8 over 760-2000: Ps fluctuates on a time scale of 100-300 in so small a box), and a
#: segregated start 10.9-13.1 over 1580-2000 (11.47 at its own stop, t = 211).  The 5 % rule
#: flagged that run; with the wander's tolerance (29 % at its 284 particles) it is steady at
#: 8.97 +- 0.87, its long mean 10.63 (SEGREGATION_DEFAULT_WANDER) 1.9 stderrs above.
PS_TREND_P = 0.05
PS_TREND_TOLERANCE = 0.05
#: Why the wander sets the tolerance (measured 2026-12-08,
#: benchmarks/segregation_trend_calibration.py, granflow.reference.SEGREGATION_TREND_CALIBRATION):
#: replayed on every 4-, 6- and 10-window stretch of the long steady tails of eight runs (the
#: default set-up's four continued runs, the 20 x 5 and 40 x 5 boxes, the paper set-up's two
#: 1/sigma = 1.25 tails), the 5 % rule alone flagged 15-22 % of 4-window stretches and 16-56 %
#: of 6- and 10-window ones at 284-1138 particles, and a flagged trend pointed towards the
#: tail's long mean in half of them (a coin flip, as time-reversal symmetry of a stationary
#: wander says), so the "one-sided bound" such a flag makes of the run's Ps was wrong half the
#: time.  With the tolerance at 3 C / sqrt(N) the four default tails flag 0.8, 2.6, 3.6 %
#: (pooled at n = 4, 6, 10; the multiple chosen on them as the smallest of 1.5, 2, 2.5, 3 with a
#: pooled rate <= 5 %), the other four 0, 1.0, 4.5 %; on the approaches of the mixed starts
#: (t < 900) it keeps 103 of the 5 % rule's 149 flags, all but one pointing towards the plateau.
PS_TREND_WANDER_MULTIPLE = 3.0


def ps_trend_tolerance(Ps: float, wander: float) -> float:
    """The relative change over a run's profile windows that counts as Ps still moving: the
    larger of :data:`PS_TREND_TOLERANCE` and :data:`PS_TREND_WANDER_MULTIPLE` times the wander
    ``wander / Ps`` (PS_TREND_TOLERANCE alone where the wander is unknown)."""
    rel = abs(wander / Ps) if Ps and math.isfinite(Ps) and math.isfinite(wander) else math.nan
    return max(PS_TREND_TOLERANCE, PS_TREND_WANDER_MULTIPLE * rel) if math.isfinite(rel) \
        else PS_TREND_TOLERANCE


def ps_still_moving(extra: dict) -> bool:
    """True when a segregation fit's per-window Ps trend (``Ps_trend_change``, ``Ps_trend_p``
    of :func:`segregation_fit`) is significant and larger than the run's ``Ps_trend_tolerance``
    (:func:`ps_trend_tolerance`; :data:`PS_TREND_TOLERANCE` for fits without it)."""
    ch, p = extra.get("Ps_trend_change"), extra.get("Ps_trend_p")
    tol = extra.get("Ps_trend_tolerance", PS_TREND_TOLERANCE)
    tol = PS_TREND_TOLERANCE if tol is None or not math.isfinite(tol) else tol
    return (ch is not None and p is not None and math.isfinite(ch) and math.isfinite(p)
            and p < PS_TREND_P and abs(ch) > tol)


def count_as_drifting(fit):
    """A run whose small particles' centre of mass was shown steady while Ps itself still
    moves over the profile's windows (:func:`ps_still_moving`): its Ps bounds the steady value
    from one side only, so its fit's segregated state is "drifting" too (the campaign table's
    row says so, and :func:`granflow.campaign.fits.assess_segregation_runs` then calls the
    per-run Ps unidentified: until 2026-12-07 the fit kept "steady" and a library took its Ps
    as the ratio's steady value)."""
    return fit.replace(
        selection=fit.selection + (
            f"; Ps still moving over its windows ({100 * fit.extra['Ps_trend_change']:+.1f} %"
            f", trend p = {fit.extra['Ps_trend_p']:.2g}, beyond its tolerance of "
            f"{100 * fit.extra.get('Ps_trend_tolerance', PS_TREND_TOLERANCE):.1f} %): counted "
            "as drifting"),
        extra=dict(fit.extra, segregation_state="drifting", Ps_still_moving=True))


def segregation_fit(run_dir, sigma: float, law: str, window: float):
    """Fit Ps (T-eq. 28) to a bidisperse run's phi(z) in its steady segregated window.

    The window is the run's profile window (``profile_time_from`` of summary.json) when the run
    found its segregated state steady (energy *and* small-particle centre of mass,
    :mod:`granflow.steady.segregation`), otherwise the last ``window`` time units.  Depth is
    scaled to [0, 1] over [b, s] of Eq. (42) computed from the same windows' sigma_zz; that
    depth, s - b, is ``extra["scaled_depth"]`` (Ps is per unit of it).  The asymmetric-flux profile (seed 001 Eq. 2.9) is fitted to the same profile for comparison
    (``extra``: Ps, kappa, rms residual and AIC of both models; ``asymmetric_status`` and
    ``asymmetric_kappa_status``: "reduced" and "fixed" where the profile does not identify
    kappa, which then is 0, the symmetric flux).
    Returns (FitResult tagged with sigma/contact_law, Ps spread over windows, profile dict);
    the fit's ``stderr`` of Ps is replaced by the larger of the standard error of the mean of
    the per-window fits (decorrelated windows, ``extra["Ps_windows_sem"]``) -- the covariance
    of the correlated profile points understates it 5-10 times -- and the wander of the
    segregated state in time measured at the run's number of flow particles
    (:func:`granflow.fitting.segregation.wander_sd`, ``extra["Ps_wander_sd"]``), which the
    windows of one run understate another 2-8 times (``stderr_method`` says how, the two
    extras hold both values); ``extra["Ps_std"]`` holds the windows' spread.
    """
    import xarray as xr

    from ..coarse.derived import flow_height
    from ..fitting import compare_segregation_models, fit_Ps

    with xr.open_dataset(Path(run_dir) / "profiles.nc") as src:
        ds = src.load()
    t_final = _f(ds.attrs.get("t_final"))
    steady = str(ds.attrs.get("segregation_state", "")) == "steady"
    t_from = _f(ds.attrs.get("profile_time_from")) if steady else t_final - window
    if not math.isfinite(t_from):
        t_from = t_final - window
    z, phi, phi_w, used = small_fraction_profiles(ds, t_from)
    szz_w = np.asarray(ds["stress_zz_window"].values, dtype=float)[used]
    counts = np.asarray(ds["window_n_snapshots"].values, dtype=float)[used]
    szz = np.tensordot(counts, szz_w, axes=1) / counts.sum()
    b, s, _, _ = flow_height(z, szz)
    inside = (z >= b) & (z <= s) if np.isfinite(b) and np.isfinite(s) else np.zeros(z.shape, bool)
    zeta = (z[inside] - b) / (s - b) if inside.any() else np.zeros(0)
    fit = fit_Ps(zeta, phi[inside], sigma=sigma, contact_law=law)
    cmp = compare_segregation_models(zeta, phi[inside])
    for _, r in cmp.iterrows():
        tag = "symmetric" if r["model"].startswith("symmetric") else "asymmetric"
        for col in ("Ps", "kappa", "rms_residual", "aic"):
            fit.extra[f"{tag}_{col}"] = float(r[col])
        if tag == "asymmetric":
            # "reduced"/"fixed": the profile does not identify kappa (at its bound 0)
            fit.extra["asymmetric_status"] = str(r["status"])
            fit.extra["asymmetric_kappa_status"] = str(r["kappa_status"])
    fit.extra["segregation_state"] = str(ds.attrs.get("segregation_state", "unknown"))
    fit.extra["profile_time_from"] = float(t_from)
    # Ps is per unit scaled depth: the depth it is per (granflow.reference.SEGREGATION_PAPER_SETUP
    # measured Ps proportional to it within 2 % over windows 19.9-24.0 d deep)
    fit.extra["scaled_depth"] = float(s - b) if inside.any() else math.nan
    per, t_per = [], []
    starts = np.asarray(ds["window_time_start"].values, dtype=float)[used]
    for k in range(len(phi_w)):
        r = fit_Ps(zeta, phi_w[k][inside], sigma=sigma, contact_law=law)
        if r.ok:
            per.append(r.params["Ps"])
            t_per.append(starts[k])
    spread = float(np.std(per, ddof=1)) if len(per) > 1 else math.nan
    from ..steady.timeseries import standard_error_of_mean, trend_test

    sem = standard_error_of_mean(per) if len(per) > 1 else math.nan
    if fit.ok:
        fit.extra["Ps_covariance_stderr"] = fit.stderr["Ps"]
        fit.extra["Ps_std"] = spread
        fit.extra["n_windows"] = len(per)
        if len(per) >= 4:
            # does Ps itself still move over the profile's windows?  (the stop rule watches the
            # small particles' centre of mass, to which Ps reacts about twice as strongly)
            tr = trend_test(np.asarray(per), np.asarray(t_per))
            fit.extra["Ps_trend_change"] = float(tr.relative_change)
            fit.extra["Ps_trend_p"] = float(tr.p_value)
        # the state wanders on times as long as the profile window: its own windows cannot see
        # that, the wander measured at this number of particles can (wander_sd)
        from ..fitting.segregation import PS_STDERR_METHOD, wander_sd
        from ..reference import SEGREGATION_WANDER_C

        n_flow = _f(ds.attrs.get("n_flow"))
        wander = wander_sd(fit.params["Ps"], n_flow)
        fit.extra["Ps_windows_sem"] = sem
        fit.extra["Ps_wander_sd"] = wander
        # a trend smaller than the wander can make over the windows is not a drift
        fit.extra["Ps_trend_tolerance"] = ps_trend_tolerance(fit.params["Ps"], wander)
        if math.isfinite(wander):
            total = max(sem, wander) if math.isfinite(sem) else wander
            method = PS_STDERR_METHOD.format(c=SEGREGATION_WANDER_C)
        else:
            total = sem
            method = ("standard error of the mean of the run's per-window fits (decorrelated "
                      "windows); the wander in time is not included (the run does not record "
                      "its number of flow particles)")
        fit = fit.replace(stderr={"Ps": total}, stderr_method=method)
    profile = {"zeta": zeta.tolist(), "phi": phi[inside].tolist(), "base": b, "surface": s,
               "t_from": float(t_from), "n_windows": int(len(used)),
               "segregation_state": fit.extra["segregation_state"]}
    return fit, spread, profile


def _read_summary(path, remove_corrupt: bool = False) -> dict:
    from ..simulate import _corrupt

    if not path.is_file():
        raise FileNotFoundError(f"summary file {str(path)!r} does not exist: the run has not "
                                "finished")
    try:
        with open(path, encoding="utf-8") as fh:
            summ = json.load(fh)
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError is a ValueError
        raise _corrupt(path, f"is not valid JSON, truncated or corrupt ({exc})", "summary",
                       remove_corrupt) from None
    if not isinstance(summ, dict) or "flow_state" not in summ:
        raise _corrupt(path, "is not a run summary (no flow_state)", "summary", remove_corrupt)
    return summ


def verify_run_outputs(run_dir, remove_corrupt: bool = False) -> dict:
    """Read back a finished run's outputs before using them; return its summary.

    ``summary.json`` must parse; ``series.nc``, ``profiles.nc`` and ``final_state.npz`` must
    exist, have the size and SHA-256 the run recorded in it (``outputs``; runs written before
    that record are only read back) and open.  Anything else raises
    :class:`granflow.simulate.CorruptFileError` (a ValueError; FileNotFoundError for a missing
    output) naming the file and what is wrong.  With ``remove_corrupt`` the bad file and the
    run's ``summary.json`` (which no longer describes what is on disk) are deleted first: the
    summary is an input of the workflow's row rule, so the rerun recomputes this run -- and
    only this run, whose simulation job writes them.
    """
    from ..simulate import CorruptFileError

    run_dir = Path(run_dir)
    summ = _read_summary(run_dir / "summary.json", remove_corrupt)
    try:
        _check_outputs(run_dir, summ, remove_corrupt)
    except (CorruptFileError, FileNotFoundError) as exc:
        if not remove_corrupt:
            raise
        try:
            (run_dir / "summary.json").unlink()
        except OSError:
            raise exc from None
        msg = str(exc).replace("; removed it:", "; removed it and the run's summary.json:")
        if "removed it" not in msg:
            msg += "; removed the run's summary.json: rerun the workflow to recompute this run"
        if isinstance(exc, CorruptFileError):
            raise CorruptFileError(exc.path, msg, True) from None
        raise FileNotFoundError(msg) from None
    return summ


def _check_outputs(run_dir: Path, summ: dict, remove_corrupt: bool):
    import xarray as xr

    from ..simulate import RUN_OUTPUTS, _corrupt, file_record, load_state

    recorded = summ.get("outputs") or {}
    kinds = {"series.nc": "time-series", "profiles.nc": "profiles", "final_state.npz": "state"}
    for name in RUN_OUTPUTS:
        path = run_dir / name
        kind = kinds.get(name, name)
        if recorded and name not in recorded:  # the run wrote none (an ingest: no final state)
            continue
        if not path.is_file():
            raise FileNotFoundError(f"{kind} file {str(path)!r} of a finished run is missing")
        want = recorded.get(name)
        if isinstance(want, dict) and "bytes" in want:
            have = file_record(path)
            if have["bytes"] != want["bytes"]:
                raise _corrupt(path, f"is {have['bytes']} bytes, the run wrote {want['bytes']} "
                                     "(truncated or replaced)", kind, remove_corrupt)
            if have["sha256"] != want.get("sha256"):
                raise _corrupt(path, "does not hold what the run wrote (its SHA-256 differs "
                                     "from the one in summary.json): modified or corrupted",
                               kind, remove_corrupt)
        if name.endswith(".nc"):
            try:
                with xr.open_dataset(path) as ds:
                    ds.load()
            except Exception as exc:  # netCDF4/HDF5 raise OSError, RuntimeError, ValueError...
                raise _corrupt(path, f"is not a readable netCDF file, truncated or corrupt "
                                     f"({type(exc).__name__}: {exc})", kind,
                               remove_corrupt) from None
        else:
            load_state(path, kind="state", remove_if_corrupt=remove_corrupt)


def derive_row(run_dir, rel: str | None = None, segregation_window: float = 100.0,
               remove_corrupt: bool = False) -> dict:
    """One campaign-table row (plus extras) from a finished run directory (see module doc).

    The run's outputs are read back first (:func:`verify_run_outputs`): a truncated or
    corrupt one raises an error naming it (and is removed with ``remove_corrupt``)."""
    run_dir = Path(run_dir)
    point = parse_run_path(rel if rel is not None else run_dir.as_posix())
    summ = verify_run_outputs(run_dir, remove_corrupt=remove_corrupt)
    avg = summ.get("depth_averages") or {}
    row = {"theta": point.theta, "H": point.H, "lam": point.lam, "sigma": point.sigma,
           "contact_law": point.law, "state": summ.get("flow_state", "undecided")}
    for src, col in _AVERAGES.items():
        row[col] = _f(avg.get(src))
        row[f"{col}_std"] = _f(avg.get(f"{src}_std"))
        row[f"{col}_sem"] = _f(avg.get(f"{src}_sem"))
    row.update(Ps=math.nan, Ps_std=math.nan, Ps_sem=math.nan, phi0=math.nan, phi0_std=math.nan,
               phi0_sem=math.nan)
    seg_state = (summ.get("segregation") or {}).get("steady")
    row.update(kind=point.kind, run=point.path, mu_bar=_f(avg.get("mu_bar")),
               t_final=_f(summ.get("t_final")), steady_start=_f(summ.get("steady_start")),
               stop_reason=(ENGINE_STOP_NO_STATE if engine_stop_without_flow_state(summ)
                            else str(summ.get("stop_reason", "")).split(":")[0]),
               n_flow=_f(summ.get("n_flow")), state_confidence=_f(summ.get("state_confidence")),
               segregation_state="" if seg_state is None else
               ("steady" if seg_state else "drifting"), replicate=float(point.replicate),
               initial_mixing=point.start if point.kind == "segregation" else "",
               base_sha256=str((summ.get("provenance") or {}).get("base_sha256") or ""))
    if row["state"] == "steady" and "layering_amplitude" not in summ:
        # a run classified before layering was checked (granflow.simulate does it since
        # 2026-11-26): the same rule on its steady-window profile
        import xarray as xr

        from ..steady.classify import layered_state

        with xr.open_dataset(run_dir / "profiles.nc") as prof:
            row["state"] = layered_state(row["state"], prof["z"].values,
                                         prof["volume_fraction"].values)[0]
    out = {"row": row, "excluded": None, "segregation_fit": None, "segregation_profile": None}
    if row["state"] not in FLOW_STATES:
        out["excluded"] = (f"flow state {row['state']!r} (not one of {FLOW_STATES}): "
                           f"{summ.get('classification', '')}")
    if point.kind == "segregation":
        fit, spread, profile = segregation_fit(run_dir, point.sigma, point.law, segregation_window)
        fit.extra["flow_state"] = row["state"]
        fit = fit.replace(runs_used=(point.path,),
                          selection=f"phi(z) of run {point.path} from t = {profile['t_from']:.6g}"
                                    f" ({profile['n_windows']} windows); flow {row['state']}, "
                                    f"segregated state {fit.extra.get('segregation_state')}")
        if row["segregation_state"] == "steady" and ps_still_moving(fit.extra):
            row["segregation_state"] = "drifting"
            fit = count_as_drifting(fit)
        row["Ps"] = fit.params["Ps"]
        row["Ps_std"] = spread
        row["Ps_sem"] = fit.stderr["Ps"]
        row["phi0"] = _f(fit.extra.get("phi0"))
        out["segregation_fit"] = fit_to_dict(fit)
        out["segregation_profile"] = profile
    return out


def write_row(run_dir, out, rel=None, segregation_window: float = 100.0,
              remove_corrupt: bool = True) -> dict:
    """The workflow's row step: :func:`derive_row` into the JSON file ``out``.  A corrupt run
    output is removed (``remove_corrupt``), so that the rerun recomputes that run."""
    res = derive_row(run_dir, rel, segregation_window, remove_corrupt=remove_corrupt)
    atomic_write_bytes(out, dumps(res).encode())
    return res


def read_rows(paths, remove_corrupt: bool = False) -> list[dict]:
    """Row files written by :func:`write_row`; an unreadable one raises an error naming it
    (and is removed with ``remove_corrupt``, so that the workflow recomputes it)."""
    from ..simulate import _corrupt

    rows = []
    for p in paths:
        try:
            with open(p, encoding="utf-8") as fh:
                row = from_jsonable(json.load(fh))
            if not isinstance(row, dict) or not isinstance(row.get("row"), dict):
                raise ValueError("no 'row' mapping")
        except (ValueError, UnicodeDecodeError) as exc:
            raise _corrupt(p, f"is not a campaign-table row file, truncated or corrupt ({exc})",
                           "row", remove_corrupt) from None
        rows.append(row)
    return rows


def _sort_key(r):
    row = r["row"]
    return (row["kind"], row["contact_law"], row["lam"], row["sigma"], row["theta"], row["H"])


#: netCDF variable names of columns whose names differ only by case from another column
#: (CF 2.3: names must not be distinguished by case alone); ``campaign_column`` keeps the column
NETCDF_NAMES = {"H": "H_fill"}


def table_dataset(table: pd.DataFrame, attrs=None, config=None):
    """The campaign table as an xarray Dataset on dim ``row`` with CF/ACDD attributes and
    provenance (git commit, created, units system, config hash of ``config``)."""
    import xarray as xr

    from .. import cfconventions
    from ..provenance import provenance_attrs

    data = {}
    for col in table.columns:
        a = dict(COLUMN_ATTRS.get(col) or EXTRA_ATTRS.get(col) or {"long_name": col})
        a["campaign_column"] = str(col)
        name = NETCDF_NAMES.get(col, col)
        if (col in STRING_COLUMNS or not pd.api.types.is_numeric_dtype(table[col])
                or pd.api.types.is_bool_dtype(table[col])):
            data[name] = ("row", np.array([str(v) for v in table[col]], dtype=object), a)
        else:
            data[name] = ("row", table[col].to_numpy(dtype=float), a)
    ds = xr.Dataset(data, coords={"row": np.arange(len(table), dtype=np.int32)})
    ds["row"].attrs = {"long_name": "campaign table row", "units": "1"}
    glob = provenance_attrs(config if config is not None else {})
    glob.update(attrs or {})
    ds.attrs.update(glob)
    campaign = glob.get("campaign", "")
    cfconventions.apply(
        ds, kind="campaign_table", config=config,
        title=glob.get("title") or f"granflow campaign table {campaign}".strip(),
        summary=(f"One row per chute run of the granflow campaign {campaign}: inclination, "
                 "filling height, basal roughness, size ratio, contact law, flow state, depth "
                 "averages (flow height, velocity, Froude number, shape factor alpha, stress "
                 "ratio K, densities) with time-window spreads and, for bidisperse runs, the "
                 "segregation Peclet number Ps (Weinhart et al. 2012; Thornton et al.)."),
        identifier=f"granflow-campaign-table-{campaign}-{glob.get('config_hash', '')}".rstrip("-"))
    return ds


def read_table(path) -> pd.DataFrame:
    """Read a campaign table written by :func:`collect_table` (.nc or .csv)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"campaign table {str(path)!r} does not exist")
    try:
        if path.suffix == ".csv":
            df = pd.read_csv(path, keep_default_na=True)
        else:
            import xarray as xr

            with xr.open_dataset(path) as ds:
                ds = ds.rename({n: v.attrs["campaign_column"] for n, v in ds.data_vars.items()
                                if v.attrs.get("campaign_column", n) != n})
                df = ds.to_dataframe().reset_index(drop=True)
    except Exception as exc:  # netCDF4/HDF5/pandas parser errors of a truncated file
        from ..simulate import CorruptFileError

        raise CorruptFileError(path, f"campaign table {str(path)!r} is not readable, truncated "
                                     f"or corrupt ({type(exc).__name__}: {exc})") from None
    for col in df.columns:
        if col in STRING_COLUMNS or col in _STRING_EXTRAS:
            df[col] = df[col].astype(object).where(df[col].notna(), "").astype(str).astype(object)
    return campaign_table_from_records(df.to_dict("records"))


def check_one_base_per_file(table: pd.DataFrame, base_files) -> None:
    """Raise ValueError when runs of one base file of the campaign (``base_files``: each row's
    path, :func:`granflow.campaign.grid.base_path`) recorded different contents of it
    (``base_sha256``): the base was remade with other settings (``base:`` making, layers) while
    finished runs kept the old one, and a fit would join runs on two bases as one.  Runs that
    recorded no base file are not checked."""
    if "base_sha256" not in table.columns:
        return
    sha = table["base_sha256"].astype(str).to_numpy()
    files = np.asarray(list(base_files), dtype=object)
    for path in sorted(set(files)):
        sel = (files == path) & (sha != "")
        found = sorted(set(sha[sel]))
        if len(found) > 1:
            runs = table["run"].to_numpy()
            groups = {f[:12]: sorted(runs[sel & (sha == f)])[:3] for f in found}
            raise ValueError(
                f"the runs on {path} fell onto {len(found)} different versions of it "
                f"{groups}: the base was remade with other settings after some runs finished; "
                "rerun the runs of the old base before fitting them together")


def collect_table(row_files, out_nc, out_csv, out_excluded=None, out_segregation=None,
                  attrs=None, config=None, remove_corrupt_rows: bool = True) -> pd.DataFrame:
    """Concatenate row files into the campaign table; write netCDF, CSV, excluded runs and the
    per-run segregation fits (JSON list, input of the library's ``segregation`` kind).  An
    unreadable row file is removed (``remove_corrupt_rows``: the workflow then recomputes it)
    and raises an error naming it."""
    results = sorted(read_rows(row_files, remove_corrupt=remove_corrupt_rows), key=_sort_key)
    seen, kept, excluded, seg = set(), [], [], []
    for r in results:
        run = r["row"]["run"]
        if run in seen:
            continue
        seen.add(run)
        if r["excluded"]:
            excluded.append(dict(r["row"], reason=r["excluded"]))
            continue
        kept.append(r["row"])
        if r["segregation_fit"] is not None:
            seg.append({"run": run, "fit": r["segregation_fit"],
                        "profile": r["segregation_profile"]})
    cols = list(dict.fromkeys(
        ["theta", "H", "lam", "sigma", "contact_law", "state", *MEASURED_COLUMNS,
         *(f"{c}_std" for c in MEASURED_COLUMNS), *(f"{c}_sem" for c in MEASURED_COLUMNS),
         *EXTRA_COLUMNS]))
    if kept:
        table = campaign_table_from_records(kept)
    else:
        table = campaign_table_from_records([])
        for c in EXTRA_COLUMNS:
            table[c] = pd.Series([], dtype=object if c in _STRING_EXTRAS else float)
    table = table[[c for c in cols if c in table.columns]]
    # rows of runs from before it was recorded: empty
    table["base_sha256"] = (table["base_sha256"] if "base_sha256" in table.columns else
                            pd.Series([""] * len(table), index=table.index, dtype=object)).map(
        lambda v: "" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v))
    # rows from before the segregated start existed: their directory says how they started
    table["initial_mixing"] = [
        (str(v) if isinstance(v, str) and v else
         (parse_run_path(r).start if k == "segregation" else ""))
        for v, r, k in zip(table["initial_mixing"] if "initial_mixing" in table.columns
                           else [""] * len(table), table["run"], table["kind"])]
    if config is not None:  # which base each run fell onto (the configuration knows)
        from .grid import base_path, base_seed

        table["base_seed"] = pd.Series([float(base_seed(config, parse_run_path(r)))
                                        for r in table["run"]], index=table.index, dtype=float)
        check_one_base_per_file(table, [base_path(config, parse_run_path(r))
                                        for r in table["run"]])
    Path(out_csv).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out_csv, table.to_csv(index=False, float_format="%.17g").encode())
    atomic_to_netcdf(table_dataset(table, attrs, config), out_nc)
    if out_excluded is not None:
        ex_cols = ["run", "reason", "theta", "H", "lam", "sigma", "contact_law", "state",
                   *[c for c in cols if c not in ("run", "theta", "H", "lam", "sigma",
                                                  "contact_law", "state")]]
        frame = pd.DataFrame(excluded)
        frame = frame.reindex(columns=ex_cols)
        atomic_write_bytes(out_excluded, frame.to_csv(index=False, float_format="%.17g").encode())
    if out_segregation is not None:
        atomic_write_bytes(out_segregation, dumps(seg).encode())
    return table


def read_excluded(path) -> pd.DataFrame:
    """Excluded runs written by :func:`collect_table` (empty frame if none)."""
    try:
        frame = pd.read_csv(path)
    except pd.errors.EmptyDataError:
        return pd.DataFrame(columns=["run", "reason"])
    for col in ("run", "reason", "contact_law", "state", "kind", "stop_reason"):
        if col in frame:
            frame[col] = frame[col].astype(str).astype(object)
    return frame


def segregation_fits(path) -> list:
    """Per-run segregation FitResults stored by :func:`collect_table`."""
    with open(path) as fh:
        data = from_jsonable(json.load(fh))
    return [fit_from_dict(d["fit"]) for d in data]
