"""The pair kernel: one fused pass over a :class:`~ase_mlg.pairlist.PairList`.

The kernel walks the rows of the half list in grid order, each row in
batches of three short loops: ``D = X[u] - X[t] + S @ cell`` gathered in
ASE's operation order, the pair function (inlined) over the batch where
LLVM vectorises it, then energy, forces and, when asked, per-atom energies
and virials accumulated.  Threads follow :mod:`ase_mlg.parallel`
and :mod:`ase_mlg.chunks`: chunks of rows with equal pair counts handed
out one at a time, a force buffer per chunk covering only the window of
ranks the chunk touches, windows summed per rank in chunk order, so the
same chunks give the same bits whichever thread ran which chunk, and the
serial twin running them in chunk order gives them too; the chunks are the
list's (:func:`ase_mlg.chunks.row_chunks`), not the thread count's, so
results do not depend on it (docs/design.md §8).

The module's vocabulary
-----------------------
The kernel takes four structures and the pairs' image codes; it unpacks the
structures by position before its ``prange`` loops (which numba's parallel
lowering needs), so it takes them named or as plain tuples, which numba
dispatches faster (what :meth:`ase_mlg.potentials.PairPotential.sum_pairs`
passes):

* :class:`SumList` -- the half list and the positions in row order (the
  codes, whose dtype varies, beside it);
* :class:`SumTables` -- the potential's tables and what to accumulate;
* :class:`ase_mlg.chunks.Chunks` -- the chunks of rows and their windows;
* :class:`SumOutputs` -- the chunk buffers and the per-atom outputs.

:func:`pair_kernel` returns the kernel for a pair function, serial or
threaded: copies of one kernel's code, each with its pair function inlined,
cached on disk for the built-in pair functions (:func:`is_built_in`) and
compiled once per process for a user's.  A kernel flags bad pairs without naming them
(no per-pair branch in the loop); :func:`first_bad_pair` then finds the
first one and says why with a :class:`PairError` code.
"""

import enum
import math
from collections import namedtuple
from types import FunctionType

import numba
import numpy as np
from numba import prange

from .jit import njit
from .pairfunctions import lennard_jones_shifted_r2, lennard_jones_smooth_r2, morse
from .pairlist import flat, pair_vector
from .parallel import serial_and_parallel, use_threads

__all__ = ["SumList", "SumTables", "SumOutputs", "PairError",
           "pair_kernel", "is_built_in", "built_in_form", "first_bad_pair", "bad_pair_error",
           "pair_geometry",
           "shift_vectors", "pair_vectors"]


class PairError(enum.IntEnum):
    """Why :func:`first_bad_pair` flagged a pair.  The kernels return codes,
    and the Python side writes the message, because a numba exception
    cannot carry the pair's indices and distance."""

    #: No bad pair.
    OK = 0
    #: Distance 0 or NaN (overlapping atoms, non-finite positions).
    BAD_DISTANCE = 1
    #: Closer than the species pair's ``rmin``.
    BELOW_RMIN = 2
    #: The pair function returned a non-finite energy or force.
    NON_FINITE = 3


#: The list side of a pair sum: ``X`` float64[N, 3] (positions in row
#: order, Å), ``types`` int32[N] (type index of each row), ``rowptr``
#: int64[N + 1], ``nbr`` int32[M] (the half list: pairs ``(t, nbr[q])`` for
#: ``q`` in ``rowptr[t]:rowptr[t + 1]``, ``D = X[nbr[q]] - X[t] +
#: svec[code[q]]``), ``svec`` float64[K, 3] (Cartesian cell shift of every
#: image code, Å), ``order`` int64[N] (the atom of each row).  The codes,
#: uint8[M] or int32[M], go beside it as an argument of their own: numba
#: 0.59 dispatches a namedtuple of four or more fields whose field types vary
#: between calls to the wrong overload (tests/test_kernel_structures.py
#: keeps every structure to one type).
SumList = namedtuple("SumList", "X types rowptr nbr svec order")

