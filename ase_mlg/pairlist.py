"""The half pair list in grid order, and the arrays it gives.

A :class:`PairList` is what the exact query (:mod:`ase_mlg.query`) and
Boris's template (:mod:`ase_mlg.template`, through
:func:`ase_mlg.query.pair_list`) produce: each unordered pair once, in
compressed sparse rows, with atoms numbered by their *rank* along the
grid's blocks (5 bytes a pair: an int32 neighbour rank and a one-byte image
code).  Its consumers read it directly: the pair kernel (:mod:`ase_mlg.pairsum`,
called by :mod:`ase_mlg.potentials`) sums over the rows, and
:meth:`PairList.arrays` writes ``ase.neighborlist``'s arrays
(docs/design.md §6): a half list in the grid's orientation, a full list,
or a half list oriented by a rule on the cell shifts (ASE's two halves).
"""

import functools
from collections import namedtuple

import numba
import numpy as np
from numba import prange
from numba.core import types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from .jit import njit
from .parallel import (dynamic_schedule, run_chunks, serial_and_parallel, threads_for,
                       use_threads)

__all__ = ["PairList", "ListArrays", "PairOutput", "Orientation", "pair_vector",
           "ase_vector", "put_pair", "shift_codes"]

NGROUP = 8  # row groups of full lists: fixed, so the output never depends on threads

#: The arrays of a :class:`PairList`, as its kernels read them (the
#: attributes of the same names; ``zero_code`` an int).  The image codes go
#: beside it as an argument of their own: their dtype (uint8 or int32)
#: depends on the number of images, and numba 0.59 dispatches a namedtuple
#: of four or more fields whose field types vary between calls to the wrong
#: overload (tests/test_kernel_structures.py keeps every structure to one type).
ListArrays = namedtuple("ListArrays", "rowptr nbr zero_code shifts images order")

#: The output arrays of :meth:`PairList.arrays` (``out_i`` int64[M], ``out_j``
#: int64[M], ``out_d`` float64[M], ``out_D`` float64[M, 3], ``out_S``
#: int64[M, 3]; empty when not wanted) and which of them are written.
PairOutput = namedtuple("PairOutput",
                        "out_i out_j out_d out_D out_S want_j want_d want_D want_S")

#: The rule of an oriented half list: per-atom integer ``offsets`` (int64[N,
#: 3], atom order; (0, 3) for all zero) and an integer ``basis`` (int64[3,
#: 3]); see :meth:`PairList.arrays`.
Orientation = namedtuple("Orientation", "offsets basis")

# how _write_pairs writes the pairs of a row
_HALF, _FULL, _ORIENTED = 0, 1, 2


@njit(cache=True)
def ase_vector(pos, j, i, S0, S1, S2, cell):
    """``D = pos[j] - pos[i] + S @ cell`` (Å), in ASE's operation order, so
    that distances agree with ``ase.neighborlist`` to the last bit."""
    return ((pos[j, 0] - pos[i, 0]) + (S0 * cell[0, 0] + S1 * cell[1, 0] + S2 * cell[2, 0]),
            (pos[j, 1] - pos[i, 1]) + (S0 * cell[0, 1] + S1 * cell[1, 1] + S2 * cell[2, 1]),
            (pos[j, 2] - pos[i, 2]) + (S0 * cell[0, 2] + S1 * cell[1, 2] + S2 * cell[2, 2]))


