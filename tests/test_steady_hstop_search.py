"""Tests of granflow.steady.hstop_search against a synthetic h_stop(theta) truth."""

import math

import pytest

from granflow.steady.hstop_search import HstopSearch, is_flowing, run_hstop_search
from granflow.steady.classify import FlowClassification

# Table 1 (lambda = 1) values, used only as a synthetic truth
D1, D2, A = 17.708, 32.780, 3.355


def hstop(theta, d1=D1, d2=D2, a=A):
    if theta <= d1:
        return math.inf
    t = math.tan(math.radians(theta))
    return a * (math.tan(math.radians(d2)) - t) / (t - math.tan(math.radians(d1)))


def theta_true(H, d1=D1, d2=D2, a=A):
    """Inverse of Eq. (45): the angle with hstop(theta) = H."""
    t1, t2 = math.tan(math.radians(d1)), math.tan(math.radians(d2))
    return math.degrees(math.atan((a * t2 + H * t1) / (H + a)))


def truth_run(theta, H):
    return "steady" if hstop(theta) <= H else "arrested"


def test_inverse_truth():
    for H in (4, 10, 40):
        assert hstop(theta_true(H)) == pytest.approx(H, rel=1e-10)


def test_intervals_bracket_truth_lambda1():
    s = run_hstop_search(truth_run)
    ivs = s.intervals()
    assert s.done and s.done_reason.startswith("H_max")
    assert len(ivs) == len({H for _, H, _ in s.runs}) >= 15
    assert ivs[0][0] == 4.0
    for H, ta, tf in ivs:
        assert ta < theta_true(H) <= tf
        assert 0.0 < tf - ta <= 1.0 + 1e-12
    # the first-flowing search at H = 4 walks up from 21 in 1-degree steps
    assert [r[0] for r in s.runs[:6]] == [21, 22, 23, 24, 25, 26]
    assert s.runs[5][2] and not any(r[2] for r in s.runs[:5])
    # theta_true(4) = 25.05: bracketed to half a degree after the first downward step
    assert ivs[0][1:] == (25.0, 25.5)
    # (25, 4) was already simulated on the way up: the walk does not repeat it
    assert (25.0, 4.0, False) in s.inferred
    assert len(s.runs) == len(set((t, h) for t, h, _ in s.runs))


@pytest.mark.parametrize("params", [(17.913, 21.357, 11.959), (17.217, 24.302, 11.088),
                                    (17.518, 29.712, 5.290)])
def test_intervals_bracket_truth_other_roughness(params):
    d1, d2, a = params
    s = run_hstop_search(lambda th, H: "arrested" if hstop(th, d1, d2, a) > H else "accelerating",
                         H_max=30)
    ivs = s.intervals()
    assert ivs
    for H, ta, tf in ivs:
        assert ta < theta_true(H, d1, d2, a) <= tf
        assert tf - ta <= 1.0 + 1e-12


def test_state_machine_steps_and_errors():
    s = HstopSearch()
    assert s.next_point() == (21.0, 4.0)
    with pytest.raises(ValueError):
        s.record(22.0, 4.0, "arrested")
    assert s.record(21.0, 4.0, "arrested") == (22.0, 4.0)  # up phase: theta + 1
    assert s.record(22.0, 4.0, "steady") == (21.5, 4.0)  # flowing: theta - 0.5
    assert s.record(21.5, 4.0, "arrested") == (21.5, 6.0)  # arrested: H + 2
    assert s.record(21.5, 6.0, FlowClassification("oscillating", None, 1.0)) == (21.0, 6.0)
    # H = 4 is bracketed; H = 6 only from above (flowing at 21.5, nothing arrested at H >= 6 yet)
    assert s.intervals() == [(4.0, 21.5, 22.0)]
    assert s.interval_objects()[1].theta_flowing == 21.5
    assert math.isnan(s.interval_objects()[1].theta_arrested)


