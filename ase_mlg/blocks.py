"""The blocked view of an MLG that the exact query scans.

The grid's sites are cut into aligned blocks of ``bx x by x bz`` sites;
every block, every row of blocks and every slab keeps the bounding box of
the stored grid coordinates of its sites.  Because the grid is monotone
these boxes are monotone along each axis, which is what lets the query
bisect them (the proof is in :mod:`ase_mlg.query` and docs/design.md §6).
"""

from collections import namedtuple

import numpy as np
from .jit import njit

from .parallel import run_chunks, threads_for

__all__ = ["BlockIndex", "Blocks", "block_for_radius", "FAR_RADII"]

#: The arrays of a :class:`BlockIndex` that the query kernels read, as one
#: argument (the attributes of the index of the same names): ``nb`` blocks
#: per axis, ``bsz`` slots per block; per slot (block-major order)
#: ``slot_atom`` (-1: hole or padding), ``slot_rank``, ``P`` (3, nslot),
#: ``G`` (3, nslot), ``MS`` (nslot, 3); the boxes ``BB``, ``R2``, ``S1`` of
#: blocks, rows and slabs and the global box ``glob``; ``natom_blk`` atoms per
#: block; the grid's ``positions``, ``cell`` and ``periods``.
Blocks = namedtuple("Blocks", "nb bsz slot_atom slot_rank P G MS BB R2 S1 glob "
                              "natom_blk positions cell periods")

# What the gather reads: the grid's sites and their stored coordinates
# (site order), every atom's grid coordinates (atom order), the positions,
# cell, periods and the grid shape.
_Sites = namedtuple("_Sites", "sites coordinates atom_coordinates positions cell "
                              "periods shape")

# What the gather fills, as :func:`_slots` allocates it.
_Slots = namedtuple("_Slots", "slot_atom P G MS BB natom_blk")


@njit(cache=True)
def _slots(nslot, nblk):
    """Empty slot arrays (-1: hole or padding; +inf positions) and block
    boxes (empty: +inf lows, -inf highs)."""
    slot_atom = np.full(nslot, -1, dtype=np.int64)
    P = np.full((3, nslot), np.inf)
    G = np.zeros((3, nslot))
    MS = np.zeros((nslot, 3), dtype=np.int64)  # 1e10 cells away: beyond int32
    BB = np.empty((nblk, 6))
    for b in range(nblk):
        for c in range(3):
            BB[b, c] = np.inf
            BB[b, 3 + c] = -np.inf
    natom_blk = np.zeros(nblk, dtype=np.int64)
    return slot_atom, P, G, MS, BB, natom_blk


@njit(cache=True, nogil=True)
def _gather(I0, I1, src, bs, nb, out):
    """Fill the slots and block boxes of slabs [I0, I1) (block-major order).

    Parameters
    ----------
    I0, I1 : int
        Slabs (blocks along axis 0) to fill.
    src : _Sites
        The grid's sites and coordinates.
    bs, nb : int64 arrays (3,)
        Sites per block and blocks per axis.
    out : _Slots
        ``slot_atom`` (-1: hole or padding), ``P`` (3, nslot): Cartesian
        position of the image that matches the stored coordinate (+inf for
        holes), ``G`` (3, nslot) stored grid coordinates, ``MS`` (nslot, 3)
        integer image of the stored coordinate, ``BB`` (nblk, 6) block
        boxes (lo0, lo1, lo2, hi0, hi1, hi2), ``natom_blk`` (nblk,).  A
        slab's sites fill only its own slots and blocks, so slabs run on
        threads.

    Returns
    -------
    float
        The largest deviation of a stored coordinate from an exact image.
    """
    sites, coords, g = src.sites, src.coordinates, src.atom_coordinates
    positions, cell, periods, shape = src.positions, src.cell, src.periods, src.shape
    slot_atom, P, G, MS = out.slot_atom, out.P, out.G, out.MS
    BB, natom_blk = out.BB, out.natom_blk
    nx, ny, nz = shape[0], shape[1], shape[2]
    bx, by, bz = bs[0], bs[1], bs[2]
    nby, nbz = nb[1], nb[2]
    bsz = bx * by * bz
    dev = 0.0
    for i in range(I0 * bx, min(I1 * bx, nx)):
        I = i // bx
        ii = i - I * bx
        for j in range(ny):
            J = j // by
            jj = j - J * by
            for k in range(nz):
                K = k // bz
                kk = k - K * bz
                s = (i * ny + j) * nz + k
                b = (I * nby + J) * nbz + K
                t = b * bsz + (ii * by + jj) * bz + kk
                for c in range(3):
                    x = coords[s, c]
                    G[c, t] = x
                    if x < BB[b, c]:
                        BB[b, c] = x
                    if x > BB[b, 3 + c]:
                        BB[b, 3 + c] = x
                a = sites[s]
                slot_atom[t] = a
                if a < 0:
                    continue
                natom_blk[b] += 1
                m0 = 0
                m1 = 0
                m2 = 0
                for c in range(3):
                    diff = coords[s, c] - g[a, c]
                    m = 0.0
                    if periods[c] > 0.0:
                        m = np.rint(diff / periods[c])
                        diff -= m * periods[c]
                    if abs(diff) > dev:
                        dev = abs(diff)
                    if c == 0:
                        m0 = int(m)
                    elif c == 1:
                        m1 = int(m)
                    else:
                        m2 = int(m)
                MS[t, 0] = m0
                MS[t, 1] = m1
                MS[t, 2] = m2
                for c in range(3):
                    P[c, t] = positions[a, c] + (m0 * cell[0, c] + m1 * cell[1, c]
                                                 + m2 * cell[2, c])
    return dev


