"""Benchmark: cost of DepthProfileAccumulator.add_snapshot per flow particle.

Reports the minimum (least disturbed by other load on the machine) and the median over repeats.

Builds a synthetic chute snapshot (jittered dense packing of N flow particles in a 20 x 10 periodic
box on a fixed base layer, all pairs closer than one diameter listed as contacts, ~3 per
particle) and times add_snapshot for a few grid spacings and cutoffs.

    python benchmarks/bench_coarse.py [N ...]
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy.spatial import cKDTree

from granflow.coarse import DepthProfileAccumulator


def synthetic_snapshot(n_flow=3000, Lx=20.0, Ly=10.0, seed=0):
    """Snapshot dict with ~n_flow flow particles, a fixed base layer and contacts."""
    rng = np.random.default_rng(seed)
    a = 0.93  # lattice spacing < d so that neighbours overlap
    nx, ny = int(Lx / a), int(Ly / a)
    nlay = int(np.ceil(n_flow / (nx * ny)))
    gx, gy, gz = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nlay), indexing="ij")
    flow = np.stack([(gx.ravel() + 0.5) * Lx / nx, (gy.ravel() + 0.5) * Ly / ny,
                     0.9 + gz.ravel() * 0.85], axis=1)[:n_flow]
    flow += rng.normal(scale=0.05, size=flow.shape)
    bx, by = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    base = np.stack([(bx.ravel() + 0.25) * Lx / nx, (by.ravel() + 0.25) * Ly / ny,
                     rng.uniform(-0.3, 0.0, bx.size)], axis=1)
    pos = np.concatenate([flow, base])
    pos[:, 0] %= Lx
    pos[:, 1] %= Ly
    n = pos.shape[0]
    fixed = np.zeros(n, dtype=bool)
    fixed[n_flow:] = True
    zoff = pos[:, 2].min() - 1.0
    tree = cKDTree(pos - [0, 0, zoff], boxsize=[Lx, Ly, 1e6])
    pairs = tree.query_pairs(1.0, output_type="ndarray")
    pairs = pairs[~(fixed[pairs[:, 0]] & fixed[pairs[:, 1]])]
    swap = fixed[pairs[:, 0]]
    pairs[swap] = pairs[swap][:, ::-1]
    ci, cj = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
    rij = pos[ci] - pos[cj]
    rij[:, 0] -= Lx * np.round(rij[:, 0] / Lx)
    rij[:, 1] -= Ly * np.round(rij[:, 1] / Ly)
    dist = np.linalg.norm(rij, axis=1)
    nrm = rij / dist[:, None]
    force = nrm * (1.0 - dist)[:, None] * 1e3 + rng.normal(scale=1.0, size=rij.shape)
    return {
        "time": 0.0, "Lx": Lx, "Ly": Ly, "pos": pos,
        "vel": rng.normal(size=(n, 3)) + [1.0, 0, 0], "mass": np.ones(n),
        "diameter": np.ones(n), "species": np.zeros(n, dtype=np.int32), "fixed": fixed,
        "contact_i": ci, "contact_j": cj, "contact_force": force, "contact_rij": rij,
        "contact_point": pos[ci] - 0.5 * nrm,
    }


def bench(n_flow, dz, cutoff, repeats=200):
    snap = synthetic_snapshot(n_flow)
    zmax = snap["pos"][:, 2].max() + 2.0
    acc = DepthProfileAccumulator(-2.0, zmax, dz, width=0.25, Lx=snap["Lx"], Ly=snap["Ly"],
                                  window_length=10.0, cutoff=cutoff)
    args = [snap[k] for k in ("pos", "vel", "mass", "diameter", "species", "fixed", "contact_i",
                              "contact_j", "contact_force", "contact_rij", "contact_point")]
    acc.add_snapshot(0.0, *args)  # compile / warm up
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        acc.add_snapshot(0.0025 * (r + 1), *args)
        times.append(time.perf_counter() - t0)
    best, med = min(times), float(np.median(times))
    m = snap["contact_i"].size
    print(f"N_flow={n_flow:5d} contacts/particle={2 * m / n_flow:4.2f} dz={dz:5.3f} "
          f"cutoff={cutoff:.0f}w nz={acc.nz:4d}: min {best * 1e3:6.3f} ms/snapshot "
          f"({best / n_flow * 1e9:5.0f} ns/particle), median {med / n_flow * 1e9:5.0f} ns/particle")


if __name__ == "__main__":
    sizes = [int(a) for a in sys.argv[1:]] or [2000, 5000]
    for n in sizes:
        for dz, cut in ((0.05, 4.0), (0.1, 4.0), (0.05, 3.0), (0.02, 4.0)):
            bench(n, dz, cut)
