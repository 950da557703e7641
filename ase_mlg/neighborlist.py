"""Drop-in replacements for :mod:`ase.neighborlist`, built on the MLG.

* :func:`neighbor_list` / :func:`primitive_neighbor_list`: the semantics of
  ``ase.neighborlist.neighbor_list`` / ``primitive_neighbor_list`` (ASE
  3.29): quantities over ``'ijdDS'``; cutoff as a float, per-atom radii (pair
  cutoff ``r_i + r_j``) or a ``{(Z1, Z2) or (sym1, sym2): cutoff}`` dict
  (pairs of elements not in the dict are never neighbours; a later entry
  overrides an earlier one for the same pair, as in ASE); ``d < cutoff``
  strictly; ``D = positions[j] - positions[i] + S @ cell`` with the positions
  as given (atoms outside the cell included, periodic or not); self pairs
  ``(i, i, S=0)`` only with ``self_interaction=True``, an atom's own periodic
  images always; ints are int64 (``int``), floats float64.
  *Ordering*: sorted by ``i`` (ASE's only guarantee).  Within one ``i``:
  small systems (:mod:`ase_mlg.allpairs`, up to ``allpairs.MAX_WORK``
  tested images, about 500 atoms of a metal at 5 Å) by ``j``, then ``S``;
  larger ones in the grid's order -- deterministic for given input, but
  not ASE's (which is itself unspecified: an unstable argsort).  Both give
  the same pairs, ``d`` to the bit and ``D`` equal (the block query writes
  a pair's second entry as ``-D``, which may turn a zero into -0.0).
  ``max_nbins`` is accepted and ignored (the MLG has no bins).
* :class:`NeighborList`, :class:`PrimitiveNeighborList`,
  :class:`NewPrimitiveNeighborList`: the semantics of the ASE classes of the
  same names, including which half of the pairs ``bothways=False`` keeps
  (ASE's two primitives keep different halves; each of ours keeps the same
  half as its ASE namesake), ``sorted=True`` order to the element (the old
  primitive: by neighbour index, then offsets; the new one: ASE's
  ``argsort(i * len(i) + j)``, ties between images of one neighbour in ASE's
  own order -- except where ASE's key breaks the order by atom, see
  ``_MLGPrimitive._sort``), the rebuild rule (any atom moved more than ``skin`` since
  the last build -- ASE adds ``skin`` to every radius -- or pbc/cell/number of
  atoms changed) and ``update()`` returning True only when it rebuilt.
  One MLG is kept across rebuilds and maintained by ``grid.update`` (swap
  sweeps); a new grid is built only when pbc, cell or the number of atoms
  change.

* :func:`first_neighbors`, :func:`get_connectivity_matrix` and
  :func:`build_neighbor_list` (which builds our :class:`NeighborList`) as in
  ASE; ``natural_cutoffs``, ``get_distance_matrix``,
  ``get_distance_indices`` and ``mic`` build no list and are ASE's own,
  re-exported, so ``import ase_mlg.neighborlist as neighborlist`` replaces
  ``import ase.neighborlist as neighborlist`` whole.

Use with ASE calculators that take a neighbour-list function::

    from ase.calculators.morse import MorsePotential
    import ase_mlg
    atoms.calc = MorsePotential(neighbor_list=ase_mlg.neighbor_list)

Bad input raises ``ValueError`` naming the problem: unknown quantity letters,
negative/NaN/inf cutoffs or skin, a cutoff list of the wrong length, unknown
elements in a cutoff dict, NaN/inf positions, a zero-volume periodic cell.
"""

import math
import numbers as _numbers

import numpy as np
# ASE's helpers that build no list are ASE's own, re-exported unchanged
from ase.neighborlist import (get_distance_indices, get_distance_matrix,
                              mic, natural_cutoffs)
# ASE's own class, bound now: code that rebinds ase.neighborlist's names to
# ours (a monkeypatch, or sys.modules["ase.neighborlist"] = this module, so
# that ASE's calculators run on the MLG) must not make _MLGPrimitive._sort
# call itself through the name it looks up
from ase.neighborlist import NewPrimitiveNeighborList as _AseNewPrimitive
from scipy import sparse as _sp

