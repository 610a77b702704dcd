"""The campaign summaries under benchmarks/ (paper_table.py, campaign_cost.py) on inputs with
known answers."""

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

REPO = Path(__file__).resolve().parents[1]


def _load(name):
    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_paper_table_applies_the_two_stderr_or_five_percent_rule():
    pt = _load("paper_table")
    rows = [
        # identified, 1.5 stderr off: agrees
        dict(kind="hstop", **{"lambda": 1.0}, parameter="delta1", value=17.708 + 0.15, stderr=0.1,
             parameter_status="identified", message=""),
        # identified, 3 stderr but within 5 %: agrees (the looser rule)
        dict(kind="hstop", **{"lambda": 1.0}, parameter="delta2", value=32.78 * 1.04, stderr=0.3,
             parameter_status="identified", message=""),
        # on the value, but not identified: never counts
        dict(kind="hstop", **{"lambda": 1.0}, parameter="A", value=3.355, stderr=9.0,
             parameter_status="unidentified", message=""),
        # identified, 10 % and 5 stderr off: disagrees
        dict(kind="flow_rule", **{"lambda": 1.0}, parameter="beta", value=0.196 * 1.1,
             stderr=0.0039, parameter_status="identified", message=""),
        # the reduced linear density against Eq. 52 at its reference angle
        dict(kind="density", **{"lambda": math.nan}, parameter="nu_ref", value=0.5492, stderr=0.001,
             parameter_status="identified",
             message="linear form (rho_c/rho_p = nu_ref + dnu_dtheta (theta - 26.4)) fitted"),
        # no paper value (Eq. 38): left out
        dict(kind="hstop_eq38", **{"lambda": 1.0}, parameter="delta1", value=20.0, stderr=1.0,
             parameter_status="identified", message=""),
    ]
    out = {(r["closure"], r["parameter"]): r for r in pt.paper_rows(pd.DataFrame(rows))}
    assert set(out) == {("hstop", "delta1"), ("hstop", "delta2"), ("hstop", "A"),
                        ("flow_rule", "beta"), ("density", "nu_ref")}
    assert out[("hstop", "delta1")]["agrees"] and out[("hstop", "delta1")]["z"] == pytest.approx(1.5)
    assert out[("hstop", "delta2")]["agrees"]
    assert not out[("hstop", "A")]["agrees"]
    assert not out[("flow_rule", "beta")]["agrees"]
    # Eq. 52: 0.5985 - exp((26.4 - 40.85) / 4.8)
    assert out[("density", "nu_ref")]["paper"] == pytest.approx(
        0.5985 - math.exp((26.4 - 40.85) / 4.8), rel=1e-12)


def test_paper_table_leaves_out_closures_the_campaign_has_no_runs_for():
    """The lambda = 1/2 reference fits no lambda = 1 flow rule (only lambda = 1 brackets): those
    rows (not_fitted, 0 runs) are outside its scope and not counted; a fit that failed on data
    (not_fitted with runs) stays in and does not agree."""
    pt = _load("paper_table")
    common = dict(message="", stderr=math.nan, fit_error=math.nan, status="failed")
    table = pd.DataFrame([
        dict(kind="flow_rule", **{"lambda": 0.5}, parameter="beta", value=0.30, stderr=0.01,
             parameter_status="identified", n_points=6, message="", fit_error=0.2, status="ok"),
        dict(kind="flow_rule", **{"lambda": 1.0}, parameter="beta", value=math.nan,
             parameter_status="not_fitted", n_points=0, **common),
        dict(kind="alpha", **{"lambda": 1.0}, parameter="d_lambda", value=math.nan,
             parameter_status="not_fitted", n_points=0, **common),
        dict(kind="hstop", **{"lambda": 0.5}, parameter="delta1", value=math.nan,
             parameter_status="not_fitted", n_points=4, **common),
    ])
    rows = {(r["closure"], r["parameter"], r["paper"]) for r in pt.paper_rows(table)}
    assert rows == {("flow_rule", "beta", 0.300), ("hstop", "delta1", 17.913)}
    assert pt.not_fitted(table) == [("alpha", 1.0), ("flow_rule", 1.0)]
    errs = pt.fit_error_rows(table)
    assert [(r["closure"], r["lambda"]) for r in errs] == [("flow_rule", 0.5)]


def test_paper_table_sets_fit_errors_against_table_1_and_2():
    """err(F) of Table 1 and alpha's error of Table 2 per lambda; closures without a paper
    error (density) and lambdas the paper does not list are left out."""
    pt = _load("paper_table")
    common = dict(parameter_status="identified", message="", status="ok")
    table = pd.DataFrame([
        dict(kind="flow_rule", **{"lambda": 1.0}, parameter="beta", value=0.2, stderr=0.01,
             fit_error=0.242, n_points=20, **common),
        dict(kind="flow_rule", **{"lambda": 1.0}, parameter="gamma", value=0.0, stderr=0.05,
             fit_error=0.242, n_points=20, **common),
        dict(kind="alpha", **{"lambda": 0.5}, parameter="alpha_constant", value=1.14,
             stderr=0.01, fit_error=0.01919, n_points=9, **common),
        dict(kind="alpha", **{"lambda": 0.75}, parameter="alpha_constant", value=1.2,
             stderr=0.01, fit_error=0.03, n_points=9, **common),
        dict(kind="density", **{"lambda": 1.0}, parameter="c0", value=0.6, stderr=0.01,
             fit_error=0.002, n_points=20, **common),
    ])
    rows = {(r["closure"], r["lambda"]): r for r in pt.fit_error_rows(table)}
    assert set(rows) == {("flow_rule", 1.0), ("alpha", 0.5)}
    assert rows[("flow_rule", 1.0)]["paper"] == 0.121
    assert rows[("flow_rule", 1.0)]["ratio"] == pytest.approx(2.0)
    assert rows[("alpha", 0.5)]["ratio"] == pytest.approx(1.0)


def test_paper_law_on_the_runs_is_exact_on_runs_made_from_it():
    """Runs whose F is Eq. (47) with Table 1 (lambda = 1/2 beta, gamma; lambda = 1 hstop) and
    whose alpha is Table 2's constant give error 0 against the paper's law; F 10 % above it gives
    a mean deviation of +10 % and the Eq. (49) error of the 10 % offsets."""
    from granflow.fitting.flow_rule import froude_eq47
    from granflow.reference import paper_law_errors
    theta = np.array([26.0, 27.0, 28.0, 26.0])
    h = np.array([19.4, 19.8, 20.7, 28.8])
    F = froude_eq47(h, theta, 0.300, -0.236, 17.708, 32.780, 3.355)
    runs = pd.DataFrame({"run": [f"r{i}" for i in range(4)], "theta": theta, "h": h,
                         "F": F, "alpha": 1.142})
    fits = [{"kind": "flow_rule", "coords": {"lam": 0.5}, "runs_used": list(runs.run)},
            {"kind": "alpha", "coords": {"lam": 0.5}, "runs_used": list(runs.run)},
            {"kind": "density", "coords": {"lam": 0.5}, "runs_used": list(runs.run)}]
    rows = {r["closure"]: r for r in paper_law_errors(fits, runs)}
    assert set(rows) == {"flow_rule", "alpha"}
    assert rows["flow_rule"]["error"] == pytest.approx(0.0, abs=1e-12)
    assert rows["alpha"]["error"] == pytest.approx(0.0, abs=1e-12)
    assert rows["flow_rule"]["paper"] == 0.229
    rows = {r["closure"]: r for r in paper_law_errors(fits, runs.assign(F=1.1 * F))}
    assert rows["flow_rule"]["mean"] == pytest.approx(0.10)
    assert rows["flow_rule"]["error"] == pytest.approx(
        math.sqrt(np.sum((0.1 * F) ** 2) / 3))


