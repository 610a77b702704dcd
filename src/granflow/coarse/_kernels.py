"""numba kernels for Gaussian coarse-graining of one DEM snapshot into depth (z) profiles.

Implements the x-y averaged form of Weinhart et al. (2012) Eq. (13), (16) and (32) (and Eq. 43
for the plane average): for a Gaussian coarse-graining function W of width w (Eq. 14) the
integral over a periodic Lx x Ly plane is exact,

    (1/(Lx Ly)) int int W(r - r_i) dx dy = g(z - z_i) / (Lx Ly),

with g the one-dimensional Gaussian of width w.  The line integrals of Eq. (32) then have closed
forms in the kernel's cumulative distribution G (error functions):

    flow-flow pair, segment r_i -> r_j (s in [0, 1]):
        int_0^1 g(z - z_i + s r_ij,z) ds = (G(z - z_j) - G(z - z_i)) / r_ij,z
    flow-base pair, path from r_i to z = -inf.  Any path from the flow particle's centre to
    infinity satisfies the momentum balance exactly (d/ds W(r - r(s)) integrates to W(r - r_i));
    three are offered (``base_mode``, cf. MercuryDPM's choice of where a fixed particle's contact
    stress goes):
      BASE_CONTACT_THEN_DOWN (default): the segment r_i -> contact point c, then straight down
        (-z) from c.  sigma_ab = f_a r_b / r_z (G(z - z_c) - G(z - z_i)) + [b = z] f_a (1 - G(z - z_c))
        with r = r_i - c: the flow particle's half of the branch, as for a flow-flow pair, and
        the base takes the load below the contact.  Every component is exactly zero above
        max(z_i, z_c) + cutoff w, and the depth integral of each is the virial f_a r_b of the
        half-branch, bounded by |f| d/2 -- whereas a half-line of direction u carries
        f_a u_b / u_z per unit depth below its start, unbounded for near-horizontal contacts
        (on the paper's 12-layer base that made the depth-averaged K of a steady thick flow
        1.11 +- 0.11 with the line turned down for upward contacts only, against 1.00 in the
        bulk).
      BASE_DOWN: straight down from r_i: sigma_az = f_a (1 - G(z - z_i)), the other components 0.
      BASE_THROUGH_CONTACT: the literal half-line of Weinhart et al. (2012) §3, from r_i through
        c and beyond (direction u):
          int_0^inf g(z - z_i - t u_z) dt = (1 - G(z - z_i)) / |u_z|   (u_z < 0, line goes down)
                                          =       G(z - z_i)  / u_z    (u_z > 0, line goes up)
        On a rough base a flow particle often sits in a hole below the centre of the base
        particle it touches; its line then points *up* through the whole flow and leaves a
        constant stress plateau (xx, yy, xy, and -f_a in the az components) everywhere above.
        Kept only to reproduce old profiles; physics.md §4 records the resolution.

Sign convention: compressive stress is positive, sigma = -sigma_Cauchy, so

    sigma_ab(z) = sum_pairs c_ab (G(z - z_j) - G(z - z_i))      c_ab = f_a r_ij,b / r_ij,z
                + sum_base  (one of the base paths above)
                + sum_i m_i v'_a v'_b g(z - z_i)

(f = force on the flow particle i, r_ij = r_i - r_j; Eq. (32) with the overall sign flipped) and
sigma_zz(z) = int_z^inf rho g cos(theta) dz' holds exactly in static equilibrium.  Because every
stress term is a per-particle coefficient times G(z - z_i), each flow particle's coefficients
are summed first and the kernel CDF is evaluated once per particle and grid point.  Above a
particle's kernel support G = 1: that plateau is stored once in a "step" array and restored by a
prefix sum, so only grid points within the cutoff are touched.  Near-horizontal pairs
(|r_ij,z| < 1e-4 w, where the CDF difference would cancel) use the midpoint expansion
g(z - z_m) + r_z^2 g''(z - z_m) / 24 (error O(r_z^4)).

The kernel is the Gaussian truncated at |z - z_i| = cutoff * w and renormalised to unit mass, so
mass and momentum balance hold exactly (not only up to the Gaussian tail) on a finite grid.

Speed: the Gaussian along a particle's grid points comes from a two-multiplication recurrence
(g_{k+1} = g_k R_k, R_{k+1} = R_k exp(-dz^2/w^2)), and G from a cubic Hermite table of the exact
CDF (values and derivatives; node spacing dz/M <= w/256, interpolation error < 4e-13) whose
nodes are aligned with the z grid, so the interpolation weights are computed once per particle.

Field columns of the per-snapshot buffer / accumulated sums (per unit plan area):
    0 density, 1-3 momentum x,y,z, 4-9 kinetic stress (xx, yy, zz, xy, xz, yz; sum m v_a v_b g
    during the snapshot), 10 .. 10+S-1 species density, 10+S .. 10+2S-1 species volume
    fraction, then 6 contact-stress and 6 base-stress components in the order
    xx, yy, zz, xy, xz, yz with ab = (force component a, line direction b).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SQRT2 = math.sqrt(2.0)
SQRT2PI = math.sqrt(2.0 * math.pi)

#: |r_ij,z| / w below which a flow-flow pair uses the midpoint expansion instead of CDF differences.
HORIZONTAL_TOL = 1e-4
#: |u_z| / |u| below which a flow-base half-line is treated as vertical (degenerate direction).
DEGENERATE_TOL = 1e-9
#: Hermite table nodes per coarse-graining width (at least).
TABLE_NODES_PER_WIDTH = 256

#: Paths of a flow-base contact's stress (see the module docstring).
BASE_THROUGH_CONTACT = 0
BASE_CONTACT_THEN_DOWN = 1
BASE_DOWN = 2

N_BASIC = 10  # density, momentum(3), kinetic(6)
#: stress components stored: (force component a, line direction b)
STRESS_AB = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
STRESS_NAMES = ("xx", "yy", "zz", "xy", "xz", "yz")


def n_columns(n_species: int) -> int:
    """Number of buffer columns for ``n_species`` species."""
    return N_BASIC + 2 * n_species + 12


@njit(cache=True)
def kernel_norm(cutoff):
    """Mass of the untruncated unit Gaussian inside |a| < cutoff (renormalisation factor)."""
    return math.erf(cutoff / SQRT2)


@njit(cache=True)
def kernel_cdf(a, width, cutoff, norm):
    """CDF G(a) of the truncated, renormalised 1D Gaussian of width ``width``."""
    lim = cutoff * width
    if a <= -lim:
        return 0.0
    if a >= lim:
        return 1.0
    return 0.5 * (1.0 + math.erf(a / (SQRT2 * width)) / norm)


@njit(cache=True)
def kernel_density(a, width, cutoff, norm):
    """Density g(a) of the truncated, renormalised 1D Gaussian of width ``width``."""
    if abs(a) >= cutoff * width:
        return 0.0
    x = a / width
    return math.exp(-0.5 * x * x) / (SQRT2PI * width * norm)


@njit(cache=True)
def grid_range(zc, z0, dz, half):
    """Inclusive grid index range [k0, k1] of points with |z_k - zc| < half (may be empty)."""
    k0 = int(math.floor((zc - half - z0) / dz)) + 1
    k1 = int(math.ceil((zc + half - z0) / dz)) - 1
    return k0, k1


def table_substeps(dz: float, width: float) -> int:
    """Table nodes M per grid step so that the node spacing dz/M is at most w/256."""
    return max(1, int(math.ceil(dz / width * TABLE_NODES_PER_WIDTH)))


@njit(cache=True)
def cdf_table(width, cutoff, dz, m_sub):
    """Hermite table (n, 2) of G on nodes a_j = -cutoff w + j dz/m_sub: [G, g h] per node."""
    h = dz / m_sub
    lim = cutoff * width
    n = int(math.ceil(2.0 * lim / h)) + 3
    norm = kernel_norm(cutoff)
    tab = np.empty((n, 2))
    for j in range(n):
        a = -lim + j * h
        x = a / width
        # untruncated Gaussian CDF shifted and renormalised; only used for |a| <= lim
        tab[j, 0] = (0.5 * math.erfc(-x / SQRT2) - 0.5 * math.erfc(cutoff / SQRT2)) / norm
        tab[j, 1] = h * math.exp(-0.5 * x * x) / (SQRT2PI * width * norm)
    return tab


@njit(cache=True)
def hermite_weights(t):
    """Node index j = floor(t) (>= 0) and the cubic Hermite weights (h00, h10, h01, h11) at the
    fraction t - j, for the table of :func:`cdf_table`."""
    j = int(math.floor(t))
    if j < 0:
        j = 0
    fr = t - j
    fr2 = fr * fr
    fr3 = fr2 * fr
    return (j, 2.0 * fr3 - 3.0 * fr2 + 1.0, fr3 - 2.0 * fr2 + fr, -2.0 * fr3 + 3.0 * fr2,
            fr3 - fr2)


@njit(cache=True)
def cdf_on_grid(zc, z0, dz, k0, n_pts, width, cutoff, tab, m_sub, out):
    """out[k] = G(z0 + (k0 + k) dz - zc) for k < n_pts: 0 below and 1 above the support of a
    kernel centred at ``zc``, the cubic Hermite table inside it (weights fixed per centre, since
    table nodes are aligned with the grid)."""
    lim = cutoff * width
    h = dz / m_sub
    a0 = z0 + k0 * dz - zc
    # the first grid point inside the support, and the Hermite weights there
    kin = 0
    if a0 <= -lim:
        kin = int(math.floor((-lim - a0) / dz)) + 1
    a_in = a0 + kin * dz
    j, h00, h10, h01, h11 = hermite_weights((a_in + lim) / h)
    nt = tab.shape[0]
    for k in range(n_pts):
        a = a0 + k * dz
        if k < kin or a <= -lim:
            out[k] = 0.0
        elif a >= lim or j + 1 >= nt:
            out[k] = 1.0
        else:
            out[k] = h00 * tab[j, 0] + h10 * tab[j, 1] + h01 * tab[j + 1, 0] + h11 * tab[j + 1, 1]
        if k >= kin:
            j += m_sub


@njit(cache=True)
def spread_base_contact(zi, r, segment, zt, w, width, cutoff, norm, z0, dz, tab, m_sub,
                        buf, col_b, below, Gi, Gc):
    """Spread one flow-base contact's stress directly into ``buf`` columns col_b .. col_b+5:

    * with ``segment``, the segment from r_i to c = r_i - r: v_q (G(z - z_c) - G(z - z_i)),
      v_q = f_a r_b / r_z (midpoint expansion when near-horizontal; ``w`` then carries f);
    * a half-line from height ``zt`` downwards: w_q (1 - G(z - zt)).

    The constant w_q below the supports goes to ``below`` (suffix-summed in
    :func:`finalize_snapshot`).  Nothing is written above max(z_i, z_c, zt) + cutoff w."""
    nz = buf.shape[0]
    lim = cutoff * width
    zc = zi - r[2]
    zlo = min(zt, zi)
    zhi = max(zt, zi)
    if segment:
        zlo = min(zlo, zc)
        zhi = max(zhi, zc)
    k0, k1 = grid_range(0.5 * (zlo + zhi), z0, dz, 0.5 * (zhi - zlo) + lim)
    if k1 < 0:
        return  # everything lies below the grid
    if k0 > nz - 1:  # the grid lies entirely below the contact: the constant only
        for q in range(6):
            below[nz - 1, q] += w[q]
        return
    if k0 < 0:
        k0 = 0
    elif k0 > 0:
        for q in range(6):
            below[k0 - 1, q] += w[q]
    if k1 > nz - 1:
        k1 = nz - 1
    n_pts = k1 - k0 + 1
    if n_pts > Gc.shape[0]:  # a very large particle: scratch arrays of the needed size
        Gi = np.empty(n_pts)
        Gc = np.empty(n_pts)
    cdf_on_grid(zt, z0, dz, k0, n_pts, width, cutoff, tab, m_sub, Gc)
    for q in range(6):
        if w[q] != 0.0:
            for k in range(n_pts):
                buf[k0 + k, col_b + q] += w[q] * (1.0 - Gc[k])
    if not segment:
        return
    f = (r[3], r[4], r[5])
    rz = r[2]
    if abs(rz) >= HORIZONTAL_TOL * width:
        cdf_on_grid(zc, z0, dz, k0, n_pts, width, cutoff, tab, m_sub, Gc)
        cdf_on_grid(zi, z0, dz, k0, n_pts, width, cutoff, tab, m_sub, Gi)
        inv = 1.0 / rz
        for q in range(6):
            v = f[STRESS_AB[q][0]] * r[STRESS_AB[q][1]] * inv
            for k in range(n_pts):
                buf[k0 + k, col_b + q] += v * (Gc[k] - Gi[k])
    else:  # near-horizontal segment: midpoint expansion, as for flow-flow pairs
        zm = 0.5 * (zi + zc)
        w2 = width * width
        for k in range(n_pts):
            a_ = z0 + (k0 + k) * dz - zm
            g = kernel_density(a_, width, cutoff, norm)
            g *= 1.0 + rz * rz * (a_ * a_ / w2 - 1.0) / (24.0 * w2)
            for q in range(6):
                buf[k0 + k, col_b + q] += f[STRESS_AB[q][0]] * r[STRESS_AB[q][1]] * g


@njit(cache=True)
def pair_coefficients(pos, fixed, ci, cj, force, rij, cpoint, width, base_mode,
                      coef, const_base, buf, z0, dz, cutoff, norm, col_contact,
                      tab, m_sub, below):
    """Per-particle stress coefficients from the contact list (Eq. 32, compressive positive).

    coef[:, 0:6] collects the flow-flow coefficients c_ab = f_a r_b / r_z (+ on j, - on i).
    Flow-base contacts: with BASE_THROUGH_CONTACT, coef[:, 6:12] collects c_ab = f_a u_b / u_z
    (- on i; + on const_base when the half-line points down); with the other modes they are
    spread directly into ``buf`` (and ``below``) by :func:`spread_base_contact`.
    Near-horizontal flow-flow pairs are spread directly into ``buf``.
    Returns (number of base contacts whose contact point lies above the flow particle's
    centre, number of degenerate base directions).
    """
    n_up = 0
    n_degenerate = 0
    lim = cutoff * width
    nz = buf.shape[0]
    col_b = col_contact + 6
    Gi = np.empty(int((2.0 * lim + 2.0) / dz) + 8)  # segments up to 2 d tall; grown if needed
    Gc = np.empty(Gi.shape[0])
    for c in range(ci.shape[0]):
        i = ci[c]
        j = cj[c]
        fi = fixed[i]
        fj = fixed[j]
        if fi and fj:
            continue
        sgn = 1.0
        if fi:  # defensive: make i the flow particle (force on i from j flips sign)
            i, j = j, i
            sgn = -1.0
            fj = True
        f = (sgn * force[c, 0], sgn * force[c, 1], sgn * force[c, 2])
        if not fj:
            # flow-flow pair: segment from r_i to r_j, r = r_i - r_j (z from the positions)
            r = (rij[c, 0], rij[c, 1], pos[i, 2] - pos[j, 2])
            if abs(r[2]) >= HORIZONTAL_TOL * width:
                inv = 1.0 / r[2]
                for q in range(6):
                    v = f[STRESS_AB[q][0]] * r[STRESS_AB[q][1]] * inv
                    coef[j, q] += v
                    coef[i, q] -= v
            else:
                zm = 0.5 * (pos[i, 2] + pos[j, 2])
                k0, k1 = grid_range(zm, z0, dz, lim)
                if k0 < 0:
                    k0 = 0
                if k1 > nz - 1:
                    k1 = nz - 1
                w2 = width * width
                for k in range(k0, k1 + 1):
                    a_ = z0 + k * dz - zm
                    g = kernel_density(a_, width, cutoff, norm)
                    g *= 1.0 + r[2] * r[2] * (a_ * a_ / w2 - 1.0) / (24.0 * w2)
                    for q in range(6):
                        buf[k, col_contact + q] += f[STRESS_AB[q][0]] * r[STRESS_AB[q][1]] * g
        else:
            # flow-base pair: u = c - r_i, from the flow particle's centre to the contact point
            if sgn > 0.0:
                u = (cpoint[c, 0] - pos[i, 0], cpoint[c, 1] - pos[i, 1], cpoint[c, 2] - pos[i, 2])
            else:  # contact point given relative to the base particle j: flow particle i sits
                # at (min image) r_j - r_ji, so u = c - r_j + r_ji
                u = (cpoint[c, 0] - pos[j, 0] + rij[c, 0], cpoint[c, 1] - pos[j, 1] + rij[c, 1],
                     cpoint[c, 2] - pos[j, 2] + rij[c, 2])
            if u[2] > 0.0:
                n_up += 1
            if base_mode != BASE_THROUGH_CONTACT:
                zi = pos[i, 2]
                # r = r_i - c (the segment) and f, packed for the kernel
                r6 = (-u[0], -u[1], -u[2], f[0], f[1], f[2])
                wz = (0.0, 0.0, f[2], 0.0, f[0], f[1])  # [b = z] f_a: xx yy zz xy xz yz
                if base_mode == BASE_DOWN:
                    spread_base_contact(zi, r6, False, zi, wz, width, cutoff, norm, z0, dz,
                                        tab, m_sub, buf, col_b, below, Gi, Gc)
                else:  # to the contact point, then straight down
                    spread_base_contact(zi, r6, True, zi - r6[2], wz, width, cutoff, norm, z0,
                                        dz, tab, m_sub, buf, col_b, below, Gi, Gc)
                continue
            un = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
            if un == 0.0 or abs(u[2]) <= DEGENERATE_TOL * un:
                n_degenerate += 1
                u = (0.0, 0.0, -1.0)
            inv = 1.0 / u[2]
            for q in range(6):
                v = f[STRESS_AB[q][0]] * u[STRESS_AB[q][1]] * inv
                coef[i, 6 + q] -= v
                if u[2] < 0.0:
                    const_base[q] += v
    return n_up, n_degenerate


@njit(cache=True)
def spread_particles(pos, vel, mass, diameter, species, fixed, coef, has_coef, width, cutoff,
                     norm, z0, dz, n_species, tab, m_sub, buf, step):
    """Spread every flow particle's momentum, m v v, species mass/volume (kernel density g)
    and its stress coefficients (kernel CDF G) onto the z grid, touching only points within
    the cutoff; the G = 1 plateau above the support goes to ``step`` (prefix-summed later).

    has_coef[i]: 0 none, 1 contact only, 2 base only, 3 both."""
    nz = buf.shape[0]
    lim = cutoff * width
    inv_w2 = 1.0 / (width * width)
    q = math.exp(-dz * dz * inv_w2)
    gnorm = 1.0 / (SQRT2PI * width * norm)
    h = dz / m_sub
    col_sm = N_BASIC
    col_sv = N_BASIC + n_species
    col_c = N_BASIC + 2 * n_species
    col_b = col_c + 6
    cg = np.empty(9)
    cc = np.empty(6)
    Gk = np.empty(int(2.0 * lim / dz) + 3)
    for i in range(pos.shape[0]):
        if fixed[i]:
            continue
        zi = pos[i, 2]
        k0, k1 = grid_range(zi, z0, dz, lim)
        hc = has_coef[i]
        if hc != 0:
            ks = k1 + 1
            if ks < 0:
                ks = 0
            if ks < nz:
                for f_ in range(12):
                    step[ks, f_] += coef[i, f_]
        if k0 < 0:
            k0 = 0
        if k1 > nz - 1:
            k1 = nz - 1
        if k1 < k0:
            continue
        m = mass[i]
        vx = vel[i, 0]
        vy = vel[i, 1]
        vz = vel[i, 2]
        cg[0] = m * vx
        cg[1] = m * vy
        cg[2] = m * vz
        cg[3] = m * vx * vx
        cg[4] = m * vy * vy
        cg[5] = m * vz * vz
        cg[6] = m * vx * vy
        cg[7] = m * vx * vz
        cg[8] = m * vy * vz
        d = diameter[i]
        vol = math.pi * d * d * d / 6.0
        s = species[i]
        a0 = z0 + k0 * dz - zi
        g = gnorm * math.exp(-0.5 * a0 * a0 * inv_w2)
        rr = math.exp(-(2.0 * a0 * dz + dz * dz) * 0.5 * inv_w2)
        for k in range(k0, k1 + 1):
            for f_ in range(9):
                buf[k, 1 + f_] += cg[f_] * g
            buf[k, col_sm + s] += m * g
            buf[k, col_sv + s] += vol * g
            g *= rr
            rr *= q
        if hc == 0:
            continue
        # cubic Hermite interpolation of G; weights fixed per particle (nodes aligned to grid)
        j, h00, h10, h01, h11 = hermite_weights((a0 + lim) / h)
        n_pts = k1 - k0 + 1
        for k in range(n_pts):
            Gk[k] = h00 * tab[j, 0] + h10 * tab[j, 1] + h01 * tab[j + 1, 0] + h11 * tab[j + 1, 1]
            j += m_sub
        if hc & 1:
            for f_ in range(6):
                cc[f_] = coef[i, f_]
            for k in range(n_pts):
                G = Gk[k]
                for f_ in range(6):
                    buf[k0 + k, col_c + f_] += cc[f_] * G
        if hc & 2:
            for f_ in range(6):
                cc[f_] = coef[i, 6 + f_]
            for k in range(n_pts):
                G = Gk[k]
                for f_ in range(6):
                    buf[k0 + k, col_b + f_] += cc[f_] * G


@njit(cache=True)
def finalize_snapshot(buf, step, const_base, below, inv_area, n_species, out):
    """Close one snapshot: prefix-sum the stress plateaus, suffix-sum the base constants below
    the direct base paths (``below``), add the downward base half-line constants, sum the
    species densities, turn sum m v v into the kinetic stress sum m v v g - rho V V
    (fluctuations about the snapshot's own V(z)), scale by 1/(Lx Ly) and add into ``out``
    (the accumulated sums)."""
    nz = buf.shape[0]
    col_c = N_BASIC + 2 * n_species
    ncol = buf.shape[1]
    low = np.zeros(6)
    for k in range(nz - 1, -1, -1):
        for f_ in range(6):
            low[f_] += below[k, f_]
            if low[f_] != 0.0:
                buf[k, col_c + 6 + f_] += low[f_]
    run = np.zeros(12)
    for k in range(nz):
        for f_ in range(12):
            run[f_] += step[k, f_]
            buf[k, col_c + f_] += run[f_]
        for f_ in range(6):
            buf[k, col_c + 6 + f_] += const_base[f_]
        rho = 0.0
        for s in range(n_species):
            rho += buf[k, N_BASIC + s]
        buf[k, 0] = rho
        if rho > 0.0:
            p0 = buf[k, 1]
            p1 = buf[k, 2]
            p2 = buf[k, 3]
            buf[k, 4] -= p0 * p0 / rho
            buf[k, 5] -= p1 * p1 / rho
            buf[k, 6] -= p2 * p2 / rho
            buf[k, 7] -= p0 * p1 / rho
            buf[k, 8] -= p0 * p2 / rho
            buf[k, 9] -= p1 * p2 / rho
        for f_ in range(ncol):
            out[k, f_] += buf[k, f_] * inv_area


@njit(cache=True)
def coarse_grain_snapshot(pos, vel, mass, diameter, species, fixed, ci, cj, force, rij, cpoint,
                          width, cutoff, z0, dz, n_species, inv_area, base_mode,
                          tab, m_sub, buf, step, coef, has_coef, out):
    """One snapshot -> adds its x-y averaged profiles to ``out`` (nz, n_columns).

    ``buf``, ``step`` (nz, 12), ``coef`` (N, 12) and ``has_coef`` (N,) are scratch arrays,
    cleared here; ``tab`` and ``m_sub`` come from :func:`cdf_table`.
    Returns (upward base half-lines, degenerate base directions).
    """
    norm = kernel_norm(cutoff)
    buf[:, :] = 0.0
    step[:, :] = 0.0
    coef[:, :] = 0.0
    const_base = np.zeros(6)
    below = np.zeros((buf.shape[0], 6))
    col_c = N_BASIC + 2 * n_species
    n_up, n_deg = pair_coefficients(pos, fixed, ci, cj, force, rij, cpoint, width, base_mode,
                                    coef, const_base, buf, z0, dz, cutoff, norm, col_c,
                                    tab, m_sub, below)
    for i in range(coef.shape[0]):
        h = 0
        for f_ in range(6):
            if coef[i, f_] != 0.0:
                h = 1
                break
        for f_ in range(6, 12):
            if coef[i, f_] != 0.0:
                h += 2
                break
        has_coef[i] = h
    spread_particles(pos, vel, mass, diameter, species, fixed, coef, has_coef, width, cutoff,
                     norm, z0, dz, n_species, tab, m_sub, buf, step)
    finalize_snapshot(buf, step, const_base, below, inv_area, n_species, out)
    return n_up, n_deg
