"""The Monotonic Logical Grid: construction, invariants, a read-only view.

N atoms live on the sites ``(i, j, k)`` of an ``(NX, NY, NZ)`` array so that
(Boris 1985, eq. 3.1)::

    X[i,j,k] <= X[i+1,j,k],  Y[i,j,k] <= Y[i,j+1,k],  Z[i,j,k] <= Z[i,j,k+1]

on the grid coordinates of :mod:`ase_mlg.geometry`.  Sites without an atom
are *holes*: they carry coordinates that respect the inequalities and never
interact.

Construction (docs/design.md §3) is one recursive split, parameterised by the rule
that picks the axis:

* ``method="kd"`` (default): split the site box along its longest logical
  axis at the middle index and send the matching fraction of atoms (by that
  coordinate) to each half.  Local quality does not degrade with N.
* ``method="sort"``: split z first until every box is one plane, then y,
  then x.  Proportional binary splits of a z-sorted set *are* Boris's sort
  construction (sort into NZ planes, each plane by y into rows, each row by
  x, Boris 1985 sec. III), so the seed's baseline costs no second kernel.

Holes are distributed proportionally (every split sends the same fraction of
sites and atoms each way) and sit at the centre of their leaf's region, which
lies between the split values, so the order holds for them too.

Maintenance (swap sweeps, the follow, the periodic seam) is in
:mod:`ase_mlg.sweeps`; Boris's template in :mod:`ase_mlg.template`.
"""

from collections import namedtuple

import numpy as np
from .jit import njit

from .geometry import Box, as_positions, cell_change, grid_shape, wrap_origins
from .parallel import run_chunks, threads_for, use_threads
from .sweeps import follow, is_monotone, sweep, take_positions

__all__ = ["MLG", "GridView"]

KD, SORT = 0, 1
_METHODS = {"kd": KD, "sort": SORT}

# MLG.renumber places a newcomer only within this many site spacings of its
# hole: the sweeps move an atom about a site a sweep, and a newcomer far off
# would run them into their cap and a rebuild after all
NEWCOMER_REACH = 3.0


# --------------------------------------------------------------------------
# construction
# --------------------------------------------------------------------------

@njit(cache=True)
def _select(perm, a0, a1, target, g, axis):
    """Reorder perm[a0:a1], and the rows of ``g`` (the atoms' coordinates in
    perm's order) with it, so that keys before ``target`` are <= keys from
    ``target`` on (nth-element, Hoare partition, median-of-three pivot:
    linear on average and safe with many equal keys).  The coordinates move
    with the atoms so that every pass reads them in sequence: reading them
    through perm (a gather at every comparison) made the construction of
    108,000 atoms 62-73 ms against 50-61 (one thread, interleaved)."""
    lo = a0
    hi = a1 - 1
    while hi > lo:
        mid = (lo + hi) // 2
        x, y, z = g[lo, axis], g[mid, axis], g[hi, axis]
        pivot = max(min(x, y), min(max(x, y), z))
        i = lo
        j = hi
        while i <= j:
            while g[i, axis] < pivot:
                i += 1
            while g[j, axis] > pivot:
                j -= 1
            if i <= j:
                t = perm[i]
                perm[i] = perm[j]
                perm[j] = t
                for c in range(3):
                    x = g[i, c]
                    g[i, c] = g[j, c]
                    g[j, c] = x
                i += 1
                j -= 1
        if target <= j:
            hi = j
        elif target >= i:
            lo = i
        else:
            break


