"""Spatial order of the particles (issue 15: throughput of large systems).

Systems with at least ``kernels.SORT_MIN_MOBILE`` mobile particles are re-sorted into bins in
(x, y, z) order at every ``SORT_EVERY``-th neighbour-list rebuild (``kernels.sort_particles``),
each particle keeping its identity in ``ParticleSystem.ids``.  A sort moves the state, it does
not change it: checked exactly here; afterwards only the order of the force sums differs, so a
sorted run follows the unsorted one to rounding over a short run.  And a sorted run keeps the
engine's guarantees: the same numbers for any thread split, any chunking of the steps, and
across a kill and resume.  The tests lower the threshold (``sort_min_mobile = 0``) on the
768-particle packing of ``test_engine_threads``.
"""

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granflow.coarse.diffusion import TracerObserver
from granflow.engine import ParticleSystem
from granflow.engine.lib import kernels as K

from test_engine_threads import _advance as _run
from test_engine_threads import _packing


def _shuffled_packing(skin=0.2, seed=9):
    """The packing with its mobile particles in random order (insertion order in a real run:
    far from the bins' order)."""
    s = _packing(skin)
    nf = int((~s.fixed).sum())
    perm = np.r_[np.random.default_rng(seed).permutation(nf), np.arange(nf, s.n)]
    t = ParticleSystem(s.Lx, s.Ly, s.interactions, gvec=s.gvec, skin=skin)
    t.set_particles(s.pos[perm], 2.0 * s.radius[perm], density=s.mass[perm] / (np.pi / 6.0 * (
        2.0 * s.radius[perm]) ** 3), ptype=s.ptype[perm], fixed=s.fixed[perm])
    t.vel[:] = s.vel[perm]
    t.omega[:] = s.omega[perm]
    t.initialize()
    return t


def _sorted_packing(every=1, skin=0.2):
    s = _shuffled_packing(skin)
    s.sort_min_mobile = 0
    s.sort_every = every
    return s


def _by_id(s):
    """State in identity order, springs keyed by the pair of identities (i < j by identity;
    the spring reverses with the pair's orientation)."""
    o = s.id_order()
    live = np.any(s.hist_t != 0.0, axis=1)
    a, b = s.ids[s.pi[live]], s.ids[s.pj[live]]
    sign = np.where(a < b, 1.0, -1.0)[:, None]
    springs = s.hist_t[live] * sign
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi, lo))
    return {"pos": s.pos[o], "vel": s.vel[o], "omega": s.omega[o], "force": s.force[o],
            "torque": s.torque[o], "radius": s.radius[o], "mass": s.mass[o],
            "inertia": s.inertia[o], "ptype": s.ptype[o], "fixed": s.fixed[o],
            "wall_hist": s.wall_hist[o],
            "spring_pairs": np.c_[lo, hi][order], "springs": springs[order] + 0.0}


def test_a_sort_moves_the_state_without_changing_it():
    s = _shuffled_packing()
    s.step(120)  # springs in the contacts
    before = _by_id(s)
    assert len(before["springs"]) > 500
    s._cache_inverse()
    vel_p, omega_p = s.vel.copy(), s.omega.copy()
    s.pi, s.pj, s.hist_t, s.hist_dmax = K.sort_particles(
        s.pos, s.vel, s.omega, vel_p, omega_p, s.force, s.torque, s.radius, s._inv_mass, s.mass,
        s._inv_inertia, s.inertia, s.ptype, s.fixed, s.ids, s._level_of, s.wall_hist,
        s.wall_dmax, s.wall_rows, s.wall_state, s.Lx, s.Ly, s.pi, s.pj, s.hist_t, s.hist_dmax)
    moved = int((s.ids != np.arange(s.n)).sum())
    assert moved > s.n // 2  # the packing's lattice order is not the bins' order
    after = _by_id(s)
    for key in before:
        assert np.array_equal(before[key], after[key]), key
    # the pair list is sorted by (i, j) with i < j, mobile particles first, fixed last
    assert np.all(s.pi < s.pj)
    key = s.pi.astype(np.int64) * s.n + s.pj
    assert np.all(np.diff(key) > 0)
    assert not s.fixed[: int((~s.fixed).sum())].any()
    # the cached inverse masses moved with the masses
    assert np.array_equal(s._inv_mass, s.inv_mass)
    assert np.array_equal(s._inv_inertia, s.inv_inertia)


