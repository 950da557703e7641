"""The small-system path of the neighbour list (ase_mlg.allpairs, issue 24.1).

Below ``allpairs.MAX_WORK`` tested images ``neighbor_list`` answers from
one compiled all-pairs call instead of the grid's block query.  Here, on
scenes on both sides of that threshold: the small path gives the block
query's pairs (``neighbor_list(..., grid=...)`` always takes the block
query) with ``i``, ``j``, ``S`` and ``d`` bitwise equal and ``D`` equal as
numbers (bitwise but for the sign of exact zeros: the block query writes a
pair's second entry as ``-D``, the small path computes every entry as ASE
does, and ``-(+0.0)`` is ``-0.0``), once both are put in one order; its
own order is by ``(i, j, S)``; and it gives ASE's pairs (``d`` and ``D``
to 1e-12 Å: ASE's ``S @ cell`` is a numpy product, summed in its own
order).  Bad input raises what the block query raises.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import ase
import ase.neighborlist as ase_nl
from ase.build import bulk, molecule

import ase_mlg
import naive
from ase_mlg import allpairs
from ase_mlg import neighborlist as nl
from ase_mlg.query import CUT_SCALAR

Q = "ijdDS"


def canonical(res):
    """(i, j, d, D, S) sorted by (i, j, S)."""
    i, j, d, D, S = res
    o = np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i))
    return i[o], j[o], d[o], D[o], S[o]


def block_query(atoms, cutoff, **kw):
    """The block query's list: a grid given, neighbor_list takes it."""
    return nl.neighbor_list(Q, atoms, cutoff, grid=ase_mlg.MLG.from_atoms(atoms), **kw)


def assert_same_list(small, large):
    """``small`` (in its own order) and ``large`` (any order): the same
    entries, i, j, S, d bitwise, D equal and bitwise up to signed zeros."""
    si, sj, sd, sD, sS = small
    li, lj, ld, lD, lS = canonical(large)
    assert len(si) == len(li)
    assert np.array_equal(si, li) and np.array_equal(sj, lj) and np.array_equal(sS, lS)
    assert np.array_equal(sd.view(np.uint64), ld.view(np.uint64))
    assert np.array_equal(sD, lD)
    assert ((sD.view(np.uint64) == lD.view(np.uint64)) | (sD == 0)).all()


def assert_ordered(res):
    i, j, _, _, S = res
    assert np.array_equal(np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i)), np.arange(len(i)))


def assert_same_as_ase(res, atoms, cutoff, **kw):
    ai, aj, ad, aD, aS = canonical(ase_nl.neighbor_list(Q, atoms, cutoff, **kw))
    i, j, d, D, S = res
    assert np.array_equal(i, ai) and np.array_equal(j, aj) and np.array_equal(S, aS)
    if len(i):
        assert np.abs(d - ad).max() < 1e-12 and np.abs(D - aD).max() < 1e-12


def small_path(atoms, cutoff, self_interaction=False):
    """allpairs.all_pairs on these atoms, as neighbor_list calls it (None
    where it declines)."""
    pos = np.ascontiguousarray(atoms.positions, dtype=np.float64)
    mode, cut, radii, types, table, _ = nl._parse_cutoff(cutoff, len(atoms), atoms.numbers)
    res = allpairs.all_pairs(pos, atoms.cell.array, atoms.pbc, (mode, cut, radii, types, table),
                             self_interaction, Q)
    return None if res is None else tuple(res[q] for q in Q)


def _rattled(atoms, seed=0, by=0.05):
    atoms = atoms.copy()
    atoms.rattle(by, seed=seed)
    return atoms


def _triclinic(n=7, pbc=True, seed=1):
    rng = np.random.default_rng(seed)
    cell = np.array([[4.0, 0.0, 0.0], [2.7, 3.5, 0.0], [-1.9, 1.2, 3.8]])
    return ase.Atoms(f"C{n}", scaled_positions=rng.random((n, 3)), cell=cell, pbc=pbc)


def _slab_without_z_vector():
    a = bulk("Cu", "fcc", a=3.61, cubic=True) * (2, 2, 2)
    a.set_cell([a.cell[0], a.cell[1], [0.0, 0.0, 0.0]], scale_atoms=False)
    a.pbc = (True, True, False)
    return _rattled(a)