class PairList:
    """A half pair list in grid order (compressed sparse rows).

    Atoms are numbered by *rank*: their order along the grid's blocks, so
    atoms close in space are close in memory whatever the input order.

    Attributes
    ----------
    order : int64[N]
        Atom index of each rank.
    rowptr : int64[N + 1]
        Pairs of rank ``t`` are ``rowptr[t]:rowptr[t + 1]``.
    nbr : int32[M]
        Rank of the second atom of each pair.
    code : uint8[M] or int32[M]
        Index of the pair's image in ``shifts``.
    shifts : int64[K, 3]
        Images m.  The pair's cell shift is ``S = m + images[u] -
        images[t]``: ``D = x[j] - x[i] + S @ cell``.
    images : int64[N, 3]
        Image of each rank that the grid keeps it in: ``x + images @ cell``
        are the positions the grid orders.  An atom that has travelled
        many cells changes these, never the (few) codes.
    zero_code : int
        Code of m = 0.
    """

    def __init__(self, order, rowptr, nbr, code, shifts, images, zero_code):
        self.chunk_counts = None  # pairs per scan chunk (sizes the next build)
        self._by_atom = None  # (rank, images) in atom order: the gather's
        self.order = order
        self.images = images
        self.rowptr = rowptr
        self.nbr = nbr
        self.code = code
        self.shifts = shifts
        self.zero_code = zero_code

    @classmethod
    def from_pairs(cls, order, images, i, j, S):
        """The list of a half list of atom pairs ``(i, j, S)`` (each
        unordered pair once, ``D = x[j] - x[i] + S @ cell``), rows in
        ``order`` (the atom of each rank) with each rank kept in its
        ``images``; each row keeps its pairs in the given order."""
        n = len(order)
        rank = np.empty(n, np.int64)
        rank[order] = np.arange(n)
        ri, rj = rank[i], rank[j]
        m = np.asarray(S, np.int64) - images[rj] + images[ri]
        slo = m.min(axis=0) if len(m) else np.zeros(3, np.int64)
        shi = m.max(axis=0) if len(m) else np.zeros(3, np.int64)
        slo, shi = np.minimum(slo, 0), np.maximum(shi, 0)
        sdim, shifts, dtype = shift_codes(slo, shi)
        mcode = ((m[:, 0] - slo[0]) * sdim[1] + m[:, 1] - slo[1]) * sdim[2] + m[:, 2] - slo[2]
        zero_code = int(((0 - slo[0]) * sdim[1] - slo[1]) * sdim[2] - slo[2])
        nbr = np.empty(len(ri), np.int32)
        code = np.empty(len(ri), dtype)
        rowptr = np.zeros(n + 1, np.int64)
        if len(ri) < 2 or (ri[1:] >= ri[:-1]).all():
            # already in rows: no sort, and no sort kernel to compile
            np.cumsum(np.bincount(ri, minlength=n), out=rowptr[1:])
            nbr[:] = rj
            code[:] = mcode
        else:
            _rows_from_pairs(ri, rj, mcode, n, nbr, code, rowptr)
        return cls(order, rowptr, nbr, code, shifts, images, zero_code)

    def __len__(self):
        return int(self.rowptr[-1])

    @property
    def natoms(self):
        return len(self.order)

    @property
    def images(self):
        """int64[N, 3], rank order (see the class doc).  Once the gather
        holds them in atom order, the rank-order copy is dropped and
        remade from that one on request (23 MB at 10^6 atoms)."""
        if self._images is None and self._by_atom is not None:
            self._images = np.ascontiguousarray(self._by_atom[1][self.order], dtype=np.int64)
        return self._images

    @images.setter
    def images(self, images):
        self._images = images

    def drop_atom_arrays(self):
        """Free the per-atom arrays (the images, the gather's ranks and
        images), keeping the pair arrays that the next scan takes over
        (:func:`ase_mlg.query.half_list`'s ``reuse``): before a rebuild's
        block index comes, not after (53 MB of its peak at 10^6 atoms)."""
        self._images = self._by_atom = None

    @property
    def list_arrays(self):
        """The list's arrays but the codes as one :data:`ListArrays` (the
        arrays themselves, not copies), as the kernels take them."""
        return ListArrays(self.rowptr, self.nbr, self.zero_code,
                          self.shifts, self.images, self.order)

    def positions(self, positions, cell):
        """Positions in row order, each in the image the grid keeps it in
        (``x[order] + images @ cell``): the ``X`` of the pair kernel, Å."""
        return self.gather_check(positions, cell)[0]

    def gather_check(self, positions, cell, ref=None, M=None, out=None):
        """``(X, umax)``: :meth:`positions`, and in the same pass the
        largest displacement beyond the affine cell map ``M`` (None: the
        cell has not changed) since ``ref`` (the positions in atom order
        when the list was built), Å; NaN if any position is NaN; 0 without
        ``ref``.  The gather and the list-validity test share one pass over
        the positions (a force call makes others: docs/design.md §6).
        ``out``: an (N, 3) float64 C array to write ``X`` into (returned)."""
        n = len(self.order)
        X = out if out is not None and out.shape == (n, 3) else np.empty((n, 3))
        cell = np.ascontiguousarray(cell, dtype=np.float64)
        if ref is None:
            ref = _NO_REF
        affine = M is not None
        if not affine:
            M = _EYE
        if self._by_atom is None:  # each atom's rank and image, atom order
            self._by_atom = _by_atom(self.order, self.images)
            self._images = None  # remade from these where asked for
        rank, images = self._by_atom
        if use_threads("atoms", n):
            worst = np.empty(4 * threads_for("atoms", n))
            with dynamic_schedule():
                _gather_threaded(positions, rank, images, cell, ref, M, affine, X, worst)
        else:
            worst = np.empty(1)
            _gather_serial(positions, rank, images, cell, ref, M, affine, X, worst)
        if len(worst) == 1:  # the serial gather: one number, no numpy passes
            w = float(worst[0])
            return X, (w if w != w else max(w, 0.0))
        umax = np.nan if np.isnan(worst).any() else float(worst.max(initial=0.0))
        return X, umax

    def inner_first(self, X, svec, radius):
        """Reorder every row so that its pairs within ``radius`` (Å) at
        positions ``X`` (row order, see :meth:`positions`) come first, in
        place.  The pair loop tests each pair against the cutoff; with the
        pairs inside it first that branch is predicted (measured: the LJ
        sum 32% faster on 10^4 atoms).  The list stays the same set."""
        n = len(self.order)
        part = _inner_first_threaded if use_threads("atoms", n) else _inner_first_serial
        part(self.rowptr, self.nbr, self.code, X, svec, radius * radius,
             min(max(n, 1), 64))

    def arrays(self, positions, cell, half=False, quantities="ijdDS", orient=None):
        """The list as ``ase.neighborlist`` returns it.

        Parameters
        ----------
        positions : (N, 3) float64
            The positions the list was built for, in atom order (Å).
        cell : (3, 3) float64
            The cell the shifts refer to (Å).
        half : bool
            Each unordered pair once, in grid order, in the grid's
            orientation; otherwise at both atoms (the mirror is ``(j, i, -D,
            d, -S)``, bitwise what ASE computes for it), sorted by ``i`` and
            within one ``i`` in grid order.  Not read with ``orient``.
        quantities : str
            Which of 'jdDS' to fill ('i' is always returned).
        orient : (offsets, basis), optional
            Each unordered pair once, oriented by a rule: ``offsets``
            int64[N, 3] per atom (atom order; None for all zero) and
            ``basis`` int64[3, 3].  A pair is written as ``(i, j, D, d, S)``
            where ``n = (S + offsets[i] - offsets[j]) @ basis`` is
            lexicographically positive (``n[0] > 0``, or ``n[0] == 0 and
            n[1] > 0``, or ``n[0] == n[1] == 0 and n[2] > 0``) or ``n == 0
            and i <= j``, else as its mirror; sorted by ``i`` as the full
            list, so that the result is, element for element and in order,
            the full list filtered by that rule.  ``offsets`` 0 and the
            identity are ``ase.neighborlist.NewPrimitiveNeighborList``'s
            half; the integer wrap offsets into the Minkowski-reduced cell
            and ``rint(inv(op))`` of its operation ``op``,
            ``PrimitiveNeighborList``'s.  A self pair (i, i, S = 0) is
            written once.

        Returns
        -------
        dict with keys 'i' and those of 'jdDS' requested: int64 / float64
        arrays.  The same for any thread count: a fixed number of row
        groups, each with its own cursor per atom.
        """
        pl = self.list_arrays
        n = self.natoms
        if orient is not None:
            orient = _orientation(orient, n)
            mode = _ORIENTED
        else:
            orient = _NO_ORIENT
            mode = _HALF if half else _FULL
        want = {q: (q in quantities) for q in "jdDS"}
        nth = threads_for("atoms", n)
        X = np.empty((n, 3))
        ngroup = max(1, min(NGROUP, n))
        rows = np.linspace(0, n, ngroup + 1).astype(np.int64)
        run_chunks(_take_rows, lambda g: (positions, pl.order, rows[g], rows[g + 1], X),
                   ngroup, nth)
        if mode == _HALF:
            cur = np.zeros((ngroup, 0), np.int64)
            m = len(self)
        else:
            # every group of rows counts its pairs per rank in its own row of
            # the table, so each group gets its own cursor into every atom's
            # range of the output.  Cursors are indexed by rank, not atom: a
            # row's neighbours are near it in rank, so the cursor table is
            # read and written locally (by atom it was a random access per
            # pair with shuffled atoms).  An oriented half counts each pair
            # at the atom it is written at
            cur = np.zeros((ngroup, n), dtype=np.int64)
            if mode == _FULL:
                run_chunks(_count_full, lambda g: (pl, self.code, rows[g], rows[g + 1], cur[g]),
                           ngroup, nth)
            else:
                run_chunks(_count_oriented, lambda g: (pl, self.code, orient, rows[g],
                                                       rows[g + 1], cur[g]), ngroup, nth)
            start = np.zeros(n + 1, dtype=np.int64)
            run_chunks(_atom_totals, lambda g: (cur, pl.order, rows[g], rows[g + 1],
                                                start), ngroup, nth)
            np.cumsum(start, out=start)
            run_chunks(_cursor, lambda g: (cur, pl.order, start, rows[g], rows[g + 1]),
                       ngroup, nth)
            m = int(start[-1])
        res = {"i": np.empty(m, np.int64)}
        arr = {"j": _E_I, "d": _E_F, "D": _E_2, "S": _E_2I}
        for q, shape, dt in (("j", (m,), np.int64), ("d", (m,), np.float64),
                             ("D", (m, 3), np.float64), ("S", (m, 3), np.int64)):
            if want[q]:
                res[q] = arr[q] = np.empty(shape, dt)
        out = PairOutput(res["i"], arr["j"], arr["d"], arr["D"], arr["S"], want["j"],
                         want["d"], want["D"], want["S"])
        run_chunks(_write_pairs,
                   lambda g: (pl, self.code, X, cell, rows[g], rows[g + 1], mode, orient,
                              cur[g], out), ngroup, nth)
        return res