@njit(cache=True)
def _boxes(BB, nb):
    """Row boxes ``R2`` (nbx*nby, 6), slab boxes ``S1`` (nbx, 6) and the
    global box (6,) from the block boxes."""
    nbx, nby, nbz = nb[0], nb[1], nb[2]
    R2 = np.empty((nbx * nby, 6))
    S1 = np.empty((nbx, 6))
    glob = np.empty(6)
    for c in range(3):
        glob[c] = np.inf
        glob[3 + c] = -np.inf
    for I in range(nbx):
        for c in range(3):
            S1[I, c] = np.inf
            S1[I, 3 + c] = -np.inf
        for J in range(nby):
            r = I * nby + J
            for c in range(3):
                R2[r, c] = np.inf
                R2[r, 3 + c] = -np.inf
            for K in range(nbz):
                b = r * nbz + K
                for c in range(3):
                    R2[r, c] = min(R2[r, c], BB[b, c])
                    R2[r, 3 + c] = max(R2[r, 3 + c], BB[b, 3 + c])
            for c in range(3):
                S1[I, c] = min(S1[I, c], R2[r, c])
                S1[I, 3 + c] = max(S1[I, 3 + c], R2[r, 3 + c])
        for c in range(3):
            glob[c] = min(glob[c], S1[I, c])
            glob[3 + c] = max(glob[3 + c], S1[I, 3 + c])
    return R2, S1, glob


#: Coordinates (Å) beyond this many list radii (at least 1 Å) from the
#: origin are refused: the query's round-off margin grows with them (1e-9
#: of the largest coordinate) and with it the images and candidates every
#: atom visits, so a list there would take minutes, and distances computed
#: as ASE computes them have lost 1e-7 of the cutoff.  Only an exploding
#: run or a unit mistake puts atoms there (1e9 Å is 10 cm).
FAR_RADII = 1e9


