"""Continuum models against particle runs the closure library was not fitted on (slow).

Needs the soft-species campaign the checks were built on (``snakemake --cores 2 --configfile
config/continuum-soft.yaml``, ``results/continuum-soft``: the default campaign before it moved to
the paper's species; it has steady runs at theta 24-28, H 6-10 to restart from) and the comparison
runs of :mod:`granflow.continuum.experiments` under ``results/continuum`` (switch runs, the long
chute, the bidisperse runs simulated again with tracers); the runs missing are made here (soft
species t_c = 0.02, 10 x 5 boxes; about 15 min on 2 shared cores, the tracer runs a few more),
then every comparison is computed afresh from the run folders.  Tolerances of issue 17: steady
u_bar within 5 % and e-folding time within 25 % after a change of inclination (uniform-layer
ODE and depth-resolved column); peak/front
positions of the long chute within 15 % (Eq. 34, with the viscous stress, and its
local-equilibrium limits, the kinematic and diffusive waves); half-segregation time within 20 % (both flux models,
and with D measured over the run's own transient).  Cases that fail are expected failures with
the measured reason (``xfail(strict=True)``: they must keep failing, or the marker is removed).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from granflow.continuum import experiments as ex

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
CAMPAIGN = REPO / "results" / "continuum-soft"
OUT = REPO / "results" / "continuum"
RUNS = CAMPAIGN / "chute" / "linear" / "lambda~1"
#: (parent theta, H, child theta, t_end): up and down, thick (H = 10) and thin (H = 6, 8);
#: child inclinations are not campaign grid points (the library never saw these steady states)
SWITCHES = [(26.0, 10, 27.5, 400.0), (28.0, 10, 26.5, 400.0), (25.0, 6, 26.5, 300.0),
            (25.0, 6, 24.5, 300.0), (24.0, 8, 25.5, 300.0), (25.0, 6, 23.5, 100.0)]
LONG_TILES = [(25.0, 10)] * 2 + [(25.0, 6)] * 8


def _name(th1, H, th2):
    return f"H{H}_{th1:g}to{th2:g}"


@pytest.fixture(scope="module")
def comparison():
    if not (CAMPAIGN / "closures.json").exists():
        pytest.skip("needs the soft-species campaign: "
                    "snakemake --cores 2 --configfile config/continuum-soft.yaml")
    dirs = []
    for th1, H, th2, t_end in SWITCHES:
        d = OUT / "switch" / _name(th1, H, th2)
        if not (d / "summary.json").exists():
            ex.run_switch(RUNS / f"theta~{th1:g}" / f"H~{H}", th2, d, t_end=t_end)
        dirs.append(d)
    lc = OUT / "long_chute"
    if not (lc / "columns.nc").exists():
        first = ex._summary(RUNS / "theta~25" / "H~6")["params"]
        ex.run_long_chute([RUNS / f"theta~{t:g}" / f"H~{H}" / "final_state.npz"
                           for t, H in LONG_TILES],
                          CAMPAIGN / "bases" / "lambda~1" / "box~10x5" / "base.npy",
                          first["Lx"], first["Ly"], first, lc, t_end=24.0)
    # the bidisperse runs again from their start with tracers, to twice their half-time (the
    # diffusivity where segregation acts)
    for run in sorted(CAMPAIGN.glob("segregation/**/summary.json")):
        m = ex.segregation_measurement(run.parent)
        d = OUT / "segregation_tracers" / f"sigma~{m['sigma']:g}"
        if not (d / "tracers.npz").exists():
            th = m["t_half"] if math.isfinite(m["t_half"]) and m["t_half"] > 0 else 100.0
            ex.run_segregation_tracers(run.parent, d, t_end=min(m["t0"] + 2 * th + 5, 700.0))
    rows = ex.diffusivity_measurements(dirs)
    fit = ex.diffusivity_fit(rows)
    lib = OUT / "closures.nc"
    ex.library_with_diffusivity(CAMPAIGN, fit, lib)
    res = ex.compare_all(lib, CAMPAIGN, dirs, lc, OUT / "comparison.json", OUT / "figures",
                         segregation_tracers=OUT / "segregation_tracers")
    res["diffusivity_runs"] = rows
    return res


def _switch(res, th1, H, th2):
    name = _name(th1, H, th2)
    return next(s for s in res["switches"] if s.get("child", "").endswith(name))


KNOWN = json.loads((Path(__file__).with_name("continuum_known_failures.json")).read_text()) \
    if Path(__file__).with_name("continuum_known_failures.json").exists() else {}


def _maybe_xfail(key):
    why = KNOWN.get(key)
    return [pytest.mark.xfail(strict=True, reason=why)] if why else []


@pytest.mark.parametrize("th1, H, th2", [pytest.param(a, b, c, marks=_maybe_xfail(
    f"u:{_name(a, b, c)}")) for a, b, c, _ in SWITCHES])
def test_switch_steady_velocity_within_5_percent(comparison, th1, H, th2):
    s = _switch(comparison, th1, H, th2)
    assert s["child_state"] == "steady", f"particle run ended {s['child_state']}"
    assert abs(s["err_u_steady"]) <= ex.TOL_STEADY_U, s["err_u_steady"]


@pytest.mark.parametrize("th1, H, th2", [pytest.param(a, b, c, marks=_maybe_xfail(
    f"tau:{_name(a, b, c)}")) for a, b, c, _ in SWITCHES])
def test_switch_efolding_time_within_25_percent(comparison, th1, H, th2):
    s = _switch(comparison, th1, H, th2)
    assert math.isfinite(s.get("tau", math.nan)), s.get("fit_error")
    assert abs(s["err_tau"]) <= ex.TOL_TAU, s["err_tau"]


@pytest.mark.parametrize("th1, H, th2", [pytest.param(a, b, c, marks=_maybe_xfail(
    f"column_tau:{_name(a, b, c)}")) for a, b, c, _ in SWITCHES])
def test_switch_efolding_time_of_the_column_within_25_percent(comparison, th1, H, th2):
    """The same closures as a depth-resolved column (granflow.continuum.column): the profile
    adjusts by shear, which alone makes the layer relax 1.28x more slowly than the ODE (linear
    theory); nothing is fitted to the switch runs."""
    s = _switch(comparison, th1, H, th2)
    assert math.isfinite(s.get("tau", math.nan)), s.get("fit_error")
    assert s["column_tau"] > s["ode_tau"]
    assert abs(s["err_tau_column"]) <= ex.TOL_TAU, s["err_tau_column"]


@pytest.mark.parametrize("feature", [pytest.param(f, marks=_maybe_xfail(f"long:{f}"))
                                     for f in ("peak", "front")])
def test_long_chute_positions_within_15_percent(comparison, feature):
    lc = comparison["long_chute"]
    assert lc["worst_err_after_quarter"][feature] <= ex.TOL_POSITION


@pytest.mark.parametrize("feature", [pytest.param(f, marks=_maybe_xfail(f"long_viscous:{f}"))
                                     for f in ("peak", "front")])
def test_long_chute_with_viscous_stress_within_15_percent(comparison, feature):
    """The same comparison with the depth-averaged viscous stress of Gray & Edwards (2014),
    nu from the library's own flow rule (no parameter fitted to the long chute)."""
    lv = comparison["long_chute_viscous"]
    assert "error" not in lv, lv.get("error")
    assert lv["viscosity"] > 0
    assert lv["worst_err_after_quarter"][feature] <= ex.TOL_POSITION