def test_paper_table_prints_the_curve_test_beside_the_parameters(tmp_path, capsys,
                                                                 monkeypatch):
    """paper_table.py on a results folder (closures.csv, fits.json) whose hstop brackets follow
    Table 1's lambda = 1 curve shifted by +0.8 deg: the parameter table is printed, and the
    curve table says the curve lies off Table 1's by about +0.8 deg, within 5 % only."""
    from granflow.campaign.fits import write_fits
    from granflow.fitting.hstop import fit_hstop, theta_stop_eq45

    rng = np.random.default_rng(5)
    rows = []
    for k in range(3):
        for H in (1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0):
            arrest = float(theta_stop_eq45(H, 17.708, 32.780, 3.355)) + 0.8 + rng.normal(0, 0.2)
            rows += [dict(theta=arrest - 0.125, H=H, state="arrested", replicate=k),
                     dict(theta=arrest + 0.125, H=H, state="steady", replicate=k)]
    fit = fit_hstop(runs=pd.DataFrame(rows), lam=1.0, contact_law="linear", n_bootstrap=100)
    write_fits([fit], tmp_path / "fits.json", tmp_path / "closures.csv")
    pt = _load("paper_table")
    monkeypatch.setattr("sys.argv", ["paper_table.py", str(tmp_path)])
    pt.main()
    out = capsys.readouterr().out
    assert "| delta1 |" in out and "paper parameters agree" in out
    line = next(x for x in out.splitlines() if x.startswith("| hstop | 1 | theta_stop(H)"))
    diff = float(line.split("|")[5].split("+-")[0])
    assert abs(diff - 0.8) < 0.15 and "within 5 % only" in line, line


def test_campaign_cost_sums_the_runs_last_log_lines(tmp_path):
    cc = _load("campaign_cost")
    lines = {"chute/linear/lambda~1/theta~24/H~10": "at t = 221 (500 flow particles, 87.3 s wall)",
             "chute/linear/lambda~1/theta~26/H~10": "at t = 161 (500 flow particles, 58.1 s wall)",
             "bracket/linear/lambda~1/theta~28.1/H~2": "at t = 131 (100 flow particles, 16.8 s wall)",
             "chute/linear/lambda~1/theta~28/H~10": None}  # still running: no final line
    for d, last in lines.items():
        p = tmp_path / d
        p.mkdir(parents=True)
        text = "2026-11-23 granflow.engine.run INFO: t = 10 / 400\n"
        (p / "simulate.log").write_text(text + (f"{d}: steady (...) {last}\n" if last else ""))
    rows = cc.run_costs(tmp_path)
    assert len(rows) == 3
    chute = [r for r in rows if r[0] == "chute"]
    assert sum(r[4] for r in chute) == pytest.approx(87.3 + 58.1)
    assert sum(r[2] for r in chute) == pytest.approx(221 + 161)
    assert {r[1] for r in rows} == {"10", "2"} and all(r[3] in (500, 100) for r in rows)


def test_campaign_cost_takes_cpu_time_of_all_segments_where_the_log_has_it(tmp_path):
    """A log with the whole run's cost counts its CPU seconds (not the segment's wall time,
    which other jobs on the same cores inflate); an old log falls back to wall x threads."""
    cc = _load("campaign_cost")
    new = tmp_path / "chute/linear/lambda~1/theta~24/H~30"
    old = tmp_path / "chute/linear/lambda~1/theta~25/H~30"
    for p in (new, old):
        p.mkdir(parents=True)
    (new / "simulate.log").write_text(
        f"{new}: steady (...) at t = 900 (1500 flow particles, 1200.0 s wall; whole run "
        "1500.5 s cpu, 2000.0 s wall, 2 segments)\n")
    (old / "simulate.log").write_text(
        f"{old}: steady (...) at t = 800 (1500 flow particles, 700.0 s wall)\n")
    rows = {r[2]: r for r in cc.run_costs(tmp_path)}
    assert rows[900.0][5] == pytest.approx(1500.5) and rows[900.0][4] == pytest.approx(2000.0)
    assert rows[900.0][7] is True and rows[900.0][8] == 2
    assert rows[800.0][5] == pytest.approx(700.0) and rows[800.0][7] is False


def test_campaign_cost_counts_spare_core_threads(tmp_path):
    """A run that took a spare core (granflow.engine.threads) costs its thread seconds: 30 s
    on one thread and 50 s on two of its 90 s wall are 90 + 50 = 140 thread seconds."""
    cc = _load("campaign_cost")
    p = tmp_path / "bracket/linear/lambda~1/theta~24.7/H~5"
    p.mkdir(parents=True)
    (p / "simulate.log").write_text(
        "2026-11-25 granflow.simulate INFO: spare cores: {'max_threads': 2, 'enabled': True, "
        "'wall_s_at_threads': {'1': 30.0, '2': 50.0}}\n"
        f"{p}: arrested (...) at t = 300 (250 flow particles, 90.0 s wall)\n")
    (row,) = cc.run_costs(tmp_path)
    assert row[4] == pytest.approx(90.0) and row[5] == pytest.approx(140.0)
    assert row[6] == pytest.approx(50.0)


