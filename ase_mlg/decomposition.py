"""Domain decompositions of an MLG for P ranks, and the regular spatial grid
they are measured against (issue 23, item 5; no MPI here).

Boris 1985 §IV.A: the MLG's arrays "can be partitioned for multi-tasking
across a number of independent processors".  A rank owns a block of the
grid's *logical* index space, so its share is set by counting sites and
their work, not by where atoms happen to be in space: a droplet in vacuum or
a liquid-vapour slab splits as evenly as a liquid.

Partition (:func:`mlg_decomposition`)
    ``P = Px * Py * Pz`` (:func:`factor_mlg`: the factorisation whose rank
    block has the smallest volume within ``reach`` of it, Steiner's formula
    on the block's logical extents times the measured site spacings; slabs
    win for small P because slabs have no edges).  Then recursive prefix
    sums of a per-site weight (holes weigh 0): the sites in C order
    (axis 0 major) are cut into ``Px`` runs of equal weight, each run in
    (axis 1, axis 0, axis 2) order into ``Py``, each of those in (axis 2,
    axis 0, axis 1) order into ``Pz``.  A cut falls at any site, also
    inside a plane, at the site boundary nearest the target, so each cut
    misses by at most half the heaviest site's weight ``w_max`` and a rank's
    owned weight is within ``w_max (1 + 1/Pz + 1/(Py Pz)) <= 3 w_max`` of
    the mean.  Every site is owned once and each region is a run of its
    parent's sweep order (nested intervals of the logical index space).
Spatial grid (:func:`spatial_decomposition`)
    Equal boxes of the cell, ``owner = floor(f_a P_a)`` on fractional
    coordinates (wrapped on periodic axes), ``P_a`` by LAMMPS's
    ``processors * * *`` rule (:func:`factor_lammps`).

What is counted (:class:`Decomposition`), exactly, from one half list at
``reach = cutoff + skin`` (Å; :class:`Pairs`: every pair and periodic image
with ``d < reach`` once, its row atom the one of lower grid rank):

* owned atoms of rank a: atoms with ``owner == a``;
* pairs of rank a: the pairs with both atoms owned by a plus half of
  those with one (``sum of deg(i) / 2`` over its atoms i, ``deg`` the
  atom's pairs): the work of a half list whose pairs across ranks are split
  evenly between the two (as LAMMPS's ``newton on`` does on average).  Both
  decompositions count the same pairs by the same rule.  ``row_pairs``:
  the half-list pairs whose row atom (the lower grid rank) rank a owns, a
  rule that charges every pair across a boundary to one side (the side
  that comes first in the grid's block order);
* halo of rank a: atoms other ranks own within ``reach`` of an atom rank a
  owns, through periodic images, each atom counted once.  A pair (i, j)
  with owners a != b puts j in a's halo and i in b's halo.
"""

import time

import numpy as np
from .jit import njit

from .blocks import BlockIndex, block_for_radius
from .query import half_list

__all__ = ["Pairs", "Decomposition", "factor_mlg", "factor_lammps",
           "mlg_decomposition", "balanced_decomposition", "least_volume_factorisations",
           "first_balanced", "spatial_decomposition", "ALPHAS"]


@njit(cache=True)
def _transpose(rowptr, nbr, n):
    """Columns of a half list as rows: for each rank, the ranks whose rows
    hold it (counting sort, stable)."""
    colptr = np.zeros(n + 1, np.int64)
    for q in range(nbr.shape[0]):
        colptr[nbr[q] + 1] += 1
    for t in range(n):
        colptr[t + 1] += colptr[t]
    cur = colptr[:-1].copy()
    tr = np.empty(nbr.shape[0], np.int32)
    for t in range(n):
        for q in range(rowptr[t], rowptr[t + 1]):
            u = nbr[q]
            tr[cur[u]] = t
            cur[u] += 1
    return colptr, tr


@njit(cache=True)
def _halo(own, rowptr, nbr, colptr, tr, nranks):
    """Halo atoms per rank: atom t is in the halo of every rank b != own[t]
    that owns one of t's neighbours (row and column), counted once per b
    (``stamp[b] == t`` marks b as seen for t)."""
    halo = np.zeros(nranks, np.int64)
    stamp = np.full(nranks, -1, np.int64)
    for t in range(own.shape[0]):
        o = own[t]
        for q in range(rowptr[t], rowptr[t + 1]):
            b = own[nbr[q]]
            if b != o and stamp[b] != t:
                stamp[b] = t
                halo[b] += 1
        for q in range(colptr[t], colptr[t + 1]):
            b = own[tr[q]]
            if b != o and stamp[b] != t:
                stamp[b] = t
                halo[b] += 1
    return halo