def test_sorted_run_follows_the_unsorted_one_to_rounding():
    plain = _run(_shuffled_packing(skin=0.05), (400,))
    srt = _run(_sorted_packing(skin=0.05), (400,))
    assert srt.n_rebuilds >= 1 and int((srt.ids != np.arange(srt.n)).sum()) > srt.n // 2
    a, b = _by_id(plain), _by_id(srt)
    # only the order of the force sums differs: rounding, not physics (0.04 time units)
    for key in ("pos", "vel", "omega"):
        scale = np.abs(a[key]).max()
        assert np.abs(a[key] - b[key]).max() <= 1e-9 * scale, key
    assert np.array_equal(a["spring_pairs"], b["spring_pairs"])
    assert np.allclose(a["springs"], b["springs"], rtol=0, atol=1e-12)
    assert srt.e_elastic == pytest.approx(plain.e_elastic, rel=1e-9)


def test_sorted_runs_give_the_same_numbers_for_any_thread_split_and_chunking():
    ref = _run(_sorted_packing(every=2, skin=0.01), (150, 250))
    assert ref.n_rebuilds >= 4  # several sorts
    a = _by_id(ref)
    split = [_run(_sorted_packing(every=2, skin=0.01), (150, 250), slots=k) for k in (2, 3)]
    if numba.config.NUMBA_NUM_THREADS >= 2:
        split.append(_run(_sorted_packing(every=2, skin=0.01), (150, 250), threads=2))
    chunked = [_run(_sorted_packing(every=2, skin=0.01), steps) for steps in ((1, 99, 300), (400,))]
    for s in split + chunked:
        b = _by_id(s)
        for key in a:
            assert np.array_equal(a[key], b[key]), key
        assert np.array_equal(s.ids, ref.ids)
    for s in split:  # (the released energy is summed per call: chunking moves its last bit)
        assert s.e_released == ref.e_released


def test_a_sorted_run_resumes_bit_for_bit(tmp_path):
    ref = _run(_sorted_packing(every=2, skin=0.01), (200, 200))
    s = _run(_sorted_packing(every=2, skin=0.01), (200,))
    s.save(tmp_path / "state.npz")
    r, _ = ParticleSystem.load(tmp_path / "state.npz")
    assert (r.sort_min_mobile, r.sort_every) == (0, 2)
    assert np.array_equal(r.ids, s.ids) and not np.array_equal(r.ids, np.arange(r.n))
    r.step(200)
    for key in ("pos", "vel", "omega", "force", "torque", "ids", "pi", "pj", "hist_t"):
        assert np.array_equal(getattr(r, key), getattr(ref, key)), key


def test_a_state_without_ids_reads_as_insertion_order():
    s = _packing()
    state = dict(s.state_dict())
    state.pop("ids")
    r = ParticleSystem.from_state_dict(state)
    assert np.array_equal(r.ids, np.arange(r.n))
    assert r.sort_min_mobile == K.SORT_MIN_MOBILE


def test_tracers_follow_particles_through_sorts():
    """The self-diffusion tracers record heights in identity order."""
    plain, srt = _shuffled_packing(skin=0.05), _sorted_packing(skin=0.05)
    tp, ts = TracerObserver(), TracerObserver()
    for _ in range(4):
        plain.step(100)
        srt.step(100)
        tp.sample(plain)
        ts.sample(srt)
    assert int((srt.ids != np.arange(srt.n)).sum()) > srt.n // 2
    _, zp, dp = tp.arrays()
    _, zs, ds = ts.arrays()
    assert np.array_equal(dp, ds)
    assert np.abs(zp - zs).max() < 1e-9


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 400), st.integers(0, 40), st.integers(0, 2**31 - 1))
def test_spatial_order_is_a_stable_bin_order_with_fixed_particles_last(nm, nf, seed):
    rng = np.random.default_rng(seed)
    n = nm + nf
    Lx, Ly = 7.5, 4.0
    pos = np.c_[rng.uniform(0, Lx, n), rng.uniform(0, Ly, n), rng.uniform(-1, 9, n)]
    radius = rng.uniform(0.3, 0.6, n)
    fixed = np.r_[np.zeros(nm, bool), np.ones(nf, bool)]
    perm = K.spatial_order(pos, radius, fixed, Lx, Ly)
    assert sorted(perm) == list(range(n))
    assert set(perm[:nm]) == set(range(nm))  # fixed particles stay last
    b = K.SORT_BIN * 2.0 * radius[:nm].max()
    for lo, hi in ((0, nm), (nm, n)):
        if hi - lo < 2:
            continue
        p = perm[lo:hi]
        nx, ny = max(1, int(Lx / b)), max(1, int(Ly / b))
        ix = np.minimum(nx - 1, (pos[p, 0] / Lx * nx).astype(int))
        iy = np.minimum(ny - 1, (pos[p, 1] / Ly * ny).astype(int))
        iz = ((pos[p, 2] - pos[lo:hi, 2].min()) / b).astype(int)
        key = list(zip(ix, iy, iz, p))
        assert key == sorted(key)  # bins in (x, y, z) order, ties by index