def test_hstop_brackets_fits_replicate_brackets_and_lets_a_rerun_override(tmp_path):
    """Synthetic bracket runs around Table 1's hstop(theta) (lambda = 1), three insertion seeds
    at each of seven heights, arrests scattered by 0.2 deg: 21 brackets, a fit that agrees with
    Table 1 by paper_table's rule; a second results folder's run replaces the first's."""
    import json

    import numpy as np

    from granflow.fitting.hstop import theta_stop_eq45

    hb = _load("hstop_brackets")
    rng = np.random.default_rng(3)
    root, rerun = tmp_path / "a", tmp_path / "b"

    def write(base, theta, H, k, state, lam="1"):
        d = base / "bracket" / "linear" / f"lambda~{lam}" / f"theta~{theta:.2f}" / f"H~{H:g}"
        d = d / f"seed~{k}" if k else d
        d.mkdir(parents=True, exist_ok=True)
        (d / "summary.json").write_text(json.dumps({"flow_state": state}))

    heights = (1.5, 2.0, 3.0, 4.0, 6.0, 12.0, 24.0)
    for H in heights:
        for k in range(3):
            arrest = float(theta_stop_eq45(H, 17.708, 32.780, 3.355)) + rng.normal(0.0, 0.2)
            write(root, arrest - 0.1, H, k, "arrested")
            write(root, arrest + 0.15, H, k, "oscillating" if H == 24.0 and k == 0 else "steady")
    runs = hb.bracket_runs(root)
    assert len(runs) == 2 * 3 * len(heights)
    iv, fit, rows = hb.hstop_table(runs)
    assert len(iv) == 3 * len(heights) and not iv["inverted"].any()
    assert fit.status == "ok"
    assert [r["parameter"] for r in rows] == ["delta1", "delta2", "A"]
    assert all(r["agrees"] for r in rows), rows
    # a rerun that finds the H = 24, seed 0 "oscillating" run arrested moves that bracket up
    flowing = runs[(runs.H == 24.0) & (runs.replicate == 0) & (runs.state == "oscillating")]
    write(rerun, float(flowing.theta.iloc[0]), 24.0, 0, "arrested")
    iv2 = hb.hstop_table(hb.bracket_runs(root, rerun))[0]
    row = iv2[(iv2.H == 24.0) & (iv2.replicate == 0)].iloc[0]
    assert row["theta_arrested_max"] == pytest.approx(float(flowing.theta.iloc[0]))
    assert math.isinf(row["theta_flowing_min"])
    # lambda = 1/2 chains beside them (as in the lambda = 1/2 reference): a curve of their own,
    # against Table 1's lambda = 1/2 row; the lambda = 1 fit is unchanged by them
    for H in heights:
        arrest = float(theta_stop_eq45(H, 17.913, 21.357, 11.959))
        write(root, arrest - 0.05, H, 0, "arrested", lam="0.5")
        write(root, arrest + 0.05, H, 0, "steady", lam="0.5")
    tables = hb.hstop_tables(hb.bracket_runs(root))
    assert set(tables) == {("linear", 1.0), ("linear", 0.5)}
    assert len(tables[("linear", 0.5)][0]) == len(heights)
    assert tables[("linear", 1.0)][1].params == pytest.approx(fit.params)
    iv_half = hb.with_paper_curve(tables[("linear", 0.5)][0], 0.5)
    # each bracket straddles Table 1's angle by construction: offsets of 0 (to rounding)
    assert np.allclose(iv_half["paper_offset"], 0.0, atol=0.006)
    half = {r["parameter"]: r for r in tables[("linear", 0.5)][2]}
    assert half["delta1"]["paper"] == 17.913 and half["delta1"]["agrees"], half
    # --realisations: the second folder is a campaign over another base, its run at the same
    # path is a datum of its own (replicate 1000 + k), not a replacement
    both = hb.bracket_runs(root, rerun, realisations=True)
    assert len(both) == len(hb.bracket_runs(root)) + 1
    assert set(both.realisation) == {0, 1} and set(both[both.realisation == 1].replicate) == {1000}
    iv3 = hb.hstop_tables(both)[("linear", 1.0)][0]
    assert len(iv3) == len(iv) + 1  # the other base's one-sided bracket at H = 24
    own = iv3[(iv3.H == 24.0) & (iv3.replicate == 0)].iloc[0]
    assert own["theta_flowing_min"] == pytest.approx(float(flowing.theta.iloc[0]))
    other = iv3[iv3.replicate == 1000].iloc[0]
    assert other["theta_arrested_max"] == pytest.approx(float(flowing.theta.iloc[0]))
    # mean offsets from Table 1 per folder: brackets built 0.1 below / 0.15 above a scattered
    # arrest of Table 1's curve: mean midpoint offset = 0.025 + mean scatter; folder 1 has
    # only a one-sided bracket, so no offset of its own
    off = hb.mean_offsets(hb.with_paper_curve(iv3, 1.0))
    two = hb.with_paper_curve(iv, 1.0)["paper_offset"].dropna()
    assert off["all"] == pytest.approx(float(two.mean()), abs=1e-12) and set(off) == {"all", 0}
    assert abs(off[0] - 0.025) < 3 * 0.2 / np.sqrt(len(two))


def test_hstop_brackets_labels_each_bracket_with_its_base_and_models_a_common_offset(tmp_path):
    """Brackets on two bases (the fixed particles of each run's final_state.npz), whose arrests
    lie 0.5 deg above / below Table 1's lambda = 1 curve: the base label is the same for every
    run on one base, whatever its angle and height and in whichever folder; the fit reports two
    bases with mean offsets +-0.5 deg from its curve and a between-base sigma_b."""
    import json

    import numpy as np

    from granflow.fitting.hstop import theta_stop_eq45

    hb = _load("hstop_brackets")
    rng = np.random.default_rng(1)
    bases = [rng.uniform(0, 5, (30, 3)) for _ in range(2)]

    def write(root, theta, H, k, state, base):
        d = root / "bracket" / "linear" / "lambda~1" / f"theta~{theta:.2f}" / f"H~{H:g}"
        d = d / f"seed~{k}" if k else d
        d.mkdir(parents=True, exist_ok=True)
        (d / "summary.json").write_text(json.dumps({"flow_state": state}))
        flow = rng.uniform(0, 5, (5, 3))  # the flow particles differ run by run
        np.savez(d / "final_state.npz", pos=np.vstack([bases[base], flow]),
                 fixed=np.r_[np.ones(30, bool), np.zeros(5, bool)])

    root, other = tmp_path / "a", tmp_path / "b"
    for H in (1.5, 2.0, 3.0, 4.0, 6.0, 12.0, 24.0):
        for k, shift in ((0, 0.5), (1, -0.5)):
            arrest = float(theta_stop_eq45(H, 17.708, 32.780, 3.355)) + shift
            write(root, arrest - 0.1, H, k, "arrested", base=k)
            write(root, arrest + 0.1, H, k, "steady", base=k)
    write(other, 30.0, 1.5, 0, "steady", base=0)
    runs = hb.bracket_runs(root, other, realisations=True)
    labels = runs.groupby("replicate")["base"].agg(set)
    assert len(labels[0]) == 1 and len(labels[1]) == 1 and labels[0] != labels[1]
    assert labels[1000] == labels[0]  # the same base in another folder is the same base
    assert hb.base_fingerprint(tmp_path / "missing.npz") is None
    iv, fit, _ = hb.hstop_table(runs[runs.realisation == 0])
    sc = fit.extra["base_scatter"]
    assert sc["n_bases"] == 2 and sc["brackets_per_base"] == [7, 7]
    np.testing.assert_allclose(sorted(sc["mean_offsets"]), [-0.5, 0.5], atol=0.05)
    assert sc["sigma_between"] > 0.5 and "sigma_b" in fit.message


def test_hstop_staircase_carries_each_state_to_the_next_run(tmp_path, monkeypatch):
    """benchmarks/hstop_staircase.py (the paper's §6 walk with carried-over state), with the
    simulation replaced by a known hstop curve: flowing iff H >= 4 + 4 (21 - theta) / 0.5.
    The walk is the paper's (21 deg flowing at H = 4, lower theta by 1/2 while flowing, add 2
    particle heights after an arrest), the first run is a fresh fall, every angle step restarts
    the previous run's state tilted and every height step tops it up, and the intervals are
    those of the curve; a rerun reuses the finished runs and simulates nothing."""
    import json

    import granflow.simulate as gsim

    st = _load("hstop_staircase")
    calls = []

    def fake_simulate(params, out_dir, base_file=None, threads=1, from_state=None,
                      top_up=False):
        theta, H = params["theta"], params["H"]
        calls.append((theta, H, None if from_state is None else Path(from_state).parent.name,
                      top_up))
        assert params["stop_when_flowing"] is False and params["t_end"] <= 500.0  # horizon
        flowing = H >= 4 + 4 * (21 - theta) / 0.5 - 1e-9
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "summary.json").write_text(json.dumps(dict(
            flow_state="steady" if flowing else "arrested", t_final=100.0,
            parent={"topped_up": 50} if top_up else {})))
        return {}

    monkeypatch.setattr(gsim, "simulate", fake_simulate)
    monkeypatch.setattr(gsim, "prepare_base_file", lambda *a, **k: None)
    args = ["--lam", "0.5", "--out", str(tmp_path / "out"), "--H-max", "12"]
    search = st.main(args)
    walk = [(t, H) for t, H, _, _ in calls]
    assert walk == [(21.0, 4.0), (20.5, 4.0), (20.5, 6.0), (20.5, 8.0), (20.0, 8.0),
                    (20.0, 10.0), (20.0, 12.0), (19.5, 12.0)]
    # fresh fall, then: tilt (angle step, same H), top-up (height step, same angle)
    assert calls[0][2:] == (None, False)
    for (t0, H0, _, _), (t1, H1, parent, top) in zip(calls, calls[1:]):
        assert parent == f"H~{H0:g}" and top == (H1 > H0)
        assert (t1 == t0) == (H1 > H0)
    assert search.intervals() == [(4.0, 20.5, 21.0), (6.0, 20.5, 21.0), (8.0, 20.0, 20.5),
                                  (10.0, 20.0, 20.5), (12.0, 19.5, 20.0)]
    calls.clear()
    again = st.main(args)
    assert calls == [] and again.runs == search.runs