def _orientation(orient, n):
    """``orient`` of :meth:`PairList.arrays` as an :data:`Orientation` of
    contiguous int64 arrays, checked."""
    try:
        offsets, basis = orient
    except (TypeError, ValueError):
        raise ValueError(f"orient: expected (offsets, basis), got {orient!r}") from None
    if offsets is None:
        offsets = _E_2I
    else:
        offsets = np.asarray(offsets)
        if offsets.shape != (n, 3) or not (offsets.size == 0
                                           or np.issubdtype(offsets.dtype, np.integer)):
            raise ValueError(f"orient: offsets must be integers of shape ({n}, 3), got "
                             f"{offsets.dtype} {offsets.shape}")
        offsets = np.ascontiguousarray(offsets, dtype=np.int64)
    basis = np.asarray(basis)
    if basis.shape != (3, 3) or not np.issubdtype(basis.dtype, np.integer):
        raise ValueError(f"orient: basis must be integers of shape (3, 3), got "
                         f"{basis.dtype} {basis.shape}")
    return Orientation(offsets, np.ascontiguousarray(basis, dtype=np.int64))


@intrinsic
def flat(typingctx, a):
    """The 1-D view of a C-contiguous array, inside a kernel.

    What ``a.reshape(-1)`` gives, without numba's reshape: its
    implementation (shape inference and checks) compiled for 0.2-0.5 s on
    the first call of every fresh environment; this view compiles to a
    few stores.  The
    kernels index their (N, 3) arrays through it: numba indexes a 2-D
    array through its run-time row stride (a multiply per access), a flat
    view at a constant stride.
    """
    if not (isinstance(a, types.Array) and a.layout == "C"):
        return None
    ret = a.copy(ndim=1, layout="C")

    def codegen(context, builder, sig, args):
        src = make_array(a)(context, builder, value=args[0])
        dst = make_array(ret)(context, builder)
        populate_array(dst, data=src.data, shape=[src.nitems], strides=[src.itemsize],
                       itemsize=src.itemsize, meminfo=src.meminfo, parent=src.parent)
        return impl_ret_borrowed(context, builder, ret, dst._getvalue())
    return ret(a), codegen


