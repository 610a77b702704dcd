"""fit_campaign on a synthetic campaign table, through to a closure library (issue 6).

The table mimics a campaign at the reference parameters: the paper's adaptive hstop search for
lambda = 1 and 2/3, plus a grid of steady runs whose F, alpha, rho_c, K follow Weinhart et al.
2012 Eq. (47), (54)/(55), (52), (53) with Table 1/2 values plus noise of the paper's error sizes,
and segregation runs following T-eq. (29).
"""

import numpy as np
import pytest

import granflow.closures as gc
from granflow.fitting import (alpha_eq54, campaign_table_from_records, density_eq52, fit_campaign,
                              fit_flow_rule, froude_eq47, hstop_eq45, Ps_teq29, stress_ratio_eq53,
                              theta_stop_eq45)
from test_fitting import DENSITY, HSTOP1, PS_LAW, STRESS_RATIO, TABLE1, adaptive_search


def synthetic_campaign(rng):
    records = []
    for lam in TABLE1:
        true = dict(zip(("delta1", "delta2", "A"), TABLE1[lam][:3]))
        beta, gamma = TABLE1[lam][3:]
        for _, run in adaptive_search(true, rng).iterrows():
            records.append(dict(theta=run.theta, H=run.H, lam=lam, contact_law="linear",
                                state=run.state))
        for theta in np.arange(21.0, 28.5, 1.0):
            for H in (10.0, 20.0, 30.0, 40.0):
                if theta < theta_stop_eq45(H, **true) + 1.0:
                    continue
                h = 0.9 * H
                hs1 = hstop_eq45(theta, **HSTOP1)
                alpha = (alpha_eq54(h, hs1, 6.678) if lam == 1.0 else 1.201) + rng.normal(0, 0.02)
                records.append(dict(
                    theta=theta, H=H, lam=lam, contact_law="linear", state="steady", h=h,
                    F=froude_eq47(h, theta, beta, gamma, **HSTOP1) + rng.normal(0, 0.1),
                    alpha=alpha, rho_c=density_eq52(theta, **DENSITY) + rng.normal(0, 0.004),
                    K=stress_ratio_eq53(theta, **STRESS_RATIO) + rng.normal(0, 0.013)))
    for sigma in np.linspace(0.4, 0.95, 12):
        records.append(dict(theta=25.0, H=20.0, lam=0.5, sigma=sigma, contact_law="linear",
                            state="steady", Ps=Ps_teq29(sigma, **PS_LAW) + rng.normal(0, 0.15),
                            Ps_std=0.15, phi0=0.5))
    for k, r in enumerate(records):
        r["run"] = f"run{k:04d}"
    return campaign_table_from_records(records)


