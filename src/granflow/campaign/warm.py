"""Compile-warm job: compile a campaign's simulation kernels once, beside the base preparation.

numba compiles the engine, coarse-graining and observer kernels on their first call and keeps
them in its on-disk cache (:mod:`granflow.engine.lib._cache`).  On a fresh clone every job that
starts before the cache holds them compiles them itself: measured on the default campaign at
845f018 (2 cores), the base job compiled for ~100 s with the second core idle, and then the two
first simulate jobs compiled the same kernels side by side for ~90 s each.  This job runs
one tiny run per distinct (kind, contact law) of the campaign -- the campaign's own parameters
with a few hundred time steps on a lattice base -- so that its compile
overlaps the base job's and every simulate job finds the kernels cached.

No physics here and nothing the closures use: the tiny runs are written to a scratch folder
that is removed; only the flag file (what was compiled, how long it took) is kept.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path

#: simulated time of each warm-up run (a few hundred steps: every kernel of the run loop,
#: the coarse-graining and the monitor are called at least once)
WARM_T_END = 0.05


def warm_runs(config: dict) -> list:
    """One run point per distinct (kind, contact law) of the campaign's grid (the thinnest)."""
    from .grid import expand_runs

    first: dict = {}
    for p in sorted(expand_runs(config), key=lambda q: q.H):
        first.setdefault((p.kind, p.law), p)
    return list(first.values())


def warm_engine(config: dict, out, scratch=None) -> dict:
    """Run :func:`warm_runs` for ``WARM_T_END`` each (numba threads: 1) and write the record
    (JSON) atomically to ``out``.  Returns the record."""
    import numpy as np

    from ..provenance import atomic_write_bytes
    from ..simulate import simulate
    from .grid import run_params

    record = {"what": "numba compile-warm runs (no results kept)", "runs": []}
    tmp = Path(tempfile.mkdtemp(prefix="granflow-warm-", dir=scratch))
    try:
        for p in warm_runs(config):
            t0 = time.monotonic()
            params = run_params(config, p)
            if params.get("engine", "numba") != "numba":
                continue  # LAMMPS runs compile nothing of granflow's engine
            params.update(t_end=WARM_T_END, early_stop=False)
            # a square lattice of base particles at z = 0: the base preparation compiles
            # kernels of its own (the base job does that), not wanted here
            lam = max(p.lam, 1.0)
            gx, gy = np.meshgrid(np.arange(0.5 * lam, params["Lx"], lam),
                                 np.arange(0.5 * lam, params["Ly"], lam), indexing="ij")
            base = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
            if p.lam == 0.0:  # flat wall
                base = np.zeros((0, 3))
            base_file = tmp / f"base_{p.kind}_{p.law}.npy"
            np.save(base_file, base)
            simulate(params, tmp / f"{p.kind}_{p.law}", base_file=base_file, threads=1)
            record["runs"].append({"run": p.path, "seconds": round(time.monotonic() - t0, 1)})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    atomic_write_bytes(out, (json.dumps(record, indent=1) + "\n").encode())
    return record
