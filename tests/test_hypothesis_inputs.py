"""Bad input, systematically (issue 19, section 3): property-based tests with hypothesis.

Three interfaces take files from users:

* run parameter files (``granflow simulate params.yaml``: :func:`granflow.simulate.load_params`
  / :func:`~granflow.simulate.validate_params`),
* campaign configurations (``granflow campaign check-config``, the Snakefile:
  :func:`granflow.campaign.config.check_config`, then ``snakemake.utils.validate``),
* closure libraries (:func:`granflow.closures.open_library`).

Each is fed random wrong types, out-of-range values, NaN/inf, missing and extra keys, absurd
sizes (a box of 1e9 particles, t_end 1e12) and, for files, random truncations and corrupted
bytes.  The property is always the same: a clear error -- ValueError (or FileNotFoundError)
naming the field or file -- or a valid result; never an exception of another type, a hang
(hypothesis' deadline) or a large allocation (tracemalloc peak), and no compute.

The number of examples per interface is ``GRANFLOW_HYPOTHESIS_EXAMPLES`` (default 200 for
the fast suite) for the cheap run-parameter interfaces, and a sixth of it for the campaign
configurations and library files (each example there validates a whole campaign or opens a
netCDF file: ~0.2-0.3 s), so that the file takes well under a minute.  Run with
``GRANFLOW_HYPOTHESIS_EXAMPLES=2000 pytest tests/test_hypothesis_inputs.py -s`` for the
issue's measurement; the examples per interface are printed at the end of the module.
"""

from __future__ import annotations

import contextlib
import copy
import io
import math
import os
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, assume, given, note, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from granflow.campaign import grid as G  # noqa: E402
from granflow.campaign.config import check_config, default_schema_path, load_yaml  # noqa: E402
from granflow.simulate import (ABSENT_UNLESS_GIVEN, MAX_STEPS, PARAMETERS,  # noqa: E402
                               estimate_run_size, load_params, machine_memory, validate_params)

REPO = Path(__file__).resolve().parents[1]
SCHEMA = default_schema_path()
N = int(os.environ.get("GRANFLOW_HYPOTHESIS_EXAMPLES", "200"))
PROFILE = settings(max_examples=N, deadline=10000, derandomize=False, database=None,
                   suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                          HealthCheck.filter_too_much])
#: campaign configurations and library files: each example costs ~0.2-0.3 s
EXPENSIVE_PROFILE = settings(PROFILE, max_examples=max(N // 6, 10), deadline=30000)
#: largest allocation a validation may make (it must not build the run)
MAX_ALLOCATION = 20e6

#: a valid, tiny run (the soft particles of the test campaign)
VALID_RUN = dict(theta=26.0, H=4.0, lam=1.0, Lx=6.0, Ly=4.0, seed=5, t_end=12.0, t_c=0.02,
                 base_layers=4.0, averaging_time=3.0, check_every=1.0, cg_window=2.0)

# values of every kind a YAML/JSON file can hold, with the usual suspects over-represented
nasty_numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.sampled_from([0, -1, 1e9, 1e12, 1e300, -1e300, 1e-300, 5e-324, math.nan, math.inf,
                     -math.inf, 2**63, 2**64, 0.5, 1.0, 90.0, 1e4, 1e7 + 1]),
)
nasty_scalars = st.one_of(nasty_numbers, st.none(), st.booleans(),
                          st.text(max_size=12), st.sampled_from(["24", "nan", "inf", "", "linear"]))
nasty_values = st.one_of(
    nasty_scalars,
    st.lists(nasty_scalars, max_size=3),
    st.dictionaries(st.text(max_size=5), nasty_scalars, max_size=2),
)
extra_keys = st.one_of(st.text(min_size=1, max_size=12), st.integers(-5, 5), st.booleans())

STATS: dict[str, dict] = {}


def _count(interface: str, outcome: str):
    s = STATS.setdefault(interface, {})
    s[outcome] = s.get(outcome, 0) + 1


@contextlib.contextmanager
def bounded_allocation(limit=MAX_ALLOCATION):
    tracemalloc.start()
    try:
        yield
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < limit, f"validation allocated {peak / 1e6:.1f} MB"


#: most that reading a damaged 0.6 MB closure library may add to the resident memory
MAX_LIBRARY_READ = 200e6


def _resident_kb(field: str) -> int:
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith(field))


