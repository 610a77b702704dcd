"""CF-1.8 / ACDD-1.3 compliance of every granflow output kind, checked by IOOS's checker.

A short bidisperse run (series.nc with the segregation monitor, profiles.nc with per-species
fields), a campaign table and a closure library from synthetic rows are written with an ACDD
attribution (the configuration's ``metadata``), then:

* the CF 1.8 check has no high-priority failure (series.nc names its nondimensional simulated
  time ``t``: a variable named ``time`` is taken for a calendar time axis, ``<unit> since
  <epoch>``, which it is not);
* ACDD 1.3 scores >= 90 % over the checks that apply to a particle simulation
  (tests/cf_compliance.py: no CF standard names, geospatial or calendar-time attributes);
* every ``units`` parses with cf_units (UDUNITS) as intended: ``1`` or ``degree``, never a
  length or a time (``d`` would be a day), and every nondimensional quantity states its scale
  in ``nondimensional_unit``, whose dimension and size are checked with SI values;
* no _FillValue on coordinates, no int64, no two names that differ only by case, and the
  campaign table carries its provenance.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import xarray as xr

from cf_compliance import check

cf_units = pytest.importorskip("cf_units")
pytest.importorskip("compliance_checker")

from granflow import units as U  # noqa: E402
from granflow.campaign.collect import (collect_table, read_table,  # noqa: E402
                                       segregation_fits)
from granflow.campaign.fits import run_fits  # noqa: E402
from granflow.closures import open_library, write_library  # noqa: E402
from granflow.provenance import config_hash  # noqa: E402
from granflow.simulate import prepare_base_file, simulate  # noqa: E402
from test_campaign import _synthetic_rows  # noqa: E402

METADATA = {"creator_name": "A. Researcher", "creator_email": "researcher@example.org",
            "creator_url": "https://example.org/researcher", "creator_type": "person",
            "creator_institution": "Example University", "institution": "Example University",
            "publisher_name": "Example University Library", "publisher_email": "data@example.org",
            "publisher_url": "https://example.org/data", "publisher_type": "institution",
            "publisher_institution": "Example University", "project": "granular closures",
            "program": "basic research", "license": "CC-BY-4.0",
            "acknowledgement": "computed with granflow", "contributor_name": "B. Reviewer",
            "contributor_role": "reviewer"}
#: the CF high-priority failures granflow keeps, and why (see the module docstring)
KEPT_CF_FAILURES: dict = {}  # none: series.nc names its nondimensional clock t, not time


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    """Every output kind, written with the attribution of METADATA."""
    mp = pytest.MonkeyPatch()
    mp.setenv("GRANFLOW_METADATA", json.dumps(METADATA))  # as the workflow passes it to jobs
    d = tmp_path_factory.mktemp("cf")
    base = d / "base.npy"
    prepare_base_file(1.0, 6.0, 4.0, 3, base, base_layers=4.0, settle_time=5.0)
    params = dict(theta=28.0, H=4.0, lam=1.0, Lx=6.0, Ly=4.0, seed=5, t_end=6.0, t_c=0.02,
                  base_layers=4.0, averaging_time=3.0, check_every=1.0, cg_window=2.0,
                  sigma=0.75, phi0=0.5, early_stop=False)
    simulate(params, d / "run", base_file=base)
    config = {"name": "synthetic", "metadata": METADATA}
    rows = _synthetic_rows(d)
    collect_table(rows, d / "campaign_table.nc", d / "t.csv", d / "ex.csv", d / "seg.json",
                  attrs={"campaign": "synthetic"}, config=config)
    table = read_table(d / "campaign_table.nc")
    fits = run_fits(table, segregation_fits(d / "seg.json"), n_bootstrap=5)
    lib = write_library(d / "lib", "cftest", fits, table, config=config)
    mp.undo()
    files = {"series.nc": d / "run" / "series.nc", "profiles.nc": d / "run" / "profiles.nc",
             "profiles_history.nc": d / "run" / "profiles_history.nc",
             "campaign_table.nc": d / "campaign_table.nc", "closure library": lib}
    return files, config


KINDS = ["series.nc", "profiles.nc", "profiles_history.nc", "campaign_table.nc",
         "closure library"]


def test_a_bidisperse_run_keeps_every_window_in_its_profiles_history(outputs):
    """profiles.nc averages the last averaging_time of this drifting bidisperse run (3 of its
    6 time units); profiles_history.nc keeps every window from t = 0, the shared ones bit for
    bit, and summary.json records it with its size and SHA-256 (so a finished run's approach
    of its segregated state is not lost with its checkpoint)."""
    from granflow.simulate import file_record

    files, _ = outputs
    run = files["profiles.nc"].parent
    with xr.open_dataset(files["profiles.nc"]) as last, \
            xr.open_dataset(files["profiles_history.nc"]) as every:
        t_last = last["window_time_start"].values
        t_every = every["window_time_start"].values
        assert t_every.min() == 0.0 and last.attrs["profile_time_from"] == 3.0
        assert t_last.min() >= 3.0 and len(t_every) == 4 and len(t_last) == 2  # 0, 2, 4, 6
        assert every.attrs["profile_time_from"] == 0.0
        assert every.attrs["profiles_nc_time_from"] == 3.0
        shared = np.isin(t_every, t_last)
        assert shared.sum() == len(t_last)
        for name in ("species_volume_fraction_window", "stress_zz_window"):
            np.testing.assert_array_equal(every[name].values[shared], last[name].values)
    summary = json.loads((run / "summary.json").read_text())
    assert summary["outputs"]["profiles_history.nc"] == file_record(files["profiles_history.nc"])


@pytest.fixture(scope="module")
def scores(outputs):
    files, _ = outputs
    out = {kind: check(path) for kind, path in files.items()}
    for kind, s in out.items():  # the numbers, for the record
        print(kind, {k: f"{v.scored:g}/{v.possible:g} = {v.percent:.1f} %" for k, v in s.items()})
    return out


@pytest.mark.parametrize("kind", KINDS)
def test_cf_has_no_high_priority_failure(scores, kind):
    failures = {name for name, _ in scores[kind]["cf:1.8"].high_failures}
    assert failures <= KEPT_CF_FAILURES.get(kind, set()), scores[kind]["cf:1.8"].high_failures


@pytest.mark.parametrize("kind", KINDS)
def test_acdd_scores_at_least_90_percent_of_what_applies(scores, kind):
    s = scores[kind]["acdd:1.3 applicable"]
    assert s.percent >= 90.0, (s.scored, s.possible, s.high_failures, s.medium_failures)
    assert not s.high_failures, s.high_failures


def _variables(path):
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        for name, var in nc.variables.items():
            yield name, var.dtype, {k: var.getncattr(k) for k in var.ncattrs()}, \
                set(nc.dimensions), dict(nc.__dict__)


@pytest.mark.parametrize("kind", KINDS)
def test_strings_are_character_arrays_not_variable_length(outputs, kind):
    """No output holds HDF5 variable-length strings, whose stored lengths a reader allocates
    before it can tell a file is corrupt (:func:`granflow.cfconventions.encoding`)."""
    files, _ = outputs
    with netCDF4.Dataset(files[kind]) as nc:
        vlen = [n for n, v in nc.variables.items() if v.dtype is str or not
                isinstance(v.dtype, np.dtype)]
    assert not vlen, vlen
    with xr.open_dataset(files[kind]) as ds:  # and they read back as strings
        text = [n for n, v in ds.variables.items() if v.dtype.kind in "OU"]
        assert all(isinstance(ds[n].values.ravel()[0], str) for n in text if ds[n].size), text
    if kind in ("campaign_table.nc", "closure library"):
        assert text  # these hold text: run ids, states, messages


@pytest.mark.parametrize("kind", KINDS)
def test_units_parse_as_intended_and_state_their_scale(outputs, kind):
    files, _ = outputs
    second, metre = cf_units.Unit("s"), cf_units.Unit("m")
    n_scaled = 0
    for name, dtype, attrs, _, _ in _variables(files[kind]):
        if "units" not in attrs:
            assert dtype == str or dtype.kind in "SU" or name.endswith("_message"), name
            continue
        unit = cf_units.Unit(attrs["units"])  # UDUNITS must parse it
        assert not unit.is_convertible(second) and not unit.is_convertible(metre), (name, attrs)
        if attrs["units"] == "degree":
            assert unit.is_convertible(cf_units.Unit("radian"))
        elif attrs["units"] == "degree-1":  # a slope per degree (reduced density form)
            assert unit.is_convertible(cf_units.Unit("radian-1"))
        else:
            assert attrs["units"] == "1" and unit.is_dimensionless(), (name, attrs)
        scale = attrs.get("nondimensional_unit")
        if scale is not None:
            n_scaled += 1
            _si_of(scale)  # a valid expression of particle_diameter, particle_mass, gravity
    assert n_scaled >= 2  # lengths, times, velocities, energies, ... state their scale


def test_the_old_units_were_misread_by_udunits():
    """Why units are '1': UDUNITS reads the paper's 'd' as a day and 'm' as a metre."""
    assert cf_units.Unit("d").is_convertible(cf_units.Unit("s"))
    assert cf_units.Unit("m").is_convertible(cf_units.Unit("km"))
    for const in ("LENGTH", "TIME", "VELOCITY", "DENSITY", "STRESS", "ENERGY", "SHEAR_RATE"):
        assert U.cf(getattr(U, const), "x")["units"] == "1"


