"""The VerletList: its contract against brute force (tests/naive.py).

* After every ``update`` the list holds every pair within ``cutoff`` of the
  current positions (the Verlet guarantee), under moves and under NVE and
  NPT-like cell changes, whether it rebuilt or not.
* It rebuilds exactly when its test says so: a move past ``skin / 2``, a
  strain the skin cannot cover, other numbers, pbc or number of atoms;
  ``version`` counts the builds.
* The row chunks belong to one list: a new build gives a new one.
"""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ase_mlg.verletlist import VerletList
from naive import pairs as naive_pairs

RC, SKIN = 3.0, 0.6


def _liquid(n, box, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, box, size=(n, 3)), np.eye(3) * box


def _held(vl, positions, cell):
    """The list's unordered pairs as a set of (i, j, S) with i <= j side
    chosen canonically, at the list's current positions."""
    res = vl.arrays(half=True, quantities="ijS")
    got = set()
    for i, j, S in zip(res["i"], res["j"], res["S"]):
        S = tuple(int(s) for s in S)
        a, b = (int(i), int(j), S), (int(j), int(i), tuple(-s for s in S))
        got.add(min(a, b))
    return got


def _within(positions, cell, pbc, cutoff):
    ref = naive_pairs(positions, cell, pbc, cutoff)
    return {min(k, (k[1], k[0], tuple(-s for s in k[2]))) for k in ref}


def _assert_holds_within_cutoff(vl, positions, cell, pbc):
    """Every pair within RC of ``positions`` is in the list (the list was
    built at other positions: compare pairs by (i, j, S) and the distance
    at the current positions)."""
    pl = vl.pairs
    t = np.repeat(np.arange(pl.natoms), np.diff(pl.rowptr))
    # the list's pairs at the current positions: X is this update's
    d = np.linalg.norm(vl.X[pl.nbr] - vl.X[t] + vl.svec[pl.code], axis=1)
    images = pl.images
    S = pl.shifts[pl.code] + images[pl.nbr] - images[t]
    i, j = pl.order[t], pl.order[pl.nbr]
    held = {min((int(a), int(b), tuple(map(int, s))), (int(b), int(a), tuple(-int(x) for x in s)))
            for a, b, s in zip(i, j, S)}
    need = _within(positions, cell, pbc, RC)
    assert need <= held, sorted(need - held)[:5]
    # and the distances the kernel sees are the current ones
    ref = naive_pairs(positions, cell, pbc, RC + SKIN + 2.0)
    for a, b, s, dist in list(zip(i, j, S, d))[:200]:
        assert dist == pytest.approx(ref[(int(a), int(b), tuple(map(int, s)))][0], abs=1e-9)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10**6), npt=st.booleans(), steps=st.integers(1, 8))
def test_every_pair_within_the_cutoff_after_every_update(seed, npt, steps):
    pos, cell = _liquid(60, 9.0, seed)
    pbc = np.array([True, True, True])
    vl = VerletList.allocate(pos, cell, pbc, RC, skin=SKIN)
    rng = np.random.default_rng(seed + 1)
    builds = []
    for _ in range(steps):
        pos = pos + rng.normal(scale=0.12, size=pos.shape)
        if npt:
            strain = np.eye(3) + rng.normal(scale=0.01, size=(3, 3))
            pos, cell = pos @ strain, cell @ strain
        builds.append(vl.update(pos, cell, pbc))
        _assert_holds_within_cutoff(vl, pos, cell, pbc)
    assert vl.version == sum(builds)
    assert vl.stats["list_builds"] == 1 + sum(builds)


def test_rebuilds_exactly_past_half_the_skin():
    pos, cell = _liquid(80, 10.0, 3)
    pbc = [True] * 3
    vl = VerletList.allocate(pos, cell, pbc, RC, skin=SKIN)
    assert vl.version == 0
    moved = pos.copy()
    moved[7] += [0.999 * SKIN / 2, 0, 0]
    assert vl.update(moved, cell, pbc) is False and vl.version == 0
    moved[7] = pos[7] + [1.001 * SKIN / 2, 0, 0]
    assert vl.update(moved, cell, pbc) is True and vl.version == 1
    # the new reference: the same positions again keep it
    assert vl.update(moved, cell, pbc) is False and vl.version == 1


def test_strain_the_skin_cannot_cover_rebuilds():
    pos, cell = _liquid(80, 10.0, 4)
    pbc = [True] * 3
    vl = VerletList.allocate(pos, cell, pbc, RC, skin=SKIN)
    # an affine change alone: valid while smin(M) (rc + skin) > rc
    small = np.diag([1.0, 1.0, 1.0 - 0.5 * SKIN / (RC + SKIN)])
    assert vl.update(pos @ small, cell @ small, pbc) is False
    big = np.diag([1.0, 1.0, 1.0 - 1.5 * SKIN / (RC + SKIN)])
    assert vl.update(pos @ big, cell @ big, pbc) is True


