"""Hierarchical-grid neighbour search for polydisperse packings (Ogarko & Luding 2012).

Implements the multilevel contact detection of Ogarko & Luding (2012) as reviewed in Thornton,
Weinhart, Ogarko & Luding, "Multi-scale methods for multi-component granular materials", §5
"Collision detection" (§5 in both seed versions, 000 and 002): 5.1.1 mapping phase, 5.1.2
contact detection phase, and the two-level grid of §5.2 for bidisperse systems:

* **Levels** (§5.1.1, Eq. 22-24).  Particles are grouped by diameter into ``L`` levels ordered by
  increasing cell size; the cell size of level ``h`` is ``s_h = 2 r_max(h) + skin`` (the largest
  diameter of the level plus the Verlet skin), so that every particle is not larger than a cell of
  its level of insertion.  :func:`make_levels` groups the sorted diameters greedily: a level
  starts at its smallest diameter ``d0`` and takes every diameter below ``ratio * d0``.  For a
  bidisperse system with size ratio above ``ratio`` this is the seed's optimal choice — two
  levels whose cells match the two diameters (§5.2); for a continuous distribution the cell sizes
  grow geometrically by ``ratio``.
* **Same-level search** (§5.1.2 step 1): classical linked cells on the level's grid, half of the
  surrounding cells (each pair found once).
* **Cross-level search** (§5.1.2 steps 1-2, Eq. 25-26): a particle ``p`` of level ``H`` visits,
  on every finer level ``h < H``, the cells overlapping the box ``r_p +- alpha`` with
  ``alpha = r_p + r_max(h) + skin`` (the seed's ``a_p + s_h/2`` with the skin), skipping the
  cells of the box whose extent is farther than ``alpha`` from ``r_p`` (the box corners), so
  cross-level pairs are tested only from the larger to the smaller particle, each exactly once.
  The seed's AABB pre-test is replaced by exact early exits of the distance test (z first).

Geometry as in :func:`granflow.engine.lib.kernels.neighbour_pairs`: periodic in x and y on
``[0, Lx) x [0, Ly)`` with the minimum-image convention, open in z (cells indexed from the lowest
particle; the top cell is clamped, which merges cells monotonically and stays exact).  Periodic
directions with fewer than 3 cells on a level are handled by de-duplicating the cell offsets
(same-level search: offsets that are their own inverse modulo the cell count are searched from
both sides with an ``i < j`` filter; cross-level search: a box wider than the level visits each
cell once).  Cell searches are widened by a relative 1e-9 margin so that floating-point rounding
at cell faces can never lose a pair: the result is exact, the distance test is the one of
``neighbour_pairs`` (the same squared distance; the minimum image by comparison with L/2, see
:func:`_accept`).

Output: ``(pi, pj)`` int64 (uint32 from :func:`hgrid_pairs_u32`), all pairs ``i < j``, not both
fixed, with minimum-image distance ``< r_i + r_j + skin``, sorted by ``(i, j)`` — exactly the
arrays of ``neighbour_pairs``.  The pairs are found per particle in parallel (``prange`` over
the particles in cell order, on cell-ordered copies of the coordinates) in one pass that keeps
up to ``cap`` partners per particle (a second pass, with the exact counts, only if a particle
found more), then transposed to rows of the lower index with a serial counting sort and each
row sorted (``prange``), so the result does not depend on the number of threads.  With a single level this is the classical
linked-cell method with a half shell; it is itself ~1.3-1.8x faster than ``neighbour_pairs``
(full shell with a ``j > i`` filter), see ``benchmarks/bench_hgrid.py``.

Cold compilation of this module takes ~30-45 s on the 2-core development machine under load
(cached afterwards, ``cache=True``).

The automatic choice between the single-level cell list and this grid is
:func:`choose_neighbour_method`; the switch point was measured with
``benchmarks/bench_hgrid.py`` (see its docstring).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: Diameter ratio d_large / d_small from which a second level pays (measured, see
#: :func:`choose_neighbour_method`).  Also the growth factor of the level diameters.
SWITCH_RATIO = 1.5
#: Relative widening of cell sizes and search boxes against rounding at cell faces.
_REL_MARGIN = 1e-9


@njit(cache=True, inline="always")
def _min_image(dx, L):
    # identical to kernels._min_image (kept local to avoid a circular import once kernels uses
    # this module)
    return dx - L * np.rint(dx / L)


@njit(cache=True, inline="always")
def _wrap_select(dx, L):
    """Minimum image of a difference of two coordinates in [0, L), by two selects."""
    a = dx - L
    dx = a if dx > 0.5 * L else dx
    b = dx + L
    return b if dx < -0.5 * L else dx


# --------------------------------------------------------------------------------------------
# levels
# --------------------------------------------------------------------------------------------
def make_levels(radius, skin, ratio=SWITCH_RATIO):
    """Group particles into levels by diameter.

    Returns ``(level_of, level_cell)``: the level (int64, 0 = finest) of every particle and the
    cell size of every level, ``2 r_max(level) + skin``, increasing.  A level holds the diameters
    in ``[d0, ratio * d0)`` where ``d0`` is its smallest diameter; ``ratio <= 1`` puts every
    distinct diameter on its own level, ``ratio = inf`` gives a single level (the plain cell
    list).
    """
    radius = np.asarray(radius, dtype=np.float64)
    n = radius.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.array([float(skin)])
    d = 2.0 * radius
    order = np.argsort(d, kind="stable")
    ds = d[order]
    level_sorted = np.empty(n, dtype=np.int64)
    cells = []
    lev = 0
    d0 = ds[0]
    dmax = ds[0]
    for k in range(n):
        if ds[k] > d0 and ds[k] >= ratio * d0:
            cells.append(dmax + skin)
            lev += 1
            d0 = ds[k]
        dmax = ds[k]
        level_sorted[k] = lev
    cells.append(dmax + skin)
    level_of = np.empty(n, dtype=np.int64)
    level_of[order] = level_sorted
    return level_of, np.asarray(cells, dtype=np.float64)


def choose_neighbour_method(radius, skin=0.2, switch_ratio=SWITCH_RATIO):
    """Automatic choice of the neighbour search: ``("cells" | "hgrid", info)``.

    The hierarchical grid is used when the extreme diameter ratio ``d_max / d_min`` (= 1/sigma of
    the seed) is at least ``switch_ratio``; the levels are then those of
    :func:`make_levels` with ``ratio = switch_ratio``, so every level boundary is itself a size
    jump that pays.

    Switch point (measured with ``benchmarks/bench_hgrid.py``: bidisperse, equal volumes of
    both sizes, packing fraction 0.6 (random placement + overlap relaxation), d_small = 1,
    skin = 0.2 (engine default), periodic x/y, N = 50 000; warm numba; one thread, process CPU
    time, minimum over interleaved rounds; a shared 2-core machine at load 4-6, two runs A/B).
    S1 = time of this code with one level / with two levels (the seed's comparison); S = time
    of the existing ``kernels.neighbour_pairs`` / two levels::

        1/sigma   t_cells     t_1level    t_2level     S1          S
                  A / B ms    A / B ms    A / B ms     A / B       A / B
        1.0       186 / 112   108 / 87    100 / 85     1.07/1.03   1.86/1.32  (1 level: noise)
        1.25      206 / 143   133 / 118   137 / 122    0.96/0.97   1.50/1.17
        1.5       221 / 163   145 / 140   126 / 122    1.15/1.15   1.76/1.34
        2         237 / 203   168 / 152   103 / 100    1.64/1.52   2.31/2.03
        3         584 / 346   356 / 248   107 / 88     3.34/2.82   5.48/3.93
        5        1595 / 981   938 / 631    94 / 87     9.99/7.24   17.0/11.3

    Two threads (wall time; with other jobs on the 2 cores these are the least reliable):
    S1 = 0.87/0.78, 1.11/0.81, 1.37/1.05, 2.91/2.48, 8.85/6.88 and S = 1.36/1.38, 1.66/1.22,
    1.99/1.81, 3.74/3.91, 24.1/15.3 at 1/sigma = 1.25, 1.5, 2, 3, 5.  The second level pays
    from between 1.25 and 1.5 on (one thread); the seed (Ogarko & Luding, Fig. 6) finds
    break-even at 1/sigma ~ 1.43, up to 40 % slower below, 22x at 1/sigma = 5 for
    N = 768 000 without a skin (the skin shrinks the gain: the small cells are 1.2 d_small, not
    d_small).  Hence ``SWITCH_RATIO = 1.5``.  Below the switch the one-level grid of this
    module (``make_levels(..., ratio=inf)`` + :func:`hgrid_pairs`) is still 1.2-1.8x faster
    than ``neighbour_pairs``.

    ``info``: ``size_ratio`` (d_max / d_min), ``cell_sizes`` (per level; one entry for
    "cells", the single-level cell size 2 r_max + skin), ``level_counts``, ``level_of``
    (int64 per particle; all zeros for "cells").
    """
    radius = np.asarray(radius, dtype=np.float64)
    n = radius.shape[0]
    if n == 0 or radius.min() <= 0.0:
        ratio = 1.0 if n == 0 else math.inf
    else:
        ratio = float(radius.max() / radius.min())
    if n > 0 and ratio >= switch_ratio:
        level_of, level_cell = make_levels(radius, skin, switch_ratio)
        if level_cell.shape[0] > 1:
            info = {"size_ratio": ratio, "cell_sizes": [float(c) for c in level_cell],
                    "level_counts": [int(c) for c in np.bincount(level_of,
                                                                  minlength=level_cell.shape[0])],
                    "level_of": level_of}
            return "hgrid", info
    cell = 2.0 * float(radius.max(initial=0.5)) + skin
    return "cells", {"size_ratio": ratio, "cell_sizes": [cell], "level_counts": [n],
                     "level_of": np.zeros(n, dtype=np.int64)}


# --------------------------------------------------------------------------------------------
# mapping phase
# --------------------------------------------------------------------------------------------
@njit(cache=True)
def _half_shell(ncx, ncy):
    """Same-level cell offsets (dx, dy, dz) visiting each neighbouring cell pair once.

    Offsets are de-duplicated modulo the periodic cell counts (fewer than 3 cells: -1 == +1).
    An offset that is its own inverse (0, or +-1 in a direction with 2 cells) is visited from
    both cells, so it carries a filter flag (keep only j > i); of every other pair {o, -o} the
    lexicographically larger (dz, dy, dx) is kept.  Returns (off (m, 3), filt (m,)).
    """
    off = np.zeros((27, 3), dtype=np.int64)
    filt = np.zeros(27, dtype=np.bool_)
    m = 0
    for dz in range(-1, 2):
        for dy in range(-1, 2):
            if ncy == 1 and dy != 0:
                continue
            if ncy == 2 and dy == -1:
                continue
            for dx in range(-1, 2):
                if ncx == 1 and dx != 0:
                    continue
                if ncx == 2 and dx == -1:
                    continue
                # inverse offset, canonicalised into the offset set
                nz = -dz
                ny = -dy if ncy >= 3 else dy
                nx = -dx if ncx >= 3 else dx
                if nz == dz and ny == dy and nx == dx:
                    off[m, 0] = dx
                    off[m, 1] = dy
                    off[m, 2] = dz
                    filt[m] = True
                    m += 1
                elif (dz, dy, dx) > (nz, ny, nx):
                    off[m, 0] = dx
                    off[m, 1] = dy
                    off[m, 2] = dz
                    filt[m] = False
                    m += 1
    return off[:m].copy(), filt[:m].copy()


@njit(cache=True)
def _build_hgrid(pos, radius, Lx, Ly, skin, level_of, level_cell):
    """Bin every particle into the grid of its level (CSR over all levels' cells).

    Returns per-level arrays (ncx, ncy, ncz, csx, csy, csz, base, rmax, count), zmin, and the
    per-particle global cell, the cell starts and the particles sorted by cell.
    """
    n = pos.shape[0]
    nlev = level_cell.shape[0]
    rmax = np.zeros(nlev)
    count = np.zeros(nlev, dtype=np.int64)
    for i in range(n):
        lv = level_of[i]
        count[lv] += 1
        if radius[i] > rmax[lv]:
            rmax[lv] = radius[i]
    zmin = np.inf
    zmax = -np.inf
    for i in range(n):
        if pos[i, 2] < zmin:
            zmin = pos[i, 2]
        if pos[i, 2] > zmax:
            zmax = pos[i, 2]
    if n == 0:
        zmin = 0.0
        zmax = 0.0
    ncx = np.empty(nlev, dtype=np.int64)
    ncy = np.empty(nlev, dtype=np.int64)
    ncz = np.empty(nlev, dtype=np.int64)
    csx = np.empty(nlev)
    csy = np.empty(nlev)
    csz = np.empty(nlev)
    base = np.empty(nlev + 1, dtype=np.int64)
    base[0] = 0
    for lv in range(nlev):
        # never smaller than the largest pair cutoff inside the level; widened against rounding
        cs = max(level_cell[lv], 2.0 * rmax[lv] + skin) * (1.0 + _REL_MARGIN)
        ncx[lv] = max(1, int(Lx / cs))
        ncy[lv] = max(1, int(Ly / cs))
        nz = int((zmax - zmin) / cs) + 1
        # bound the cell count of sparse tall systems (clamping the top cell stays exact)
        cap = max(4, (8 * count[lv] + 4096) // (ncx[lv] * ncy[lv]))
        ncz[lv] = min(nz, cap, 4096)
        csx[lv] = Lx / ncx[lv]
        csy[lv] = Ly / ncy[lv]
        csz[lv] = cs
        base[lv + 1] = base[lv] + ncx[lv] * ncy[lv] * ncz[lv]
    ncell = base[nlev]
    cell_of = np.empty(n, dtype=np.int64)
    start = np.zeros(ncell + 1, dtype=np.int64)
    for i in range(n):
        lv = level_of[i]
        x = pos[i, 0] - Lx * np.floor(pos[i, 0] / Lx)
        y = pos[i, 1] - Ly * np.floor(pos[i, 1] / Ly)
        cx = min(max(int(x / csx[lv]), 0), ncx[lv] - 1)
        cy = min(max(int(y / csy[lv]), 0), ncy[lv] - 1)
        cz = min(max(int((pos[i, 2] - zmin) / csz[lv]), 0), ncz[lv] - 1)
        c = base[lv] + (cz * ncy[lv] + cy) * ncx[lv] + cx
        cell_of[i] = c
        start[c + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    cell_particles = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cell_of[i]
        cell_particles[fill[c]] = i
        fill[c] += 1
    return (ncx, ncy, ncz, csx, csy, csz, base, rmax, count, zmin, zmax, cell_of, start,
            cell_particles)


# --------------------------------------------------------------------------------------------
# contact detection phase
# --------------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _accept(xi, yi, zi, ri, xj, yj, zj, rj, Lx, Ly, skin):
    """The pair test of ``kernels._neighbour_rows``, branch-free: squared minimum-image distance
    (summed as dx^2 + dy^2 + dz^2) below (r_i + r_j + skin)^2.

    The minimum image is taken by comparison with L/2 (:func:`_wrap_select`), which equals
    ``kernels._min_image`` (x - L rint(x / L)) for |x| < L except where x / L rounds to exactly
    1/2 from above, i.e. never for a difference of two coordinates in [0, L) that lies above
    L/2 by at least one unit in the last place.  The test is symmetric in (i, j) bit for bit.
    """
    rc = ri + rj + skin
    dx = _wrap_select(xi - xj, Lx)
    dy = _wrap_select(yi - yj, Ly)
    dz = zi - zj
    return dx * dx + dy * dy + dz * dz < rc * rc


@njit(cache=True)
def _particle_rows(sp, xs, ys, zs, rs, fs, Lx, Ly, skin, ls, ncx, ncy, ncz, csx, csy, csz, base,
                   rmax, count, zmin, margin, offs, filts, noff, cell_of, start, cell_particles,
                   out0, lim, out_q):
    """Count the partners q found by the particle in slot sp and write the first ``lim`` of
    them to ``out_q[out0:]``.

    Same-level partners through the half shell, finer-level partners through the cross-level
    box (Eq. 25-26); every pair is found by exactly one of its particles, and whichever finds
    it, the decision is the same (:func:`_accept`).  Returns the number of partners.
    """
    p = cell_particles[sp]
    lv = ls[sp]
    c = cell_of[p] - base[lv]
    nx = ncx[lv]
    ny = ncy[lv]
    nz = ncz[lv]
    cx = c % nx
    cy = (c // nx) % ny
    cz = c // (nx * ny)
    px = xs[sp]
    py = ys[sp]
    pz = zs[sp]
    pr = rs[sp]
    fp = fs[sp]
    cnt = 0
    # ---- step 1: linked cells on the level of insertion (half shell)
    for k in range(noff[lv]):
        zz = cz + offs[lv, k, 2]
        if zz < 0 or zz >= nz:
            continue
        yy = cy + offs[lv, k, 1]
        if yy < 0:
            yy += ny
        elif yy >= ny:
            yy -= ny
        xx = cx + offs[lv, k, 0]
        if xx < 0:
            xx += nx
        elif xx >= nx:
            xx -= nx
        cc = base[lv] + (zz * ny + yy) * nx + xx
        s0 = start[cc]
        s1 = start[cc + 1]
        if filts[lv, k]:
            # own cell (or a self-inverse offset): keep each pair once, from the lower index
            for s in range(s0, s1):
                q = cell_particles[s]
                ok = (q > p) & ~(fp & fs[s]) & _accept(px, py, pz, pr, xs[s], ys[s], zs[s],
                                                        rs[s], Lx, Ly, skin)
                if cnt < lim:
                    out_q[out0 + cnt] = q
                cnt += np.int64(ok)
        else:
            for s in range(s0, s1):
                ok = ~(fp & fs[s]) & _accept(px, py, pz, pr, xs[s], ys[s], zs[s], rs[s], Lx,
                                             Ly, skin)
                if cnt < lim:
                    out_q[out0 + cnt] = cell_particles[s]
                cnt += np.int64(ok)
    # ---- step 2: cross-level search on the finer levels (Eq. 25-26)
    xp = px - Lx * np.floor(px / Lx)
    yp = py - Ly * np.floor(py / Ly)
    zp = pz - zmin
    for h in range(lv):
        if count[h] == 0:
            continue
        alpha = pr + rmax[h] + skin + margin
        hx = ncx[h]
        hy = ncy[h]
        hz = ncz[h]
        x0 = int(np.floor((xp - alpha) / csx[h]))
        x1 = int(np.floor((xp + alpha) / csx[h]))
        wrapx = x1 - x0 + 1 < hx
        if not wrapx:
            x0 = 0
            x1 = hx - 1
        y0 = int(np.floor((yp - alpha) / csy[h]))
        y1 = int(np.floor((yp + alpha) / csy[h]))
        wrapy = y1 - y0 + 1 < hy
        if not wrapy:
            y0 = 0
            y1 = hy - 1
        z0 = min(max(int(np.floor((zp - alpha) / csz[h])), 0), hz - 1)
        z1 = min(max(int(np.floor((zp + alpha) / csz[h])), 0), hz - 1)
        # visit only the cells of the box whose extent is within alpha of p (Euclidean);
        # the top z cell is clamped (open above)
        a2 = alpha * alpha
        for zz in range(z0, z1 + 1):
            gz = zz * csz[h] - zp
            if gz < 0.0:
                gz = 0.0 if zz == hz - 1 else max(0.0, zp - (zz + 1) * csz[h])
            gz2 = gz * gz
            if gz2 > a2:
                continue
            for yv in range(y0, y1 + 1):
                gy2 = gz2
                if wrapy:
                    gy = max(0.0, yv * csy[h] - yp, yp - (yv + 1) * csy[h])
                    gy2 += gy * gy
                    if gy2 > a2:
                        continue
                yy = yv % hy
                row = base[h] + (zz * hy + yy) * hx
                for xv in range(x0, x1 + 1):
                    if wrapx:
                        gx = max(0.0, xv * csx[h] - xp, xp - (xv + 1) * csx[h])
                        if gy2 + gx * gx > a2:
                            continue
                    cc = row + xv % hx
                    for s in range(start[cc], start[cc + 1]):
                        if fp and fs[s]:
                            continue
                        if _accept(px, py, pz, pr, xs[s], ys[s], zs[s], rs[s], Lx, Ly,
                                   skin):
                            if cnt < lim:
                                out_q[out0 + cnt] = cell_particles[s]
                            cnt += 1
    return cnt


# Parallel kernels and every cached caller of them are parallel=True: a cached *serial* caller
# of a cached parallel callee segfaulted when loaded from numba's cache (numba issue 8578).
@njit(cache=True, parallel=True)
def _found_rows(xs, ys, zs, rs, fs, Lx, Ly, skin, ls, ncx, ncy, ncz, csx, csy, csz, base, rmax,
                count, zmin, margin, offs, filts, noff, cell_of, start, cell_particles,
                found_count, found_start, out_q, cap):
    """Find the partners of every particle: their number into ``found_count`` and the partners
    into ``out_q``, at ``p * cap`` (at most ``cap`` of them; ``cap > 0``) or at
    ``found_start[p]`` (all of them; ``cap = 0``, counts known).

    ``xs, ys, zs, rs, fs, ls`` are x, y, z, radius, fixed and level in cell order (copies, so
    that the candidates of a cell are contiguous in memory); particles are processed in cell
    order too.  Each particle writes only its own slice of ``out_q``: the result does not depend
    on the number of threads.
    """
    n = xs.shape[0]
    for su in prange(n):
        sp = np.int64(su)  # prange may hand out unsigned indices
        p = cell_particles[sp]
        if cap > 0:
            out0 = p * cap
            lim = cap
        else:
            out0 = found_start[p]
            lim = found_count[p]
        found_count[p] = _particle_rows(sp, xs, ys, zs, rs, fs, Lx, Ly, skin, ls, ncx, ncy, ncz,
                                        csx, csy, csz, base, rmax, count, zmin, margin, offs,
                                        filts, noff, cell_of, start, cell_particles, out0, lim,
                                        out_q)


@njit(cache=True)
def _gather(pos, radius, fixed, level_of, cell_particles, xs, ys, zs, rs, fs, ls):
    for su in range(cell_particles.shape[0]):
        i = cell_particles[su]
        xs[su] = pos[i, 0]
        ys[su] = pos[i, 1]
        zs[su] = pos[i, 2]
        rs[su] = radius[i]
        fs[su] = fixed[i]
        ls[su] = level_of[i]


@njit(cache=True, parallel=True)
def _sort_rows(row_start, pj):
    """Sort every row of ``pj`` in place (Shell sort, Ciura gaps; plain insertion sort for the
    short rows of a packing)."""
    gaps = np.array([701, 301, 132, 57, 23, 10, 4, 1], dtype=np.int64)
    n = row_start.shape[0] - 1
    for iu in prange(n):
        i = np.int64(iu)
        a = row_start[i]
        m = row_start[i + 1] - a
        for g in gaps:
            if g >= m:
                continue
            for u in range(g, m):
                v = pj[a + u]
                w = u
                while w >= g and pj[a + w - g] > v:
                    pj[a + w] = pj[a + w - g]
                    w -= g
                pj[a + w] = v


@njit(cache=True, parallel=True)  # parallel callees (see _found_rows)
def hgrid_pairs_u32(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell, cap):
    """:func:`hgrid_pairs` with uint32 indices, in one search pass when no particle finds more
    than ``cap`` partners (else a second pass with the exact counts)."""
    n = pos.shape[0]
    nlev = level_cell.shape[0]
    (ncx, ncy, ncz, csx, csy, csz, base, rmax, count, zmin, zmax, cell_of, start,
     cell_particles) = _build_hgrid(pos, radius, Lx, Ly, skin, level_of, level_cell)
    margin = _REL_MARGIN * (Lx + Ly + (zmax - zmin) + 2.0 * rmax.max() + skin)
    offs = np.zeros((nlev, 27, 3), dtype=np.int64)
    filts = np.zeros((nlev, 27), dtype=np.bool_)
    noff = np.zeros(nlev, dtype=np.int64)
    for lv in range(nlev):
        o, f = _half_shell(ncx[lv], ncy[lv])
        m = o.shape[0]
        noff[lv] = m
        offs[lv, :m, :] = o
        filts[lv, :m] = f
    xs = np.empty(n)
    ys = np.empty(n)
    zs = np.empty(n)
    rs = np.empty(n)
    fs = np.empty(n, dtype=np.bool_)
    ls = np.empty(n, dtype=np.int64)
    _gather(pos, radius, fixed, level_of, cell_particles, xs, ys, zs, rs, fs, ls)
    found_count = np.zeros(n, dtype=np.int64)
    found_start = np.zeros(n + 1, dtype=np.int64)
    cap = max(cap, 1)
    out_q = np.empty(n * cap, dtype=np.uint32)
    _found_rows(xs, ys, zs, rs, fs, Lx, Ly, skin, ls, ncx, ncy, ncz, csx, csy, csz, base, rmax,
                count, zmin, margin, offs, filts, noff, cell_of, start, cell_particles,
                found_count, found_start, out_q, cap)
    overflow = False
    for p in range(n):
        found_start[p + 1] = found_start[p] + found_count[p]
        if found_count[p] > cap:
            overflow = True
    npair = found_start[n]
    if overflow:  # second pass, every partner at its exact place
        out_q = np.empty(npair, dtype=np.uint32)
        _found_rows(xs, ys, zs, rs, fs, Lx, Ly, skin, ls, ncx, ncy, ncz, csx, csy, csz, base,
                    rmax, count, zmin, margin, offs, filts, noff, cell_of, start, cell_particles,
                    found_count, found_start, out_q, np.int64(0))  # not a literal: one compile
    # transpose to rows of the lower index (counting sort, serial: deterministic)
    row_start = np.zeros(n + 1, dtype=np.int64)
    for p in range(n):
        s0 = found_start[p] if overflow else p * cap
        for s in range(s0, s0 + found_count[p]):
            q = np.int64(out_q[s])
            row_start[(p if p < q else q) + 1] += 1
    for i in range(n):
        row_start[i + 1] += row_start[i]
    fillp = row_start[:-1].copy()
    pj = np.empty(npair, dtype=np.uint32)
    for p in range(n):
        s0 = found_start[p] if overflow else p * cap
        for s in range(s0, s0 + found_count[p]):
            q = np.int64(out_q[s])
            if p < q:
                pj[fillp[p]] = q
                fillp[p] += 1
            else:
                pj[fillp[q]] = p
                fillp[q] += 1
    _sort_rows(row_start, pj)
    pi = np.empty(npair, dtype=np.uint32)
    for i in range(n):
        for s in range(row_start[i], row_start[i + 1]):
            pi[s] = i
    return pi, pj


#: Partners per particle that the single search pass of :func:`hgrid_pairs` makes room for
#: (a dense monodisperse packing with skin 0.2 has ~4 on average, ~12 at most).
DEFAULT_CAPACITY = 24


@njit(cache=True, parallel=True)  # parallel callees (see _found_rows)
def hgrid_pairs(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell):
    """All pairs i < j (not both fixed) closer than r_i + r_j + skin, sorted by (i, j).

    ``level_of`` (int64, per particle) and ``level_cell`` (cell size per level, increasing) come
    from :func:`make_levels`; a level's cell is enlarged if it is below ``2 r_max + skin`` of its
    particles, so any assignment is exact (the efficiency needs levels ordered by size).  Callable
    from other njit kernels.
    """
    pi32, pj32 = hgrid_pairs_u32(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell,
                                 DEFAULT_CAPACITY)
    pi = np.empty(pi32.shape[0], dtype=np.int64)
    pj = np.empty(pi32.shape[0], dtype=np.int64)
    for p in prange(pi32.shape[0]):
        pi[p] = pi32[p]
        pj[p] = pj32[p]
    return pi, pj


def hgrid_neighbour_pairs(pos, radius, fixed, Lx, Ly, skin, level_of=None, level_cell=None,
                          ratio=SWITCH_RATIO):
    """Neighbour pairs through the hierarchical grid; same result as ``neighbour_pairs``.

    Without ``level_of``/``level_cell`` the levels are made by :func:`make_levels` with
    ``ratio`` (pass them in when the radii do not change, e.g. from
    :func:`choose_neighbour_method`'s ``info``).
    """
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    radius = np.ascontiguousarray(radius, dtype=np.float64)
    fixed = np.ascontiguousarray(fixed, dtype=np.bool_)
    if level_of is None or level_cell is None:
        level_of, level_cell = make_levels(radius, skin, ratio)
    return hgrid_pairs(pos, radius, fixed, float(Lx), float(Ly), float(skin),
                       np.ascontiguousarray(level_of, dtype=np.int64),
                       np.ascontiguousarray(level_cell, dtype=np.float64))