from .allpairs import all_pairs
from .blocks import BlockIndex
from .geometry import Box, as_positions, same
from .grid import MLG
from .query import CUT_RADII, CUT_SCALAR, CUT_TABLE, find_pairs
from .verletlist import VerletList

__all__ = ["neighbor_list", "primitive_neighbor_list", "NeighborList",
           "PrimitiveNeighborList", "NewPrimitiveNeighborList",
           "first_neighbors", "get_connectivity_matrix",
           "build_neighbor_list", "natural_cutoffs", "get_distance_matrix",
           "get_distance_indices", "mic"]

_QUANTITIES = "ijdDS"
BLOCK = 2


# --------------------------------------------------------------------------
# input checking
# --------------------------------------------------------------------------

def _check_quantities(quantities):
    if not isinstance(quantities, str):
        raise ValueError(f"quantities: expected a string over 'ijdDS', got "
                         f"{type(quantities).__name__}")
    bad = sorted(set(quantities) - set(_QUANTITIES))
    if bad:
        raise ValueError(f"quantities: unsupported quantity letter(s) {bad} in "
                         f"{quantities!r}; use any of 'i', 'j', 'd', 'D', 'S'")


def _check_value(x, what):
    """``x`` (a float) finite and >= 0, or a ValueError naming ``what``."""
    if not (math.isfinite(x) and x >= 0):
        raise ValueError(f"{what}: must be finite and >= 0, got {x}")


def _element_number(key, what):
    from ase.data import atomic_numbers
    if isinstance(key, (bool, np.bool_)):
        raise ValueError(f"{what}: element {key!r} is not an element symbol "
                         "or atomic number")
    if isinstance(key, (_numbers.Integral, np.integer)):
        return int(key)
    if isinstance(key, str):
        if key in atomic_numbers:
            return int(atomic_numbers[key])
        raise ValueError(f"{what}: unknown element symbol {key!r}")
    raise ValueError(f"{what}: element {key!r} is not an element symbol or "
                     "atomic number")


def _is_scalar(cutoff):
    if isinstance(cutoff, (str, bytes)):
        raise ValueError(f"cutoff: expected a number, a list of radii or a "
                         f"dict, got {cutoff!r}")
    return np.isscalar(cutoff) or (isinstance(cutoff, np.ndarray)
                                   and cutoff.ndim == 0)