def test_termination_and_round_trip():
    s = HstopSearch(theta_max=23.0)
    for theta in (21.0, 22.0, 23.0):
        s.record(theta, 4.0, "arrested")
    assert s.done and "theta_max" in s.done_reason and s.next_point() is None
    with pytest.raises(RuntimeError):
        s.record(24.0, 4.0, "steady")

    s = HstopSearch(max_runs=7)
    while (p := s.next_point()) is not None:
        s.record(*p, truth_run(*p))
    assert len(s.runs) == 7 and "max_runs" in s.done_reason

    a = HstopSearch()
    for _ in range(9):
        a.record(*a.next_point(), truth_run(*a.next_point()))
    b = HstopSearch.from_state_dict(a.state_dict())
    while (p := a.next_point()) is not None:
        assert b.next_point() == p
        a.record(*p, truth_run(*p))
        b.record(*p, truth_run(*p))
    assert a.intervals() == b.intervals()


def test_noisy_run_is_flagged_inconsistent():
    s = HstopSearch()
    outcomes = {(21.0, 4.0): "arrested", (22.0, 4.0): "steady", (21.5, 4.0): "steady"}
    for _ in range(3):
        p = s.next_point()
        s.record(*p, outcomes[p])
    # (21.0, 4.0) is implied arrested by the first run -> skipped; the walk goes to (21.0, 6.0)
    assert s.next_point() == (21.0, 6.0)
    s.record(21.0, 6.0, "steady")
    assert s.next_point() == (20.5, 6.0)
    s.record(20.5, 6.0, "arrested")
    assert s.next_point() == (20.5, 8.0)
    s.record(20.5, 8.0, "arrested")
    s.record(*s.next_point(), "arrested")  # (20.5, 10)
    objs = {iv.H: iv for iv in s.interval_objects()}
    assert objs[6.0].consistent and objs[6.0].as_tuple() == (6.0, 20.5, 21.0)
    # arrested at a larger angle on a thicker layer than a flowing run contradicts monotonicity
    bad = HstopSearch(skip_implied=False)
    bad.runs = [(22.0, 4.0, True), (23.0, 6.0, False)]
    assert not bad.interval_objects()[0].consistent
    assert bad.intervals() == []
    assert len(bad.intervals(complete_only=False)) == 2


def test_is_flowing():
    assert not is_flowing("arrested") and not is_flowing("Arrested ")
    for st in ("steady", "accelerating", "layered", "oscillating", "undecided"):
        assert is_flowing(st)
    assert is_flowing(True) and not is_flowing(False)
    with pytest.raises(TypeError):
        is_flowing(3)


def test_a_run_without_a_flow_state_ends_the_walk_and_enters_no_interval(tmp_path):
    """A run that an engine guard stopped before it had any flow state (an impact while the
    layer fell in) is no evidence: the paper's walk ends there, without recording it, instead
    of taking it as flowing and stepping the angle down (issue 14, as the bisection chains)."""
    import json

    from granflow.campaign import hstop as HS

    s = HstopSearch()
    s.record(21.0, 4.0, "arrested")
    s.record(22.0, 4.0, "steady")
    s.record(21.5, 4.0, "arrested")
    with pytest.raises(ValueError):
        s.record_failed(30.0, 6.0)
    s.record_failed(21.5, 6.0, "overlap")
    assert s.done and s.next_point() is None and "no flow state (overlap)" in s.done_reason
    assert len(s.runs) == 3 and s.intervals() == [(4.0, 21.5, 22.0)]
    again = HstopSearch.from_state_dict(s.state_dict())
    assert again.done and again.done_reason == s.done_reason
    # through the campaign's step: the summary's engine stop decides
    st = HS.init_state("linear", 1.0, {})
    for th, state in ((21.0, "arrested"), (22.0, "steady")):
        (tmp_path / "s.json").write_text(json.dumps({"flow_state": state}))
        st = HS.step_state(st, tmp_path / "s.json")
    (tmp_path / "s.json").write_text(json.dumps({
        "flow_state": "undecided", "engine_stop": "overlap 0.05",
        "flow_state_before_engine_stop": "undecided"}))
    st = HS.step_state(st, tmp_path / "s.json")
    assert st["last"]["flow_state"] == "failed" and HS.next_point(st) is None
    assert len(HS.search_runs(st)) == 2
