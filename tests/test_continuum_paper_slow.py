"""Uniform-layer ODE against particle runs at the paper's species (slow).

The change-of-inclination check of issue 17 (part 1) as ``tests/test_continuum_slow.py`` makes
it, but restarted from the steady runs of the lambda = 1 reference
(``config/reference-lambda1.yaml``: the paper's species t_c = 0.005, 10 x 5 box, hstop and the
flow rule identified) instead of the soft-species campaign, whose hstop (and so mu(h, F)) is not
identified.  Needs that campaign's results (``snakemake --cores 2 --configfile
config/reference-lambda1.yaml``, about 1.5-2 h on 2 cores); the switch runs missing are made here
under ``results/continuum-paper`` (about 2-5 min each on one core).  The children's inclinations
lie between the reference's grid angles (its library never saw these steady states).  Tolerances
of issue 17: steady u_bar within 5 %, e-folding time within 25 %; cases that fail are strict
expected failures with the measured reason (``tests/continuum_known_failures.json``, keys
``paper_u:``, ``paper_tau:`` and ``paper_column_tau:``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from granflow.continuum import experiments as ex

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
CAMPAIGN = REPO / "results" / "reference-lambda1"
OUT = REPO / "results" / "continuum-paper"
RUNS = CAMPAIGN / "chute" / "linear" / "lambda~1"
#: (parent theta, H, child theta, t_end): up and down, thin (H = 10) and thick (H = 20), and one
#: near hstop (H = 10 at 23.5 deg: h/hstop 1.5 by Table 1, 1.2 by the reference's own curve;
#: its 23 deg run oscillated, its 22 deg run arrested)
SWITCHES = [(26.0, 10, 27.5, 400.0), (28.0, 10, 26.5, 400.0), (24.0, 20, 25.5, 400.0),
            (28.0, 20, 26.5, 400.0), (24.0, 10, 23.5, 300.0)]


#: the long chute (issue 17 part 2): two thick tiles (H = 20) on eight thin ones (H = 10), 26 deg,
#: the reference's own steady states on its own base, 100 long
LONG_TILES = [(26.0, 20)] * 2 + [(26.0, 10)] * 8


def _long_chute():
    """The long chute of LONG_TILES on the reference's base (run here when missing)."""
    lc = OUT / "long_chute"
    if not (lc / "columns.nc").exists():
        first = ex._summary(RUNS / "theta~26" / "H~10")["params"]
        ex.run_long_chute([RUNS / f"theta~{t:g}" / f"H~{H}" / "final_state.npz"
                           for t, H in LONG_TILES],
                          CAMPAIGN / "bases" / "lambda~1" / "box~10x5" / "base.npy",
                          first["Lx"], first["Ly"], first, lc, t_end=24.0)
    return lc


def _name(th1, H, th2):
    return f"H{H}_{th1:g}to{th2:g}"


KNOWN = json.loads((Path(__file__).with_name("continuum_known_failures.json")).read_text())


def _maybe_xfail(key):
    why = KNOWN.get(key)
    return [pytest.mark.xfail(strict=True, reason=why)] if why else []


@pytest.fixture(scope="module")
def comparison():
    if not (CAMPAIGN / "closures.nc").exists():
        pytest.skip("needs the lambda = 1 reference: "
                    "snakemake --cores 2 --configfile config/reference-lambda1.yaml")
    from granflow.closures import open_library

    lib = open_library(CAMPAIGN / "closures.nc")
    out = {}
    for th1, H, th2, t_end in SWITCHES:
        parent = RUNS / f"theta~{th1:g}" / f"H~{H}"
        child = OUT / "switch" / _name(th1, H, th2)
        if not (child / "summary.json").exists():
            ex.run_switch(parent, th2, child, t_end=t_end)
        out[_name(th1, H, th2)] = ex.compare_switch(lib, parent, child)
    lc = _long_chute()
    rho = ex._summary(RUNS / "theta~26" / "H~10")["depth_averages"]["rho_bar"]
    for key, visc in (("long_chute", None), ("long_chute_viscous", "gray_edwards")):
        out[key] = ex.compare_long_chute(lib, lc / "columns.nc", rho, 26.0, viscosity=visc)
    out["long_chute_kinematic"] = ex.compare_long_chute(lib, lc / "columns.nc", rho, 26.0,
                                                        model="kinematic_wave")
    return out


