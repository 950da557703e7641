"""The unit of parallel work of a pair sum: chunks of rows, the window of
ranks each chunk touches, and the reduction of the chunks' buffers.

A half list in grid order (:class:`~ase_mlg.pairlist.PairList`) has the
MLG's promise built in: the rows of a chunk of consecutive ranks are atoms
close in space, and their neighbours are close to them in rank.  A chunk's
pairs therefore touch a narrow *window* of ranks (its rows and the next
ranks within the list radius, plus the ranks across a periodic seam), so
its force buffer needs to cover only that window, not all N atoms
(docs/design.md §8).  Windows are cyclic intervals of ranks: a chunk at the
start of the grid whose neighbours sit across the seam at its end gets one
interval that wraps, not two that span everything between.

Buffers then cost ``sum(width) ~ (1 + overlap) N`` entries whatever the
thread count, instead of ``threads x N``: measured on a 10^5-atom argon
liquid (rc + skin = 9.5 Å), 1.2 N at 2 chunks and 2.8 N at 16.  The
reduction sums, for every rank, the buffers of the chunks whose windows
cover it, in chunk order: the window edges cut the ranks into *segments*
with a fixed set of covering chunks, so the reduction reads each buffer
entry once and the result does not depend on which thread ran which chunk.
"""

from collections import namedtuple

import numpy as np
from numba import njit, prange

from .parallel import serial_and_parallel, threads_for, use_threads

__all__ = ["Chunks", "RowChunks", "row_chunks", "chunk_count",
           "CHUNKS_PER_THREAD", "PAIRS_PER_CHUNK", "WINDOW_BUDGET"]

#: Chunks per thread of a threaded pair sum.  Chunks are handed out one at
#: a time (:class:`ase_mlg.parallel.dynamic_schedule`), so a thread that
#: wakes late takes fewer; more chunks balance better and cost wider total
#: windows.
CHUNKS_PER_THREAD = 4
#: Fewest pairs a chunk should hold (shorter ones cost more in window
#: zeroing and reduction than they balance).
PAIRS_PER_CHUNK = 20_000
#: Most buffer entries, in units of N, that the windows of all chunks may
#: take before fewer chunks a thread are used (never fewer than one a
#: thread).  Windows widen as chunks thin (a chunk's halo of neighbours
#: stays rc + skin deep): on 10^6 argon atoms 8 chunks take 1.4 N, 64 take
#: 4.4 N and 256 take 13 N, so 64 threads at 4 chunks each would cost 310 MB
#: of buffers where 64 chunks cost 105 MB.
WINDOW_BUDGET = 3.0
_NBIN = 4096  # rank bins of the window search: windows over-cover by < 2 bins

#: The arrays the pair kernel reads (one argument for numba).
#: ``rows`` int64[C + 1] (chunk ``c`` is rows ``rows[c]:rows[c + 1]``),
#: ``lo``/``width`` int64[C] (window: ranks ``lo, lo + 1, ...`` cyclically,
#: ``width`` of them), ``offset`` int64[C + 1] (window ``c`` is buffer
#: entries ``offset[c]:offset[c + 1]``), ``seg`` int64[S + 1] (segment
#: edges, 0 ... N), ``cover_ptr`` int64[S + 1] and ``cover`` int64[*] (the
#: chunks covering segment ``s``, ascending), ``thread`` int64[C] (out: the
#: numba thread that ran chunk ``c``).
Chunks = namedtuple("Chunks", "rows lo width offset seg cover_ptr cover thread")