@contextlib.contextmanager
def bounded_resident_growth(limit):
    """Peak resident memory (VmHWM, reset through /proc/self/clear_refs) may grow by at most
    ``limit`` bytes over the block: it sees the C libraries' allocations (HDF5), which
    tracemalloc does not."""
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")  # the peak restarts from the present resident size
    before = _resident_kb("VmRSS:")
    try:
        yield
    finally:  # also when the block raises (a refused file)
        grown = (_resident_kb("VmHWM:") - before) * 1024
        assert grown < limit, f"reading the file took {grown / 1e6:.0f} MB"


def _mentions_a_parameter(msg: str, keys) -> bool:
    """``msg`` names one of ``keys`` as a word (``theta = ...``, ``['thetaa']``, ``Lx, Ly``)."""
    import re

    return any(re.search(rf"(?<![A-Za-z0-9_]){re.escape(str(k))}(?![A-Za-z0-9_])", msg)
               for k in keys)


# ------------------------------------------------------------------------------ run parameters
@st.composite
def run_parameter_mappings(draw):
    params = dict(VALID_RUN)
    changed = []
    for _ in range(draw(st.integers(1, 4))):
        action = draw(st.sampled_from(["set", "set", "set", "delete", "extra", "absurd"]))
        if action == "set":
            key = draw(st.sampled_from(sorted(PARAMETERS)))
            params[key] = draw(nasty_values)
            changed.append(key)
        elif action == "delete" and params:
            key = draw(st.sampled_from(sorted(params, key=repr)))
            del params[key]
        elif action == "extra":
            key = draw(extra_keys)
            params[key] = draw(nasty_values)
            changed.append(key)
        else:  # absurd sizes that are each within range
            key, value = draw(st.sampled_from([
                ("H", 1e4), ("Lx", 1e4), ("Ly", 1e4), ("t_end", 1e7), ("t_end", 1e12),
                ("cg_dz", 1e-300), ("cg_window", 1e-300), ("sample_interval", 1e-300),
                ("t_c", 1e-300), ("steps_per_collision", 1e6), ("sigma", 1e-300),
                ("base_layers", 100.0), ("cg_every", 1), ("skin", 10.0), ("cg_width", 100.0)]))
            params[key] = value
            changed.append(key)
    return params, changed


@PROFILE
@given(run_parameter_mappings())
def test_run_parameters_clear_error_or_valid_run(case):
    params, changed = case
    note(repr(params))
    try:
        with bounded_allocation():
            p = validate_params(dict(params))
    except ValueError as exc:
        msg = str(exc)
        assert msg and "Traceback" not in msg
        assert _mentions_a_parameter(msg, [*changed, *PARAMETERS]), msg
        _count("run parameters", "refused")
        return
    _count("run parameters", "accepted")
    # accepted: every value typed and in range, a run that fits this machine
    for key in PARAMETERS:  # engine and initial_Ps stay absent unless given
        assert key in p or key in ABSENT_UNLESS_GIVEN
    assert all(isinstance(p[k], (int, float)) and not isinstance(p[k], bool)
               for k in ("theta", "H", "lam", "Lx", "Ly", "t_end", "t_c", "seed"))
    size = estimate_run_size(p)
    assert size["n_steps"] <= MAX_STEPS and size["memory_bytes"] <= machine_memory()
    assert size["n_flow"] >= 1 and math.isfinite(size["output_bytes"])
    from granflow.simulate import chute_config

    chute_config(p).validate()


@PROFILE
@given(run_parameter_mappings(), st.sampled_from(["as_is", "truncated", "garbage", "list",
                                                  "bad_yaml", "binary"]),
       st.integers(0, 10_000))
