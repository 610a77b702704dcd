"""Closure libraries: versioned netCDF round trip, verification, evaluators, comparison (issue 6).

Parameter values are Weinhart et al. 2012 Table 1/2, Eq. (52b), (53) and Thornton et al. T-eq. (29),
copied here; the library must return them bit-for-bit.
"""

import math
import shutil

import netCDF4
import numpy as np
import pandas as pd
import pytest
import xarray as xr

from granflow import cfconventions

import granflow.closures as gc
from granflow.closures import (compare_libraries, format_comparison, open_library,
                               write_library)
from granflow.fitting import (FitResult, alpha_eq54, campaign_table_from_records, failed_fit,
                              fit_flow_rule, fit_hstop, friction_closure, froude_eq47, hstop_eq45,
                              Ps_teq29, stress_ratio_eq53)
from granflow.units import RHO_PARTICLE

TABLE1 = {1.0: (17.708, 32.780, 3.355, 0.196, 0.040),
          2.0 / 3.0: (17.217, 24.302, 11.088, 0.215, -0.143)}
HSTOP1 = dict(zip(("delta1", "delta2", "A"), TABLE1[1.0][:3]))


def _fit(kind, params, stderr_frac=0.01, ranges=None, **coords):
    return FitResult(kind=kind, equation="test", params=dict(params),
                     stderr={k: abs(v) * stderr_frac for k, v in params.items()},
                     error=0.1, n_points=20, ok=True, message="synthetic",
                     valid_range=dict(ranges or {}), coords=coords)


def make_fits(contact_law="linear"):
    fits = []
    for lam, (d1, d2, A, beta, gamma) in TABLE1.items():
        fits.append(_fit("hstop", dict(delta1=d1, delta2=d2, A=A), lam=lam,
                         contact_law=contact_law, ranges={"theta": (18.0, 28.0), "h": (2.0, 40.0)}))
        fits.append(_fit("flow_rule", dict(beta=beta, gamma=gamma), lam=lam, contact_law=contact_law,
                         ranges={"theta": (20.0, 29.0), "h": (2.0, 60.0), "F": (0.0, 6.0)}))
        fits.append(_fit("friction", dict(HSTOP1, beta=beta, gamma=gamma), lam=lam,
                         contact_law=contact_law,
                         ranges={"theta": (20.0, 29.0), "h": (2.0, 60.0), "F": (0.0, 6.0)}))
    fits.append(_fit("alpha", dict(d_lambda=6.678, alpha_constant=math.nan), lam=1.0,
                     contact_law=contact_law, ranges={"theta": (20.0, 29.0), "h": (5.0, 40.0)}))
    fits.append(_fit("alpha", dict(d_lambda=math.nan, alpha_constant=1.201), lam=2.0 / 3.0,
                     contact_law=contact_law, ranges={"theta": (20.0, 29.0), "h": (5.0, 40.0)}))
    fits.append(_fit("density", dict(c0=0.5985, c1=4.8, c2=40.85), contact_law=contact_law,
                     ranges={"theta": (20.0, 29.0)}))
    fits.append(_fit("stress_ratio", dict(d0=132.0, d1=21.5), contact_law=contact_law,
                     ranges={"theta": (20.0, 29.0)}))
    fits.append(_fit("Ps_law", dict(Pmax=7.35, k=5.21), contact_law=contact_law,
                     ranges={"sigma": (0.3, 0.95)}))
    fits.append(_fit("mu_I", dict(mu_s=0.382, mu_d=0.682, I0=0.279), contact_law=contact_law,
                     ranges={"I": (0.01, 1.0)}))
    for sigma in (0.5, 0.8):
        r = _fit("segregation", {"Ps": float(Ps_teq29(sigma, 7.35, 5.21))}, sigma=sigma,
                 contact_law=contact_law, ranges={"z": (0.0, 1.0)})
        fits.append(FitResult(**{**r.__dict__, "extra": {"phi0": 0.5, "ci95": (6.9, 7.7),
                                                        "scaled_depth": 21.87}}))
    return fits


