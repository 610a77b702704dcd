"""Hierarchical-grid neighbour search (issue 3; Ogarko & Luding 2012, seed §5.1).

Every test compares exact (pi, pj) arrays: against an O(N^2) numpy brute force with the
minimum image in x and y (same floating-point operations as the kernels' pair test) and against
the single-level ``kernels.neighbour_pairs`` (same order).
"""

import math

import numba
import numpy as np
import pytest

from granflow.engine.lib.hgrid import (SWITCH_RATIO, choose_neighbour_method,
                                       hgrid_neighbour_pairs, hgrid_pairs, make_levels)
from granflow.engine.lib.kernels import neighbour_pairs

SKIN = 0.2


def brute_pairs(pos, radius, fixed, Lx, Ly, skin):
    """All i < j, not both fixed, with minimum-image distance < r_i + r_j + skin, by (i, j)."""
    n = len(radius)
    out_i, out_j = [], []
    for a in range(0, n, 256):
        i = np.arange(a, min(n, a + 256))[:, None]
        j = np.arange(n)[None, :]
        dx = pos[i, 0] - pos[j, 0]
        dx = dx - Lx * np.rint(dx / Lx)
        dy = pos[i, 1] - pos[j, 1]
        dy = dy - Ly * np.rint(dy / Ly)
        dz = pos[i, 2] - pos[j, 2]
        rc = radius[i] + radius[j] + skin
        ok = (dx * dx + dy * dy + dz * dz < rc * rc) & (j > i) & ~(fixed[i] & fixed[j])
        ii, jj = np.nonzero(ok)
        out_i.append(ii + a)
        out_j.append(jj)
    return np.concatenate(out_i).astype(np.int64), np.concatenate(out_j).astype(np.int64)


def bidisperse(n, inv_sigma, phi, Lx, Ly, seed, d_small=None, frac_fixed=0.0, base=False):
    """Random bidisperse set at the number density of volume fraction ``phi``.

    Equal total volume of small and large spheres, d_large = 1.  Large spheres are placed first
    on a jittered cubic lattice, small ones uniformly (overlaps are irrelevant to the pair
    geometry being tested); the box height follows from ``phi``.  ``base`` adds a fixed rough
    layer at z ~ 0 (base-base pairs must be excluded).
    """
    rng = np.random.default_rng(seed)
    dl = 1.0
    ds = dl / inv_sigma if d_small is None else d_small
    vs, vl = math.pi / 6 * ds**3, math.pi / 6 * dl**3
    frac_s = 0.5 / vs / (0.5 / vs + 0.5 / vl) if inv_sigma != 1.0 else 1.0
    n_s = int(round(n * frac_s))
    n_l = n - n_s
    vol = (n_s * vs + n_l * vl) / phi
    Lz = vol / (Lx * Ly)
    # large: jittered lattice with ~n_l sites
    a = (Lx * Ly * Lz / max(n_l, 1)) ** (1 / 3)
    nx, ny = max(1, int(Lx / a)), max(1, int(Ly / a))
    nz = int(math.ceil(n_l / (nx * ny))) if n_l else 0
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"),
                 -1).reshape(-1, 3)[:n_l]
    large = (g + 0.5) * [Lx / nx, Ly / ny, Lz / max(nz, 1)] + rng.normal(0, 0.1, (n_l, 3))
    small = rng.uniform(0, 1, (n_s, 3)) * [Lx, Ly, Lz]
    pos = np.concatenate([large, small])
    radius = np.concatenate([np.full(n_l, dl / 2), np.full(n_s, ds / 2)])
    perm = rng.permutation(len(radius))
    pos, radius = pos[perm], radius[perm]
    fixed = rng.random(len(radius)) < frac_fixed
    if base:
        nb = int(Lx * Ly / (0.8 * ds) ** 2)
        bpos = rng.uniform(0, 1, (nb, 3)) * [Lx, Ly, 0.3 * ds]
        pos = np.concatenate([bpos, pos])
        radius = np.concatenate([np.full(nb, ds / 2), radius])
        fixed = np.concatenate([np.ones(nb, bool), fixed])
    pos[:, 0] %= Lx
    pos[:, 1] %= Ly
    return np.ascontiguousarray(pos), radius, fixed


def assert_same(a, b):
    assert a[0].dtype == np.int64 and a[1].dtype == np.int64
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def check(pos, radius, fixed, Lx, Ly, skin=SKIN, ratio=1.01, against_cells=True):
    level_of, level_cell = make_levels(radius, skin, ratio)
    got = hgrid_neighbour_pairs(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell)
    ref = brute_pairs(pos, radius, fixed, Lx, Ly, skin)
    assert len(ref[0]) > 0
    assert_same(got, ref)
    if against_cells:
        assert_same(got, neighbour_pairs(pos, radius, fixed, Lx, Ly, skin,
                                         2 * radius.max() + skin))
    return got, level_cell


@pytest.mark.parametrize("inv_sigma", [1.25, 2.0, 3.0, 5.0])
@pytest.mark.parametrize("phi", [0.55, 0.05])
def test_bidisperse_matches_brute_force_and_cells(inv_sigma, phi):
    n = 2500 if phi > 0.3 else 1200
    pos, radius, fixed = bidisperse(n, inv_sigma, phi, 8.0, 6.0, seed=int(10 * inv_sigma))
    _, cells = check(pos, radius, fixed, 8.0, 6.0)
    assert len(cells) == 2