class Pairs:
    """The half list at ``reach`` (Å) on ``grid`` and its transpose: what
    every decomposition of that grid is measured on (built once, shared).

    Attributes
    ----------
    reach : float
        Pair distance, Å (``d < reach``).
    order : int64 (N,)
        Atom of each grid rank; ``rank`` its inverse.
    rowptr, nbr : the half list's rows (pairs of rank t: ``nbr[rowptr[t]:
        rowptr[t+1]]``, ranks of the second atoms; periodic images each once).
    colptr, tr : the same pairs by second atom.
    row_pairs, degree : int64 (N,)
        Pairs in the atom's row, and all its pairs (row and column), in
        atom order.
    seconds : float
        Time to build the list and its transpose, s.
    """

    def __init__(self, grid, reach):
        t0 = time.perf_counter()
        self.reach = float(reach)
        index = BlockIndex(grid, block_for_radius(grid, self.reach))
        pl = half_list(index, np.full(grid.natoms, self.reach), cut=self.reach)
        del index
        self.order = np.asarray(pl.order, np.int64)
        self.rank = np.empty_like(self.order)
        self.rank[self.order] = np.arange(len(self.order))
        self.rowptr, self.nbr = pl.rowptr, pl.nbr
        del pl  # its image codes are not needed: free them
        self.colptr, self.tr = _transpose(self.rowptr, self.nbr, len(self.order))
        self.row_pairs = np.diff(self.rowptr)[self.rank]
        self.degree = self.row_pairs + np.diff(self.colptr)[self.rank]
        self.seconds = time.perf_counter() - t0

    def __len__(self):
        return int(self.rowptr[-1])


class Decomposition:
    """Owners of P ranks and what each rank holds (definitions: module doc).

    Attributes
    ----------
    dims : tuple (Px, Py, Pz)
    owner : int32 (N,)
        Rank of each atom.
    site_owner : int32 (nsites,) or None
        Rank of each site of the grid (flat C order); None for the spatial grid.
    natoms, halo, row_pairs : int64 (P,)
        Owned atoms, halo atoms and pairs whose row atom is owned, per rank.
    pairs : float64 (P,)
        Pairs per rank, those across ranks counted half (module doc).
    work : float64 (P,) or None
        Owned weight per rank (MLG partitions).
    alpha : float or None
        The weight ``1 + alpha pairs / mean`` :func:`balanced_decomposition`
        chose (None otherwise).
    seconds : float
        Time to compute the owners (not the list, not the counts), s.
    """

    def __init__(self, dims, owner, pairs, site_owner=None, work=None, seconds=0.0):
        nranks = int(np.prod(dims))
        self.dims = tuple(int(d) for d in dims)
        self.owner = owner
        self.site_owner = site_owner
        self.work = work
        self.alpha = None  # the weight balanced_decomposition chose
        self.seconds = seconds
        self.natoms = np.bincount(owner, minlength=nranks).astype(np.int64)
        self.pairs = 0.5 * np.bincount(owner, weights=pairs.degree, minlength=nranks)
        self.row_pairs = np.bincount(owner, weights=pairs.row_pairs,
                                     minlength=nranks).astype(np.int64)
        own = np.ascontiguousarray(owner[pairs.order])
        self.halo = _halo(own, pairs.rowptr, pairs.nbr, pairs.colptr, pairs.tr, nranks)

    @property
    def nranks(self):
        return len(self.natoms)

    def imbalance(self):
        """max/mean of owned atoms, halo atoms, pairs and row pairs per
        rank, and the number of ranks owning no atom."""
        def ratio(x):
            m = x.mean()
            return float(x.max() / m) if m > 0 else 1.0
        return {"atoms": ratio(self.natoms), "halo": ratio(self.halo),
                "pairs": ratio(self.pairs), "row_pairs": ratio(self.row_pairs),
                "empty": int((self.natoms == 0).sum())}


def _check_ranks(nranks, nsites, natoms):
    if isinstance(nranks, bool) or not isinstance(nranks, (int, np.integer)):
        raise TypeError(f"P: expected an int, got {nranks!r}")
    nranks = int(nranks)
    if nranks < 1:
        raise ValueError(f"P: must be >= 1, got {nranks}")
    if nranks > nsites:
        raise ValueError(f"P={nranks} ranks on too few sites: the grid has "
                         f"{nsites} sites")
    if nranks > natoms:
        raise ValueError(f"P={nranks} ranks on too few atoms: the grid holds "
                         f"{natoms} atoms")
    return nranks