@pytest.mark.parametrize("change", ["numbers", "pbc", "natoms"])
def test_other_system_rebuilds(change):
    pos, cell = _liquid(40, 8.0, 5)
    numbers = np.full(40, 18)
    vl = VerletList.allocate(pos, cell, [True] * 3, RC, numbers=numbers, skin=SKIN,
                             types=lambda z: (z == 36).astype(np.int32))
    assert vl.update(pos, cell, [True] * 3, numbers) is False
    if change == "numbers":
        numbers = numbers.copy()
        numbers[3] = 36
        assert vl.update(pos, cell, [True] * 3, numbers) is True
        assert vl.types[np.flatnonzero(vl.pairs.order == 3)[0]] == 1
    elif change == "pbc":
        assert vl.update(pos, cell, [True, True, False], numbers) is True
    else:
        assert vl.update(pos[:-1], cell, [True] * 3, numbers[:-1]) is True
        assert vl.pairs.natoms == 39
    assert vl.version == 1


def test_numbers_same_is_trusted_not_compared():
    """``numbers_same=True`` (an MD step's check found no new numbers) keeps
    the list without comparing them: other numbers given with it do not
    rebuild it, and the next update that compares them does."""
    pos, cell = _liquid(40, 8.0, 5)
    numbers = np.full(40, 18)
    vl = VerletList.allocate(pos, cell, [True] * 3, RC, numbers=numbers, skin=SKIN,
                             types=lambda z: (z == 36).astype(np.int32))
    other = numbers.copy()
    other[3] = 36
    assert vl.update(pos, cell, [True] * 3, other, numbers_same=True) is False
    assert vl.update(pos, cell, [True] * 3, other) is True
    assert vl.types[np.flatnonzero(vl.pairs.order == 3)[0]] == 1


def test_skin_zero_rebuilds_every_update_and_closed_keeps_the_cutoff():
    # two atoms exactly rc apart: ASE's potentials keep d == rc
    pos = np.array([[0.0, 0.0, 0.0], [RC, 0.0, 0.0]])
    cell = np.eye(3) * 20.0
    for closed, expected in ((True, 1), (False, 0)):
        vl = VerletList.allocate(pos, cell, [False] * 3, RC, skin=0.0, closed=closed)
        assert len(vl.pairs) == expected
        assert vl.update(pos, cell, [False] * 3) is True
    assert vl.version == 1


@pytest.mark.parametrize("natoms, box", [(200, 12.0), (5000, 35.0)])
def test_row_chunks_belong_to_one_list(natoms, box):
    # the chunks are the list's (row_chunks: a function of the list alone),
    # never the thread count's: one object for any nthreads, kept until the
    # next build, which cuts its list into chunks of its own
    from ase_mlg.chunks import WINDOW_BUDGET, chunk_count
    pos, cell = _liquid(natoms, box, 6)
    vl = VerletList.allocate(pos, cell, [True] * 3, RC, skin=SKIN)
    p1 = vl.chunks()
    assert vl.chunks(1) is p1 and vl.chunks(2) is p1
    assert 1 <= p1.nchunk <= chunk_count(len(vl.pairs))
    assert (p1.nchunk == 1) == (natoms == 200)  # a short list: one chunk
    assert p1.entries <= max(WINDOW_BUDGET, 1) * natoms
    vl.build(pos, cell, [True] * 3)
    p2 = vl.chunks(2)
    assert p2 is not p1 and vl.chunks(1) is p2
    assert p2.nchunk == p1.nchunk  # the same list, the same chunks
    np.testing.assert_array_equal(p2.arrays.rows, p1.arrays.rows)
    rows = p2.arrays.rows
    assert rows[0] == 0 and rows[-1] == vl.pairs.natoms and (np.diff(rows) >= 0).all()


def test_radii_and_cutoff_setter_match_brute_force():
    pos, cell = _liquid(50, 8.0, 7)
    pbc = [True, False, True]
    radii = np.random.default_rng(8).uniform(0.5, 1.5, 50)
    vl = VerletList.allocate(pos, cell, pbc, radii, block=2, follow_cell=False)
    assert _held(vl, pos, cell) == _within(pos, cell, pbc, radii[:, None] + radii[None, :])
    exact = VerletList.allocate(pos, cell, pbc, 2.0, block=2, follow_cell=False)
    exact.cutoff = 2.7
    assert exact.pairs is None  # a new radius drops the list
    exact.build(pos, cell, pbc)
    assert _held(exact, pos, cell) == _within(pos, cell, pbc, 2.7)
    with pytest.raises(ValueError, match="template"):
        VerletList(radii, template=3)
    with pytest.raises(ValueError, match="skin"):
        VerletList(RC, skin=-1.0)


