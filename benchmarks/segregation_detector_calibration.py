"""Not a timing: how often the segregation steady detector calls a run steady *early*, on
indicator series with known answers (issue 14's trust question for the segregation closures).

For each case and seed an indicator s(t) with a known plateau is drawn (the true relaxation
plus AR(1) noise), the detector (:func:`granflow.steady.segregation.segregation_steadiness`,
this code's rule) is applied every 50 time units as a run's monitor would, and at its first
steady verdict the change truly still to come, |s_inf - s_true(t)|, is set against the
tolerance the detector applied (``SEGREGATION_REL_TOL`` x total + ``SEGREGATION_ABS_TOL``).
A verdict with more to come than the tolerance is *early*.  The one-sided 95 % bound of the
projection aims at an early rate of 5 % or less.

Cases (the series of ``tests/test_steady_segregation.py``):

* ``mixed``: 0 -> -4 as exp(-t / 300) (a mixed start: what campaigns run), AR(1) noise 0.03;
* ``stretched``: 0 -> -4 as exp(-(t / 300)^0.7) (a slower-than-exponential approach, as at the
  paper's set-up), same noise;
* ``above``: -4.25 - 0.3 exp(-t / 20) + 0.2 (1 - exp(-t / 500)), AR(1) noise 0.04 (a start above
  the steady state: a fast rearrangement, then a slow relaxation the other way; the module's
  known limitation).

    .venv/bin/python benchmarks/segregation_detector_calibration.py mixed above --seeds 20

Prints one line per seed (first steady time, change to come, tolerance, early or not; "never"
when the series ends first) and per case the early and never counts.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

CASES = {
    # name: (t_end, dt, min_onset, AR(1) phi, noise, s_inf, true(t))
    "mixed": (2500.0, 2.0, 20.0, math.exp(-0.2), 0.03, -4.0,
              lambda t: -4.0 * (1.0 - np.exp(-t / 300.0))),
    "stretched": (4400.0, 2.0, 20.0, math.exp(-0.2), 0.03, -4.0,
                  lambda t: -4.0 * (1.0 - np.exp(-(t / 300.0) ** 0.7))),
    "above": (1500.0, 1.0, 34.0, math.exp(-0.5), 0.04, -4.05,
              lambda t: -4.25 - 0.3 * np.exp(-t / 20.0) + 0.2 * (1.0 - np.exp(-t / 500.0))),
}


def first_verdict(case: str, seed: int, check_every: float = 50.0,
                  averaging_time: float = 200.0) -> dict:
    """The detector's first steady verdict on one known-answer series (seed ``1000 + seed``)."""
    from granflow.steady.segregation import (SEGREGATION_ABS_TOL, SEGREGATION_REL_TOL,
                                             segregation_steadiness)
    from granflow.steady.timeseries import ar1_noise

    t_end, dt, min_onset, phi, noise, s_inf, true_of = CASES[case]
    rng = np.random.default_rng(1000 + seed)
    t = np.arange(0.0, t_end, dt)
    true = true_of(t)
    s = true + ar1_noise(t.size, rng, phi, noise)
    for end in np.arange(250.0, t_end, check_every):
        k = t <= end
        st = segregation_steadiness(t[k], s[k], averaging_time=averaging_time,
                                    min_onset=min_onset)
        if st.steady:
            to_come = abs(s_inf - float(true[k][-1]))
            tol = SEGREGATION_REL_TOL * abs(st.total) + SEGREGATION_ABS_TOL
            return {"case": case, "seed": seed, "t": float(end), "to_come": to_come,
                    "tolerance": tol, "early": bool(to_come > tol)}
    return {"case": case, "seed": seed, "t": math.nan, "to_come": math.nan,
            "tolerance": math.nan, "early": False}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="+", choices=sorted(CASES))
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args(argv)
    summary = {}
    for case in args.cases:
        rows = [first_verdict(case, seed) for seed in range(args.seeds)]
        for r in rows:
            if math.isnan(r["t"]):
                print(f"{case:10s} seed {r['seed']:3d}  never steady")
            else:
                print(f"{case:10s} seed {r['seed']:3d}  steady at t = {r['t']:6.0f}  to come "
                      f"{r['to_come']:.4f}  tolerance {r['tolerance']:.4f}"
                      f"{'  EARLY' if r['early'] else ''}")
        early = sum(r["early"] for r in rows)
        never = sum(math.isnan(r["t"]) for r in rows)
        summary[case] = (early, never, len(rows))
        print(f"{case}: {early} of {len(rows)} seeds called steady early, {never} never steady "
              f"before the series ends")
    return summary


if __name__ == "__main__":
    main()