# inlined at numba IR, the one exception to docs/design.md §8's rule: as a
# call (12 array arguments, 2 per site) it cost 18% of the serial build, and
# still 15% with LLVM left to inline it (108,000 atoms: 81-90 ms against
# 69-81, interleaved)
@njit(cache=True, nogil=True, inline="always")
def _split(g, perm, sites, coords, ny, nz, b, f, method, out_b, out_f, k):
    """One step of the recursive split (see module docstring) on the box
    ``b`` (site box: 6 ints, atom range perm[b[6]:b[7]]) with bounds ``f``
    (6 floats): a one-site box writes its site (atom or hole) and returns 0;
    a larger one reorders its atom range, writes its two halves at rows
    ``k`` (right) and ``k + 1`` (left) of ``out_b``/``out_f`` and returns 2.
    A box touches only its own sites and atom range, so boxes that do not
    nest can be split in any order, on any thread: the grid is the same."""
    l0 = b[3] - b[0]
    l1 = b[4] - b[1]
    l2 = b[5] - b[2]
    ns = l0 * l1 * l2
    a0, a1 = b[6], b[7]
    m = a1 - a0
    if ns == 1:
        s = (b[0] * ny + b[1]) * nz + b[2]
        if m == 1:
            sites[s] = perm[a0]
            for a in range(3):
                coords[s, a] = g[a0, a]
        else:  # a hole: the centre of its leaf's region
            for a in range(3):
                coords[s, a] = 0.5 * (f[a] + f[3 + a])
        return 0
    # pick the axis to split
    axis = 0
    if method == KD:
        best = -1.0
        for a in range(3):
            la = l0 if a == 0 else (l1 if a == 1 else l2)
            # longest logical axis; ties go to the larger physical extent
            key = la + 1e-9 * min(f[3 + a] - f[a], 1e8) / 1e8
            if la > 1 and key > best:
                best = key
                axis = a
    else:  # Boris's order: planes (z), then rows (y), then x
        axis = 2 if l2 > 1 else (1 if l1 > 1 else 0)
    la = l0 if axis == 0 else (l1 if axis == 1 else l2)
    c0 = b[axis]
    c1 = b[3 + axis]
    cmid = c0 + (c1 - c0) // 2
    nleft = ns // la * (cmid - c0)
    nright = ns - nleft
    ml = (m * nleft + ns // 2) // ns  # proportional share of atoms
    ml = max(m - nright, min(nleft, ml))
    lo, hi = f[axis], f[3 + axis]
    prop = lo + (hi - lo) * nleft / ns
    if 0 < ml < m:
        _select(perm, a0, a1, a0 + ml, g, axis)
        maxl = g[a0, axis]
        for t in range(a0 + 1, a0 + ml):
            maxl = max(maxl, g[t, axis])
        minr = g[a0 + ml, axis]
        for t in range(a0 + ml + 1, a1):
            minr = min(minr, g[t, axis])
        split = 0.5 * (maxl + minr)
        split = min(max(split, maxl), minr)  # guard rounding
    elif ml == 0 and m > 0:
        minr = g[a0, axis]
        for t in range(a0 + 1, a1):
            minr = min(minr, g[t, axis])
        split = min(prop, minr)
    elif ml == m and m > 0:
        maxl = g[a0, axis]
        for t in range(a0 + 1, a1):
            maxl = max(maxl, g[t, axis])
        split = max(prop, maxl)
    else:
        split = prop
    # right half, then left (element copies: a row assignment compiles
    # numba's shape-error formatting, seconds of a cold start)
    for h in range(2):
        for x in range(8):
            out_b[k + h, x] = b[x]
        for x in range(6):
            out_f[k + h, x] = f[x]
    out_b[k, axis] = cmid
    out_b[k, 6] = a0 + ml
    out_f[k, axis] = split
    out_b[k + 1, 3 + axis] = cmid
    out_b[k + 1, 7] = a0 + ml
    out_f[k + 1, 3 + axis] = split
    return 2


# What every split reads and writes: the atoms' grid coordinates (in the
# order of the atom permutation, reordered with it), the permutation, the flat ``sites`` and their
# ``coordinates`` it fills, the grid's ``ny``, ``nz`` and the axis rule.
_Construction = namedtuple("_Construction", "atom_coordinates perm sites coordinates "
                                            "ny nz method")


@njit(cache=True, nogil=True)
def _split_boxes(work, ib, fb, k0, k1, out_b, out_f, nchild):
    """Split boxes ``k0:k1`` of (ib, fb) once (``work``: a
    ``_Construction``): children of box k at rows 2k, 2k + 1 of (out_b,
    out_f), their number in ``nchild[k]``."""
    g, perm, sites, coords = work.atom_coordinates, work.perm, work.sites, work.coordinates
    ny, nz, method = work.ny, work.nz, work.method
    for k in range(k0, k1):
        nchild[k] = _split(g, perm, sites, coords, ny, nz, ib[k].copy(),
                           fb[k].copy(), method, out_b, out_f, 2 * k)


@njit(cache=True, nogil=True)
def _subtrees(work, ib, fb, k0, k1):
    """Split boxes ``k0:k1`` of (ib, fb) down to single sites (depth first,
    an explicit stack; ``work``: a ``_Construction``)."""
    g, perm, sites, coords = work.atom_coordinates, work.perm, work.sites, work.coordinates
    ny, nz, method = work.ny, work.nz, work.method
    cap = 256
    ibox = np.empty((cap, 8), dtype=np.int64)
    fbox = np.empty((cap, 6))
    # the box being split, copied out of the stack row its children
    # overwrite, into scratch: two .copy() a split (two allocations a site)
    # cost a further 20 % of the construction (108,000 atoms: 50 -> 40 ms)
    b = np.empty(8, dtype=np.int64)
    f = np.empty(6)
    for k in range(k0, k1):
        for x in range(8):  # element copies, as in _split
            ibox[0, x] = ib[k, x]
        for x in range(6):
            fbox[0, x] = fb[k, x]
        top = 1
        while top > 0:
            top -= 1
            if top + 2 > cap:
                raise RuntimeError("MLG construction stack overflow")
            for x in range(8):
                b[x] = ibox[top, x]
            for x in range(6):
                f[x] = fbox[top, x]
            top += _split(g, perm, sites, coords, ny, nz, b, f, method, ibox, fbox, top)


def _build(g, nx, ny, nz, lo0, hi0, method):
    """Recursive-split construction (see module docstring).

    Returns ``sites`` (flat, -1 for holes) and ``coords`` (flat sites x 3).
    On threads the first levels are split box by box, a level at a time,
    until there are 4 boxes a thread; then each box's subtree runs on its
    own (the boxes are disjoint: the grid does not depend on the threads).
    """
    n = g.shape[0]
    nsite = nx * ny * nz
    sites = np.full(nsite, -1, dtype=np.int64)
    coords = np.empty((nsite, 3))
    perm = np.arange(n)
    if nsite == 0:
        return sites, coords
    ib = np.array([[0, 0, 0, nx, ny, nz, 0, n]], dtype=np.int64)
    fb = np.ascontiguousarray(np.concatenate([lo0, hi0])[None, :], dtype=np.float64)
    nth = threads_for("atoms", n)
    # the coordinates in perm's order, reordered with it (see _select)
    work = _Construction(np.array(g, dtype=np.float64, order="C"), perm, sites, coords,
                         ny, nz, method)
    while nth > 1 and 0 < len(ib) < 4 * nth:
        out_b = np.empty((2 * len(ib), 8), dtype=np.int64)
        out_f = np.empty((2 * len(ib), 6))
        nchild = np.zeros(len(ib), dtype=np.int64)
        run_chunks(_split_boxes, lambda k: (work, ib, fb, k, k + 1, out_b, out_f, nchild),
                   len(ib), nth)
        keep = np.repeat(nchild == 2, 2)
        ib, fb = out_b[keep], out_f[keep]
    nbox = len(ib)
    if nbox:
        run_chunks(_subtrees, lambda k: (work, ib, fb, k, k + 1), nbox, nth)
    return sites, coords


# --------------------------------------------------------------------------
# the grid object
# --------------------------------------------------------------------------

# Periodic coordinates further than this many cells from the cell cannot be
# wrapped to better than ~2**36 * 2**-52 = 1.5e-5 of a cell; beyond it the exact
# query was measured to fail (MemoryError at 1e11 cells), so refuse clearly.
MAX_CELLS = 2.0 ** 36


def _check_fractional(frac, pbc):
    # whole-array tests first: a per-row reduction over 3 columns is ~30x
    # slower (1.4 ms at 10^5 atoms), and only needed to name the atoms
    if np.isfinite(frac).all() and not (
            pbc.any() and np.abs(frac[:, pbc]).max() > MAX_CELLS):
        return
    bad = ~np.isfinite(frac).all(axis=1)
    if pbc.any():
        bad |= (np.abs(frac[:, pbc]) > MAX_CELLS).any(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise ValueError(
            f"positions: atom(s) {idx[:10].tolist()}{' ...' if len(idx) > 10 else ''} "
            f"are more than 2**36 (7e10) cells from the cell (or overflow); they cannot "
            f"be wrapped without losing precision -- wrap them (atoms.wrap()) first")


def _int_arg(name, value, minimum):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer, float, np.floating)):
        raise TypeError(f"{name}: expected an int, got {value!r}")
    if not np.isfinite(value) or int(value) != value or value < minimum:
        raise ValueError(f"{name}: must be an int >= {minimum}, got {value!r}")
    return int(value)