def make_table():
    return campaign_table_from_records([
        dict(theta=24.0, H=20.0, lam=1.0, contact_law="linear", state="steady", h=18.25, u_bar=3.5,
             F=0.84, alpha=1.29, K=1.02, rho_bar=1.05, rho_c=1.101, h_std=0.01, run_id="r001"),
        dict(theta=19.5, H=20.0, lam=1.0, contact_law="linear", state="arrested", h=17.9,
             run_id="r002"),
        dict(theta=25.0, H=30.0, lam=0.5, sigma=0.5, contact_law="linear", state="steady",
             Ps=7.2, Ps_std=0.3, phi0=0.5, run_id="r003"),
    ])


@pytest.fixture
def lib_path(tmp_path):
    return write_library(tmp_path / "libs", "rough", make_fits(), make_table(),
                         config={"campaign": "synthetic", "seed": 1}, attrs={"purpose": "test"},
                         reductions="T = 50 instead of 100; 10 heights")


def test_write_read_round_trip_is_exact(lib_path):
    assert lib_path.name == "rough-v1.nc"
    lib = open_library(lib_path)
    expected = gc.build_library_dataset(make_fits(), make_table(), name="rough", version=1,
                                        config={"campaign": "synthetic", "seed": 1},
                                        attrs={"purpose": "test"},
                                        reductions="T = 50 instead of 100; 10 heights")
    # every data value identical (NaN == NaN), every attribute identical except creation time
    bare_lib, bare_expected = lib.copy(), expected.copy()
    bare_lib.attrs, bare_expected.attrs = {}, {}
    xr.testing.assert_identical(bare_lib, bare_expected)
    for key in expected.attrs:
        if key not in ("created", "content_hash", *cfconventions.CREATION_TIME_ATTRS):
            assert lib.attrs[key] == expected.attrs[key], key
    assert lib.attrs["content_hash"] == gc.content_hash(lib)
    assert lib.attrs["reductions_vs_paper"] == "T = 50 instead of 100; 10 heights"
    assert lib.attrs["library_version"] == 1 and lib.attrs["purpose"] == "test"
    for key in ("granflow_version", "git_commit", "config_hash", "created", "schema_version"):
        assert key in lib.attrs
    # parameters and stderr as written, bit for bit
    assert lib["hstop_delta2"].sel({"lambda": 1.0, "contact_law": "linear"}).item() == 32.780
    assert lib["hstop_A_stderr"].sel({"lambda": 1.0}).item() == pytest.approx(0.03355, rel=1e-15)
    assert lib["segregation_Ps_ci95_low"].sel(sigma=0.5).item() == 6.9
    # the depth Ps is per travels with it, with its units
    assert lib["segregation_scaled_depth"].sel(sigma=0.8).item() == 21.87
    assert "scaled" in lib["segregation_scaled_depth"].attrs["long_name"]
    for name, var in lib.data_vars.items():
        assert "long_name" in var.attrs, name
        if var.dtype.kind in "fiu" and var.dims != ("run",):  # numbers carry units
            assert "units" in var.attrs, name
    pd.testing.assert_frame_equal(gc.campaign_table(lib), make_table(), check_dtype=False)


def test_versions_never_overwritten(lib_path):
    before = lib_path.read_bytes()
    second = write_library(lib_path.parent, "rough", make_fits(), make_table())
    assert second.name == "rough-v2.nc"
    with pytest.raises(FileExistsError):
        write_library(lib_path.parent, "rough", make_fits(), version=1)
    assert lib_path.read_bytes() == before
    assert gc.library_versions(lib_path.parent, "rough") == [1, 2]
    assert not [p for p in lib_path.parent.iterdir() if p.name.startswith(".")]  # no staging left


def test_bad_files_give_clear_errors(lib_path, tmp_path):
    truncated = tmp_path / "truncated.nc"
    data = lib_path.read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="truncated"):
        open_library(truncated)
    foreign = tmp_path / "foreign.nc"
    xr.Dataset({"t": ("x", np.arange(3.0))}).to_netcdf(foreign)
    with pytest.raises(ValueError, match="not a granflow closure library"):
        open_library(foreign)
    text = tmp_path / "notes.nc"
    text.write_text("hello")
    with pytest.raises(ValueError, match="not a readable netCDF"):
        open_library(text)
    with pytest.raises(FileNotFoundError):
        open_library(tmp_path / "missing.nc")