def _parse_cutoff(cutoff, natoms, numbers):
    """Return (mode, scalar cut, radii, types, table, per-atom query radius);
    the query radius is None for a scalar cutoff (``cut`` for every atom:
    the array only where the grid's query needs it, not on every small
    call)."""
    if isinstance(cutoff, dict):
        if not cutoff:
            raise ValueError("cutoff: the cutoff dict is empty")
        entries = []
        for key, c in cutoff.items():
            try:
                z1, z2 = key
            except (TypeError, ValueError):
                raise ValueError(f"cutoff: dict keys must be pairs of elements, "
                                 f"got {key!r}") from None
            try:
                c = float(c)
            except (TypeError, ValueError, OverflowError):
                raise ValueError(f"cutoff: value for {key!r} is not a number: "
                                 f"{c!r}") from None
            _check_value(c, f"cutoff[{key!r}]")
            entries.append((_element_number(z1, "cutoff"),
                            _element_number(z2, "cutoff"), c))
        cmax = max(c for _, _, c in entries)
        if numbers is None:
            # ASE: without atomic numbers only the largest value is used
            return CUT_SCALAR, cmax, None, None, None, None
        numbers = np.asarray(numbers)
        if numbers.shape != (natoms,):
            raise ValueError(f"numbers: expected shape ({natoms},), got "
                             f"{numbers.shape}")
        uniq, types = np.unique(numbers, return_inverse=True)
        pos = {int(z): t for t, z in enumerate(uniq)}
        table = np.zeros((len(uniq), len(uniq)))
        for z1, z2, c in entries:  # later entries override, as in ASE
            if z1 in pos and z2 in pos:
                table[pos[z1], pos[z2]] = c
                table[pos[z2], pos[z1]] = c
        rat = table.max(axis=1)[types] if natoms else np.zeros(0)
        return CUT_TABLE, 0.0, None, types.astype(np.int64), table, rat
    if _is_scalar(cutoff):
        try:
            c = float(cutoff)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"cutoff: expected a number, got {cutoff!r}") from None
        _check_value(c, "cutoff")
        return CUT_SCALAR, c, None, None, None, None
    try:
        radii = np.asarray(cutoff, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("cutoff: expected a number, a list of per-atom radii or "
                         "a dict of element-pair cutoffs") from None
    if radii.shape != (natoms,):
        raise ValueError(f"cutoff: per-atom radii need one value per atom "
                         f"({natoms}), got shape {radii.shape}")
    bad = np.flatnonzero(~np.isfinite(radii) | (radii < 0))
    if bad.size:
        raise ValueError(f"cutoff: radii must be finite and >= 0; bad for atom(s) "
                         f"{bad[:10].tolist()}: {radii[bad[:10]].tolist()}")
    rmax = float(radii.max()) if natoms else 0.0
    return CUT_RADII, 0.0, radii, None, None, radii + rmax


def _assemble(quantities, res):
    out = tuple(res[q] for q in quantities)
    return out[0] if len(out) == 1 else out


def _empty_result(quantities):
    res = {"i": np.empty(0, dtype=int), "j": np.empty(0, dtype=int),
           "d": np.empty(0, dtype=float), "D": np.empty((0, 3), dtype=float),
           "S": np.empty((0, 3), dtype=int)}
    return _assemble(quantities, res)


# --------------------------------------------------------------------------
# functions
# --------------------------------------------------------------------------

def primitive_neighbor_list(quantities, pbc, cell, positions, cutoff,
                            numbers=None, self_interaction=False,
                            use_scaled_positions=False, max_nbins=1e6,
                            grid=None):
    """Neighbour list of a configuration given as arrays; the semantics of
    ``ase.neighborlist.primitive_neighbor_list`` (see the module doc).

    Parameters
    ----------
    quantities : str
        Any string over ``'ijdDS'``; one array per letter, in that order (a
        bare array for a single letter).
    pbc : bool or 3 bools
    cell : (3, 3) array_like
        Cell vectors as rows.  May be zero on non-periodic axes.
    positions : (N, 3) array_like
        Cartesian positions, or scaled ones with ``use_scaled_positions``.
    cutoff : float, (N,) radii, or dict
        Global cutoff, per-atom radii (pairs within ``r_i + r_j``) or
        per-element-pair cutoffs (needs ``numbers``; without them only the
        largest value is used, as in ASE).
    numbers : (N,) ints, optional
        Atomic numbers (for a dict cutoff).
    self_interaction : bool
        Include each atom as its own neighbour (S = 0).
    use_scaled_positions : bool
    max_nbins : ignored
        Accepted for compatibility; the MLG needs no bins.
    grid : MLG, optional
        A grid already built or updated for exactly these positions, cell and
        pbc (e.g. one maintained across MD steps by ``grid.update``); it is
        used instead of building a new one.  Without it, small systems
        (:data:`ase_mlg.allpairs.MAX_WORK`) are answered with no grid at
        all, by :func:`ase_mlg.allpairs.all_pairs`.

    Returns
    -------
    arrays in the order of ``quantities``: i, j (int64), d (float64),
    D (float64, (M, 3)), S (int64, (M, 3)); sorted by i.
    """
    _check_quantities(quantities)
    pos = as_positions(positions)
    n = len(pos)
    mode, cut, radii, types, table, rat = _parse_cutoff(cutoff, n, numbers)
    if n == 0:
        return _empty_result(quantities)
    cell = np.asarray(cell, dtype=np.float64)
    if cell.shape == (3,):
        cell = np.diag(cell)
    if use_scaled_positions:
        if cell.shape != (3, 3) or not np.isfinite(cell).all():
            raise ValueError("cell: expected a finite (3, 3) array")
        pos = np.ascontiguousarray(pos @ cell)
    if grid is None:
        # small systems: a few compiled calls, no grid (ase_mlg.allpairs); it
        # answers None where the grid's query is faster or must decide
        res = all_pairs(pos, cell, pbc, (mode, cut, radii, types, table),
                        bool(self_interaction), quantities)
        if res is not None:
            return _assemble(quantities, res)
        grid = MLG(pos, cell, pbc)
    else:
        box = Box(cell, pbc)
        if (grid.natoms != n or not np.array_equal(grid.box.pbc, box.pbc)
                or not np.array_equal(grid.box.full, box.full)
                or not np.array_equal(grid.positions, pos)):
            raise ValueError("grid: the MLG does not hold these positions, cell "
                             "and pbc; call grid.update(positions) first")
    index = BlockIndex(grid, BLOCK)
    if rat is None:
        rat = np.full(n, cut)
    res = find_pairs(index, rat, mode, cut, radii, types, table,
                     self_interaction=bool(self_interaction),
                     quantities=quantities)
    return _assemble(quantities, res)


def neighbor_list(quantities, a, cutoff, self_interaction=False,
                  max_nbins=1e6, grid=None):
    """Neighbour list of an ASE ``Atoms``; the semantics of
    ``ase.neighborlist.neighbor_list`` (see the module doc).

    >>> i, j, d = neighbor_list('ijd', atoms, 5.0)      # doctest: +SKIP
    >>> i = neighbor_list('i', atoms, {('H', 'C'): 1.2})  # doctest: +SKIP

    ``grid``: optionally an :class:`~ase_mlg.MLG` already updated to these
    atoms (see :func:`primitive_neighbor_list`).
    """
    # the raw cell: a periodic axis without a cell vector is an error here,
    # where ASE would silently complete it with a 1 A unit vector
    return primitive_neighbor_list(quantities, a.pbc, a.cell.array,
                                   a.positions, cutoff, numbers=a.numbers,
                                   self_interaction=self_interaction,
                                   max_nbins=max_nbins, grid=grid)


def first_neighbors(natoms, first_atom):
    """Offsets of each atom's range in a list sorted by ``i`` (as
    ``ase.neighborlist.first_neighbors``): neighbours of atom k are at
    ``s[k]:s[k+1]``."""
    first_atom = np.asarray(first_atom, dtype=np.int64)
    counts = np.bincount(first_atom, minlength=natoms) if len(first_atom) else \
        np.zeros(natoms, dtype=np.int64)
    seed = np.zeros(natoms + 1, dtype=int)
    np.cumsum(counts[:natoms], out=seed[1:])
    return seed


# --------------------------------------------------------------------------
# classes
# --------------------------------------------------------------------------

class _MLGPrimitive:
    """Shared machinery of the two primitive neighbour lists."""

    _ase_half = None  # "old" (PrimitiveNeighborList) or "new"

    def __init__(self, cutoffs, skin=0.3, sorted=False, self_interaction=True,
                 bothways=False, use_scaled_positions=False):
        skin = float(skin)
        _check_value(skin, "skin")
        try:
            r = np.asarray(cutoffs, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise TypeError(f"cutoffs: expected a list of radii in Å, got "
                            f"{cutoffs!r}") from None
        bad = np.flatnonzero(~np.isfinite(r) | (r < 0))
        if bad.size:
            raise ValueError(f"cutoffs: radii must be finite and >= 0; bad for "
                             f"atom(s) {bad[:10].tolist()}")
        self.cutoffs = r + skin
        self.skin = skin
        self.sorted = sorted
        self.self_interaction = self_interaction
        self.bothways = bothways
        self.use_scaled_positions = use_scaled_positions
        self.nupdates = 0
        # one grid kept across builds; a new cell builds a new grid (see
        # ase_mlg.tracker).  ASE's rebuild rule stays here (_needs_build).
        self.verlet_list = VerletList(self.cutoffs, follow_cell=False,
                                      self_interaction=bool(self_interaction))
        self._reduced = (None, None, None)  # ASE's half: (cell and pbc, reduced cell, basis)

    @property
    def grid(self):
        """The :class:`~ase_mlg.grid.MLG` of the last build (None before)."""
        return self.verlet_list.grid

    # -- rebuild rule -------------------------------------------------------
    def _needs_build(self, pbc, cell, coordinates):
        if self.nupdates == 0:
            return True
        pbc = np.asarray(pbc, dtype=bool)
        if pbc.shape != (3,):
            pbc = np.broadcast_to(pbc, (3,))
        coordinates = np.asarray(coordinates, dtype=np.float64)
        # same(): a few numbers compared as lists, not numpy passes (an
        # update with nothing moved is all overhead)
        if not (same(pbc, self.pbc) and same(np.asarray(cell, dtype=np.float64), self.cell)):
            return True
        if coordinates.shape != self.coordinates.shape:
            return True
        if len(coordinates) == 0:
            return False
        d = self.coordinates - coordinates
        # every |d| < skin when every component is below skin / sqrt(3)
        # (margin 1e-9 over the rounding of |d|^2): one pass, not four; else
        # ASE's own test, to the bit
        if np.abs(d).max() * 3.0 ** 0.5 < self.skin * (1.0 - 1e-9):
            return False
        return bool((d ** 2).sum(1).max() > self.skin ** 2)

    def update(self, pbc, cell, coordinates, numbers=None):
        """Make sure the list is up to date; True if it was rebuilt."""
        if self._needs_build(pbc, cell, coordinates):
            self.build(pbc, cell, coordinates, numbers=numbers)
            return True
        return False

    # -- build --------------------------------------------------------------
    def build(self, pbc, cell, coordinates, numbers=None):
        """Build the list (coordinates scaled or not per
        ``use_scaled_positions``)."""
        from ase.cell import Cell
        pbc = np.broadcast_to(np.asarray(pbc, dtype=bool), (3,)).copy()
        cellobj = Cell(np.asarray(cell, dtype=np.float64))
        coords = as_positions(coordinates, "coordinates")
        n = len(coords)
        if len(self.cutoffs) != n:
            raise ValueError(f"Wrong number of cutoff radii: {len(self.cutoffs)} "
                             f"!= {n}")
        self.pbc = pbc
        self.cell = cellobj.array.copy()
        self.coordinates = coords.copy()
        self.positions = self.coordinates  # NewPrimitiveNeighborList name
        if self.use_scaled_positions:
            positions = np.ascontiguousarray(cellobj.cartesian_positions(coords))
        else:
            positions = coords
        if n == 0:
            self.verlet_list.reset()
            i = np.empty(0, int)
            j = np.empty(0, int)
            S = np.empty((0, 3), int)
        else:
            self.verlet_list.build(positions, self.cell, pbc)
            # bothways=False: ASE's half straight from the half list, each
            # pair once in the orientation ASE keeps
            orient = None if self.bothways else self._orientation(cellobj, pbc, positions)
            res = self.verlet_list.arrays(quantities="jS", orient=orient)
            i, j, S = res["i"], res["j"], res["S"]
            if self.sorted:
                i, j, S = self._sort(i, j, S, pbc, coords)
        self.pair_first = i
        self.pair_second = j
        self.offset_vec = S
        self.first_neigh = first_neighbors(n, i)
        self._lists = None
        self.nupdates += 1

    def _sort(self, i, j, S, pbc, coords):
        """ASE's ``sorted=True`` order of the list (i, j, S)."""
        if self._ase_half != "new":
            # ase PrimitiveNeighborList: each atom's neighbours by index, then
            # offsets x, y, z (a stable lexsort: one order for a given set)
            order = np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i))
            return i[order], j[order], S[order]
        # ase NewPrimitiveNeighborList: np.argsort(i * len(i) + j), ASE's
        # key and call.  With distinct keys the result is one order whatever
        # the input order, so ours is ASE's.  Equal keys (an atom seeing
        # several images of one neighbour in a small cell) are left in the
        # order of ASE's bin search by an unstable sort: the only way to get
        # that order is ASE's own search, run for these (small-cell) cases.
        key = i * len(i) + j
        order = np.argsort(key)
        if (np.diff(i[order]) < 0).any():
            # Deliberate difference: with fewer pairs than the largest
            # neighbour index ASE's key is not ordered by i, its list is not
            # sorted by atom, and its get_neighbors returns other atoms'
            # neighbours.  We sort by (i, j, offsets): correct neighbours.
            order = np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i))
            return i[order], j[order], S[order]
        skey = key[order]
        if len(skey) < 2 or not (skey[1:] == skey[:-1]).any():
            return i[order], j[order], S[order]
        if issubclass(_AseNewPrimitive, _MLGPrimitive):
            # this module was re-imported after ASE's name had been bound to
            # ours: ASE's search is out of reach, keep one deterministic order
            order = np.lexsort((S[:, 2], S[:, 1], S[:, 0], key))
            return i[order], j[order], S[order]
        ref = _AseNewPrimitive(self.cutoffs, skin=0.0, sorted=True,
                               self_interaction=self.self_interaction,
                               bothways=self.bothways,
                               use_scaled_positions=self.use_scaled_positions)
        ref.build(pbc, self.cell, coords)
        ai, aj, aS = (np.asarray(ref.pair_first, dtype=int),
                      np.asarray(ref.pair_second, dtype=int),
                      np.asarray(ref.offset_vec, dtype=int).reshape(-1, 3))
        # the same set of pairs (the ASE suite checks it); otherwise keep ours
        mine = np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i))
        theirs = np.lexsort((aS[:, 2], aS[:, 1], aS[:, 0], aj, ai))
        if (len(ai) == len(i) and np.array_equal(i[mine], ai[theirs])
                and np.array_equal(j[mine], aj[theirs])
                and np.array_equal(S[mine], aS[theirs])):
            return ai, aj, aS
        order = np.lexsort((S[:, 2], S[:, 1], S[:, 0], key))
        return i[order], j[order], S[order]

    def _orientation(self, cellobj, pbc, positions):
        """The rule by which ASE's primitive keeps one of ``(i, j, S)`` and
        ``(j, i, -S)`` (``PairList.arrays``' ``orient``): ``n = (S +
        offsets[i] - offsets[j]) @ basis`` lexicographically positive, or
        zero with ``i <= j``."""
        if self._ase_half == "new":
            # ase NewPrimitiveNeighborList: the cell shift itself
            return None, np.eye(3, dtype=np.int64)
        # ase PrimitiveNeighborList: the image shifts in the Minkowski-reduced
        # basis of the wrapped positions; the reduction depends on the cell
        # only, so it is kept until the cell or pbc change
        from ase.geometry import minkowski_reduce, wrap_positions
        key = (cellobj.array.tobytes(), np.asarray(pbc).tobytes())
        if self._reduced[0] != key:
            rcell, op = minkowski_reduce(cellobj, pbc)
            self._reduced = key, rcell, np.rint(np.linalg.inv(op)).astype(np.int64)
        _, rcell, basis = self._reduced
        wrapped = wrap_positions(positions, rcell, pbc=pbc, eps=0)
        offsets = cellobj.scaled_positions(wrapped - positions).round().astype(np.int64)
        return offsets, basis

    # -- access -------------------------------------------------------------
    def get_neighbors(self, a):
        """Indices and cell offsets of the neighbours of atom ``a``:
        ``positions[indices] + offsets @ cell`` are the neighbour images."""
        s, e = self.first_neigh[a], self.first_neigh[a + 1]
        return self.pair_second[s:e], self.offset_vec[s:e]

    def _split(self):
        if self._lists is None:
            n = len(self.first_neigh) - 1
            cuts = self.first_neigh[1:-1]
            self._lists = (np.split(self.pair_second, cuts) if n else [],
                           np.split(self.offset_vec, cuts) if n else [])
        return self._lists

    @property
    def neighbors(self):
        """Per-atom neighbour index arrays (ASE's attribute)."""
        return self._split()[0]

    @property
    def displacements(self):
        """Per-atom offset arrays (ASE's attribute)."""
        return self._split()[1]