def test_run_parameter_files_clear_error_or_valid_run(tmp_path_factory, case, damage, cut):
    params, changed = case
    path = tmp_path_factory.mktemp("params", numbered=True) / "params.yaml"
    text = yaml.safe_dump(params, allow_unicode=True)
    if damage == "truncated":
        text = text[: cut % (len(text) + 1)]
    elif damage == "garbage":
        text = text[: cut % (len(text) + 1)] + "}{: ][\n\t- !!python/object:os.system\n"
    elif damage == "list":
        text = yaml.safe_dump([[k, v] for k, v in params.items()])
    elif damage == "bad_yaml":
        text = "theta: [24\nH: 10\n"
    if damage == "binary":
        path.write_bytes(os.urandom(64) + b"\xff\xfe")
    else:
        path.write_text(text, encoding="utf-8")
    try:
        with bounded_allocation():
            load_params(path)
    except (ValueError, FileNotFoundError) as exc:
        msg = str(exc)
        assert str(path) in msg or _mentions_a_parameter(msg, [*changed, *PARAMETERS]), msg
        _count("run parameter files", "refused")
        return
    _count("run parameter files", "accepted")


@settings(max_examples=max(N // 10, 10), deadline=5000, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(run_parameter_mappings())
def test_cli_refuses_bad_parameter_files_without_a_traceback(tmp_path_factory, case):
    """`granflow simulate` on a refused file: exit status 2, one line naming the problem,
    nothing created.  (Accepted files are not run: that would be compute.)"""
    from granflow.cli import main

    params, _ = case
    try:
        validate_params(dict(params))
        assume(False)
    except ValueError:
        pass
    tmp = tmp_path_factory.mktemp("cli", numbered=True)
    path = tmp / "p.yaml"
    path.write_text(yaml.safe_dump(params))
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(["simulate", str(path), "--out", str(tmp / "out")])
    assert rc == 2 and err.getvalue().startswith("granflow simulate: error: ")
    assert "Traceback" not in err.getvalue()
    assert not (tmp / "out").exists()
    _count("granflow simulate (CLI)", "refused")


def test_absurd_runs_are_refused_with_the_estimate():
    big = dict(VALID_RUN, H=1e4, Lx=1e4, Ly=1e4)  # 1e12 flow particles
    with pytest.raises(ValueError, match=r"run too large for this machine: it needs about "
                                         r"[0-9.]+ PiB of memory \(1e\+12 flow"):
        validate_params(big)
    box_1e9 = dict(VALID_RUN, H=10.0, Lx=1e4, Ly=1e4)  # a box of 1e9 particles
    with pytest.raises(ValueError, match=r"1e\+09 flow \+ [0-9.e+]+ base particles"):
        validate_params(box_1e9)
    with pytest.raises(ValueError, match=r"t_end = 1000000000000.0 is out of range: allowed \(0.0, 10000000.0\]"):
        validate_params(dict(VALID_RUN, t_end=1e12))
    with pytest.raises(ValueError, match=r"time steps of dt = t_c / steps_per_collision"):
        validate_params(dict(VALID_RUN, t_c=1e-9))
    with pytest.raises(ValueError, match=r"cg_dz, cg_window"):
        validate_params(dict(VALID_RUN, cg_dz=1e-12))


# ------------------------------------------------------------------------------ campaign configs
def _base_config():
    cfg = load_yaml(REPO / "config" / "config.yaml")
    from granflow.campaign.commands import _merge

    _merge(cfg, load_yaml(REPO / "config" / "test-tiny.yaml"))
    return cfg


BASE_CONFIG = _base_config()


def _paths(obj, path=()):
    """Every path into a nested configuration (mappings and lists)."""
    yield path
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*path, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, (*path, i))


ALL_PATHS = [p for p in _paths(BASE_CONFIG) if p]
#: config keys -> the run parameter or message word that names them
ALIASES = {"lambda": "lam", "layers": "base_layers", "sigma": "sigma", "H": "H", "theta": "theta"}


def _get(cfg, path):
    for p in path:
        cfg = cfg[p]
    return cfg


@st.composite
def mutated_configs(draw):
    cfg = copy.deepcopy(BASE_CONFIG)
    names = []
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(cfg) if p]
        path = draw(st.sampled_from(paths))
        parent = _get(cfg, path[:-1])
        action = draw(st.sampled_from(["set", "set", "delete", "extra", "absurd", "perturb",
                                       "perturb", "perturb"]))
        value = parent[path[-1]]
        if action == "perturb" and isinstance(value, (int, float)) and not isinstance(value, bool):
            # a plausible change (0.25 to 4 times the value): often a valid campaign
            factor = draw(st.floats(0.25, 4.0))
            parent[path[-1]] = type(value)(value * factor) if isinstance(value, float) \
                else max(int(round(value * factor)), 0)
        elif action in ("set", "perturb"):
            parent[path[-1]] = draw(nasty_values)
        elif action == "delete":
            del parent[path[-1]]
        elif action == "extra" and isinstance(parent, dict):
            key = draw(extra_keys)
            parent[key] = draw(nasty_values)
            path = (*path[:-1], key)
        elif action == "absurd":
            key, value = draw(st.sampled_from([
                (("campaigns", "chute", "Lx"), 1e4), (("campaigns", "chute", "Ly"), 1e4),
                (("campaigns", "chute", "grids", 0, "H"), [1e4]),
                (("numerics", "t_end"), 1e12), (("numerics", "t_end"), 1e7),
                (("numerics", "cg_dz"), 1e-300), (("species", "t_c"), 1e-300),
                (("campaigns", "segregation", "sigma"), [1e-300, 0.5, 0.7]),
                (("campaigns", "segregation", "Lx"), 1e4),
                (("library", "n_bootstrap"), 10**9), (("numerics", "threads"), 10**6)]))
            try:
                parent = _get(cfg, key[:-1])
            except (KeyError, IndexError, TypeError):
                continue  # an earlier change removed or replaced that part of the configuration
            if not isinstance(parent, dict):
                continue
            parent[key[-1]] = value
            path = key
        names += [str(x) for x in path if isinstance(x, str)]
        if action == "extra":
            names.append(repr(path[-1]))
    return cfg, names


