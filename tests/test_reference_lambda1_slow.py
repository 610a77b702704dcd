"""The lambda = 1 reference against the paper's Table 1, Eq. 52 and Eq. 53 (slow).

Needs the reference's results (``snakemake --cores 2 --configfile config/reference-lambda1.yaml``,
about 2 h on 2 cores, ``results/reference-lambda1``; skipped without them).  Each parameter must
agree with the paper's value within twice its own stderr, or within 5 % where that is looser
(issue 14, ``granflow.reference.compare_with_paper`` through ``benchmarks/paper_table.py``), and
be identified by the data.  The parameters the configuration as it is does not reproduce are
strict expected failures with the measured numbers (2026-12-01, a832318: the paper's insertion
column), so a rerun that reproduces them, or loses another, shows here.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pandas as pd
import pytest

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "results" / "reference-lambda1"

#: measured misses of the configuration as it is (README, "The lambda = 1 reference as it is
#: configured now"); the reason is the measurement
MISSES = {
    ("flow_rule", "beta"): "0.246 +- 0.019 against Table 1's 0.196 (+25 %, z +2.6): the hstop "
                           "curve lies +0.93 deg above Table 1's; with Table 1's hstop the same "
                           "runs give 0.164 +- 0.007",
    ("density", "c1"): "6.34 +- 0.61 against Eq. 52's 4.8 (+32 %, z +2.5); the curve is within "
                       "0.3 % of Eq. 52 over 22-29 deg",
    ("density", "c2"): "44.9 +- 1.2 against Eq. 52's 40.85 (+9.9 %, z +3.3)",
}
PARAMETERS = [("hstop", "delta1"), ("hstop", "delta2"), ("hstop", "A"), ("flow_rule", "beta"),
              ("flow_rule", "gamma"), ("alpha", "d_lambda"), ("density", "c0"),
              ("density", "c1"), ("density", "c2"), ("stress_ratio", "d0"),
              ("stress_ratio", "d1")]


@pytest.fixture(scope="module")
def rows():
    if not (RESULTS / "closures.csv").exists():
        pytest.skip("needs the lambda = 1 reference: "
                    "snakemake --cores 2 --configfile config/reference-lambda1.yaml")
    spec = importlib.util.spec_from_file_location("paper_table",
                                                  REPO / "benchmarks" / "paper_table.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    table = mod.paper_rows(pd.read_csv(RESULTS / "closures.csv"))
    return {(r["closure"], r["parameter"]): r for r in table}


@pytest.mark.parametrize("kind, parameter", [
    pytest.param(k, p, marks=[pytest.mark.xfail(strict=True, reason=MISSES[(k, p)])]
                 if (k, p) in MISSES else []) for k, p in PARAMETERS])
def test_parameter_agrees_with_the_paper(rows, kind, parameter):
    r = rows[(kind, parameter)]
    assert math.isfinite(r["value"]) and math.isfinite(r["stderr"])
    assert r["agrees"], (f"{kind}.{parameter} = {r['value']:.4g} +- {r['stderr']:.2g} against "
                         f"the paper's {r['paper']:g} (z {r['z']:+.1f})")


def test_the_reference_identifies_every_parameter_it_compares(rows):
    """Agreement is only counted for parameters the data identify: none of the eleven may be
    unidentified, reduced away or at a bound."""
    assert {(k, p) for k, p in PARAMETERS} <= set(rows)
    for key in PARAMETERS:
        assert rows[key]["status"] == "identified", (key, rows[key])