def _water():
    rng = np.random.default_rng(4)
    pos = rng.random((12, 3)) * 6.0
    return ase.Atoms("OH2" * 4, positions=pos, cell=[6.0, 6.0, 6.0], pbc=True)


# (name, atoms, cutoff, self_interaction)
SCENES = [
    ("Cu fcc primitive, 1 atom", bulk("Cu", "fcc", a=3.61), 5.0, False),
    ("Cu primitive, rc 11 A: 458 images", bulk("Cu", "fcc", a=3.61), 11.0, False),
    ("Cu primitive, self_interaction", bulk("Cu", "fcc", a=3.61), 5.0, True),
    ("Si diamond, 8 atoms", bulk("Si", "diamond", a=5.43, cubic=True), 5.0, False),
    ("Si, dict cutoff", bulk("Si", "diamond", a=5.43, cubic=True), {("Si", "Si"): 2.5}, False),
    ("C60, no cell, no pbc", molecule("C60"), 5.0, False),
    ("C60, radii", molecule("C60"), [0.75] * 60, True),
    ("mixed pbc (1, 0, 1), triclinic", _triclinic(pbc=(True, False, True)), 3.0, True),
    ("triclinic, cutoff beyond the cell", _triclinic(), 6.5, False),
    ("slab, no z vector", _slab_without_z_vector(), 4.0, False),
    ("water-like, dict by number", _water(), {(8, 1): 1.2, ("H", "H"): 1.7, (8, 8): 3.0}, False),
    ("Cu, 108 atoms", _rattled(bulk("Cu", "fcc", a=3.61, cubic=True) * 3), 5.0, False),
    ("Cu, 500 atoms (below the threshold)",
     _rattled(bulk("Cu", "fcc", a=3.61, cubic=True) * 5), 5.0, False),
]


@pytest.mark.parametrize("name,atoms,cutoff,self_interaction", SCENES,
                         ids=[s[0] for s in SCENES])
def test_small_path_is_the_block_query_and_ase(name, atoms, cutoff, self_interaction):
    ours = nl.neighbor_list(Q, atoms, cutoff, self_interaction=self_interaction)
    took = small_path(atoms, cutoff, self_interaction)
    assert took is not None, "the small path declined"
    for x, y in zip(ours, took):  # neighbor_list answered with it
        assert np.array_equal(x, y) and x.dtype == y.dtype
    assert len(ours[0]) > 0
    assert_ordered(ours)
    assert_same_list(ours, block_query(atoms, cutoff, self_interaction=self_interaction))
    assert_same_as_ase(ours, atoms, cutoff, self_interaction=self_interaction)


def test_many_images_of_one_atom():
    """A 1-atom cell and a cutoff of many cell heights: every image, each
    once, both S and -S."""
    atoms = bulk("Cu", "fcc", a=3.61)
    i, j, d, D, S = nl.neighbor_list(Q, atoms, 11.0)
    assert (i == 0).all() and (j == 0).all() and len(i) > 400
    assert len({tuple(s) for s in S.tolist()}) == len(S)
    assert np.array_equal(np.sort(S, axis=0), np.sort(-S, axis=0))
    assert (d < 11.0).all() and (d > 0).all()


def test_threshold_splits_the_paths():
    """Cu at 5 Å: 500 atoms (work 4.7e5) take the small path, 864 (1.2e6)
    the block query -- whose order within an atom is the grid's, not (j,
    S) -- and both give ASE's pairs."""
    below = _rattled(bulk("Cu", "fcc", a=3.61, cubic=True) * 5)
    above = _rattled(bulk("Cu", "fcc", a=3.61, cubic=True) * 6)
    assert allpairs.work(len(below), below.cell.array, below.pbc, 5.0) <= allpairs.MAX_WORK
    assert allpairs.work(len(above), above.cell.array, above.pbc, 5.0) > allpairs.MAX_WORK
    assert small_path(below, 5.0) is not None
    assert small_path(above, 5.0) is None
    ours = nl.neighbor_list(Q, above, 5.0)
    grid = block_query(above, 5.0)
    for x, y in zip(ours, grid):
        assert np.array_equal(x, y)
    assert_same_as_ase(canonical(ours), above, 5.0)


