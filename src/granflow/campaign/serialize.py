"""Exact JSON round trip of :class:`granflow.fitting.FitResult` (NaN/inf as strings)."""

from __future__ import annotations

import json
import math

import numpy as np

from ..fitting.result import FitResult

_SPECIAL = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}


def _enc(x):
    if isinstance(x, dict):
        return {str(k): _enc(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_enc(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        if math.isnan(x):
            return "NaN"
        if math.isinf(x):
            return "Infinity" if x > 0 else "-Infinity"
        return x
    if x is None or isinstance(x, str):
        return x
    return str(x)


def _dec(x):
    if isinstance(x, dict):
        return {k: _dec(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_dec(v) for v in x]
    if isinstance(x, str) and x in _SPECIAL:
        return _SPECIAL[x]
    return x


def to_jsonable(obj):
    """Strict-JSON-safe copy of nested dicts/lists/numbers (floats keep their exact value)."""
    return _enc(obj)


def from_jsonable(obj):
    return _dec(obj)


def fit_to_dict(r: FitResult) -> dict:
    return _enc({
        "kind": r.kind, "equation": r.equation, "params": r.params, "stderr": r.stderr,
        "error": r.error, "n_points": r.n_points, "ok": r.ok, "message": r.message,
        "stderr_method": r.stderr_method, "error_measure": r.error_measure,
        "valid_range": {k: list(v) for k, v in r.valid_range.items()},
        "coords": r.coords, "extra": r.extra, "status": r.status, "form": r.form,
        "param_status": r.param_status, "param_reason": r.param_reason,
        "ensemble": [list(e) for e in r.ensemble], "diagnostics": r.diagnostics,
        "runs_used": list(r.runs_used), "selection": r.selection,
        # the order of params is the order of the ensemble's columns; the JSON writer sorts
        # keys, so it is stored apart
        "param_order": list(r.params),
    })


def _param_order(d: dict) -> list:
    """The fit's parameter (= ensemble column) order: stored with it, else (fits.json written
    before the order was stored) the order of its kind in the library schema, else as read."""
    names = list(d["params"])
    order = d.get("param_order")
    if order and sorted(order) == sorted(names):
        return list(order)
    from ..closures.schema import KINDS

    spec = KINDS.get(d.get("kind"))
    if spec is not None and sorted(spec.params) == sorted(names):
        return list(spec.params)
    return names


def fit_from_dict(d: dict) -> FitResult:
    d = _dec(d)
    extra = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.get("extra", {}).items()}
    order = _param_order(d)
    return FitResult(kind=d["kind"], equation=d["equation"],
                     params={k: d["params"][k] for k in order},
                     stderr={k: d["stderr"][k] for k in order if k in d["stderr"]}, error=float(d["error"]),
                     n_points=int(d["n_points"]), ok=bool(d["ok"]), message=d["message"],
                     stderr_method=d.get("stderr_method", "covariance"),
                     error_measure=d.get("error_measure", ""),
                     valid_range={k: tuple(v) for k, v in d.get("valid_range", {}).items()},
                     coords=dict(d.get("coords", {})), extra=extra,
                     status=d.get("status", ""), form=d.get("form", "full"),
                     param_status=dict(d.get("param_status", {})),
                     param_reason=dict(d.get("param_reason", {})),
                     ensemble=tuple(tuple(e) for e in d.get("ensemble", [])),
                     diagnostics=dict(d.get("diagnostics", {})),
                     runs_used=tuple(d.get("runs_used", [])), selection=d.get("selection", ""))


def dumps(obj) -> str:
    return json.dumps(_enc(obj), indent=1, sort_keys=True, allow_nan=False)
