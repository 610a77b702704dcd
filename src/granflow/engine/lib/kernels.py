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

Layout of a time step (issue 15: throughput, and the same numbers for any thread count).
:func:`advance` runs, per step, two parallel passes and a few serial scalar reductions:

1. **pair pass** (:func:`pair_pass`) over the *near list*: the listed pairs that were within a
   quarter of the Verlet skin of touching when it was built (:func:`near_pass`; rebuilt after
   an eighth of the skin of displacement; in a dense flow with skin 0.2 it holds ~65 % of the
   listed pairs).  Per block of PAIR_BLOCK near pairs: a vectorised scan finds the touching
   pairs, a branch-free compaction lists them (and those whose contact just opened: a one-byte
   spring flag per pair, so non-touching pairs read no history), and the contact law runs over
   the touching pairs only — for linear-law systems in SIMD form over chunks gathered into a
   per-thread work row (:func:`_linear_maths`: same operations, same order as the scalar
   :func:`_contact_force`, bitwise the same results), otherwise inlined scalar code.  Each
   contact writes one compact row (force, torque on i, torque on j; energy, overlap, normal
   force).  The blocks are split into one run per thread; the first run adds its contacts to
   the forces as it goes, the other runs' rows are added after it, again in pair order, by the
   particle pass (each thread onto its own particles; :func:`push_rows` does the same
   serially).  So every force is summed in pair order, exactly as a serial loop over the pairs
   would, for any number of threads.  The first run writes its rows into a per-thread buffer
   of one block (cache-resident) except at the last step of an :func:`advance` call, whose rows
   the observers read: the pair list's rows of a large system exceed the caches, and writing
   them every step cost a fifth of the step at 1e5 particles.  With the linear law it writes
   no buffer rows at all: :func:`_scatter_linear` adds each contact to the forces straight
   from the work row (the same additions in the same order; 2026-11-28, ~8 % of the step).
2. **particle pass** (:func:`particle_pass`, parallel over fixed blocks of particles, an equal
   share of the blocks per thread): the rows the pair pass's runs 1... left for the thread's
   particles (in pair order), the
   flat-wall contact, the closing half kick of this step and — fused — the opening half kick,
   drift, predicted velocity, force reset to gravity, wall contact and Verlet-skin
   displacements of the next step.  Per-block maxima (overlap, displacement) and partial sums
   (released spring energy) are combined serially in block order: independent of the threads.