def test_fit_campaign_to_library(tmp_path):
    table = synthetic_campaign(np.random.default_rng(2012))
    fits = fit_campaign(table, n_bootstrap=30)
    by = {(f.kind, f.coords.get("lam")): f for f in fits}
    assert all(f.state != "failed" for f in fits), [f.message for f in fits if not f.ok]
    assert {k for k, _ in by} == {"hstop", "hstop_eq38", "flow_rule", "friction", "alpha",
                                  "density", "stress_ratio", "Ps_law"}
    # closures that do not depend on the fitted hstop: full forms identified, within 3 of their
    # own stderr of the generating values
    for kind, true in (("density", DENSITY), ("stress_ratio", STRESS_RATIO), ("Ps_law", PS_LAW)):
        f = by[(kind, None)]
        assert f.status == "ok" and f.form == "full", (kind, f.message)
        for name, value in true.items():
            assert abs(f.params[name] - value) < 3 * f.stderr[name], (kind, name)
    # hstop(theta; 1) from the simulated adaptive search (0.25 deg threshold noise) is identified
    h1 = by[("hstop", 1.0)]
    assert h1.status == "ok"
    for name, value in zip(("delta1", "delta2", "A"), (17.708, 32.780, 3.355)):
        assert abs(h1.params[name] - value) < 3 * h1.stderr[name], name
    # the flow rule's stderr is unconditional (joint bootstrap over the hstop refits): larger
    # than the covariance of a fit with hstop held fixed; beta within 3 of it of Table 1
    fr = by[("flow_rule", 1.0)]
    assert fr.stderr_method.startswith("bootstrap")
    cond = fit_flow_rule(*(table.loc[table["run"].isin(fr.runs_used), c].to_numpy(float)
                           for c in ("theta", "h", "F")), dict(h1.params))
    assert fr.stderr["beta"] > cond.stderr["beta"]
    assert abs(fr.params["beta"] - 0.196) < 3 * fr.stderr["beta"]
    # selections are generated from what was used
    assert f"{len(fr.runs_used)} of " in fr.selection and "arrested" in fr.selection
    # an hstop fit says that one base realisation's scatter is not in its stderrs, with the
    # measured numbers (granflow.reference.BASE_REALISATION_EFFECT)
    assert ("single brackets move by up to 1.75 deg between bases" in h1.selection
            and "+0.05 ... +0.55 deg" in h1.selection
            and "standard deviation of 0.16 deg" in h1.selection), h1.selection
    # ... and that the scatter between bases is in them when the table's runs lie on several
    # (hstop_bisection.replicate_bases: the campaign table's base_seed column)
    # (one base per height here: a bracket's runs must lie on one base)
    several = table.assign(base_seed=1.0 + table["H"].rank(method="dense").astype(int) % 3)
    h1s = next(f for f in fit_campaign(several, n_bootstrap=10)
               if f.kind == "hstop" and f.coords.get("lam") == 1.0)
    assert "lie on 3 base realisations (base seeds 1, 2, 3" in h1s.selection, h1s.selection
    assert "random effect" in h1s.selection and "BASE_REALISATION_EFFECT" not in h1s.selection
    assert h1s.status != "failed" and h1s.extra["base_scatter"]["n_bases"] == 3
    # the library stores sigma_b beside the parameters (NaN where all brackets lie on one base)
    lib_s = gc.open_library(gc.write_library(tmp_path, "several", [h1s], several,
                                             reductions="synthetic"))
    var = lib_s["hstop_base_sigma_between"]
    assert var.attrs["units"] == "degree" and "random effect" in var.attrs["long_name"]
    assert float(var.sel(contact_law="linear", **{"lambda": 1.0})) == pytest.approx(
        h1s.extra["base_sigma_between"])
    # runs of one bracket on two bases are refused, by name
    mixed = table.assign(base_seed=1.0 + np.arange(len(table)) % 3)
    h1m = next(f for f in fit_campaign(mixed, n_bootstrap=10)
               if f.kind == "hstop" and f.coords.get("lam") == 1.0)
    assert h1m.status == "failed" and "lie on several bases" in h1m.message, h1m.message
    # lambda = 2/3 uses a constant alpha; mean of alpha = 1.201 + N(0, 0.02): within 3 SEM
    a23 = by[("alpha", 2.0 / 3.0)]
    assert abs(a23.params["alpha_constant"] - 1.201) < 3 * a23.stderr["alpha_constant"]
    lib = gc.open_library(gc.write_library(tmp_path, "campaign", fits, table,
                                           reductions="synthetic"))
    assert len(gc.campaign_table(lib)) == len(table)
    assert int(lib["campaign_used_by_flow_rule"].sum()) == len(by[("flow_rule", 1.0)].runs_used) \
        + len(by[("flow_rule", 2.0 / 3.0)].runs_used)
    # steady-flow identity through the stored, fitted closures: mu(h, F(h, theta)) = tan(theta)
    theta = np.array([22.0, 24.0, 26.0])
    h = np.array([20.0, 25.0, 30.0])
    F = gc.froude(lib, h, theta, 1.0)
    np.testing.assert_allclose(gc.mu(lib, h, F, 1.0), np.tan(np.radians(theta)), atol=1e-10)


def test_disordered_window_delta3_steps():
    """Eq. (48) at lambda = 1/2 as steps: 25.5 deg up to H = 10 (thinner layers too), 24.5 above;
    with no open last step, heights above the last H_max have no delta3."""
    from granflow.fitting import DisorderedWindow

    w = DisorderedWindow.from_config({"delta3": [{"H_max": 10.0, "theta": 25.5},
                                                 {"theta": 24.5}], "delta_acc": 29.0})
    np.testing.assert_array_equal(w.delta3_at([1.5, 10.0, 10.01, 40.0]),
                                  [25.5, 25.5, 24.5, 24.5])
    assert w.delta_acc == 29.0 and DisorderedWindow.from_config(w.to_config()) == w
    assert "25.5 deg for H <= 10, 24.5 deg for H > 10, delta_acc = 29" in w.describe()
    assert np.isnan(DisorderedWindow(((10.0, 25.5),)).delta3_at([12.0])[0])
    with pytest.raises(ValueError, match="H_max must increase"):
        DisorderedWindow(((10.0, 25.5), (5.0, 24.5)))
    with pytest.raises(ValueError, match=r"delta_acc 95.*\(0, 90\)"):
        DisorderedWindow((), 95.0)