@pytest.mark.parametrize("th1, H, th2", [pytest.param(a, b, c, marks=_maybe_xfail(
    f"paper_u:{_name(a, b, c)}")) for a, b, c, _ in SWITCHES])
def test_switch_steady_velocity_within_5_percent(comparison, th1, H, th2):
    s = comparison[_name(th1, H, th2)]
    assert s["child_state"] == "steady", f"particle run ended {s['child_state']}"
    assert abs(s["err_u_steady"]) <= ex.TOL_STEADY_U, s["err_u_steady"]


@pytest.mark.parametrize("th1, H, th2", [pytest.param(a, b, c, marks=_maybe_xfail(
    f"paper_tau:{_name(a, b, c)}")) for a, b, c, _ in SWITCHES])
def test_switch_efolding_time_within_25_percent(comparison, th1, H, th2):
    s = comparison[_name(th1, H, th2)]
    assert math.isfinite(s.get("tau", math.nan)), s.get("fit_error")
    assert abs(s["err_tau"]) <= ex.TOL_TAU, s["err_tau"]


@pytest.mark.parametrize("th1, H, th2", [pytest.param(a, b, c, marks=_maybe_xfail(
    f"paper_column_tau:{_name(a, b, c)}")) for a, b, c, _ in SWITCHES])
def test_switch_efolding_time_of_the_column_within_25_percent(comparison, th1, H, th2):
    """The same closures as a depth-resolved column (granflow.continuum.column: the profile
    adjusts by shear); nothing is fitted to the switch runs.  At the paper's species it is
    within 25 % of every steady switch (2026-12-01: -24.0, -12.6, -6.2, -11.0 %) where the
    uniform-layer ODE misses three of four by 28-39 %."""
    s = comparison[_name(th1, H, th2)]
    assert math.isfinite(s.get("tau", math.nan)), s.get("fit_error")
    assert s["column_tau"] > s["ode_tau"]
    assert abs(s["err_tau_column"]) <= ex.TOL_TAU, s["err_tau_column"]


@pytest.mark.parametrize("model", ["long_chute", "long_chute_viscous", "long_chute_kinematic"])
@pytest.mark.parametrize("feature", ["peak", "front"])
def test_long_chute_positions_within_15_percent(comparison, request, model, feature):
    """Eq. (34) as the paper writes it, with the Gray-Edwards viscous stress (nu from the
    library's flow rule), from the particle run's own h(x), u_bar(x) at t = 0, and its
    kinematic-wave limit (u = u_s(h) of the library's steady flow rule, from h(x) alone; not
    yet run at the paper's species when it was added, 2026-12-02: on the soft campaign's chute
    its peak is within 15 % and its front -15 ... -23 %)."""
    key = "paper_" + {"long_chute": "long", "long_chute_viscous": "long_viscous",
                      "long_chute_kinematic": "long_kinematic_wave"}[model] + f":{feature}"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    lc = comparison[model]
    assert lc["closure_status"].get("friction") == "ok"
    assert lc["worst_err_after_quarter"][feature] <= ex.TOL_POSITION


def test_the_reference_library_identifies_the_friction_law(comparison):
    """What makes these switches a test of the closures rather than of their uncertainty: the
    reference identifies hstop (Eq. 45) and fits the flow rule, so mu(h, F) is not
    'unidentified' as in the soft-species campaign."""
    s = next(iter(comparison.values()))
    assert s["closure_status"].get("friction") not in (None, "unidentified", "failed"), \
        s["closure_status"]