At one thread both passes run their bodies (:func:`_pair_runs`, :func:`_particle_blocks`) on
the calling thread instead of launching a parallel region: the same code and numbers, without
the ~1 us per region and step that a one-thread region still costs, which small systems feel
(measured 2026-11-27: 12.6 -> 11.2 us per step at 177 particles, 22.3 -> 21.2 at 602, the
default campaign's thinnest bracket and its H = 10 chute).

The neighbour list is rebuilt (:func:`rebuild_pairs`: hierarchical grid, one search pass) when
a particle has moved more than skin/2.  Systems of at least SORT_MIN_MOBILE mobile particles are
put in spatial order at every SORT_EVERY-th rebuild (:func:`sort_particles`: bins of one diameter
in (x, y, z) order, the state moved exactly, ``ids`` keeping each particle's identity), so that
the particles a pair pass visits together lie together in memory.  The displacements are not measured every step: the
particle pass gives the largest drift speed, :func:`advance` adds dt max|v| to a bound of the
largest displacement since each list's build and measures the displacements
(:func:`displacement_maxima`) only when a bound crosses its threshold; a bound is never below
the displacement, so the lists are rebuilt at the same steps as with a measurement every step
(measured: median 0.963/0.988 -> 1.020/1.014 of LAMMPS on the benchmark chute).  Pairs are unsigned 32-bit indices sorted by (i, j), with
the reduced mass of every pair.  Touching pairs are always in both lists, so the numbers do not
depend on when the lists are rebuilt (nor on the skin) -- except through the spatial sort of
large systems, which happens at rebuilds and changes the order of later sums: their numbers
depend on the skin in the last bits (never on the threads, the chunking of steps or a resume).

Hot loops use unsigned indices (numba adds negative-index handling to signed ones) and
``error_model="numpy"`` (no zero-division checks: a zero distance gives NaN, which the
non-finite guard reports).  The contact maths (:func:`pair_pass` with the inlined scalar law,
:func:`_linear_maths`) is compiled with the fast-math flags CONTACT_FASTMATH: fused multiply-add
and no signed zeros, but neither 'nnan'/'ninf' (the guards) nor 'reassoc' (the summation order
is fixed); divisions by r and by k_t are one reciprocal each.  The numbers are the same for any
thread count (and skin, below SORT_MIN_MOBILE mobile particles), and from run to run and after a kill and resume on the same machine and
software; across CPUs (with or without FMA) or LLVM versions they may differ in the last bits.
The integration (:func:`particle_pass`, including the flat-wall contact) has no fast-math.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from .hgrid import DEFAULT_CAPACITY, hgrid_pairs_u32

LAW_LINEAR = 0
LAW_HERTZ = 1
LAW_PLASTIC = 2
#: Columns of the per-particle flat-wall rows: f (0:3), torque (3:6), (6:9 unused), elastic
#: energy (9; for a contact that opened in the step: the spring energy released), overlap (10),
#: normal force (11).
NROW = 12
#: Columns of the legacy per-pair output (``ParticleSystem.pair_out``): the row plus the released
#: spring energy (12).
NOUT = 13
#: Pair / wall state bytes: no contact, contact (accumulated), contact opened in this step
#: (spring energy released), touching with zero overlap in floating point (not accumulated).
NO_CONTACT = 0
CONTACT = 1
OPENED = 2
GRAZING = 3
#: Particles per block of the particle pass (blocks fix the order of the per-block reductions).
PARTICLE_BLOCK = 256
#: Near pairs per block of the pair pass (blocks fix the order of its per-block sums).
PAIR_BLOCK = 512
#: Marks the step API of issue 15 (used by benchmarks/bench_engine_profile.py).
STEP_API = 1
RELEASE_FRACTION = 0.5
#: LLVM fast-math flags of the contact maths (pair pass, vectorised linear law): fused
#: multiply-add ('contract'), no signed zeros, reciprocal multiplication ('arcp': no effect
#: beside the explicit reciprocals on the benchmark chute, same numbers without it).  Not
#: 'nnan' / 'ninf' (the non-finite guards must see NaN and inf) and not 'reassoc' (the order of
#: every sum is what makes the numbers independent of the thread count).
CONTACT_FASTMATH = {"contract", "arcp", "nsz"}


@njit(cache=True, inline="always")
def _min_image(dx, L):
    return dx - L * np.rint(dx / L)


@njit(cache=True, inline="always")
def _wrap_image(dx, L, half_L):
    """Minimum image of a difference of two wrapped coordinates (|dx| < L): the same value as
    :func:`_min_image` except when |dx| / L rounds to exactly 1/2 (never a touching pair)."""
    if dx > half_L:
        return dx - L
    if dx < -half_L:
        return dx + L
    return dx


@njit(cache=True, inline="always")
def _wrap_select(dx, L, half_L):
    """:func:`_wrap_image` as two selects (vectorisable), the same value."""
    a = dx - L
    dx = a if dx > half_L else dx
    b = dx + L
    return b if dx < -half_L else dx


# --------------------------------------------------------------------------------------------
# contact law of one touching pair (the physics); inlined into the pair and the wall loops
# --------------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _contact_force(nx, ny, nz, r, ri, rj, vi, vj, wi, wj, m_ij, law, coef, spring, dmax,
                   update_history, ds):
    """Force on i from j for one touching pair with unit normal n (from j to i), distance r.

    ``vi, vj, wi, wj`` (3-tuples) are the (predicted) velocities and angular velocities at the
    force time, used by the dashpots; ``coef`` = (kn_hat, gn_hat, kt_hat, gt_hat, mu, k2_hat).
    ``spring`` (3-tuple) is the pair's tangential spring: it is rotated into the current tangent
    plane, advanced by ``ds`` = dt times the relative tangential contact velocity over
    the last step (forward Euler of Eq. 9 with the mid-step velocity, which keeps the elastic
    tangential force conservative) when ``update_history``, and truncated at the Coulomb limit.
    ``dmax`` is the maximum overlap so far (plastic law).

    Returns (f (3), torque on i (3), torque on j (3), elastic energy, overlap, normal force,
    new spring (3), new maximum overlap).
    """
    vix, viy, viz = vi
    vjx, vjy, vjz = vj
    wix, wiy, wiz = wi
    wjx, wjy, wjz = wj
    kn_hat, gn_hat, kt_hat, gt_hat, mu, k2_hat = coef
    sx, sy, sz = spring
    dsx, dsy, dsz = ds
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
    if law == LAW_HERTZ:
        scale = np.sqrt(delta / (ri + rj))
        kn *= scale
        gn *= scale
        kt *= scale
        gt *= scale
        fn = kn * delta - gn * vn
        # elastic energy ke de^2: int_0^delta k sqrt(x/d) x dx = (2/5) k sqrt(delta/d) delta^2
        ke = 0.4 * kn
        de = delta
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
        ke = 0.5 * k2 if delta_e > 0.0 else 0.0
        de = delta_e if delta_e > 0.0 else 0.0
    else:
        fn = kn * delta - gn * vn
        ke = 0.5 * kn
        de = delta

    # tangential spring: rotate into the current tangent plane keeping its length (Eq. 9)
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
            inv_kt = 1.0 / kt  # one division for the three components
            sx = -(ftx + gt * vtx) * inv_kt
            sy = -(fty + gt * vty) * inv_kt
            sz = -(ftz + gt * vtz) * inv_kt
    # elastic energy in one expression, in one place, for every law (the vectorised linear law
    # writes the same expression: the same multiply-add fusion, the same numbers)
    e_el = ke * de * de + 0.5 * kt * (sx * sx + sy * sy + sz * sz)

    fx = fn * nx + ftx
    fy = fn * ny + fty
    fz = fn * nz + ftz
    # torque on i: b_i x f ; on j: b_j x (-f)
    return (fx, fy, fz,
            biy * fz - biz * fy, biz * fx - bix * fz, bix * fy - biy * fx,
            -(bjy * fz - bjz * fy), -(bjz * fx - bjx * fz), -(bjx * fy - bjy * fx),
            e_el, delta, fn, sx, sy, sz, dmax)


@njit(cache=True, inline="always")
def _released_spring_energy(sx, sy, sz, nx, ny, nz, dsx, dsy, dsz, m_ij, law, kt_hat):
    """Elastic energy left in a tangential spring when its contact opens.

    In the dissipation-free limit this energy becomes internal energy of the particles
    (Weinhart et al. 2012, Appendix A); it is accounted so that total energy is conserved.
    The Hertzian spring stiffness vanishes at zero overlap, so nothing is released.
    """
    if law == LAW_HERTZ:
        return 0.0
    sx = sx + dsx
    sy = sy + dsy
    sz = sz + dsz
    sn = sx * nx + sy * ny + sz * nz
    sx -= sn * nx
    sy -= sn * ny
    sz -= sn * nz
    return 0.5 * m_ij * kt_hat * (sx * sx + sy * sy + sz * sz)


@njit(cache=True, inline="always")
def _has_spring(sx, sy, sz):
    # the test the contact law applies to a stored spring (s2 > 0), kept as a one-byte flag
    return sx * sx + sy * sy + sz * sz > 0.0


# --------------------------------------------------------------------------------------------
# coefficient tables
# --------------------------------------------------------------------------------------------
#: Columns of the per-type-pair coefficient table ``coef`` (T, T, NCOEF): stiffness and damping
#: per unit reduced mass, friction coefficient, plastic unloading stiffness.
C_KN, C_GN, C_KT, C_GT, C_MU, C_K2 = 0, 1, 2, 3, 4, 5
NCOEF = 6


def coefficient_table(law_tab, kn_tab, gn_tab, kt_tab, gt_tab, mu_tab, k2_tab):
    """The law table, the packed (T, T, NCOEF) coefficient table and whether every type pair
    uses the linear law (then the pair pass runs the vectorised linear contact)."""
    law = np.ascontiguousarray(law_tab, dtype=np.int64)
    coef = np.ascontiguousarray(np.stack([kn_tab, gn_tab, kt_tab, gt_tab, mu_tab, k2_tab],
                                         axis=-1), dtype=np.float64)
    return law, coef, bool(np.all(law == LAW_LINEAR))


# --------------------------------------------------------------------------------------------
# pair pass
# --------------------------------------------------------------------------------------------
@njit(cache=True, inline="always", error_model="numpy")
def _pair_contact(p, q, pos, vel, omega, vel_h, omega_h, radius, ptype, box, pi, pj, mred,
                  hist_t, hist_dmax, hflag, law_tab, coef, dt, update_history, crow, cext, ridx,
                  prel, pstate, touching):
    """Contact of listed pair p (any law): a touching pair's rows at compact index q, or the
    release of an opened one (returns the released energy; 0 for a touching pair).
    ``box`` = (Lx, Ly, Lx/2, Ly/2)."""
    Lx, Ly, half_Lx, half_Ly = box
    i = pi[p]
    j = pj[p]
    dx = _wrap_image(pos[i, 0] - pos[j, 0], Lx, half_Lx)
    dy = _wrap_image(pos[i, 1] - pos[j, 1], Ly, half_Ly)
    dz = pos[i, 2] - pos[j, 2]
    r2 = dx * dx + dy * dy + dz * dz
    r = np.sqrt(r2)
    ti = ptype[i]
    tj = ptype[j]
    m_ij = mred[p]
    inv_r = 1.0 / r  # one division for the three components of the normal
    nx = dx * inv_r
    ny = dy * inv_r
    nz = dz * inv_r
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
        e_rel = _released_spring_energy(
            hist_t[p, 0], hist_t[p, 1], hist_t[p, 2], nx, ny, nz, RELEASE_FRACTION * dsx,
            RELEASE_FRACTION * dsy, RELEASE_FRACTION * dsz, m_ij, law_tab[ti, tj],
            coef[ti, tj, C_KT])
        prel[p] = e_rel
        pstate[p] = OPENED
        hist_t[p, 0] = 0.0
        hist_t[p, 1] = 0.0
        hist_t[p, 2] = 0.0
        hist_dmax[p] = 0.0
        hflag[p] = 0
        return e_rel
    (fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, e_el, delta, fn, sx, sy, sz,
     dm) = _contact_force(
        nx, ny, nz, r, radius[i], radius[j], (vel[i, 0], vel[i, 1], vel[i, 2]),
        (vel[j, 0], vel[j, 1], vel[j, 2]), (omega[i, 0], omega[i, 1], omega[i, 2]),
        (omega[j, 0], omega[j, 1], omega[j, 2]), m_ij, law_tab[ti, tj],
        (coef[ti, tj, C_KN], coef[ti, tj, C_GN], coef[ti, tj, C_KT], coef[ti, tj, C_GT],
         coef[ti, tj, C_MU], coef[ti, tj, C_K2]), (hist_t[p, 0], hist_t[p, 1], hist_t[p, 2]),
        hist_dmax[p], update_history, (dsx, dsy, dsz))
    crow[q, 0] = fx
    crow[q, 1] = fy
    crow[q, 2] = fz
    crow[q, 3] = tix
    crow[q, 4] = tiy
    crow[q, 5] = tiz
    crow[q, 6] = tjx
    crow[q, 7] = tjy
    crow[q, 8] = tjz
    cext[q, 0] = e_el
    cext[q, 1] = delta
    cext[q, 2] = fn
    ridx[p] = q
    pstate[p] = CONTACT if delta != 0.0 else GRAZING
    if update_history:
        hist_t[p, 0] = sx
        hist_t[p, 1] = sy
        hist_t[p, 2] = sz
        hist_dmax[p] = dm
        hflag[p] = _has_spring(sx, sy, sz)
    return 0.0


# Vectorised linear contact: the touching pairs of a block are processed in chunks of CHUNK;
# their inputs are gathered into a per-thread work row (variables at fixed offsets, CHUNK_STRIDE
# apart: compile-time constant distances, so the maths loop vectorises without alias checks),
# the maths runs over the chunk in SIMD form (no branches: both sides of every choice are
# computed and selected), and the results are scattered back.  Same operations in the same
# order as :func:`_contact_force`, with the same fast-math flags: the results are bitwise those
# of the scalar path (the elastic energy is one expression in both, so that the multiply-add
# fusion is the same; tests/test_engine_threads.py checks it).
#: Contacts per chunk.  Each contact is computed on its own, so the chunk size changes no
#: number, only the speed.  What mattered was the rows' alignment, not the chunk: with rows
#: CHUNK + 3 doubles apart (rows off the 64-byte cache lines, the vector loads straddling them)
#: the benchmark chute's step at one thread took 224 us with CHUNK = 64, 171-176 with 128 and
#: 151-156 with 256 (Zen 5, 2026-11-28; the same pattern on the Xeon host 2026-11-26); with
#: rows a multiple of 8 doubles apart in a 64-byte aligned array (:func:`work_rows`) 145-150
#: with 32, 64, 128 or 256.  256: most blocks of PAIR_BLOCK near pairs are one chunk, and the
#: work row (NWORK x 264 doubles, 106 KB per thread) stays inside the L2.
CHUNK = 256
CHUNK_STRIDE = CHUNK + 8   # a whole number of cache lines, not a power of two
WORK_ALIGN = 64            # bytes: each thread's row starts on a cache line
(W_DX, W_DY, W_DZ, W_RI, W_RJ, W_M, W_KN, W_GN, W_KT, W_GT, W_MU, W_VI, W_VJ, W_WI, W_WJ,
 W_DVH, W_WHI, W_WHJ, W_S) = (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 14, 17, 20, 23, 26, 29, 32)
(W_F, W_TI, W_TJ, W_EEL, W_DELTA, W_FN, W_SN) = (35, 38, 41, 44, 45, 46, 47)
NWORK = 50
WORK_SIZE = NWORK * CHUNK_STRIDE


def work_rows(nthreads):
    """Zeroed per-thread work rows (``nthreads x WORK_SIZE`` doubles) whose rows start on
    WORK_ALIGN-byte boundaries: with CHUNK_STRIDE a multiple of 8 doubles every variable's
    row of a chunk then starts on a cache line, so the maths loop's vector loads do not
    straddle lines (numpy's allocator only guarantees 16 bytes)."""
    per = WORK_ALIGN // 8
    buf = np.zeros(nthreads * WORK_SIZE + per)
    shift = (-buf.ctypes.data % WORK_ALIGN) // 8
    rows = buf[shift:shift + nthreads * WORK_SIZE].reshape(nthreads, WORK_SIZE)
    assert rows.ctypes.data % WORK_ALIGN == 0 and (WORK_SIZE * 8) % WORK_ALIGN == 0
    return rows


@njit(cache=True)
def _gather_linear(work, tid, scratch, q0, m, pos, vel, omega, vel_h, omega_h, radius, ptype,
                   box, pi, pj, mred, hist_t, coef):
    Lx, Ly, half_Lx, half_Ly = box
    w = work[tid]
    q0u = np.uint64(q0)
    for k in range(np.uint64(m)):
        p = scratch[q0u + k]
        i = pi[p]
        j = pj[p]
        ti = ptype[i]
        tj = ptype[j]
        w[np.uint64(W_DX * CHUNK_STRIDE) + k] = _wrap_image(pos[i, 0] - pos[j, 0], Lx, half_Lx)
        w[np.uint64(W_DY * CHUNK_STRIDE) + k] = _wrap_image(pos[i, 1] - pos[j, 1], Ly, half_Ly)
        w[np.uint64(W_DZ * CHUNK_STRIDE) + k] = pos[i, 2] - pos[j, 2]
        w[np.uint64(W_RI * CHUNK_STRIDE) + k] = radius[i]
        w[np.uint64(W_RJ * CHUNK_STRIDE) + k] = radius[j]
        w[np.uint64(W_M * CHUNK_STRIDE) + k] = mred[p]
        w[np.uint64(W_KN * CHUNK_STRIDE) + k] = coef[ti, tj, C_KN]
        w[np.uint64(W_GN * CHUNK_STRIDE) + k] = coef[ti, tj, C_GN]
        w[np.uint64(W_KT * CHUNK_STRIDE) + k] = coef[ti, tj, C_KT]
        w[np.uint64(W_GT * CHUNK_STRIDE) + k] = coef[ti, tj, C_GT]
        w[np.uint64(W_MU * CHUNK_STRIDE) + k] = coef[ti, tj, C_MU]
        for c in range(3):
            w[np.uint64((W_VI + c) * CHUNK_STRIDE) + k] = vel[i, c]
            w[np.uint64((W_VJ + c) * CHUNK_STRIDE) + k] = vel[j, c]
            w[np.uint64((W_WI + c) * CHUNK_STRIDE) + k] = omega[i, c]
            w[np.uint64((W_WJ + c) * CHUNK_STRIDE) + k] = omega[j, c]
            w[np.uint64((W_DVH + c) * CHUNK_STRIDE) + k] = vel_h[i, c] - vel_h[j, c]
            w[np.uint64((W_WHI + c) * CHUNK_STRIDE) + k] = omega_h[i, c]
            w[np.uint64((W_WHJ + c) * CHUNK_STRIDE) + k] = omega_h[j, c]
            w[np.uint64((W_S + c) * CHUNK_STRIDE) + k] = hist_t[p, c]


@njit(cache=True, error_model="numpy", fastmath=CONTACT_FASTMATH)
def _linear_maths(work, tid, m, dt, update_history):
    """The linear contact law (:func:`_contact_force`, law LINEAR, after :func:`_pair_contact`'s
    geometry) over a chunk of the work row, in branch-free form."""
    w = work[tid]
    for k in range(np.uint64(m)):
        dx = w[np.uint64(W_DX * CHUNK_STRIDE) + k]
        dy = w[np.uint64(W_DY * CHUNK_STRIDE) + k]
        dz = w[np.uint64(W_DZ * CHUNK_STRIDE) + k]
        ri = w[np.uint64(W_RI * CHUNK_STRIDE) + k]
        rj = w[np.uint64(W_RJ * CHUNK_STRIDE) + k]
        m_ij = w[np.uint64(W_M * CHUNK_STRIDE) + k]
        r2 = dx * dx + dy * dy + dz * dz
        r = np.sqrt(r2)
        inv_r = 1.0 / r
        nx = dx * inv_r
        ny = dy * inv_r
        nz = dz * inv_r
        bi = -(ri - 0.5 * (ri + rj - r))
        bj = rj - 0.5 * (ri + rj - r)
        whix = w[np.uint64(W_WHI * CHUNK_STRIDE) + k]
        whiy = w[np.uint64((W_WHI + 1) * CHUNK_STRIDE) + k]
        whiz = w[np.uint64((W_WHI + 2) * CHUNK_STRIDE) + k]
        whjx = w[np.uint64(W_WHJ * CHUNK_STRIDE) + k]
        whjy = w[np.uint64((W_WHJ + 1) * CHUNK_STRIDE) + k]
        whjz = w[np.uint64((W_WHJ + 2) * CHUNK_STRIDE) + k]
        dsx = dt * (w[np.uint64(W_DVH * CHUNK_STRIDE) + k] + bi * (whiy * nz - whiz * ny)
                    - bj * (whjy * nz - whjz * ny))
        dsy = dt * (w[np.uint64((W_DVH + 1) * CHUNK_STRIDE) + k] + bi * (whiz * nx - whix * nz)
                    - bj * (whjz * nx - whjx * nz))
        dsz = dt * (w[np.uint64((W_DVH + 2) * CHUNK_STRIDE) + k] + bi * (whix * ny - whiy * nx)
                    - bj * (whjx * ny - whjy * nx))
        delta = ri + rj - r
        bix = bi * nx
        biy = bi * ny
        biz = bi * nz
        bjx = bj * nx
        bjy = bj * ny
        bjz = bj * nz
        vix = w[np.uint64(W_VI * CHUNK_STRIDE) + k]
        viy = w[np.uint64((W_VI + 1) * CHUNK_STRIDE) + k]
        viz = w[np.uint64((W_VI + 2) * CHUNK_STRIDE) + k]
        vjx = w[np.uint64(W_VJ * CHUNK_STRIDE) + k]
        vjy = w[np.uint64((W_VJ + 1) * CHUNK_STRIDE) + k]
        vjz = w[np.uint64((W_VJ + 2) * CHUNK_STRIDE) + k]
        wix = w[np.uint64(W_WI * CHUNK_STRIDE) + k]
        wiy = w[np.uint64((W_WI + 1) * CHUNK_STRIDE) + k]
        wiz = w[np.uint64((W_WI + 2) * CHUNK_STRIDE) + k]
        wjx = w[np.uint64(W_WJ * CHUNK_STRIDE) + k]
        wjy = w[np.uint64((W_WJ + 1) * CHUNK_STRIDE) + k]
        wjz = w[np.uint64((W_WJ + 2) * CHUNK_STRIDE) + k]
        vx = vix + (wiy * biz - wiz * biy) - vjx - (wjy * bjz - wjz * bjy)
        vy = viy + (wiz * bix - wix * biz) - vjy - (wjz * bjx - wjx * bjz)
        vz = viz + (wix * biy - wiy * bix) - vjz - (wjx * bjy - wjy * bjx)
        vn = vx * nx + vy * ny + vz * nz
        vtx = vx - vn * nx
        vty = vy - vn * ny
        vtz = vz - vn * nz
        kn = m_ij * w[np.uint64(W_KN * CHUNK_STRIDE) + k]
        gn = m_ij * w[np.uint64(W_GN * CHUNK_STRIDE) + k]
        kt = m_ij * w[np.uint64(W_KT * CHUNK_STRIDE) + k]
        gt = m_ij * w[np.uint64(W_GT * CHUNK_STRIDE) + k]
        fn = kn * delta - gn * vn
        # spring rotated into the tangent plane keeping its length (s2 > 0, p2 > 0)
        sx = w[np.uint64(W_S * CHUNK_STRIDE) + k]
        sy = w[np.uint64((W_S + 1) * CHUNK_STRIDE) + k]
        sz = w[np.uint64((W_S + 2) * CHUNK_STRIDE) + k]
        s2 = sx * sx + sy * sy + sz * sz
        rotate = s2 > 0.0
        sn = sx * nx + sy * ny + sz * nz
        px = sx - sn * nx
        py = sy - sn * ny
        pz = sz - sn * nz
        sx = px if rotate else sx
        sy = py if rotate else sy
        sz = pz if rotate else sz
        p2 = sx * sx + sy * sy + sz * sz
        fac = np.sqrt(s2 / p2)
        rescale = rotate & (p2 > 0.0)
        px = sx * fac
        py = sy * fac
        pz = sz * fac
        sx = px if rescale else sx
        sy = py if rescale else sy
        sz = pz if rescale else sz
        if update_history:
            dn = dsx * nx + dsy * ny + dsz * nz
            sx += dsx - dn * nx
            sy += dsy - dn * ny
            sz += dsz - dn * nz
        ftx = -kt * sx - gt * vtx
        fty = -kt * sy - gt * vty
        ftz = -kt * sz - gt * vtz
        ft2 = ftx * ftx + fty * fty + ftz * ftz
        fmax = w[np.uint64(W_MU * CHUNK_STRIDE) + k] * abs(fn)
        # sliding: truncate the spring so that |f_t| = mu_c |f_n|
        slide = ft2 > fmax * fmax
        c = fmax / np.sqrt(ft2)
        px = ftx * c
        py = fty * c
        pz = ftz * c
        ftx = px if slide else ftx
        fty = py if slide else fty
        ftz = pz if slide else ftz
        reset = slide & (kt > 0.0)
        inv_kt = 1.0 / kt
        px = -(ftx + gt * vtx) * inv_kt
        py = -(fty + gt * vty) * inv_kt
        pz = -(ftz + gt * vtz) * inv_kt
        sx = px if reset else sx
        sy = py if reset else sy
        sz = pz if reset else sz
        ke = 0.5 * kn
        e_el = ke * delta * delta + 0.5 * kt * (sx * sx + sy * sy + sz * sz)
        fx = fn * nx + ftx
        fy = fn * ny + fty
        fz = fn * nz + ftz
        w[np.uint64(W_F * CHUNK_STRIDE) + k] = fx
        w[np.uint64((W_F + 1) * CHUNK_STRIDE) + k] = fy
        w[np.uint64((W_F + 2) * CHUNK_STRIDE) + k] = fz
        w[np.uint64(W_TI * CHUNK_STRIDE) + k] = biy * fz - biz * fy
        w[np.uint64((W_TI + 1) * CHUNK_STRIDE) + k] = biz * fx - bix * fz
        w[np.uint64((W_TI + 2) * CHUNK_STRIDE) + k] = bix * fy - biy * fx
        w[np.uint64(W_TJ * CHUNK_STRIDE) + k] = -(bjy * fz - bjz * fy)
        w[np.uint64((W_TJ + 1) * CHUNK_STRIDE) + k] = -(bjz * fx - bjx * fz)
        w[np.uint64((W_TJ + 2) * CHUNK_STRIDE) + k] = -(bjx * fy - bjy * fx)
        w[np.uint64(W_EEL * CHUNK_STRIDE) + k] = e_el
        w[np.uint64(W_DELTA * CHUNK_STRIDE) + k] = delta
        w[np.uint64(W_FN * CHUNK_STRIDE) + k] = fn
        w[np.uint64(W_SN * CHUNK_STRIDE) + k] = sx
        w[np.uint64((W_SN + 1) * CHUNK_STRIDE) + k] = sy
        w[np.uint64((W_SN + 2) * CHUNK_STRIDE) + k] = sz


@njit(cache=True)
def _scatter_linear(work, tid, scratch, q0, m, update_history, crow, cext, ridx, pstate, hist_t,
                    hflag, roff, write_rows, push, pi, pj, force, torque, ov):
    """Results of a chunk back to the pairs: rows at ``q - roff`` (``roff`` = 0: the rows of
    the pair list; the block's start: a block-local row buffer), unless ``write_rows`` is
    False (rows nobody reads); ``push``: the contacts added to ``force`` and ``torque`` from
    the work row, in pair order (what :func:`_pair_runs` does with the rows for the other
    laws: the same additions in the same order, without writing and re-reading the rows).
    Returns the largest overlap of the chunk's contacts and ``ov``."""
    w = work[tid]
    q0u = np.uint64(q0)
    r0u = np.uint64(q0 - roff)
    for k in range(np.uint64(m)):
        q = q0u + k
        p = scratch[q]
        delta = w[np.uint64(W_DELTA * CHUNK_STRIDE) + k]
        if write_rows:
            r = r0u + k
            for c in range(9):
                crow[r, c] = w[np.uint64((W_F + c) * CHUNK_STRIDE) + k]
            cext[r, 0] = w[np.uint64(W_EEL * CHUNK_STRIDE) + k]
            cext[r, 1] = delta
            cext[r, 2] = w[np.uint64(W_FN * CHUNK_STRIDE) + k]
        ridx[p] = q
        if delta != 0.0:
            pstate[p] = CONTACT
            if push:
                i = pi[p]
                j = pj[p]
                for c in range(3):
                    f = w[np.uint64((W_F + c) * CHUNK_STRIDE) + k]
                    force[i, c] += f
                    force[j, c] -= f
                    torque[i, c] += w[np.uint64((W_TI + c) * CHUNK_STRIDE) + k]
                    torque[j, c] += w[np.uint64((W_TJ + c) * CHUNK_STRIDE) + k]
            if delta > ov:
                ov = delta
        else:
            pstate[p] = GRAZING
        if update_history:
            sx = w[np.uint64(W_SN * CHUNK_STRIDE) + k]
            sy = w[np.uint64((W_SN + 1) * CHUNK_STRIDE) + k]
            sz = w[np.uint64((W_SN + 2) * CHUNK_STRIDE) + k]
            hist_t[p, 0] = sx
            hist_t[p, 1] = sy
            hist_t[p, 2] = sz
            hflag[p] = _has_spring(sx, sy, sz)
    return ov


@njit(cache=True, error_model="numpy", fastmath=CONTACT_FASTMATH)
def _pair_runs(s0, s1, pos, vel, omega, vel_h, omega_h, radius, ptype, Lx, Ly, pi, pj, mred,
               hist_t, hist_dmax, hflag, law_tab, coef, all_linear, work, dt, update_history, crow,
               cext, ridx, prel, pstate, scratch, blk_overlap, blk_erel, blk_nc, run_start,
               force, torque, near, near_n, ntouch, keep_rows, lrow, lext):
    """Runs ``s0:s1`` of :func:`pair_pass` (its body; serial), on the calling thread."""
    nnear = near_n[0]
    box = (Lx, Ly, 0.5 * Lx, 0.5 * Ly)
    half_Lx = 0.5 * Lx
    half_Ly = 0.5 * Ly
    for slot in range(s0, s1):
        local = slot == 0 and not keep_rows
        tid = numba.get_thread_id()
        if local:
            rc = lrow[tid]
            re = lext[tid]
        else:
            rc = crow
            re = cext
        for b in range(run_start[slot], run_start[slot + 1]):
            k0 = b * PAIR_BLOCK
            k1 = min(k0 + PAIR_BLOCK, nnear)
            roff = k0 if local else 0
            # scan of the block's near pairs (vectorised, gathers; unsigned indices: no
            # negative-index handling): which pairs touch
            for k in range(np.uint64(k0), np.uint64(k1)):
                p = near[k]
                i = pi[p]
                j = pj[p]
                dx = _wrap_select(pos[i, 0] - pos[j, 0], Lx, half_Lx)
                dy = _wrap_select(pos[i, 1] - pos[j, 1], Ly, half_Ly)
                dz = pos[i, 2] - pos[j, 2]
                r2 = dx * dx + dy * dy + dz * dz
                rsum = radius[i] + radius[j]
                ntouch[k] = r2 < rsum * rsum
            # compaction (branch-free): touching pairs to the front of the block's scratch, pairs
            # whose contact opened (a spring, no longer touching) to its back
            ncu = np.uint64(k0)
            nou = np.uint64(k1)
            for k in range(np.uint64(k0), np.uint64(k1)):
                p = near[k]
                t = ntouch[k]
                pstate[p] = t
                scratch[ncu] = p
                ncu += np.uint64(t)
                scratch[nou - np.uint64(1)] = p  # a free slot (or the one just taken, same p)
                nou -= np.uint64(hflag[p] & (t ^ 1))
            nc = np.int64(ncu)
            no = np.int64(nou)
            # release of the opened contacts (in pair order)
            erel = 0.0
            if update_history:
                for q in range(k1 - 1, no - 1, -1):
                    erel += _pair_contact(np.int64(scratch[q]), 0, pos, vel, omega, vel_h,
                                          omega_h, radius, ptype, box, pi, pj, mred, hist_t,
                                          hist_dmax, hflag, law_tab, coef, dt, update_history,
                                          rc, re, ridx, prel, pstate, False)
            # contacts of the touching pairs (rows at q - roff); the first run adds its
            # contacts to the forces (linear law: straight from the work row, its block
            # buffer rows not written; others: from the rows, below); largest overlap
            ov = 0.0
            if all_linear:
                for q0 in range(k0, nc, CHUNK):
                    m = min(CHUNK, nc - q0)
                    _gather_linear(work, tid, scratch, q0, m, pos, vel, omega, vel_h, omega_h,
                                   radius, ptype, box, pi, pj, mred, hist_t, coef)
                    _linear_maths(work, tid, m, dt, update_history)
                    ov = _scatter_linear(work, tid, scratch, q0, m, update_history, rc, re,
                                         ridx, pstate, hist_t, hflag, roff, not local,
                                         slot == 0, pi, pj, force, torque, ov)
            else:
                for q in range(k0, nc):
                    _pair_contact(np.int64(scratch[q]), q - roff, pos, vel, omega, vel_h,
                                  omega_h, radius, ptype, box, pi, pj, mred, hist_t, hist_dmax,
                                  hflag, law_tab, coef, dt, update_history, rc, re, ridx, prel,
                                  pstate, True)
                    if local:
                        ridx[scratch[q]] = q
                # push the contacts (first run of blocks); largest overlap of the block
                for q in range(np.uint64(k0), np.uint64(nc)):
                    p = scratch[q]
                    r = q - np.uint64(roff)
                    if pstate[p] == CONTACT:
                        if slot == 0:
                            i = pi[p]
                            j = pj[p]
                            for k in range(3):
                                force[i, k] += rc[r, k]
                                force[j, k] -= rc[r, k]
                                torque[i, k] += rc[r, 3 + k]
                                torque[j, k] += rc[r, 6 + k]
                        if re[r, 1] > ov:
                            ov = re[r, 1]
            blk_overlap[b] = ov
            blk_erel[b] = erel
            blk_nc[b] = nc - k0


@njit(cache=True, parallel=True, error_model="numpy", fastmath=CONTACT_FASTMATH)
def pair_pass(pos, vel, omega, vel_h, omega_h, radius, ptype, Lx, Ly, pi, pj, mred, hist_t,
              hist_dmax, hflag, law_tab, coef, all_linear, work, dt, update_history, crow, cext,
              ridx, prel, pstate, scratch, blk_overlap, blk_erel, blk_nc, run_start, force,
              torque, near, near_n, ntouch, keep_rows, lrow, lext):
    """Contact forces of the pairs of the near list (see the module docstring).

    ``vel, omega`` are the velocities at the force time (dashpots), ``vel_h, omega_h`` the
    mid-step velocities of the last drift (tangential spring increment).  Only the pairs of the
    near list ``near[:near_n[0]]`` (:func:`near_pass`; in pair order) are examined: the others
    cannot touch.  They are processed in blocks of PAIR_BLOCK near entries; ``ntouch[k]`` says
    whether near entry k touches; the touching pairs of block b, in pair order, get the compact
    indices q = b PAIR_BLOCK, b PAIR_BLOCK + 1, ... (``ridx[p] = q``): ``crow[q]`` = force on i
    (0:3), torque on i (3:6), torque on j (6:9), ``cext[q]`` = elastic energy, overlap, normal
    force; ``pstate[p]`` = CONTACT (or GRAZING: touching with zero overlap in floating point,
    not accumulated).  A pair that stops touching while it carries a spring releases the
    spring's energy (``prel[p]``, state OPENED) and loses its history.  Per block: the largest
    overlap and the released energy (summed in pair order).  ``scratch`` (uint32, one per
    pair) holds the block-local lists of touching pairs; ``work`` (one row per thread) the
    vectorised linear contacts (``all_linear``).

    The blocks are split into contiguous runs, one per thread: run s is blocks
    ``run_start[s]:run_start[s + 1]`` (:func:`split_runs` balances them by the contacts each
    block had at the previous step).  The first run adds its contacts to ``force`` and
    ``torque`` (which hold gravity) in pair order as it goes; the others leave their rows
    (``blk_nc[b]`` contacts in block b) for :func:`particle_pass` (``push``) or
    :func:`push_rows`, which add them afterwards, again in pair order.  So every force is
    summed in pair order, whatever the number of threads and wherever the runs split: the
    same numbers for any count.

    ``keep_rows`` False (a step whose rows nobody reads: not the last of an :func:`advance`
    call): the first run writes its rows into the per-thread block buffers ``lrow[tid]``,
    ``lext[tid]`` (PAIR_BLOCK rows, cache-resident) instead of ``crow``/``cext`` (which exceed
    the caches of a large system), and adds them from there: the same numbers; ``ridx`` and the
    rows of the pair list are then stale until a step that keeps them.
    """
    nslots = run_start.shape[0] - 1
    if nslots == 1:
        # one run (one thread): no parallel region to launch (~1 us per region and step)
        _pair_runs(np.int64(0), np.int64(1), pos, vel, omega, vel_h, omega_h, radius, ptype, Lx,
                   Ly, pi, pj, mred, hist_t, hist_dmax, hflag, law_tab, coef, all_linear, work,
                   dt, update_history, crow, cext, ridx, prel, pstate, scratch, blk_overlap,
                   blk_erel, blk_nc, run_start, force, torque, near, near_n, ntouch, keep_rows,
                   lrow, lext)
    else:
        for su in prange(nslots):
            slot = np.int64(su)
            _pair_runs(slot, slot + 1, pos, vel, omega, vel_h, omega_h, radius, ptype, Lx, Ly,
                       pi, pj, mred, hist_t, hist_dmax, hflag, law_tab, coef, all_linear, work,
                       dt, update_history, crow, cext, ridx, prel, pstate, scratch, blk_overlap,
                       blk_erel, blk_nc, run_start, force, torque, near, near_n, ntouch,
                       keep_rows, lrow, lext)


#: Cost of a contact in the pair pass, in units of the cost of scanning one near pair, and the
#: extra cost of adding a contact to the forces in the first run (measured on the benchmark
#: chute at one thread, 2026-11-24: ~6.8 ns per near pair, ~57 ns per contact, ~5 ns per push;
#: the split changes no number, only the balance of the threads).
CONTACT_COST = 8.0
PUSH_COST = 1.0


@njit(cache=True)
def split_runs(nnear, blk_nc, nslots, run_start):
    """Split the near list's blocks into ``nslots`` contiguous runs of about equal work
    (``run_start``, nslots + 1 block boundaries): a block costs its near pairs plus
    CONTACT_COST times its contacts at the last step (``blk_nc``; 0 for blocks that did not
    exist), the first run also PUSH_COST per contact (it adds its contacts to the forces while
    the others compute; the particle pass adds theirs afterwards).  Any split gives the same
    numbers: it only moves work between threads."""
    nblock = (nnear + PAIR_BLOCK - 1) // PAIR_BLOCK
    run_start[0] = 0
    run_start[nslots] = nblock
    if nslots == 1:
        return
    total = 0.0
    for b in range(nblock):
        k0 = b * PAIR_BLOCK
        total += min(k0 + PAIR_BLOCK, nnear) - k0 + CONTACT_COST * blk_nc[b]
    # the first run: the number of blocks x that minimises the larger of its cost (with the
    # pushes) and an equal share of the rest
    first = 0.0
    rest = total
    x = 0
    best = rest / (nslots - 1)
    for b in range(nblock):
        k0 = b * PAIR_BLOCK
        c = min(k0 + PAIR_BLOCK, nnear) - k0 + CONTACT_COST * blk_nc[b]
        f = first + c + PUSH_COST * blk_nc[b]
        r = rest - c
        worse = max(f, r / (nslots - 1))
        if worse > best:
            break
        best = worse
        first = f
        rest = r
        x = b + 1
    run_start[1] = x
    # the other runs: equal shares of the rest
    share = rest / (nslots - 1)
    acc = 0.0
    s = 2
    for b in range(x, nblock):
        if s >= nslots:
            break
        k0 = b * PAIR_BLOCK
        acc += min(k0 + PAIR_BLOCK, nnear) - k0 + CONTACT_COST * blk_nc[b]
        if acc >= share * (s - 1):
            run_start[s] = b + 1
            s += 1
    while s < nslots:
        run_start[s] = nblock
        s += 1


@njit(cache=True)
def _push_rows_into(b0, b1, lo, hi, pi, pj, crow, pstate, scratch, blk_nc, force, torque):
    """:func:`push_rows` for near-list blocks ``b0:b1``, onto the particles ``lo <= k < hi``
    only (the others' rows are skipped): each particle still gets its contacts in pair order.
    The pairs are (i < j) sorted by (i, j), so the scan stops at the first contact with
    i >= hi (returns True then: no later row reaches the range either)."""
    for b in range(b0, b1):
        k0 = b * PAIR_BLOCK
        for q in range(np.uint64(k0), np.uint64(k0 + blk_nc[b])):
            p = scratch[q]
            if pstate[p] == CONTACT:
                i = np.int64(pi[p])
                if i >= hi:
                    return True
                j = np.int64(pj[p])
                if lo <= i:
                    for k in range(3):
                        force[i, k] += crow[q, k]
                        torque[i, k] += crow[q, 3 + k]
                if lo <= j and j < hi:
                    for k in range(3):
                        force[j, k] -= crow[q, k]
                        torque[j, k] += crow[q, 6 + k]
    return False


@njit(cache=True)
def push_rows(b_start, nnear, pi, pj, crow, pstate, scratch, blk_nc, force, torque):
    """Add the contacts of near-list blocks ``b_start...`` (left as rows by :func:`pair_pass`)
    to the forces and torques, in pair order (serially; :func:`particle_pass` with ``push``
    does it per thread)."""
    nblock = (nnear + PAIR_BLOCK - 1) // PAIR_BLOCK
    _push_rows_into(b_start, nblock, np.int64(0), np.int64(force.shape[0]), pi, pj, crow,
                    pstate, scratch, blk_nc, force, torque)


#: Skin of the near list, as a fraction of the neighbour-list skin: the pair pass examines only
#: the pairs closer than r_i + r_j + NEAR_FRACTION * skin at the near list's build, which is
#: rebuilt (from the neighbour list) when a particle has moved NEAR_FRACTION * skin / 2.  (In a
#: dense flow with skin 0.2, 65 % of the listed pairs are within 0.05 of touching.)
NEAR_FRACTION = 0.25


@njit(cache=True, error_model="numpy")
def _near_blocks(b0, b1, pos, radius, hflag, Lx, Ly, pi, pj, near_skin, near_tmp, near_count,
                 pstate):
    """Blocks ``b0:b1`` of :func:`near_pass` (its body; serial), on the calling thread."""
    npair = pi.shape[0]
    half_Lx = 0.5 * Lx
    half_Ly = 0.5 * Ly
    for b in range(b0, b1):
        p0 = b * PAIR_BLOCK
        p1 = min(p0 + PAIR_BLOCK, npair)
        for p in range(np.uint64(p0), np.uint64(p1)):
            i = pi[p]
            j = pj[p]
            dx = _wrap_select(pos[i, 0] - pos[j, 0], Lx, half_Lx)
            dy = _wrap_select(pos[i, 1] - pos[j, 1], Ly, half_Ly)
            dz = pos[i, 2] - pos[j, 2]
            r2 = dx * dx + dy * dy + dz * dz
            rc = radius[i] + radius[j] + near_skin
            pstate[p] = (r2 < rc * rc) | (hflag[p] != 0)
        c = np.uint64(p0)
        for p in range(np.uint64(p0), np.uint64(p1)):
            t = pstate[p]
            near_tmp[c] = p
            c += np.uint64(t)
            pstate[p] = NO_CONTACT
        near_count[b] = np.int64(c) - p0


@njit(cache=True, parallel=True, error_model="numpy")
def near_pass(pos, radius, hflag, Lx, Ly, pi, pj, near_skin, near_tmp, near_count, pstate,
              serial):
    """Near pairs per block of PAIR_BLOCK listed pairs: those closer than
    r_i + r_j + ``near_skin`` (and every pair that carries a spring), in pair order, at
    ``near_tmp[b PAIR_BLOCK:]``, their number in ``near_count[b]``; every pair's state is reset
    (pairs outside the near list keep NO_CONTACT until the next near list).  ``serial``: all
    blocks on the calling thread, no parallel region (the same numbers)."""
    npair = pi.shape[0]
    nblock = (npair + PAIR_BLOCK - 1) // PAIR_BLOCK
    if serial or nblock <= 1:
        # one thread or one block: no parallel region to launch (~1 us per region)
        _near_blocks(np.int64(0), np.int64(nblock), pos, radius, hflag, Lx, Ly, pi, pj,
                     near_skin, near_tmp, near_count, pstate)
    else:
        for bu in prange(nblock):
            b = np.int64(bu)
            _near_blocks(b, b + 1, pos, radius, hflag, Lx, Ly, pi, pj, near_skin, near_tmp,
                         near_count, pstate)


@njit(cache=True)
def near_index(near_tmp, near_count, near, near_n):
    """The near list in pair order, ``near[:near_n[0]]``, from the per-block lists of
    :func:`near_pass`."""
    c = 0
    for b in range(near_count.shape[0]):
        p0 = b * PAIR_BLOCK
        for k in range(p0, p0 + near_count[b]):
            near[c] = near_tmp[k]
            c += 1
    near_n[0] = c


# --------------------------------------------------------------------------------------------
# particle pass: kicks, drift, predicted velocity, flat wall, skin check
# --------------------------------------------------------------------------------------------
@njit(cache=True, inline="always", error_model="numpy")
def _wall_contact(i, pos, vel, omega, vel_h, omega_h, radius, inv_mass, ptype, wall_type,
                  wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef, dt,
                  update_history):
    """Contact of mobile particle i with the flat frictional wall z = 0 (lambda = 0 base)."""
    if inv_mass[i] == 0.0 or pos[i, 2] >= radius[i]:
        wall_state[i] = NO_CONTACT
        if update_history and inv_mass[i] > 0.0:
            sx = wall_hist[i, 0]
            sy = wall_hist[i, 1]
            sz = wall_hist[i, 2]
            if _has_spring(sx, sy, sz):
                bi = -radius[i]
                wall_rows[i, 9] = _released_spring_energy(
                    sx, sy, sz, 0.0, 0.0, 1.0,
                    RELEASE_FRACTION * dt * (vel_h[i, 0] + bi * omega_h[i, 1]),
                    RELEASE_FRACTION * dt * (vel_h[i, 1] - bi * omega_h[i, 0]), 0.0,
                    1.0 / inv_mass[i], law_tab[ptype[i], wall_type],
                    coef[ptype[i], wall_type, C_KT])
                wall_state[i] = OPENED
        if update_history:
            wall_hist[i, 0] = 0.0
            wall_hist[i, 1] = 0.0
            wall_hist[i, 2] = 0.0
            wall_dmax[i] = 0.0
        return
    ti = ptype[i]
    # the wall acts as a sphere of zero radius at (x, y, 0) touching from below
    r = pos[i, 2]
    bi = -(radius[i] - 0.5 * (radius[i] - r))
    dsx = dt * (vel_h[i, 0] + bi * omega_h[i, 1])
    dsy = dt * (vel_h[i, 1] - bi * omega_h[i, 0])
    dsz = dt * vel_h[i, 2]
    (fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, e_el, delta, fn, sx, sy, sz,
     dm) = _contact_force(
        0.0, 0.0, 1.0, r, radius[i], 0.0, (vel[i, 0], vel[i, 1], vel[i, 2]), (0.0, 0.0, 0.0),
        (omega[i, 0], omega[i, 1], omega[i, 2]), (0.0, 0.0, 0.0), 1.0 / inv_mass[i],
        law_tab[ti, wall_type],
        (coef[ti, wall_type, C_KN], coef[ti, wall_type, C_GN], coef[ti, wall_type, C_KT],
         coef[ti, wall_type, C_GT], coef[ti, wall_type, C_MU], coef[ti, wall_type, C_K2]),
        (wall_hist[i, 0], wall_hist[i, 1], wall_hist[i, 2]), wall_dmax[i], update_history,
        (dsx, dsy, dsz))
    wall_rows[i, 0] = fx
    wall_rows[i, 1] = fy
    wall_rows[i, 2] = fz
    wall_rows[i, 3] = tix
    wall_rows[i, 4] = tiy
    wall_rows[i, 5] = tiz
    wall_rows[i, 6] = tjx
    wall_rows[i, 7] = tjy
    wall_rows[i, 8] = tjz
    wall_rows[i, 9] = e_el
    wall_rows[i, 10] = delta
    wall_rows[i, 11] = fn
    wall_state[i] = CONTACT if delta != 0.0 else GRAZING
    if update_history:
        wall_hist[i, 0] = sx
        wall_hist[i, 1] = sy
        wall_hist[i, 2] = sz
        wall_dmax[i] = dm


@njit(cache=True, error_model="numpy")
def _particle_blocks(
    b0, b1, do_reset, do_sum, do_kick, do_begin, do_wall, pos, vel, omega, vel_p, omega_p, force,
    torque, radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec, dt, use_wall, wall_type,
    wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef, pos_ref, blk_overlap,
    blk_erel, blk_bad, blk_disp, near_ref, blk_disp_near,
):
    """Blocks ``b0:b1`` of :func:`particle_pass` (its body; serial), on the calling thread."""
    n = pos.shape[0]
    h = 0.5 * dt
    g0 = gvec[0]
    g1 = gvec[1]
    g2 = gvec[2]
    integrate = do_kick or do_begin
    for b in range(b0, b1):
        # unsigned particle indices: no negative-index handling in the loops
        i0 = np.uint64(b * PARTICLE_BLOCK)
        i1 = np.uint64(min(b * PARTICLE_BLOCK + PARTICLE_BLOCK, n))
        # initial forces of a run (compute_forces): wall contacts, force reset
        if do_wall and use_wall:
            for i in range(i0, i1):
                _wall_contact(i, pos, vel, omega, vel, omega, radius, inv_mass, ptype, wall_type,
                              wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef, dt,
                              False)
        if do_reset:
            for i in range(i0, i1):
                if inv_mass[i] > 0.0:
                    for k in range(3):
                        force[i, k] = mass[i] * gvec[k]
                else:
                    for k in range(3):
                        force[i, k] = 0.0
                for k in range(3):
                    torque[i, k] = 0.0
        ov = 0.0
        erel_wall = 0.0
        bad = False
        disp = 0.0
        if not (do_sum or integrate):
            blk_overlap[b] = ov
            blk_erel[b] = erel_wall
            blk_bad[b] = bad
            blk_disp[b] = disp
            blk_disp_near[b] = 0.0
            continue
        # the step's parts, fused: one visit per particle
        for i in range(i0, i1):
            f0 = force[i, 0]
            f1 = force[i, 1]
            f2 = force[i, 2]
            t0 = torque[i, 0]
            t1 = torque[i, 1]
            t2 = torque[i, 2]
            if do_sum:
                # the wall row onto the pairs' sum (force, torque are written back: they are
                # the step's forces if no next step begins here)
                if use_wall:
                    st = wall_state[i]
                    if st == CONTACT:
                        f0 += wall_rows[i, 0]
                        f1 += wall_rows[i, 1]
                        f2 += wall_rows[i, 2]
                        t0 += wall_rows[i, 3]
                        t1 += wall_rows[i, 4]
                        t2 += wall_rows[i, 5]
                        force[i, 0] = f0
                        force[i, 1] = f1
                        force[i, 2] = f2
                        torque[i, 0] = t0
                        torque[i, 1] = t1
                        torque[i, 2] = t2
                        if wall_rows[i, 10] > ov:
                            ov = wall_rows[i, 10]
                    elif st == OPENED:
                        erel_wall += wall_rows[i, 9]
                if not np.isfinite(f0 + f1 + f2 + t0 + t1 + t2):
                    bad = True
            if not integrate:
                continue
            im = inv_mass[i]
            ii = inv_inertia[i]
            v0 = vel[i, 0]
            v1 = vel[i, 1]
            v2 = vel[i, 2]
            w0 = omega[i, 0]
            w1 = omega[i, 1]
            w2 = omega[i, 2]
            if im != 0.0:
                if do_kick and do_begin:
                    # closing half kick of this step and opening half kick of the next (two
                    # roundings)
                    dv0 = h * f0 * im
                    dv1 = h * f1 * im
                    dv2 = h * f2 * im
                    dw0 = h * t0 * ii
                    dw1 = h * t1 * ii
                    dw2 = h * t2 * ii
                    v0 = (v0 + dv0) + dv0
                    v1 = (v1 + dv1) + dv1
                    v2 = (v2 + dv2) + dv2
                    w0 = (w0 + dw0) + dw0
                    w1 = (w1 + dw1) + dw1
                    w2 = (w2 + dw2) + dw2
                else:
                    v0 += h * f0 * im
                    v1 += h * f1 * im
                    v2 += h * f2 * im
                    w0 += h * t0 * ii
                    w1 += h * t1 * ii
                    w2 += h * t2 * ii
                vel[i, 0] = v0
                vel[i, 1] = v1
                vel[i, 2] = v2
                omega[i, 0] = w0
                omega[i, 1] = w1
                omega[i, 2] = w2
            if not do_begin:
                continue
            # drift
            if im != 0.0:
                x = pos[i, 0] + dt * v0
                y = pos[i, 1] + dt * v1
                # periodic wrap; the division only for the rare particle that crossed a face
                if not (0.0 <= x < Lx):
                    x -= Lx * np.floor(x / Lx)
                    if x >= Lx:
                        x = 0.0
                if not (0.0 <= y < Ly):
                    y -= Ly * np.floor(y / Ly)
                    if y >= Ly:
                        y = 0.0
                pos[i, 0] = x
                pos[i, 1] = y
                pos[i, 2] += dt * v2
            # second-order estimate of v(t + dt) from the half-step velocity and the old
            # force, for the velocity-dependent (damping) forces: restitution to O(dt^2)
            vel_p[i, 0] = v0 + h * f0 * im
            vel_p[i, 1] = v1 + h * f1 * im
            vel_p[i, 2] = v2 + h * f2 * im
            omega_p[i, 0] = w0 + h * t0 * ii
            omega_p[i, 1] = w1 + h * t1 * ii
            omega_p[i, 2] = w2 + h * t2 * ii
            # the pair pass adds the contacts onto gravity
            if im > 0.0:
                m = mass[i]
                force[i, 0] = m * g0
                force[i, 1] = m * g1
                force[i, 2] = m * g2
            else:
                force[i, 0] = 0.0
                force[i, 1] = 0.0
                force[i, 2] = 0.0
            torque[i, 0] = 0.0
            torque[i, 1] = 0.0
            torque[i, 2] = 0.0
            if use_wall:
                _wall_contact(i, pos, vel_p, omega_p, vel, omega, radius, inv_mass, ptype,
                              wall_type, wall_hist, wall_dmax, wall_rows, wall_state, law_tab,
                              coef, dt, True)
            # the largest squared drift speed of the block (inf for a NaN velocity): the caller
            # bounds the displacements since the lists' builds by sum dt max|v| and measures
            # them (displacement_maxima) only when a bound crosses its threshold
            s2 = v0 * v0 + v1 * v1 + v2 * v2
            if s2 > disp:
                disp = s2
            elif not s2 == s2:
                disp = np.inf
        blk_overlap[b] = ov
        blk_erel[b] = erel_wall
        blk_bad[b] = bad
        blk_disp[b] = disp
        blk_disp_near[b] = 0.0


@njit(cache=True, parallel=True, error_model="numpy")
def particle_pass(
    do_reset, do_sum, do_kick, do_begin, do_wall, pos, vel, omega, vel_p, omega_p, force, torque,
    radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec, dt, use_wall, wall_type, wall_hist,
    wall_dmax, wall_rows, wall_state, law_tab, coef, pos_ref, blk_overlap, blk_erel, blk_bad,
    blk_disp, near_ref, blk_disp_near, serial, push, run_start, near, near_n, pi, pj, crow,
    pstate, scratch, blk_nc,
):
    """The per-particle part of a step, in blocks of PARTICLE_BLOCK particles (``serial``: all
    on the calling thread, no parallel region; the same numbers).

    ``push``: first add the contacts that runs 1... of the pair pass left as rows (run_start,
    near list, rows as :func:`push_rows` takes them), in the same region: slot r of
    ``run_start.shape[0] - 1`` takes an equal share of the particle blocks, adds onto its own
    particles the rows of runs 1... that reach them, in pair order (after run 0's direct sums,
    as :func:`push_rows` would; :func:`_push_rows_into` stops at the first pair whose i is past
    the slot's particles: the pairs are i < j sorted by (i, j)) and then runs its blocks.  Each
    particle gets its contacts in pair order and each block's reductions are written by one
    thread: the same numbers as :func:`push_rows` followed by this pass without ``push``, for
    any thread count, and no serial push after the pair pass (issue 15: it was 10 of the
    benchmark chute's 140 us per step at two threads, reading rows from the other core).

    For every particle, in this order: ``do_wall``: its flat-wall contact at the current state
    (without history update: the initial forces); ``do_reset``: force = gravity, torque = 0;
    ``do_sum``: add its wall row to the force and torque (the pair pass added the pairs) and
    check them; ``do_kick``: the closing half kick; ``do_begin``: the next step's opening half
    kick, drift, predicted velocity (``vel_p``, ``omega_p``), force reset to gravity (for the
    next pair pass), flat-wall contact (history updated) and squared drift speed.  Per block:
    the largest wall overlap, the spring energy released at the wall, a non-finite-force flag
    and the largest squared drift speed |v|^2 (``blk_disp``; inf for a NaN velocity;
    ``blk_disp_near`` is set to 0).  ``pos_ref`` and ``near_ref`` are not read here: see
    :func:`displacement_maxima`.

    The parts of a particle depend on that particle alone, so the step's parts (``do_sum``,
    ``do_kick``, ``do_begin``) run in one loop over the particles, each particle's force,
    torque and velocities read once into registers: the same operations in the same order per
    particle as one loop per part, the same numbers, and the per-block reductions still in
    particle order (issue 15: one loop per part re-read and re-wrote every particle's rows in
    each loop, ~48 us per step on the benchmark chute; fused ~33 us).
    """
    n = pos.shape[0]
    nblock = (n + PARTICLE_BLOCK - 1) // PARTICLE_BLOCK
    nslots = run_start.shape[0] - 1
    nnear = near_n[0]
    if push and not serial and nslots > 1 and nblock > 1:
        for su in prange(nslots):
            r = np.int64(su)
            b0 = (r * nblock) // nslots
            b1 = ((r + 1) * nblock) // nslots
            lo = b0 * PARTICLE_BLOCK
            hi = min(b1 * PARTICLE_BLOCK, n)
            for rr in range(1, nslots):
                if _push_rows_into(run_start[rr], run_start[rr + 1], lo, hi, pi, pj, crow,
                                   pstate, scratch, blk_nc, force, torque):
                    break
            _particle_blocks(b0, b1, do_reset, do_sum, do_kick, do_begin, do_wall, pos, vel,
                             omega, vel_p, omega_p, force, torque, radius, inv_mass, mass,
                             inv_inertia, ptype, Lx, Ly, gvec, dt, use_wall, wall_type,
                             wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef,
                             pos_ref, blk_overlap, blk_erel, blk_bad, blk_disp, near_ref,
                             blk_disp_near)
        return
    if push and nslots > 1:
        push_rows(run_start[1], nnear, pi, pj, crow, pstate, scratch, blk_nc, force, torque)
    if serial or nblock == 1:
        # one thread or one block: no parallel region to launch (~1 us per region and step)
        _particle_blocks(np.int64(0), np.int64(nblock), do_reset, do_sum, do_kick, do_begin,
                         do_wall, pos, vel, omega, vel_p, omega_p, force, torque, radius,
                         inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec, dt, use_wall,
                         wall_type, wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef,
                         pos_ref, blk_overlap, blk_erel, blk_bad, blk_disp, near_ref,
                         blk_disp_near)
    else:
        for bu in prange(nblock):
            b = np.int64(bu)
            _particle_blocks(b, b + 1, do_reset, do_sum, do_kick, do_begin, do_wall, pos, vel,
                             omega, vel_p, omega_p, force, torque, radius, inv_mass, mass,
                             inv_inertia, ptype, Lx, Ly, gvec, dt, use_wall, wall_type,
                             wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef,
                             pos_ref, blk_overlap, blk_erel, blk_bad, blk_disp, near_ref,
                             blk_disp_near)


@njit(cache=True, error_model="numpy")
def _displacement_blocks(b0, b1, pos, pos_ref, near_ref, Lx, Ly, blk_disp, blk_disp_near):
    """Blocks ``b0:b1`` of :func:`displacement_maxima` (its body; serial), on the calling
    thread."""
    n = pos.shape[0]
    for b in range(b0, b1):
        i0 = np.uint64(b * PARTICLE_BLOCK)
        i1 = np.uint64(min(b * PARTICLE_BLOCK + PARTICLE_BLOCK, n))
        disp = 0.0
        disp_near = 0.0
        for i in range(i0, i1):
            dx = _wrap_select(pos[i, 0] - pos_ref[i, 0], Lx, 0.5 * Lx)
            dy = _wrap_select(pos[i, 1] - pos_ref[i, 1], Ly, 0.5 * Ly)
            dz = pos[i, 2] - pos_ref[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > disp:
                disp = d2
            elif not d2 == d2:  # NaN position
                disp = np.inf
            dx = _wrap_select(pos[i, 0] - near_ref[i, 0], Lx, 0.5 * Lx)
            dy = _wrap_select(pos[i, 1] - near_ref[i, 1], Ly, 0.5 * Ly)
            dz = pos[i, 2] - near_ref[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > disp_near:
                disp_near = d2
        blk_disp[b] = disp
        blk_disp_near[b] = disp_near


@njit(cache=True, parallel=True, error_model="numpy")
def displacement_maxima(pos, pos_ref, near_ref, Lx, Ly, blk_disp, blk_disp_near, serial):
    """Per block of PARTICLE_BLOCK particles: the largest squared displacement since the last
    neighbour build (``pos_ref``; inf for a NaN position) and since the last near list
    (``near_ref``), minimum image in x, y.  ``serial``: all blocks on the calling thread, no
    parallel region (the same numbers)."""
    n = pos.shape[0]
    nblock = (n + PARTICLE_BLOCK - 1) // PARTICLE_BLOCK
    if serial or nblock <= 1:
        # one thread or one block: no parallel region to launch (~1 us per region)
        _displacement_blocks(np.int64(0), np.int64(nblock), pos, pos_ref, near_ref, Lx, Ly,
                             blk_disp, blk_disp_near)
    else:
        for bu in prange(nblock):
            b = np.int64(bu)
            _displacement_blocks(b, b + 1, pos, pos_ref, near_ref, Lx, Ly, blk_disp,
                                 blk_disp_near)


#: Slack added to the displacement bounds per step (absolute, in d): covers the rounding of the
#: drift, so that a bound is never below the displacement it bounds.
BOUND_SLACK = 1e-12


@njit(cache=True)
def _block_max(blk):
    m = 0.0
    for b in range(blk.shape[0]):
        v = blk[b]
        if v > m:
            m = v
        elif not v == v:
            m = np.inf
    return m


@njit(cache=True)
def _exact_displacements(pos, pos_ref, near_ref, Lx, Ly, blk_disp, blk_disp_near, serial):
    """(largest displacement since the neighbour build, since the near list); inf for NaN."""
    displacement_maxima(pos, pos_ref, near_ref, Lx, Ly, blk_disp, blk_disp_near, serial)
    d2 = 0.0
    d2n = 0.0
    for b in range(blk_disp.shape[0]):
        d2 = max(d2, blk_disp[b])
        d2n = max(d2n, blk_disp_near[b])
    return np.sqrt(d2), np.sqrt(d2n)


# --------------------------------------------------------------------------------------------
# neighbour list rebuild: pairs, history transfer, pull index, reduced masses
# --------------------------------------------------------------------------------------------
@njit(cache=True)
def transfer_history(old_i, old_j, old_t, old_dmax, new_i, new_j, n, new_t, new_dmax):
    """Carry contact history from an old sorted pair list to a new one (merge walk, O(P));
    ``new_t``, ``new_dmax``: zeros of the new list's length, filled where a pair persists."""
    npair = new_i.shape[0]
    q = 0
    nold = old_i.shape[0]
    for p in range(npair):
        key = np.int64(new_i[p]) * n + np.int64(new_j[p])
        while q < nold and np.int64(old_i[q]) * n + np.int64(old_j[q]) < key:
            q += 1
        if q < nold and np.int64(old_i[q]) * n + np.int64(old_j[q]) == key:
            new_t[p, 0] = old_t[q, 0]
            new_t[p, 1] = old_t[q, 1]
            new_t[p, 2] = old_t[q, 2]
            new_dmax[p] = old_dmax[q]
    return new_t, new_dmax


# --------------------------------------------------------------------------------------------
# spatial order of the particles (issue 15: throughput of large systems)
# --------------------------------------------------------------------------------------------
#: Mobile particles from which the engine keeps them in spatial order (smaller systems fit the
#: caches in any order; their numbers stay those of insertion order).  Measured on the dense
#: benchmark chute, one thread: N = 4395 +7 %, 9918 +17 %, 110200 +48 % particle-steps/s
#: sorted against random order.
SORT_MIN_MOBILE = 2048
#: Re-sort at every SORT_EVERY-th neighbour-list rebuild (counted over the whole run, so a
#: resumed run sorts at the same steps); LAMMPS sorts every 1000 steps by default.
SORT_EVERY = 4
#: Bin of the sort key, in units of the largest mobile diameter.
SORT_BIN = 1.0


@njit(cache=True)
def _bin_keys(pos, i0, i1, Lx, Ly, b):
    """Sort keys of particles i0..i1-1: (x bin, y bin, z bin) of bins of size ``b``, ties by
    index (a stable order)."""
    m = i1 - i0
    zlo = np.inf
    zhi = -np.inf
    for i in range(i0, i1):
        zlo = min(zlo, pos[i, 2])
        zhi = max(zhi, pos[i, 2])
    nx = max(1, np.int64(Lx / b))
    ny = max(1, np.int64(Ly / b))
    nz = np.int64((zhi - zlo) / b) + 1
    key = np.empty(m, dtype=np.int64)
    for k in range(m):
        i = i0 + k
        ix = max(0, min(nx - 1, np.int64(pos[i, 0] / Lx * nx)))
        iy = max(0, min(ny - 1, np.int64(pos[i, 1] / Ly * ny)))
        iz = max(0, min(nz - 1, np.int64((pos[i, 2] - zlo) / b)))
        key[k] = ((ix * ny + iy) * nz + iz) * m + k
    return key


@njit(cache=True)
def spatial_order(pos, radius, fixed, Lx, Ly):
    """A permutation ``perm`` (new index -> old index) that orders the mobile particles, and
    separately the fixed ones (which stay last), by bins of one largest mobile diameter
    (SORT_BIN) in (x, y, z) order; stable: equal bins keep their order.  Serial and
    deterministic."""
    n = pos.shape[0]
    nm = 0
    while nm < n and not fixed[nm]:
        nm += 1
    perm = np.arange(n)
    if nm < 2:
        return perm
    dmax = 0.0
    for i in range(nm):
        dmax = max(dmax, 2.0 * radius[i])
    b = SORT_BIN * dmax
    perm[:nm] = np.argsort(_bin_keys(pos, 0, nm, Lx, Ly, b))
    if n - nm > 1:
        perm[nm:] = nm + np.argsort(_bin_keys(pos, nm, n, Lx, Ly, b))
    return perm


@njit(cache=True)
def _permute_rows(a, perm):
    """``a[:] = a[perm]`` in place (1-D or 2-D rows)."""
    tmp = a.copy()
    for k in range(perm.shape[0]):
        a[k] = tmp[perm[k]]


@njit(cache=True)
def remap_pairs(pi, pj, hist_t, hist_dmax, inv):
    """The pair list and history in the new particle order (``inv``: old index -> new index):
    each pair as (min, max) of its new indices — swapping i and j reverses the tangential
    spring — sorted by (i, j) again."""
    npair = pi.shape[0]
    n = inv.shape[0]
    ni = np.empty(npair, dtype=np.uint32)
    nj = np.empty(npair, dtype=np.uint32)
    nt = np.empty_like(hist_t)
    nd = np.empty_like(hist_dmax)
    key = np.empty(npair, dtype=np.int64)
    for p in range(npair):
        a = inv[pi[p]]
        c = inv[pj[p]]
        key[p] = min(a, c) * n + max(a, c)
    order = np.argsort(key)
    for q in range(npair):
        p = order[q]
        a = inv[pi[p]]
        c = inv[pj[p]]
        sign = 1.0
        if a > c:
            a, c = c, a
            sign = -1.0
        ni[q] = a
        nj[q] = c
        for k in range(3):
            nt[q, k] = sign * hist_t[p, k] if hist_t[p, k] != 0.0 else hist_t[p, k]
        nd[q] = hist_dmax[p]
    return ni, nj, nt, nd


@njit(cache=True)
def sort_particles(pos, vel, omega, vel_p, omega_p, force, torque, radius, inv_mass, mass,
                   inv_inertia, inertia, ptype, fixed, ids, level_of, wall_hist, wall_dmax,
                   wall_rows, wall_state, Lx, Ly, pi, pj, hist_t, hist_dmax):
    """Put the mobile particles in spatial order (:func:`spatial_order`): every per-particle
    array is permuted in place (``ids`` keeps each particle's identity: its index at
    insertion), the pair list and its history are returned in the new order.  Positions,
    velocities, forces and springs are moved, never recomputed: the state is the same, only the
    order in which later sums visit it changes."""
    n = pos.shape[0]
    perm = spatial_order(pos, radius, fixed, Lx, Ly)
    for a in (pos, vel, omega, vel_p, omega_p, force, torque, wall_hist, wall_rows):
        _permute_rows(a, perm)
    for a in (radius, inv_mass, mass, inv_inertia, inertia, wall_dmax):
        _permute_rows(a, perm)
    _permute_rows(ptype, perm)
    _permute_rows(ids, perm)
    _permute_rows(level_of, perm)
    _permute_rows(wall_state, perm)
    inv = np.empty(n, dtype=np.int64)
    for k in range(n):
        inv[perm[k]] = k
    return remap_pairs(pi, pj, hist_t, hist_dmax, inv)


#: The per-pair arrays derived from a pair list and written by the pair pass, in the order
#: that :func:`pair_index` returns them and :func:`advance` takes them.
PAIR_ARRAYS = ("hflag", "mred", "crow", "cext", "ridx", "prel", "pstate", "scratch",
               "blk_pair_overlap", "blk_pair_erel", "blk_pair_nc", "near_tmp", "near_count",
               "near", "near_n", "ntouch", "near_ref", "near_ok")


@njit(cache=True)
def pair_index(pi, pj, hist_t, inv_mass, n):
    """The PAIR_ARRAYS of a sorted pair list: spring flags, reduced masses, the arrays the pair
    pass writes (compact rows ``crow`` (P, 9) and ``cext`` (P, 3), compact index ``ridx``,
    released energies ``prel``, states ``pstate``, ``scratch``, per-block overlap / released
    energy, contacts), and the near list (:func:`near_pass`, :func:`near_index`; ``near_ok`` = 0:
    to be built) with the positions at its build ``near_ref``."""
    npair = pi.shape[0]
    mred = np.empty(npair)
    hflag = np.empty(npair, dtype=np.uint8)
    for p in range(npair):
        mred[p] = 1.0 / (inv_mass[pi[p]] + inv_mass[pj[p]])
        hflag[p] = _has_spring(hist_t[p, 0], hist_t[p, 1], hist_t[p, 2])
    nblock = (npair + PAIR_BLOCK - 1) // PAIR_BLOCK
    return (hflag, mred, np.zeros((npair, 9)), np.zeros((npair, 3)),
            np.zeros(npair, dtype=np.uint32), np.zeros(npair), np.zeros(npair, dtype=np.uint8),
            np.zeros(npair, dtype=np.uint32), np.zeros(nblock), np.zeros(nblock),
            np.zeros(nblock, dtype=np.int64), np.zeros(npair, dtype=np.uint32),
            np.zeros(nblock, dtype=np.int64), np.zeros(npair, dtype=np.uint32),
            np.zeros(1, dtype=np.int64), np.zeros(npair, dtype=np.uint8), np.zeros((n, 3)),
            np.zeros(1, dtype=np.uint8))


@njit(cache=True, parallel=True)  # parallel callees (see hgrid._found_rows)
def rebuild_pairs(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell, old_pi, old_pj,
                  old_hist, old_dmax):
    """New neighbour list (uint32, sorted by (i, j)) with the contact history carried over."""
    n = pos.shape[0]
    # room for the partners of a particle in the single search pass (else a second pass)
    cap = max(DEFAULT_CAPACITY, 4 * (old_pi.shape[0] // max(n, 1)) + 8)
    pi, pj = hgrid_pairs_u32(pos, radius, fixed, Lx, Ly, skin, level_of, level_cell, cap)
    hist_t = np.zeros((pi.shape[0], 3))
    hist_dmax = np.zeros(pi.shape[0])
    transfer_history(old_pi, old_pj, old_hist, old_dmax, pi, pj, n, hist_t, hist_dmax)
    return pi, pj, hist_t, hist_dmax


# --------------------------------------------------------------------------------------------
# time stepping
# --------------------------------------------------------------------------------------------
@njit(cache=True)
def elastic_energy(cext, ridx, pstate, use_wall, wall_rows, wall_state):
    """Elastic energy of all contacts (pairs in pair order, then the wall contacts)."""
    e = 0.0
    for p in range(pstate.shape[0]):
        if pstate[p] == CONTACT:
            e += cext[ridx[p], 0]
    if use_wall:
        for i in range(wall_state.shape[0]):
            if wall_state[i] == CONTACT:
                e += wall_rows[i, 9]
    return e


@njit(cache=True, parallel=True)
def compute_forces(
    pos, vel, omega, force, torque, radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec,
    pi, pj, hist_t, hist_dmax, hflag, mred, crow, cext, ridx, prel, pstate, scratch,
    blk_pair_overlap, blk_pair_erel, blk_pair_nc, near_tmp, near_count, near, near_n, ntouch,
    near_ref, near_ok, use_wall, wall_type, wall_hist, wall_dmax, wall_rows, wall_state, law_tab,
    coef, all_linear, work, dt, pos_ref, skin, nslots,
):
    """Forces and torques of the current state without changing the contact history (the
    initial forces of a run).  Returns (elastic energy, maximum overlap)."""
    _T = np.bool_(True)
    _F = np.bool_(False)
    n = pos.shape[0]
    nblock = (n + PARTICLE_BLOCK - 1) // PARTICLE_BLOCK
    blk_overlap = np.zeros(nblock)
    blk_erel = np.zeros(nblock)
    blk_bad = np.zeros(nblock, dtype=np.bool_)
    blk_disp = np.zeros(nblock)
    blk_disp_near = np.zeros(nblock)
    serial = np.bool_(nslots == 1)  # one thread: passes without a parallel region
    near_pass(pos, radius, hflag, Lx, Ly, pi, pj, NEAR_FRACTION * skin, near_tmp, near_count,
              pstate, serial)
    near_index(near_tmp, near_count, near, near_n)
    near_ref[:, :] = pos
    near_ok[0] = 1
    run_start = np.empty(nslots + 1, dtype=np.int64)
    split_runs(near_n[0], np.zeros(near_count.shape[0], dtype=np.int64), nslots, run_start)
    # flags as run-time booleans (np.bool_): numba compiles one specialisation of a kernel per
    # combination of *literal* flags -- four of particle_pass and two of pair_pass and
    # _linear_maths, 124.7 s of compilation for a fresh clone's default campaign warm-up; with
    # run-time flags everywhere but the step's particle pass 83.2 s, the same numbers and the
    # same speed (issue 15; an all-run-time particle pass was 2 % slower per step)
    particle_pass(_T, _F, _F, _F, _T, pos, vel, omega, vel, omega, force, torque,
                  radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec, dt, use_wall,
                  wall_type, wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef, pos_ref,
                  blk_overlap, blk_erel, blk_bad, blk_disp, near_ref, blk_disp_near, serial, _F,
                  run_start, near, near_n, pi, pj, crow, pstate, scratch, blk_pair_nc)
    pair_pass(pos, vel, omega, vel, omega, radius, ptype, Lx, Ly, pi, pj, mred, hist_t,
              hist_dmax, hflag, law_tab, coef, all_linear, work, dt, _F, crow, cext, ridx,
              prel, pstate, scratch, blk_pair_overlap, blk_pair_erel, blk_pair_nc, run_start,
              force, torque, near, near_n, ntouch, _T, np.empty((1, 0, 9)),
              np.empty((1, 0, 3)))
    nbp = (near_n[0] + PAIR_BLOCK - 1) // PAIR_BLOCK
    # the rows of runs 1... are added in the particle pass (push): as push_rows would
    particle_pass(_F, _T, _F, _F, _F, pos, vel, omega, vel, omega, force, torque,
                  radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec, dt, use_wall,
                  wall_type, wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef, pos_ref,
                  blk_overlap, blk_erel, blk_bad, blk_disp, near_ref, blk_disp_near, serial, _T,
                  run_start, near, near_n, pi, pj, crow, pstate, scratch, blk_pair_nc)
    max_ov = 0.0
    for b in range(nbp):
        max_ov = max(max_ov, blk_pair_overlap[b])
    for b in range(nblock):
        max_ov = max(max_ov, blk_overlap[b])
    return elastic_energy(cext, ridx, pstate, use_wall, wall_rows, wall_state), max_ov


@njit(cache=True, parallel=True)
def advance(
    nsteps, pos, vel, omega, force, torque, radius, inv_mass, mass, inv_inertia, ptype, fixed,
    Lx, Ly, gvec, pi, pj, hist_t, hist_dmax, hflag, mred, crow, cext, ridx, prel, pstate,
    scratch, blk_pair_overlap, blk_pair_erel, blk_pair_nc, near_tmp, near_count, near, near_n,
    ntouch, near_ref, near_ok, pos_ref, skin, level_of, level_cell, use_wall, wall_type,
    wall_hist, wall_dmax, wall_rows, wall_state, law_tab, coef, all_linear, work, dt,
    max_overlap_allowed, nslots, inertia, ids, sort_min_mobile, sort_every, n_rebuilds0,
):
    """Advance ``nsteps`` velocity-Verlet steps (Eq. 11), rebuilding the neighbour list when a
    particle has moved more than skin/2 since the last build (by the hierarchical grid of
    :mod:`.hgrid` with the levels ``level_of``/``level_cell``; one level = plain cell list), and
    the near list when a particle has moved more than half its skin since its build.  The
    neighbour and near lists hold every touching pair, in pair order, whenever they are rebuilt:
    the numbers do not depend on when they are.

    ``nslots``: the number of threads (runs of near-list blocks of the pair pass); the forces
    are summed in pair order for any value: the same numbers.

    With at least ``sort_min_mobile`` mobile particles, every ``sort_every``-th rebuild of the
    run (``n_rebuilds0`` rebuilds before this call) first puts the particles in spatial order
    (:func:`sort_particles`; ``ids``, ``inertia`` are permuted with the rest): a rebuild happens
    at the same steps whatever the chunking of the steps into calls, so does a sort.

    Arrays are updated in place, except the pair arrays, which are returned (they change size
    on a rebuild).  Returns (pi, pj, hist_t, hist_dmax, the PAIR_ARRAYS tuple, e_elastic,
    max_overlap, e_released, steps_done, n_rebuilds, status) with status 0 = ok,
    1 = non-finite position or force, 2 = overlap too large (the step at which it happened is
    steps_done).
    """
    _T = np.bool_(True)  # run-time flags: one specialisation per kernel (see compute_forces)
    _F = np.bool_(False)
    n = pos.shape[0]
    nblock = (n + PARTICLE_BLOCK - 1) // PARTICLE_BLOCK
    blk_overlap = np.zeros(nblock)
    blk_erel = np.zeros(nblock)
    blk_bad = np.zeros(nblock, dtype=np.bool_)
    blk_disp = np.zeros(nblock)
    blk_disp_near = np.zeros(nblock)
    e_released = 0.0
    max_ov = 0.0
    nreb = 0
    status = 0
    done = 0
    half_skin = 0.5 * skin
    near_skin = NEAR_FRACTION * skin
    half_near = 0.5 * near_skin
    vel_p = np.empty_like(vel)
    omega_p = np.empty_like(omega)
    run_start = np.empty(nslots + 1, dtype=np.int64)
    serial = np.bool_(nslots == 1)  # one thread: passes without a parallel region
    n_mobile = 0
    while n_mobile < n and not fixed[n_mobile]:
        n_mobile += 1
    do_sort = n_mobile >= sort_min_mobile and sort_every > 0
    # block row buffers of the pair pass for the steps whose rows are not kept (all but the
    # last): a large system's rows then stay in the cache
    lrow = np.empty((work.shape[0], PAIR_BLOCK, 9))
    lext = np.empty((work.shape[0], PAIR_BLOCK, 3))
    # bounds of the largest displacement since the neighbour build / the near list: exact
    # after a measurement, then + dt max|v| per step; measured again only when one crosses its
    # threshold.  A bound is never below the displacement, so the lists are rebuilt at exactly
    # the steps at which a measurement every step would rebuild them.
    bound = 0.0
    bound_near = 0.0
    if nsteps > 0:
        particle_pass(_F, _F, _F, _T, _F, pos, vel, omega, vel_p, omega_p, force,
                      torque, radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly, gvec, dt,
                      use_wall, wall_type, wall_hist, wall_dmax, wall_rows, wall_state, law_tab,
                      coef, pos_ref, blk_overlap, blk_erel, blk_bad, blk_disp, near_ref,
                      blk_disp_near, serial, _F, run_start, near, near_n, pi, pj, crow, pstate,
                      scratch, blk_pair_nc)
        bound, bound_near = _exact_displacements(pos, pos_ref, near_ref, Lx, Ly, blk_disp,
                                                 blk_disp_near, serial)
    for step in range(nsteps):
        done = step + 1
        if bound > half_skin or bound_near > half_near or not np.isfinite(bound):
            bound, bound_near = _exact_displacements(pos, pos_ref, near_ref, Lx, Ly, blk_disp,
                                                     blk_disp_near, serial)
        if not np.isfinite(bound):
            status = 1
            break
        if bound > half_skin:
            if do_sort and (n_rebuilds0 + nreb) % sort_every == 0:
                pi, pj, hist_t, hist_dmax = sort_particles(
                    pos, vel, omega, vel_p, omega_p, force, torque, radius, inv_mass, mass,
                    inv_inertia, inertia, ptype, fixed, ids, level_of, wall_hist, wall_dmax,
                    wall_rows, wall_state, Lx, Ly, pi, pj, hist_t, hist_dmax)
            pi, pj, hist_t, hist_dmax = rebuild_pairs(pos, radius, fixed, Lx, Ly, skin, level_of,
                                                      level_cell, pi, pj, hist_t, hist_dmax)
            (hflag, mred, crow, cext, ridx, prel, pstate, scratch, blk_pair_overlap,
             blk_pair_erel, blk_pair_nc, near_tmp, near_count, near, near_n, ntouch, near_ref,
             near_ok) = pair_index(pi, pj, hist_t, inv_mass, n)
            pos_ref[:, :] = pos
            bound = 0.0
            nreb += 1
        if near_ok[0] == 0 or bound_near > half_near:
            near_pass(pos, radius, hflag, Lx, Ly, pi, pj, near_skin, near_tmp, near_count, pstate,
                      serial)
            near_index(near_tmp, near_count, near, near_n)
            near_ref[:, :] = pos
            near_ok[0] = 1
            bound_near = 0.0
        # blocks of the near list per thread, balanced by the last step's contacts (a near list
        # just built has new blocks: its first step splits by the old counts, still a fair guess)
        split_runs(near_n[0], blk_pair_nc, nslots, run_start)
        pair_pass(pos, vel_p, omega_p, vel, omega, radius, ptype, Lx, Ly, pi, pj, mred, hist_t,
                  hist_dmax, hflag, law_tab, coef, all_linear, work, dt, _T, crow, cext, ridx,
                  prel, pstate, scratch, blk_pair_overlap, blk_pair_erel, blk_pair_nc,
                  run_start, force, torque, near, near_n, ntouch, step + 1 == nsteps, lrow, lext)
        nbp = (near_n[0] + PAIR_BLOCK - 1) // PAIR_BLOCK
        # literal flags: the step's particle pass is specialised (2 % faster than with run-time
        # flags, measured); every other call shares the run-time specialisation.  It first adds
        # the rows that runs 1... of the pair pass left (push), each thread onto its particles
        particle_pass(False, True, True, step + 1 < nsteps, False, pos, vel, omega, vel_p,
                      omega_p, force, torque, radius, inv_mass, mass, inv_inertia, ptype, Lx, Ly,
                      gvec, dt, use_wall, wall_type, wall_hist, wall_dmax, wall_rows, wall_state,
                      law_tab, coef, pos_ref, blk_overlap, blk_erel, blk_bad, blk_disp, near_ref,
                      blk_disp_near, serial, True, run_start, near, near_n, pi, pj, crow, pstate,
                      scratch, blk_pair_nc)
        step_len = dt * np.sqrt(_block_max(blk_disp)) + BOUND_SLACK  # inf for a NaN velocity
        bound += step_len
        bound_near += step_len
        # per-block results combined in block order: independent of the thread count
        max_ov = 0.0
        e_pairs = 0.0
        for b in range(nbp):
            if blk_pair_overlap[b] > max_ov:
                max_ov = blk_pair_overlap[b]
            e_pairs += blk_pair_erel[b]
        e_wall = 0.0
        bad = False
        for b in range(nblock):
            if blk_overlap[b] > max_ov:
                max_ov = blk_overlap[b]
            e_wall += blk_erel[b]
            bad = bad or blk_bad[b]
        e_released += e_pairs + e_wall
        if bad:
            status = 1
            break
        if max_ov > max_overlap_allowed:
            status = 2
            break
    e_el = elastic_energy(cext, ridx, pstate, use_wall, wall_rows, wall_state)
    return (pi, pj, hist_t, hist_dmax,
            (hflag, mred, crow, cext, ridx, prel, pstate, scratch, blk_pair_overlap,
             blk_pair_erel, blk_pair_nc, near_tmp, near_count, near, near_n, ntouch, near_ref,
             near_ok),
            e_el, max_ov, e_released, done, nreb, status)


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
def contact_list(pos, radius, Lx, Ly, pi, pj, crow, cext, ridx, pstate, use_wall, wall_rows,
                 wall_state):
    """Contacts of the current state for coarse-graining: (i, j, force on i, r_i - r_j, contact
    point relative to stored r_i).  Wall contacts have j = -1 and r_ij = (0, 0, z_i)."""
    m = 0
    for p in range(pi.shape[0]):
        if pstate[p] == CONTACT and cext[ridx[p], 1] > 0.0:
            m += 1
    nw = 0
    if use_wall:
        for i in range(pos.shape[0]):
            if wall_state[i] == CONTACT:
                nw += 1
    ci = np.empty(m + nw, dtype=np.int64)
    cj = np.empty(m + nw, dtype=np.int64)
    f = np.empty((m + nw, 3))
    rij = np.empty((m + nw, 3))
    cp = np.empty((m + nw, 3))
    q = 0
    for p in range(pi.shape[0]):
        if not (pstate[p] == CONTACT and cext[ridx[p], 1] > 0.0):
            continue
        i = np.int64(pi[p])
        j = np.int64(pj[p])
        dx = _min_image(pos[i, 0] - pos[j, 0], Lx)
        dy = _min_image(pos[i, 1] - pos[j, 1], Ly)
        dz = pos[i, 2] - pos[j, 2]
        r = np.sqrt(dx * dx + dy * dy + dz * dz)
        delta = cext[ridx[p], 1]
        bi = -(radius[i] - 0.5 * delta) / r
        ci[q] = i
        cj[q] = j
        for k in range(3):
            f[q, k] = crow[ridx[p], k]
        rij[q, 0] = dx
        rij[q, 1] = dy
        rij[q, 2] = dz
        cp[q, 0] = pos[i, 0] + bi * dx
        cp[q, 1] = pos[i, 1] + bi * dy
        cp[q, 2] = pos[i, 2] + bi * dz
        q += 1
    if use_wall:
        for i in range(pos.shape[0]):
            if wall_state[i] != CONTACT:
                continue
            ci[q] = i
            cj[q] = -1
            for k in range(3):
                f[q, k] = wall_rows[i, k]
            rij[q, 0] = 0.0
            rij[q, 1] = 0.0
            rij[q, 2] = pos[i, 2]
            cp[q, 0] = pos[i, 0]
            cp[q, 1] = pos[i, 1]
            cp[q, 2] = pos[i, 2] - (radius[i] - 0.5 * wall_rows[i, 10])
            q += 1
    return ci, cj, f, rij, cp


def legacy_pair_rows(crow, cext, ridx, prel, pstate):
    """The (P, NOUT) per-pair table of the engine before issue 15: force on i (0:3), torque on i
    (3:6), torque on j (6:9), elastic energy (9), overlap (10), normal force (11), spring energy
    released by a contact that opened in the last step (12); zeros for pairs without contact."""
    out = np.zeros((pstate.shape[0], NOUT))
    live = (pstate == CONTACT) | (pstate == GRAZING)
    q = ridx[live].astype(np.int64)
    out[live, :9] = crow[q]
    out[live, 9:12] = cext[q]
    opened = pstate == OPENED
    out[opened, 12] = prel[opened]
    return out


def legacy_wall_rows(wall_rows, wall_state):
    """The per-particle flat-wall table in the layout of :func:`legacy_pair_rows`."""
    out = np.zeros((wall_state.shape[0], NOUT))
    live = (wall_state == CONTACT) | (wall_state == GRAZING)
    out[live, :NROW] = wall_rows[live]
    opened = wall_state == OPENED
    out[opened, 12] = wall_rows[opened, 9]
    return out