@pytest.mark.parametrize("inv_sigma", [1.25, 2.0, 3.0, 5.0])
def test_fixed_particles_and_base(inv_sigma):
    pos, radius, fixed = bidisperse(1500, inv_sigma, 0.5, 6.0, 5.0, seed=3, frac_fixed=0.2,
                                    base=True)
    got, _ = check(pos, radius, fixed, 6.0, 5.0)
    assert not np.any(fixed[got[0]] & fixed[got[1]])
    assert np.any(fixed[got[0]] | fixed[got[1]])  # flow-base pairs are kept


@pytest.mark.parametrize("Lx,Ly", [(2.5, 1.5), (1.1, 7.0), (3.3, 2.3), (0.9, 0.7)])
def test_thin_periodic_boxes(Lx, Ly):
    """Coarse level with 1-2 cells across (offsets -1 and +1 are the same cell), and boxes
    thinner than the pair cutoff (several images within range: minimum image only)."""
    pos, radius, fixed = bidisperse(1200, 3.0, 0.5, Lx, Ly, seed=5, frac_fixed=0.1)
    check(pos, radius, fixed, Lx, Ly)


def test_tall_sparse_column_clamped_cells():
    """Particles spread far above the packing: the top z cells are clamped (still exact)."""
    pos, radius, fixed = bidisperse(1500, 5.0, 0.4, 6.0, 6.0, seed=7)
    rng = np.random.default_rng(8)
    k = rng.choice(len(radius), 200, replace=False)
    pos[k, 2] += rng.uniform(0, 400.0, 200)
    pos[k[:20], 2] = pos[k[20:40], 2] + 0.1  # some close pairs far up
    pos[k[:20], :2] = pos[k[20:40], :2]
    check(pos, radius, fixed, 6.0, 6.0)


def test_cell_faces_and_box_edges():
    """Positions exactly on cell faces, at 0, and slightly outside [0, L) (wrapped binning)."""
    Lx, Ly = 4.8, 3.6
    g = np.stack(np.meshgrid(np.arange(0, Lx, 0.3), np.arange(0, Ly, 0.3),
                             np.arange(0, 3.0, 0.3), indexing="ij"), -1).reshape(-1, 3)
    rng = np.random.default_rng(9)
    radius = np.where(rng.random(len(g)) < 0.15, 0.5, 0.1)
    pos = g.astype(float).copy()
    edge = rng.choice(len(g), 40, replace=False)
    pos[edge[:20], 0] = -1e-12
    pos[edge[20:], 1] = Ly - 1e-15
    got, _ = check(pos, radius, np.zeros(len(g), bool), Lx, Ly, against_cells=False)
    assert len(got[0]) > len(g)


def test_polydisperse_many_levels():
    rng = np.random.default_rng(11)
    n = 2500
    radius = 0.5 * np.exp(rng.uniform(np.log(0.2), 0.0, n))  # d in [0.2, 1]
    L = 9.0
    pos = rng.uniform(0, 1, (n, 3)) * [L, L, 6.0]
    fixed = rng.random(n) < 0.1
    _, cells = check(pos, radius, fixed, L, L, ratio=1.5)
    assert len(cells) == 4 and np.all(np.diff(cells) > 0)
    # every distinct size on its own level, and a single level, are exact too
    check(pos[:600], radius[:600], fixed[:600], L, L, ratio=1.0, against_cells=False)
    check(pos, radius, fixed, L, L, ratio=np.inf)


def test_independent_of_thread_count():
    pos, radius, fixed = bidisperse(2000, 3.0, 0.55, 7.0, 7.0, seed=13, frac_fixed=0.1)
    lo, lc = make_levels(radius, SKIN, 1.01)
    nt = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = hgrid_pairs(pos, radius, fixed, 7.0, 7.0, SKIN, lo, lc)
    finally:
        numba.set_num_threads(nt)
    assert_same(a, hgrid_pairs(pos, radius, fixed, 7.0, 7.0, SKIN, lo, lc))


def test_make_levels_bidisperse_and_cells():
    r = np.array([0.1, 0.5, 0.1, 0.5, 0.1])
    lo, lc = make_levels(r, 0.2, 1.5)
    assert lo.tolist() == [0, 1, 0, 1, 0]
    assert np.allclose(lc, [0.4, 1.2])
    lo, lc = make_levels(r, 0.2, 10.0)
    assert lo.tolist() == [0] * 5 and np.allclose(lc, [1.2])


def test_choose_neighbour_method():
    mono = np.full(1000, 0.5)
    method, info = choose_neighbour_method(mono, SKIN)
    assert method == "cells"
    assert info["cell_sizes"] == [pytest.approx(1.0 + SKIN)]
    assert np.all(info["level_of"] == 0)

    r = np.concatenate([np.full(10, 0.5), np.full(1000, 0.1)])
    method, info = choose_neighbour_method(r, SKIN)
    assert method == "hgrid"
    assert info["size_ratio"] == pytest.approx(5.0)
    assert info["cell_sizes"] == [pytest.approx(0.2 + SKIN), pytest.approx(1.0 + SKIN)]
    assert info["level_counts"] == [1000, 10]
    assert info["level_of"][:10].tolist() == [1] * 10

    # just below / at the switch
    r = np.array([0.5, 0.5 * 0.999 * SWITCH_RATIO])
    assert choose_neighbour_method(r, SKIN)[0] == "cells"
    r = np.array([0.5, 0.5 * SWITCH_RATIO])
    assert choose_neighbour_method(r, SKIN)[0] == "hgrid"