def test_disordered_window_keeps_layered_and_thin_runs_out_of_the_steady_closures():
    """The paper's steady closures at lambda <= 2/3 hold only for delta3(H) < theta < delta_acc
    (Eq. 47, 50, §9.2).  A thin steady run just above its arrest (a bracket at H = 1.5) and a
    run above delta_acc, with values far off the closures, must leave the flow rule, alpha,
    density and K -- exactly as if they were not in the table -- and stay in the hstop
    brackets; without the window they enter (so the test can fail)."""
    table = synthetic_campaign(np.random.default_rng(7))
    lam = 2.0 / 3.0
    odd = [dict(theta=20.5, H=1.5, h=2.07, F=0.21, alpha=1.38, rho_c=0.50, K=0.80),
           dict(theta=29.5, H=20.0, h=18.0, F=9.0, alpha=1.10, rho_c=0.50, K=0.80)]
    records = table.to_dict("records")
    for k, o in enumerate(odd):
        records.append({**{c: np.nan for c in table.columns}, "lam": lam, "sigma": 1.0,
                        "contact_law": "linear", "state": "steady", "run": f"odd{k}", **o})
    from granflow.fitting import campaign_table_from_records

    with_odd = campaign_table_from_records(records)
    window = {lam: {"delta3": [{"H_max": 10.0, "theta": 22.0}, {"theta": 21.0}],
                    "delta_acc": 29.0}}
    kinds = ("flow_rule", "alpha", "density", "stress_ratio")

    def by(fits):
        return {f.kind: f for f in fits if f.kind in kinds and f.coords.get("lam") in (lam, None)
                } | {"hstop": next(f for f in fits if f.kind == "hstop"
                                    and f.coords.get("lam") == lam)}

    cut = by(fit_campaign(with_odd, windows=window, n_bootstrap=10, include_eq38=False))
    # the window also removes the synthetic grid's steady runs at or below 21/22 deg
    ref_table = with_odd[~with_odd["run"].isin(["odd0", "odd1"])]
    th, H, lam_col = (ref_table[c].to_numpy(float) for c in ("theta", "H", "lam"))
    d3 = np.where(H <= 10.0, 22.0, 21.0)
    keep = ~((np.abs(lam_col - lam) < 1e-9) & (ref_table["state"] == "steady").to_numpy()
             & (th <= d3))
    ref = by(fit_campaign(ref_table[keep], n_bootstrap=10, include_eq38=False))
    for kind in kinds:
        assert not {"odd0", "odd1"} & set(cut[kind].runs_used), kind
        for p, v in ref[kind].params.items():
            assert cut[kind].params[p] == pytest.approx(v, rel=1e-9, abs=1e-12, nan_ok=True), (kind, p)
        assert "at or below delta3 at lambda = 0.666667" in cut[kind].selection, cut[kind].selection
        assert "at or above delta_acc at lambda = 0.666667 (1 " not in cut[kind].selection
    assert "1 at or above delta_acc at lambda = 0.666667" in cut["flow_rule"].selection
    assert "odd0" in cut["hstop"].runs_used and "odd1" in cut["hstop"].runs_used
    plain = by(fit_campaign(with_odd, n_bootstrap=10, include_eq38=False))
    assert "odd0" in plain["alpha"].runs_used and "odd0" in plain["density"].runs_used


def test_steady_runs_still_creeping_are_named_in_the_selections():
    """A run called steady while its tail still trended (state_confidence < CREEP_CONFIDENCE,
    which the classifier's confidence = min(1, N_eff/50) min(1, p/0.2) ties to a tail-trend
    p below it) is named in the selection of every steady closure that used it; runs above the
    threshold, and tables without the column, give no such sentence."""
    from granflow.fitting.campaign import CREEP_CONFIDENCE, creeping_steady_runs

    table = synthetic_campaign(np.random.default_rng(7))
    steady = table.index[(table["state"] == "steady") & (table["lam"] == 1.0)
                         & np.isfinite(table["F"].to_numpy(float))]
    creep = list(table.loc[steady[[0, 3]], "run"])
    conf = np.where(table["run"].isin(creep), 0.5 * CREEP_CONFIDENCE, 0.9)
    # an arrested run with a low confidence is no steady call: never named
    conf[int(np.flatnonzero(table["state"] == "arrested")[0])] = 0.0
    flagged = table.assign(state_confidence=conf)
    assert creeping_steady_runs(flagged) == creep
    assert creeping_steady_runs(table) == []
    fits = {(f.kind, f.coords.get("lam")): f for f in fit_campaign(flagged, n_bootstrap=5)}
    for kind in ("flow_rule", "alpha", "density", "stress_ratio"):
        sel = fits[(kind, 1.0 if kind in ("flow_rule", "alpha") else None)].selection
        assert "2 of the used runs were called steady while their tail still trended" in sel, sel
        assert all(r in sel for r in creep), sel
    at_margin = flagged.assign(state_confidence=np.where(conf < 0.9, CREEP_CONFIDENCE, 0.9))
    fr = next(f for f in fit_campaign(at_margin, n_bootstrap=5)
              if f.kind == "flow_rule" and f.coords.get("lam") == 1.0)
    assert "still trended" not in fr.selection
