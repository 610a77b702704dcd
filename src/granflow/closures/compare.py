"""Parameter-by-parameter comparison of two closure library versions.

:func:`compare_libraries` lists every fitted parameter (variables with a ``_stderr`` twin) at every
coordinate of either library, with both values and uncertainties, the difference b - a and that
difference in units of the combined standard error sqrt(stderr_a^2 + stderr_b^2).
:func:`format_comparison` renders the table as text (for the ``granflow`` CLI).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import xarray as xr

from .library import open_library
from .schema import CONTACT_LAW_DIM, LAMBDA_DIM, SIGMA_DIM

COMPARISON_COLUMNS = ("kind", "parameter", "contact_law", "lambda", "sigma", "units",
                      "value_a", "stderr_a", "value_b", "stderr_b", "difference",
                      "combined_stderr", "z")


def _as_lib(x):
    return x if isinstance(x, xr.Dataset) else open_library(x)


def _parameter_names(lib):
    return {n for n in lib.data_vars if f"{n}_stderr" in lib.data_vars}


def _series(lib, name):
    if lib is None or name not in lib:
        return None
    s = lib[name].to_series()
    if not isinstance(s.index, pd.MultiIndex):
        s.index = pd.MultiIndex.from_arrays([s.index], names=[s.index.name])
    return s


def _records(lib, name):
    out = {}
    for what in ("value", "stderr"):
        s = _series(lib, name if what == "value" else f"{name}_stderr")
        if s is None:
            continue
        for key, v in s.items():
            key = key if isinstance(key, tuple) else (key,)
            coords = dict(zip(s.index.names, key))
            ident = (str(coords.get(CONTACT_LAW_DIM, "")),
                     float(coords.get(LAMBDA_DIM, math.nan)),
                     float(coords.get(SIGMA_DIM, math.nan)))
            ident = tuple("nan" if isinstance(x, float) and math.isnan(x) else
                          (round(x, 9) if isinstance(x, float) else x) for x in ident)
            out.setdefault(ident, {})[what] = float(v)
    return out


def compare_libraries(path_a, path_b) -> pd.DataFrame:
    """Compare two libraries (paths or opened Datasets) parameter by parameter.

    Returns a DataFrame with columns :data:`COMPARISON_COLUMNS`; ``z`` = difference /
    combined_stderr (0 where both are identical, NaN where undefined).
    """
    a, b = _as_lib(path_a), _as_lib(path_b)
    rows = []
    for name in sorted(_parameter_names(a) | _parameter_names(b)):
        src = a if name in a else b
        attrs = src[name].attrs
        ra, rb = _records(a, name), _records(b, name)
        for ident in sorted(set(ra) | set(rb), key=str):
            va = ra.get(ident, {}).get("value", math.nan)
            sa = ra.get(ident, {}).get("stderr", math.nan)
            vb = rb.get(ident, {}).get("value", math.nan)
            sb = rb.get(ident, {}).get("stderr", math.nan)
            diff = vb - va
            comb = math.hypot(sa, sb) if math.isfinite(sa) and math.isfinite(sb) else math.nan
            if diff == 0:
                z = 0.0
            elif math.isfinite(comb) and comb > 0:
                z = diff / comb
            else:
                z = math.nan
            law, lam, sig = ident
            rows.append({"kind": attrs.get("closure_kind", ""),
                         "parameter": attrs.get("parameter", name),
                         "contact_law": law, "lambda": math.nan if lam == "nan" else lam,
                         "sigma": math.nan if sig == "nan" else sig,
                         "units": attrs.get("nondimensional_unit") or attrs.get("units", ""), "value_a": va, "stderr_a": sa,
                         "value_b": vb, "stderr_b": sb, "difference": diff,
                         "combined_stderr": comb, "z": z})
    return pd.DataFrame(rows, columns=list(COMPARISON_COLUMNS))


def format_comparison(df: pd.DataFrame, *, only_fitted: bool = True) -> str:
    """Plain-text table of :func:`compare_libraries` output (rows with no values dropped)."""
    if only_fitted:
        df = df[np.isfinite(df["value_a"]) | np.isfinite(df["value_b"])]

    def num(x):
        return "-" if not np.isfinite(x) else f"{x:.6g}"

    def coord(r):
        parts = [r["contact_law"]]
        if np.isfinite(r["lambda"]):
            parts.append(f"lambda={r['lambda']:.4g}")
        if np.isfinite(r["sigma"]):
            parts.append(f"sigma={r['sigma']:.4g}")
        return " ".join(parts)

    header = ["closure", "param", "where", "units", "a", "+-a", "b", "+-b", "b-a", "z"]
    lines = [[r["kind"], r["parameter"], coord(r), r["units"], num(r["value_a"]),
              num(r["stderr_a"]), num(r["value_b"]), num(r["stderr_b"]), num(r["difference"]),
              num(r["z"])] for _, r in df.iterrows()]
    widths = [max(len(str(x)) for x in col) for col in zip(header, *lines)] if lines else \
        [len(h) for h in header]
    fmt = "  ".join(f"{{:<{w}}}" if i < 4 else f"{{:>{w}}}" for i, w in enumerate(widths))
    out = [fmt.format(*header), fmt.format(*["-" * w for w in widths])]
    out += [fmt.format(*map(str, line)) for line in lines]
    return "\n".join(out)