class PrimitiveNeighborList(_MLGPrimitive):
    """MLG version of ``ase.neighborlist.PrimitiveNeighborList``.

    Parameters
    ----------
    cutoffs : list of float
        Radius of each atom; atoms are neighbours when their spheres (of
        radius ``cutoff + skin``) overlap.
    skin : float
        The list is rebuilt when an atom has moved more than ``skin`` since
        the last build (or pbc/cell/number of atoms changed).
    sorted : bool
        Sort each atom's neighbours by index, then offsets.
    self_interaction : bool
        Include each atom as its own neighbour (offset 0).
    bothways : bool
        Full list; otherwise each pair once (ASE's half).
    use_scaled_positions : bool
        Coordinates given to ``update`` are scaled.
    """

    _ase_half = "old"


class NewPrimitiveNeighborList(_MLGPrimitive):
    """MLG version of ``ase.neighborlist.NewPrimitiveNeighborList`` (same
    parameters as :class:`PrimitiveNeighborList`; its ``bothways=False`` half
    keeps pairs with a positive cell shift, or zero shift and ``i <= j``)."""

    _ase_half = "new"


class NeighborList:
    """MLG drop-in for ``ase.neighborlist.NeighborList``.

    Parameters
    ----------
    cutoffs : list of float
        Radius of each atom (see :func:`ase.neighborlist.natural_cutoffs`).
    skin : float
        Verlet skin: the list is reused until an atom moves more than
        ``skin`` (radii are enlarged by ``skin``, as in ASE).
    sorted, self_interaction, bothways : bool
        As in ASE.
    primitive : class
        :class:`PrimitiveNeighborList` (default) or
        :class:`NewPrimitiveNeighborList` (they differ only in which half
        ``bothways=False`` keeps), or any class with their interface.

    >>> nl = NeighborList([1.2] * len(atoms), self_interaction=False,
    ...                   bothways=True)                  # doctest: +SKIP
    >>> nl.update(atoms)                                  # doctest: +SKIP
    True
    >>> indices, offsets = nl.get_neighbors(0)            # doctest: +SKIP
    """

    def __init__(self, cutoffs, skin=0.3, sorted=False, self_interaction=True,
                 bothways=False, primitive=PrimitiveNeighborList):
        self.nl = primitive(cutoffs, skin, sorted,
                            self_interaction=self_interaction,
                            bothways=bothways)
        self._checked = None  # (cell, pbc, completed cell) last checked by Box

    def update(self, atoms):
        """Bring the list up to date with ``atoms``; True if it was rebuilt."""
        cell, pbc = atoms.cell.array, atoms.pbc
        last = self._checked
        if last is None or not (same(cell, last[0]) and same(pbc, last[1])):
            # ValueError on a zero-volume periodic cell; checked, and the
            # cell completed as ASE's get_cell(complete=True), once per cell
            # (it was 70% of an update with nothing moved)
            Box(cell, pbc)
            last = self._checked = (cell.copy(), pbc.copy(),
                                    atoms.get_cell(complete=True).array)
        return self.nl.update(pbc, last[2], atoms.positions)

    def get_neighbors(self, a):
        """(indices, offsets) of the neighbours of atom ``a``."""
        if self.nl.nupdates <= 0:
            raise RuntimeError('Must call update(atoms) on your neighborlist '
                               'first!')
        return self.nl.get_neighbors(a)

    def get_connectivity_matrix(self, sparse=True):
        """(N, N) int8 matrix with 1 where j is a neighbour of i (scipy
        ``dok_matrix`` if ``sparse``, else a dense array), as
        ``ase.neighborlist.get_connectivity_matrix``."""
        return get_connectivity_matrix(self.nl, sparse)

    @property
    def nupdates(self):
        """Number of list builds."""
        return self.nl.nupdates

    @property
    def nneighbors(self):
        """Number of neighbours (ASE's deprecated property)."""
        import warnings
        warnings.warn('Use, e.g., `sum(_.size for _ in nl.neighbors)` for '
                      '`bothways=False` and `self_interaction=False`.',
                      FutureWarning, stacklevel=2)
        nneighbors = sum(indices.size for indices in self.nl.neighbors)
        if self.nl.self_interaction:
            nneighbors -= len(self.nl.neighbors)
        return nneighbors // 2 if self.nl.bothways else nneighbors

    @property
    def npbcneighbors(self):
        """Number of neighbours across periodic faces (ASE's deprecated
        property)."""
        import warnings
        warnings.warn('Use, e.g., `sum(_.any(1).sum() for _ in '
                      'nl.displacements)` for `bothways=False` and '
                      '`self_interaction=False`.', FutureWarning, stacklevel=2)
        nneighbors = sum(offsets.any(axis=1).sum()
                         for offsets in self.nl.displacements)
        return nneighbors // 2 if self.nl.bothways else nneighbors


