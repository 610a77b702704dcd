"""Versioned netCDF closure libraries: writing, reading and content verification.

:func:`write_library` stores a set of :class:`granflow.fitting.FitResult` (the closures of
Weinhart et al. 2012 Eq. 45-55 and Thornton et al. T-eq. 28-29), together with the campaign table
that produced them, as ``<directory>/<name>-v<N>.nc`` (netCDF4). N is the next free version; an
existing version file is never overwritten (``FileExistsError``). The file is staged with
:func:`granflow.provenance.atomic_to_netcdf` and then hard-linked into place, which is atomic and
fails if the target appeared meanwhile. The layout is described in :mod:`granflow.closures.schema`.

Global attributes: ``granflow_schema``, ``schema_version``, ``library_name``, ``library_version``,
``created``, ``granflow_version``, ``git_commit``, ``config_hash`` (+ ``config_json``),
``units_system``, ``reductions_vs_paper`` and ``content_hash`` = ``sha256:<hex>`` of the data
values (see :func:`content_hash`), which :func:`open_library` verifies.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import uuid
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from .. import cfconventions
from .. import units as U
from ..fitting.result import DATA_BOUND_LEVEL, FitResult
from ..fitting.table import COLUMN_ATTRS, STRING_COLUMNS, validate_campaign_table
from ..provenance import atomic_to_netcdf, provenance_attrs
from ..fitting.identify import CRITERION, assess
from .schema import (CAMPAIGN_PREFIX, CONTACT_LAW_DIM, COORD_TO_DIM, KINDS, LAMBDA_DIM,
                     RUN_DIM, SAMPLE_DIM, SCHEMA_NAME, SCHEMA_VERSION, SIGMA_DIM)

_NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
RESERVED_ATTRS = ("granflow_schema", "schema_version", "library_name", "library_version",
                  "content_hash", "created", "granflow_version", "git_commit", "config_hash",
                  "config_json", "units_system", "reductions_vs_paper", "Conventions", "kinds",
                  "identifiability_criterion")
_LAMBDA_ATOL = 1e-9


# ---------------------------------------------------------------------------- hashing
def content_hash(ds: xr.Dataset) -> str:
    """``sha256:<hex>`` of a dataset's data values (all variables and coordinates, by name).

    Values are hashed in a canonical form so the hash survives a netCDF round trip: floats as
    little-endian float64 (every NaN the same), integers and booleans as little-endian int64,
    strings as UTF-8 separated by U+001F. Each variable contributes its name, dimensions and
    shape. Attributes are not hashed (they carry provenance, not data).
    """
    sha = hashlib.sha256()
    for name in sorted(map(str, ds.variables)):
        var = ds.variables[name]
        values = np.asarray(var.values)
        sha.update(f"{name}|{','.join(map(str, var.dims))}|{values.shape}|".encode())
        if values.dtype.kind in "fc":
            v = values.astype("<f8" if values.dtype.kind == "f" else "<c16")
            v = np.where(np.isnan(v), np.nan, v)
            sha.update(np.ascontiguousarray(v).tobytes())
        elif values.dtype.kind in "iub":
            sha.update(np.ascontiguousarray(values.astype("<i8")).tobytes())
        else:
            sha.update("\x1f".join(str(x.decode() if isinstance(x, bytes) else x)
                                   for x in values.ravel()).encode())
        sha.update(b"\x1e")
    return "sha256:" + sha.hexdigest()


# ---------------------------------------------------------------------------- building
def _flatten(fits):
    out = []
    stack = [fits]
    while stack:
        item = stack.pop()
        if isinstance(item, FitResult):
            out.append(item)
        elif isinstance(item, dict):
            stack.extend(reversed(list(item.values())))
        elif isinstance(item, (list, tuple)):
            stack.extend(reversed(item))
        else:
            raise TypeError(f"expected FitResult (or lists/dicts of them), got {type(item)}")
    return out


def _unique_floats(values):
    out = []
    for v in sorted(values):
        if not out or abs(v - out[-1]) > _LAMBDA_ATOL:
            out.append(v)
    return out


def _index_of(coord_values, value):
    if isinstance(value, str):
        return coord_values.index(value)
    for i, c in enumerate(coord_values):
        if abs(c - value) <= _LAMBDA_ATOL:
            return i
    raise KeyError(value)


def _closure_variables(results, default_contact_law):
    by_kind = {}
    for r in results:
        if r.kind not in KINDS:
            raise ValueError(f"unknown closure kind {r.kind!r}; known: {sorted(KINDS)}")
        coords = dict(r.coords)
        coords.setdefault("contact_law", default_contact_law)
        spec = KINDS[r.kind]
        for key, dim in COORD_TO_DIM.items():
            if dim in spec.dims and coords.get(key) is None:
                raise ValueError(f"{r.kind} fit needs coordinate {key!r} (use result.tagged({key}=...))")
        by_kind.setdefault(r.kind, []).append((coords, r))

    coord_values = {CONTACT_LAW_DIM: set(), LAMBDA_DIM: set(), SIGMA_DIM: set()}
    for kind, items in by_kind.items():
        for coords, _ in items:
            for key, dim in COORD_TO_DIM.items():
                if dim in KINDS[kind].dims:
                    coord_values[dim].add(str(coords[key]) if dim == CONTACT_LAW_DIM
                                          else float(coords[key]))
    cvals = {CONTACT_LAW_DIM: sorted(coord_values[CONTACT_LAW_DIM]),
             LAMBDA_DIM: _unique_floats(coord_values[LAMBDA_DIM]),
             SIGMA_DIM: _unique_floats(coord_values[SIGMA_DIM])}

    data_vars = {}
    max_samples = [0]
    for kind in sorted(by_kind):
        spec = KINDS[kind]
        shape = tuple(len(cvals[d]) for d in spec.dims)
        pv = {p: np.full(shape, np.nan) for p in spec.params}
        se = {p: np.full(shape, np.nan) for p in spec.params}
        err = np.full(shape, np.nan)
        ok = np.zeros(shape, dtype=np.int8)
        npts = np.zeros(shape, dtype=np.int32)
        msg = np.full(shape, "not fitted", dtype=object)
        status = np.full(shape, "not fitted", dtype=object)
        form = np.full(shape, "", dtype=object)
        selection = np.full(shape, "", dtype=object)
        pstat = {p: np.full(shape, "not_fitted", dtype=object) for p in spec.params}
        preason = {p: np.full(shape, "", dtype=object) for p in spec.params}
        diag = {k: np.full(shape, np.nan) for k in ("heldout_max_abs_z", "chi2_dof",
                                                     "birge_ratio")}
        between = {p: np.full(shape, np.nan) for p in spec.params}
        # one-sided bounds the data give parameters an optimiser bound limits on the other side
        data_lo = {p: np.full(shape, np.nan) for p in spec.params}
        data_hi = {p: np.full(shape, np.nan) for p in spec.params}
        heldout_json = np.full(shape, "{}", dtype=object)
        ens = {}
        rmin = {v: np.full(shape, np.nan) for v in spec.ranges}
        rmax = {v: np.full(shape, np.nan) for v in spec.ranges}
        extra = {}
        seen = set()
        methods = set()
        for coords, r in by_kind[kind]:
            idx = tuple(_index_of(cvals[d], str(coords[k]) if d == CONTACT_LAW_DIM else float(coords[k]))
                        for d in spec.dims for k, dd in COORD_TO_DIM.items() if dd == d)
            if idx in seen:
                raise ValueError(f"two {kind} fits for the same coordinates {coords}")
            seen.add(idx)
            if not r.param_status and r.state != "failed":
                # a fit made without the identifiability tests (a user's own FitResult): test
                # it here rather than store its parameters as identified because it converged
                r = assess(r)
            unknown = set(r.params) - set(spec.params)
            if unknown:
                raise ValueError(f"{kind} fit has unexpected parameters {sorted(unknown)}")
            for p in spec.params:
                pv[p][idx] = r.params.get(p, math.nan)
                se[p][idx] = r.stderr.get(p, math.nan)
            err[idx] = r.error
            ok[idx] = int(bool(r.ok))
            npts[idx] = int(r.n_points)
            msg[idx] = r.message or ("ok" if r.ok else "failed")
            status[idx] = r.state
            form[idx] = r.form
            selection[idx] = r.selection
            for p in spec.params:
                pstat[p][idx] = r.param_status.get(p, "unidentified")
                preason[p][idx] = r.param_reason.get(p, "")
            d = r.diagnostics
            diag["heldout_max_abs_z"][idx] = d.get("heldout_max_abs_z", np.nan)
            if d.get("dof"):
                diag["chi2_dof"][idx] = d.get("chi2", np.nan) / d["dof"]
            diag["birge_ratio"][idx] = d.get("birge_ratio", np.nan)
            for p, b in ((r.extra.get("bootstrap") or {}).get("data_bound") or {}).items():
                if p in data_lo and b and math.isfinite(b.get("value", math.nan)):
                    (data_hi if b["side"] == "upper" else data_lo)[p][idx] = b["value"]
            for p, parts in (d.get("uncertainty_split") or {}).items():
                if p in between:
                    between[p][idx] = parts.get("between", np.nan)
            heldout_json[idx] = json.dumps({k: (v if math.isfinite(v) else None)
                                            for k, v in d.get("heldout_z", {}).items()},
                                           sort_keys=True)
            arr = r.ensemble_array()
            if arr.shape[0]:
                ens[idx] = arr
            methods.add(r.stderr_method)
            for v, (lo, hi) in r.valid_range.items():
                if v in spec.ranges:
                    rmin[v][idx], rmax[v][idx] = lo, hi
            for key in spec.extras:
                val = r.extra.get(key)
                if val is None:
                    continue
                if isinstance(val, (tuple, list)) and len(val) == 2:
                    for suffix, x in zip(("low", "high"), val):
                        extra.setdefault(f"{key}_{suffix}", np.full(shape, np.nan))[idx] = x
                elif isinstance(val, (int, float, np.number)):
                    extra.setdefault(key, np.full(shape, np.nan))[idx] = val
        dims = spec.dims
        eq = spec.equation
        for p, (units, long_name) in spec.params.items():
            data_vars[f"{kind}_{p}"] = (dims, pv[p], U.cf(
                units, long_name, equation=eq, closure_kind=kind, parameter=p,
                uncertainty_variable=f"{kind}_{p}_stderr"))
            data_vars[f"{kind}_{p}_stderr"] = (dims, se[p], U.cf(
                units, f"standard error of {long_name}", closure_kind=kind,
                stderr_method="; ".join(sorted(methods))))
        data_vars[f"{kind}_error"] = (dims, err, U.cf(
            spec.error_units, f"{kind} fit error", equation="Weinhart et al. 2012 Eq. (49)",
            closure_kind=kind,
            error_measure="; ".join(sorted({r.error_measure for _, r in by_kind[kind]}))))
        data_vars[f"{kind}_ok"] = (dims, ok, U.cf(
            U.DIMENSIONLESS, f"{kind} fit succeeded", flag_values=np.array([0, 1], np.int8),
            flag_meanings="failed ok", closure_kind=kind))
        data_vars[f"{kind}_n_points"] = (dims, npts, U.cf(
            U.DIMENSIONLESS, f"number of data points in the {kind} fit", closure_kind=kind))
        data_vars[f"{kind}_message"] = (dims, msg, {"long_name": f"{kind} fit status message",
                                                    "closure_kind": kind})
        data_vars[f"{kind}_status"] = (dims, status, {
            "long_name": f"{kind} closure status", "closure_kind": kind,
            "allowed_values": "ok reduced unidentified misfit failed",
            "comment": "ok: every parameter of the full form identified; reduced: a stated "
                       "reduced form is identified and stored; unidentified: no form is; "
                       "misfit: a held-out run contradicts it; failed: no fit"})
        data_vars[f"{kind}_form"] = (dims, form, {
            "long_name": f"{kind} closure form stored (full or a reduced form)",
            "closure_kind": kind})
        data_vars[f"{kind}_selection"] = (dims, selection, {
            "long_name": f"runs used by the {kind} fit and why others were left out",
            "closure_kind": kind})
        for p in spec.params:
            data_vars[f"{kind}_{p}_status"] = (dims, pstat[p], {
                "long_name": f"identifiability of {kind} parameter {p}", "closure_kind": kind,
                "allowed_values": "identified unidentified fixed not_in_form not_fitted",
                "criterion": CRITERION})
            data_vars[f"{kind}_{p}_reason"] = (dims, preason[p], {
                "long_name": f"why {kind} parameter {p} has its status", "closure_kind": kind})
        for p in spec.params:
            if np.isfinite(between[p]).any():
                data_vars[f"{kind}_{p}_between_seed_fraction"] = (dims, between[p], U.cf(
                    U.DIMENSIONLESS, f"share of the variance of {kind} parameter {p} from the "
                    "scatter between seeds (replicates; the rest is within-run)",
                    closure_kind=kind))
        for p, (units, long_name) in spec.params.items():
            for side, arr in (("lower", data_lo[p]), ("upper", data_hi[p])):
                if np.isfinite(arr).any():
                    data_vars[f"{kind}_{p}_data_{side}_bound"] = (dims, arr, U.cf(
                        units, f"one-sided {100 * DATA_BOUND_LEVEL:g} % {side} bound on "
                        f"{long_name} that the data give where an optimiser bound limits it on "
                        "the other side (bootstrap percentile; NaN: the data bound it from "
                        "both sides or from neither)", closure_kind=kind, parameter=p))
        data_vars[f"{kind}_heldout_max_abs_z"] = (dims, diag["heldout_max_abs_z"], U.cf(
            U.DIMENSIONLESS, f"largest held-out (leave-one-out) |z| of the {kind} closure",
            closure_kind=kind))
        data_vars[f"{kind}_heldout_z_json"] = (dims, heldout_json, {
            "long_name": f"held-out z-score per run of the {kind} closure (JSON)",
            "closure_kind": kind})
        data_vars[f"{kind}_chi2_dof"] = (dims, diag["chi2_dof"], U.cf(
            U.DIMENSIONLESS, f"chi-square per degree of freedom of the {kind} fit (runs "
            "weighted by their standard errors)", closure_kind=kind))
        data_vars[f"{kind}_birge_ratio"] = (dims, diag["birge_ratio"], U.cf(
            U.DIMENSIONLESS, f"Birge ratio sqrt(chi2/dof) of the {kind} fit (stderr inflated by "
            "it when > 1)", closure_kind=kind))
        if ens:
            n_s = max(a.shape[0] for a in ens.values())
            max_samples[0] = max(max_samples[0], n_s)
            for j, p in enumerate(spec.params):
                arr = np.full(shape + (n_s,), np.nan)
                for idx, a in ens.items():
                    arr[idx + (slice(0, a.shape[0]),)] = a[:, j]
                data_vars[f"{kind}_ensemble_{p}"] = (dims + (SAMPLE_DIM,), arr, U.cf(
                    spec.params[p][0], f"ensemble of {spec.params[p][1]} (bootstrap refits or "
                    "covariance draws)", closure_kind=kind, parameter=p))
        for v, (units, long_name) in spec.ranges.items():
            data_vars[f"{kind}_{v}_min"] = (dims, rmin[v], U.cf(
                units, f"smallest {long_name} in the {kind} fit data", closure_kind=kind))
            data_vars[f"{kind}_{v}_max"] = (dims, rmax[v], U.cf(
                units, f"largest {long_name} in the {kind} fit data", closure_kind=kind))
        for key, arr in extra.items():
            base = key.rsplit("_", 1)[0] if key.endswith(("_low", "_high")) else key
            units, long_name = spec.extras[base]
            name = f"{kind}_Ps_{key}" if base == "ci95" else f"{kind}_{key}"
            data_vars[name] = (dims, arr, U.cf(units, long_name + (
                f" ({key.rsplit('_', 1)[1]} end)" if base != key else ""), closure_kind=kind))
    for name, (dims, arr, attrs) in list(data_vars.items()):
        if SAMPLE_DIM in dims and arr.shape[-1] < max_samples[0]:
            pad = np.full(arr.shape[:-1] + (max_samples[0] - arr.shape[-1],), np.nan)
            data_vars[name] = (dims, np.concatenate([arr, pad], axis=-1), attrs)
    coords = {}
    for dim, long_name, units in ((CONTACT_LAW_DIM, "contact law", None),
                                  (LAMBDA_DIM, "basal roughness lambda = d_base/d_flow", U.DIMENSIONLESS),
                                  (SIGMA_DIM, "size ratio sigma = d_small/d_large", U.DIMENSIONLESS)):
        if cvals[dim]:
            values = (np.array(cvals[dim], dtype=object) if dim == CONTACT_LAW_DIM
                      else np.array(cvals[dim], dtype=float))
            attrs = {"long_name": long_name} if units is None else U.cf(units, long_name)
            coords[dim] = (dim, values, attrs)
    return data_vars, coords, sorted(by_kind)


def _campaign_variables(table: pd.DataFrame):
    validate_campaign_table(table)
    table = table.reset_index(drop=True)
    out = {}
    for col in table.columns:
        # CF 2.3: no two names that differ only by case (campaign_h, campaign_H)
        name = f"{CAMPAIGN_PREFIX}{'H_fill' if col == 'H' else col}"
        series = table[col]
        from ..campaign.collect import EXTRA_ATTRS  # units of the non-schema columns

        attrs = dict(COLUMN_ATTRS.get(col) or EXTRA_ATTRS.get(col)
                     or {"long_name": f"campaign column {col}"})
        attrs["campaign_column"] = str(col)
        if col in STRING_COLUMNS or not pd.api.types.is_numeric_dtype(series) \
                or pd.api.types.is_bool_dtype(series):
            values = np.array([str(v) for v in series.tolist()], dtype=object)
            attrs["campaign_dtype"] = "str"
        else:
            values = series.to_numpy(dtype=float)
            attrs["campaign_dtype"] = "float"
        out[name] = ((RUN_DIM,), values, attrs)
    return out


def _run_usage_variables(table: pd.DataFrame, results) -> dict:
    """Per run: which closures it entered (``campaign_used_by_<kind>``, int8) and its held-out
    z-score in each (``campaign_heldout_z_<kind>``; NaN where not held out)."""
    from ..fitting.campaign import _ids

    ids = list(_ids(table.reset_index(drop=True)))
    pos = {rid: i for i, rid in enumerate(ids)}
    used, zs = {}, {}
    for r in results:
        if not r.runs_used:
            continue
        u = used.setdefault(r.kind, np.zeros(len(ids), dtype=np.int8))
        z = zs.setdefault(r.kind, np.full(len(ids), np.nan))
        for rid in r.runs_used:
            if rid in pos:
                u[pos[rid]] = 1
        for rid, v in r.diagnostics.get("heldout_z", {}).items():
            if rid in pos and v is not None:
                z[pos[rid]] = v
    out = {}
    for kind in sorted(used):
        out[f"{CAMPAIGN_PREFIX}used_by_{kind}"] = ((RUN_DIM,), used[kind], U.cf(
            U.DIMENSIONLESS, f"run entered the {kind} fit", flag_values=np.array([0, 1], np.int8),
            flag_meanings="not_used used", campaign_derived=1))
        if np.isfinite(zs[kind]).any():
            out[f"{CAMPAIGN_PREFIX}heldout_z_{kind}"] = ((RUN_DIM,), zs[kind], U.cf(
                U.DIMENSIONLESS, f"held-out (leave-one-out) z-score of the run in the {kind} fit",
                campaign_derived=1))
    return out


def build_library_dataset(fits, campaign_table=None, *, name="closures", version=1, config=None,
                          attrs=None, reductions=None,
                          default_contact_law="unspecified") -> xr.Dataset:
    """The in-memory Dataset that :func:`write_library` stores (content hash included)."""
    results = _flatten(fits)
    if not results:
        raise ValueError("no fits given")
    data_vars, coords, kinds = _closure_variables(results, default_contact_law)
    if campaign_table is not None:
        data_vars.update(_campaign_variables(campaign_table))
        data_vars.update(_run_usage_variables(campaign_table, results))
    ds = xr.Dataset(data_vars=data_vars, coords=coords)
    user = dict(attrs or {})
    clash = sorted(set(user) & set(RESERVED_ATTRS))
    if clash:
        raise ValueError(f"attrs may not set reserved global attributes {clash}")
    glob = {
        "Conventions": cfconventions.CONVENTIONS,
        "title": f"granflow closure library {name} v{version}",
        "granflow_schema": SCHEMA_NAME,
        "schema_version": SCHEMA_VERSION,
        "library_name": name,
        "library_version": int(version),
        "kinds": " ".join(kinds),
        "references": "Weinhart, Thornton, Luding, Bokhove (2012) Granular Matter 14:531; "
                      "Thornton, Weinhart, Ogarko, Luding, multi-scale methods (segregation)",
        "reductions_vs_paper": reductions if reductions else "none stated",
        "identifiability_criterion": CRITERION,
    }
    glob.update(provenance_attrs(config if config is not None else {}))
    for key, value in user.items():
        if isinstance(value, bool):
            value = int(value)
        if not isinstance(value, (str, int, float, np.number)):
            value = str(value)
        glob[key] = value
    ds.attrs = glob
    ds.attrs["content_hash"] = content_hash(ds)
    cfconventions.apply(  # CF/ACDD attributes (not hashed: attributes only)
        ds, kind="closure_library", config=config,
        summary=(f"Closure relations for shallow granular flows ({', '.join(kinds)}) fitted "
                 "with uncertainties to a campaign of periodic-chute discrete particle "
                 "simulations (Weinhart et al. 2012 Eq. 45-55; Thornton et al. T-eq. 28-29), "
                 "with the campaign table they were fitted to."),
        title=glob["title"], identifier=f"{name}-v{int(version)}")
    return ds


# ---------------------------------------------------------------------------- versions / writing
def _check_name(name: str):
    if not _NAME_RE.fullmatch(name):
        raise ValueError(f"library name {name!r} must match {_NAME_RE.pattern}")


def library_versions(directory, name: str) -> list[int]:
    """Version numbers of ``<name>-v<N>.nc`` files present in ``directory`` (sorted)."""
    _check_name(name)
    pattern = re.compile(rf"{re.escape(name)}-v(\d+)\.nc")
    directory = Path(directory)
    if not directory.is_dir():
        return []
    return sorted(int(m.group(1)) for p in directory.iterdir()
                  if (m := pattern.fullmatch(p.name)))


def library_path(directory, name: str, version: int) -> Path:
    """Path of version ``version`` of library ``name`` in ``directory``."""
    _check_name(name)
    return Path(directory) / f"{name}-v{int(version)}.nc"


def write_library(directory, name: str, fits, campaign_table=None, config=None, attrs=None, *,
                  reductions: str | None = None, version: int | None = None,
                  default_contact_law: str = "unspecified") -> Path:
    """Write closure fits as a new library version ``<directory>/<name>-v<N>.nc``; return its path.

    Parameters
    ----------
    fits : FitResult objects (or nested lists/dicts of them), each tagged with the coordinates
        its kind needs (``lam`` for hstop/flow_rule/friction/alpha, ``sigma`` for segregation;
        ``contact_law`` defaults to ``default_contact_law``).
    campaign_table : the campaign table (validated) stored on the ``run`` dimension, or None.
    config : configuration mapping; its hash and JSON go into ``config_hash``/``config_json``.
    attrs : extra global attributes (may not override reserved ones).
    reductions : text describing reductions versus the paper protocol (shorter runs, fewer
        heights, ...), stored as ``reductions_vs_paper``.
    version : explicit version number; default: one more than the highest present. An existing
        version file is never overwritten: ``FileExistsError``.
    """
    _check_name(name)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    auto = version is None
    for _attempt in range(20):
        if auto:
            present = library_versions(directory, name)
            version = (present[-1] + 1) if present else 1
        if int(version) < 1:
            raise ValueError("library version numbers start at 1")
        final = library_path(directory, name, version)
        if final.exists():
            raise FileExistsError(f"{final} exists; library versions are never overwritten")
        ds = build_library_dataset(fits, campaign_table, name=name, version=version, config=config,
                                   attrs=attrs, reductions=reductions,
                                   default_contact_law=default_contact_law)
        staging = directory / f".{final.name}.staging-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        try:
            # strings as character arrays (schema 2.1): granflow.cfconventions.encoding
            atomic_to_netcdf(ds, staging, engine="netcdf4", format="NETCDF4")
            try:
                os.link(staging, final)  # atomic; fails if final exists
            except FileExistsError:
                if auto:
                    continue
                raise FileExistsError(f"{final} exists; library versions are never overwritten")
            except OSError:  # file system without hard links
                if final.exists():
                    if auto:
                        continue
                    raise FileExistsError(f"{final} exists; library versions are never overwritten")
                os.rename(staging, final)
            return final
        finally:
            if staging.exists():
                staging.unlink()
    raise FileExistsError(f"could not claim a free version of {name!r} in {directory}")


# ---------------------------------------------------------------------------- reading
def open_library(path, *, verify: bool = True) -> xr.Dataset:
    """Read a closure library into memory and check it.

    Raises FileNotFoundError if ``path`` does not exist and ValueError if it is not a readable
    netCDF file (e.g. truncated), is a netCDF file without the granflow closure schema, has an
    unsupported schema version, or (with ``verify``) its data do not match ``content_hash``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no closure library at {path}")
    try:
        with xr.open_dataset(path, engine="netcdf4", decode_times=False,
                             decode_timedelta=False) as src:
            ds = src.load()
    except Exception as exc:  # netCDF4/HDF5 raise OSError, RuntimeError, ...
        raise ValueError(f"{path} is not a readable netCDF file (truncated or corrupt?): "
                         f"{type(exc).__name__}: {exc}") from None
    if ds.attrs.get("granflow_schema") != SCHEMA_NAME:
        raise ValueError(f"{path} is a netCDF file but not a granflow closure library "
                         f"(no granflow_schema = {SCHEMA_NAME!r} attribute)")
    version = str(ds.attrs.get("schema_version", ""))
    if version.split(".")[0] != SCHEMA_VERSION.split(".")[0]:
        raise ValueError(f"{path} has closure-library schema version {version!r}; this granflow "
                         f"reads {SCHEMA_VERSION}")
    if verify:
        stored = ds.attrs.get("content_hash")
        actual = content_hash(ds)
        if stored != actual:
            raise ValueError(f"{path}: content hash mismatch (stored {stored}, data give "
                             f"{actual}); the file was modified or corrupted")
    return ds


def campaign_table(lib: xr.Dataset) -> pd.DataFrame:
    """The campaign table stored in a library (empty DataFrame if none)."""
    cols = {}
    for name, var in lib.data_vars.items():
        if (name.startswith(CAMPAIGN_PREFIX) and var.dims == (RUN_DIM,)
                and not var.attrs.get("campaign_derived")):
            col = var.attrs.get("campaign_column", name[len(CAMPAIGN_PREFIX):])
            values = var.values
            if var.attrs.get("campaign_dtype") == "str":
                cols[col] = pd.Series([str(v) for v in values], dtype=object)
            else:
                cols[col] = pd.Series(values.astype(float))
    return pd.DataFrame(cols)