def test_empty_and_no_pairs():
    for atoms in (ase.Atoms(), ase.Atoms(cell=[3, 3, 3], pbc=True)):
        res = nl.neighbor_list(Q, atoms, 5.0)
        assert [x.shape for x in res] == [(0,), (0,), (0,), (0, 3), (0, 3)]
    atoms = molecule("C60")
    res = nl.neighbor_list(Q, atoms, 0.5)
    assert len(res[0]) == 0 and res[3].shape == (0, 3) and res[4].dtype == np.int64
    # a zero cutoff keeps nothing, not even the self pair
    assert len(nl.neighbor_list("i", atoms, 0.0, self_interaction=True)) == 0


@pytest.mark.parametrize("quantities", ["i", "j", "d", "D", "S", "ij", "Sd", "dd", "Dji"])
def test_quantities_in_any_order(quantities):
    atoms = bulk("Si", "diamond", a=5.43, cubic=True)
    full = dict(zip(Q, nl.neighbor_list(Q, atoms, 4.0)))
    res = nl.neighbor_list(quantities, atoms, 4.0)
    res = (res,) if len(quantities) == 1 else res
    assert len(res) == len(quantities)
    for q, x in zip(quantities, res):
        assert np.array_equal(x, full[q]) and x.dtype == full[q].dtype


def test_scaled_positions_and_primitive():
    atoms = _triclinic(pbc=(True, True, False))
    ref = nl.neighbor_list(Q, atoms, 3.5)
    res = nl.primitive_neighbor_list(Q, atoms.pbc, atoms.cell.array,
                                     atoms.get_scaled_positions(wrap=False), 3.5,
                                     use_scaled_positions=True)
    i, j, d, D, S = res
    assert np.array_equal(i, ref[0]) and np.array_equal(j, ref[1])
    assert np.array_equal(S, ref[4]) and np.abs(d - ref[2]).max() < 1e-12
    # pbc as a plain bool and a list, cell as a (3,) diagonal
    box = ase.Atoms("C4", scaled_positions=np.random.default_rng(2).random((4, 3)),
                    cell=[3.0, 3.5, 4.0], pbc=True)
    a = nl.primitive_neighbor_list(Q, True, [3.0, 3.5, 4.0], box.positions, 4.0)
    b = nl.primitive_neighbor_list(Q, [1, 1, 1], box.cell.array, box.positions, 4.0)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    assert_same_list(a, block_query(box, 4.0))


def _error(f):
    with pytest.raises((ValueError, TypeError)) as e:
        f()
    return type(e.value), str(e.value)


POS = np.array([[0.1, 0.2, 0.3], [1.0, 1.1, 0.9]])


@pytest.mark.parametrize("cell,pbc", [
    (np.zeros((3, 3)), True),                                  # zero periodic cell
    ([[2.0, 0, 0], [0, 2, 0], [0, 0, 0]], True),               # periodic axis without vector
    ([[2.0, 0, 0], [4.0, 0, 0], [0, 0, 3]], (1, 0, 1)),        # dependent vectors
    ([[2.0, 0, 0], [0, np.nan, 0], [0, 0, 2]], False),         # NaN in the cell
    ([[2.0, 0, 0], [0, 2, 0]], True),                          # wrong shape
    (np.eye(3) * 3, [True, False]),                            # pbc of two
    (np.eye(3) * 3, "yes"),                                    # pbc a string
])
def test_bad_cells_raise_what_the_block_query_raises(cell, pbc):
    small = _error(lambda: nl.primitive_neighbor_list("ij", pbc, cell, POS, 2.0))
    grid = _error(lambda: ase_mlg.MLG(POS, np.asarray(cell, dtype=float), pbc))
    assert small == grid


def test_declined_inputs_go_to_the_block_query():
    """Atoms far out, cutoffs of a million images, an ill-conditioned
    inverse: the small path declines, the block query answers or raises
    as it always did."""
    atoms = bulk("Cu", "fcc", a=3.61)
    far = atoms.copy()
    far.positions += 3000 * far.cell[0]        # 3000 cells out: the block query's
    assert small_path(far, 5.0) is None
    assert_same_as_ase(canonical(nl.neighbor_list(Q, far, 5.0)), far, 5.0)
    with pytest.raises(ValueError, match="periodic images"):
        nl.neighbor_list("ij", atoms, 1e4)
    out = atoms.copy()
    out.positions += 1e12
    out.pbc = False
    assert small_path(out, 5.0) is None
    with pytest.raises(ValueError, match="precision"):
        nl.neighbor_list("ij", out, 5.0)