#: The potential side of a pair sum: ``squared`` (bool: the pair function
#: takes ``r**2`` and returns ``(e, dE/dr / r)``: no square root, one
#: division less, the built-in LJ), ``params`` float64[T, T, P], ``cut2``
#: float64[T, T] (squared cutoffs, Å²: pairs with ``d**2 > cut2`` are
#: skipped, ASE's LJ keeps ``d == rc``), ``rmin2`` float64[T, T] (squared
#: ``rmin``, Å²: closer pairs are errors), ``check_rmin`` (bool: count
#: pairs below ``rmin``), ``want_virial`` (bool: accumulate the virial;
#: per-atom virials need it too).
SumTables = namedtuple("SumTables",
                       "squared params cut2 rmin2 check_rmin want_virial")

#: What a pair sum writes: ``fbuf`` float64[E, 3], ``ebuf`` float64[E or 0],
#: ``vbuf`` float64[E or 0, 6] (the chunks' window buffers,
#: :meth:`ase_mlg.chunks.RowChunks.buffers`: zero-length ``ebuf`` /
#: ``vbuf`` when no per-atom energies / virials are wanted), ``part``
#: float64[C, 9] (per chunk: energy (eV), virial (6, eV), the sum of every
#: pair's ``dE/dr / r`` (not finite if any pair energy, force or distance
#: was bad) and the number of pairs below ``rmin``), ``forces``
#: float64[N, 3] eV/Å, ``energies`` float64[N or 0] eV, ``virials``
#: float64[N or 0, 6] eV (in atom order; virials are ``-D (x) dE/dD`` in
#: Voigt order xx, yy, zz, yz, xz, xy, half of each pair to each atom).
SumOutputs = namedtuple("SumOutputs",
                        "fbuf ebuf vbuf part forces energies virials")


# Not cached: it takes a user's pair function too; the kernels that call it
# carry it compiled in (LLVM inlines it there, and vectorises the loop;
# numba's IR inlining, inline='always', left the loop scalar)
@numba.njit(error_model='numpy')
def _terms(pair, squared, guard, p, cut, r2):
    """A pair's energy (eV) and ``dE/dr / r`` (eV/Å²) from the pair function
    ``pair`` (taking ``r**2`` if ``squared``) with parameters ``p``, at the
    squared distance ``r2`` (Å²); both 0 beyond the squared cutoff ``cut``
    (NaN is not beyond: the kernel's check flags it).  With ``guard`` the
    pair function is not called beyond the cutoff (one that may raise)."""
    beyond = r2 > cut
    if guard and beyond:
        return 0.0, 0.0
    if squared:
        e, s = pair(r2, p)
    else:
        r = math.sqrt(r2)
        e, dedr = pair(r, p)
        s = dedr / r
    return (0.0 if beyond else e), (0.0 if beyond else s)