def test_hstop_fresh_falls_brackets_a_known_curve_with_the_chosen_base(tmp_path, monkeypatch):
    """benchmarks/hstop_fresh_falls.py with the simulation replaced by a known demarcation
    (arrested iff theta < 19.9 + 0.02 H): the campaign's chain at each height (first run at
    Table 1's angle, steps of 1/2 deg, bisection to 0.25 deg) brackets it; every run is a fresh
    fall with the flow-base species of the chosen convention, the base is settled with the
    species asked for, the runs are where hstop_brackets.py reads them, and bad settling input
    is refused before anything runs."""
    import json

    import granflow.simulate as gsim
    from granflow.engine.species import ContactSpecies, flow_base_species

    ff = _load("hstop_fresh_falls")
    hb = _load("hstop_brackets")
    calls, bases = [], []

    seeds = {}

    def fake_simulate(params, out_dir, base_file=None, threads=1, from_state=None, top_up=False):
        calls.append((params["H"], params["theta"], params.get("base_t_c"), params.get("base_e"),
                      from_state))
        seeds.setdefault("run", set()).add(params["seed"])
        out_dir.mkdir(parents=True, exist_ok=True)
        arrested = params["theta"] < 19.9 + 0.02 * params["H"]
        (out_dir / "summary.json").write_text(json.dumps(dict(
            flow_state="arrested" if arrested else "steady", t_final=100.0)))
        return {}

    monkeypatch.setattr(gsim, "simulate", fake_simulate)
    def fake_base(lam, Lx, Ly, seed, out, **kw):
        bases.append(kw)
        seeds.setdefault("base", []).append(seed)
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_bytes(b"")

    monkeypatch.setattr(gsim, "prepare_base_file", fake_base)
    out = tmp_path / "out"
    args = ["--configfile", str(REPO / "config" / "reference-lambda-half.yaml"), "--lam", "0.5",
            "--H", "16", "24", "--out", str(out), "--base-prep-mu", "0",
            "--base-fill-packing", "0.648", "--base-band", "top", "--base-species", "absolute",
            "--base-prep-tc", "0.005", "--base-prep-e", "0.88"]
    rows = ff.main(args)
    for H, lo, hi, ok in rows:
        true = 19.9 + 0.02 * H
        assert ok and lo < true <= hi and hi - lo <= 0.25 + 1e-9, (H, lo, hi)
    fb = flow_base_species(ContactSpecies(), "absolute")
    assert {(c[2], c[3]) for c in calls} == {(fb.t_c, fb.e)}
    assert all(c[4] is None for c in calls)  # fresh falls
    first = {H: next(c[1] for c in calls if c[0] == H) for H in (16.0, 24.0)}
    assert first[16.0] == pytest.approx(19.40, abs=0.01)  # Table 1 (the configuration's prior)
    assert first[24.0] == pytest.approx(19.07, abs=0.01)
    assert bases == [{"base_layers": 12.0, "settle_time": 30.0, "prep_t_c": 0.005,
                      "prep_e": 0.88, "prep_mu_c": 0.0, "fill_packing": 0.648, "band": "top"}]
    runs = hb.bracket_runs(out)
    assert len(runs) == len(calls) and set(runs.H) == {16.0, 24.0}
    # a rerun simulates nothing
    calls.clear()
    assert ff.main(args) == rows and calls == []
    # bad input: named, before any run or base
    with pytest.raises(ValueError, match="prep_e"):
        ff.main(args[:-1] + ["1.5"])
    with pytest.raises(ValueError, match="fill_packing = 0.9 is out of range"):
        ff.main([a if a != "0.648" else "0.9" for a in args])
    with pytest.raises(ValueError, match="--base-species absolute is defined for --law linear"):
        ff.main(args + ["--law", "hertz"])
    # runs of another base or species are not mixed into a results folder
    with pytest.raises(ValueError, match="another --out"):
        ff.main(args[:-5] + ["per_pair"])
    assert calls == [] and len(bases) == 1
    # a configuration's own `base:` settings make the base (as the workflow's base rule does)
    cfg = tmp_path / "mercury.yaml"
    cfg.write_text((REPO / "config" / "reference-lambda-half.yaml").read_text()
                   .replace("  seed: 1\n\ncampaigns:", "  seed: 1\n  settle_mu_c: 0.0\n"
                            "  band: top\n\ncampaigns:"))
    assert "band: top" in cfg.read_text()
    bases.clear()
    ff.main(["--configfile", str(cfg), "--lam", "0.5", "--H", "16", "--out", str(tmp_path / "m")])
    assert bases == [{"base_layers": 12.0, "settle_time": 30.0, "prep_mu_c": 0.0, "band": "top"}]
    # --seed (the flow's insertion) and --base-seed (another base realisation) reach the runs
    # and the base; a negative one is refused before anything runs
    bases.clear()
    calls.clear()
    seeds.clear()
    ff.main(["--configfile", str(cfg), "--lam", "0.5", "--H", "16", "--seed", "2",
             "--base-seed", "3", "--out", str(tmp_path / "s")])
    assert seeds == {"base": [3], "run": {2}}
    assert json.loads((tmp_path / "s" / "fresh_falls.json").read_text())["base_seed"] == 3
    with pytest.raises(ValueError, match="--base-seed = -1: must be an integer >= 0"):
        ff.main(["--lam", "0.5", "--H", "16", "--base-seed", "-1", "--out", str(tmp_path / "x")])
    assert not (tmp_path / "x").exists()


def test_arrest_tests_counts_where_granflow_and_the_papers_test_disagree(tmp_path, capsys,
                                                                        monkeypatch):
    """benchmarks/arrest_tests.py on three synthetic runs with known answers: a clean arrest
    (both agree, paper time 38), a rattler-held pile that granflow calls arrested (ratio 1.5e-3:
    the paper's test does not), a flowing run (both agree)."""
    import json
    import sys

    import xarray as xr

    at = _load("arrest_tests")
    t = np.round(np.arange(0.0, 120.0, 0.0025), 10)
    series = {"clean": 10.0 * np.exp(-(t / 37.3) * np.log(1e6)),
              "rattler": np.where(t > 60, 1.5e-3, 10.0), "flow": np.full_like(t, 3.0)}
    states = {"clean": "arrested", "rattler": "arrested", "flow": "steady"}
    for k, (name, ratio) in enumerate(series.items()):
        d = tmp_path / "bracket" / "linear" / "lambda~0.5" / f"theta~{20 + k:.2f}" / "H~8"
        d.mkdir(parents=True)
        (d / "summary.json").write_text(json.dumps({"flow_state": states[name],
                                                    "t_final": float(t[-1])}))
        xr.Dataset({"energy_ratio": ("t", ratio)}, coords={"t": t}).to_netcdf(d / "series.nc")
    rows = at.arrest_rows(tmp_path)
    assert [(r["theta"], r["state"], r["paper_arrest"]) for r in rows] == [
        (20.0, "arrested", 38.0), (21.0, "arrested", None), (22.0, "steady", None)]
    monkeypatch.setattr(sys, "argv", ["arrest_tests.py", str(tmp_path)])
    at.main()
    out = capsys.readouterr().out
    assert out.count("<- differs") == 1
    assert "3 runs; granflow arrested, paper test not: 1; paper test arrested, granflow not: 0" in out



