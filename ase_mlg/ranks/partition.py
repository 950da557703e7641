"""The MLG partition of a system over P MPI ranks (Boris 1985 §IV.A).

A rank owns a block of the MLG's logical index space.  The sort
construction of the MLG (docs/design.md §3) puts an atom on logical plane
``i`` by the rank of its first grid coordinate, then on line ``j`` of that
plane by its second, then on site ``k`` by its third; so a block of planes
``[i0, i1)`` is the atoms between two values of the first coordinate, a
block of lines inside it the atoms between two values of the second, and so
on.  The partition is those cut values: ``Px`` runs along axis 0, each cut
into ``Py`` along axis 1, each into ``Pz`` along axis 2 (``P = Px Py Pz``
by :func:`ase_mlg.decomposition.factor_mlg`, the least volume within reach
of a rank's block; slabs for few ranks), exactly the nested intervals of
:func:`ase_mlg.decomposition.mlg_decomposition`, placed by weight and not
by whole planes, so the cuts fall inside planes.

The cuts come from the atoms where they are, spread over the ranks, by
bisection on the cut values with one small all-gather of weights a round
(:func:`_weighted_cuts`): no rank ever holds the whole system.  The weight
of an atom is ``1 + alpha pairs / mean pairs`` from the last list (1
before there is one), and the cut axes and ``alpha`` are chosen so that
owned atoms and pairs are balanced together (:func:`balanced_partition`,
the rule of :func:`ase_mlg.decomposition.balanced_decomposition`).  Coordinates are fractional (wrapped
on periodic axes); the periodic seam at 0 is one of the cuts of a periodic
axis that is cut.

A rank's region is then a box in fractional coordinates
(:meth:`Partition.box`), what its halo is computed from
(:mod:`ase_mlg.ranks.halo`).
"""

import numpy as np

from ..decomposition import ALPHAS, factor_mlg, first_balanced, least_volume_factorisations
from ..geometry import Box, grid_shape
from ..jit import njit

__all__ = ["Partition", "balanced_partition", "imbalance", "BISECTIONS"]

#: Rounds of bisection for each cut: 2^-60 of the coordinate range, far
#: below the spacing of any two atoms' coordinates.
BISECTIONS = 60


@njit(cache=True)
def _fractional(positions, inverse, out):
    # a loop, not numpy's product ``positions @ inverse``: numpy hands that
    # to its BLAS, which under mpiexec starts threads of its own in every
    # rank; on cores the ranks share, one such product took 136 ms instead
    # of 3 (2 ranks of 10^6 argon atoms on 2 cores, six a rebuild: a tenth
    # of every MD step), unless the user had set OPENBLAS_NUM_THREADS=1
    for i in range(positions.shape[0]):
        p0, p1, p2 = positions[i, 0], positions[i, 1], positions[i, 2]
        for c in range(3):
            out[i, c] = p0 * inverse[0, c] + p1 * inverse[1, c] + p2 * inverse[2, c]
    return out


def _weighted_cuts(comm, coord, group, ngroups, pieces, weight, lo, hi):
    """``(ngroups, pieces - 1)`` cut values: for each group g, the values
    splitting the atoms of that group (on every rank) into ``pieces`` runs
    of equal weight along ``coord``.  Each cut is placed at the atom
    boundary nearest its target weight, as ``decomposition._cut_points``
    does (ties go to the lower piece)."""
    m = pieces - 1
    if m == 0:
        return np.zeros((ngroups, 0))
    order = np.lexsort((coord, group))
    g_sorted, c_sorted, w_cum = group[order], coord[order], np.cumsum(weight[order])
    start = np.searchsorted(g_sorted, np.arange(ngroups), side="left")
    stop = np.searchsorted(g_sorted, np.arange(ngroups), side="right")
    base = np.where(start > 0, w_cum[np.maximum(start - 1, 0)], 0.0)
    local_total = np.where(stop > start, w_cum[np.maximum(stop - 1, 0)], 0.0) - np.where(
        stop > start, base, 0.0)

    def below(values):  # (ngroups, m): weight of each group's atoms with coord < value
        out = np.empty_like(values)
        for g in range(ngroups):
            seg = c_sorted[start[g]:stop[g]]
            k = np.searchsorted(seg, values[g], side="left")
            cum = w_cum[start[g]:stop[g]]
            out[g] = np.where(k > 0, cum[np.maximum(k - 1, 0)] - base[g], 0.0) if len(seg) else 0.0
        return out

    total = sum(comm.allgather(local_total))
    targets = total[:, None] * (np.arange(1, pieces) / pieces)[None, :]
    lo = np.broadcast_to(np.asarray(lo, float)[:, None], (ngroups, m)).copy()
    hi = np.broadcast_to(np.asarray(hi, float)[:, None], (ngroups, m)).copy()
    w_lo = np.zeros((ngroups, m))
    w_hi = total[:, None] + np.zeros(m)
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        w_mid = sum(comm.allgather(below(mid)))
        up = w_mid >= targets  # the crossing lies below mid
        hi = np.where(up, mid, hi)
        w_hi = np.where(up, w_mid, w_hi)
        lo = np.where(up, lo, mid)
        w_lo = np.where(up, w_lo, w_mid)
    return np.where(w_hi - targets <= targets - w_lo, hi, lo)


