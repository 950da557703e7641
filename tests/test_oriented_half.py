"""PairList.arrays(orient=...): each unordered pair once, oriented by a rule
on the cell shifts, equal element for element (order and bits included) to
the full list filtered by that rule.

Two rules, those of ASE's two primitives' ``bothways=False`` halves:
NewPrimitiveNeighborList's (S lexicographically positive, or S == 0 and
i <= j: offsets 0, basis the identity) and PrimitiveNeighborList's (the
image shift n in the Minkowski-reduced basis of the wrapped positions,
computed here as ``ase_mlg.neighborlist._MLGPrimitive._orientation`` does).
"""

import numpy as np
import pytest
from ase.cell import Cell
from ase.geometry import minkowski_reduce, wrap_positions

from ase_mlg.blocks import BlockIndex
from ase_mlg.grid import MLG
from ase_mlg.query import CUT_RADII, CUT_SCALAR, half_list

EYE = np.eye(3, dtype=np.int64)


def old_rule(cell, pbc, positions):
    """(offsets, basis) of ase PrimitiveNeighborList's half."""
    cellobj = Cell(cell)
    rcell, op = minkowski_reduce(cellobj, pbc)
    wrapped = wrap_positions(positions, rcell, pbc=pbc, eps=0)
    offsets = cellobj.scaled_positions(wrapped - positions).round().astype(int)
    return offsets, np.rint(np.linalg.inv(op)).astype(int)


def rule_mask(i, j, S, offsets, basis):
    """The entries (i, j, S) of a full list that the rule keeps."""
    off = np.zeros((max(i.max(initial=-1), j.max(initial=-1)) + 1, 3), np.int64) \
        if offsets is None else offsets
    n0, n1, n2 = ((S + off[i] - off[j]) @ basis).T
    return ((n0 > 0) | ((n0 == 0) & (n1 > 0)) | ((n0 == 0) & (n1 == 0) & (n2 > 0))
            | ((n0 == 0) & (n1 == 0) & (n2 == 0) & (i <= j)))


def system(seed):
    """A small random system: triclinic or not, any pbc, positions partly
    outside the cell, a cutoff up to about a cell height (tiny cells: an
    atom sees its own images), scalar or per-atom cutoffs."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    cell = np.diag(rng.uniform(2.0, 8.0, 3))
    if seed % 3:
        cell[1, 0], cell[2, 0], cell[2, 1] = rng.uniform(-2.0, 2.0, 3)
    pbc = rng.random(3) < 0.6
    pos = rng.uniform(0, 1, (n, 3)) @ cell + rng.normal(scale=0.4, size=(n, 3))
    rc = float(rng.uniform(1.0, 5.0))
    radii = rng.uniform(0.3, 2.5, n) if seed % 2 else None
    return pos, cell, pbc, rc, radii, bool(seed % 4 == 1)


def build(pos, cell, pbc, rc, radii, self_interaction):
    """The half list as ase_mlg.query.find_pairs builds it."""
    grid = MLG(pos, cell, pbc)
    index = BlockIndex(grid, 2)
    if radii is None:
        pl = half_list(index, np.full(len(pos), rc), CUT_SCALAR, rc,
                       self_interaction=self_interaction)
    else:
        pl = half_list(index, radii + radii.max(), CUT_RADII, radii=radii,
                       self_interaction=self_interaction)
    return pl, index


def check(pl, index, orient, quantities="ijdDS"):
    full = pl.arrays(index.positions, index.cell, False, "ijdDS")
    keep = rule_mask(full["i"], full["j"], full["S"], *orient)
    got = pl.arrays(index.positions, index.cell, quantities=quantities, orient=orient)
    assert sorted(got) == sorted(set("i" + quantities))
    for q, v in got.items():
        want = full[q][keep]
        assert v.dtype == want.dtype and v.shape == want.shape, q
        assert np.array_equal(v, want), q
        assert v.tobytes() == want.tobytes(), q  # the same bits (signed zeros)
    # each unordered pair once: the kept entries and their mirrors are the full list
    if "j" in got and "S" in got:
        n = len(full["i"])
        one = np.column_stack([got["i"], got["j"], got["S"]])
        both = np.unique(np.vstack([one, np.column_stack([got["j"], got["i"], -got["S"]])]),
                         axis=0)
        assert len(both) == n
        assert len(got["i"]) == (n + np.sum((full["i"] == full["j"])
                                            & (full["S"] == 0).all(axis=1))) // 2
    return got


@pytest.mark.parametrize("seed", range(16))
def test_oriented_equals_masked_full(seed):
    pos, cell, pbc, rc, radii, si = system(seed)
    pl, index = build(pos, cell, pbc, rc, radii, si)
    new = check(pl, index, (None, EYE))
    # offsets given as zeros: the same
    zeros = pl.arrays(index.positions, index.cell, orient=(np.zeros((len(pos), 3), int), EYE))
    for q in new:
        assert np.array_equal(new[q], zeros[q])
    check(pl, index, old_rule(cell, pbc, index.positions))
    check(pl, index, (None, EYE), "iS")
    check(pl, index, old_rule(cell, pbc, index.positions), "ijd")


@pytest.mark.parametrize("self_interaction", [False, True])
@pytest.mark.parametrize("tri", [False, True])
def test_tiny_cell_own_images(self_interaction, tri):
    # a 1.7 Å cell with a 4 Å cutoff: every atom pairs with many of its own
    # images (i == j, S != 0), and with itself (S == 0) when asked
    cell = np.diag([1.7, 2.1, 1.9])
    if tri:
        cell[1, 0], cell[2, 0], cell[2, 1] = 0.8, -0.6, 0.5
    rng = np.random.default_rng(7)
    pos = rng.uniform(0, 1, (3, 3)) @ cell + np.array([0.0, -2.5, 3.0])
    for pbc in ([True] * 3, [True, False, True]):
        pbc = np.array(pbc)
        pl, index = build(pos, cell, pbc, 4.0, None, self_interaction)
        full = pl.arrays(index.positions, index.cell)
        assert ((full["i"] == full["j"]) & (full["S"] != 0).any(axis=1)).sum() > 10
        got = check(pl, index, (None, EYE))
        check(pl, index, old_rule(cell, pbc, index.positions))
        selfs = ((got["i"] == got["j"]) & (got["S"] == 0).all(axis=1)).sum()
        assert selfs == (3 if self_interaction else 0)


def test_oriented_ignores_half_and_empty():
    pos, cell, pbc, rc, radii, si = system(3)
    pl, index = build(pos, cell, pbc, rc, radii, si)
    a = pl.arrays(index.positions, index.cell, half=True, orient=(None, EYE))
    b = pl.arrays(index.positions, index.cell, half=False, orient=(None, EYE))
    for q in "ijdDS":
        assert np.array_equal(a[q], b[q])
    # no atoms
    pl, index = build(np.zeros((0, 3)), np.eye(3) * 5, np.array([True] * 3), 2.0, None, False)
    got = pl.arrays(index.positions, index.cell, orient=(np.zeros((0, 3), int), EYE))
    assert all(len(v) == 0 for v in got.values())


def test_orient_checked():
    pos, cell, pbc, rc, radii, si = system(2)
    pl, index = build(pos, cell, pbc, rc, radii, si)
    n = len(pos)
    for bad in [EYE, (np.zeros((n + 1, 3), int), EYE), (None, np.eye(3)),
                (np.zeros((n, 3)), EYE), (None, EYE[:2])]:
        with pytest.raises(ValueError, match="orient"):
            pl.arrays(index.positions, index.cell, orient=bad)