def _pair_sum(lst, code, pot, chunks, out):
    """Energy, forces and virials of a half pair list, one fused pass.

    The source of every kernel: :func:`_kernel` compiles a copy of it for
    each pair function ``PAIR``, form ``SQUARED`` and ``GENERAL``, which
    the copy reads as constants (its globals), so the pair function is
    inlined into the loop and the branches on the two flags leave it.
    Rows are split into the chunks of
    ``chunks`` (about equal pair counts); each chunk accumulates into its
    own window of the buffers (``out.fbuf`` and ``out.ebuf``/``out.vbuf``
    when per-atom energies or virials are wanted): entry
    ``slot[c, r >> shift] + (r & mask)`` is rank ``r`` of chunk ``c``.  The
    windows are then summed per rank in chunk order and scattered to atom order
    (``forces[order[t]]``), so the result is the same on every run with the
    same chunks, whichever thread ran which chunk.

    Constants
    ---------
    PAIR : numba function ``(r, p) -> (e, dE/dr)``
        Or ``(r**2, p) -> (e, dE/dr / r)`` with ``SQUARED``.
    SQUARED : bool
        ``pot.squared`` as a constant: the branch leaves the loop (3 % of
        the loop on AMD Zen 4 with the per-pair row below).
    GENERAL : bool
        Whether the kernel reads the species tables (``lst.types`` into
        ``pot``'s tables), counts pairs below ``rmin`` (``pot.check_rmin``)
        and writes the virial and per-atom energies and virials (as
        ``pot.want_virial`` and the buffers' lengths ask).  A constant of
        each entry point: with False, the kernel of one species' forces and
        energy (an MD step without a barostat), numba prunes that code
        before typing it, so it neither compiles nor runs: on AMD Zen 4
        the kernel compiles in 2.26 s instead of 2.70, and runs 7.05
        against 7.5 ns a pair at 256 atoms, 7.5 against 8.0 at 10,976, the
        same bits.
    GUARD : bool
        Whether the pair function is called within the cutoff only (one
        compiled with numba's default error model, which raises on a
        division by zero); otherwise it is called on every pair up to the
        row's last one within the cutoff, and its results beyond it dropped.
    lst : SumList
    code : uint8[M] or int32[M]
        The image code of every pair.
    pot : SumTables
    chunks : ase_mlg.chunks.Chunks
        The chunks, their windows and the bins each covers; the kernel
        writes ``chunks.thread`` (the numba thread of each chunk).
    out : SumOutputs
        Written: every field (``part`` per chunk; :func:`first_bad_pair`
        then names a flagged pair).
    """
    # every field as a local: numba's parallel lowering cannot read a
    # tuple's fields inside prange.  By position, so that the structures can
    # come as plain tuples (PairPotential.sum_pairs): numba types a named
    # tuple's fields in Python at every call, 5.4 µs of dispatch against 2.3
    X, types, rowptr, nbr, svec, order = lst
    _, params, cut2, rmin2, check_rmin, want_virial = pot
    rows, slot, shift, offset, cover_ptr, cover, thread = chunks
    mask = (1 << shift) - 1
    fbuf, ebuf, vbuf, part, forces, energies, virials = out
    n = X.shape[0]
    nchunk = slot.shape[0]
    if GENERAL:
        want_e = ebuf.shape[0] > 0
        want_v = vbuf.shape[0] > 0
        want_w = want_virial
        typed = params.shape[0] > 1  # one species-agnostic row: no lookups
    else:
        want_e = want_v = want_w = typed = check_rmin = False
    # The pair loop reads and writes flat views with constant strides,
    # indexed by unsigned integers: numba indexes a 2-D array through its
    # run-time row stride (a multiply per access) and wraps every signed
    # index (a shift, a mask and an add per access).  Both cost the loop
    # 14% on an Intel Ice Lake (108,000 argon atoms, one thread: 47.8 ->
    # 41.3 ms), with the same bits.
    U = numba.uint64
    Xf = flat(X)
    sv = flat(svec)
    fb = flat(fbuf)
    vb = flat(vbuf)
    for c in prange(nchunk):
        thread[c] = numba.get_thread_id()
        base = offset[c]
        sl = slot[c]
        for e in range(3 * base, 3 * offset[c + 1]):
            fb[e] = 0.0
        if want_e:
            for e in range(base, offset[c + 1]):
                ebuf[e] = 0.0
        if want_v:
            for e in range(6 * base, 6 * offset[c + 1]):
                vb[e] = 0.0
        # Neumaier-compensated sum of row energies: 10^7 pair energies of
        # both signs would otherwise lose digits to rounding
        energy = 0.0
        comp = 0.0
        check = 0.0
        nlow = 0
        v0 = v1 = v2 = v3 = v4 = v5 = 0.0
        # a row's batch: pair vectors, squared distances, pair terms
        buf = np.empty((6, BATCH))
        bx = buf[0]
        by = buf[1]
        bz = buf[2]
        br = buf[3]
        be = buf[4]
        bs = buf[5]
        bt = np.empty(BATCH if typed else 0, np.int64)
        c2 = cut2[0, 0]
        for t in range(rows[c], rows[c + 1]):
            x0 = Xf[3 * t]
            x1 = Xf[3 * t + 1]
            x2 = Xf[3 * t + 2]
            lt = sl[t >> shift] + (t & mask)
            ta = types[t] if typed else 0
            ft0 = ft1 = ft2 = 0.0
            erow = 0.0
            # Each batch of a row in three loops (docs/design.md §6): the
            # pair vectors gathered; the pair function over contiguous
            # buffers, where LLVM vectorises it (LJ's divisions in vdivpd: a
            # call at 256 atoms 70 -> 48 µs, AMD Zen 4, the same bits); the
            # forces scattered.  The list puts each row's pairs within the
            # cutoff first (PairList.inner_first): the last two loops stop
            # after the last pair within it, and mask those before it that
            # are not.
            for a in range(rowptr[t], rowptr[t + 1], BATCH):
                m = min(BATCH, rowptr[t + 1] - a)
                last = 0
                for h in range(m):
                    q = U(a + h)
                    u = U(3) * U(nbr[q])
                    k = U(3) * U(code[q])
                    # as ASE: positions[j] - positions[i] + S @ cell
                    dx = (Xf[u] - x0) + sv[k]
                    dy = (Xf[u + U(1)] - x1) + sv[k + U(1)]
                    dz = (Xf[u + U(2)] - x2) + sv[k + U(2)]
                    bx[h] = dx
                    by[h] = dy
                    bz[h] = dz
                    r2 = dx * dx + dy * dy + dz * dz
                    br[h] = r2
                    if typed:
                        tb = types[nbr[q]]
                        bt[h] = tb
                        c2 = cut2[ta, tb]
                    # NaN is within: the check sum below flags it
                    last = last if r2 > c2 else h + 1
                # one species: its parameters' row read once, not in the
                # loop, where LLVM cannot tell it from the buffers written
                # and leaves the loop scalar
                if typed:
                    for h in range(last):
                        be[h], bs[h] = _terms(PAIR, SQUARED, GUARD, params[ta, bt[h]],
                                              cut2[ta, bt[h]], br[h])
                else:
                    p = params[0, 0]
                    for h in range(last):
                        be[h], bs[h] = _terms(PAIR, SQUARED, GUARD, p, c2, br[h])
                for h in range(last):
                    j = nbr[U(a + h)]
                    e = be[h]
                    s = bs[h]
                    dx = bx[h]
                    dy = by[h]
                    dz = bz[h]
                    erow += e
                    check += s  # r = 0 or NaN makes it non-finite
                    if check_rmin:
                        r2 = br[h]
                        tb = bt[h] if typed else 0
                        if not r2 > cut2[ta, tb] and r2 < rmin2[ta, tb]:
                            nlow += 1
                    fx = s * dx  # force on t; minus that on j
                    fy = s * dy
                    fz = s * dz
                    ft0 += fx
                    ft1 += fy
                    ft2 += fz
                    lu = U(sl[j >> shift] + (j & mask))
                    fb[U(3) * lu] -= fx
                    fb[U(3) * lu + U(1)] -= fy
                    fb[U(3) * lu + U(2)] -= fz
                    if want_e:
                        ebuf[lt] += 0.5 * e
                        ebuf[lu] += 0.5 * e
                    if not want_w:  # MD needs no virial: 10% of the loop
                        continue
                    # central forces give a symmetric virial: six components
                    w0 = fx * dx
                    w1 = fy * dy
                    w2 = fz * dz
                    w3 = fy * dz
                    w4 = fx * dz
                    w5 = fx * dy
                    v0 -= w0
                    v1 -= w1
                    v2 -= w2
                    v3 -= w3
                    v4 -= w4
                    v5 -= w5
                    if want_v:
                        for g in range(2):
                            b = U(6) * (U(lt) if g == 0 else lu)
                            vb[b] -= 0.5 * w0
                            vb[b + U(1)] -= 0.5 * w1
                            vb[b + U(2)] -= 0.5 * w2
                            vb[b + U(3)] -= 0.5 * w3
                            vb[b + U(4)] -= 0.5 * w4
                            vb[b + U(5)] -= 0.5 * w5
            fb[3 * lt] += ft0
            fb[3 * lt + 1] += ft1
            fb[3 * lt + 2] += ft2
            s = energy + erow
            if abs(energy) >= abs(erow):
                comp += (energy - s) + erow
            else:
                comp += (erow - s) + energy
            energy = s
        part[c, 0] = energy + comp
        part[c, 1] = v0
        part[c, 2] = v1
        part[c, 3] = v2
        part[c, 4] = v3
        part[c, 5] = v4
        part[c, 6] = v5
        part[c, 7] = check
        part[c, 8] = nlow
    # sum the windows touching each rank's bin in chunk order, back in atom
    # order; pieces of ranks, each walking the bins it crosses
    npiece = nchunk
    ff = flat(forces)
    for piece in prange(npiece):
        t0 = piece * n // npiece
        t1 = (piece + 1) * n // npiece
        for t in range(t0, t1):
            b = t >> shift
            r = t & mask
            a = order[t]
            f0 = f1 = f2 = 0.0
            for w in range(U(cover_ptr[b]), U(cover_ptr[b + 1])):
                e = U(3) * U(slot[cover[w], b] + r)
                f0 += fb[e]
                f1 += fb[e + U(1)]
                f2 += fb[e + U(2)]
            i = U(3) * U(a)
            ff[i] = f0
            ff[i + U(1)] = f1
            ff[i + U(2)] = f2
            if want_e:
                es = 0.0
                for w in range(cover_ptr[b], cover_ptr[b + 1]):
                    es += ebuf[slot[cover[w], b] + r]
                energies[a] = es
            if want_v:
                for x in range(6):
                    vs = 0.0
                    for w in range(cover_ptr[b], cover_ptr[b + 1]):
                        vs += vbuf[slot[cover[w], b] + r, x]
                    virials[a, x] = vs


