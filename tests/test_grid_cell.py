"""Cell changes without a rebuild (issue 10, NPT): ``MLG.update(positions,
cell)`` rescales the stored grid coordinates per axis and keeps the order."""

import numpy as np
import pytest
from ase import Atoms
from ase.neighborlist import neighbor_list as ase_neighbor_list

from ase_mlg import MLG
from ase_mlg.blocks import BlockIndex
from ase_mlg.query import find_pairs

from test_grid import check_valid


def pair_set(i, j, S):
    return set(zip(i.tolist(), j.tolist(), map(tuple, np.asarray(S).tolist())))


def exact_pairs(grid, rc):
    n = grid.natoms
    out = find_pairs(BlockIndex(grid), np.full(n, rc), 0, rc, quantities="jS")
    return pair_set(out["i"], out["j"], out["S"])


def ase_pairs(positions, cell, pbc, rc):
    atoms = Atoms("Ar%d" % len(positions), positions=positions, cell=cell, pbc=pbc)
    i, j, S = ase_neighbor_list("ijS", atoms, rc)
    return pair_set(i, j, S)


SCENES = [
    # (cell, pbc, vacuum axis or None)
    ("ortho", (True, True, True)),
    ("triclinic", (True, True, True)),
    ("triclinic", (True, True, False)),
    ("ortho", (True, False, True)),
]


def start(kind, pbc, n, rng):
    L = 9.0
    cell = np.diag([L, 1.1 * L, 0.9 * L])
    if kind == "triclinic":
        cell = cell + np.array([[0, 0, 0], [2.0, 0, 0], [-1.5, 1.0, 0]])
    frac = rng.random((n, 3))
    for a in range(3):
        if not pbc[a]:
            # a slab in vacuum along a: atoms in the middle 60 % of the cell
            frac[:, a] = 0.2 + 0.6 * frac[:, a]
    return frac @ cell, cell


@pytest.mark.parametrize("kind,pbc", SCENES)
def test_npt_like_strains_keep_the_grid(kind, pbc):
    """MTKNPT-like: every step a small random strain of the cell (atoms
    scaled with it) plus small moves.  No rebuild, the grid stays monotone,
    the stored coordinates stay g(atom) + m * period, and the exact
    neighbour list equals ASE's on the new cell."""
    rng = np.random.default_rng(7)
    n, rc = 250, 2.6
    x, cell = start(kind, pbc, n, rng)
    grid = MLG(x, cell, pbc)
    for step in range(12):
        strain = rng.normal(scale=4e-3, size=(3, 3))
        if kind == "ortho":
            strain = np.diag(np.diag(strain))
        new_cell = cell @ (np.eye(3) + strain)
        x = x @ np.linalg.solve(cell, new_cell)  # scale the atoms with the cell
        x = x + rng.normal(scale=0.05, size=x.shape)
        cell = new_cell
        rec = grid.update(x, cell)
        assert not rec["rebuilt"], rec
        assert grid.is_monotone()
        assert np.allclose(grid.box.cell, cell, rtol=0, atol=0)
        check_valid(grid, n)
        assert exact_pairs(grid, rc) == ase_pairs(x, cell, pbc, rc)
    assert grid.stats["rebuilds"] == 0


def test_cell_rescale_alone_needs_no_swap():
    """Atoms scaled with the cell keep their fractional coordinates: the
    rescaled grid is already in order, periodic image offsets included
    (atoms that crossed faces many periods away)."""
    rng = np.random.default_rng(3)
    n = 400
    cell = np.diag([10.0, 11.0, 12.0])
    x = rng.random((n, 3)) @ cell
    grid = MLG(x, cell, True, monitor_every=0)
    # drift every atom three periods along x: the lines' windows follow, so
    # stored coordinates carry image offsets m * L with m up to 3
    for t in range(1, 101):
        grid.update(x + [t * 0.3, 0.0, 0.0])
    x = x + [30.0, 0.0, 0.0]
    assert grid._coords[:, 0].max() > 30.0 and grid.stats["rebuilds"] == 0
    new_cell = np.diag([10.5, 10.0, 12.3])
    rec = grid.update(x @ np.linalg.solve(cell, new_cell), new_cell)
    assert rec["sweeps"] == 0 and not rec["rebuilt"]
    check_valid(grid, n)
    # the image offsets were rescaled with the period
    h = grid.box.heights
    g = grid.box.fractional(grid.positions) * h
    m = (grid.coordinates()[..., 0][grid.sites >= 0]
         - g[grid.sites[grid.sites >= 0], 0]) / h[0]
    assert np.allclose(m, np.rint(m), atol=1e-9) and np.abs(np.rint(m)).max() >= 1