def _factorisations(nranks):
    """All (Px, Py, Pz) with product P, Px descending (ties keep the first:
    the most slab-like)."""
    out = []
    for px in range(nranks, 0, -1):
        if nranks % px == 0:
            rest = nranks // px
            for py in range(rest, 0, -1):
                if rest % py == 0:
                    out.append((px, py, rest // py))
    return out


def _spacings(grid):
    """Median distance between neighbouring sites along each logical axis
    (stored grid coordinates, Å; 1 on an axis of one site): what one
    logical layer is worth in space, also where the grid is anisotropic (a
    liquid-vapour slab packs its liquid into many z planes)."""
    view = grid.view()
    shape = view.shape
    d = np.ones(3)
    for a in range(3):
        if shape[a] > 1:
            c = view.coordinates[:, a].reshape(shape)
            step = np.diff(c, axis=a).ravel()
            if step.size > 10 ** 6:  # a subsample gives the median to 0.1 %
                step = step[:: step.size // 10 ** 6]
            d[a] = max(float(np.median(step)), 1e-12)
    return d


def factor_mlg(shape, spacing, nranks, reach):
    """``(Px, Py, Pz)`` for P ranks on a grid of ``shape`` with site
    ``spacing`` (Å per axis): the smallest volume within ``reach`` (Å) of a
    rank's block (Steiner's formula for a box of extents ``N_a d_a / P_a``
    on the cut axes; uncut axes span the grid and only scale it), among the
    factorisations with ``P_a <= N_a`` if any."""
    shape = np.asarray(shape, np.int64)
    ext = shape * np.asarray(spacing, float)
    best, dims = np.inf, None
    fits = [f for f in _factorisations(nranks) if (np.asarray(f) <= shape).all()]
    for f in fits or _factorisations(nranks):
        vol = _reach_volume(ext, f, reach)
        if vol < best * (1 - 1e-12):
            best, dims = vol, f
    return dims


def _reach_volume(ext, dims, reach):
    """Volume within ``reach`` (Å) of a rank's block outside it: Steiner's
    formula for a box of extents ``ext / dims`` on the cut axes (uncut
    axes span the grid and only scale it)."""
    r = float(reach)
    p = np.asarray(dims)
    cut = p > 1
    e = ext[cut] / p[cut]
    k = int(cut.sum())
    if k == 0:
        vol = 0.0
    elif k == 1:
        vol = 2 * r
    elif k == 2:
        vol = 2 * r * e.sum() + np.pi * r * r
    else:
        vol = (2 * r * (e[0] * e[1] + e[0] * e[2] + e[1] * e[2])
               + np.pi * r * r * e.sum() + 4 / 3 * np.pi * r ** 3)
    return vol * float(np.prod(ext[~cut]))


def factor_lammps(lengths, nranks):
    """``(Px, Py, Pz)`` as LAMMPS's ``processors * * *`` picks it
    (``ProcMap::factor`` / ``best_factors``): the smallest surface of one
    sub-box, ``xy/(px py) + xz/(px pz) + yz/(py pz)`` with ``lengths`` the
    box's lengths (cell heights here, Å); the first found in LAMMPS's
    order (px, then py ascending) wins ties."""
    x, y, z = (float(v) for v in lengths)
    best, dims = np.inf, None
    for px in range(1, nranks + 1):
        if nranks % px:
            continue
        for py in range(1, nranks // px + 1):
            if (nranks // px) % py:
                continue
            pz = nranks // px // py
            surf = x * y / px / py + x * z / px / pz + y * z / py / pz
            if surf < best:
                best, dims = surf, (px, py, pz)
    return dims


def _cut_points(cum, m):
    """Boundaries of m runs of equal weight along a sequence whose running
    weight is ``cum``: for each target k W/m the site boundary nearest it
    (within half a site's weight).  Returns m + 1 indices, 0 ... len."""
    n = len(cum)
    total = cum[-1] if n else 0.0
    targets = total * np.arange(1, m) / m
    b = np.searchsorted(cum, targets, side="left")  # cum[b] >= target
    above = cum[np.minimum(b, n - 1)]
    below = np.where(b > 0, cum[np.maximum(b - 1, 0)], 0.0)
    b = np.where(above - targets <= targets - below, b + 1, b)
    return np.concatenate([[0], np.minimum(b, n), [n]]).astype(np.int64)


def _split(seq, wsite, m):
    """Cut the site sequence ``seq`` into m runs of equal weight."""
    if m == 1:
        return [seq]
    cuts = _cut_points(np.cumsum(wsite[seq]), m)
    return [seq[cuts[t]:cuts[t + 1]] for t in range(m)]


def _sweep(seq, shape, major):
    """``seq`` (flat C-order sites) reordered with axis ``major`` first,
    then the other two axes in their order."""
    i, j, k = np.unravel_index(seq, shape)
    nx, ny, nz = shape
    key = ((j * nx + i) * nz + k) if major == 1 else ((k * nx + i) * ny + j)
    return seq[np.argsort(key, kind="stable")]


def _site_weights(grid, pairs, weight):
    """Per-site weight (holes 0) from ``weight``: "pairs" (half the
    atom's pairs: exactly what its owner is charged), "atoms" (1 an atom),
    "work" (both, scaled so atoms and pairs count alike: the atom's pairs
    over the mean, plus one), or an array of one weight per atom."""
    n = grid.natoms
    rows = 0.5 * pairs.degree.astype(np.float64)
    if isinstance(weight, str):
        mean = rows.mean() if n else 0.0
        if weight == "pairs" and mean > 0:
            w = rows
        elif weight == "atoms" or (weight == "pairs" and not mean > 0):
            w = np.ones(n)
        elif weight == "work":
            w = rows / mean + 1.0 if mean > 0 else np.ones(n)
        else:
            raise ValueError(f"weight: expected 'pairs', 'atoms', 'work' or an "
                             f"array, got {weight!r}")
    else:
        w = np.asarray(weight, np.float64)
        if w.shape != (n,) or not (w >= 0).all() or not np.isfinite(w).all():
            raise ValueError(f"weight: expected {n} finite weights >= 0")
    sites = grid.view().sites
    wsite = np.zeros(len(sites))
    filled = sites >= 0
    wsite[filled] = w[sites[filled]]
    return wsite


def mlg_decomposition(grid, nranks, pairs=None, reach=None, weight="work", dims=None):
    """The MLG partition of ``grid`` for ``nranks`` ranks (module doc).

    Parameters
    ----------
    grid : MLG
    nranks : int
        P, 1 <= P <= min(sites, atoms).
    pairs : Pairs, optional
        The half list to weigh and count with (built at ``reach`` if None).
    reach : float, optional
        cutoff + skin, Å (needed without ``pairs``).
    weight : "work" | "pairs" | "atoms" | array (N,)
        Work per atom the boundaries balance (holes weigh 0).
    dims : 3 ints, optional
        Force (Px, Py, Pz); default :func:`factor_mlg`.

    Returns
    -------
    Decomposition
    """
    nsites = int(np.prod(grid.shape))
    nranks = _check_ranks(nranks, nsites, grid.natoms)
    if pairs is None:
        pairs = Pairs(grid, reach)
    t0 = time.perf_counter()
    shape = tuple(grid.shape)
    if dims is None:
        dims = factor_mlg(shape, _spacings(grid), nranks, pairs.reach)
    if int(np.prod(dims)) != nranks:
        raise ValueError(f"dims: {tuple(dims)} is not a factorisation of P={nranks}")
    px, py, pz = (int(d) for d in dims)
    wsite = _site_weights(grid, pairs, weight)
    site_owner = np.empty(nsites, np.int32)
    for p, slab in enumerate(_split(np.arange(nsites), wsite, px)):
        for q, row in enumerate(_split(_sweep(slab, shape, 1), wsite, py)):
            for t, run in enumerate(_split(_sweep(row, shape, 2), wsite, pz)):
                site_owner[run] = (p * py + q) * pz + t
    sites = grid.view().sites
    owner = np.empty(grid.natoms, np.int32)
    filled = sites >= 0
    owner[sites[filled]] = site_owner[filled]
    work = np.bincount(site_owner, weights=wsite, minlength=nranks)
    seconds = time.perf_counter() - t0
    return Decomposition((px, py, pz), owner, pairs, site_owner, work, seconds)


#: The work weights ``1 + alpha * pairs / mean pairs`` a balanced
#: partition tries, in order of preference (1: the "work" weight; 0: atoms
#: alone).
ALPHAS = (1.0, 0.5, 2.0, 0.25, 0.0)


def least_volume_factorisations(shape, spacing, nranks, reach, count=6):
    """The ``count`` factorisations ``(Px, Py, Pz)`` of P with ``P_a <=
    N_a`` of least volume within ``reach`` of a rank's block
    (:func:`factor_mlg`'s measure; its choice first)."""
    shape = np.asarray(shape, np.int64)
    ext = shape * np.asarray(spacing, float)
    fits = [f for f in _factorisations(nranks) if (np.asarray(f) <= shape).all()]
    vols = [_reach_volume(ext, f, reach) for f in fits]
    # stable: ties keep factor_mlg's order (the most slab-like first)
    return [fits[k] for k in np.argsort(vols, kind="stable")[:count]]


def first_balanced(attempt, candidates, tol, best=None):
    """The balanced partitions' rule: try ``candidates`` (``(dims, alpha)``
    pairs, in order of preference) with ``attempt(dims, alpha) -> (worst,
    partition)`` (``worst``: max/mean of owned atoms or pairs, the larger)
    and return the first partition with ``worst <= tol``, else the one of
    least ``worst`` (``best``: a ``(worst, partition)`` tried before)."""
    for dims, alpha in candidates:
        worst, part = attempt(dims, alpha)
        if best is None or worst < best[0]:
            best = (worst, part)
        if worst <= tol:
            return part
    return best[1]


def balanced_decomposition(grid, nranks, pairs=None, reach=None, tol=1.05, candidates=6):
    """The MLG partition that balances owned atoms and pairs together.

    One run of sites cannot balance both where pairs per atom vary
    (surfaces, vapour): each weight trades one against the other, and so
    does the choice of the cut axes (a slab cut only across its surface
    gives every rank the same mix).  So this tries the ``candidates``
    factorisations of least volume within reach
    (:func:`least_volume_factorisations`, the least halo first), each with
    the weights of :data:`ALPHAS` in turn, and keeps the first whose owned
    atoms and pairs are both within ``tol`` of the mean (max/mean); where
    none is, the one of least ``max(atoms, pairs)``.  The live MPI
    partition chooses by the same rule
    (:func:`ase_mlg.ranks.partition.balanced_partition`).

    Returns
    -------
    Decomposition
        With ``alpha`` (the weight chosen) and ``seconds`` the whole search.
    """
    nranks = _check_ranks(nranks, int(np.prod(grid.shape)), grid.natoms)
    if pairs is None:
        pairs = Pairs(grid, reach)
    t0 = time.perf_counter()
    rows = 0.5 * pairs.degree.astype(np.float64)
    mean = rows.mean() if len(rows) else 0.0

    def attempt(dims, alpha):
        w = 1.0 + alpha * rows / mean if mean > 0 else np.ones(len(rows))
        dec = mlg_decomposition(grid, nranks, pairs, weight=w, dims=dims)
        dec.alpha = alpha
        s = dec.imbalance()
        return max(s["atoms"], s["pairs"]), dec

    order = [(d, a) for d in least_volume_factorisations(grid.shape, _spacings(grid), nranks,
                                                         pairs.reach, candidates)
             for a in ALPHAS]
    dec = first_balanced(attempt, order, tol)
    dec.seconds = time.perf_counter() - t0
    return dec


def spatial_decomposition(grid, nranks, pairs=None, reach=None, dims=None):
    """The regular spatial grid of the same P: equal boxes of the cell,
    ``owner = floor(f_a P_a)`` per axis (``f`` fractional coordinates,
    wrapped into [0, 1) on periodic axes, clipped on open ones), rank
    ``(ix Py + iy) Pz + iz``, ``P_a`` by :func:`factor_lammps` on the cell
    heights.  Counted on the same pairs as :func:`mlg_decomposition`."""
    nranks = _check_ranks(nranks, int(np.prod(grid.shape)), grid.natoms)
    if pairs is None:
        pairs = Pairs(grid, reach)
    t0 = time.perf_counter()
    box = grid.view().box
    if dims is None:
        dims = factor_lammps(box.heights, nranks)
    if int(np.prod(dims)) != nranks:
        raise ValueError(f"dims: {tuple(dims)} is not a factorisation of P={nranks}")
    f = box.fractional(grid.positions)
    idx = np.empty(f.shape, np.int64)
    for a in range(3):
        fa = f[:, a] - np.floor(f[:, a]) if box.pbc[a] else np.clip(f[:, a], 0.0, 1.0)
        idx[:, a] = np.minimum(np.floor(fa * dims[a]).astype(np.int64), dims[a] - 1)
    owner = ((idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]).astype(np.int32)
    seconds = time.perf_counter() - t0
    return Decomposition(dims, owner, pairs, seconds=seconds)