# ----------------------------------------------------------------------------- part 3
#: the segregation reference's 1/sigma = 2 run (seed 1) simulated in its campaign folder with
#: tracer heights: ``config/reference-segregation.yaml``'s set-up (83.3 x 5, depth 24, 25 deg,
#: the paper's species), deep enough for the steady interface (~3 d wide) to be resolved, where
#: the shallow default's (depth 8: 0.5-0.85 d) is not
SEG_CAMPAIGN = REPO / "results" / "reference-segregation"
SEG_REL = "segregation/linear/lambda~1/theta~25/H~24.009603841536613/sigma~0.5"
SEG_RUN = SEG_CAMPAIGN / SEG_REL
SEG_MAKE = (f"granflow campaign run-params ... --out {SEG_RUN}/params.yaml (snakemake -n -p "
            "--configfile config/reference-segregation.yaml prints it), then .venv/bin/python -m "
            f"granflow.continuum.experiments segregation-run {SEG_RUN} --base "
            f"{SEG_CAMPAIGN}/bases/lambda~1/box~83.3x5/base.npy --rel {SEG_REL}")
#: Ps laws the symmetric model is also run with: T-eq. 29 with the paper's Pmax, k at 1/sigma = 2,
#: and the reference's recorded plateau (granflow.reference.SEGREGATION_PAPER_SETUP["fit"])
SEG_LAWS = {"paper T-eq. 29": 7.35 * -math.expm1(-5.21), "reference plateau": 6.849}
#: the final profile: rms of phi(z) model - particles at the run's end, in volume fraction
TOL_PHI_RMS = 0.05


@pytest.fixture(scope="module")
def segregation_comparison():
    if not ((SEG_RUN / "tracers.npz").exists() and (SEG_RUN / "row.json").exists()):
        pytest.skip(f"needs the segregation reference's 1/sigma = 2 run with tracers: {SEG_MAKE}")
    from granflow.reference import SEGREGATION_PAPER_SETUP

    # a run cut short by its t_end (plateau from the relaxation fit) takes the recorded steady
    # Ps of the same configuration and seed; a run shown steady, its own
    steady = ex._summary(SEG_RUN)["segregation"]["steady"]
    return ex.compare_segregation_reference(
        SEG_RUN, Ps_laws=SEG_LAWS, Ps=None if steady else SEGREGATION_PAPER_SETUP["Ps"][1][0])


@pytest.mark.parametrize("model", ["symmetric", "asymmetric", "symmetric_D_transient",
                                   "law:paper T-eq. 29", "law:reference plateau"])
def test_paper_segregation_half_time_within_20_percent(segregation_comparison, request, model):
    """T-eq. (27) from the run's start of shear (t0, s0) with the run's steady Ps (what the
    library's per-size-ratio cell holds) and D measured in its steady window (or over its
    transient, or with a law's Ps): the time to half the final segregation within 20 %."""
    key = f"paper_seg:{model}"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    s = segregation_comparison
    assert s["segregation_steady"] or s["fraction_reached"] > 0.75, \
        "the run stopped before three quarters of its segregation"
    assert abs(s[model]["err_t_half"]) <= ex.TOL_HALF_TIME, s[model]["err_t_half"]


@pytest.mark.parametrize("flux", ["symmetric", "asymmetric"])
def test_paper_segregation_final_profile(segregation_comparison, request, flux):
    key = f"paper_seg_phi:{flux}"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    assert segregation_comparison[flux]["phi_rms_vs_particles"] <= TOL_PHI_RMS