@pytest.mark.parametrize("model", ["kinematic_wave", "diffusive_wave"])
@pytest.mark.parametrize("feature", ["peak", "front"])
def test_long_chute_in_local_equilibrium_within_15_percent(comparison, request, model, feature):
    """The local-equilibrium limits of Eq. (34) (granflow.continuum.kinematic: u follows h, from
    the particle run's h(x) at t = 0 alone): the kinematic wave u = u_s(h) of the library's
    steady flow rule, and the diffusive wave mu(h, F) = tan(theta) - K dh/dx."""
    key = f"long_{model}:{feature}"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    lk = comparison["long_chute_kinematic" if model == "kinematic_wave" else "long_chute_diffusive"]
    assert "error" not in lk, lk.get("error")
    assert lk["model"] == model
    assert lk["worst_err_after_quarter"][feature] <= ex.TOL_POSITION


@pytest.mark.parametrize("flux", ["symmetric", "asymmetric"])
@pytest.mark.parametrize("sigma", [0.5, 0.6, 0.7, 0.8, 0.9])
def test_segregation_half_time_within_20_percent(comparison, request, flux, sigma):
    why = KNOWN.get(f"seg:{flux}:{sigma:g}")
    if why:
        request.applymarker(pytest.mark.xfail(strict=True, reason=why))
    s = next(r for r in comparison["segregation"] if abs(r.get("sigma", -1) - sigma) < 1e-9)
    assert abs(s[flux]["err_t_half"]) <= ex.TOL_HALF_TIME, s[flux]["err_t_half"]


