"""numba kernels of the DPM chute engine: contact forces, neighbour lists, velocity Verlet.

Implements Weinhart et al. (2012) §2, Eq. (1)-(11):

* overlap delta_n = max(0, (d_i + d_j)/2 - r_ij)                        (Eq. 1)
* normal force k_n delta_n n - gamma_n v_n                             (Eq. 3-4)
* relative tangential velocity at the contact point with rotation      (Eq. 8)
* tangential spring delta_t, zero at first contact, integrated by forward Euler and kept
  tangential by rotating it into the current tangent plane (Eq. 9); Coulomb truncation
  |f_t| <= mu_c |f_n|
* force and torque sums (Eq. 10), velocity Verlet (Eq. 11)

plus the Hertzian (multiply both forces by sqrt(delta_n / d_ij)) and the Walton-Braun plastic
laws of Thornton et al. (T-eq. 4-5).  Stiffness and damping are stored *per unit reduced mass*
(k_hat = k / m_ij, g_hat = gamma / m_ij) per pair of particle types, so that every pair, including
unequal masses and flow-base pairs (m_ij = m_i), has the collision time and restitution of its
species (physics.md §1).

All kernels are small pure functions on arrays.  Pair loops write into per-pair arrays in
parallel; per-particle sums are done serially in pair order, so results are bitwise identical for
any number of numba threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .hgrid import hgrid_pairs

LAW_LINEAR = 0
LAW_HERTZ = 1
LAW_PLASTIC = 2
#: Columns of the per-pair output rows: f (0:3), torque on i (3:6), torque on j (6:9), elastic
#: energy (9), overlap (10), normal force (11), tangential spring energy released on opening (12).
NOUT = 13


@njit(cache=True, inline="always")
def _min_image(dx, L):
    return dx - L * np.rint(dx / L)


# --------------------------------------------------------------------------------------------
# contact force of one pair (the physics); used by the pair loop and the flat-wall loop
# --------------------------------------------------------------------------------------------
@njit(cache=True)
def _contact(
    nx, ny, nz, r, ri, rj, vix, viy, viz, vjx, vjy, vjz,
    wix, wiy, wiz, wjx, wjy, wjz, m_ij, law, kn_hat, gn_hat, kt_hat, gt_hat, mu, k2_hat,
    hist, dmax_in, dt, update_history, out, dsx, dsy, dsz,
):
    """Force on i from j for one touching pair with unit normal n (from j to i), distance r.

    Velocities are the (predicted) velocities at the force time, used by the dashpots.
    ``hist`` is the pair's tangential spring (length 3): it is rotated into the current tangent
    plane, advanced by (dsx, dsy, dsz) = dt times the relative tangential contact velocity over
    the last step (forward Euler of Eq. 9 with the mid-step velocity, which keeps the elastic
    tangential force conservative), truncated at the Coulomb limit, and stored when
    ``update_history``.  Returns the new maximum overlap (plastic law) and writes into ``out``:
    f (0:3), torque on i (3:6), torque on j (6:9), elastic energy (9), overlap (10),
    normal force magnitude (11).
    """
    delta = ri + rj - r
    # branch vectors: from centre i to the contact point and from centre j to it
    bi = -(ri - 0.5 * delta)
    bj = rj - 0.5 * delta
    bix = bi * nx
    biy = bi * ny
    biz = bi * nz
    bjx = bj * nx
    bjy = bj * ny
    bjz = bj * nz
    # velocity of the contact point on i minus that on j (Eq. 8)
    vx = vix + (wiy * biz - wiz * biy) - vjx - (wjy * bjz - wjz * bjy)
    vy = viy + (wiz * bix - wix * biz) - vjy - (wjz * bjx - wjx * bjz)
    vz = viz + (wix * biy - wiy * bix) - vjz - (wjx * bjy - wjy * bjx)
    vn = vx * nx + vy * ny + vz * nz
    vtx = vx - vn * nx
    vty = vy - vn * ny
    vtz = vz - vn * nz

    kn = m_ij * kn_hat
    gn = m_ij * gn_hat
    kt = m_ij * kt_hat
    gt = m_ij * gt_hat
    scale = 1.0
    dmax = dmax_in
    if law == LAW_HERTZ:
        scale = np.sqrt(delta / (ri + rj))
        kn *= scale
        gn *= scale
        kt *= scale
        gt *= scale
        fn = kn * delta - gn * vn
        e_el = 0.4 * kn * delta * delta  # int_0^delta k sqrt(x/d) x dx = (2/5) k sqrt(delta/d) delta^2
    elif law == LAW_PLASTIC:
        k1 = kn
        k2 = m_ij * k2_hat
        if delta > dmax:
            dmax = delta
        delta_e = delta - dmax * (1.0 - k1 / k2)
        if k2 * delta_e >= k1 * delta:
            fn = k1 * delta
        elif delta_e > 0.0:
            fn = k2 * delta_e
        else:
            fn = 0.0
        if delta_e > 0.0:
            e_el = 0.5 * k2 * delta_e * delta_e
        else:
            e_el = 0.0
    else:
        fn = kn * delta - gn * vn
        e_el = 0.5 * kn * delta * delta

    # tangential spring: rotate into the current tangent plane keeping its length (Eq. 9)
    sx = hist[0]
    sy = hist[1]
    sz = hist[2]
    s2 = sx * sx + sy * sy + sz * sz
    if s2 > 0.0:
        sn = sx * nx + sy * ny + sz * nz
        sx -= sn * nx
        sy -= sn * ny
        sz -= sn * nz
        p2 = sx * sx + sy * sy + sz * sz
        if p2 > 0.0:
            fac = np.sqrt(s2 / p2)
            sx *= fac
            sy *= fac
            sz *= fac
    if update_history:
        # forward Euler step of the spring (Eq. 9), tangential part of the increment only
        dn = dsx * nx + dsy * ny + dsz * nz
        sx += dsx - dn * nx
        sy += dsy - dn * ny
        sz += dsz - dn * nz
    ftx = -kt * sx - gt * vtx
    fty = -kt * sy - gt * vty
    ftz = -kt * sz - gt * vtz
    ft2 = ftx * ftx + fty * fty + ftz * ftz
    fmax = mu * abs(fn)
    if ft2 > fmax * fmax:
        # sliding: truncate the spring so that |f_t| = mu_c |f_n|
        ftm = np.sqrt(ft2)
        c = fmax / ftm
        ftx *= c
        fty *= c
        ftz *= c
        if kt > 0.0:
            sx = -(ftx + gt * vtx) / kt
            sy = -(fty + gt * vty) / kt
            sz = -(ftz + gt * vtz) / kt
    e_el += 0.5 * kt * (sx * sx + sy * sy + sz * sz)
    if update_history:
        hist[0] = sx
        hist[1] = sy
        hist[2] = sz

    fx = fn * nx + ftx
    fy = fn * ny + fty
    fz = fn * nz + ftz
    out[0] = fx
    out[1] = fy
    out[2] = fz
    # torque on i: b_i x f ; on j: b_j x (-f)
    out[3] = biy * fz - biz * fy
    out[4] = biz * fx - bix * fz
    out[5] = bix * fy - biy * fx
    out[6] = -(bjy * fz - bjz * fy)
    out[7] = -(bjz * fx - bjx * fz)
    out[8] = -(bjx * fy - bjy * fx)
    out[9] = e_el
    out[10] = delta
    out[11] = fn
    out[12] = 0.0
    return dmax


RELEASE_FRACTION = 0.5


@njit(cache=True, inline="always")
def _released_spring_energy(hist, nx, ny, nz, dsx, dsy, dsz, m_ij, law, kt_hat):
    """Elastic energy left in a tangential spring when its contact opens.

    In the dissipation-free limit this energy becomes internal energy of the particles
    (Weinhart et al. 2012, Appendix A); it is accounted so that total energy is conserved.
    The Hertzian spring stiffness vanishes at zero overlap, so nothing is released.
    """
    if law == LAW_HERTZ:
        return 0.0
    sx = hist[0] + dsx
    sy = hist[1] + dsy
    sz = hist[2] + dsz
    sn = sx * nx + sy * ny + sz * nz
    sx -= sn * nx
    sy -= sn * ny
    sz -= sn * nz
    return 0.5 * m_ij * kt_hat * (sx * sx + sy * sy + sz * sz)


@njit(cache=True, parallel=True)
def pair_forces(
    pos, vel, omega, vel_h, omega_h, radius, inv_mass, ptype, Lx, Ly, pi, pj, hist_t, hist_dmax,
    law_tab, kn_tab, gn_tab, kt_tab, gt_tab, mu_tab, k2_tab, dt, update_history, pair_out,
):
    """Contact forces of all listed pairs into ``pair_out`` (P, NOUT); untouched pairs get zeros.

    ``vel, omega`` are the velocities at the force time (dashpots), ``vel_h, omega_h`` the
    mid-step velocities of the last drift (tangential spring increment).  Contact history
    (tangential spring, maximum overlap) is reset when a pair is not touching.
    """
    npair = pi.shape[0]
    for p in prange(npair):
        i = pi[p]
        j = pj[p]
        dx = _min_image(pos[i, 0] - pos[j, 0], Lx)
        dy = _min_image(pos[i, 1] - pos[j, 1], Ly)
        dz = pos[i, 2] - pos[j, 2]
        r2 = dx * dx + dy * dy + dz * dz
        rsum = radius[i] + radius[j]
        touching = r2 < rsum * rsum
        if not touching and not (update_history and hist_t[p, 0] * hist_t[p, 0]
                                 + hist_t[p, 1] * hist_t[p, 1] + hist_t[p, 2] * hist_t[p, 2] > 0.0):
            for k in range(NOUT):
                pair_out[p, k] = 0.0
            continue
        r = np.sqrt(r2)
        ti = ptype[i]
        tj = ptype[j]
        m_ij = 1.0 / (inv_mass[i] + inv_mass[j])
        nx = dx / r
        ny = dy / r
        nz = dz / r
        bi = -(radius[i] - 0.5 * (radius[i] + radius[j] - r))
        bj = radius[j] - 0.5 * (radius[i] + radius[j] - r)
        # relative contact-point displacement over the step (mid-step velocities)
        dsx = dt * (vel_h[i, 0] - vel_h[j, 0] + bi * (omega_h[i, 1] * nz - omega_h[i, 2] * ny)
                    - bj * (omega_h[j, 1] * nz - omega_h[j, 2] * ny))
        dsy = dt * (vel_h[i, 1] - vel_h[j, 1] + bi * (omega_h[i, 2] * nx - omega_h[i, 0] * nz)
                    - bj * (omega_h[j, 2] * nx - omega_h[j, 0] * nz))
        dsz = dt * (vel_h[i, 2] - vel_h[j, 2] + bi * (omega_h[i, 0] * ny - omega_h[i, 1] * nx)
                    - bj * (omega_h[j, 0] * ny - omega_h[j, 1] * nx))
        if not touching:
            # the contact opened during this step: its spring energy becomes internal energy
            for k in range(NOUT):
                pair_out[p, k] = 0.0
            pair_out[p, 12] = _released_spring_energy(
                hist_t[p], nx, ny, nz, RELEASE_FRACTION * dsx, RELEASE_FRACTION * dsy,
                RELEASE_FRACTION * dsz, m_ij, law_tab[ti, tj], kt_tab[ti, tj])
            hist_t[p, 0] = 0.0
            hist_t[p, 1] = 0.0
            hist_t[p, 2] = 0.0
            hist_dmax[p] = 0.0
            continue
        dm = _contact(
            nx, ny, nz, r, radius[i], radius[j],
            vel[i, 0], vel[i, 1], vel[i, 2], vel[j, 0], vel[j, 1], vel[j, 2],
            omega[i, 0], omega[i, 1], omega[i, 2], omega[j, 0], omega[j, 1], omega[j, 2],
            m_ij, law_tab[ti, tj], kn_tab[ti, tj], gn_tab[ti, tj], kt_tab[ti, tj], gt_tab[ti, tj],
            mu_tab[ti, tj], k2_tab[ti, tj], hist_t[p], hist_dmax[p], dt, update_history,
            pair_out[p], dsx, dsy, dsz,
        )
        if update_history:
            hist_dmax[p] = dm


@njit(cache=True, parallel=True)
def wall_forces(
    pos, vel, omega, vel_h, omega_h, radius, inv_mass, ptype, wall_type, wall_hist, wall_dmax,
    law_tab, kn_tab, gn_tab, kt_tab, gt_tab, mu_tab, k2_tab, dt, update_history, wall_out,
):
    """Contacts of mobile particles with the flat frictional wall z = 0 (lambda = 0 base)."""
    n = pos.shape[0]
    for i in prange(n):
        if inv_mass[i] == 0.0 or pos[i, 2] >= radius[i]:
            for k in range(NOUT):
                wall_out[i, k] = 0.0
            if update_history and inv_mass[i] > 0.0:
                bi = -radius[i]
                wall_out[i, 12] = _released_spring_energy(
                    wall_hist[i], 0.0, 0.0, 1.0, RELEASE_FRACTION * dt * (vel_h[i, 0] + bi * omega_h[i, 1]),
                    RELEASE_FRACTION * dt * (vel_h[i, 1] - bi * omega_h[i, 0]), 0.0,
                    1.0 / inv_mass[i], law_tab[ptype[i], wall_type], kt_tab[ptype[i], wall_type])
            if update_history:
                wall_hist[i, 0] = 0.0
                wall_hist[i, 1] = 0.0
                wall_hist[i, 2] = 0.0
                wall_dmax[i] = 0.0
            continue
        ti = ptype[i]
        # the wall acts as a sphere of zero radius at (x, y, 0) touching from below
        r = pos[i, 2]
        bi = -(radius[i] - 0.5 * (radius[i] - r))
        dsx = dt * (vel_h[i, 0] + bi * omega_h[i, 1])
        dsy = dt * (vel_h[i, 1] - bi * omega_h[i, 0])
        dsz = dt * vel_h[i, 2]
        dm = _contact(
            0.0, 0.0, 1.0, r, radius[i], 0.0,
            vel[i, 0], vel[i, 1], vel[i, 2], 0.0, 0.0, 0.0,
            omega[i, 0], omega[i, 1], omega[i, 2], 0.0, 0.0, 0.0,
            1.0 / inv_mass[i], law_tab[ti, wall_type], kn_tab[ti, wall_type],
            gn_tab[ti, wall_type], kt_tab[ti, wall_type], gt_tab[ti, wall_type],
            mu_tab[ti, wall_type], k2_tab[ti, wall_type], wall_hist[i], wall_dmax[i], dt,
            update_history, wall_out[i], dsx, dsy, dsz,
        )
        if update_history:
            wall_dmax[i] = dm


@njit(cache=True)
def accumulate_forces(inv_mass, mass, gvec, pi, pj, pair_out, use_wall, wall_out, force, torque):
    """Serial, order-fixed sum of gravity and pair/wall contributions into force and torque.

    Returns (total elastic energy, maximum overlap, tangential spring energy released by
    contacts that opened in this step).
    """
    n = force.shape[0]
    for i in range(n):
        if inv_mass[i] > 0.0:
            force[i, 0] = mass[i] * gvec[0]
            force[i, 1] = mass[i] * gvec[1]
            force[i, 2] = mass[i] * gvec[2]
        else:
            force[i, 0] = 0.0
            force[i, 1] = 0.0
            force[i, 2] = 0.0
        torque[i, 0] = 0.0
        torque[i, 1] = 0.0
        torque[i, 2] = 0.0
    e_el = 0.0
    max_overlap = 0.0
    e_rel = 0.0
    for p in range(pi.shape[0]):
        if pair_out[p, 10] == 0.0:
            e_rel += pair_out[p, 12]
            continue
        i = pi[p]
        j = pj[p]
        for k in range(3):
            force[i, k] += pair_out[p, k]
            force[j, k] -= pair_out[p, k]
            torque[i, k] += pair_out[p, 3 + k]
            torque[j, k] += pair_out[p, 6 + k]
        e_el += pair_out[p, 9]
        if pair_out[p, 10] > max_overlap:
            max_overlap = pair_out[p, 10]
    if use_wall:
        for i in range(n):
            if wall_out[i, 10] == 0.0:
                e_rel += wall_out[i, 12]
                continue
            for k in range(3):
                force[i, k] += wall_out[i, k]
                torque[i, k] += wall_out[i, 3 + k]
            e_el += wall_out[i, 9]
            if wall_out[i, 10] > max_overlap:
                max_overlap = wall_out[i, 10]
    return e_el, max_overlap, e_rel


# --------------------------------------------------------------------------------------------
# neighbour list: cell list + Verlet skin, half list without base-base pairs
# --------------------------------------------------------------------------------------------
@njit(cache=True)
def _cell_offsets(n):
    if n >= 3:
        return np.array([-1, 0, 1])
    if n == 2:
        return np.array([0, 1])
    return np.array([0])


@njit(cache=True)
def build_cells(pos, Lx, Ly, cell_size):
    """Bin particles into a periodic-x,y, open-z cell grid. Returns (ncx, ncy, ncz, z0, cell_of,
    cell_start, cell_particles) with particles sorted by cell (CSR)."""
    n = pos.shape[0]
    ncx = max(1, int(Lx / cell_size))
    ncy = max(1, int(Ly / cell_size))
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
    ncz = int((zmax - zmin) / cell_size) + 1
    if ncz > 4096:  # particles far above the flow are clamped into the top cell (still exact)
        ncz = 4096
    csx = Lx / ncx
    csy = Ly / ncy
    cell_of = np.empty(n, dtype=np.int64)
    counts = np.zeros(ncx * ncy * ncz + 1, dtype=np.int64)
    for i in range(n):
        cx = int(pos[i, 0] / csx)
        cy = int(pos[i, 1] / csy)
        cz = int((pos[i, 2] - zmin) / cell_size)
        cx = min(max(cx, 0), ncx - 1)
        cy = min(max(cy, 0), ncy - 1)
        cz = min(max(cz, 0), ncz - 1)
        c = (cz * ncy + cy) * ncx + cx
        cell_of[i] = c
        counts[c + 1] += 1
    for c in range(ncx * ncy * ncz):
        counts[c + 1] += counts[c]
    fill = counts[:-1].copy()
    cell_particles = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cell_of[i]
        cell_particles[fill[c]] = i
        fill[c] += 1
    return ncx, ncy, ncz, cell_of, counts, cell_particles


@njit(cache=True, parallel=True)
def _neighbour_rows(pos, radius, fixed, Lx, Ly, skin, ncx, ncy, ncz, cell_of, cell_start,
                    cell_particles, row_count, row_start, out_j, fill):
    """Count (fill=False) or write (fill=True) the neighbours j > i of every particle i."""
    n = pos.shape[0]
    ox = _cell_offsets(ncx)
    oy = _cell_offsets(ncy)
    for i in prange(n):
        c = cell_of[i]
        cx = c % ncx
        cy = (c // ncx) % ncy
        cz = c // (ncx * ncy)
        cnt = 0
        base = row_start[i] if fill else 0
        for dz in range(-1, 2):
            zz = cz + dz
            if zz < 0 or zz >= ncz:
                continue
            for a in range(oy.shape[0]):
                yy = (cy + oy[a]) % ncy
                for b in range(ox.shape[0]):
                    xx = (cx + ox[b]) % ncx
                    cc = (zz * ncy + yy) * ncx + xx
                    for q in range(cell_start[cc], cell_start[cc + 1]):
                        j = cell_particles[q]
                        if j <= i or (fixed[i] and fixed[j]):
                            continue
                        dx = _min_image(pos[i, 0] - pos[j, 0], Lx)
                        dy = _min_image(pos[i, 1] - pos[j, 1], Ly)
                        dzz = pos[i, 2] - pos[j, 2]
                        rc = radius[i] + radius[j] + skin
                        if dx * dx + dy * dy + dzz * dzz < rc * rc:
                            if fill:
                                out_j[base + cnt] = j
                            cnt += 1
        if fill:
            # insertion sort of the row so that pairs are ordered by (i, j)
            for u in range(base + 1, base + cnt):
                v = out_j[u]
                w = u - 1
                while w >= base and out_j[w] > v:
                    out_j[w + 1] = out_j[w]
                    w -= 1
                out_j[w + 1] = v
        else:
            row_count[i] = cnt


@njit(cache=True)
def neighbour_pairs(pos, radius, fixed, Lx, Ly, skin, cell_size):
    """All pairs i < j (not both fixed) closer than r_i + r_j + skin, sorted by (i, j)."""
    n = pos.shape[0]
    ncx, ncy, ncz, cell_of, cell_start, cell_particles = build_cells(pos, Lx, Ly, cell_size)
    row_count = np.zeros(n, dtype=np.int64)
    row_start = np.zeros(n + 1, dtype=np.int64)
    dummy = np.empty(0, dtype=np.int64)
    _neighbour_rows(pos, radius, fixed, Lx, Ly, skin, ncx, ncy, ncz, cell_of, cell_start,
                    cell_particles, row_count, row_start, dummy, False)
    for i in range(n):
        row_start[i + 1] = row_start[i] + row_count[i]
    npair = row_start[n]
    pj = np.empty(npair, dtype=np.int64)
    _neighbour_rows(pos, radius, fixed, Lx, Ly, skin, ncx, ncy, ncz, cell_of, cell_start,
                    cell_particles, row_count, row_start, pj, True)
    pi = np.empty(npair, dtype=np.int64)
    for i in range(n):
        for q in range(row_start[i], row_start[i + 1]):
            pi[q] = i
    return pi, pj


@njit(cache=True)
def transfer_history(old_i, old_j, old_t, old_dmax, new_i, new_j, n):
    """Carry contact history from an old sorted pair list to a new one (merge walk, O(P))."""
    npair = new_i.shape[0]
    new_t = np.zeros((npair, 3))
    new_dmax = np.zeros(npair)
    q = 0
    nold = old_i.shape[0]
    for p in range(npair):
        key = new_i[p] * n + new_j[p]
        while q < nold and old_i[q] * n + old_j[q] < key:
            q += 1
        if q < nold and old_i[q] * n + old_j[q] == key:
            new_t[p, 0] = old_t[q, 0]
            new_t[p, 1] = old_t[q, 1]
            new_t[p, 2] = old_t[q, 2]
            new_dmax[p] = old_dmax[q]
    return new_t, new_dmax


@njit(cache=True)
def max_displacement_sq(pos, pos_ref, Lx, Ly):
    m = 0.0
    for i in range(pos.shape[0]):
        dx = _min_image(pos[i, 0] - pos_ref[i, 0], Lx)
        dy = _min_image(pos[i, 1] - pos_ref[i, 1], Ly)
        dz = pos[i, 2] - pos_ref[i, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > m:
            m = d2
        elif not d2 == d2:  # NaN position or velocity
            return np.inf
    return m


# --------------------------------------------------------------------------------------------
# time integration
# --------------------------------------------------------------------------------------------
@njit(cache=True)
def _half_kick(vel, omega, force, torque, inv_mass, inv_inertia, dt):
    h = 0.5 * dt
    for i in range(vel.shape[0]):
        im = inv_mass[i]
        if im == 0.0:
            continue
        ii = inv_inertia[i]
        for k in range(3):
            vel[i, k] += h * force[i, k] * im
            omega[i, k] += h * torque[i, k] * ii


@njit(cache=True)
def _predict_velocity(vel, omega, force, torque, inv_mass, inv_inertia, dt, vel_p, omega_p):
    """Second-order estimate of v(t + dt) from the half-step velocity and the old force, used
    for the velocity-dependent (damping) forces so that restitution is accurate to O(dt^2)."""
    h = 0.5 * dt
    for i in range(vel.shape[0]):
        im = inv_mass[i]
        ii = inv_inertia[i]
        for k in range(3):
            vel_p[i, k] = vel[i, k] + h * force[i, k] * im
            omega_p[i, k] = omega[i, k] + h * torque[i, k] * ii


@njit(cache=True)
def _drift(pos, vel, inv_mass, Lx, Ly, dt):
    for i in range(pos.shape[0]):
        if inv_mass[i] == 0.0:
            continue
        x = pos[i, 0] + dt * vel[i, 0]
        y = pos[i, 1] + dt * vel[i, 1]
        x -= Lx * np.floor(x / Lx)
        y -= Ly * np.floor(y / Ly)
        if x >= Lx:
            x = 0.0
        if y >= Ly:
            y = 0.0
        pos[i, 0] = x
        pos[i, 1] = y
        pos[i, 2] += dt * vel[i, 2]


@njit(cache=True)
def compute_forces(
    pos, vel, omega, vel_h, omega_h, radius, inv_mass, mass, ptype, fixed, Lx, Ly, gvec, pi, pj, hist_t,
    hist_dmax, use_wall, wall_type, wall_hist, wall_dmax, law_tab, kn_tab, gn_tab, kt_tab,
    gt_tab, mu_tab, k2_tab, dt, update_history, pair_out, wall_out, force, torque,
):
    pair_forces(pos, vel, omega, vel_h, omega_h, radius, inv_mass, ptype, Lx, Ly, pi, pj, hist_t, hist_dmax,
                law_tab, kn_tab, gn_tab, kt_tab, gt_tab, mu_tab, k2_tab, dt, update_history,
                pair_out)
    if use_wall:
        wall_forces(pos, vel, omega, vel_h, omega_h, radius, inv_mass, ptype, wall_type, wall_hist, wall_dmax,
                    law_tab, kn_tab, gn_tab, kt_tab, gt_tab, mu_tab, k2_tab, dt, update_history,
                    wall_out)
    return accumulate_forces(inv_mass, mass, gvec, pi, pj, pair_out, use_wall, wall_out, force,
                             torque)


@njit(cache=True)
def advance(
    nsteps, pos, vel, omega, force, torque, radius, inv_mass, mass, inv_inertia, ptype, fixed,
    Lx, Ly, gvec, pi, pj, hist_t, hist_dmax, pos_ref, skin, level_of, level_cell, use_wall, wall_type,
    wall_hist, wall_dmax, law_tab, kn_tab, gn_tab, kt_tab, gt_tab, mu_tab, k2_tab, dt,
    pair_out, wall_out, max_overlap_allowed,
):
    """Advance ``nsteps`` velocity-Verlet steps (Eq. 11), rebuilding the neighbour list when a
    particle has moved more than skin/2 since the last build (by the hierarchical grid of
    :mod:`.hgrid` with the levels ``level_of``/``level_cell``; one level = plain cell list).

    Arrays are updated in place, except the pair arrays, which are returned (they change size on
    a rebuild).  Returns (pi, pj, hist_t, hist_dmax, pair_out, e_elastic, max_overlap,
    e_released, steps_done, n_rebuilds, status) with status 0 = ok, 1 = non-finite force, 2 = overlap too
    large (the step at which it happened is steps_done).
    """
    e_el = 0.0
    max_ov = 0.0
    e_released = 0.0
    nreb = 0
    half_skin2 = 0.25 * skin * skin
    vel_p = np.empty_like(vel)
    omega_p = np.empty_like(omega)
    for step in range(nsteps):
        _half_kick(vel, omega, force, torque, inv_mass, inv_inertia, dt)
        _drift(pos, vel, inv_mass, Lx, Ly, dt)
        _predict_velocity(vel, omega, force, torque, inv_mass, inv_inertia, dt, vel_p, omega_p)
        disp2 = max_displacement_sq(pos, pos_ref, Lx, Ly)
        if not np.isfinite(disp2):
            return pi, pj, hist_t, hist_dmax, pair_out, np.nan, max_ov, e_released, step + 1, nreb, 1
        if disp2 > half_skin2:
            npi, npj = hgrid_pairs(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell)
            nt, nd = transfer_history(pi, pj, hist_t, hist_dmax, npi, npj, pos.shape[0])
            pi = npi
            pj = npj
            hist_t = nt
            hist_dmax = nd
            pair_out = np.zeros((pi.shape[0], NOUT))
            pos_ref[:, :] = pos
            nreb += 1
        e_el, max_ov, e_rel = compute_forces(
            pos, vel_p, omega_p, vel, omega, radius, inv_mass, mass, ptype, fixed, Lx, Ly, gvec, pi, pj, hist_t,
            hist_dmax, use_wall, wall_type, wall_hist, wall_dmax, law_tab, kn_tab, gn_tab,
            kt_tab, gt_tab, mu_tab, k2_tab, dt, True, pair_out, wall_out, force, torque,
        )
        _half_kick(vel, omega, force, torque, inv_mass, inv_inertia, dt)
        e_released += e_rel
        if not np.isfinite(e_el):
            return pi, pj, hist_t, hist_dmax, pair_out, e_el, max_ov, e_released, step + 1, nreb, 1
        if max_ov > max_overlap_allowed:
            return pi, pj, hist_t, hist_dmax, pair_out, e_el, max_ov, e_released, step + 1, nreb, 2
    return pi, pj, hist_t, hist_dmax, pair_out, e_el, max_ov, e_released, nsteps, nreb, 0


@njit(cache=True)
def kinetic_energy(vel, omega, mass, inertia, inv_mass):
    """Translational and rotational kinetic energy of the mobile particles."""
    et = 0.0
    er = 0.0
    for i in range(vel.shape[0]):
        if inv_mass[i] == 0.0:
            continue
        et += 0.5 * mass[i] * (vel[i, 0] ** 2 + vel[i, 1] ** 2 + vel[i, 2] ** 2)
        er += 0.5 * inertia[i] * (omega[i, 0] ** 2 + omega[i, 1] ** 2 + omega[i, 2] ** 2)
    return et, er


@njit(cache=True)
def insert_random(existing_pos, existing_radius, new_radius, Lx, Ly, z_lo, height0, grow,
                  uniforms):
    """Random sequential insertion without overlaps (physics.md §3).

    Particle k gets a uniform centre in [0,Lx) x [0,Ly) x [z_lo, z_lo + I]; after every rejected
    trial the insertion height I grows by ``grow``.  Overlaps are checked against the existing
    particles and those already inserted (brute force, done once per run).  ``uniforms`` supplies
    the random numbers (3 per trial), so the result is fixed by the caller's seeded generator.
    Returns (positions, trials used, final I); trials used = -1 if the numbers ran out.
    """
    nnew = new_radius.shape[0]
    nold = existing_pos.shape[0]
    out = np.empty((nnew, 3))
    height = height0
    u = 0
    nu = uniforms.shape[0]
    for k in range(nnew):
        rk = new_radius[k]
        while True:
            if u + 3 > nu:
                return out, -1, height
            x = uniforms[u] * Lx
            y = uniforms[u + 1] * Ly
            z = z_lo + uniforms[u + 2] * height
            u += 3
            ok = True
            for q in range(nold):
                dx = _min_image(x - existing_pos[q, 0], Lx)
                dy = _min_image(y - existing_pos[q, 1], Ly)
                dz = z - existing_pos[q, 2]
                rr = rk + existing_radius[q]
                if dx * dx + dy * dy + dz * dz < rr * rr:
                    ok = False
                    break
            if ok:
                for q in range(k):
                    dx = _min_image(x - out[q, 0], Lx)
                    dy = _min_image(y - out[q, 1], Ly)
                    dz = z - out[q, 2]
                    rr = rk + new_radius[q]
                    if dx * dx + dy * dy + dz * dz < rr * rr:
                        ok = False
                        break
            if ok:
                out[k, 0] = x
                out[k, 1] = y
                out[k, 2] = z
                break
            height += grow
    return out, u // 3, height


@njit(cache=True)
def contact_list(pos, radius, Lx, Ly, pi, pj, pair_out, use_wall, wall_out):
    """Contacts of the current state for coarse-graining: (i, j, force on i, r_i - r_j, contact
    point relative to stored r_i).  Wall contacts have j = -1 and r_ij = (0, 0, z_i)."""
    m = 0
    for p in range(pi.shape[0]):
        if pair_out[p, 10] > 0.0:
            m += 1
    nw = 0
    if use_wall:
        for i in range(pos.shape[0]):
            if wall_out[i, 10] > 0.0:
                nw += 1
    ci = np.empty(m + nw, dtype=np.int64)
    cj = np.empty(m + nw, dtype=np.int64)
    f = np.empty((m + nw, 3))
    rij = np.empty((m + nw, 3))
    cp = np.empty((m + nw, 3))
    q = 0
    for p in range(pi.shape[0]):
        if pair_out[p, 10] == 0.0:
            continue
        i = pi[p]
        j = pj[p]
        dx = _min_image(pos[i, 0] - pos[j, 0], Lx)
        dy = _min_image(pos[i, 1] - pos[j, 1], Ly)
        dz = pos[i, 2] - pos[j, 2]
        r = np.sqrt(dx * dx + dy * dy + dz * dz)
        delta = pair_out[p, 10]
        bi = -(radius[i] - 0.5 * delta) / r
        ci[q] = i
        cj[q] = j
        for k in range(3):
            f[q, k] = pair_out[p, k]
        rij[q, 0] = dx
        rij[q, 1] = dy
        rij[q, 2] = dz
        cp[q, 0] = pos[i, 0] + bi * dx
        cp[q, 1] = pos[i, 1] + bi * dy
        cp[q, 2] = pos[i, 2] + bi * dz
        q += 1
    if use_wall:
        for i in range(pos.shape[0]):
            if wall_out[i, 10] == 0.0:
                continue
            ci[q] = i
            cj[q] = -1
            for k in range(3):
                f[q, k] = wall_out[i, k]
            rij[q, 0] = 0.0
            rij[q, 1] = 0.0
            rij[q, 2] = pos[i, 2]
            cp[q, 0] = pos[i, 0]
            cp[q, 1] = pos[i, 1]
            cp[q, 2] = pos[i, 2] - (radius[i] - 0.5 * wall_out[i, 10])
            q += 1
    return ci, cj, f, rij, cp