def _gather_atoms(positions, rank, images, cell, ref, M, affine, X, worst):
    """Write ``X[rank[a]] = x[a] + images[a] @ cell`` (``images`` in atom
    order) and, when ``ref`` has rows, find how far each atom moved beyond
    the affine map ``M`` of the cell since ``ref`` (its positions then, atom
    order: ``x - ref @ M``, or ``x - ref`` without ``affine``, a cell that
    has not changed, as in NVE: the same bits, 64 -> 43 µs at 10,976 atoms
    on AMD Zen 4; the list's images cancel): ``worst`` gets the largest
    displacement of each of its chunks of atoms (Å), NaN if any is NaN.  A
    max does not depend on the chunking.
    The pass reads in atom order and scatters the writes: atoms in a random
    order (an ASE system after a long liquid run) made a gather in row
    order wait on memory, 39 against 6 ns an atom at 10^6 atoms."""
    n = rank.shape[0]
    nchunk = worst.shape[0]
    check = ref.shape[0] > 0
    # flat views, unsigned indices and the 3 x 3 matrices in registers: 2-D
    # indexing multiplies by the run-time row stride and wraps signed
    # indices, and a store to X could alias the matrices, which were then
    # read again for every atom (as in pairsum._pair_sum)
    U = numba.uint64
    x = flat(positions)
    im = flat(images)
    r = flat(ref)
    Xf = flat(X)
    c00, c01, c02 = cell[0, 0], cell[0, 1], cell[0, 2]
    c10, c11, c12 = cell[1, 0], cell[1, 1], cell[1, 2]
    c20, c21, c22 = cell[2, 0], cell[2, 1], cell[2, 2]
    M00, M01, M02 = M[0, 0], M[0, 1], M[0, 2]
    M10, M11, M12 = M[1, 0], M[1, 1], M[1, 2]
    M20, M21, M22 = M[2, 0], M[2, 1], M[2, 2]
    for ch in prange(nchunk):
        w = 0.0
        for a in range(U(ch * n // nchunk), U((ch + 1) * n // nchunk)):
            t = U(3) * U(rank[a])
            i = U(3) * a
            m0 = im[i]
            m1 = im[i + U(1)]
            m2 = im[i + U(2)]
            x0 = x[i]
            x1 = x[i + U(1)]
            x2 = x[i + U(2)]
            Xf[t] = x0 + (m0 * c00 + m1 * c10 + m2 * c20)
            Xf[t + U(1)] = x1 + (m0 * c01 + m1 * c11 + m2 * c21)
            Xf[t + U(2)] = x2 + (m0 * c02 + m1 * c12 + m2 * c22)
            if not check:
                continue
            r0 = r[i]
            r1 = r[i + U(1)]
            r2 = r[i + U(2)]
            if affine:
                d0 = x0 - (r0 * M00 + r1 * M10 + r2 * M20)
                d1 = x1 - (r0 * M01 + r1 * M11 + r2 * M21)
                d2 = x2 - (r0 * M02 + r1 * M12 + r2 * M22)
            else:
                d0 = x0 - r0
                d1 = x1 - r1
                d2 = x2 - r2
            s = d0 * d0
            s += d1 * d1
            s += d2 * d2
            if s > w:
                w = s
            elif not s == s:  # NaN: the list is never valid
                w = np.nan
        worst[ch] = np.sqrt(w)


_gather_serial, _gather_threaded = serial_and_parallel(_gather_atoms)


def _by_atom(order, images):
    """Each atom's rank and image in atom order, for the gather: int32
    where they fit (every list but one of 2^31 atoms, or of an atom 2^31
    cells out), so that the pair list's per-atom arrays at a rebuild's peak
    are 15 MB smaller at 10^6 atoms and a step's gather reads 16 bytes an
    atom fewer.  An integer image is exactly the same float64 either way."""
    n = len(order)
    kind = np.int32 if n < 2 ** 31 else np.int64
    rank = np.empty(n, kind)
    rank[order] = np.arange(n, dtype=kind)
    fits = images.size == 0 or (int(images.min()) > -2 ** 31 and int(images.max()) < 2 ** 31)
    by_atom = np.empty((n, 3), np.int32 if fits else np.int64)
    by_atom[order] = images
    return rank, by_atom
_NO_REF = np.zeros((0, 3))
_EYE = np.eye(3)


@njit(cache=True)
def pair_vector(X, svec, t, u, k):
    """``D = X[u] - X[t] + svec[k]`` of one list pair (Å), in ASE's
    operation order (``x[j] - x[i] + S @ cell``)."""
    return ((X[u, 0] - X[t, 0]) + svec[k, 0], (X[u, 1] - X[t, 1]) + svec[k, 1],
            (X[u, 2] - X[t, 2]) + svec[k, 2])


def _inner_first_rows(rowptr, nbr, code, X, svec, r2max, nchunk):
    n = rowptr.shape[0] - 1
    for ch in prange(nchunk):
        # one scratch per chunk of rows, not per row
        t0 = ch * n // nchunk
        t1 = (ch + 1) * n // nchunk
        longest = 0
        for t in range(t0, t1):
            longest = max(longest, rowptr[t + 1] - rowptr[t])
        out_j = np.empty(longest, nbr.dtype)
        out_c = np.empty(longest, code.dtype)
        for t in range(t0, t1):
            # stable: the pairs outside go to the scratch, then after
            nout = 0
            w = rowptr[t]
            for q in range(rowptr[t], rowptr[t + 1]):
                u = nbr[q]
                k = code[q]
                dx, dy, dz = pair_vector(X, svec, t, u, k)
                if dx * dx + dy * dy + dz * dz <= r2max:
                    nbr[w] = u
                    code[w] = k
                    w += 1
                else:
                    out_j[nout] = u
                    out_c[nout] = k
                    nout += 1
            for e in range(nout):
                nbr[w + e] = out_j[e]
                code[w + e] = out_c[e]


_inner_first_serial, _inner_first_threaded = serial_and_parallel(_inner_first_rows)


@njit(cache=True, nogil=True)
def _count_full(lists, code, r0, r1, cnt):
    """Pairs each rank gets from rows [r0, r1) of a half list written at
    both atoms (the mirror of a self pair (i, i, 0) is itself)."""
    rowptr = lists.rowptr
    nbr = lists.nbr
    zero_code = lists.zero_code
    for t in range(r0, r1):
        cnt[t] += rowptr[t + 1] - rowptr[t]
        for p in range(rowptr[t], rowptr[t + 1]):
            u = nbr[p]
            if not (u == t and code[p] == zero_code):
                cnt[u] += 1


@njit(cache=True)
def _pair_shift(shifts, images, k, t, u):
    """The cell shift ``S = m + images[u] - images[t]`` of a list pair."""
    return (shifts[k, 0] + images[u, 0] - images[t, 0],
            shifts[k, 1] + images[u, 1] - images[t, 1],
            shifts[k, 2] + images[u, 2] - images[t, 2])


@njit(cache=True)
def _oriented(offsets, basis, a, j, S0, S1, S2):
    """Which entries of the pair (a, j, S) an oriented half keeps:
    ``(a, j, S)`` itself when ``n = (S + offsets[a] - offsets[j]) @ basis``
    is lexicographically positive or n == 0 and a <= j; its mirror ``(j, a,
    -S)`` (whose n is -n) by the same rule.  One of the two unless n == 0
    and a == j (the self pair, with an invertible basis)."""
    e0 = S0
    e1 = S1
    e2 = S2
    if offsets.shape[0] > 0:
        e0 += offsets[a, 0] - offsets[j, 0]
        e1 += offsets[a, 1] - offsets[j, 1]
        e2 += offsets[a, 2] - offsets[j, 2]
    sign = 0
    for c in range(3):
        nc = e0 * basis[0, c] + e1 * basis[1, c] + e2 * basis[2, c]
        if nc != 0:
            sign = 1 if nc > 0 else -1
            break
    if sign == 0:
        return a <= j, j <= a
    return sign > 0, sign < 0


@njit(cache=True, nogil=True)
def _count_oriented(lists, code, orient, r0, r1, cnt):
    """Pairs each rank gets from rows [r0, r1) of the half list oriented by
    ``orient`` (see :func:`_oriented`): a pair kept as it is counts at its
    row, one kept as its mirror at its neighbour.  (A serial kernel: the
    fields are read where they are used.)"""
    order = lists.order
    for t in range(r0, r1):
        a = order[t]
        for p in range(lists.rowptr[t], lists.rowptr[t + 1]):
            u = lists.nbr[p]
            k = code[p]
            S0, S1, S2 = _pair_shift(lists.shifts, lists.images, k, t, u)
            direct, mirror = _oriented(orient.offsets, orient.basis, a, order[u],
                                       S0, S1, S2)
            if direct:
                cnt[t] += 1
            if mirror and not (u == t and k == lists.zero_code):
                cnt[u] += 1


@njit(cache=True, nogil=True)
def _take_rows(positions, order, r0, r1, X):
    """``X[t] = positions[order[t]]`` for ranks [r0, r1)."""
    for t in range(r0, r1):
        a = order[t]
        for c in range(3):
            X[t, c] = positions[a, c]


@njit(cache=True, nogil=True)
def _atom_totals(cnt, order, r0, r1, tot):
    """``tot[atom + 1]`` = pairs of the atom of each rank in [r0, r1), over
    all groups (an exclusive prefix sum then gives every atom's start)."""
    for t in range(r0, r1):
        s = 0
        for g in range(cnt.shape[0]):
            s += cnt[g, t]
        tot[order[t] + 1] = s


@njit(cache=True)
def put_pair(out, q, i, j, d, Dx, Dy, Dz, S0, S1, S2):
    """Entry ``q`` of the output: ``(i, j, d, D, S)``, the wanted ones
    (also the writer of :mod:`ase_mlg.allpairs`)."""
    out.out_i[q] = i
    if out.want_j:
        out.out_j[q] = j
    if out.want_d:
        out.out_d[q] = d
    if out.want_D:
        out_D = out.out_D
        out_D[q, 0] = Dx
        out_D[q, 1] = Dy
        out_D[q, 2] = Dz
    if out.want_S:
        out_S = out.out_S
        out_S[q, 0] = S0
        out_S[q, 1] = S1
        out_S[q, 2] = S2


@njit(cache=True, nogil=True)
def _write_pairs(lists, code, X, cell, r0, r1, mode, orient, cur, out):
    """Write the pairs of rows [r0, r1) with D, d, S computed as ASE does.

    ``mode`` _FULL: each pair at both atoms, at the cursors ``cur[rank]``;
    the mirror is ``(j, i, -D, d, -S)`` (bitwise what ASE computes for it:
    IEEE negation is exact).  _ORIENTED: each pair once, as it is at
    ``cur[t]`` or as its mirror at ``cur[u]``, as :func:`_oriented` says.
    _HALF: once, as it is, at ``rowptr[t]``.  ``out_i`` is written with each
    entry (not in a pass of its own: one more stream to lines the pair
    already writes)."""
    rowptr = lists.rowptr
    nbr = lists.nbr
    zero_code = lists.zero_code
    shifts = lists.shifts
    images = lists.images
    order = lists.order
    offsets = orient.offsets
    basis = orient.basis
    full = mode == _FULL
    oriented = mode == _ORIENTED
    for t in range(r0, r1):
        a = order[t]
        for p in range(rowptr[t], rowptr[t + 1]):
            u = nbr[p]
            j = order[u]
            k = code[p]
            S0, S1_, S2 = _pair_shift(shifts, images, k, t, u)
            Dx, Dy, Dz = ase_vector(X, u, t, S0, S1_, S2, cell)
            d = np.sqrt(Dx * Dx + Dy * Dy + Dz * Dz)
            direct = True
            mirror = full
            if oriented:
                direct, mirror = _oriented(offsets, basis, a, j, S0, S1_, S2)
            if direct:
                if full or oriented:
                    q = cur[t]
                    cur[t] = q + 1
                else:
                    q = p
                put_pair(out, q, a, j, d, Dx, Dy, Dz, S0, S1_, S2)
            if not mirror or (u == t and k == zero_code):
                continue
            q = cur[u]
            cur[u] = q + 1
            put_pair(out, q, j, a, d, -Dx, -Dy, -Dz, -S0, -S1_, -S2)


@njit(cache=True, nogil=True)
def _cursor(cur, order, start, r0, r1):
    """cur holds each group's pair counts per rank; for ranks [r0, r1) make
    it each group's first position in the atom's range of the output (the
    atom's start plus the counts of the groups before)."""
    for t in range(r0, r1):
        prev = start[order[t]]
        for g in range(cur.shape[0]):
            c = cur[g, t]
            cur[g, t] = prev
            prev += c


_E_I = np.empty(0, np.int64)
_E_F = np.empty(0)
_E_2 = np.empty((0, 3))
_E_2I = np.empty((0, 3), np.int64)
_NO_ORIENT = Orientation(_E_2I, np.eye(3, dtype=np.int64))


def shift_codes(slo, shi):
    """Code table for integer shifts in the box [slo, shi]: dims, the
    shift of every code, the code dtype (one byte when it fits).  Copies
    of a table kept per box (writable: numba compiles read-only arrays
    apart): a small system's rebuild made it anew each time, 27 µs of a
    0.8 ms rebuild of 256 argon atoms, against 2 for the copies."""
    sdim, shifts, dtype = _shift_codes(tuple(int(v) for v in slo),
                                       tuple(int(v) for v in shi))
    return sdim.copy(), shifts.copy(), dtype


@functools.lru_cache(maxsize=64)
def _shift_codes(slo, shi):
    sdim = np.array(shi, np.int64) - slo + 1
    k = np.indices(sdim).reshape(3, -1).T
    shifts = np.ascontiguousarray(k + slo, dtype=np.int64)
    dtype = np.uint8 if len(shifts) <= 256 else np.int32
    return sdim, shifts, dtype


@njit(cache=True)
def _rows_from_pairs(rank_i, rank_j, mcode, n, nbr, code, rowptr):
    """Counting sort of a half list by row (stable)."""
    for k in range(rank_i.shape[0]):
        rowptr[rank_i[k] + 1] += 1
    for t in range(n):
        rowptr[t + 1] += rowptr[t]
    cur = rowptr[:-1].copy()
    for k in range(rank_i.shape[0]):
        q = cur[rank_i[k]]
        cur[rank_i[k]] = q + 1
        nbr[q] = rank_j[k]
        code[q] = mcode[k]
