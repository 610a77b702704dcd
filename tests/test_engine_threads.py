"""The engine's numbers do not depend on how the work is split (issue 15).

Forces are summed in pair order whatever the number of threads (the pair pass's runs of
blocks, ``kernels.pair_pass``, split by ``kernels.split_runs``; the rows of runs 1... added
by the particle pass, each thread onto its own share of the particles), and the neighbour and
near lists hold every touching pair in pair order whenever they are rebuilt, so a run gives the
same numbers, bit for bit, on any number of threads and with any Verlet skin.
"""

import math

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granflow.engine import ContactSpecies, InteractionTable, ParticleSystem

A = 0.999      # lattice spacing: every particle overlaps its 6 lattice neighbours by 0.1 %
L = 8 * A


def _packing(skin=0.2, seed=4):
    """A compressed simple-cubic packing of 768 frictional, damped particles (paper species)
    on a lattice base, random velocities and spins, tilted gravity: ~2000 contacts, ~3000
    listed pairs (several pair blocks)."""
    rng = np.random.default_rng(seed)
    tab = InteractionTable(["flow", "base"], [1.0, 1.0])
    for a in ("flow", "base"):
        for b in ("flow", "base"):
            tab.set(a, b, ContactSpecies())
    s = ParticleSystem(L, L, tab, gvec=(math.sin(0.45), 0.0, -math.cos(0.45)), skin=skin)
    g = (np.arange(8) + 0.5) * A
    gx, gy = np.meshgrid(g, g)
    base = np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]
    fx, fy, fz = np.meshgrid(g, g, A * np.arange(1, 13), indexing="ij")
    flow = np.c_[fx.ravel(), fy.ravel(), fz.ravel()]
    pos = np.vstack([flow, base])
    nf = len(flow)
    s.set_particles(pos, np.ones(len(pos)), ptype=np.r_[np.zeros(nf, int), np.ones(len(base), int)],
                    fixed=np.r_[np.zeros(nf, bool), np.ones(len(base), bool)])
    s.vel[:nf] = rng.normal(0.0, 0.6, (nf, 3))
    s.omega[:nf] = rng.normal(0.0, 0.5, (nf, 3))
    s.initialize()
    return s


def _state(s):
    """Dynamic state; springs keyed by pair (the pair list itself depends on the skin)."""
    live = np.any(s.hist_t != 0.0, axis=1)
    order = np.lexsort((s.pj[live], s.pi[live]))
    return {"pos": s.pos.copy(), "vel": s.vel.copy(), "omega": s.omega.copy(),
            "force": s.force.copy(), "torque": s.torque.copy(), "e_el": np.array(s.e_elastic),
            "spring_pairs": np.c_[s.pi[live], s.pj[live]][order],
            "springs": s.hist_t[live][order]}


def _assert_same(a, b):
    for key in a:
        assert np.array_equal(a[key], b[key]), key


def _advance(s, steps, threads=1, slots=None):
    """Step ``s`` by each count in ``steps`` on ``threads`` threads (``slots`` runs of pair
    blocks); the thread count is restored afterwards."""
    nt = numba.get_num_threads()
    try:
        numba.set_num_threads(threads)
        s._slots_override = slots
        for n in steps:
            s.step(n)
    finally:
        numba.set_num_threads(nt)
    return s


def _run(threads=1, slots=None, skin=0.2, steps=(150, 250)):
    return _advance(_packing(skin), steps, threads, slots)


def test_same_numbers_for_any_split_of_the_pair_pass():
    ref = _run(threads=1)
    contacts = int((ref.pair_out[:, 10] > 0).sum())
    assert contacts > 500  # a packing, not a gas
    assert len(ref.pi) > 4 * 512  # several pair blocks to split
    a = _state(ref)
    released = ref.e_released
    for slots in (2, 3, 7):  # the multi-thread summation, on one thread
        s = _run(threads=1, slots=slots)
        _assert_same(a, _state(s))
        assert s.e_released == released
    if numba.config.NUMBA_NUM_THREADS >= 2:
        s = _run(threads=2)
        _assert_same(a, _state(s))
        assert s.e_released == released


def test_same_numbers_for_any_verlet_skin_and_chunking():
    a = _state(_run(skin=0.2))
    s = _run(skin=0.02, steps=(400,))  # many neighbour- and near-list rebuilds
    assert s.n_rebuilds >= 3
    _assert_same(a, _state(s))
    _assert_same(a, _state(_run(skin=0.5, steps=(1, 99, 300))))


