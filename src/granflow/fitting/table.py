"""Campaign table: one row per simulation run, the input of every closure fit.

The table is a plain :class:`pandas.DataFrame` with the columns of :data:`CAMPAIGN_COLUMNS`
(Weinhart et al. 2012 §8-9 and Thornton et al. §6 quantities). Later pipeline stages build the
rows from the attributes of the per-run netCDF files; here the schema is only documented and
checked. Extra columns (e.g. ``run_id``) are allowed and kept.

Columns (all nondimensional, :mod:`granflow.units`):

=============  =========  =================================================================
column         units      meaning
=============  =========  =================================================================
theta          degree     chute inclination
H              d          filling height (about 200 H flowing particles in a 20 x 10 box)
lam            1          basal roughness lambda = d_base / d_flow (0 = flat wall)
sigma          1          size ratio d_small / d_large (1 for monodisperse runs)
contact_law    --         ``linear`` / ``hertzian`` / ``plastic`` (free string)
state          --         ``arrested`` / ``steady`` / ``accelerating`` / ``layered`` / ``oscillating``
                          / ``undecided`` (cap reached before the classifier could decide; each
                          closure states how it treats these runs) / ``flowing`` (an hstop
                          bracket run stopped once decisively not arresting: flowing for hstop,
                          no steady averages)
h              d          flow height, Eq. (42)
u_bar          sqrt(g d)  depth-averaged velocity, Eq. (33)
F              1          Froude number u_bar / sqrt(g cos(theta) h)
alpha          1          shape factor mean(u^2)/u_bar^2
K              1          stress ratio sigma_xx_bar / sigma_zz_bar
rho_bar        m d-3      depth-averaged density
rho_c          m d-3      bulk density, Eq. (51)
Ps             1          segregation Peclet number (NaN for non-segregation runs)
phi0           1          mean small-particle volume fraction (NaN for non-segregation runs)
<col>_std      as <col>   spread (standard deviation over the averaging window) of each
                          measured column: h, u_bar, F, alpha, K, rho_bar, rho_c, Ps, phi0
<col>_sem      as <col>   standard error of the run's mean from decorrelated time windows
                          (sqrt(g var / N)); the per-run uncertainty the fits use: within
                          the run's steady window only, a lower bound (``SEM_CAVEAT``)
=============  =========  =================================================================

Optional extra columns used by the fits when present: ``run`` (run identifier, listed in each
closure's ``runs_used``) and ``segregation_state`` (``steady`` / ``drifting`` for bidisperse
runs: only steady segregated states enter the Ps(sigma) law).

Measured columns may be NaN where not applicable (e.g. ``u_bar`` of an arrested run).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from .. import units as U

#: Columns that describe how a run was set up.
INPUT_COLUMNS = ("theta", "H", "lam", "sigma", "contact_law", "state")
#: Measured (output) columns; each also has a ``<col>_std`` spread column.
MEASURED_COLUMNS = ("h", "u_bar", "F", "alpha", "K", "rho_bar", "rho_c", "Ps", "phi0")
STD_COLUMNS = tuple(f"{c}_std" for c in MEASURED_COLUMNS)
SEM_COLUMNS = tuple(f"{c}_sem" for c in MEASURED_COLUMNS)
STRING_COLUMNS = ("contact_law", "state")
CAMPAIGN_COLUMNS = INPUT_COLUMNS + MEASURED_COLUMNS + STD_COLUMNS + SEM_COLUMNS
FLOW_STATES = ("arrested", "steady", "accelerating", "layered", "oscillating", "undecided",
               "flowing")

#: CF units and long names of each column (used when the table is stored in a library).
COLUMN_ATTRS = {
    "theta": U.cf(U.ANGLE, "chute inclination theta"),
    "H": U.cf(U.LENGTH, "filling height H"),
    "lam": U.cf(U.DIMENSIONLESS, "basal roughness lambda = d_base/d_flow"),
    "sigma": U.cf(U.DIMENSIONLESS, "size ratio sigma = d_small/d_large"),
    "contact_law": {"long_name": "contact law"},
    "state": {"long_name": "flow state", "allowed_values": " ".join(FLOW_STATES)},
    "h": U.cf(U.LENGTH, "flow height h (Eq. 42)"),
    "u_bar": U.cf(U.VELOCITY, "depth-averaged downslope velocity"),
    "F": U.cf(U.DIMENSIONLESS, "Froude number u_bar/sqrt(g cos(theta) h)"),
    "alpha": U.cf(U.DIMENSIONLESS, "velocity shape factor alpha"),
    "K": U.cf(U.DIMENSIONLESS, "stress ratio K = sigma_xx/sigma_zz"),
    "rho_bar": U.cf(U.DENSITY, "depth-averaged density"),
    "rho_c": U.cf(U.DENSITY, "bulk density (Eq. 51)"),
    "Ps": U.cf(U.DIMENSIONLESS, "segregation Peclet number Ps"),
    "phi0": U.cf(U.DIMENSIONLESS, "mean small-particle volume fraction phi0"),
}
#: What a run's ``<col>_sem`` does not know (stored as the columns' ``comment``).  Measured on the
#: lambda = 1/2 reference (README, benchmarks/early_stop_bias.py): continued to t = 2000, its
#: early-stopped runs' 100-unit means of u_bar scatter 1.4-14x more than their u_bar_sem says.
SEM_CAVEAT = ("within-run only: batch means of the run's coarse-graining windows inside its "
              "steady averaging window, so a lower bound when that window spans few correlation "
              "times of the flow (measured on the lambda = 1/2 reference: the scatter of one "
              "run's 100-unit means 1.4-14x this value, README); the scatter between seeds "
              "enters the fits only through replicate runs")
for _c in MEASURED_COLUMNS:
    _a = dict(COLUMN_ATTRS[_c])
    _a["long_name"] = "spread (standard deviation) of " + _a["long_name"]
    COLUMN_ATTRS[f"{_c}_std"] = _a
    _a = dict(COLUMN_ATTRS[_c])
    _a["long_name"] = ("standard error of the run mean (decorrelated time windows) of "
                       + _a["long_name"])
    _a["comment"] = SEM_CAVEAT
    COLUMN_ATTRS[f"{_c}_sem"] = _a


def empty_campaign_table() -> pd.DataFrame:
    """A campaign table with the schema's columns and no rows."""
    data = {c: pd.Series([], dtype=object if c in STRING_COLUMNS else float)
            for c in CAMPAIGN_COLUMNS}
    return pd.DataFrame(data)


