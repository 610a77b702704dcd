"""hstop bisection chains (granflow.steady.bisection) on a known demarcation, and the monitor's
"decisively flowing" stop for bracket runs."""

import math

import numpy as np
import pytest

from granflow.campaign import hstop as HS
from granflow.fitting import theta_stop_eq45
from granflow.steady.bisection import Bisection
from granflow.steady.monitor import SteadyStateMonitor

TRUE = dict(delta1=17.708, delta2=32.780, A=3.355)  # Weinhart et al. 2012 Table 1, lambda = 1


def _drive(b, threshold):
    while (t := b.next_point()) is not None:
        b.record(t, "arrested" if t < threshold else "steady")
    return b


@pytest.mark.parametrize("offset", [-3.3, -0.4, 0.0, 0.7, 4.1])
def test_bisection_brackets_the_demarcation_within_tolerance(offset):
    """Whatever the prior's error (offset of the true threshold from the first guess, up to 4
    degrees), the chain ends with arrested < threshold <= flowing, at most `tolerance` wide, in
    at most 2 + log2(step / tolerance) + log2(|offset| / step) + 2 runs."""
    H = 6.0
    guess = float(theta_stop_eq45(H, **TRUE))
    thr = guess + offset
    b = _drive(Bisection(H, guess, step=1.0, tolerance=0.25, max_runs=12), thr)
    _, lo, hi, ok = b.interval()
    assert ok and lo < thr <= hi and hi - lo <= 0.25 + 1e-9, (lo, hi, b.runs)
    assert len(b.runs) <= 2 + math.ceil(math.log2(1 / 0.25)) + \
        max(0, math.ceil(math.log2(max(abs(offset), 1.0)))) + 2
    # the state survives a JSON-like round trip exactly, including what comes next
    again = Bisection.from_state_dict(b.state_dict())
    assert again.runs == b.runs and again.next_point() is None


def test_bisection_stops_on_contradicting_outcomes_and_on_max_runs():
    b = Bisection(4.0, 25.0, step=1.0, tolerance=0.1, max_runs=10)
    b.record(25.0, "steady")
    b.record(24.0, "arrested")
    b.record(24.5, "steady")
    b.record(24.25, "arrested")
    b.record(24.4, "arrested")  # noise: arrested above ...
    b.record(24.3, "steady")    # ... a flowing angle
    assert not b.consistent and b.next_point() is None and "monotonicity" in b.note
    _, lo, hi, ok = b.interval()
    assert (lo, hi, ok) == (24.3, 24.4, False)
    capped = _drive(Bisection(4.0, 25.0, step=1.0, tolerance=0.01, max_runs=3), 24.1)
    assert len(capped.runs) == 3 and "max_runs" in capped.note


def test_chain_state_machine_proposes_bracket_runs(tmp_path):
    import json

    cfg = {"prior": TRUE, "step": 1.0, "tolerance": 0.5, "max_runs": 6}
    st = HS.init_bisection("linear", 1.0, 4.0, cfg)
    thr = float(theta_stop_eq45(4.0, **TRUE)) + 0.8
    n = 0
    while (p := HS.bisection_next_point(st)) is not None:
        assert p.kind == "bracket" and p.path.startswith("bracket/linear/lambda~1/theta~")
        summ = tmp_path / f"s{n}.json"
        summ.write_text(json.dumps({"flow_state": "arrested" if p.theta < thr else "flowing"}))
        st = HS.bisection_step(st, summ, p.path)
        n += 1
    runs = HS.bisection_runs(st)
    assert len(runs) == n and st["bisection"]["next"] is None
    from granflow.campaign.grid import run_params

    params = run_params({"campaigns": {"chute": {"Lx": 10.0, "Ly": 5.0}}}, runs[0])
    assert params["stop_when_flowing"] is True and params["H"] == 4.0
    # replicate chain k: the same height, bracket runs with insertion seed + k
    rep = HS.init_bisection("linear", 1.0, 4.0, cfg, replicate=2)
    p = HS.bisection_next_point(rep)
    assert p.path.endswith("/H~4/seed~2") and p.replicate == 2
    assert run_params({"numerics": {"seed": 5}, "campaigns": {"chute": {}}}, p)["seed"] == 7