class _Q:
    """A number with SI dimensions (kg, m, s) -- enough to evaluate a scale expression."""

    def __init__(self, value, kg=0.0, m=0.0, s=0.0):
        self.value, self.dims = value, np.array([kg, m, s], float)

    def __mul__(self, o):
        o = o if isinstance(o, _Q) else _Q(o)
        return _Q(self.value * o.value, *(self.dims + o.dims))

    __rmul__ = __mul__

    def __truediv__(self, o):
        o = o if isinstance(o, _Q) else _Q(o)
        return _Q(self.value / o.value, *(self.dims - o.dims))

    def __pow__(self, p):
        return _Q(self.value ** p, *(self.dims * p))


D_BEAD, M_BEAD, G = 1e-4, 2500 * math.pi / 6 * 1e-12, 9.80665  # 0.1 mm glass bead


def _si_of(expr):
    ns = {"particle_diameter": _Q(D_BEAD, m=1), "particle_mass": _Q(M_BEAD, kg=1),
          "gravity": _Q(G, m=1, s=-2), "__builtins__": {}}
    return eval(expr, ns)  # noqa: S307 -- our own expressions, names limited to ns


@pytest.mark.parametrize("const,dims", [
    ("LENGTH", (0, 1, 0)), ("TIME", (0, 0, 1)), ("VELOCITY", (0, 1, -1)),
    ("ACCELERATION", (0, 1, -2)), ("MASS", (1, 0, 0)), ("DENSITY", (1, -3, 0)),
    ("MASS_PER_AREA", (1, -2, 0)), ("STRESS", (1, -1, -2)), ("FORCE", (1, 1, -2)),
    ("ENERGY", (1, 2, -2)), ("SHEAR_RATE", (0, 0, -1))])