# The constants the source of the kernels reads (each compiled copy has
# its own: :func:`_kernel`)
PAIR = SQUARED = GENERAL = GUARD = None

#: Pairs of a row handled per batch by the kernel: its six buffers (3 KiB)
#: stay in L1 whatever the cutoff; 32, 128 and 256 ran alike (AMD Zen 4).
BATCH = 64


def _kernel(name, pair, squared, general, cache):
    """``(serial, threaded)`` kernels of :func:`_pair_sum` for the pair
    function ``pair`` (:func:`ase_mlg.parallel.serial_and_parallel`):
    copies of its code with ``PAIR``, ``SQUARED``, ``GENERAL`` and
    ``GUARD`` bound in the copy's globals, named ``name`` (the on-disk cache's key with
    ``cache``).

    Why copies, not one kernel taking the three as arguments and inlined
    into an entry point per pair function: numba inlines a function at its
    IR by deep-copying the IR, 1.1 s of every kernel's first compilation
    (AMD Zen 4); a global is a constant to numba as a literal argument is,
    so the same branches are pruned before typing."""
    body = _pair_sum
    # A pair function compiled with numba's default error model raises on a
    # division by zero: it is called within the cutoff only (GUARD), as
    # before the loop was vectorised; one with error_model='numpy' is called
    # on the listed pairs beyond it too, its results dropped
    guard = pair.targetoptions.get('error_model', 'python') != 'numpy'
    constants = dict(PAIR=pair, SQUARED=bool(squared), GENERAL=bool(general),
                     GUARD=guard)
    copy = FunctionType(body.__code__, dict(body.__globals__, **constants), name)
    copy.__qualname__ = name
    copy.__module__ = body.__module__
    copy.__doc__ = body.__doc__
    return serial_and_parallel(copy, cache=cache, nogil=True, error_model='numpy')