GridView = namedtuple("GridView", "sites coordinates periods shape positions box")


def _read_only(a):
    v = a.view()
    v.flags.writeable = False
    return v


class MLG:
    """A Monotonic Logical Grid of atoms (Boris 1985).

    Parameters
    ----------
    positions : array_like, shape (N, 3)
        Cartesian positions (Å).  Any float dtype or memory layout; computed
        in float64.
    cell : array_like, shape (3, 3), optional
        Cell vectors as rows (Å).  May be zero on non-periodic axes.
    pbc : bool or 3 bools
        Periodic axes.  Only periodic axes wrap (coordinates and template).
    method : {"kd", "sort"}
        Construction: recursive median split (default) or Boris's sort.
    shape : 3 ints, optional
        Force the grid shape (``NX*NY*NZ >= N``); by default it follows the
        occupied extent and dimensionality of the atoms (docs/design.md §3).
    sweep_cap : int
        Maximum swap sweeps per update before falling back to a rebuild.
    monitor_every : int
        Updates between checks of line registration on periodic axes.
    max_phase_lag : float
        Rebuild when two lines of a periodic axis are out of register by more
        than this many site spacings.

    Attributes
    ----------
    shape : tuple (NX, NY, NZ)
    sites : int64 array (NX, NY, NZ)
        Atom index at each site, -1 for a hole.  Every atom appears once.
    positions : float64 array (N, 3)
        The positions the grid was last built or updated with (Å).
    box : :class:`ase_mlg.geometry.Box`
        Cell and pbc.
    stats : dict
        Cumulative ``updates``, ``sweeps``, ``swaps``, ``rebuilds`` and the
        ``last`` update's record.
    version : int
        Changes whenever the grid moves (every :meth:`update` and
        :meth:`rebuild`): what a list built on the grid compares.
    generation : int
        Changes whenever the order is constructed anew (construction,
        :meth:`rebuild`, a rebuild inside :meth:`update`), not when swap
        sweeps repair it.
    """

    def __init__(self, positions, cell=None, pbc=False, method="kd",
                 shape=None, sweep_cap=64, monitor_every=10,
                 max_phase_lag=1.5):
        if not isinstance(method, str) or method not in _METHODS:
            raise ValueError(f"method: expected 'kd' or 'sort', got {method!r}")
        sweep_cap = _int_arg("sweep_cap", sweep_cap, 1)
        monitor_every = _int_arg("monitor_every", monitor_every, 0)
        try:
            max_phase_lag = float(max_phase_lag)
        except (TypeError, ValueError):
            raise TypeError(f"max_phase_lag: expected a number, got {max_phase_lag!r}") from None
        if not max_phase_lag > 0:  # also NaN
            raise ValueError(f"max_phase_lag: must be > 0, got {max_phase_lag}")
        self.method = method
        self.box = Box(cell, pbc)
        self.sweep_cap = sweep_cap
        self.monitor_every = monitor_every
        self.max_phase_lag = max_phase_lag
        self._forced_shape = None if shape is None else tuple(int(s) for s in shape)
        self.stats = {"updates": 0, "sweeps": 0, "swaps": 0, "rebuilds": 0,
                      "last": None}
        self.version = self.generation = -1
        self._build(as_positions(positions))

    @classmethod
    def from_atoms(cls, atoms, **kwargs):
        """Grid of an ASE ``Atoms`` object (positions, cell, pbc)."""
        return cls(atoms.positions, atoms.cell.array, atoms.pbc, **kwargs)

    # -- construction -----------------------------------------------------
    def _grid_coordinates(self, positions):
        frac = self.box.fractional(positions)
        _check_fractional(frac, self.box.pbc)
        self._origin = wrap_origins(frac, self.box.pbc)
        for a in range(3):
            if self.box.pbc[a]:
                f = frac[:, a] - self._origin[a]
                frac[:, a] = f - np.floor(f) + self._origin[a]
        return np.ascontiguousarray(frac * self.box.heights)

    def _build(self, positions):
        n = len(positions)
        self.positions = positions.copy()
        self.natoms = n
        g = self._grid_coordinates(positions) if n else np.zeros((0, 3))
        pbc = self.box.pbc
        h = self.box.heights
        if n:
            # column by column: numpy's reduction over axis 0 of an (N, 3)
            # array is 25x slower (2.5 ms each at 10^5 atoms)
            lo = np.array([g[:, a].min() for a in range(3)])
            hi = np.array([g[:, a].max() for a in range(3)])
            extent = hi - lo
            for a in range(3):
                if pbc[a]:
                    # a periodic axis filled with atoms spans its whole period
                    if self._origin[a] == 0.0:
                        lo[a], hi[a] = 0.0, h[a]
                        extent[a] = h[a]
        else:
            lo = hi = extent = np.zeros(3)
        # a periodic axis with a vacuum gap is gridded over its occupied
        # extent, like an open axis
        filled = pbc & (self._origin == 0.0) if n else pbc
        shape = self._forced_shape or grid_shape(extent, filled, n)
        if np.prod(shape) < n or min(shape) < (1 if n else 0):
            raise ValueError(f"shape: {shape} has fewer sites than the {n} atoms")
        self.shape = tuple(int(s) for s in shape)
        self._periods = np.where(pbc, h, 0.0)
        sites, coords = _build(g, *self.shape, lo.astype(np.float64),
                               hi.astype(np.float64), _METHODS[self.method])
        self._sites = sites
        self._coords = coords
        self._since_monitor = 0
        self.version += 1
        self.generation += 1

    def rebuild(self, positions=None):
        """Construct the grid anew (O(N log N))."""
        pos = self.positions if positions is None else as_positions(positions)
        self._build(pos)
        self.stats["rebuilds"] += 1

    # -- public views -------------------------------------------------------
    def view(self):
        """Read-only views of the grid's own arrays (no copies), for the
        queries built on it.

        Returns
        -------
        GridView
            ``sites`` (int64, flat, atom at each site or -1), ``coordinates``
            (float64, (nsites, 3), the stored grid coordinates the order holds
            on, Å), ``periods`` (float64, 3, cell height on periodic axes,
            0 on open ones, Å), ``shape``, ``positions`` (Å) and ``box``.
        """
        return GridView(_read_only(self._sites), _read_only(self._coords),
                        _read_only(self._periods), self.shape,
                        _read_only(self.positions), self.box)

    @property
    def sites(self):
        return self._sites.reshape(self.shape)

    @property
    def nholes(self):
        return int(np.prod(self.shape)) - self.natoms

    def coordinates(self):
        """Grid coordinates of every site, shape ``(NX, NY, NZ, 3)`` (Å).

        These are the numbers the monotone order holds on (holes included):
        fractional coordinates times cell heights, continuous in time across
        periodic faces (see the module docstring)."""
        return self._coords.reshape(self.shape + (3,)).copy()

    def site_of_atom(self):
        """Flat site index of each atom (inverse of ``sites``)."""
        inv = np.empty(self.natoms, dtype=np.int64)
        occ = np.flatnonzero(self._sites >= 0)
        inv[self._sites[occ]] = occ
        return inv

    def is_monotone(self):
        """True when eq. 3.1 holds on every line (and the seam condition on
        periodic axes)."""
        if self._sites.size == 0:
            return True
        return is_monotone(self._coords, np.array(self.shape), self._periods)

    # -- maintenance ----------------------------------------------------------
    def update(self, positions, cell=None, pbc=None):
        """Follow the atoms to ``positions`` and restore the order by swap
        sweeps (O(N), Boris 1985 sec. III); rebuild if the sweep cap is hit
        or periodic lines have drifted out of register.

        Parameters
        ----------
        positions : array_like, shape (N, 3)
            New Cartesian positions (Å), N as at construction.
        cell : array_like, shape (3, 3) or (3,), optional
            New cell (NPT).  An affine change of the cell keeps the grid:
            every stored grid coordinate, periodic image offsets and holes
            included, is multiplied by ``h'_a / h_a`` (new over old cell
            height per axis, > 0), which keeps the order exactly (see
            :func:`ase_mlg.geometry.cell_change`); then the usual follow and
            sweeps.  The grid is rebuilt instead when a cell vector appears
            or vanishes, or the cell degenerates (``reason`` says which).
        pbc : bool or 3 bools, optional
            New periodic axes; a change rebuilds the grid.

        Returns
        -------
        dict
            ``sweeps`` (sweeps that swapped), ``swaps``, ``rebuilt`` (bool)
            and ``reason`` (None, "sweep cap", "phase lag", "pbc changed",
            "cell rank changed", "cell completion changed" or "cell
            degenerate").  Also added to ``stats``.

        Raises
        ------
        ValueError
            If N differs from the grid's (build a new grid), a position is
            not finite or too far from the cell, or the new cell has no
            volume on a periodic axis.
        """
        # the common case (a float64 C array) skips as_positions' numpy
        # passes: the copy kernel below checks finiteness in parallel
        if not (type(positions) is np.ndarray and positions.dtype == np.float64
                and positions.ndim == 2 and positions.shape[1] == 3
                and positions.flags.c_contiguous):
            positions = as_positions(positions)
        if len(positions) != self.natoms:
            raise ValueError(f"positions: grid holds {self.natoms} atoms, got "
                             f"{len(positions)}; build a new grid (or call rebuild)")
        box, reason, scale = self.box, None, None
        if cell is not None or pbc is not None:
            box = Box(self.box.cell if cell is None else cell,
                      self.box.pbc if pbc is None else pbc)
            if box.same_as(self.box):
                box = self.box
            else:
                reason, scale = cell_change(self.box, box)
        periods = np.where(box.pbc, box.heights, 0.0)
        # validate against the new cell before any state changes, so a bad
        # call leaves the grid as it was
        pos = np.empty((self.natoms, 3))
        par = use_threads("sites", self._sites.size)
        if take_positions(positions, pos, box.inverse, periods, MAX_CELLS, par):
            as_positions(positions)  # raises the NaN/inf error
            _check_fractional(box.fractional(positions), box.pbc)
            raise ValueError("positions: non-finite fractional coordinates")
        self.positions = pos
        rec = {"sweeps": 0, "swaps": 0, "rebuilt": False, "reason": None}
        if reason is not None:
            self.box = box
            self.rebuild(pos)
            rec["rebuilt"], rec["reason"] = True, reason
        elif self.natoms:
            if box is not self.box:
                self.box = box
                self._periods = periods
            if scale is None:
                scale = np.ones(3)
            follow(self._sites, self._coords, pos, box.inverse, box.heights,
                   self._periods, scale, par)
            sweeps, swaps, ok = sweep(self._sites, self._coords,
                                      np.array(self.shape), self._periods,
                                      self.sweep_cap)
            rec["sweeps"], rec["swaps"] = int(sweeps), int(swaps)
            if not ok:
                rec["rebuilt"], rec["reason"] = True, "sweep cap"
            elif self.box.pbc.any() and self.monitor_every > 0:
                self._since_monitor += 1
                if self._since_monitor >= self.monitor_every:
                    self._since_monitor = 0
                    if self.phase_lag() > self.max_phase_lag:
                        rec["rebuilt"], rec["reason"] = True, "phase lag"
            if rec["rebuilt"]:
                self.rebuild(pos)
        else:
            self.box = box
            self._periods = periods
        if not rec["rebuilt"]:
            self.version += 1  # a rebuild counted it
        st = self.stats
        st["updates"] += 1
        st["sweeps"] += rec["sweeps"]
        st["swaps"] += rec["swaps"]
        st["last"] = rec
        return rec

    def renumber(self, new_of_old, positions, cell=None, pbc=None):
        """Carry the grid over to another set of atoms that shares most of
        its atoms with this one (a rank's local system after migration and
        new ghosts, docs/design.md §11), then :meth:`update` it there.

        The atoms kept take their new numbers in their sites; the sites of
        the atoms gone become holes; each newcomer takes a hole near it in
        grid space (a hole's stored coordinate is where its last atom was),
        and the update's follow and sweeps restore the order (Boris 1985
        §III).  A new grid for a rank of 5.8e5 argon atoms cost 0.42 s
        against 0.06 s for an update.

        Parameters
        ----------
        new_of_old : (natoms,) int array
            Each atom's index among ``positions``, or -1 where it is gone;
            every index at most once.
        positions : (N', 3) float64
            The new atoms' positions (Å).
        cell, pbc : optional
            As in :meth:`update`.

        Returns
        -------
        dict or None
            :meth:`update`'s record, or None (the grid unchanged) where the
            holes are fewer than the newcomers or one would sit farther
            than ``NEWCOMER_REACH`` site spacings from its hole: the caller
            then builds a new grid.
        """
        new_of_old = np.asarray(new_of_old, dtype=np.int64)
        positions = as_positions(positions)
        n = len(positions)
        if new_of_old.shape != (self.natoms,) or (new_of_old >= n).any():
            raise ValueError(f"new_of_old: expected {self.natoms} indices below {n}")
        sites = np.where(self._sites >= 0, new_of_old[np.maximum(self._sites, 0)], -1)
        taken = np.zeros(n, dtype=bool)
        taken[sites[sites >= 0]] = True
        if np.count_nonzero(taken) != np.count_nonzero(sites >= 0):
            raise ValueError("new_of_old: an index appears more than once")
        newcomers = np.flatnonzero(~taken)
        holes = np.flatnonzero(sites < 0)
        if len(newcomers) > len(holes) or not np.isfinite(positions[newcomers]).all():
            return None
        if len(newcomers):
            box = self.box if cell is None and pbc is None else Box(
                self.box.cell if cell is None else cell, self.box.pbc if pbc is None else pbc)
            if not box.same_as(self.box):
                return None  # a new cell with new atoms: no common frame to place them
            g = (positions[newcomers] @ self.box.inverse) * self.box.heights
            hc = self._coords[holes].copy()
            periods = self._periods
            for a in range(3):  # the tree's torus on periodic axes
                if periods[a] > 0:
                    g[:, a] %= periods[a]
                    hc[:, a] %= periods[a]
                    # a float a hair below the period may round up to it
                    g[g[:, a] >= periods[a], a] = 0.0
                    hc[hc[:, a] >= periods[a], a] = 0.0
            occupied = self._coords[self._sites >= 0]
            span = occupied.max(axis=0) - occupied.min(axis=0) if len(occupied) else np.zeros(3)
            span = np.where(periods > 0, periods, span)
            volume = np.prod(span[span > 0]) if (span > 0).any() else 0.0
            spacing = (volume / max(self._sites.size, 1)) ** (1.0 / max((span > 0).sum(), 1))
            from scipy.spatial import cKDTree  # here: 0.1 s of import a process skips
            k = min(8, len(holes))
            dist, near = cKDTree(hc, boxsize=periods).query(g, k=k)
            dist, near = dist.reshape(len(g), k), near.reshape(len(g), k)
            used = np.zeros(len(holes), dtype=bool)
            reach = NEWCOMER_REACH * spacing
            for q in range(len(newcomers)):
                for c in range(k):
                    h = near[q, c]
                    if not used[h]:
                        break
                else:
                    return None
                if not dist[q, c] <= reach:
                    return None
                used[h] = True
                sites[holes[h]] = newcomers[q]
        self._sites = sites
        self.natoms = n
        self.positions = positions.copy()  # update() replaces it
        return self.update(positions, cell, pbc)

    def phase_lag(self):
        """Largest misregistration between adjacent lines of a periodic
        axis, in site spacings.

        A line's phase is the mean offset of its stored coordinates from the
        evenly spaced positions ``(i + 1/2) L / n``; seam swaps preserve it,
        so it follows the line's centre of mass (docs/design.md §5).  Adjacent lines
        whose phases differ by p spacings pair site i with site i - p.
        """
        c = self._coords.reshape(self.shape + (3,))
        worst = 0.0
        for a in range(3):
            n = self.shape[a]
            if not self.box.pbc[a] or n < 2:
                continue
            spacing = self._periods[a] / n
            ideal = (np.arange(n) + 0.5) * spacing
            x = np.moveaxis(c[..., a], a, -1) - ideal
            phase = x.mean(axis=-1) / spacing  # (lines over the other two axes)
            for ax in range(2):
                if phase.shape[ax] > 1:
                    worst = max(worst, float(np.abs(np.diff(phase, axis=ax)).max()))
        return worst

    def __repr__(self):
        return (f"MLG(natoms={self.natoms}, shape={self.shape}, holes={self.nholes}, "
                f"method={self.method!r}, pbc={self.box.pbc.tolist()})")
