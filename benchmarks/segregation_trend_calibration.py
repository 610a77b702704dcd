"""Not a timing: how often the campaign's "Ps still moving" rule flags a segregated state that
is steady, and whether a flag says which side the steady Ps lies on (issue 14's trust question
for the per-run Ps of the segregation closures).

A run whose small particles' centre of mass was shown steady is still counted as drifting
when the linear trend of Ps over its profile windows is significant and larger than a
tolerance (:func:`granflow.campaign.collect.ps_still_moving`); its Ps then becomes a one-sided
bound on the steady value, on the side the trend points to.  This script replays that rule on
the per-window Ps series of long runs (``benchmarks/segregation_approach.py RUN --json OUT``):
every stretch of ``n`` consecutive windows (``--windows``, a profile window's worth) is one
would-be profile window; the stretches starting at or after ``--t-from`` (the steady tail,
known steady because its later means agree with its earlier ones) should be flagged in about
5 % of cases at most, and a flag should point towards the tail's long mean (else the bound it
makes is a coin flip).  ``--t-to`` instead keeps the stretches *before* that time: an approach,
where flags are wanted and should all point towards the plateau (the mean after ``--t-from``).

Each series is given as ``FILE:T_FROM:N`` (N: the run's number of flow particles, which sets
the wander tolerance :func:`granflow.campaign.collect.ps_trend_tolerance`).  Two rules are
replayed: ``5 %`` (the rule before 2026-12-08: trend p < PS_TREND_P and change > 5 %) and
``wander`` (today's: change also > PS_TREND_WANDER_MULTIPLE x C / sqrt(N)).

    .venv/bin/python benchmarks/segregation_approach.py RUN --json w.json [--parent P]
    .venv/bin/python benchmarks/segregation_trend_calibration.py w.json:1000:346 [...]
        [--windows 4 6 10] [--approach-to 900]

Prints one line per series and window count: stretches, flags of each rule and the fraction
of flags pointing towards the long mean; then the pooled rates.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np


def replay(t_start, Ps, *, n_flow: float, t_from: float, windows=(4, 6, 10),
           t_to: float | None = None) -> dict:
    """Replay both rules on every stretch of ``n`` consecutive windows.

    Steady tail (``t_to`` None): stretches whose windows all start at or after ``t_from``.
    Approach (``t_to`` given): stretches whose windows all start before ``t_to``; the long mean
    is still the mean of the windows from ``t_from`` on.  Returns n -> dict(stretches, flags_5,
    flags_wander, toward_5, toward_wander: flags pointing towards the long mean), and the long
    mean under ``"mean"``."""
    from granflow.campaign.collect import ps_still_moving, ps_trend_tolerance
    from granflow.fitting.segregation import wander_sd
    from granflow.steady.timeseries import trend_test

    t_start, Ps = np.asarray(t_start, dtype=float), np.asarray(Ps, dtype=float)
    ok = np.isfinite(Ps) & np.isfinite(t_start)
    t_start, Ps = t_start[ok], Ps[ok]
    tail = t_start >= t_from
    if tail.sum() < 4:
        raise ValueError(f"{int(tail.sum())} windows start at or after t_from = {t_from:g}: "
                         "allowed a t_from that leaves at least 4")
    if not (n_flow > 0):
        raise ValueError(f"n_flow must be a positive number of particles, got {n_flow}")
    mean = float(Ps[tail].mean())
    keep = tail if t_to is None else t_start < t_to
    t, x = t_start[keep], Ps[keep]
    out = {"mean": mean}
    for n in windows:
        if n < 4:
            raise ValueError(f"windows = {n}: allowed 4 or more (the campaign tests no trend "
                             "over fewer)")
        rows = []
        for i in range(0, x.size - n + 1):
            tr = trend_test(x[i:i + n], t[i:i + n])
            m = float(x[i:i + n].mean())
            toward = bool(np.sign(tr.relative_change) == np.sign(mean - m))
            extra = {"Ps_trend_change": tr.relative_change, "Ps_trend_p": tr.p_value}
            old = ps_still_moving(extra)  # no tolerance in it: the 5 % rule
            new = ps_still_moving(dict(extra, Ps_trend_tolerance=ps_trend_tolerance(
                m, wander_sd(m, n_flow))))
            rows.append((old, new, toward))
        a = np.array(rows, dtype=bool).reshape(-1, 3)
        out[n] = {"stretches": int(a.shape[0]), "flags_5": int(a[:, 0].sum()),
                  "flags_wander": int(a[:, 1].sum()),
                  "toward_5": int((a[:, 0] & a[:, 2]).sum()),
                  "toward_wander": int((a[:, 1] & a[:, 2]).sum())}
    return out


def _parse(spec: str):
    try:
        path, t_from, n = spec.rsplit(":", 2)
        return path, float(t_from), float(n)
    except ValueError:
        raise argparse.ArgumentTypeError(f"series {spec!r}: expected FILE:T_FROM:N (N the "
                                         "run's number of flow particles)") from None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("series", nargs="+", type=_parse,
                    help="FILE:T_FROM:N, FILE a segregation_approach.py --json output")
    ap.add_argument("--windows", type=int, nargs="+", default=[4, 6, 10],
                    help="windows per stretch (a profile window's worth; 4 or more)")
    ap.add_argument("--approach-to", type=float, default=None,
                    help="replay on the stretches before this time (the approach) instead")
    args = ap.parse_args(argv)
    pooled = {}
    for path, t_from, n_flow in args.series:
        w = json.load(open(path))
        ws = w["windows"]
        try:
            r = replay(ws["t_start"], ws["Ps"], n_flow=n_flow, t_from=t_from,
                       windows=args.windows, t_to=args.approach_to)
        except ValueError as exc:
            ap.error(f"{path}: {exc}")
        for n in args.windows:
            c = r[n]
            p = pooled.setdefault(n, dict.fromkeys(c, 0))
            for k, v in c.items():
                p[k] += v
            print(f"{path} (N {n_flow:g}, long mean {r['mean']:.3f}) n = {n:2d}: "
                  f"{c['stretches']:3d} stretches; 5 % rule {c['flags_5']:3d} flags "
                  f"({c['flags_5'] / c['stretches']:.2f}; {c['toward_5']} towards the mean), "
                  f"wander rule {c['flags_wander']:3d} "
                  f"({c['flags_wander'] / c['stretches']:.2f}; {c['toward_wander']} towards)")
    for n, c in pooled.items():
        s = max(c["stretches"], 1)
        print(f"pooled n = {n:2d}: {c['stretches']} stretches; 5 % rule "
              f"{c['flags_5'] / s:.3f} flagged ({c['toward_5']}/{c['flags_5']} towards); "
              f"wander rule {c['flags_wander'] / s:.3f} ({c['toward_wander']}/"
              f"{c['flags_wander']} towards)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