def test_paper_segregation_diffusivities_are_measured(segregation_comparison):
    """Both diffusivities come with a stderr below 10 % of themselves (tracer batch means), and
    the run reproduces the recorded Ps of this seed (granflow.reference.SEGREGATION_PAPER_SETUP:
    6.821 +- 0.032; same configuration and seed)."""
    from granflow.reference import SEGREGATION_PAPER_SETUP

    s = segregation_comparison
    pairs = [(s["D_transient"], s["D_transient_stderr"])]
    if s["steady"]:
        pairs.append((s["steady"]["D"], s["steady"]["D_stderr"]))
        Ps, Ps_se = SEGREGATION_PAPER_SETUP["Ps"][1]
        assert s["Ps"] == pytest.approx(Ps, abs=2 * Ps_se)
    else:  # cut short: the relaxation fit's tau agrees with its own crossing time
        assert s["t_half"] == pytest.approx(s["tau_ln2"], rel=0.2)
    for D, se in pairs:
        assert 0 < se < 0.1 * D


#: T-eq. (27)'s rates measured on the transient against those the steady state gives (the
#: steady profile's Ps, the self-diffusivity, S = Ps D / h), and the transient's two halves
#: against each other: agreement within this (relative)
TOL_RATES = 0.25


def test_paper_segregation_transient_fit_describes_the_transient(segregation_comparison):
    """T-eq. (27) with S and D_r fitted to the run's own phi(z, t) from t0 explains most of it
    (r2 >= 0.9, both rates identified with stderrs below 5 %): the rates are measured, whatever
    they say about the steady state."""
    f = segregation_comparison["transient_rates"]["fit"]
    assert f["identified"], f["unidentified"]
    assert f["r2"] >= 0.9
    assert f["S_stderr"] < 0.05 * f["S"] and f["D_r_stderr"] < 0.05 * f["D_r"]


def test_paper_segregation_velocity_scales_with_inverse_pressure(segregation_comparison):
    """The local segregation velocity S(z) measured on the transient follows 1 / p: S p is
    constant within a coefficient of variation of 0.15 over the levels above the basal layers
    (z >= 5), the best of the three scalings tried (1 / p, shear rate, shear rate / p).
    Measured 2026-12-02: S p 0.112-0.132 at z = 6 ... 18 (CV 0.06), S / gamma_dot 0.023-0.31
    (CV 0.88), S p / gamma_dot CV 0.35."""
    ps = segregation_comparison["transient_rates"]["pressure_scaling"]
    assert ps["cv"]["S_p"] <= 0.15, ps["cv"]
    assert ps["best"] == "S_p"


@pytest.mark.parametrize("variant", ["fitted_constant_rates", "measured_S_and_D_profiles",
                                     "steady_rates_from_measured_start"])
def test_paper_segregation_half_time_with_transient_rates(segregation_comparison, request,
                                                          variant):
    """The half-time within 20 % with what the transient measures: T-eq. (27) with the
    constant rates fitted to phi(z, t); with the local S(z) and the banded D(z) measured on
    it (depth-dependent rates); and with the steady (Ps, D) but started from the particles'
    own profile at t0 instead of a mixed start aligned on s0 (is the protocol the gap?)."""
    key = f"paper_seg_transient:{variant}"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    r = segregation_comparison["transient_rates"]
    err = {"fitted_constant_rates": r["model"]["err_t_half"],
           "measured_S_and_D_profiles": r["measured_profiles"]["err_t_half"],
           "steady_rates_from_measured_start":
               r["steady_model_from_measured_start"]["err_t_half"]}[variant]
    assert abs(err) <= ex.TOL_HALF_TIME, err


@pytest.mark.parametrize("rate", ["S", "D_r", "Ps"])
def test_paper_segregation_transient_rates_are_the_steady_ones(segregation_comparison, request,
                                                               rate):
    """The rates the transient shows equal those the model takes from the steady state: S
    against Ps D / h, D_r against the self-diffusivity over the transient, Ps = S h / D_r
    against the steady profile's (within 25 %).  If T-eq. (27) with constant rates held, all
    three would."""
    key = f"paper_seg_rates:{rate}"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    r = segregation_comparison["transient_rates"]
    ratio = {"S": r["S_over_model_S"], "D_r": r["D_r_over_D_self"],
             "Ps": r["Ps_transient_over_steady"]}[rate]
    assert abs(ratio - 1.0) <= TOL_RATES, ratio