@st.composite
def small_scenes(draw):
    n = draw(st.integers(1, 12))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    cell = np.diag(rng.uniform(1.0, 7.0, 3))
    shear = draw(st.sampled_from([0.0, 0.5, 1.5]))
    cell[1, 0], cell[2, 0], cell[2, 1] = shear * rng.uniform(-1, 1, 3) * cell[0, 0]
    pbc = draw(st.tuples(st.booleans(), st.booleans(), st.booleans()))
    frac = rng.uniform(-0.5 if draw(st.booleans()) else 0.0, 1.2, (n, 3))
    if n > 1 and draw(st.booleans()):
        frac[-1] = frac[0]  # a duplicate position
    numbers = rng.choice([1, 6, 8], n)
    atoms = ase.Atoms(numbers=numbers, scaled_positions=frac, cell=cell, pbc=pbc)
    kind = draw(st.sampled_from(["scalar", "radii", "dict"]))
    big = draw(st.sampled_from([1.0, 3.0, 8.0]))
    if kind == "scalar":
        cutoff = float(rng.uniform(0, big))
    elif kind == "radii":
        cutoff = list(rng.uniform(0, big / 2, n))
    else:
        cutoff = {("H", "C"): float(rng.uniform(0, big)), (8, 8): float(rng.uniform(0, big)),
                  (6, 6): float(rng.uniform(0, big)), ("O", "H"): float(rng.uniform(0, big))}
    return atoms, cutoff, draw(st.booleans())


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(small_scenes())
def test_small_path_is_the_block_query_on_random_scenes(scene):
    """Triclinic cells, all pbc, atoms outside the cell, duplicates, all
    three cutoff kinds, cutoffs beyond the cell: both paths decide every
    pair on the same D, so there are no borderline pairs to leave out."""
    atoms, cutoff, self_interaction = scene
    ours = small_path(atoms, cutoff, self_interaction)
    assert ours is not None
    assert_ordered(ours)
    assert_same_list(ours, block_query(atoms, cutoff, self_interaction=self_interaction))


@pytest.mark.parametrize("pbc", [(True, True, True), (True, False, True), (False, False, False)])
@pytest.mark.parametrize("kind", ["scalar", "radii", "dict"])
@pytest.mark.parametrize("self_interaction", [False, True])
@pytest.mark.parametrize("screen", [False, True])
def test_one_image_rows_are_the_block_query(pbc, kind, self_interaction, screen, monkeypatch):
    """Cutoffs under half of every cell height: a pair can be within its
    cutoff at its nearest image only, and from allpairs.SCREEN_ATOMS atoms
    a vectorised screen at the largest cutoff leaves the partners that
    allpairs._half_pairs tests (here from 0 atoms, or never).  60 atoms of
    a sheared cell, some outside it, atoms at the largest cutoff's
    distance and a duplicate position."""
    calls = []
    kernel = allpairs._screen
    monkeypatch.setattr(allpairs, "SCREEN_ATOMS", 0 if screen else 10 ** 9)
    monkeypatch.setattr(allpairs, "_screen", lambda *a: calls.append(1) or kernel(*a))
    rng = np.random.default_rng(11)
    cell = np.array([[14.0, 0.0, 0.0], [3.0, 13.0, 0.0], [-2.0, 1.5, 15.0]])
    frac = rng.uniform(-0.3, 1.3, (60, 3))
    frac[-1] = frac[0]
    atoms = ase.Atoms(numbers=rng.choice([1, 6, 8], 60), scaled_positions=frac, cell=cell,
                      pbc=pbc)
    atoms.positions[1] = atoms.positions[2] + [4.0, 0.0, 0.0]  # exactly at 4 Å
    if kind == "scalar":
        cutoff = 4.0
    elif kind == "radii":
        cutoff = list(rng.uniform(0.5, 2.5, 60))
    else:
        cutoff = {("H", "C"): 4.0, (8, 8): 5.0, (6, 6): 2.0, ("O", "H"): 3.5}
    pos = np.ascontiguousarray(atoms.positions)
    mode, cut, radii, types, table, _ = nl._parse_cutoff(cutoff, 60, atoms.numbers)
    store, m = allpairs.half_store(pos, atoms.cell.array, atoms.pbc,
                                   (mode, cut, radii, types, table), self_interaction)
    rows = {tuple(r) for r in store[:m].tolist()}
    assert len(rows) == m
    ours = small_path(atoms, cutoff, self_interaction)
    assert_ordered(ours)
    large = block_query(atoms, cutoff, self_interaction=self_interaction)
    assert_same_list(ours, large)
    i, j, _, _, S = large
    half = {(a, b, *s) for a, b, s in zip(i.tolist(), j.tolist(), S.tolist()) if a <= b}
    assert rows == half
    assert len(calls) == (2 if screen else 0)  # half_store's and all_pairs'