@pytest.mark.parametrize("steps", [(1,), (300,), (150, 150)])
def test_rows_after_a_call_are_those_of_its_last_step(steps):
    """The pair pass keeps the contact rows of the pair list only at the last step of a call
    (the others use block buffers): the contacts an observer reads after ``step`` must add up
    to the forces the engine integrated, particle by particle."""
    s = _sorted_packing(skin=0.01)
    s.sort_every = 2
    for n in steps:
        s.step(n)
    c = s.contacts()
    i, j, f = c["contact_i"], c["contact_j"], c["contact_force"]
    assert len(i) > 500
    total = np.zeros_like(s.force)
    np.add.at(total, i, f)
    np.add.at(total, j[j >= 0], -f[j >= 0])
    mobile = ~s.fixed
    expected = s.force[mobile] - s.mass[mobile, None] * s.gvec
    assert np.allclose(total[mobile], expected, rtol=0, atol=1e-9 * np.abs(f).max())


def test_mobile_selection_is_the_mask_as_a_slice_and_gives_the_same_sums():
    """The per-sample energies select the mobile particles by a slice (they precede the fixed
    ones and sorts keep it so): the same particles in the same order as the boolean mask, so
    the same sums bit for bit, through sorts; a system that breaks the order gets the mask."""
    s = _shuffled_packing()
    s.sort_min_mobile = 0
    mask = ~s.fixed
    sel = s.mobile_selection()
    assert sel == slice(0, int(mask.sum()))
    assert s.fixed.flags.c_contiguous and s.fixed.flags.writeable
    for _ in range(3):
        _run(s, [200])
        e = s.energies()
        want = float(np.sum(s.mass[mask] * (-s.gvec[2]) * s.pos[mask, 2]))
        assert e["gravitational"] == want  # exact: same elements, same order, same sum
        np.testing.assert_array_equal(s.vel[sel, 0], s.vel[mask, 0])
    t = _shuffled_packing()
    t.fixed = np.r_[True, t.fixed[1:]]  # a fixed particle first: not mobile-first
    np.testing.assert_array_equal(t.mobile_selection(), ~t.fixed)


def test_a_scalar_fixed_flag_is_stored_as_an_own_contiguous_array():
    """``set_particles(fixed=False)`` (the base preparation) gives the same array layout as a
    per-particle flag array or a restored state, so the kernels compile once for all three
    (a broadcast scalar was a stride-0 view: numba compiled a second 'A'-layout version)."""
    s = _packing()
    t = ParticleSystem(s.Lx, s.Ly, s.interactions, gvec=s.gvec)
    t.set_particles(s.pos, 2.0 * s.radius, ptype=s.ptype, fixed=False)
    u = ParticleSystem(s.Lx, s.Ly, s.interactions, gvec=s.gvec)
    u.set_particles(s.pos, 2.0 * s.radius, ptype=s.ptype, fixed=s.fixed)
    for a in (t.fixed, u.fixed):
        assert a.flags.c_contiguous and a.flags.writeable and a.strides == (1,)
    assert numba.typeof(t.fixed) == numba.typeof(u.fixed) == numba.typeof(s.fixed.copy())