def test_engine_stop_before_any_flow_state_stops_the_chain_and_enters_no_bracket(tmp_path):
    """A bracket run that the engine's overlap guard ends while the layer still falls in (no
    flow state yet: measured on soft t_c = 0.02 layers of H = 20, stopped at t = 6.7-8.1) is no
    evidence: the chain records it as failed and stops, instead of counting it as flowing and
    walking down (it had reached 7.28 deg, and the hstop fit's delta1 went to 0).  A run the
    guard stops after it was seen flowing still counts as flowing (a fast flow on a fine base)."""
    import json

    cfg = {"prior": TRUE, "step": 1.0, "tolerance": 0.5, "max_runs": 6}
    st = HS.init_bisection("linear", 1.0, 20.0, cfg)
    p = HS.bisection_next_point(st)
    fall = {"flow_state": "undecided", "engine_stop": "overlap 0.0512 exceeds 5% ...",
            "flow_state_before_engine_stop": "undecided"}
    (tmp_path / "a.json").write_text(json.dumps(fall))
    st = HS.bisection_step(st, tmp_path / "a.json", p.path)
    assert st["last"]["flow_state"] == "failed" and st["bisection"]["next"] is None
    assert "before it had a flow state" in st["bisection"]["note"]
    b = Bisection.from_state_dict(st["bisection"])
    assert (b.theta_arrested, b.theta_flowing) == (-math.inf, math.inf)
    # an older summary without the field: the state named in the classification decides
    old = {"flow_state": "undecided", "engine_stop": "overlap",
           "classification": "undecided: the engine stopped the run at t = 8 (overlap); until "
                             "then the classifier said undecided: too few samples"}
    seen = dict(old, classification=old["classification"].replace(
        "said undecided: too few samples", "said accelerating: ratio grows"))
    for summ, expect in ((old, "failed"), (seen, "undecided"),
                         (dict(fall, flow_state_before_engine_stop="steady"), "undecided")):
        st = HS.init_bisection("linear", 1.0, 20.0, cfg)
        (tmp_path / "b.json").write_text(json.dumps(summ))
        st = HS.bisection_step(st, tmp_path / "b.json", HS.bisection_next_point(st).path)
        assert st["last"]["flow_state"] == expect
        if expect != "failed":  # flowing: the chain steps down
            assert st["bisection"]["next"] < p.theta


def test_hstop_intervals_leave_out_runs_without_a_flow_state():
    """Campaign-table rows stopped by an engine guard before any flow state are left out of
    the hstop brackets; an engine stop after the run was seen flowing stays flowing."""
    import pandas as pd

    from granflow.fitting.hstop import ENGINE_STOP_NO_STATE, hstop_intervals_from_runs

    t = pd.DataFrame({"theta": [22.0, 23.0, 7.28, 28.0], "H": [20.0] * 4,
                      "state": ["arrested", "steady", "undecided", "undecided"],
                      "stop_reason": ["arrested", "steady", ENGINE_STOP_NO_STATE,
                                      "engine guard"]})
    iv = hstop_intervals_from_runs(t)
    assert (iv.theta_arrested_max[0], iv.theta_flowing_min[0]) == (22.0, 23.0)
    iv2 = hstop_intervals_from_runs(t.assign(stop_reason="engine guard"))
    # counting it as flowing would invert the bracket into [7.28, 22]
    assert (iv2.theta_arrested_max[0], iv2.theta_flowing_min[0], iv2.inverted[0]) == \
        (7.28, 22.0, True)


def _feed(mon, t, ratio):
    for ti, ri in zip(t, ratio):
        mon.update(ti, ri, 1.0, 1.0)
    return mon.decision()


def test_monitor_stops_a_bracket_run_once_it_is_decisively_flowing():
    """A steady flow (flat ratio 1e3 after a short spin-up): with stop_when_flowing the run
    stops as "flowing" long before the steady stop that needs the averaging time; without it
    it waits for onset + averaging_time.  An arresting run is unaffected."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 400.0, 0.5)
    ratio = 1e3 * (1 - np.exp(-t / 10.0)) * (1 + 0.05 * rng.normal(size=t.size)) + 1e-3
    kw = dict(t_cap=400.0, averaging_time=100.0, check_every=10.0, min_onset=20.0)
    fast = _feed(SteadyStateMonitor(stop_when_flowing=True, **kw), t, ratio)
    slow = _feed(SteadyStateMonitor(**kw), t, ratio)
    assert fast.stop and fast.reason == "flowing"
    assert slow.stop and slow.reason == "steady"
    assert fast.t < slow.t - 50.0
    decay = 1e2 * np.exp(-t / 5.0)
    arr = _feed(SteadyStateMonitor(stop_when_flowing=True, **kw), t, decay)
    assert arr.stop and arr.reason == "arrested"
    # the decision survives a checkpoint exactly
    mon = SteadyStateMonitor(stop_when_flowing=True, **kw)
    half = t.size // 3
    _feed(mon, t[:half], ratio[:half])
    back = SteadyStateMonitor.from_state_dict(mon.state_dict())
    assert _feed(back, t[half:], ratio[half:]) == _feed(mon, t[half:], ratio[half:])