def campaign_table_from_records(records) -> pd.DataFrame:
    """Build and validate a campaign table from a list of dicts (one per run).

    Missing measured and ``_std`` columns (and keys) are filled with NaN; a missing ``sigma``
    defaults to 1 (monodisperse); ``lam`` is required. Unknown keys become extra columns.
    """
    records = list(records)
    df = pd.DataFrame.from_records(records) if records else empty_campaign_table()
    for col in CAMPAIGN_COLUMNS:
        if col not in df.columns:
            if col == "sigma":
                df[col] = 1.0
            elif col in MEASURED_COLUMNS or col in STD_COLUMNS or col in SEM_COLUMNS:
                df[col] = math.nan
    df["sigma"] = pd.to_numeric(df["sigma"]).fillna(1.0)  # monodisperse runs
    ordered = [c for c in CAMPAIGN_COLUMNS if c in df.columns]
    df = df[ordered + [c for c in df.columns if c not in CAMPAIGN_COLUMNS]]
    for col in CAMPAIGN_COLUMNS:
        if col in df.columns and col not in STRING_COLUMNS:
            try:
                df[col] = pd.to_numeric(df[col]).astype(float)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"campaign table column {col!r} is not numeric: {exc}") from None
        elif col in df.columns:
            df[col] = df[col].astype(object)
    validate_campaign_table(df)
    return df.reset_index(drop=True)


def validate_campaign_table(df: pd.DataFrame) -> pd.DataFrame:
    """Check a campaign table against the schema; raise ValueError naming the bad column.

    Checks: every schema column present; numeric columns numeric; theta in (0, 90); H > 0;
    lam >= 0; sigma in (0, 1]; state one of :data:`FLOW_STATES`; contact_law a non-empty
    string; phi0 in [0, 1]; h, rho_bar, rho_c > 0 where given; spreads >= 0 where given.
    Returns ``df`` unchanged.
    """
    if not isinstance(df, pd.DataFrame):
        raise ValueError("campaign table must be a pandas DataFrame")
    for col in CAMPAIGN_COLUMNS:
        if col not in df.columns:
            raise ValueError(f"campaign table is missing column {col!r}")
    for col in CAMPAIGN_COLUMNS:
        if col in STRING_COLUMNS:
            values = df[col].tolist()
            if any(not isinstance(v, str) or not v for v in values):
                raise ValueError(f"campaign table column {col!r} must hold non-empty strings")
            if col == "state":
                bad = sorted(set(values) - set(FLOW_STATES))
                if bad:
                    raise ValueError(f"campaign table column 'state' has unknown states {bad}; "
                                     f"allowed: {FLOW_STATES}")
            continue
        if not pd.api.types.is_numeric_dtype(df[col]) or pd.api.types.is_bool_dtype(df[col]):
            raise ValueError(f"campaign table column {col!r} must be numeric")
    v = {c: df[c].to_numpy(dtype=float) for c in CAMPAIGN_COLUMNS if c not in STRING_COLUMNS}

    def _bad(col, cond_bad, what, allow_nan=True):
        x = v[col]
        if not allow_nan and np.any(~np.isfinite(x)):
            raise ValueError(f"campaign table column {col!r} must be finite")
        with np.errstate(invalid="ignore"):
            if np.any(cond_bad(x) & np.isfinite(x)):
                raise ValueError(f"campaign table column {col!r} must be {what}")

    _bad("theta", lambda x: (x <= 0) | (x >= 90), "in (0, 90) degrees", allow_nan=False)
    _bad("H", lambda x: x <= 0, "> 0", allow_nan=False)
    _bad("lam", lambda x: x < 0, ">= 0", allow_nan=False)
    _bad("sigma", lambda x: (x <= 0) | (x > 1), "in (0, 1]", allow_nan=False)
    _bad("phi0", lambda x: (x < 0) | (x > 1), "in [0, 1]")
    for col in ("h", "rho_bar", "rho_c"):
        _bad(col, lambda x: x <= 0, "> 0")
    for col in STD_COLUMNS + SEM_COLUMNS:
        _bad(col, lambda x: x < 0, ">= 0")
    return df


def select_runs(df: pd.DataFrame, *, states=None, lam=None, contact_law=None, sigma=None,
                atol: float = 1e-9) -> pd.DataFrame:
    """Rows of a campaign table with the given state(s), lambda, contact law and size ratio."""
    mask = np.ones(len(df), dtype=bool)
    if states is not None:
        states = (states,) if isinstance(states, str) else tuple(states)
        mask &= df["state"].isin(states).to_numpy()
    if lam is not None:
        mask &= np.isclose(df["lam"].to_numpy(dtype=float), float(lam), rtol=0, atol=atol)
    if contact_law is not None:
        mask &= (df["contact_law"] == contact_law).to_numpy()
    if sigma is not None:
        mask &= np.isclose(df["sigma"].to_numpy(dtype=float), float(sigma), rtol=0, atol=atol)
    return df.loc[mask]