def _describe_accepted(cfg):
    """What the Snakefile and common.smk do with an accepted configuration, at parse time."""
    from snakemake.utils import validate

    from granflow.campaign import cluster as CL
    from granflow.campaign import hstop as HS
    from granflow.steady.hstop_search import HstopSearch

    validate(copy.deepcopy(cfg), str(SCHEMA))  # Snakemake's own check agrees
    runs = G.expand_runs(cfg)
    for p in runs:
        assert G.parse_run_path(p.path) == p  # run directories round trip
        validate_params(G.run_params(cfg, p), check_machine=False)
        G.base_path(cfg, p)
    CL.ClusterPlan(cfg, threads=G.threads(cfg))
    G.base_settings(cfg)
    search = (G.campaign_cfg(cfg, "chute").get("hstop_search") or {})
    if G.enabled(cfg, "chute") and search.get("enabled"):
        HstopSearch(**HS.search_settings(search))
    return runs


@EXPENSIVE_PROFILE
@given(mutated_configs())
def test_campaign_configs_clear_error_or_valid_campaign(case):
    cfg, names = case
    note(repr(cfg))
    try:
        with bounded_allocation():
            check_config(cfg, SCHEMA)
    except ValueError as exc:
        msg = str(exc)
        assert msg.startswith("invalid campaign configuration:"), msg
        words = set(names) | {ALIASES.get(n, n) for n in names}
        assert any(w in msg for w in words) or "required property" in msg \
            or "defines no runs" in msg, (names, msg)
        _count("campaign configs", "refused")
        return
    _describe_accepted(cfg)
    _count("campaign configs", "accepted")


@PROFILE
@given(st.sampled_from(["truncated", "garbage", "scalar", "binary"]), st.integers(0, 100_000))
def test_campaign_config_files_clear_error(tmp_path_factory, damage, cut):
    path = tmp_path_factory.mktemp("cfg", numbered=True) / "c.yaml"
    text = (REPO / "config" / "test-tiny.yaml").read_text()
    if damage == "truncated":
        path.write_text(text[: cut % (len(text) + 1)])
    elif damage == "garbage":
        path.write_text(text[: cut % (len(text) + 1)] + "\n: ][ {\n")
    elif damage == "scalar":
        path.write_text("42\n")
    else:
        path.write_bytes(text.encode()[: cut % len(text)] + b"\xff\xfe\x00")
    try:
        cfg = load_yaml(path)
        from granflow.campaign.commands import _merge

        full = load_yaml(REPO / "config" / "config.yaml")
        _merge(full, cfg)
        check_config(full, SCHEMA)
    except (ValueError, FileNotFoundError) as exc:
        assert str(path) in str(exc) or str(exc).startswith("invalid campaign configuration"), exc
        _count("campaign config files", "refused")
        return
    _count("campaign config files", "accepted")