# A user's pair function: its kernels, compiled once per process (numba's
# on-disk cache cannot key a Python object it did not compile from a file
# of its own), kept by (pair, squared, general)
_GENERIC = {}


@njit(cache=True, error_model='numpy')
def first_bad_pair(pair, lst, code, pot):
    """The first pair of the list that a kernel of :func:`pair_kernel`
    flagged (the error path only: a serial scan).

    Parameters
    ----------
    pair : numba function
        The pair function the kernel ran with.
    lst : SumList
    code : uint8[M] or int32[M]
    pot : SumTables

    Returns
    -------
    (int, PairError)
        The pair's index ``q`` into ``lst.nbr`` and why it is bad, or
        ``(-1, PairError.OK)``.
    """
    X = lst.X
    types = lst.types
    rowptr = lst.rowptr
    nbr = lst.nbr
    svec = lst.svec
    params = pot.params
    cut2 = pot.cut2
    rmin2 = pot.rmin2
    for t in range(X.shape[0]):
        ta = types[t]
        for q in range(rowptr[t], rowptr[t + 1]):
            u = nbr[q]
            dx, dy, dz = pair_vector(X, svec, t, u, code[q])
            r2 = dx * dx + dy * dy + dz * dz
            tb = types[u]
            if r2 > cut2[ta, tb]:
                continue
            if not r2 > 0.0:  # also NaN
                return q, PairError.BAD_DISTANCE
            if r2 < rmin2[ta, tb]:
                return q, PairError.BELOW_RMIN
            if pot.squared:
                e, s = pair(r2, params[ta, tb])
            else:
                r = math.sqrt(r2)
                e, dedr = pair(r, params[ta, tb])
                s = dedr / r
            if not (math.isfinite(e) and math.isfinite(s)):
                return q, PairError.NON_FINITE
    return -1, PairError.OK


