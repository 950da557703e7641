"""One pair list kept across calls: Verlet's list on the MLG.

A :class:`VerletList` is everything a list kept across MD steps, list
builds or trajectory frames needs, in one object: the grid that follows the
atoms (:class:`~ase_mlg.tracker.GridTracker`), the half list itself
(:class:`~ase_mlg.pairlist.PairList`, whose arrays the next build
overwrites), the reference positions and cell of the validity test, the
atoms' types in row order, and the unit of parallel work
(:class:`~ase_mlg.chunks.RowChunks`, kept with its buffers).  The block
index the exact query scans is built for each build and dropped after it
(it is a tenth of the list's memory, and stale after the next grid update).
Its :attr:`~VerletList.version` changes at every build: what its users
compare.

* :meth:`VerletList.allocate` builds the first list;
  :meth:`VerletList.update` brings it to new positions and cell and says
  whether it rebuilt it, :meth:`VerletList.build` rebuilds it whatever.
* The list holds every pair with ``d < cutoff + skin``.  It is kept while
  no pair outside it can have come within ``cutoff``: at a fixed cell the
  usual ``max |u| < skin / 2`` (Verlet 1967); under a changing cell (NPT)
  the bound of :meth:`VerletList.update`, which covers strain and
  displacement together.
* ``template=None`` lists come from the exact query (:mod:`ase_mlg.query`,
  docs/design.md §6), or below :data:`ase_mlg.allpairs.MAX_WORK` tested
  images (a few hundred atoms; the default ``block`` only) from every atom
  pair tested (:func:`ase_mlg.allpairs.half_store`: the same pairs, rows
  in atom order, no grid built or followed: :meth:`VerletList.build`);
  ``template=W`` from Boris's W x W x W half template
  (:mod:`ase_mlg.template`, approximate, docs/design.md §7).

The design, with the validity bound's proof, is docs/design.md §6, "The list
kept across calls".

The calculator (:class:`ase_mlg.MLGCalculator`), the neighbour-list classes
(:mod:`ase_mlg.neighborlist`) and the RDFs' pair source
(:mod:`ase_mlg.analysis.pairs`) are its users.
"""

import ctypes
import time

import numpy as np

from .allpairs import half_store, store_list, within_reach
from .blocks import BlockIndex, block_for_radius
from .geometry import Box, same
from .pairsum import shift_vectors
from .chunks import row_chunks
from .query import CUT_RADII, CUT_SCALAR, half_list, pair_list
from .template import template_pairs
from .tracker import GridTracker

__all__ = ["VerletList", "FAR_LISTS"]

#: An atom that moved this many list radii since the list was built, plus
#: ten times the cell edges, is in an unrelated configuration: the list is
#: rebuilt on a new grid (a large move is a reason to rebuild, never an
#: error; non-finite positions and coincident atoms are the errors).
FAR_LISTS = 100.0
#: Atoms from which a build hands the memory it freed back to the system
#: (glibc's ``malloc_trim``): glibc serves the build's arrays below 32 MB
#: (a grid's positions, the block index) from its heap once a larger one
#: was freed, and keeps that heap after they are freed.  On 10^6 atoms it
#: held 110 MB after a rebuild; a trim costs 40 µs even on a small heap,
#: nothing against a build of 10^5 atoms (50 ms).
TRIM_ATOMS = 100_000


def _trimmer():
    """glibc's ``malloc_trim``, or None where the C library has none
    (macOS, musl): there the allocator keeps its own policy."""
    try:
        return ctypes.CDLL(None).malloc_trim
    except (AttributeError, OSError):
        return None


_malloc_trim = _trimmer()


def trim_heap(natoms):
    """Hand glibc's freed heap back to the system after work on ``natoms``
    >= :data:`TRIM_ATOMS` atoms (a no-op without glibc)."""
    if natoms >= TRIM_ATOMS and _malloc_trim is not None:
        _malloc_trim(0)