@pytest.mark.parametrize("sigma", [0.5, 0.6, 0.7, 0.8, 0.9])
def test_segregation_half_time_with_transient_D_within_20_percent(comparison, request, sigma):
    """T-eq. (27) with the library's Ps and D measured in the run itself over its transient:
    what is left of the half-time error once the diffusivity closure is taken out of it."""
    why = KNOWN.get(f"seg:transient_D:{sigma:g}")
    if why:
        request.applymarker(pytest.mark.xfail(strict=True, reason=why))
    s = next(r for r in comparison["segregation"] if abs(r.get("sigma", -1) - sigma) < 1e-9)
    assert abs(s["symmetric_D_transient"]["err_t_half"]) <= ex.TOL_HALF_TIME


@pytest.mark.parametrize("sigma", [0.5, 0.6, 0.7, 0.8, 0.9])
def test_diffusivity_closure_predicts_the_mixture_within_25_percent(comparison, sigma):
    """The diffusivity closure (fitted on monodisperse switch runs) at the length scale the
    comparison uses (ex.SEGREGATION_D_LENGTH, the small diameter) against D measured over each
    bidisperse run's segregation transient.  The volume-weighted mean diameter gave 1.5-1.8x the
    measured D at sigma 0.5-0.7 (2026-11-26), so this fails if the scaling is switched back."""
    s = next(r for r in comparison["segregation"] if abs(r.get("sigma", -1) - sigma) < 1e-9)
    assert s["d_length"] == ex.SEGREGATION_D_LENGTH == "small"
    assert s["D_transient_stderr"] < 0.1 * s["D_transient"]
    assert abs(s["D_closure_over_transient"] - 1.0) <= 0.25, s["D_closure_over_transient"]


def test_diffusivity_closure_is_stored_with_its_uncertainty(comparison):
    from granflow.closures import open_library

    lib = open_library(OUT / "closures.nc")
    assert "diffusivity_c_D" in lib
    rows = comparison["diffusivity_runs"]
    assert len(rows) >= 3
    D = lib.closures.diffusivity(rows[0]["u_bar"], rows[0]["h"], uncertainty=True,
                                 allow_unidentified=True)
    assert float(D["std"]) > 0
    # each run's D within 3 combined standard errors of the closure (held-out style check)
    for r in rows:
        pred = float(lib.closures.diffusivity(r["u_bar"], r["h"], allow_unidentified=True))
        assert abs(pred - r["D"]) <= 3 * math.hypot(r["D_stderr"], float(D["std"]))


def test_package_example_runs_on_the_comparison_library(comparison):
    """The example of the granflow.continuum docstring, as written, on results/continuum."""
    import os

    import numpy as np

    import granflow.continuum as C

    code = C.__doc__.split("Example: open a library and run each model ::")[1]
    code = "\n".join(line[4:] for line in code.splitlines())
    ns = {}
    cwd = os.getcwd()
    os.chdir(REPO)
    try:
        exec(code, ns)
    finally:
        os.chdir(cwd)
    assert float(abs(ns["res"].mass[-1] / ns["res"].mass[0] - 1)) < 1e-12
    assert float(abs(ns["res_v"].mass[-1] / ns["res_v"].mass[0] - 1)) < 1e-12
    assert ns["res_v"].attrs["viscosity"] > 0
    assert float(abs(ns["res_kw"].mass[-1] / ns["res_kw"].mass[0] - 1)) < 1e-12
    assert ns["res_kw"].attrs["continuum_model"] == "kinematic_wave"
    # the viscous stress damps the bump's velocity differences
    assert np.ptp(ns["res_v"].u_bar.values[-1]) < np.ptp(ns["res"].u_bar.values[-1])
    lib = ns["lib"]
    c_D = float(lib["diffusivity_c_D"].squeeze())
    assert ns["D"] == pytest.approx(c_D * 0.75 / 7.9, rel=1e-12)
    assert ns["Ps_status"] in ("ok", "reduced")
    assert np.isfinite(float(ns["seg"].t_half))
