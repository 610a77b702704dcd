"""Hierarchical-grid neighbour search for polydisperse packings (Ogarko & Luding 2012).

Implements the multilevel contact detection reviewed in the seed papers (Weinhart, Thornton,
Luding & Bokhove, "From discrete particles to continuum fields near a boundary" / closure
review, §5 "Collision detection", 5.1.1 mapping phase and 5.1.2 contact detection phase; the
two-level grid of §5.2 for bidisperse systems):

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
  ``alpha = r_p + r_max(h) + skin`` (the seed's ``a_p + s_h/2`` with the skin), so cross-level
  pairs are tested only from the larger to the smaller particle, each exactly once.

Geometry as in :func:`granflow.engine.lib.kernels.neighbour_pairs`: periodic in x and y on
``[0, Lx) x [0, Ly)`` with the minimum-image convention, open in z (cells indexed from the lowest
particle; the top cell is clamped, which merges cells monotonically and stays exact).  Periodic
directions with fewer than 3 cells on a level are handled by de-duplicating the cell offsets
(same-level search: offsets that are their own inverse modulo the cell count are searched from
both sides with an ``i < j`` filter; cross-level search: a box wider than the level visits each
cell once).  Cell searches are widened by a relative 1e-9 margin so that floating-point rounding
at cell faces can never lose a pair: the result is exact, the distance test is the one of
``neighbour_pairs`` evaluated on the same operands (bitwise the same decision).

Output: ``(pi, pj)`` int64, all pairs ``i < j``, not both fixed, with minimum-image distance
``< r_i + r_j + skin``, sorted by ``(i, j)`` — exactly the arrays of ``neighbour_pairs``.  The
pairs are found per particle in parallel (``prange``; count pass, prefix sum, fill pass), then
transposed to rows of the lower index with a serial counting sort and each row sorted, so the
result does not depend on the number of threads.

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
#: Rows longer than this are sorted with np.sort instead of insertion sort.
_INSERTION_MAX = 48


@njit(cache=True, inline="always")
def _min_image(dx, L):
    # identical to kernels._min_image (kept local to avoid a circular import once kernels uses
    # this module)
    return dx - L * np.rint(dx / L)


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

    Switch point (measured, ``benchmarks/bench_hgrid.py``; bidisperse, equal volumes of both
    sizes, phi ~ 0.5 random sequential placement, d_large = 1, skin = 0.1 d_large, periodic
    cube, N = 50 000-600 000 (N grows with 1/sigma), warm numba, one thread; the two-level grid
    against the single-level cell list)::

        1/sigma    speed-up (t_cells / t_hgrid)
        1.25       0.95    (two levels of nearly equal cells: pure overhead)
        1.5        1.2
        2          1.9
        3          4.6
        5          13

    (two threads: the same within ~10 %).  The grid breaks even between 1.25 and 1.5; the switch
    is set to ``SWITCH_RATIO = 1.5``.  The seed's reference (Ogarko & Luding, Fig. 6,
    N = 128 000-768 000, phi near jamming): up to 40 % slower for 1/sigma < 1.43 and 22x faster
    at 1/sigma = 5.

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
@njit(cache=True, parallel=True)
def _found_rows(xs, ys, zs, rs, fs, Lx, Ly, skin, ls, ncx, ncy, ncz, csx, csy, csz, base, rmax,
                count, zmin, margin, offs, filts, noff, cell_of, start, cell_particles,
                found_count, found_start, out_q, fill):
    """Count (fill=False) or write (fill=True) the partners q found by every particle p.

    ``xs, ys, zs, rs, fs, ls`` are x, y, z, radius, fixed and level in cell order (copies, so
    that the candidates of a cell are contiguous in memory); particles are processed in cell
    order too.  Same-level partners through the half shell, finer-level partners through the
    cross-level box; every pair is found by exactly one of its particles.  The distance test is
    that of ``kernels._neighbour_rows`` on the same operands; it is symmetric in (i, j) bit for
    bit (round-half-even rint is odd, a - b = -(b - a), + commutes), so whichever particle finds
    the pair, the decision is the same.
    """
    n = xs.shape[0]
    for su in prange(n):
        sp = np.int64(su)  # prange may hand out unsigned indices
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
        out0 = found_start[p] if fill else 0
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
                    if q <= p or (fp and fs[s]):
                        continue
                    dx = _min_image(px - xs[s], Lx)
                    dy = _min_image(py - ys[s], Ly)
                    dz = pz - zs[s]
                    rc = pr + rs[s] + skin
                    if dx * dx + dy * dy + dz * dz < rc * rc:
                        if fill:
                            out_q[out0 + cnt] = q
                        cnt += 1
            else:
                for s in range(s0, s1):
                    if fp and fs[s]:
                        continue
                    dx = _min_image(px - xs[s], Lx)
                    dy = _min_image(py - ys[s], Ly)
                    dz = pz - zs[s]
                    rc = pr + rs[s] + skin
                    if dx * dx + dy * dy + dz * dz < rc * rc:
                        if fill:
                            out_q[out0 + cnt] = cell_particles[s]
                        cnt += 1
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
                            dx = _min_image(px - xs[s], Lx)
                            dy = _min_image(py - ys[s], Ly)
                            dz = pz - zs[s]
                            rc = pr + rs[s] + skin
                            if dx * dx + dy * dy + dz * dz < rc * rc:
                                if fill:
                                    out_q[out0 + cnt] = cell_particles[s]
                                cnt += 1
        if not fill:
            found_count[p] = cnt


@njit(cache=True, parallel=True)
def _gather(pos, radius, fixed, level_of, cell_particles, xs, ys, zs, rs, fs, ls):
    for su in prange(cell_particles.shape[0]):
        i = cell_particles[su]
        xs[su] = pos[i, 0]
        ys[su] = pos[i, 1]
        zs[su] = pos[i, 2]
        rs[su] = radius[i]
        fs[su] = fixed[i]
        ls[su] = level_of[i]


@njit(cache=True, parallel=True)
def _sort_rows(row_start, pj):
    n = row_start.shape[0] - 1
    for i in prange(n):
        a = row_start[i]
        b = row_start[i + 1]
        if b - a > _INSERTION_MAX:
            pj[a:b] = np.sort(pj[a:b])
        else:
            for u in range(a + 1, b):
                v = pj[u]
                w = u - 1
                while w >= a and pj[w] > v:
                    pj[w + 1] = pj[w]
                    w -= 1
                pj[w + 1] = v


@njit(cache=True)
def hgrid_pairs(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell):
    """All pairs i < j (not both fixed) closer than r_i + r_j + skin, sorted by (i, j).

    ``level_of`` (int64, per particle) and ``level_cell`` (cell size per level, increasing) come
    from :func:`make_levels`; a level's cell is enlarged if it is below ``2 r_max + skin`` of its
    particles, so any assignment is exact (the efficiency needs levels ordered by size).  Callable
    from other njit kernels.
    """
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
    dummy = np.empty(0, dtype=np.int64)
    _found_rows(xs, ys, zs, rs, fs, Lx, Ly, skin, ls, ncx, ncy, ncz, csx, csy, csz, base, rmax,
                count, zmin, margin, offs, filts, noff, cell_of, start, cell_particles,
                found_count, found_start, dummy, False)
    for p in range(n):
        found_start[p + 1] = found_start[p] + found_count[p]
    npair = found_start[n]
    out_q = np.empty(npair, dtype=np.int64)
    _found_rows(xs, ys, zs, rs, fs, Lx, Ly, skin, ls, ncx, ncy, ncz, csx, csy, csz, base, rmax,
                count, zmin, margin, offs, filts, noff, cell_of, start, cell_particles,
                found_count, found_start, out_q, True)
    # transpose to rows of the lower index (counting sort, serial: deterministic)
    row_start = np.zeros(n + 1, dtype=np.int64)
    for p in range(n):
        for s in range(found_start[p], found_start[p + 1]):
            q = out_q[s]
            row_start[(p if p < q else q) + 1] += 1
    for i in range(n):
        row_start[i + 1] += row_start[i]
    fillp = row_start[:-1].copy()
    pj = np.empty(npair, dtype=np.int64)
    for p in range(n):
        for s in range(found_start[p], found_start[p + 1]):
            q = out_q[s]
            if p < q:
                pj[fillp[p]] = q
                fillp[p] += 1
            else:
                pj[fillp[q]] = p
                fillp[q] += 1
    _sort_rows(row_start, pj)
    pi = np.empty(npair, dtype=np.int64)
    for i in range(n):
        for s in range(row_start[i], row_start[i + 1]):
            pi[s] = i
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