def test_vectorised_linear_contacts_equal_the_scalar_law():
    """Linear-law systems run their pair contacts through the SIMD kernel
    (``kernels._linear_maths``); it must give the scalar contact law's numbers bit for bit."""
    from granflow.engine.lib import kernels as K

    vector = _packing()
    scalar = _packing()
    law, coef, all_linear = K.coefficient_table(*scalar.tables)
    assert all_linear
    scalar._coef, scalar._coef_src = (law, coef, False), scalar.tables  # force the scalar path
    for n in (1, 200):
        vector.step(n)
        scalar.step(n)
        _assert_same(_state(vector), _state(scalar))
    assert int((vector.pair_out[:, 10] > 0).sum()) > 500


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 40 * 512), st.integers(1, 9), st.integers(0, 2**31 - 1))
def test_split_runs_covers_the_blocks_in_order_and_balances_two_runs(nnear, nslots, seed):
    """``split_runs``: runs of blocks that cover the near list once, in order; with two runs,
    the larger cost is within one block of the best contiguous split (the cost model of the
    kernel: near pairs + CONTACT_COST x contacts, the first run also PUSH_COST x contacts)."""
    from granflow.engine.lib import kernels as K

    nblock = (nnear + K.PAIR_BLOCK - 1) // K.PAIR_BLOCK
    rng = np.random.default_rng(seed)
    blk_nc = rng.integers(0, 400, nblock + 3).astype(np.int64)  # stale entries beyond nblock
    run = np.full(nslots + 1, -1, dtype=np.int64)
    K.split_runs(nnear, blk_nc, nslots, run)
    assert run[0] == 0 and run[-1] == nblock
    assert np.all(np.diff(run) >= 0)
    if nslots == 2 and nblock:
        size = np.minimum(K.PAIR_BLOCK, nnear - K.PAIR_BLOCK * np.arange(nblock))
        cost = size + K.CONTACT_COST * blk_nc[:nblock]
        first = np.r_[0.0, np.cumsum(cost + K.PUSH_COST * blk_nc[:nblock])]
        rest = cost.sum() - np.r_[0.0, np.cumsum(cost)]
        worst = np.maximum(first, rest)
        assert worst[run[1]] <= worst.min() + (cost + K.PUSH_COST * blk_nc[:nblock]).max()


@settings(max_examples=100, deadline=None)
@given(st.integers(2, 1300), st.integers(0, 4 * 512), st.integers(2, 9), st.integers(0, 2**31 - 1))
def test_fused_push_gives_every_particle_its_rows_in_pair_order(n, npair, nslots, seed):
    """The particle pass's push (``kernels._push_rows_into``, one equal share of the particle
    blocks per slot, stopping at the first pair past the share) adds exactly what the serial
    ``push_rows`` adds, bit for bit: every row of runs 1... onto both its particles, in pair
    order, on sorted pair lists (i < j, by (i, j)) with random contacts and run splits."""
    from granflow.engine.lib import kernels as K

    rng = np.random.default_rng(seed)
    # a sorted pair list i < j (duplicates removed)
    i = rng.integers(0, n - 1, npair)
    j = np.minimum(i + 1 + rng.geometric(0.02, npair), n - 1)
    key = np.unique(i * n + j)
    pi, pj = (key // n).astype(np.uint32), (key % n).astype(np.uint32)
    npair = len(pi)
    nblk = (npair + K.PAIR_BLOCK - 1) // K.PAIR_BLOCK
    pstate = rng.choice(np.array([K.CONTACT, K.NO_CONTACT, K.GRAZING], np.uint8), npair,
                        p=[0.6, 0.3, 0.1]).astype(np.uint8)
    scratch = np.zeros(max(npair, 1), np.uint32)
    blk_nc = np.zeros(nblk + 1, np.int64)
    for b in range(nblk):  # the block's touching (and grazing) pairs, in pair order
        listed = [p for p in range(b * K.PAIR_BLOCK, min((b + 1) * K.PAIR_BLOCK, npair))
                  if pstate[p] != K.NO_CONTACT]
        scratch[b * K.PAIR_BLOCK:b * K.PAIR_BLOCK + len(listed)] = listed
        blk_nc[b] = len(listed)
    crow = rng.normal(size=(max(npair, 1), 9)) * 10.0 ** rng.integers(-8, 8, (max(npair, 1), 1))
    run_start = np.r_[0, np.sort(rng.integers(0, nblk + 1, nslots - 1)), nblk].astype(np.int64)
    force0 = rng.normal(size=(n, 3))
    torque0 = rng.normal(size=(n, 3))
    ref_f, ref_t = force0.copy(), torque0.copy()
    K.push_rows(run_start[1], npair, pi, pj, crow, pstate, scratch, blk_nc, ref_f, ref_t)
    f, t = force0.copy(), torque0.copy()
    nblock = (n + K.PARTICLE_BLOCK - 1) // K.PARTICLE_BLOCK
    for r in range(nslots):
        lo = (r * nblock) // nslots * K.PARTICLE_BLOCK
        hi = min(((r + 1) * nblock) // nslots * K.PARTICLE_BLOCK, n)
        for rr in range(1, nslots):
            if K._push_rows_into(run_start[rr], run_start[rr + 1], lo, hi, pi, pj, crow,
                                 pstate, scratch, blk_nc, f, t):
                break
    assert np.array_equal(f, ref_f) and np.array_equal(t, ref_t)


@pytest.mark.parametrize("nthreads", [1, 2, 3, 8])
def test_work_rows_start_on_cache_lines(nthreads):
    """Every variable's row of every thread's work row starts on a 64-byte line (the maths
    loop's vector loads must not straddle lines: 151-156 -> 144-148 us per step on the
    benchmark chute, benchmarks/README.md), and the rows start zeroed and do not overlap."""
    from granflow.engine.lib import kernels as K

    assert (K.CHUNK_STRIDE * 8) % K.WORK_ALIGN == 0
    w = K.work_rows(nthreads)
    assert w.shape == (nthreads, K.WORK_SIZE) and w.flags.c_contiguous
    assert not w.any()
    for t in range(nthreads):
        for var in range(K.NWORK):
            assert w[t, var * K.CHUNK_STRIDE:].ctypes.data % K.WORK_ALIGN == 0
    w[0, -1] = 1.0  # the last element of thread 0's row is not thread 1's first
    if nthreads > 1:
        assert not w[1:].any()
    assert _packing()._work.ctypes.data % K.WORK_ALIGN == 0