@pytest.mark.parametrize("rate", ["S", "D_r"])
def test_paper_segregation_transient_rates_are_constant(segregation_comparison, request, rate):
    """The rates fitted over the transient's first half (t0 to the particle half-time) and
    over its second half agree within 25 %."""
    key = f"paper_seg_rates_halves:{rate}"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    r = segregation_comparison["transient_rates"]
    a, b = r["fit_first"], r["fit_second"]
    assert b is not None and a["identified"] and b["identified"]
    assert abs(b[rate] / a[rate] - 1.0) <= TOL_RATES, (a[rate], b[rate])


def _pressure_scaled(comparison, request=None, key=None) -> dict:
    """The comparison's 1 / p results (skip where the run has no steady window); ``key``: the
    KNOWN entry that marks the calling check as a strict xfail."""
    if key is not None and key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    q = comparison.get("pressure_scaled")
    if q is None:
        pytest.skip("the run has no steady window (pressure_scaled needs its steady profile)")
    return q


def test_paper_segregation_steady_profile_follows_inverse_pressure(segregation_comparison):
    """The run's steady profile above the basal layers (z >= 4) is fitted better by the exact
    steady state of T-eq. (27) with S ~ 1 / p than by T-eq. (28)'s constant rates: its rms at
    most 0.6x the constant-rate fit's.  Measured 2026-12-04 (run steady at t = 1221): 0.033
    against 0.070 (Ps_mid 5.88; constant 6.65) -- the top is pure large above z ~ 18, which a
    constant S cannot make while the lower half stays broad."""
    q = _pressure_scaled(segregation_comparison)
    assert q["steady"]["rms"] <= 0.6 * q["steady"]["rms_constant"], q["steady"]


@pytest.mark.parametrize("rate", ["D_r", "Ps"])
def test_paper_segregation_pressure_scaled_rates(segregation_comparison, request, rate):
    """With S ~ 1 / p, T-eq. (27) fitted to the bulk transient (z >= 4) gives a remixing
    diffusivity D_r within 25 % of the self-diffusivity and Ps_mid within 25 % of the steady
    profile's (with constant rates they were 0.11x and 12.9x)."""
    q = _pressure_scaled(segregation_comparison, request, f"paper_seg_pressure_rates:{rate}")
    tr = q["transient"]
    assert tr["identified"], tr["unidentified"]
    ratio = {"D_r": tr["D_r_over_D_self"], "Ps": tr["Ps_over_steady"]}[rate]
    assert abs(ratio - 1.0) <= TOL_RATES, ratio


@pytest.mark.parametrize("variant", ["prediction", "prediction_transient_rates",
                                     "asymmetric_consistent_D_self"])
def test_paper_segregation_pressure_scaled_half_time(segregation_comparison, request, variant):
    """The bulk's half-time (small particles' centre of mass above z = 4, from the particles'
    own profile at t0) within 20 % with the 1 / p model: its Ps_mid from the steady profile and
    D the self-diffusivity (closures of the steady state), or the rates fitted to the
    transient; or with the asymmetric flux at the kappa where transient and steady profile
    agree on Ps_mid, with D the self-diffusivity."""
    q = _pressure_scaled(segregation_comparison, request, f"paper_seg_pressure:{variant}")
    if variant == "asymmetric_consistent_D_self":
        assert q["asymmetric"]["at_kappa"] is not None, q["asymmetric"]["scan"]
        r = q["asymmetric"]["at_kappa"]["prediction"]
    else:
        r = q[variant]
    assert abs(r["err_t_half"]) <= ex.TOL_HALF_TIME, r