class Partition:
    """Cut values of the MLG partition of one configuration.

    Parameters
    ----------
    comm : mpi4py communicator or SerialComm
    positions : (n, 3) float64
        This rank's atoms (Å).
    cell, pbc
        The system's cell (Å) and periodic axes.
    natoms : int
        The system's atom count (all ranks).
    reach : float
        ``cutoff + skin`` (Å): what a rank's halo covers.
    weight : (n,) float64, optional
        Work per atom (default 1).
    dims : (Px, Py, Pz), optional
        Ranks along each cell axis (default :func:`factor_mlg`'s).

    Attributes
    ----------
    dims : (Px, Py, Pz)
        Ranks along each cell axis.
    shape, spacing : (3,) arrays
        The MLG's shape and site spacing (Å) the dims are chosen on.
    box : Box
        The cell; fractional coordinates and heights.
    alpha : float or None
        The weight :func:`balanced_partition` chose.
    """

    def __init__(self, comm, positions, cell, pbc, natoms, reach, weight=None, dims=None):
        self.box = box = Box(cell, pbc)
        nranks = comm.size
        frac = self.fractional(positions)
        lo = np.min(frac, axis=0, initial=np.inf)
        hi = np.max(frac, axis=0, initial=-np.inf)
        lows, highs = comm.allgather(lo), comm.allgather(hi)
        lo, hi = np.min(lows, axis=0), np.max(highs, axis=0)
        lo = np.where(box.pbc, 0.0, lo)
        hi = np.where(box.pbc, 1.0, hi)
        extent = np.where(box.pbc, box.heights, (hi - lo) * box.heights)
        shape = grid_shape(extent, box.pbc, natoms)
        spacing = np.maximum(extent, 1e-12) / np.maximum(shape, 1)
        if dims is None:
            dims = factor_mlg(shape, spacing, nranks, reach)
        self.dims = dims = tuple(int(d) for d in dims)
        self.shape, self.spacing, self.alpha = shape, spacing, None
        if any(d > s for d, s in zip(dims, shape)):
            raise ValueError(
                f"{nranks} ranks on too few sites: the MLG of {natoms} atoms is "
                f"{tuple(int(s) for s in shape)} sites, and {dims} ranks along its axes "
                f"need as many planes; run on fewer ranks")
        self.reach = float(reach)
        w = np.ones(len(frac)) if weight is None else np.asarray(weight, float)
        px, py, pz = dims
        # nested cuts: axis 0 over all, axis 1 inside each x run, axis 2 inside each (x, y)
        self.cuts0 = _weighted_cuts(comm, frac[:, 0], np.zeros(len(frac), np.int64), 1, px,
                                    w, [lo[0]], [hi[0]])[0]
        i = np.searchsorted(self.cuts0, frac[:, 0], side="right")
        self.cuts1 = _weighted_cuts(comm, frac[:, 1], i, px, py, w,
                                    np.full(px, lo[1]), np.full(px, hi[1]))
        j = self._index(self.cuts1, i, frac[:, 1])
        self.cuts2 = _weighted_cuts(comm, frac[:, 2], i * py + j, px * py, pz, w,
                                    np.full(px * py, lo[2]), np.full(px * py, hi[2]))

    @staticmethod
    def _index(cuts, group, values):
        """Each value's slot among its group's cuts.  The groups present by
        a bincount, not np.unique's sort (two of them were 60 ms of a
        rebuild at 2 ranks of 10^6 atoms), and no mask where one group
        holds every value (a rank's own atoms, mostly), none on an axis
        not cut."""
        if not any(len(c) for c in cuts):  # an axis not cut: every value in slot 0
            return np.zeros(len(values), np.int64)
        present = np.flatnonzero(np.bincount(group, minlength=len(cuts)))
        if len(present) == 1:
            return np.searchsorted(cuts[present[0]], values, side="right")
        out = np.empty(len(values), np.int64)
        for g in present:
            sel = group == g
            out[sel] = np.searchsorted(cuts[g], values[sel], side="right")
        return out

    def fractional(self, positions, wrap=True):
        """Fractional coordinates, wrapped into [0, 1) on periodic axes
        (``wrap``)."""
        positions = np.ascontiguousarray(positions, dtype=np.float64)
        f = _fractional(positions, self.box.inverse, np.empty((len(positions), 3)))
        if not wrap:
            return f
        for a in np.flatnonzero(self.box.pbc):  # columns in place, no fancy-index copies
            col = f[:, a]
            col -= np.floor(col)
            col[col >= 1.0] = 0.0  # -1e-17 wraps to 1.0
        return f

    def owner(self, positions):
        """The rank that owns each position (rank = (i Py + j) Pz + k)."""
        frac = self.fractional(positions)
        px, py, pz = self.dims
        i = np.searchsorted(self.cuts0, frac[:, 0], side="right")
        j = self._index(self.cuts1, i, frac[:, 1])
        k = self._index(self.cuts2, i * py + j, frac[:, 2])
        return (i * py + j) * pz + k

    def box_of(self, rank):
        """``(low, high)``: the fractional box of ``rank``'s region, and
        which axes are cut (the others span the system)."""
        px, py, pz = self.dims
        i, rest = divmod(rank, py * pz)
        j, k = divmod(rest, pz)
        edges = []
        for cuts, n, a in ((self.cuts0, i, 0), (self.cuts1[i], j, 1),
                           (self.cuts2[i * py + j], k, 2)):
            pbc = self.box.pbc[a]
            low = cuts[n - 1] if n > 0 else (0.0 if pbc else -np.inf)
            high = cuts[n] if n < len(cuts) else (1.0 if pbc else np.inf)
            edges.append((low, high))
        low, high = np.array(edges).T
        return low, high, np.array(self.dims) > 1