def bad_pair_error(potential, lst, code, pot=None, cause=None):
    """The ValueError naming the first bad pair of ``lst`` (a
    :class:`SumList`, image codes ``code``) for ``potential`` (a
    :class:`~ase_mlg.potentials.PairPotential`): the one
    :func:`first_bad_pair` flags with the tables ``pot``, or without them
    the first whose pair function raises an ArithmeticError (``cause``:
    None if none does).  The error path only: a scan in Python."""
    if pot is not None:
        q, why = first_bad_pair(potential.pair, lst, code, pot)
        if q < 0:
            return ValueError('non-finite total energy or force (overflow of the pair sums)')
    else:
        q, why = _raising_pair(potential, lst, code), PairError.NON_FINITE
        if q < 0:
            return None
    t, u, r = pair_geometry(lst, code, q)
    ta, tb = lst.types[t], lst.types[u]
    where = f'atoms {lst.order[t]} and {lst.order[u]} at distance {r:.6g} Å'
    if why == PairError.BAD_DISTANCE:
        return ValueError(f'{where}: distance must be > 0 (overlapping atoms?)')
    if why == PairError.BELOW_RMIN:
        return ValueError(f'{where}: closer than rmin {potential.rmin[ta, tb]} '
                          f'Å for {potential._type_name(ta, tb)}')
    if cause is not None:
        what = f'{type(cause).__name__}: {cause}'
    else:
        e, dedr = _call_pair(potential, r, ta, tb)
        what = f'energy {e}, dE/dr {dedr}'
    return ValueError(f'{where}: non-finite pair energy or force ({what})')


def _raising_pair(potential, lst, code):
    for q in range(int(lst.rowptr[-1])):
        t, u, r = pair_geometry(lst, code, q)
        ta, tb = lst.types[t], lst.types[u]
        if 0 < r <= potential.cutoffs[ta, tb]:
            try:
                _call_pair(potential, r, ta, tb)
            except ArithmeticError:
                return q
    return -1


def _call_pair(potential, r, ta, tb):
    """``(e, dE/dr)`` of one pair at distance ``r``."""
    if potential.squared:
        e, du = potential.pair(r * r, potential.params[ta, tb])
        return e, du * r
    return potential.pair(r, potential.params[ta, tb])


def pair_geometry(lst, code, q):
    """Rows ``(t, u)`` and distance (Å) of pair ``q`` of ``lst`` (a
    :class:`SumList`, image codes ``code``): the error path's message."""
    t = int(np.searchsorted(lst.rowptr, q, side='right') - 1)
    u = int(lst.nbr[q])
    D = (lst.X[u] - lst.X[t]) + lst.svec[code[q]]
    return t, u, float(np.sqrt(D @ D))


def shift_vectors(shifts, cell):
    """``S @ cell`` for integer shifts S (K, 3), in the operation order of
    ``ase.neighborlist`` (``s0 * c0 + s1 * c1 + s2 * c2``), Å."""
    cell = np.asarray(cell, dtype=np.float64)
    S = np.asarray(shifts, dtype=np.float64)
    return np.ascontiguousarray(S[:, 0:1] * cell[0] + S[:, 1:2] * cell[1]
                                + S[:, 2:3] * cell[2])


def _pair_vectors(positions, i, j, shifts, cell, D, d):
    for k in prange(i.shape[0]):
        a = i[k]
        b = j[k]
        s0, s1, s2 = shifts[k, 0], shifts[k, 1], shifts[k, 2]
        r2 = 0.0
        for c in range(3):
            x = positions[b, c] - positions[a, c] + (s0 * cell[0, c] + s1 * cell[1, c] + s2 * cell[2, c])
            D[k, c] = x
            r2 += x * x
        d[k] = math.sqrt(r2)