def test_a_rebuild_takes_the_screen_and_keeps_the_list(monkeypatch):
    """A VerletList's rebuild (the last list of these atoms sizes its
    store) takes the screen from allpairs.SCREEN_REBUILD_ATOMS atoms, a
    first build only from allpairs.SCREEN_ATOMS (it would compile there
    for nothing).  256 atoms between the two: the rebuilt list is a fresh
    build's of the same positions, row for row, and each row holds the
    brute-force pairs within the list radius, those within the cutoff
    first (the store's flag placement)."""
    from ase_mlg.verletlist import VerletList
    assert allpairs.SCREEN_REBUILD_ATOMS <= 256 < allpairs.SCREEN_ATOMS
    calls = []
    kernel = allpairs._screen
    monkeypatch.setattr(allpairs, "_screen", lambda *a: calls.append(1) or kernel(*a))
    rng = np.random.default_rng(5)
    atoms = bulk("Ar", "fcc", a=5.3, cubic=True).repeat(4)
    atoms.positions += rng.normal(scale=0.05, size=atoms.positions.shape)
    cell, pbc = atoms.cell.array, atoms.pbc
    kept = VerletList(8.5, skin=1.0)
    kept.build(atoms.positions, cell, pbc)
    x = atoms.positions + rng.normal(scale=0.4, size=atoms.positions.shape)
    fresh = VerletList(8.5, skin=1.0)
    fresh.build(x, cell, pbc)
    assert calls == []
    kept.rebuild(x, cell, pbc)
    assert calls == [1]
    a, b = kept.pairs, fresh.pairs
    for name in ("order", "rowptr", "nbr", "code", "shifts", "images"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    brute = np.array(sorted((i, j, *S) for i, j, S in naive.pairs(x, cell, pbc, 9.5)
                            if i < j or (i == j and np.sign(S) @ [4, 2, 1] > 0)))
    assert np.array_equal(naive.atom_pairs(a), brute)
    t = np.repeat(np.arange(a.natoms), np.diff(a.rowptr))
    u = a.nbr.astype(np.int64)
    D = x[a.order[u]] - x[a.order[t]] + (a.shifts[a.code] + a.images[u] - a.images[t]) @ cell
    inside = np.linalg.norm(D, axis=1) <= 8.5
    assert 0 < inside.sum() < len(inside)
    for r in range(a.natoms):  # within the cutoff first in every row
        row = inside[a.rowptr[r]:a.rowptr[r + 1]]
        assert not (~row[:-1] & row[1:]).any(), r


def test_mirror_entries_match_the_entry():
    """Each pair at both atoms: (j, i, -S) beside (i, j, S), same d."""
    atoms = _triclinic(pbc=(True, False, True))
    i, j, d, D, S = nl.neighbor_list(Q, atoms, 4.0)
    entry = {(a, b, tuple(s)): (dd, DD) for a, b, s, dd, DD in
             zip(i.tolist(), j.tolist(), S.tolist(), d, D)}
    for (a, b, s), (dd, DD) in entry.items():
        md, mD = entry[(b, a, tuple(-x for x in s))]
        assert md == dd and np.array_equal(mD, -DD)


def test_cutoff_kinds_use_the_pair_rule():
    """radii: r_i + r_j; dict: the element pair's, absent pairs never."""
    atoms = _water()
    radii = np.linspace(0.3, 1.4, len(atoms))
    i, j, d = nl.neighbor_list("ijd", atoms, radii)
    assert (d < radii[i] + radii[j]).all() and len(i) > 0
    table = {(8, 1): 1.2, ("O", "O"): 3.0}
    i, j, d = nl.neighbor_list("ijd", atoms, table)
    z = atoms.numbers
    assert not ((z[i] == 1) & (z[j] == 1)).any()
    assert (d[(z[i] == 8) & (z[j] == 8)] < 3.0).all()
    assert (d[(z[i] != z[j])] < 1.2).all()
    # without numbers a dict means its largest value, as in ASE
    r = nl.primitive_neighbor_list("ij", atoms.pbc, atoms.cell.array, atoms.positions, table)
    s = nl.primitive_neighbor_list("ij", atoms.pbc, atoms.cell.array, atoms.positions, 3.0)
    assert np.array_equal(r[0], s[0]) and np.array_equal(r[1], s[1])
    assert CUT_SCALAR == 0


# (name, atoms, scalar cutoff or per-atom radii, self_interaction)
LIST_SCENES = [
    ("Cu primitive, rc 11 A: an atom and its own images", bulk("Cu", "fcc", a=3.61), 11.0,
     False),
    ("Cu primitive, self_interaction", bulk("Cu", "fcc", a=3.61), 5.0, True),
    ("C60, no cell, radii", molecule("C60"), np.full(60, 0.8), False),
    ("mixed pbc (1, 0, 1), triclinic", _triclinic(pbc=(True, False, True)), 3.0, False),
    ("triclinic, cutoff beyond the cell", _triclinic(), 6.5, False),
    ("slab, no z vector", _slab_without_z_vector(), 4.0, False),
    ("Cu, 108 atoms", _rattled(bulk("Cu", "fcc", a=3.61, cubic=True) * 3), 5.0, False),
]


@pytest.mark.parametrize("name,atoms,cutoff,self_interaction", LIST_SCENES,
                         ids=[s[0] for s in LIST_SCENES])
def test_verlet_list_builds_small_systems_with_the_block_querys_pairs(
        name, atoms, cutoff, self_interaction):
    """Below MAX_WORK the Verlet list's exact builds come from
    allpairs.half_store and PairList.from_store: the same set of pairs as
    the block query's (the list with an explicit block), each unordered
    pair once, rows in the
    atoms' order with no grid built (one is built when asked for), and
    (with a skin) each row's pairs within the cutoff first."""
    from ase_mlg.verletlist import VerletList
    skin = 0.0 if np.ndim(cutoff) else 0.7
    pos, cell = atoms.positions, atoms.cell.array
    small = VerletList.allocate(pos, cell, atoms.pbc, cutoff, skin=skin,
                                self_interaction=self_interaction)
    large = VerletList.allocate(pos, cell, atoms.pbc, cutoff, skin=skin, block=2,
                                self_interaction=self_interaction)
    assert len(small.pairs) > 0
    rows = naive.atom_pairs(small.pairs)
    assert len(np.unique(rows, axis=0)) == len(rows), "a pair is listed twice"
    np.testing.assert_array_equal(rows, naive.atom_pairs(large.pairs))
    np.testing.assert_array_equal(small.pairs.order, np.arange(len(atoms)))
    assert small.stats["grid_builds"] == 0 and large.stats["grid_builds"] == 1
    assert small.grid.natoms == len(atoms) and small.stats["grid_builds"] == 1
    assert (small.pairs.images == 0).all()
    if skin:
        pl = small.pairs
        t = np.repeat(np.arange(pl.natoms), np.diff(pl.rowptr))
        D = small.X[pl.nbr] - small.X[t] + small.svec[pl.code]
        outside = np.einsum("ij,ij->i", D, D) > cutoff ** 2
        for r in range(pl.natoms):  # inside first: no False after a True
            seg = outside[pl.rowptr[r]:pl.rowptr[r + 1]]
            assert not (np.diff(seg.astype(int)) < 0).any(), r