class BlockIndex:
    """Blocked view of an MLG for exact range queries (see module doc).

    Built in O(N) from the grid's current state; rebuild it (cheap) after
    every ``grid.update``.

    Attributes
    ----------
    blocks : Blocks or None
        The arrays the query kernels read, in one argument (None for an
        empty grid); each is also the attribute of the same name.
    order : int64 array (N,)
        The atom of every rank (atoms numbered along the blocks).
    dev : float
        Largest deviation of a stored coordinate from an exact image.
    scale : float
        Magnitude of the coordinates, for the query's relative padding.
    """

    def __init__(self, grid, block=2):
        bs = np.broadcast_to(np.asarray(block, dtype=np.int64), (3,)).copy()
        if (bs < 1).any():
            raise ValueError(f"block: sizes must be >= 1, got {bs.tolist()}")
        shape = np.array(grid.shape, dtype=np.int64)
        bs = np.minimum(bs, np.maximum(shape, 1))
        nb = (shape + bs - 1) // bs
        view = grid.view()
        self.grid = grid
        self.bs = bs
        self.nb = nb
        self.positions = grid.positions
        box = view.box
        self.cell = np.ascontiguousarray(box.full, dtype=np.float64)
        self.stretch = box.stretch  # the per-atom sphere of the scan, in grid space
        self.periods = np.array(view.periods, dtype=np.float64)
        n = grid.natoms
        if n:
            g = np.ascontiguousarray(box.fractional(view.positions))
            g *= box.heights  # in place: one N x 3 temporary, not two
            nslab = int(nb[0])
            bsz = int(np.prod(bs))
            slots = _Slots(*_slots(int(np.prod(nb)) * bsz, int(np.prod(nb))))
            src = _Sites(view.sites, view.coordinates, g, grid.positions, self.cell,
                         self.periods, shape)
            nth = threads_for("atoms", n)
            nchunk = min(nslab, 1 if nth == 1 else 4 * nth)
            cuts = np.linspace(0, nslab, nchunk + 1).astype(np.int64)
            devs = run_chunks(_gather, lambda ch: (cuts[ch], cuts[ch + 1], src, bs, nb, slots),
                              nchunk, nth)
            self.dev = max(devs)
            (self.slot_atom, self.P, self.G, self.MS, self.BB,
             self.natom_blk) = slots
            self.R2, self.S1, self.glob = _boxes(self.BB, nb)
            # ranks: atoms numbered along the blocks (holes skipped)
            filled = self.slot_atom >= 0
            self.order = self.slot_atom[filled]
            self.slot_rank = np.full(len(filled), -1, np.int32)
            self.slot_rank[filled] = np.arange(n, dtype=np.int32)
            scale = max(1.0, float(np.abs(self.glob).max()),
                        float(np.abs(grid.positions).max()),
                        float(np.abs(self.cell).sum()))
            self.blocks = Blocks(nb, bsz, self.slot_atom, self.slot_rank, self.P, self.G,
                                 self.MS, self.BB, self.R2, self.S1, self.glob,
                                 self.natom_blk, self.positions, self.cell, self.periods)
        else:
            scale = 1.0
            self.dev = 0.0
            self.order = np.zeros(0, np.int64)
            self.blocks = None
        self.scale = scale

    def refuse_far(self, rmax):
        """ValueError where a query radius ``rmax`` (Å) meets coordinates
        beyond :data:`FAR_RADII` radii from the origin."""
        limit = FAR_RADII * max(rmax, 1.0)
        if not self.scale > limit:
            return
        far = np.abs(self.positions).max(axis=1) > limit
        where = (f"atom(s) {np.flatnonzero(far)[:10].tolist()}{' ...' if far.sum() > 10 else ''}"
                 if far.any() else "the cell vectors")
        raise ValueError(f"positions: {where} reach {self.scale:.3g} Å from the origin, beyond "
                         f"{FAR_RADII:.0e} list radii ({limit:.3g} Å), where distances lose "
                         f"precision; an exploding MD run (check the time step and "
                         f"overlapping atoms in the start) or a unit mistake?")


def block_for_radius(grid, radius):
    """Block edge (sites per axis) for scans of radius ``radius`` (Å) on
    ``grid``: ``radius`` over the mean site spacing of each axis, rounded
    up, between 2 and 4.  A scan pays per candidate block (its box test and
    setup) and per slot of it (a distance): small blocks cost too many
    blocks, big ones too many slots outside the sphere.  Measured on fcc
    argon at rc + skin = 9.5 Å (spacing 3.6 Å, so 3): the scan took 132 ms
    with 3-site blocks against 181 ms with 2 at 10^5 atoms (17.5 against
    19.5 ms at 10^4); 4 gave 154 ms.  The list is the same for any block."""
    view = grid.view()
    shape = np.asarray(view.shape, dtype=np.float64)
    if grid.natoms == 0:
        return 2
    c = view.coordinates
    extent = np.array([c[:, a].max() - c[:, a].min() for a in range(3)])
    spacing = np.where(shape > 1, extent / np.maximum(shape - 1, 1), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        edge = np.ceil(radius / spacing)
    edge = np.where(np.isfinite(edge), edge, 2)
    return np.clip(edge, 2, 4).astype(np.int64)