def balanced_partition(comm, positions, cell, pbc, natoms, reach, pairs=None, tol=1.05,
                       first=None, candidates=6, current=None):
    """The partition that balances owned atoms and pairs together, by the
    rule of :func:`ase_mlg.decomposition.balanced_decomposition`: the
    least-volume factorisations in turn, each with the weights ``1 + alpha
    pairs / mean`` of :data:`~ase_mlg.decomposition.ALPHAS`, the first
    whose owned atoms and pairs (max/mean over ranks; half of each of an
    atom's ``pairs``) are both within ``tol``; where none is, the most
    balanced.  ``first``, a ``(dims, alpha)`` (the last choice), is tried
    before the others: a scene that stays balanced costs one partition a
    rebuild.  ``current``, the partition in use, is kept while it is still
    within ``tol`` on both counts at ``positions`` (LAMMPS's ``fix
    balance`` threshold): the cuts' 60 rounds of bisection cost 20-30 ms a
    rebuild at 2 ranks of 108,000 atoms, the test 1-2 ms.  Without
    ``pairs`` (before the first list) the atoms weigh alike, on
    :func:`factor_mlg`'s dims.  Every rank makes the same choice: each test
    is reduced over all ranks."""
    if pairs is None:
        return Partition(comm, positions, cell, pbc, natoms, reach)
    rows = np.asarray(pairs, float)
    total = sum(comm.allgather(np.array([rows.sum(), len(rows)])))
    mean = total[0] / max(total[1], 1.0)
    if not mean > 0:
        return Partition(comm, positions, cell, pbc, natoms, reach)
    nranks = comm.size
    if (current is not None and current.box.same_as(Box(cell, pbc))
            and current.reach == float(reach)
            and max(imbalance(comm, current, positions, rows)) <= tol):
        return current

    def attempt(dims, alpha):
        part = Partition(comm, positions, cell, pbc, natoms, reach,
                         1.0 + alpha * rows / mean, dims)
        part.alpha = alpha
        return max(imbalance(comm, part, positions, rows)), part

    tried, best = [], None
    if first is not None:
        try:  # the same on every rank: a grid too small for its dims now
            best = attempt(*first)
            tried.append(first)
        except ValueError:
            best = None
    if best is None:
        best = attempt(None, ALPHAS[0])
        tried.append((best[1].dims, ALPHAS[0]))
    if best[0] <= tol:
        return best[1]
    shape, spacing = best[1].shape, best[1].spacing
    order = [(tuple(d), a) for d in least_volume_factorisations(shape, spacing, nranks, reach,
                                                                candidates)
             for a in ALPHAS if (tuple(d), a) not in tried]
    return first_balanced(attempt, order, tol, best)


def imbalance(comm, part, positions, pairs):
    """``(atoms, pairs)``: max/mean over ranks of the atoms ``part`` gives
    each rank and of their pairs (half of each atom's ``pairs``), for the
    atoms at ``positions`` on every rank (collective)."""
    owner = part.owner(positions)
    n = comm.size
    counts = sum(comm.allgather(np.stack([
        np.bincount(owner, minlength=n).astype(float),
        np.bincount(owner, weights=0.5 * np.asarray(pairs, float), minlength=n)])))
    return tuple(float(c.max() / c.mean()) if c.mean() > 0 else 1.0 for c in counts)