def test_an_atom_sent_far_rebuilds_on_a_new_grid():
    """A large move is a reason to rebuild, never an error (issue 25.7):
    every pair within the cutoff is held after it, from a new grid."""
    pos, cell = _liquid(40, 8.0, 9)
    vl = VerletList.allocate(pos, cell, [True] * 3, RC, skin=SKIN)
    grids = vl.stats["grid_builds"]
    far = pos.copy()
    far[11] += 1e6
    assert vl.update(far, cell, [True] * 3)
    assert vl.stats["grid_builds"] == grids + 1
    fresh = VerletList.allocate(far, cell, [True] * 3, RC, skin=SKIN)
    assert _held(vl, far, cell) == _held(fresh, far, cell)
    # the atoms that stayed keep their pairs (brute force before the move)
    stay = {k for k in _held(vl, far, cell) if 11 not in k[:2]}
    assert stay == {k for k in _within(pos, cell, [True] * 3, RC + SKIN) if 11 not in k[:2]}


def test_radii_lists_update_and_refuse_a_skin():
    """Per-atom radii: update rebuilds (the list holds no skin) and holds
    every pair within r_i + r_j; a skin would be ignored, so it is refused
    (issue 25.9: update crashed on rlist = None)."""
    pos, cell = _liquid(40, 8.0, 3)
    radii = np.random.default_rng(4).uniform(0.8, 1.6, 40)
    vl = VerletList.allocate(pos, cell, [True] * 3, radii)
    moved = pos + np.random.default_rng(5).normal(scale=0.05, size=pos.shape)
    assert vl.update(moved, cell, [True] * 3)
    pair_cut = radii[:, None] + radii[None, :]
    assert _held(vl, moved, cell) == _within(moved, cell, [True] * 3, pair_cut)
    assert vl.update(moved, cell, [True] * 3)  # nothing moved: still rebuilt (no skin)
    with pytest.raises(ValueError, match="skin"):
        VerletList(radii, skin=0.5)


def test_images_in_rank_order_remade_after_the_gather():
    # the gather keeps each atom's image in atom order; the rank-order copy
    # goes (23 MB at 10^6 atoms) and comes back equal where asked for
    pos, cell = _liquid(5000, 35.0, 6)
    vl = VerletList(RC, skin=SKIN)
    pl = vl.build(pos, cell, [True] * 3)
    before = pl.images.copy()
    X = pl.positions(pos, cell)  # the gather
    assert pl._images is None
    np.testing.assert_array_equal(pl.images, before)
    assert pl.images.flags.c_contiguous
    np.testing.assert_array_equal(pl.positions(pos, cell), X)
    assert pl.images.dtype == np.int64  # what the list's kernels take


@pytest.mark.parametrize("far", [0, 2 ** 31 + 5])
def test_the_gather_reads_images_beyond_int32(far):
    # the gather keeps ranks and images as int32 where they fit, and int64
    # for an atom 2^31 cells out; X is x[order] + images @ cell in the
    # kernel's operation order either way
    pos, cell = _liquid(5000, 35.0, 7)
    pl = VerletList(RC, skin=SKIN).build(pos, cell, [True] * 3)
    images = pl.images.copy()
    images[17, 1] += far
    pl.drop_atom_arrays()
    pl.images = images
    X = pl.positions(pos, cell)
    assert pl._by_atom[1].dtype == (np.int64 if far else np.int32)
    x, m = pos[pl.order], images.astype(np.float64)
    want = x + (m[:, :1] * cell[0] + m[:, 1:2] * cell[1] + m[:, 2:] * cell[2])
    np.testing.assert_array_equal(X, want)
    np.testing.assert_array_equal(pl.images, images)


def test_a_list_on_a_grid_carried_to_new_numbers_is_the_exact_one():
    """VerletList.build(renumber=...) (a rank's local atoms after
    migration): the grid is carried over, and the list is brute force's."""
    rng = np.random.default_rng(7)
    n, L = 1500, 24.0
    x = rng.random((n, 3)) * L
    cell, pbc = np.eye(3) * L, np.array([True, True, False])
    vl = VerletList.allocate(x, cell, pbc, RC, skin=SKIN)
    vl.build(x, cell, pbc)
    gone = rng.choice(n, 30, replace=False)
    kept = np.setdiff1d(np.arange(n), gone)
    y = np.concatenate([x[kept], x[gone[:20]] + 0.2])
    y += rng.normal(scale=0.05, size=y.shape)
    perm = rng.permutation(len(y))
    new_of_old = np.full(n, -1)
    new_of_old[kept] = perm[:len(kept)]
    z = np.empty_like(y)
    z[perm] = y
    carries = vl.stats["grid_carries"]
    vl.build(z, cell, pbc, renumber=new_of_old)
    assert vl.stats["grid_carries"] == carries + 1
    assert _held(vl, z, cell) == _within(z, cell, pbc, RC + SKIN)
