"""The pair kernel: one fused loop over a :class:`~ase_mlg.pairlist.PairList`.

:func:`_pair_sum` walks the rows of the half list in grid order, computes
``D = X[u] - X[t] + S @ cell`` in registers in ASE's operation order, calls
the pair function (inlined), and accumulates energy, forces and, when
asked, per-atom energies and virials.  A user's pair function is passed as
a compile-time argument (:data:`_GENERIC`, compiled once per process); the
built-in potentials have cached entry points with their pair function
inlined (:data:`_BUILT_IN`).  Threads follow :mod:`ase_mlg.parallel` and
:mod:`ase_mlg.partition`: chunks of rows with equal pair counts handed out
one at a time, a force buffer per chunk covering only the window of ranks
the chunk touches, windows summed per rank in chunk order, so the same
chunks give the same bits (docs/design.md §8).
"""

import math

import numba
import numpy as np
from numba import prange

from .pairfunctions import lennard_jones_shifted_r2, lennard_jones_smooth_r2, morse
from .pairlist import pair_vector
from .partition import local_rank
from .parallel import serial_and_parallel, use_threads

__all__ = ["shift_vectors", "pair_vectors"]

# Error codes returned by the kernel; the Python side turns them into messages
# because a numba exception cannot carry the pair's indices and distance.
_OK, _BAD_DISTANCE, _BELOW_RMIN, _NON_FINITE = range(4)


def _pair_sum(pair, args):
    """Energy, forces and virials of a half pair list, one fused pass.

    The pair function is a compile-time argument (a numba dispatcher), so it
    is inlined into the loop.  Rows are split into the chunks of
    ``chunks`` (:class:`ase_mlg.partition.Chunks`, about equal pair counts);
    each chunk accumulates into its own window of the buffers (``fbuf`` and
    ``ebuf``/``vbuf`` when per-atom energies or virials are wanted: pass
    zero-length arrays otherwise): entry ``offset[c] + local_rank(r)`` is
    rank ``r`` of chunk ``c``.  The windows are then summed per rank in
    chunk order and scattered to atom order (``forces[order[t]]``), so the
    result is the same on every run with the same chunks, whichever thread
    ran which chunk.

    Parameters
    ----------
    pair : numba function ``(r, p) -> (e, dE/dr)``
    args : tuple
        ``(squared, X, types, rowptr, nbr, code, svec, params, cut2, rmin2,
        check_rmin, want_w, chunks, order, fbuf, ebuf, vbuf, part, forces,
        energies, virials)`` (one tuple, so that the cached entry points of the
        built-in potentials below stay one line each):
    want_w : bool
        Accumulate the virial (stress); per-atom virials need it too.
    squared : bool
        ``pair`` takes ``r**2`` and returns ``(e, dE/dr / r)`` instead
        (no square root, one division less: the built-in LJ).
    X : float64[N, 3]
        Positions in row order, Å.
    types : int32[N]
        Type index of each row.
    rowptr, nbr, code : int64[N + 1], int32[M], uint8[M] or int32[M]
        The half list: pairs ``(t, nbr[q])`` for ``q`` in
        ``rowptr[t]:rowptr[t + 1]``, ``D = X[nbr[q]] - X[t] + svec[code[q]]``.
    svec : float64[K, 3]
        Cartesian cell shift of every code, Å.
    params : float64[T, T, P]
    cut2, rmin2 : float64[T, T]
        Squared cutoff (pairs with ``d**2 > cut2`` are skipped: ASE's LJ
        keeps ``d == rc``) and squared ``rmin`` (closer pairs are counted
        as errors, only with ``check_rmin``), Å².
    chunks : Chunks
        The chunks, their windows and the reduction's segments; the kernel
        writes ``chunks.thread`` (the numba thread of each chunk).
    part : float64[C, 9]
        Out, per chunk: energy (eV), virial (6, eV), the sum of every
        pair's ``dE/dr / r`` (not finite if any pair energy, force or
        distance was bad: no per-pair branch in the loop) and the number of
        pairs below rmin.  :func:`_first_bad_pair` then names the pair.

    Out: ``forces`` (N, 3) eV/Å, ``energies`` (N or 0) eV, ``virials``
    (N or 0, 6) eV, in atom order.  Virials are ``-D (x) dE/dD`` in Voigt
    order (xx, yy, zz, yz, xz, xy), half of each pair to each atom.
    """
    (squared, X, types, rowptr, nbr, code, svec, params, cut2, rmin2,
     check_rmin, want_w, chunks, order, fbuf, ebuf, vbuf, part, forces,
     energies, virials) = args
    # the chunk tables as locals: numba's parallel lowering cannot read a
    # named tuple's fields inside prange
    rows, wlo, _, offset, seg, cover_ptr, cover, thread = chunks
    n = X.shape[0]
    nchunk = wlo.shape[0]
    want_e = ebuf.shape[0] > 0
    want_v = vbuf.shape[0] > 0
    typed = params.shape[0] > 1  # one species-agnostic row: no lookups
    for c in prange(nchunk):
        thread[c] = numba.get_thread_id()
        base = offset[c]
        lo = wlo[c]
        for e in range(base, offset[c + 1]):
            fbuf[e, 0] = 0.0
            fbuf[e, 1] = 0.0
            fbuf[e, 2] = 0.0
            if want_e:
                ebuf[e] = 0.0
            if want_v:
                for x in range(6):
                    vbuf[e, x] = 0.0
        # Neumaier-compensated sum of row energies: 10^7 pair energies of
        # both signs would otherwise lose digits to rounding
        energy = 0.0
        comp = 0.0
        check = 0.0
        nlow = 0
        v0 = v1 = v2 = v3 = v4 = v5 = 0.0
        last_a = -1
        last_b = -1
        p = params[0, 0]
        for t in range(rows[c], rows[c + 1]):
            x0 = X[t, 0]
            x1 = X[t, 1]
            x2 = X[t, 2]
            lt = base + local_rank(t, lo, n)
            ta = types[t] if typed else 0
            ft0 = ft1 = ft2 = 0.0
            erow = 0.0
            for q in range(rowptr[t], rowptr[t + 1]):
                u = nbr[q]
                k = code[q]
                # as ASE: positions[j] - positions[i] + S @ cell
                dx = (X[u, 0] - x0) + svec[k, 0]
                dy = (X[u, 1] - x1) + svec[k, 1]
                dz = (X[u, 2] - x2) + svec[k, 2]
                r2 = dx * dx + dy * dy + dz * dz
                tb = types[u] if typed else 0
                if r2 > cut2[ta, tb]:
                    continue
                if check_rmin and r2 < rmin2[ta, tb]:
                    nlow += 1
                if ta != last_a or tb != last_b:
                    last_a, last_b = ta, tb
                    p = params[ta, tb]
                if squared:
                    e, s = pair(r2, p)
                else:
                    r = math.sqrt(r2)
                    e, dedr = pair(r, p)
                    s = dedr / r
                erow += e
                check += s  # r = 0 or NaN makes it non-finite
                fx = s * dx  # force on t; minus that on u
                fy = s * dy
                fz = s * dz
                ft0 += fx
                ft1 += fy
                ft2 += fz
                lu = base + local_rank(u, lo, n)
                fbuf[lu, 0] -= fx
                fbuf[lu, 1] -= fy
                fbuf[lu, 2] -= fz
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
                    for h in range(2):
                        a = lt if h == 0 else lu
                        vbuf[a, 0] -= 0.5 * w0
                        vbuf[a, 1] -= 0.5 * w1
                        vbuf[a, 2] -= 0.5 * w2
                        vbuf[a, 3] -= 0.5 * w3
                        vbuf[a, 4] -= 0.5 * w4
                        vbuf[a, 5] -= 0.5 * w5
            fbuf[lt, 0] += ft0
            fbuf[lt, 1] += ft1
            fbuf[lt, 2] += ft2
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
    # sum the windows covering each rank in chunk order, back in atom order;
    # pieces of ranks, each walking the segments it crosses
    npiece = nchunk
    for piece in prange(npiece):
        t0 = piece * n // npiece
        t1 = (piece + 1) * n // npiece
        if t1 <= t0:
            continue
        s = np.searchsorted(seg, t0, side="right") - 1
        for t in range(t0, t1):
            while seg[s + 1] <= t:
                s += 1
            a = order[t]
            f0 = f1 = f2 = 0.0
            for w in range(cover_ptr[s], cover_ptr[s + 1]):
                c = cover[w]
                e = offset[c] + local_rank(t, wlo[c], n)
                f0 += fbuf[e, 0]
                f1 += fbuf[e, 1]
                f2 += fbuf[e, 2]
            forces[a, 0] = f0
            forces[a, 1] = f1
            forces[a, 2] = f2
            if want_e:
                es = 0.0
                for w in range(cover_ptr[s], cover_ptr[s + 1]):
                    c = cover[w]
                    es += ebuf[offset[c] + local_rank(t, wlo[c], n)]
                energies[a] = es
            if want_v:
                for x in range(6):
                    vs = 0.0
                    for w in range(cover_ptr[s], cover_ptr[s + 1]):
                        c = cover[w]
                        vs += vbuf[offset[c] + local_rank(t, wlo[c], n), x]
                    virials[a, x] = vs