class VerletList:
    """A half pair list in grid order, kept across calls.

    Parameters
    ----------
    cutoff : float or (N,) array_like
        Pair cutoff, Å: one value for every pair, or per-atom radii (the
        pair cutoff is then ``r_i + r_j``, as in ASE's ``NeighborList``).
    skin : float
        Verlet skin, Å: the list holds the pairs with ``d < cutoff + skin``
        and :meth:`update` keeps it while no pair outside it can have come
        within ``cutoff``.  0 rebuilds it at every update (per-atom radii
        take only 0).
    closed : bool
        With ``skin == 0``, hold the pairs at ``d == cutoff`` too (ASE's
        pair potentials keep them); the list radius is then the next float
        above ``cutoff``.
    template : None, odd int or callable
        None: the exact query.  W: Boris's W^3 half template.  A callable
        ``(grid, numbers) -> W or None`` chooses at every build (the
        ``template="auto"`` policy); a cell change then rebuilds the list,
        so that the policy re-checks its width.
    types : callable, optional
        ``numbers -> int array`` of a type index per atom (a potential's
        ``prepare``); :attr:`types` then holds them in row order.
    self_interaction : bool
        Hold each atom's pair with itself (``S = 0``) when its cutoff is > 0.
    block : int, optional
        Block edge of the exact query, sites (default
        :func:`ase_mlg.blocks.block_for_radius` of the list radius).  The
        set of pairs does not depend on it; the rank order does.
    follow_cell : bool
        On a new cell let the grid follow it (NPT keeps one grid), or build
        a new grid (see :mod:`ase_mlg.tracker`).
    grid_kwargs : dict, optional
        Passed to :class:`~ase_mlg.grid.MLG`.

    Attributes
    ----------
    version : int
        -1 before the first build, then one more at every build.
    pairs : PairList or None
        The list (ranks, compressed rows).
    width : int or None
        The template width of the list, None for the exact query.
    X : float64[N, 3] or None
        Positions of the last update in row order, each in the image the
        grid keeps it in (Å): the pair kernel's positions.  A bare
        :meth:`build` gathers them only for a template list with a skin
        (its rows put the pairs within the cutoff first); otherwise None until
        :meth:`update` or :meth:`allocate`.
    svec : float64[K, 3]
        Cartesian cell shift of every image code at the last update's cell, Å.
    types : int32[N] or None
        Type index of each row.
    rlist : float or None
        List radius, Å (scalar cutoffs; None with per-atom radii, whose
        lists hold no skin: every :meth:`update` rebuilds them).
    timings : dict
        Cumulative seconds of ``check`` (gather and validity test, one
        pass), ``list_build`` (rebuilds, the grid's part included) and
        ``grid`` (grid updates and sweeps).
    """

    def __init__(self, cutoff, skin=0.0, closed=False, template=None, types=None,
                 self_interaction=False, block=None, follow_cell=True, grid_kwargs=None):
        skin = float(skin)
        if not np.isfinite(skin) or skin < 0:
            raise ValueError(f"skin: must be finite and >= 0, got {skin}")
        self.skin = skin
        self.closed = bool(closed)
        self.pairs = self._spare = None
        if np.ndim(cutoff) == 0:
            self.radii = None
            self.cutoff = cutoff
        else:
            if template is not None:
                raise ValueError("template: per-atom radii need the exact query")
            if skin > 0:
                # the radii query cuts at r_i + r_j: a skin would be ignored
                raise ValueError("skin: per-atom radii lists hold no skin (add it to "
                                 "the radii, as ase.neighborlist does); use skin=0")
            self.radii = np.ascontiguousarray(cutoff, dtype=np.float64)
            self._cutoff = self.rlist = None
        self.template = template
        self.self_interaction = bool(self_interaction)
        self.block = block
        self._types_of = types
        self._tracker = GridTracker(follow_cell=follow_cell, **dict(grid_kwargs or {}))
        self.timings = dict.fromkeys(("check", "list_build", "grid"), 0.0)
        self.version = -1
        self._builds = 0
        self.reset()

    @classmethod
    def allocate(cls, positions, cell, pbc, cutoff, numbers=None, **options):
        """A list built for ``positions`` (Å) in ``cell`` with ``pbc``,
        ready for :meth:`update`; ``options`` are the constructor's."""
        vl = cls(cutoff, **options)
        vl.rebuild(positions, np.asarray(cell, dtype=np.float64), pbc, numbers)
        return vl

    def reset(self):
        """Forget the list and the grid: the next update builds both."""
        self._tracker.reset()
        self.pairs = self.X = self.svec = self.types = self.width = None
        self._chunks = self._ref = self._spare = self._svec_key = self._built = None

    @property
    def cutoff(self):
        """The scalar cutoff, Å (None with per-atom radii).  Setting it
        drops the list: the next update builds one at the new radius (into
        the old one's arrays)."""
        return self._cutoff

    @cutoff.setter
    def cutoff(self, cutoff):
        self._cutoff = float(cutoff)
        self.rlist = self._cutoff + self.skin
        if self.skin == 0 and self.closed:
            self.rlist = float(np.nextafter(self._cutoff, np.inf))
        if self.pairs is not None:
            self._spare = self.pairs
        self.pairs = None

    @property
    def grid(self):
        """The :class:`~ase_mlg.grid.MLG` of the last build (None before).
        A small system's exact list is built without one (:meth:`build`):
        asked for, the grid of that build's positions is built then, and
        followed from there by later builds that need one."""
        if self._tracker.grid is None and self._built is not None:
            self._tracker.follow(*self._built)
        return self._tracker.grid

    @property
    def positions(self):
        """The positions of the last build (float64 C, Å, atom order)."""
        return self._built[0] if self._built is not None else self._tracker.grid.positions

    @property
    def stats(self):
        """Cumulative ``list_builds`` and the grid's ``grid_builds``,
        ``grid_updates``, ``sweeps``, ``swaps``, ``grid_rebuilds`` and ``grid_carries``."""
        return {"list_builds": self._builds, **self._tracker.stats}

    # -- keeping it -----------------------------------------------------------
    def update(self, positions, cell, pbc, numbers=None, numbers_same=False, box_same=False):
        """Bring the list to ``positions`` (float64 (N, 3), Å) in ``cell``
        with ``pbc``, rebuilding it when it may miss a pair within the
        cutoff, when the number of atoms, pbc or ``numbers`` changed;
        returns True if it rebuilt.  :attr:`X` and :attr:`svec` are then
        those of the new positions and cell.  ``numbers_same``: the caller
        knows that ``numbers`` are those of the last call (an MD step's
        check said so), and they are not compared again (two arrays of N
        read a step; 10-20 µs at 10^4 atoms once the pair sum has pushed them
        out of the cache).  ``box_same``: the caller knows that ``cell``
        and ``pbc`` are those of the last call, so neither is compared
        again nor are the shift vectors checked (2 µs of a force call at 256
        atoms).

        A pair left out was at ``d0 >= rlist`` when the list was built.
        With ``M`` the affine map of the cell since then and ``u`` each
        atom's displacement beyond it, its distance now is at least
        ``smin(M) d0 - 2 max|u|`` (``smin`` the smallest singular value of
        M: the triangle inequality), so the list is valid while
        ``smin(M) rlist - 2 max|u| > cutoff``.  At a fixed cell that is the
        usual ``max|u| < skin / 2``; under NPT the skin covers displacement
        and strain together.  (LAMMPS's ``check_distance`` bounds the strain
        by the box corners' displacement instead.)
        """
        X = self.kept(positions, cell, pbc, None if numbers_same else numbers, box_same)
        if X is None:
            self.rebuild(positions, cell, pbc, numbers)
            return True
        if box_same:  # the last call's cell: its shift vectors
            self.X = X
        else:
            self.keep(X, cell)
        return False

    def kept(self, positions, cell, pbc, numbers=None, box_same=False):
        """The list's positions in row order at ``positions`` if the list
        still holds there (the test of :meth:`update`), else None: the
        positions are written into :attr:`X` in place, the pairs are not
        changed (a list that fails the test is rebuilt, with a new
        :attr:`X`).  With :meth:`keep`, :meth:`update` in two halves: the
        ranks of a distributed run decide together between them.
        ``box_same``: as :meth:`update`'s, for ``pbc``."""
        t0 = time.perf_counter()
        cell = np.asarray(cell, dtype=np.float64)
        X = None
        if (self.pairs is not None and len(positions) == self.pairs.natoms
                and (box_same or same(pbc, self._pbc))
                and (numbers is None or same(numbers, self._numbers))):
            X = self._kept_positions(positions, cell) if self._ref is not None else None
        self.timings["check"] += time.perf_counter() - t0
        return X

    def keep(self, X, cell):
        """Keep the list at the row-order positions ``X`` that :meth:`kept`
        returned, in ``cell``."""
        self.X = X
        cell = np.asarray(cell, dtype=np.float64)
        key = (self.version, cell.tobytes())
        if key != self._svec_key:  # the same cell's shift vectors are the same bits
            self.svec = shift_vectors(self.pairs.shifts, cell)
            self._svec_key = key

    def _kept_positions(self, positions, cell):
        """Positions in row order if the list still holds every pair within
        the cutoff (see :meth:`update`), else None."""
        if self.skin == 0.0:
            return None  # also every per-atom radii list: they take no skin
        ref_cell = self._ref_cell
        fixed = cell.tobytes() == self._ref_bytes or np.array_equal(cell, ref_cell)
        if fixed:
            M = None  # the gather's test without the map
        elif callable(self.template):
            return None  # the policy re-checks its width on a new cell
        elif abs(np.linalg.det(ref_cell)) < 1e-12 * max(np.abs(ref_cell).max(), 1.0) ** 3:
            return None
        else:
            M = np.ascontiguousarray(np.linalg.solve(ref_cell, cell))
        # into the last step's X, in place: a new one each step was 23 MB
        # allocated and faulted in a step at 10^6 atoms.  When the list
        # fails the test it is rebuilt, with a new X
        X, umax = self.pairs.gather_check(positions, cell, self._ref, M, out=self.X)
        if fixed:
            kept = umax < 0.5 * self.skin
        else:
            smin = float(np.linalg.svd(M, compute_uv=False).min())
            kept = smin * self.rlist - 2.0 * umax > self.cutoff
        if kept:
            return X
        if umax > FAR_LISTS * self.rlist + 10.0 * float(np.linalg.norm(cell, axis=1).sum()):
            # an unrelated configuration (a structure swapped in, a crystal
            # translated by many cells, far-apart frames): a new grid is
            # cheaper than sweeping the old one there (NaN is not > far:
            # the grid names non-finite positions)
            self._tracker.reset()
        return None

    # -- building it ----------------------------------------------------------
    def build(self, positions, cell, pbc, numbers=None, renumber=None, owned=None):
        """Build the list for ``positions`` (float64 (N, 3), Å) in ``cell``
        with ``pbc``, whatever the state (the grid is updated, not rebuilt,
        where it can be).  ``renumber``: the rows are not the atoms of the
        last build (a rank's local system after migration and new ghosts)
        but share most of them: each atom of the last build's index among
        ``positions`` or -1 (gone).  The grid is then carried over to the
        new numbering (:meth:`ase_mlg.grid.MLG.renumber`: 0.06 s against
        0.42 s for a new grid at 5.8e5 atoms), or built anew where it
        cannot be; following it without the new numbers would sweep nearly
        every atom to its new label (3.6 million swaps at 2 ranks of
        108,000 atoms).  ``owned``: only the pairs with one of the first
        ``owned`` atoms (a rank's own atoms before its ghosts;
        :func:`~ase_mlg.query.half_list`); a small system's list, without
        a grid, holds every pair.

        An exact list (``template=None``) of a small system comes from
        every atom pair tested (:func:`~ase_mlg.allpairs.half_store`), rows
        in atom order, and no grid is built or followed for it: below a few
        hundred atoms the MLG's order buys no locality that the caches do
        not already give, and its construction was a quarter of a first
        force call (1.9 of 8.3 s compiling) and most of a rebuild.
        :attr:`grid` builds one on request."""
        t0 = time.perf_counter()
        cell = np.asarray(cell, dtype=np.float64)
        old = self.pairs if self.pairs is not None else self._spare
        if old is not None:
            old.drop_atom_arrays()  # the scan takes over its pair arrays only
        self.pairs = self._chunks = self._spare = None
        self.X = self.svec = self._ref = self._svec_key = self._built = None
        template = self.template
        pl = None
        if template is None and self.block is None and within_reach(len(positions)):
            # a copy: the caller's array moves on (an MD step writes it in
            # place); only where the small path may take it (above, the
            # copy was alive through the whole build: 13 MB of a rank's peak
            # at 2 ranks of 10^6 atoms)
            x = np.array(positions, dtype=np.float64, order="C")
            pl = self._small_list(x, None, cell, pbc, old)
        if pl is not None:
            # no grid: a grid kept from a larger system would be stale
            self._tracker.reset()
            self._built = (x, cell.copy(), np.array(pbc, dtype=bool))
            self.width, positions = None, x
            inner_first = True
        else:
            grid = self._tracker.follow(positions, cell, pbc, renumber)
            positions = grid.positions  # the same numbers, as float64 C arrays
            self.timings["grid"] += time.perf_counter() - t0
            self.width = template(grid, numbers) if callable(template) else template
            pl, inner_first = self._grid_list(grid, old, cell, pbc, owned)
        del old
        self.pairs = pl
        if not inner_first and self.radii is None and self.rlist != self.cutoff:
            self._gather(positions, cell)
            pl.inner_first(self.X, self.svec, self.cutoff)
        if self._types_of is not None:
            self.types = np.ascontiguousarray(self._types_of(numbers)[pl.order])
        self._numbers = None if numbers is None else np.array(numbers, copy=True)
        self._pbc = np.broadcast_to(np.asarray(pbc, dtype=bool), (3,)).copy()
        self._ref_cell = cell.copy()
        self._ref_bytes = self._ref_cell.tobytes()
        self.version += 1
        self._builds += 1
        trim_heap(pl.natoms)  # the scan's and the old list's memory, back
        self.timings["list_build"] += time.perf_counter() - t0
        return pl

    def _grid_list(self, grid, old, cell, pbc, owned=None):
        """The list on ``grid``: ``(PairList, inner_first)``, ``inner_first``
        whether each row holds the pairs within the cutoff first."""
        n = grid.natoms
        if self.width is None and self.block is None:
            # an auto template that chose the exact query, on a small system
            pl = self._small_list(grid.positions, grid.sites.ravel(), cell, pbc, old)
            if pl is not None:
                return pl, True
        if self.radii is not None:
            rmax = float(self.radii.max()) if n else 0.0
            rat, hint = self.radii + rmax, None
        else:
            rat = np.full(n, self.rlist)
            hint = None if old is None or old.natoms != n else len(old) / max(n, 1)
        index = BlockIndex(grid, block_for_radius(grid, float(rat.max(initial=0.0)))
                           if self.block is None else self.block)
        # the freed temporaries of the grid's follow and the block index (and
        # a rank's migration) back before the scan, the build's peak: 75 MB
        # of a rank's 620 at 2 ranks of 10^6 atoms were freed but resident
        trim_heap(n)
        if self.width is not None:
            i, j, S, _ = template_pairs(grid, self.width, self.rlist)
            return pair_list(index, i, j, S), False
        if self.radii is not None:
            return half_list(index, rat, CUT_RADII, radii=self.radii,
                             self_interaction=self.self_interaction, reuse=old,
                             owned=owned), False
        # pairs within the cutoff first in each row, straight from the
        # scan, where the list holds others
        split = None if self.rlist == self.cutoff else self.cutoff
        return half_list(index, rat, cut=self.rlist, self_interaction=self.self_interaction,
                         pairs_per_atom=hint, reuse=old, split=split, owned=owned), True

    def _small_list(self, x, sites, cell, pbc, old=None):
        """The list of a small system, every atom pair tested
        (:func:`ase_mlg.allpairs.half_store`: the exact query's pairs), rows
        in atom order (``sites`` None) or in the grid's site order, or None
        above its size or where a position is not finite (the grid names
        the atoms).  Where the exact query's set-up (the block index, the
        scan's room and codes) costs more than the pairs, and on a first
        call its compilation, this path answers in one kernel.  ``old``:
        the last list, whose length sizes the kernel's store."""
        if not np.isfinite(x).all():
            return None
        cut = ((CUT_RADII, 0.0, self.radii, None, None) if self.radii is not None
               else (CUT_SCALAR, self.rlist, None, None, None))
        # the last list of these atoms sizes the store (another system's
        # might be 10^6 atoms')
        room = 1.25 * len(old) if old is not None and old.natoms == len(x) else None
        res = half_store(x, cell, pbc, cut, self.self_interaction, room=room)
        if res is None:
            return None
        store, m = res
        if sites is None:
            order = np.arange(len(x), dtype=np.int64)
        else:
            order = np.ascontiguousarray(sites[sites >= 0], dtype=np.int64)
        # the pairs within the cutoff first in each row, as the scan writes them
        split = self.cutoff if self.radii is None and self.rlist != self.cutoff else None
        return store_list(order, store, m, x, cell, split)

    def rebuild(self, positions, cell, pbc, numbers=None, renumber=None, owned=None):
        """:meth:`build`, and the kernel's positions (:attr:`X`,
        :attr:`svec`): what :meth:`update` does when the list does not hold."""
        cell = np.asarray(cell, dtype=np.float64)
        self.build(positions, cell, pbc, numbers, renumber=renumber, owned=owned)
        t0 = time.perf_counter()
        if self.X is None:
            self._gather(self.positions, cell)
        self.timings["list_build"] += time.perf_counter() - t0

    def _gather(self, positions, cell):
        """The kernel's positions and shift vectors at the build, through
        the per-call gather (compiled or loaded here, not in the first call
        after): only for lists that :meth:`update` keeps (the neighbour
        lists and the RDFs read :meth:`arrays`).  The validity test's
        reference is ``positions`` itself (atom order: the gather reads in
        atom order): the build's own float64 C array, the grid's or the
        copy of a small system's, which nothing writes after (a grid's
        update makes a new array), so that a copy would only cost N x 24
        bytes (23 MB at 10^6 atoms)."""
        self.X = self.pairs.positions(positions, cell)
        self._ref = positions
        self.svec = shift_vectors(self.pairs.shifts, cell)

    # -- reading it -----------------------------------------------------------
    def chunks(self, nthreads=None):
        """The unit of parallel work of a pass over the list: its rows cut
        into :class:`~ase_mlg.chunks.RowChunks`
        (:func:`~ase_mlg.chunks.row_chunks`: a function of the list
        alone), kept with their buffers until the next build.  The same
        object for any ``nthreads`` (accepted for compatibility): the
        chunks never follow the thread count, so neither do the results;
        numba's thread count at the pair sum decides how many threads
        share them."""
        if self._chunks is None:
            self._chunks = row_chunks(self.pairs.rowptr, self.pairs.nbr)
        return self._chunks

    def arrays(self, half=False, quantities="ijdDS", orient=None):
        """The list as ``ase.neighborlist`` returns it, at the positions
        and cell of the last build (see :meth:`ase_mlg.pairlist.PairList.arrays`)."""
        if self._built is not None:
            x, cell, pbc = self._built
            full = Box(cell, pbc).full
        else:
            x, full = self._tracker.grid.positions, self._tracker.grid.box.full
        return self.pairs.arrays(x, np.ascontiguousarray(full),
                                 half=half, quantities=quantities, orient=orient)