# Both compilations give identical results (independent pairs).
_pair_vectors_serial, _pair_vectors_parallel = serial_and_parallel(_pair_vectors)


def pair_vectors(positions, i, j, shifts, cell):
    """``D = positions[j] - positions[i] + shifts @ cell`` and ``|D|`` (Å) for
    a pair list with cell shifts, in the operation order of
    ``ase.neighborlist`` so the rounding is the same.

    ``positions`` (N, 3) and ``cell`` (3, 3) float64, ``shifts`` (M, 3)
    float64 (integer values), ``i``/``j`` int arrays (M,)."""
    m = len(i)
    D = np.empty((m, 3))
    d = np.empty(m)
    kernel = _pair_vectors_parallel if use_threads("pairs", m) else _pair_vectors_serial
    kernel(positions, i, j, shifts, cell, D, d)
    return D, d


# The built-in potentials' kernels, cached on disk under their own names.
# Each compiles on first use: an MD run of one species without a barostat
# never compiles the ``_general`` ones.
def _twins(name, pair, squared):
    """general -> (serial, threaded) of a built-in pair function."""
    return {False: _kernel(name, pair, squared, False, True),
            True: _kernel(name + "_general", pair, squared, True, True)}


# pair function -> (its form, compiled into its kernels; the kernels)
_BUILT_IN = {pair: (squared, _twins("_sum_" + name, pair, squared))
             for name, pair, squared in (("lj_shifted", lennard_jones_shifted_r2, True),
                                         ("lj_smooth", lennard_jones_smooth_r2, True),
                                         ("morse", morse, False))}


def is_built_in(pair):
    """Whether ``pair`` has a cached kernel of its own (the pair functions
    of :mod:`ase_mlg.pairfunctions` that the built-in potentials use)."""
    return pair in _BUILT_IN


def built_in_form(pair):
    """``squared`` as compiled into the cached kernel of the built-in pair
    function ``pair`` (True: it takes ``r**2``), or None for any other."""
    entry = _BUILT_IN.get(pair)
    return None if entry is None else entry[0]


def pair_kernel(pair, threaded, general=True, squared=False):
    """The pair-sum kernel for the pair function ``pair``.

    Parameters
    ----------
    pair : numba dispatcher
    threaded : bool
        The threaded twin (``prange`` over the chunks) or the serial one
        (:func:`ase_mlg.parallel.serial_and_parallel`); launch a threaded
        one inside :class:`ase_mlg.parallel.dynamic_schedule`.
    general : bool
        A kernel that reads the species tables, checks ``rmin`` and writes
        the virial and per-atom energies and virials where the tables and
        buffers ask (True), or one compiled for forces and energy of one
        species alone (False: it reads row ``params[0, 0]`` and ignores the
        rest; see :func:`_pair_sum`).
    squared : bool
        Whether ``pair`` takes ``r**2`` (``PairPotential.squared``); a
        built-in pair function's form is its own (:func:`built_in_form`).

    Returns
    -------
    numba dispatcher ``kernel(lst, code, pot, chunks, out)``
        Takes a :class:`SumList`, the image codes, a :class:`SumTables`, an
        :class:`ase_mlg.chunks.Chunks` and a :class:`SumOutputs`, fills
        ``out`` and returns None.  For a built-in pair function
        (:func:`is_built_in`) loaded from numba's on-disk cache; for any
        other one made on first use and compiled in each process, the same
        kernel on every call with the same arguments.
    """
    entry = _BUILT_IN.get(pair)
    if entry is not None:
        return entry[1][bool(general)][bool(threaded)]
    key = (pair, bool(squared), bool(general))
    twins = _GENERIC.get(key)
    if twins is None:
        # setdefault is atomic: threads racing here all get the one stored
        # (a spare is dropped before anything compiles it); no lock, so
        # nothing a fork could inherit held
        twins = _GENERIC.setdefault(key, _kernel("_sum_generic", pair, squared, general, False))
    return twins[bool(threaded)]