# Threads pay off only on long lists (waking them costs more than a short
# list): one Python function, compiled serial and threaded.  With a user's
# pair function as its (compile-time) argument the kernel is compiled once
# per process: numba's on-disk cache cannot key a function argument.  The
# built-in potentials get cached entry points below, the pair function
# inlined into each.
_GENERIC = serial_and_parallel(_pair_sum, cache=False, nogil=True,
                               error_model='numpy')
_pair_sum_inline = numba.njit(inline='always', error_model='numpy')(_pair_sum)


@numba.njit(cache=True, error_model='numpy')
def _first_bad_pair(pair, squared, X, types, rowptr, nbr, code, svec, params,
                    cut2, rmin2):
    """The first pair of the list that :func:`_pair_sum` flagged (error
    path only): ``(q, why)``, or ``(-1, _OK)``."""
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
                return q, _BAD_DISTANCE
            if r2 < rmin2[ta, tb]:
                return q, _BELOW_RMIN
            if squared:
                e, s = pair(r2, params[ta, tb])
            else:
                r = math.sqrt(r2)
                e, dedr = pair(r, params[ta, tb])
                s = dedr / r
            if not (math.isfinite(e) and math.isfinite(s)):
                return q, _NON_FINITE
    return -1, _OK

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


# Cached kernels of the built-in potentials: module-level functions naming
# their pair function, so numba can key them on disk.
def _sum_lj_shifted(args):
    _pair_sum_inline(lennard_jones_shifted_r2, args)


def _sum_lj_smooth(args):
    _pair_sum_inline(lennard_jones_smooth_r2, args)


def _sum_morse(args):
    _pair_sum_inline(morse, args)


_FLAGS = dict(nogil=True, error_model='numpy')
_BUILT_IN = {lennard_jones_shifted_r2: serial_and_parallel(_sum_lj_shifted, **_FLAGS),
             lennard_jones_smooth_r2: serial_and_parallel(_sum_lj_smooth, **_FLAGS),
             morse: serial_and_parallel(_sum_morse, **_FLAGS)}
