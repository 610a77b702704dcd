"""IOOS compliance-checker scores (CF 1.8, ACDD 1.3) of netCDF files, as numbers.

Used by tests/test_cf_compliance.py and runnable on its own to record scores:

    .venv/bin/python tests/cf_compliance.py results/test-tiny/closures.nc ...

prints, per file and checker, the scored/possible points, the percentage and every failed
check of high priority -- for ACDD twice: as the checker scores it, and over the checks that
apply to a particle simulation (``acdd:1.3 applicable``), which leaves out

* the per-variable CF ``standard_name`` (the CF standard-name table has no granular-flow
  quantities; an invented name would fail the CF check, and the generic ones -- time, height --
  require dimensional units while granflow's are nondimensional);
* the geospatial and ``time_coverage_*`` attributes (no place on Earth, no calendar time) and
  the platform/instrument vocabularies (no observing platform).
"""

from __future__ import annotations

import contextlib
import copy
import sys
from dataclasses import dataclass, field

#: compliance_checker.cf.util functions of the dataset alone that the CF checks call once per
#: variable, each scanning every variable (quadratic: 208 s of a closure library's 330
#: variables, measured 2026-12-07); the checks only read the dataset, so each is memoized per
#: (dataset, arguments) while :func:`check` runs -- the same results, the same scores
MEMOIZED_CF_UTIL = ("get_auxiliary_coordinate_variables", "get_axis_variables",
                    "get_time_variables", "get_cell_boundary_variables",
                    "get_bounds_variables")


@contextlib.contextmanager
def _memoized_cf_util():
    """Every module of compliance_checker that holds one of :data:`MEMOIZED_CF_UTIL` gets a
    memoizing wrapper of it until the block ends (the originals are put back)."""
    from compliance_checker.cf import util

    wrapped = {}
    for name in MEMOIZED_CF_UTIL:
        fn = getattr(util, name, None)
        if fn is None:
            continue
        cache = {}

        def memo(ds, *args, _fn=fn, _cache=cache, **kwargs):
            key = (id(ds), args, tuple(sorted(kwargs.items())))
            if key not in _cache:
                _cache[key] = _fn(ds, *args, **kwargs)
            return copy.copy(_cache[key])  # a caller that edits its list leaves the cache be
        wrapped[fn] = memo
    patched = []
    for mod in [m for k, m in list(sys.modules.items()) if k.startswith("compliance_checker")]:
        for attr, value in list(vars(mod).items()):
            if callable(value) and value in wrapped:
                patched.append((mod, attr, value))
                setattr(mod, attr, wrapped[value])
    try:
        yield
    finally:
        for mod, attr, value in patched:
            setattr(mod, attr, value)

CHECKERS = ("cf:1.8", "acdd:1.3")
#: ACDD global attributes that do not apply to a particle simulation (see the docstring)
ACDD_NOT_APPLICABLE = (
    "geospatial_bounds", "geospatial_bounds_crs", "geospatial_bounds_vertical_crs",
    "geospatial_lat_min", "geospatial_lat_max", "geospatial_lon_min", "geospatial_lon_max",
    "geospatial_vertical_min", "geospatial_vertical_max", "geospatial_vertical_positive",
    "geospatial_lat_units", "geospatial_lat_resolution", "geospatial_lon_units",
    "geospatial_lon_resolution", "geospatial_vertical_units", "geospatial_vertical_resolution",
    "time_coverage_start", "time_coverage_end", "time_coverage_duration",
    "time_coverage_resolution", "standard_name_vocabulary", "platform", "platform_vocabulary",
    "instrument", "instrument_vocabulary", "keywords_vocabulary", "metadata_link")
ACDD_NOT_APPLICABLE_RESULTS = ("geospatial_lat_extents_match", "geospatial_lon_extents_match")


@dataclass
class Score:
    checker: str
    scored: float
    possible: float
    high_failures: list = field(default_factory=list)   # (name, messages)
    medium_failures: list = field(default_factory=list)

    @property
    def percent(self) -> float:
        return 100.0 * self.scored / self.possible if self.possible else 100.0


def _failures(results):
    out = []
    for r in results:
        if r.value[0] < r.value[1]:
            out.append((str(r.name), [str(m) for m in r.msgs]))
    return out


def _score(suite, name, results, path, checker=None):
    agg = suite.build_structure(checker or name, results, str(path), limit=1)
    return Score(name, agg["scored_points"], agg["possible_points"],
                 _failures(agg["high_priorities"]), _failures(agg["medium_priorities"]))


def _acdd_applicable(suite, ds, path):
    """ACDD 1.3 over the checks that apply (see the module docstring)."""
    from compliance_checker.base import Result

    checker = suite.checkers["acdd:1.3"]()
    groups = suite.run_all(ds, ["acdd:1.3"], skip_checks=["check_var_standard_name"])
    results, errors = groups["acdd:1.3"]
    if errors:
        raise RuntimeError(f"compliance checker acdd:1.3 errored on {path}: {errors}")
    present = set(ds.ncattrs())
    weight_of = {**{a: 2 for a in checker.rec_atts}, **{a: 1 for a in checker.sug_atts}}
    absent_na = {}
    for a in ACDD_NOT_APPLICABLE:
        if a not in present and a in weight_of:
            absent_na[weight_of[a]] = absent_na.get(weight_of[a], 0) + 1
    out = []
    for r in results:
        if r.name in ACDD_NOT_APPLICABLE_RESULTS:
            continue
        if r.name == "Global Attributes" and absent_na.get(r.weight):
            scored, possible = r.value
            r = Result(r.weight, (scored, possible - absent_na[r.weight]), r.name, r.msgs)
        out.append(r)
    return _score(suite, "acdd:1.3 applicable", out, path, checker="acdd:1.3")


def check(path, checkers=CHECKERS) -> dict[str, Score]:
    """Run the compliance checker on ``path``; scores by checker name (plus
    ``acdd:1.3 applicable`` when ACDD is checked)."""
    from compliance_checker.runner import CheckSuite

    CheckSuite.load_all_available_checkers()
    suite = CheckSuite()
    ds = suite.load_dataset(str(path))
    out = {}
    try:
        with _memoized_cf_util():
            groups = suite.run_all(ds, list(checkers), skip_checks=[])
        for name, (results, errors) in groups.items():
            if errors:
                raise RuntimeError(f"compliance checker {name} errored on {path}: {errors}")
            out[name] = _score(suite, name, results, path)
        if "acdd:1.3" in checkers:
            out["acdd:1.3 applicable"] = _acdd_applicable(suite, ds, path)
    finally:
        close = getattr(ds, "close", None)
        if close is not None:
            close()
    return out


def report(paths) -> str:
    lines = []
    for path in paths:
        for name, s in check(path).items():
            lines.append(f"{path}: {name} {s.scored:g}/{s.possible:g} = {s.percent:.1f} %"
                         f" ({len(s.high_failures)} high-priority failures)")
            for fname, msgs in s.high_failures:
                lines.append(f"    HIGH {fname}: {'; '.join(msgs)[:300]}")
    return "\n".join(lines)


if __name__ == "__main__":
    print(report(sys.argv[1:]))