def test_strings_are_stored_as_character_arrays(lib_path):
    """No variable-length data on disk (schema 2.1): HDF5 allocates a variable-length string's
    stored length before it can tell the file is corrupt (one flipped byte of a 2.0 library
    made its reader allocate 1.2 GB); a character array is the size its shape declares.  The
    strings read back unchanged."""
    lib = open_library(lib_path)
    strings = [n for n, v in lib.variables.items() if v.dtype.kind in "OUS"]
    assert len(strings) > 50  # messages, statuses, forms, reasons, the table's text columns
    with netCDF4.Dataset(lib_path) as nc:
        for name in strings:
            assert nc[name].dtype == np.dtype("S1"), (name, nc[name].dtype)
        assert not [n for n, v in nc.variables.items() if v.dtype is str]
    assert lib.attrs["schema_version"] == "2.1"
    assert lib["hstop_message"].sel({"lambda": 1.0, "contact_law": "linear"}).item() == "synthetic"
    assert list(gc.campaign_table(lib)["run_id"]) == ["r001", "r002", "r003"]
    # a library of schema 2.0 (variable-length strings) still opens, with the same data
    old = lib_path.with_name("rough-v2.nc")
    as_2_0 = lib.assign_attrs(schema_version="2.0")
    for var in as_2_0.variables.values():
        var.encoding = {}  # xarray's default: variable-length strings
    as_2_0.to_netcdf(old, engine="netcdf4")
    with netCDF4.Dataset(old) as nc:
        assert nc["hstop_message"].dtype is str
    assert open_library(old).attrs["content_hash"] == lib.attrs["content_hash"]


def test_content_hash_mismatch_detected(lib_path, tmp_path):
    tampered = tmp_path / "tampered.nc"
    shutil.copy(lib_path, tampered)
    with netCDF4.Dataset(tampered, "a") as nc:
        nc["flow_rule_beta"][0, 0] = 0.25
    with pytest.raises(ValueError, match="content hash mismatch"):
        open_library(tampered)
    assert open_library(tampered, verify=False)["flow_rule_beta"].values[0, 0] == 0.25


def test_evaluators_match_formulas(lib_path):
    lib = open_library(lib_path)
    theta = np.linspace(20.0, 28.0, 9)
    np.testing.assert_array_equal(gc.hstop(lib, theta, 1.0), hstop_eq45(theta, **HSTOP1))
    h = np.linspace(5.0, 40.0, 9)
    np.testing.assert_allclose(gc.alpha(lib, theta, h, 1.0),
                               alpha_eq54(h, hstop_eq45(theta, **HSTOP1), 6.678), rtol=1e-14)
    np.testing.assert_array_equal(gc.alpha(lib, theta, h, 2 / 3), np.full(9, 1.201))
    np.testing.assert_allclose(gc.K(lib, theta), stress_ratio_eq53(theta, 132.0, 21.5), rtol=1e-15)
    np.testing.assert_allclose(gc.density(lib, theta) / RHO_PARTICLE,
                               0.5985 - np.exp((theta - 40.85) / 4.8), rtol=1e-14)
    assert gc.Ps(lib, 0.5) == pytest.approx(7.35 * (1 - math.exp(-5.21)), rel=1e-14)
    assert gc.mu_I(lib, 0.279) == pytest.approx(0.382 + 0.3 / 2, rel=1e-14)  # I = I0: midway


@pytest.mark.parametrize("lam", [1.0, 2.0 / 3.0])
def test_mu_from_library_is_tan_theta_at_steady_flows(lib_path, lam):
    lib = open_library(lib_path)
    theta, h = np.meshgrid(np.linspace(21.0, 28.0, 8), np.linspace(10.0, 40.0, 7))
    beta, gamma = TABLE1[lam][3:]
    F = froude_eq47(h, theta, beta, gamma, **HSTOP1)
    keep = (F > 0) & (F < 6)
    np.testing.assert_allclose(gc.froude(lib, h[keep], theta[keep], lam), F[keep], rtol=1e-14)
    mu = gc.mu(lib, h[keep], F[keep], lam)
    np.testing.assert_allclose(mu, np.tan(np.radians(theta[keep])), rtol=0, atol=1e-10)