def chunk_count(npairs, nthreads):
    """Chunks of a pair sum of ``npairs`` list pairs on ``nthreads``
    threads: one on one thread, else :data:`CHUNKS_PER_THREAD` a thread,
    but no fewer than 2 a thread and no shorter than
    :data:`PAIRS_PER_CHUNK` where possible."""
    if nthreads <= 1:
        return 1
    by_size = max(2 * nthreads, npairs // PAIRS_PER_CHUNK)
    return int(max(1, min(CHUNKS_PER_THREAD * nthreads, by_size)))


def _mark_windows(rowptr, nbr, rows, shift, marks, lo, width):
    """Window of every chunk: mark the rank bins (``2**shift`` ranks each)
    its rows and their neighbours fall in, then drop the largest cyclic run
    of empty bins."""
    binsize = 1 << shift
    n = rowptr.shape[0] - 1
    nbin = marks.shape[1]
    for c in prange(rows.shape[0] - 1):
        m = marks[c]
        m[:] = 0
        r0 = rows[c]
        r1 = rows[c + 1]
        if r1 <= r0:
            lo[c] = r0 % max(n, 1)
            width[c] = 0
            continue
        for b in range(r0 // binsize, (r1 - 1) // binsize + 1):
            m[b] = 1
        for q in range(rowptr[r0], rowptr[r1]):
            m[nbr[q] >> shift] = 1
        first = r0 // binsize  # a marked bin: start the cyclic scan there
        gap_start = 0
        gap_len = 0
        run = 0
        for s in range(1, nbin + 1):
            b = (first + s) % nbin
            if m[b] == 0:
                run += 1
            else:
                if run > gap_len:
                    gap_len = run
                    gap_start = (b - run) % nbin
                run = 0
        if gap_len == 0:
            lo[c] = 0
            width[c] = n
            continue
        start_bin = (gap_start + gap_len) % nbin
        last_bin = (gap_start - 1) % nbin
        start = start_bin * binsize
        end = min((last_bin + 1) * binsize, n)
        w = end - start
        if w <= 0:
            w += n
        lo[c] = start
        width[c] = w


_mark_serial, _mark_threaded = serial_and_parallel(_mark_windows)


def _chunks(rowptr, nbr, nchunk):
    """:class:`Chunks` of a half list (``rowptr`` int64[N + 1], ``nbr``
    int32[M] ranks) cut into ``nchunk`` chunks of about equal pair counts."""
    n = len(rowptr) - 1
    m = int(rowptr[-1]) if n >= 0 else 0
    nchunk = max(1, min(int(nchunk), max(n, 1)))
    rows = np.searchsorted(rowptr, np.linspace(0, m, nchunk + 1)).astype(np.int64)
    rows[0], rows[-1] = 0, max(n, 0)
    np.maximum.accumulate(rows, out=rows)
    lo = np.zeros(nchunk, np.int64)
    width = np.zeros(nchunk, np.int64)
    if nchunk == 1:
        width[:] = n  # one chunk: the whole list, no search
    else:
        shift = max(0, int(np.ceil(np.log2(max(n, 1) / _NBIN))))
        nbin = -(-n // (1 << shift))
        marks = np.empty((nchunk, nbin), np.uint8)
        kernel = _mark_threaded if use_threads("pairs", m) else _mark_serial
        kernel(rowptr, nbr, rows, shift, marks, lo, width)
    offset = np.zeros(nchunk + 1, np.int64)
    np.cumsum(width, out=offset[1:])
    live = width > 0
    edges = np.concatenate(([0, n], lo[live], (lo[live] + width[live]) % max(n, 1)))
    seg = np.unique(edges[(edges >= 0) & (edges <= n)]).astype(np.int64)
    if len(seg) < 2:
        seg = np.array([0, n], np.int64)
    starts = seg[:-1]
    covered = (((starts[:, None] - lo[None, :]) % max(n, 1)) < width[None, :])
    cover_ptr = np.zeros(len(starts) + 1, np.int64)
    np.cumsum(covered.sum(axis=1), out=cover_ptr[1:])
    cover = np.nonzero(covered)[1].astype(np.int64)  # row-major: chunk order
    return Chunks(rows, lo, width, offset, seg, cover_ptr, cover,
                  np.zeros(nchunk, np.int64))


class RowChunks:
    """The chunks of one pair list for one chunk count, with their buffers:
    what :meth:`ase_mlg.potentials.PairPotential.sum_pairs` takes as
    ``chunks`` (the same chunks give the same bits).

    Parameters
    ----------
    rowptr, nbr : int64[N + 1], int32[M]
        The half list (ranks).
    nchunk : int
        Chunks (see :func:`chunk_count`).

    Attributes
    ----------
    arrays : Chunks
        What the kernel reads.
    nchunk : int
    entries : int
        Buffer entries over all windows (``N`` for one chunk).
    """

    def __init__(self, rowptr, nbr, nchunk):
        self.arrays = _chunks(rowptr, nbr, nchunk)
        self.nchunk = len(self.arrays.lo)
        self.entries = int(self.arrays.offset[-1])
        self._buffers = {}

    def buffers(self, energies, virials):
        """Force buffer float64[entries, 3] and, when asked, the per-atom
        energy float64[entries] and virial float64[entries, 6] buffers
        (zero-length otherwise), reused from call to call: the kernel
        zeroes each window itself."""
        key = (bool(energies), bool(virials))
        if key not in self._buffers:
            e = self.entries
            self._buffers[key] = (np.empty((e, 3)), np.empty(e if energies else 0),
                                  np.empty((e if virials else 0, 6)))
        return self._buffers[key]

    def threads_used(self):
        """Distinct numba threads that ran the chunks on the last call."""
        return int(len(np.unique(self.arrays.thread)))

    def nbytes(self):
        """Bytes of the chunk tables and the buffers allocated so far."""
        return (sum(a.nbytes for a in self.arrays)
                + sum(b.nbytes for bufs in self._buffers.values() for b in bufs))


def row_chunks(rowptr, nbr, nthreads=None):
    """The :class:`RowChunks` of a half list for ``nthreads`` threads
    (default: numba's count on long lists, 1 on short ones):
    :func:`chunk_count` chunks, halved while their windows take more than
    :data:`WINDOW_BUDGET` x N buffer entries and a thread has more than one."""
    m = int(rowptr[-1]) if len(rowptr) else 0
    n = max(len(rowptr) - 1, 1)
    if nthreads is None:
        nthreads = threads_for("pairs", m)
    nchunk = chunk_count(m, nthreads)
    while True:
        chunks = RowChunks(rowptr, nbr, nchunk)
        if chunks.entries <= WINDOW_BUDGET * n or nchunk <= nthreads:
            return chunks
        nchunk = max(nthreads, nchunk // 2)


@njit(cache=True, inline="always")
def local_rank(r, lo, n):
    """Index of rank ``r`` in the cyclic window starting at rank ``lo``."""
    x = r - lo
    return x + n if x < 0 else x