def test_unchanged_cell_is_bitwise_the_plain_update():
    rng = np.random.default_rng(4)
    cell = np.diag([8.0, 8.0, 8.0])
    x = rng.random((300, 3)) * 8
    a, b = MLG(x, cell, True), MLG(x, cell, True)
    for _ in range(5):
        x = x + rng.normal(scale=0.1, size=x.shape)
        ra, rb = a.update(x), b.update(x, cell.copy())
        assert ra == rb
        assert np.array_equal(a._sites, b._sites)
        assert np.array_equal(a._coords, b._coords)


@pytest.mark.parametrize("change,reason", [
    ("flat", "cell degenerate"),
    ("flip", "cell degenerate"),
    ("vanish", "cell rank changed"),
    ("pbc", "pbc changed"),
])
def test_degenerate_or_incompatible_cell_rebuilds(change, reason):
    rng = np.random.default_rng(5)
    cell = np.diag([9.0, 9.0, 20.0])
    pbc = (True, True, False)
    x = rng.random((200, 3)) * [9, 9, 5] + [0, 0, 7]
    grid = MLG(x, cell, pbc)
    new_pbc = None
    new = cell.copy()
    if change == "flat":  # the vacuum axis folds onto the xy plane
        new[2] = [9.0, 9.0, 1e-5]
    elif change == "flip":  # handedness flipped: passed through zero volume
        new[2] = -new[2]
    elif change == "vanish":  # the vacuum vector is dropped (ASE allows it)
        new[2] = 0.0
    else:
        new_pbc = (True, True, True)
    rec = grid.update(x, new, pbc=new_pbc)
    assert rec["rebuilt"] and rec["reason"] == reason
    assert grid.stats["rebuilds"] == 1
    check_valid(grid, 200)
    assert np.array_equal(grid.box.cell, new)
    if change != "flat":  # (periodic heights of the flat cell are ~1e-5 Å)
        assert exact_pairs(grid, 3.0) == ase_pairs(x, new, grid.box.pbc, 3.0)


def test_bad_cell_leaves_the_grid_unchanged():
    rng = np.random.default_rng(6)
    cell = np.diag([9.0, 9.0, 9.0])
    x = rng.random((100, 3)) * 9
    grid = MLG(x, cell, True)
    sites, coords = grid._sites.copy(), grid._coords.copy()
    with pytest.raises(ValueError, match="cell"):
        grid.update(x, np.zeros((3, 3)))
    y = x.copy()
    y[3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        grid.update(y, cell * 1.01)
    assert np.array_equal(grid.box.cell, cell)
    assert np.array_equal(grid._sites, sites) and np.array_equal(grid._coords, coords)
    assert grid.stats["updates"] == 0


@pytest.mark.parametrize("cell, pbc", [
    ([10.0, 12.0, 9.0], True),
    ([[10, 0, 0], [6, 9, 0], [3, -4, 8]], True),
    ([[10, 0, 0], [9.5, 2, 0], [0, 0, 7]], (True, False, True)),
    ([[10, 0, 0], [4, 8, 0], [0, 0, 0]], (True, True, False)),
])
def test_box_stretch_bounds_grid_displacements(cell, pbc):
    """The scan's per-atom sphere in grid space (query, Box.stretch): grid
    coordinates are g = N x with N the unit face normals, so |dg| <=
    stretch |dx| for every displacement, the bound is tight, and an
    orthorhombic cell has stretch 1."""
    from ase_mlg.geometry import Box
    box = Box(np.array(cell, dtype=float), pbc)
    N = box.inverse.T * box.heights[:, None]
    dx = np.random.default_rng(3).normal(size=(5000, 3))
    ratio = np.linalg.norm(dx @ N.T, axis=1) / np.linalg.norm(dx, axis=1)
    assert ratio.max() <= box.stretch * (1 + 1e-12)
    worst = np.linalg.eigh(N.T @ N)[1][:, -1]  # the direction that stretches most
    assert np.linalg.norm(N @ worst) == pytest.approx(box.stretch, rel=1e-12)
    if np.ndim(cell) == 1:
        assert box.stretch == pytest.approx(1.0, abs=1e-15)
    else:
        assert box.stretch > 1.0


@pytest.mark.parametrize("pbc", [(True, True, True), (True, False, True), (False, True, True)])
def test_block_query_on_a_strongly_sheared_cell_is_ase(pbc):
    """The scan's sphere test stretched to grid space (Box.stretch well
    above 1 here) loses no pair: the block query against ASE."""
    rng = np.random.default_rng(11)
    cell = 1.5 * np.array([[10.0, 0, 0], [9.0, 4.0, 0], [-7.0, 5.0, 6.0]])
    x = rng.random((150, 3)) @ cell
    grid = MLG(x, cell, pbc)
    assert grid.box.stretch > 1.5
    for rc in (3.0, 6.0):  # 6 Å is beyond the cell's smallest height
        assert exact_pairs(grid, rc) == ase_pairs(x, cell, pbc, rc)