def test_evaluators_range_checks_and_extrapolation(lib_path):
    lib = open_library(lib_path)
    with pytest.raises(ValueError, match="outside the fitted range"):
        gc.hstop(lib, [20.0, 30.0], 1.0)
    assert gc.hstop(lib, 30.0, 1.0, extrapolate=True) == pytest.approx(
        float(hstop_eq45(30.0, **HSTOP1)), rel=1e-15)
    with pytest.raises(ValueError, match="h in"):
        gc.mu(lib, 100.0, 1.0, 1.0)
    assert np.isfinite(gc.mu(lib, 100.0, 1.0, 1.0, extrapolate=True))
    with pytest.raises(ValueError, match="sigma"):
        gc.Ps(lib, 0.1)
    with pytest.raises(ValueError, match="theta"):
        gc.density(lib, 35.0)
    with pytest.raises(ValueError, match="lambda = 0.5"):
        gc.hstop(lib, 24.0, 0.5)
    with pytest.raises(ValueError, match="contact law"):
        gc.K(lib, 24.0, contact_law="hertzian")


def test_evaluators_accept_dataarrays_and_accessor(lib_path):
    lib = open_library(lib_path)
    theta = xr.DataArray(np.array([21.0, 24.0, 27.0]), dims="theta")
    h = xr.DataArray(np.array([10.0, 20.0]), dims="h")
    a = gc.alpha(lib, theta, h, 1.0)
    assert isinstance(a, xr.DataArray) and a.dims == ("theta", "h") and a.shape == (3, 2)
    assert a.isel(theta=1, h=1).item() == pytest.approx(
        float(alpha_eq54(20.0, hstop_eq45(24.0, **HSTOP1), 6.678)), rel=1e-14)
    xr.testing.assert_identical(lib.closures.alpha(theta, h, lam=1.0), a)
    assert lib.closures.K(24.0) == gc.K(lib, 24.0)
    pd.testing.assert_frame_equal(lib.closures.campaign_table(), gc.campaign_table(lib))


def test_failed_fit_is_stored_and_refused(tmp_path):
    fits = make_fits()
    fits.append(failed_fit("hstop", "Eq. 45", ("delta1", "delta2", "A"), "too few brackets",
                           1, lam=0.5, contact_law="linear"))
    lib = open_library(write_library(tmp_path, "partial", fits))
    sel = {"lambda": 0.5, "contact_law": "linear"}
    assert lib["hstop_ok"].sel(sel).item() == 0 and np.isnan(lib["hstop_A"].sel(sel).item())
    assert lib["hstop_message"].sel(sel).item() == "too few brackets"
    with pytest.raises(ValueError, match="is failed: too few brackets"):
        gc.hstop(lib, 24.0, 0.5)
    assert lib["flow_rule_ok"].sel(sel).item() == 0  # combination never fitted
    with pytest.raises(ValueError, match="two hstop fits"):
        write_library(tmp_path, "dup", make_fits() + make_fits()[:1])


def test_compare_identical_and_changed_versions(lib_path):
    v2 = write_library(lib_path.parent, "rough", make_fits(), make_table())
    same = compare_libraries(lib_path, v2)
    fitted = same[np.isfinite(same["value_a"])]
    assert len(fitted) > 30
    assert (fitted["difference"] == 0).all() and (fitted["z"] == 0).all()
    changed = [f if not (f.kind == "flow_rule" and f.coords["lam"] == 1.0) else
               _fit("flow_rule", dict(beta=0.206, gamma=0.040), lam=1.0, contact_law="linear",
                    ranges=f.valid_range) for f in make_fits()]
    v3 = write_library(lib_path.parent, "rough", changed)
    diff = compare_libraries(lib_path, v3).set_index(["kind", "parameter", "lambda"])
    row = diff.loc[("flow_rule", "beta", 1.0)]
    # beta 0.196 -> 0.206 with 1 % stderr each: z = 0.010 / hypot(0.00196, 0.00206)
    assert row["difference"] == pytest.approx(0.010, abs=1e-15)
    assert row["z"] == pytest.approx(0.010 / math.hypot(0.00196, 0.00206), rel=1e-12)
    text = format_comparison(compare_libraries(lib_path, v3))
    assert "flow_rule" in text and "beta" in text and "lambda=1" in text