def test_paper_segregation_one_model_has_the_transient_and_the_steady_state(
        segregation_comparison):
    """S ~ 1 / p with seed 001's asymmetric flux: there is a kappa in (0, 1) at which the rates
    fitted to the bulk transient have the steady profile's Ps_mid, and that model (Ps_mid from
    the steady profile, D_r from the transient) fits the steady bulk profile with rms <= 0.035,
    the transient with r2 >= 0.9, and gives the bulk's half-time within 20 %.  A description
    of this run, not a prediction: its D_r is fitted.  Measured 2026-12-04: kappa 0.638,
    Ps_mid 6.40 (steady rms 0.029), D_r 0.0390 (1.61 x D_self), r2 0.957, half-time 295
    against 249 (+18.6 %).  Seed 2 (not this fixture's run) gives kappa 0.661, D_r 1.56x and
    +27.5 %: the 20 % holds for seed 1 only."""
    ak = _pressure_scaled(segregation_comparison)["asymmetric"]["at_kappa"]
    assert ak is not None and 0.0 < ak["kappa"] < 1.0, q["asymmetric"]["scan"]
    assert ak["rms_steady"] <= 0.035 and ak["transient"]["r2"] >= 0.9, ak
    assert abs(ak["prediction_fitted_D_r"]["err_t_half"]) <= ex.TOL_HALF_TIME, ak


def test_paper_segregation_consistent_remixing_is_the_self_diffusivity(segregation_comparison,
                                                                     request):
    """In that one model, the remixing diffusivity D_r within 25 % of the tracers'
    self-diffusivity (the closure the prediction uses)."""
    q = _pressure_scaled(segregation_comparison, request,
                         "paper_seg_pressure_rates:D_r_consistent")
    ak = q["asymmetric"]["at_kappa"]
    assert ak is not None
    assert abs(ak["transient"]["D_r_over_D_self"] - 1.0) <= TOL_RATES, ak["transient"]


@pytest.fixture(scope="module")
def paper_long_chute():
    """The long chute at the paper's species from the reference's two 26 deg steady runs alone
    (made here when missing: ``snakemake`` on their two summary.json, ~10 min on one core, and
    the tiled chute, ~1.5 min); no library needed."""
    import subprocess
    import sys

    tiles = sorted({(t, H) for t, H in LONG_TILES})
    need = [RUNS / f"theta~{t:g}" / f"H~{H}" / "summary.json" for t, H in tiles]
    if not all(p.exists() for p in need):
        snakemake = Path(sys.executable).parent / "snakemake"
        subprocess.run([str(snakemake), *[str(p.relative_to(REPO)) for p in need],
                        "--configfile", "config/reference-lambda1.yaml", "--cores", "2"],
                       cwd=REPO, check=True, capture_output=True, timeout=7200)
    return _long_chute()


@pytest.mark.parametrize("feature", ["peak", "front"])
def test_kinematic_wave_with_the_paper_closures_within_15_percent(paper_long_chute, request,
                                                                  feature, tmp_path):
    """The README's command as written: the kinematic wave with the paper's own closures
    (Table 1 lambda = 1, Eq. 53; FlowClosures.paper) against the paper-species long chute.
    Measured 2026-12-02: front -8.8 ... +10.2 % after t = 6 (Eq. 34 with the same closures
    -3 ... +24 %), peak +5 ... +26 %."""
    import subprocess
    import sys

    key = f"paper_closures_long_kinematic_wave:{feature}"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
    out = tmp_path / "kw.json"
    cmd = [sys.executable, "-m", "granflow.continuum.experiments", "compare-long-chute",
           str(paper_long_chute.relative_to(REPO)), "--closures", "paper", "--model",
           "kinematic_wave", "--out", str(out), "--figure", str(tmp_path / "kw.png")]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads(out.read_text())
    assert (tmp_path / "kw.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert res["model"] == "kinematic_wave"
    assert res["closure_status"] == {"friction": "paper", "alpha": "paper",
                                     "stress_ratio": "paper"}
    assert res["worst_err_after_quarter"][feature] <= ex.TOL_POSITION