# --------------------------------------------------------------------------
# functions on lists
# --------------------------------------------------------------------------

def get_connectivity_matrix(nl, sparse=True):
    """(N, N) int8 matrix with 1 where j is a neighbour of i, as
    ``ase.neighborlist.get_connectivity_matrix``: a scipy ``dok_matrix`` if
    ``sparse``, else a dense array; symmetric only for ``bothways=True``.

    ``nl`` is a primitive list (``NeighborList.nl``, as in ASE) or, here
    also, a :class:`NeighborList`; foreign primitives with ASE's interface
    (``cutoffs``, ``nupdates``, ``get_neighbors``) work too.
    """
    if isinstance(nl, NeighborList):
        nl = nl.nl
    for attr in ("cutoffs", "nupdates", "get_neighbors"):
        if not hasattr(nl, attr):
            raise TypeError(f"nl: expected a neighbour list, got "
                            f"{type(nl).__name__} (no {attr!r})")
    if nl.nupdates <= 0:
        raise RuntimeError('Must call update(atoms) on your neighborlist '
                           'first!')
    n = len(nl.cutoffs)
    if hasattr(nl, "pair_first"):
        i, j = nl.pair_first, nl.pair_second
    else:  # a foreign primitive: ask it atom by atom
        parts = [np.asarray(nl.get_neighbors(a)[0], dtype=int)
                 for a in range(n)]
        i = np.repeat(np.arange(n), [len(p) for p in parts])
        j = np.concatenate(parts) if parts else np.empty(0, int)
    if sparse:
        key = np.unique(np.asarray(i, np.int64) * max(n, 1) + j)
        ii, jj = np.divmod(key, max(n, 1))
        m = _sp.coo_matrix((np.ones(len(key), np.int8), (ii, jj)),
                           shape=(n, n), dtype=np.int8)
        return m.todok()
    matrix = np.zeros((n, n), dtype=np.int8)
    matrix[i, j] = 1
    return matrix


def build_neighbor_list(atoms, cutoffs=None, **kwargs):
    """A :class:`NeighborList` (ours) for ``atoms``, already updated, as
    ``ase.neighborlist.build_neighbor_list``.

    ``cutoffs``: per-atom radii; default :func:`natural_cutoffs` (covalent
    radii).  ``kwargs`` go to :class:`NeighborList` (``skin``, ``sorted``,
    ``self_interaction``, ``bothways``, ``primitive``).
    """
    if cutoffs is None:
        cutoffs = natural_cutoffs(atoms)
    nl = NeighborList(cutoffs, **kwargs)
    nl.update(atoms)
    return nl