def test_real_fits_through_library(tmp_path):
    """End to end: fits on synthetic steady data -> library -> mu(h, F) = tan(theta)."""
    rng = np.random.default_rng(6)
    hs_fit = fit_hstop(pd.DataFrame({"H": [2.0, 4, 8, 16, 32],
                                     "theta_arrested_max": [27.2, 24.7, 22.2, 20.2, 18.9],
                                     "theta_flowing_min": [27.7, 25.2, 22.7, 20.7, 19.4]}),
                       lam=1.0, contact_law="linear", n_bootstrap=20)
    theta = rng.uniform(21.0, 28.0, 40)
    hs = hstop_eq45(theta, **hs_fit.params)
    h = rng.uniform(1.5, 5.0, 40) * hs
    F = froude_eq47(h, theta, 0.196, 0.040, **hs_fit.params) + rng.normal(0, 0.05, 40)
    flow = fit_flow_rule(theta, h, F, hs_fit, lam=1.0, contact_law="linear")
    fric = friction_closure(hs_fit, flow, theta=theta, h=h, F=F)
    lib = open_library(write_library(tmp_path, "e2e", [hs_fit, flow, fric]))
    Fs = gc.froude(lib, h, theta, 1.0)
    np.testing.assert_allclose(gc.mu(lib, h, Fs, 1.0), np.tan(np.radians(theta)), atol=1e-10)
    assert lib["friction_error"].item() == fric.error > 0
    assert lib["hstop_delta1_stderr"].attrs["stderr_method"] == "bootstrap"


def test_lam_may_be_omitted_only_for_a_one_lambda_library(lib_path, tmp_path):
    lib = open_library(lib_path)
    assert lib["lambda"].size > 1
    with pytest.raises(ValueError, match=r"several lambda \[.*\]: pass lam="):
        lib.closures.hstop(25.0)
    one = lib.sel({"lambda": [1.0]})  # the same closures at lambda = 1 only
    assert one.closures.hstop(25.0) == lib.closures.hstop(25.0, lam=1.0) == pytest.approx(
        float(hstop_eq45(25.0, **HSTOP1)), rel=1e-14)
    assert one.closures.alpha(24.0, 20.0) == lib.closures.alpha(24.0, 20.0, lam=1.0)


def test_accessor_is_registered_by_import_granflow(lib_path):
    """`import granflow` alone (a fresh interpreter) gives ds.closures, without warnings."""
    import subprocess
    import sys

    code = ("import warnings; warnings.simplefilter('error')\n"
            "import granflow, xarray as xr\n"
            f"lib = xr.open_dataset({str(lib_path)!r})\n"
            "print(float(lib.closures.K(24.0)))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert float(proc.stdout) == pytest.approx(float(gc.K(open_library(lib_path), 24.0)))


def test_paper_reference_values_and_comparison():
    """granflow.reference holds Weinhart et al. 2012 Table 1/2, Eq. 52-53 and T-eq. 29 as
    printed; compare_with_paper marks agreement within 2 stderr or 5 %."""
    from granflow.reference import compare_with_paper, paper_value

    assert paper_value("hstop", "delta2", 1.0) == 32.780
    assert paper_value("flow_rule", "gamma", 0.5) == -0.236
    assert paper_value("alpha", "alpha_constant", 0.5) == 1.142
    assert paper_value("stress_ratio", "d1") == 21.50 and paper_value("Ps_law", "k") == 5.21
    assert math.isnan(paper_value("hstop", "A", 0.3))
    f = _fit("stress_ratio", dict(d0=140.0, d1=21.9), stderr_frac=0.01, contact_law="linear")
    rows = {r["parameter"]: r for r in compare_with_paper([f])}
    assert rows["d0"]["agrees"] is False  # 8 off, stderr 1.4, 5 % = 6.6
    assert rows["d1"]["agrees"] is True   # 0.4 off, 2 stderr = 0.44
    assert rows["d1"]["z"] == pytest.approx((21.9 - 21.5) / 0.219)
    # an unidentified parameter agrees with nothing, however close (its stderr measures nothing)
    g = f.replace(param_status={"d0": "identified", "d1": "unidentified"})
    rows = {r["parameter"]: r for r in compare_with_paper([g])}
    assert rows["d1"]["agrees"] is False and rows["d1"]["parameter_status"] == "unidentified"