def test_library_damage_memory_finds_the_stored_lengths_of_variable_length_data():
    """benchmarks/library_damage_memory.py's "lengths" damage: the parser finds each 4-byte
    length stored before the address of a global heap collection (a known layout) and skips
    zero lengths."""
    import struct

    bench = _load("library_damage_memory")
    heap = 64
    blob = bytearray(256)
    blob[heap:heap + 4] = b"GCOL"
    for offset, length in ((8, 5), (24, 0), (120, 77), (200, 2)):
        blob[offset:offset + 4] = struct.pack("<I", length)
        blob[offset + 4:offset + 12] = struct.pack("<Q", heap)
    assert bench.length_fields(bytes(blob)) == [8, 120, 200]


def _series(path, t, u):
    import xarray as xr

    xr.Dataset({"u_mean": ("time", np.asarray(u, float))},
               coords={"time": np.asarray(t, float)}).to_netcdf(path)


def test_early_stop_bias_compares_the_steady_window_with_the_last_averaging_time(
        tmp_path, monkeypatch, capsys):
    """benchmarks/early_stop_bias.py on a run whose continuation is known: the early run stopped
    at t = 300 with u = 10 over its steady window [200, 300]; the continuation (to the paper's
    t = 2000: 1700 more) alternates T-block means 10.2 / 9.8 and ends on 10.2, so the relative
    change is +2 %, the sd of the 17 block means is that of the alternation, and the ratio to
    the run's reported u_bar_sem is exact.  Arrested, and already long, runs are not continued."""
    import json

    import yaml

    mod = _load("early_stop_bias")
    res = tmp_path / "results" / "c"
    run = res / "chute" / "linear" / "lambda~0.5" / "theta~27" / "H~10"
    run.mkdir(parents=True)
    (run / "params.yaml").write_text(yaml.safe_dump(dict(theta=27.0, H=10.0, averaging_time=100.0,
                                                          t_end=2000.0, early_stop=True)))
    t = np.arange(0.0, 300.0, 0.5)
    _series(run / "series.nc", t, np.where(t >= 200.0, 10.0, 5.0))
    (run / "final_state.npz").write_bytes(b"state")
    (run / "summary.json").write_text(json.dumps(dict(
        flow_state="steady", t_final=300.0, steady_start=200.0,
        depth_averages=dict(froude=2.0, flow_height=10.5, u_bar_sem=0.01))))
    other = run.parent.parent / "theta~20" / "H~10"
    other.mkdir(parents=True)
    (other / "summary.json").write_text(json.dumps(dict(flow_state="arrested")))
    calls = []

    def fake(params_file, dest, state):
        p = yaml.safe_load(params_file.read_text())
        calls.append((p["t_end"], p["early_stop"], state.name))
        tc = np.arange(0.0, p["t_end"] + 1e-9, 0.5)
        block = np.minimum((tc // 100).astype(int), 16)
        _series(dest / "series.nc", tc, np.where(block % 2 == 0, 10.2, 9.8))
        (dest / "summary.json").write_text(json.dumps(dict(flow_state="steady",
                                                            t_final=p["t_end"])))

    monkeypatch.setattr(mod, "simulate_from", fake)
    mod.main([str(res), "--lam", "0.5", "--jobs", "1", "--out", str(tmp_path / "esb")])
    assert calls == [(1700.0, False, "final_state.npz")]
    row, = json.loads((tmp_path / "esb" / "early_stop_bias.json").read_text())
    assert row["u_early"] == pytest.approx(10.0)
    assert row["u_paper"] == pytest.approx(10.2)
    assert row["rel_change"] == pytest.approx(0.02)
    assert row["F_paper_est"] == pytest.approx(2.04)
    blocks = [10.2 if k % 2 == 0 else 9.8 for k in range(17)]
    assert row["n_blocks"] == 17 and row["block_sd"] == pytest.approx(np.std(blocks, ddof=1))
    assert row["block_sd_over_sem"] == pytest.approx(np.std(blocks, ddof=1) / 0.01)
    assert "+2.00%" in capsys.readouterr().out
    # a second call reuses the continuation
    mod.main([str(res), "--lam", "0.5", "--jobs", "1", "--out", str(tmp_path / "esb")])
    assert len(calls) == 1


def test_flow_rule_runs_recovers_table_1_from_runs_on_its_law(tmp_path, capsys):
    """benchmarks/flow_rule_runs.py on run folders whose F lies exactly on Table 1's lambda = 1/2
    law (beta 0.300, gamma -0.236 with Table 1's hstop(theta; 1)): the fit returns Table 1's
    parameters, the paper's law has zero error on them, alpha is the runs' mean; a layered run
    is listed but left out, and a bad --hstop curve is refused before anything is read."""
    import json

    from granflow.fitting.flow_rule import froude_eq47
    from granflow.reference import paper_value

    frr = _load("flow_rule_runs")
    hs1 = {k: paper_value("hstop", k, 1.0) for k in ("delta1", "delta2", "A")}
    points = [(26.0, 20.0, 19.3), (27.0, 10.0, 10.5), (27.0, 20.0, 19.7), (28.0, 10.0, 11.2),
              (28.0, 20.0, 20.3), (25.0, 20.0, 19.0)]
    dirs = []
    for k, (theta, H, h) in enumerate(points):
        F = float(froude_eq47(h, theta, 0.300, -0.236, **hs1))
        d = tmp_path / f"run{k}"
        d.mkdir()
        state = "layered" if theta == 25.0 else "steady"
        (d / "summary.json").write_text(json.dumps({
            "flow_state": state,
            "params": {"theta": theta, "H": H, "lam": 0.5, "Lx": 20.0, "Ly": 10.0},
            "depth_averages": {"flow_height": h, "froude": F if state == "steady" else 9.0,
                               "alpha": 1.14 + 0.001 * k}}))
        dirs.append(str(d))
    runs = frr.read_runs(dirs)
    steady = [r for r in runs if r["state"] == "steady"]
    assert len(runs) == 6 and len(steady) == 5
    f = frr.fit_with(steady, hs1)
    assert f.params["beta"] == pytest.approx(0.300, abs=1e-9)
    assert f.params["gamma"] == pytest.approx(-0.236, abs=1e-9)
    law = frr.paper_law(steady, 0.5)
    assert law["error"] == pytest.approx(0.0, abs=1e-12) and law["paper"] == 0.229
    frr.main(dirs)
    out = capsys.readouterr().out
    assert "5 steady of 6 runs" in out and "| layered |" in out
    assert "beta 0.3 +- " in out and "gamma -0.236 +- " in out
    assert "alpha: 1.1420 +- 0.0016 (mean, sd of 5) against Table 2's 1.142 (+0.0 %)" in out
    with pytest.raises(SystemExit, match="need 0 < delta1 < delta2 < 90"):
        frr.main(dirs + ["--hstop", "30", "20", "3"])


def test_particle_order_curves_are_permutations_that_step_to_grid_neighbours():
    """benchmarks/bench_particle_order.py's orders: the Hilbert index of an 8 x 8 grid visits
    every cell once, each step to an edge neighbour (the curve's defining property); every
    order of random particles is a permutation whose column keys never decrease."""
    bo = _load("bench_particle_order")
    gx, gy = np.meshgrid(np.arange(8), np.arange(8), indexing="ij")
    d = bo._hilbert_index(8, gx.ravel(), gy.ravel())
    assert sorted(d) == list(range(64))
    path = np.empty((64, 2), int)
    path[d] = np.c_[gx.ravel(), gy.ravel()]
    assert np.all(np.abs(np.diff(path, axis=0)).sum(axis=1) == 1)
    m = bo._part1by1(np.arange(4))
    assert list(m) == [0, 1, 4, 5]  # bits spread to the even positions
    rng = np.random.default_rng(3)
    pos = rng.random((500, 3)) * [16.0, 8.0, 10.0]
    for kind in ("xyz", "yxz", "morton", "hilbert"):
        o = bo.order(pos, 16.0, 8.0, kind)
        assert sorted(o) == list(range(500)), kind
    o = bo.order(pos, 16.0, 8.0, "xyz")
    col = np.floor(pos[o, 0]).astype(int) * 8 + np.floor(pos[o, 1]).astype(int)
    assert np.all(np.diff(col) >= 0)
    with pytest.raises(ValueError):
        bo.order(pos, 16.0, 8.0, "random")


def _approach_profiles(path, t_mid, Ps_of_t, depth=24.0):
    """A profiles.nc with one window per time: a hydrostatic sigma_zz over [0, depth] and the
    small fraction of T-eq. (28) at Ps_of_t (phi0 = 0.5, total volume fraction 0.6)."""
    import xarray as xr

    from granflow.fitting.segregation import phi_teq28

    z = np.arange(-2.0, depth + 4.0, 0.05)
    zeta = np.clip(z / depth, 0.0, 1.0)
    inside = (z >= 0) & (z <= depth)
    nu, szz = [], []
    for Ps in Ps_of_t:
        phi = phi_teq28(zeta, Ps, 0.5)
        nu.append(np.stack([np.where(inside, 0.6 * phi, 0.0), np.where(inside, 0.6 * (1 - phi), 0.0)]))
        szz.append(np.where(inside, 0.6 * (depth - z), np.where(z < 0, 0.6 * depth, 0.0)))
    n = len(t_mid)
    ds = xr.Dataset({"species_volume_fraction_window": (("time_window", "species", "z"), np.array(nu)),
                     "stress_zz_window": (("time_window", "z"), np.array(szz)),
                     "window_n_snapshots": ("time_window", np.full(n, 100)),
                     "window_time_start": ("time_window", np.asarray(t_mid) - 25.0),
                     "window_mean_time": ("time_window", np.asarray(t_mid, dtype=float))},
                    coords={"z": z, "time_window": np.arange(n)},
                    attrs={"cg_small_species": 0, "cg_window_length": 50.0})
    ds.to_netcdf(path / "profiles.nc")


def test_segregation_approach_recovers_window_peclets_and_the_plateau_they_approach(tmp_path):
    """benchmarks/segregation_approach.py on windows of T-eq. (28) profiles whose Ps relaxes
    exponentially to 5 (from above, as after a segregated start; from below, as after a mixed
    one): each window's Ps recovered to 1e-4, the side of the approach named, the last windows'
    mean a bound on the plateau from that side, and the relaxation fit's Ps_inf within 2 of its
    stderrs of 5 (and within 2 %)."""
    sa = _load("segregation_approach")
    t = 25.0 + 50.0 * np.arange(20)
    wiggle = 0.01 * np.sin(1.7 * np.arange(20))  # the fit needs residuals to weigh
    for a, side in ((4.0, -1.0), (-2.5, 1.0)):
        Ps = 5.0 + a * np.exp(-t / 300.0) + wiggle
        run = tmp_path / f"a{a}"
        run.mkdir()
        _approach_profiles(run, t, Ps)
        w = sa.window_peclets(run)
        assert w["window"] == 50.0 and w["Ps"].size == 20
        np.testing.assert_allclose(w["t_mid"], t)
        np.testing.assert_allclose(w["Ps"], Ps, rtol=1e-4)
        np.testing.assert_allclose(w["depth"], 24.0, rtol=1e-3)
        res = sa.approach(w["t_mid"], w["Ps"], t_from=0.0)
        assert res["side"] == side
        assert (res["Ps_last"] - 5.0) * side < 0  # a bound from the named side
        assert res["identified"]
        assert abs(res["Ps_inf"] - 5.0) < max(2 * res["Ps_inf_stderr"], 0.1)
        assert res["Ps_inf"] == pytest.approx(5.0, rel=0.02)
        assert res["tau"] == pytest.approx(300.0, rel=0.25)
    with pytest.raises(ValueError, match="windows after t_from"):
        sa.approach(t[:5], Ps[:5])
    with pytest.raises(SystemExit):
        sa.main([str(run), "--last", "1"])
    # too few windows for an approach: --json still holds the windows, and says why there is
    # no approach (it used to return before writing the file)
    short = tmp_path / "short"
    short.mkdir()
    _approach_profiles(short, t[:3], Ps[:3])
    assert sa.main([str(short), "--json", str(tmp_path / "short.json")]) == 0
    got = json.loads((tmp_path / "short.json").read_text())
    np.testing.assert_allclose(got["windows"]["Ps"], Ps[:3], rtol=1e-4)
    assert "windows after t_from" in got["approach"]["error"]
    # a finished bidisperse run: profiles.nc holds the last windows only, profiles_history.nc
    # every window, and the tool reads the latter
    (run / "profiles.nc").rename(run / "profiles_history.nc")
    _approach_profiles(run, t[-4:], Ps[-4:])
    w = sa.window_peclets(run)
    assert w["Ps"].size == 20
    np.testing.assert_allclose(w["Ps"], Ps, rtol=1e-4)


def test_segregation_approach_tells_a_flat_tail_from_one_still_moving():
    """Known answers for the flatness test of the last ten windows: a relaxation long over
    (tau 300, 2000 units in) with AR(1) noise of 0.02 is flat, its tail mean within 2 sem of
    the plateau; the same relaxation 600 units in (Ps still rising by ~0.3 over the tail) is
    not; a linear creep of 1 % per 100 units is not; pure noise of 0.2 on 5 (the interval
    too wide to show anything) is not."""
    from granflow.steady.timeseries import ar1_noise

    sa = _load("segregation_approach")
    rng = np.random.default_rng(7)
    t = 25.0 + 50.0 * np.arange(60)
    noise = ar1_noise(t.size, rng, 0.3, 0.02)
    relax = 5.5 - 2.0 * np.exp(-t / 300.0) + noise
    done = sa.flat_tail(t, relax)
    assert done["flat"] and done["windows"] == 10 and done["span"] == 450.0
    assert abs(done["mean"] - 5.5) < 2 * done["sem"] + 1e-3
    early = sa.flat_tail(t[:12], relax[:12])
    assert not early["flat"] and early["change"] > 0.2
    creep = sa.flat_tail(t, 5.0 * (1.0 + 1e-4 * t) + noise)
    assert not creep["flat"] and creep["p_value"] < 0.01
    noisy = sa.flat_tail(t, 5.0 + ar1_noise(t.size, rng, 0.3, 0.2))
    assert not noisy["flat"]
    with pytest.raises(ValueError, match="flatness test needs 10"):
        sa.flat_tail(t[:5], relax[:5])


def test_segregation_approach_reads_every_window_so_far_from_a_checkpoint(tmp_path):
    """``--checkpoint``: the windows of the profile observer's state in a run's checkpoint.npz
    (keys ``extra__obs__profiles__*``) give the same per-window fields as the accumulator that
    wrote them, bit for bit; a checkpoint without that state is refused by name."""
    from granflow.coarse.profiles import DepthProfileAccumulator

    sa = _load("segregation_approach")
    rng = np.random.default_rng(3)
    acc = DepthProfileAccumulator(-1.0, 12.0, 0.1, width=0.25, Lx=4.0, Ly=4.0, n_species=2,
                                  window_length=1.0)
    n = 60
    for k in range(5):
        pos = rng.random((n, 3)) * [4.0, 4.0, 10.0]
        acc.add_snapshot(0.5 * k, pos, rng.normal(size=(n, 3)), np.ones(n), np.ones(n),
                         rng.integers(0, 2, n), np.zeros(n, bool), np.zeros(0, int),
                         np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    state = {sa.PREFIX + k: v for k, v in acc.state_dict().items()}
    state[sa.PREFIX + "observer_calls"] = np.int64(5)
    np.savez(tmp_path / "checkpoint.npz", pos=np.zeros((1, 3)), **state)
    got = sa.checkpoint_profiles(tmp_path / "checkpoint.npz")
    want = acc.to_dataset()
    assert got["species_volume_fraction_window"].shape[0] == 3  # windows [0, 1), [1, 2), [2, 3)
    for name in ("species_volume_fraction_window", "stress_zz_window", "window_time_start",
                 "window_n_snapshots"):
        np.testing.assert_array_equal(got[name].values, want[name].values)
    np.savez(tmp_path / "bare.npz", pos=np.zeros((1, 3)))
    with pytest.raises(ValueError, match="holds no profile accumulator"):
        sa.checkpoint_profiles(tmp_path / "bare.npz")


def test_segregation_approach_joins_a_continuation_to_its_parent_on_the_parents_clock(
        tmp_path, capsys):
    """``--parent``: a relaxation split at t = 500 into a parent run and a continuation (its
    clock reset to 0, as ``simulate --from`` does) gives, joined on the parent's clock, the
    same window series and plateau as the unsplit run; the parent's time is read from the
    continuation's summary.json (``parent.parent_time``); a time <= 0 is refused by name."""
    sa = _load("segregation_approach")
    t = 25.0 + 50.0 * np.arange(20)
    Ps = 5.0 + 4.0 * np.exp(-t / 300.0) + 0.01 * np.sin(1.7 * np.arange(20))
    whole, parent, child = (tmp_path / n for n in ("whole", "parent", "child"))
    for d in (whole, parent, child):
        d.mkdir()
    _approach_profiles(whole, t, Ps)
    _approach_profiles(parent, t[:10], Ps[:10])
    _approach_profiles(child, t[10:] - 500.0, Ps[10:])
    (child / "summary.json").write_text(json.dumps({"params": {}, "parent": {
        "parent_state": "x", "parent_time": 500.0}}))
    out = tmp_path / "joined.json"
    assert sa.main([str(child), "--parent", str(parent), "--t-from", "0", "--json",
                    str(out)]) == 0
    assert "10 parent windows first" in capsys.readouterr().out
    got = json.loads(out.read_text())
    ref = sa.window_peclets(whole)
    np.testing.assert_allclose(got["windows"]["t_mid"], ref["t_mid"])
    np.testing.assert_allclose(got["windows"]["Ps"], ref["Ps"], rtol=1e-12)
    assert got["windows"]["piece"] == [0.0] * 10 + [1.0] * 10
    want = sa.approach(ref["t_mid"], ref["Ps"], t_from=0.0)
    assert got["approach"]["Ps_inf"] == pytest.approx(want["Ps_inf"], rel=1e-9)
    assert got["approach"]["side"] == -1.0
    with pytest.raises(ValueError, match="parent_time"):
        sa.join_windows(ref, ref, 0.0)
    # a chain in three pieces (continued twice): --parent oldest first, each continuation's
    # own summary.json naming its parent's time; the same series as the unsplit run
    first, middle, last = (tmp_path / n for n in ("first", "middle", "last"))
    for d in (first, middle, last):
        d.mkdir()
    _approach_profiles(first, t[:6], Ps[:6])
    _approach_profiles(middle, t[6:13] - 300.0, Ps[6:13])
    _approach_profiles(last, t[13:] - 650.0, Ps[13:])
    for d, tp in ((middle, 300.0), (last, 350.0)):
        (d / "summary.json").write_text(json.dumps({"params": {}, "parent": {
            "parent_state": "x", "parent_time": tp}}))
    assert sa.main([str(last), "--parent", str(first), "--parent", str(middle), "--t-from",
                    "0", "--json", str(out)]) == 0
    got = json.loads(out.read_text())
    np.testing.assert_allclose(got["windows"]["t_mid"], ref["t_mid"])
    np.testing.assert_allclose(got["windows"]["Ps"], ref["Ps"], rtol=1e-12)
    assert got["windows"]["piece"] == [0.0] * 6 + [1.0] * 7 + [2.0] * 7
    with pytest.raises(SystemExit):  # a later parent must name its own parent's time
        sa.main([str(last), "--parent", str(middle), "--parent", str(first)])
    with pytest.raises(FileNotFoundError, match="the run has finished"):
        sa.window_peclets(child, from_checkpoint=True)


def test_segregation_approach_replays_the_steady_detector_on_a_recorded_indicator(tmp_path):
    """``--verdicts`` (``detector_verdicts``): a series.nc whose indicator relaxes from 0 to
    -4 with tau 150 (AR(1) noise 0.03, samples every 2; the run's averaging_time 200 and
    start-up 20 read from its attributes) is judged every 50 units by this code's rule: not
    steady while the change truly to come exceeds the tolerance (3 % of the total + 0.03),
    first steady at t = 800 (0.5 % to come), the same verdicts as the detector on the same
    samples."""
    import xarray as xr

    from granflow.steady.segregation import segregation_steadiness

    sa = _load("segregation_approach")
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 1200.0, 2.0)
    true = -4.0 * (1.0 - np.exp(-t / 150.0))
    noise = np.zeros(t.size)
    e = rng.normal(0.0, 0.03 * math.sqrt(1 - math.exp(-0.4)), t.size)
    for i in range(1, t.size):
        noise[i] = math.exp(-0.2) * noise[i - 1] + e[i]
    s = true + noise
    run = tmp_path / "run"
    run.mkdir()
    xr.Dataset({"segregation_indicator": ("segregation_time", s)},
               coords={"segregation_time": t},
               attrs={"steady_min_onset": 20.0,
                      "config_json": json.dumps({"averaging_time": 200.0})}
               ).to_netcdf(run / "series.nc")
    got = sa.detector_verdicts(run)
    assert [v["t"] for v in got] == list(np.arange(200.0, 1150.0 + 1e-9, 50.0))
    first = next(v for v in got if v["steady"])
    assert first["t"] == 800.0
    for v in got:
        to_come = abs(true[t <= v["t"]][-1] + 4.0)
        if to_come > 0.03 * 4.0 + 0.03:
            assert not v["steady"], v
    k = t <= 600.0
    direct = segregation_steadiness(t[k], s[k], averaging_time=200.0, min_onset=20.0)
    v600 = next(v for v in got if v["t"] == 600.0)
    assert v600["steady"] == direct.steady and v600["plateau"] == direct.plateau


def test_segregation_detector_calibration_replays_the_detector_on_known_answers():
    """benchmarks/segregation_detector_calibration.py: on the mixed-start known answer (0 -> -4
    with tau 300) the first steady verdicts of seeds 0 and 1 come at t = 1150 and 1200 with
    0.087 and 0.073 truly to come, inside the detector's tolerance (0.138, 0.139): not early
    (20 seeds: 0 early, measured 2026-12-07).  The same verdict as the detector itself."""
    from granflow.steady.segregation import segregation_steadiness

    cal = _load("segregation_detector_calibration")
    for seed, t_first, come in ((0, 1150.0, 0.0865), (1, 1200.0, 0.0733)):
        r = cal.first_verdict("mixed", seed)
        assert r["t"] == t_first and not r["early"], r
        assert r["to_come"] == pytest.approx(come, abs=5e-4)
        # 3 % of the change seen since the start-up (t >= 20: about 3.6) + 0.03
        assert r["tolerance"] == pytest.approx(0.138, abs=0.002)
    t_end, dt, min_onset, phi, noise, s_inf, true_of = cal.CASES["mixed"]
    t = np.arange(0.0, t_end, dt)
    from granflow.steady.timeseries import ar1_noise

    s = true_of(t) + ar1_noise(t.size, np.random.default_rng(1000), phi, noise)
    k = t <= 1150.0
    assert segregation_steadiness(t[k], s[k], averaging_time=200.0, min_onset=20.0).steady
    k = t <= 1100.0
    assert not segregation_steadiness(t[k], s[k], averaging_time=200.0, min_onset=20.0).steady


def test_segregation_wander_tells_an_honest_window_stderr_from_a_wandering_state(tmp_path,
                                                                                 capsys):
    """benchmarks/segregation_wander.py on series with known answers: independent windows
    (white noise, sd 0.3) have an autocorrelation time of one window and block means that
    scatter as their own stderrs say (ratio 1 within 25 %); an AR(1) series whose
    autocorrelation time is 20 windows has that time (within 30 %) and 3-window means
    scattering more than twice their own stderrs -- a state wandering on times longer than the
    averaging, as measured at the default segregation set-up."""
    sw = _load("segregation_wander")
    rng = np.random.default_rng(52)
    white = 5.0 + 0.3 * rng.standard_normal(3000)
    t = 20.0 * np.arange(white.size)
    r = sw.wander(t, white, t_from=0.0, window=20.0, lengths=(60.0, 300.0))
    assert r["acf_time"] == 20.0 and r["mean"] == pytest.approx(5.0, abs=0.03)
    assert r["blocks"][60.0]["ratio"] == pytest.approx(1.0, abs=0.25)
    assert r["blocks"][60.0]["sd"] == pytest.approx(0.3 / math.sqrt(3), rel=0.1)
    phi = math.exp(-1.0 / 20.0)
    ar = np.empty(20000)
    ar[0] = 0.0
    eps = rng.standard_normal(ar.size) * math.sqrt(1 - phi ** 2)
    for i in range(1, ar.size):
        ar[i] = phi * ar[i - 1] + eps[i]
    r = sw.wander(20.0 * np.arange(ar.size), 5.0 + 0.4 * ar, t_from=0.0, window=20.0,
                  lengths=(60.0,))
    assert r["acf_time"] / 20.0 == pytest.approx(20.0, rel=0.3)
    assert r["blocks"][60.0]["ratio"] > 2.0
    with pytest.raises(ValueError, match="t_from"):
        sw.wander(t[:10], white[:10], t_from=1e9, window=20.0)
    # the command line on segregation_approach.py's --json output (the README's command)
    path = tmp_path / "w.json"
    path.write_text(json.dumps({"window": 20.0, "windows": {
        "t_start": t.tolist(), "Ps": white.tolist()}}))
    assert sw.main([str(path), "--t-from", "1000"]) == 0
    out = capsys.readouterr().out
    assert "2950 windows of 20 over t = 1000-60000" in out and "60-unit means: 983" in out
    # with the run's number of particles: C = relative spread x sqrt(N), and what granflow
    # assumes (white noise of sd 0.3 about 5: 6 % for the windows, C = 0.06 * 10 at N = 100)
    assert sw.main([str(path), "--t-from", "1000", "--n-flow", "100"]) == 0
    out = capsys.readouterr().out
    c_windows = float(out.split("20-unit windows ")[1].split("(C ")[1].split(")")[0])
    assert c_windows == pytest.approx(0.6, rel=0.05)
    assert "granflow's wander_sd assumes 16.31 % (C 1.631)" in out
    with pytest.raises(SystemExit):
        sw.main([str(path), "--t-from", "1000", "--n-flow", "0"])


def test_segregation_trend_calibration_replays_the_still_moving_rule_on_known_answers(
        tmp_path, capsys):
    """benchmarks/segregation_trend_calibration.py on series with known answers.  A stationary
    wander (AR(1) over 20-unit windows, autocorrelation time 100 units, 9 % spread: the default
    set-up's, measured) has no drift, yet the 5 % rule flags a third or more of its 10-window
    stretches, with the trend pointing towards the long mean in about half of them (a coin
    flip: the "one-sided bound" it makes is wrong half the time); the rule with the wander's
    tolerance (3 C / sqrt(N) at N = 396, where C / sqrt(N) is that 8.2 %) flags at most 8 %.
    An approach (Ps relaxing from 0 to 10 with a time of 150 units, as the default's mixed
    starts do, the same wander on top) keeps flags under both rules, and every flag of the
    wander rule points towards the plateau."""
    from granflow.steady.timeseries import ar1_noise

    tc = _load("segregation_trend_calibration")
    rng = np.random.default_rng(8)
    n = 1500
    t = 20.0 * np.arange(n)
    steady = 10.0 * (1.0 + ar1_noise(n, rng, math.exp(-20.0 / 100.0), 0.09))
    r = tc.replay(t, steady, n_flow=396, t_from=0.0, windows=(4, 10))
    assert abs(r["mean"] - 10.0) < 0.2
    c = r[10]
    assert c["flags_5"] / c["stretches"] > 0.25
    assert 0.35 < c["toward_5"] / c["flags_5"] < 0.65
    assert c["flags_wander"] / c["stretches"] < 0.08
    assert r[4]["flags_wander"] / r[4]["stretches"] < 0.03
    # an approach to the same plateau, then the plateau
    t = 20.0 * np.arange(440)
    wander = 1.0 + ar1_noise(t.size, np.random.default_rng(9), math.exp(-0.2), 0.09)
    series = 10.0 * (1.0 - np.exp(-(t + 10.0) / 150.0)) * wander
    a = tc.replay(t, series, n_flow=396, t_from=800.0, t_to=800.0, windows=(6,))[6]
    assert a["flags_wander"] >= 0.2 * a["stretches"]
    assert a["toward_wander"] == a["flags_wander"] and a["flags_5"] >= a["flags_wander"]
    with pytest.raises(ValueError, match="n_flow"):
        tc.replay(t, series, n_flow=0, t_from=800.0)
    with pytest.raises(ValueError, match="windows = 3"):
        tc.replay(t, series, n_flow=396, t_from=800.0, windows=(3,))
    # the command line (FILE:T_FROM:N) on segregation_approach.py's --json output
    path = tmp_path / "w.json"
    path.write_text(json.dumps({"window": 20.0, "windows": {
        "t_start": t.tolist(), "Ps": series.tolist()}}))
    assert tc.main([f"{path}:800:396", "--windows", "4", "10"]) == 0
    out = capsys.readouterr().out
    assert "pooled n = 10" in out and "wander rule" in out
    with pytest.raises(SystemExit):
        tc.main([f"{path}:800"])