def test_scale_expressions_have_the_right_dimension(const, dims):
    q = _si_of(U.cf(getattr(U, const), "x")["nondimensional_unit"])
    assert np.allclose(q.dims, dims), (const, q.dims)


def test_time_and_velocity_units_of_glass_beads():
    """The README's numbers: for 0.1 mm glass beads the time unit is 3.2 ms, velocity 0.031 m/s."""
    t = _si_of(U.cf(U.TIME, "x")["nondimensional_unit"]).value
    v = _si_of(U.cf(U.VELOCITY, "x")["nondimensional_unit"]).value
    assert round(t * 1e3, 1) == 3.2 and round(v, 3) == 0.031
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert "for 0.1 mm glass beads 3.2 ms" in readme


@pytest.mark.parametrize("kind", KINDS)
def test_no_fill_value_on_coordinates_no_int64_no_case_duplicates(outputs, kind):
    files, _ = outputs
    names = []
    for name, dtype, attrs, dims, _ in _variables(files[kind]):
        names.append(name)
        if name in dims:
            assert "_FillValue" not in attrs, name
        assert not (dtype != str and dtype.kind in "iu" and dtype.itemsize == 8), name
    lower = [n.lower() for n in names]
    assert len(set(lower)) == len(lower), sorted(n for n in names if lower.count(n.lower()) > 1)


def test_campaign_table_carries_provenance_and_reads_back_with_column_H(outputs):
    files, config = outputs
    with netCDF4.Dataset(files["campaign_table.nc"]) as nc:
        attrs = dict(nc.__dict__)
        assert "H" not in nc.variables and nc.variables["H_fill"].campaign_column == "H"
    for key in ("git_commit", "created", "units_system", "granflow_version", "history"):
        assert attrs.get(key), key
    assert attrs["config_hash"] == config_hash(config)
    assert attrs["creator_name"] == METADATA["creator_name"]
    table = read_table(files["campaign_table.nc"])
    measured = table["h"].notna()  # an undecided run without a flow height is in the table too
    assert {"h", "H"} <= set(table.columns) and (table["H"] > table["h"])[measured].all()
    lib = open_library(files["closure library"])
    assert "campaign_H_fill" in lib and "campaign_H" not in lib