# ------------------------------------------------------------------------------ library files
@pytest.fixture(scope="module")
def small_library(tmp_path_factory):
    from test_closures import make_fits, make_table

    from granflow.closures import write_library

    return write_library(tmp_path_factory.mktemp("lib"), "rough", make_fits(), make_table(),
                         config={"campaign": "synthetic"})


@EXPENSIVE_PROFILE
@given(data=st.data())
def test_library_files_clear_error_or_the_original_library(small_library, tmp_path_factory,
                                                            data):
    from granflow.closures import open_library

    path = small_library
    original = path.read_bytes()
    damage = data.draw(st.sampled_from(["truncate", "flip", "block", "append", "empty",
                                        "swap_halves"]))
    blob = bytearray(original)
    n = len(blob)
    if damage == "truncate":
        blob = blob[: data.draw(st.integers(0, n - 1))]
    elif damage == "flip":
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, n - 1))
            blob[i] ^= data.draw(st.integers(1, 255))
    elif damage == "block":
        i = data.draw(st.integers(0, n - 1))
        size = data.draw(st.integers(1, 4096))
        blob[i:i + size] = os.urandom(min(size, n - i))
    elif damage == "append":
        blob += os.urandom(data.draw(st.integers(1, 4096)))
    elif damage == "empty":
        blob = bytearray()
    else:
        blob = blob[n // 2:] + blob[: n // 2]
    bad = tmp_path_factory.mktemp("badlib", numbered=True) / "rough-v1.nc"
    bad.write_bytes(bytes(blob))
    try:
        with bounded_resident_growth(MAX_LIBRARY_READ):  # no corrupt length is allocated
            lib = open_library(bad)
    except (ValueError, FileNotFoundError) as exc:
        assert str(bad) in str(exc), exc
        _count(f"library files ({damage})", "refused")
        return
    # accepted: the damage missed everything the library holds -- same content as the original
    ref = open_library(path)
    assert lib.attrs["content_hash"] == ref.attrs["content_hash"]
    for name in ref.data_vars:
        assert np.array_equal(lib[name].values, ref[name].values, equal_nan=True) \
            if ref[name].dtype.kind == "f" else (lib[name].values == ref[name].values).all()
    _count(f"library files ({damage})", "accepted (damage outside the data)")


@EXPENSIVE_PROFILE
@given(data=st.data())
def test_library_values_changed_inside_a_valid_file_are_detected(small_library,
                                                                 tmp_path_factory, data):
    """Semantic corruption (a valid netCDF with one value changed, an attribute removed):
    never silently wrong -- the content hash or the schema check refuses it."""
    import netCDF4

    from granflow.closures import open_library

    path = small_library
    original = path.read_bytes()
    bad = tmp_path_factory.mktemp("tampered", numbered=True) / "rough-v1.nc"
    bad.write_bytes(original)
    with netCDF4.Dataset(bad, "a") as nc:
        names = sorted(v for v in nc.variables
                       if getattr(nc[v].dtype, "kind", "") == "f" and nc[v].size > 0)
        name = data.draw(st.sampled_from(names))
        var = nc[name]
        flat = data.draw(st.integers(0, var.size - 1))
        idx = np.unravel_index(flat, var.shape) if var.shape else ()
        old = var[idx]
        new = data.draw(st.floats(allow_nan=True, allow_infinity=True))
        assume(not (np.ma.is_masked(old) and math.isnan(new)))
        assume(np.ma.is_masked(old) or not (float(old) == new or
                                            (math.isnan(float(old)) and math.isnan(new))))
        var[idx] = new
        if data.draw(st.booleans()):
            attr = data.draw(st.sampled_from(sorted(nc.ncattrs())))
            nc.delncattr(attr)
    note(f"{name}{idx}: {old} -> {new}")
    with pytest.raises((ValueError, FileNotFoundError)) as err:
        open_library(bad)
    assert str(bad) in str(err.value)
    _count("library files (values changed)", "refused")


@pytest.fixture(scope="module", autouse=True)
def report_example_counts():
    """Print the examples run per interface (collected by the tests above; -s to see it)."""
    yield
    for name, outcomes in sorted(STATS.items()):
        total = sum(outcomes.values())
        print(f"\nhypothesis {name}: {total} examples "
              + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())), end="")
