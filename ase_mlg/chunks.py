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

Buffers then cost ``sum(width) ~ (1 + overlap) N`` entries, instead of
``chunks x N``: measured on argon liquids (a = 5.26 Å, rc + skin = 9.5 Å),
1.5 N at 2 chunks and 3.9 N at 8 on 6,912 atoms, 1.3 N and 3.3 N at 2 and
16 chunks on 10^5, 2.1 N and 5.3 N at 16 and 64 chunks on 10^6 (a chunk's
halo of neighbours stays rc + skin deep, so each chunk adds about the same
width).  The reduction sums, for every rank, the buffers of the chunks
whose windows cover it, in chunk order: the window edges cut the ranks into
*segments* with a fixed set of covering chunks, so the reduction reads each
buffer entry once and the result does not depend on which thread ran which
chunk.

The chunks are a function of the list alone (:func:`row_chunks`): its pair
count, its atom count and the window budget, never numba's thread count.
One thread (``NUMBA_NUM_THREADS=1``, ``numba.set_num_threads(1)``) runs the
same chunks in chunk order that several threads share, so forces, energy,
stress and the per-atom energies and virials are the same bits at any
thread count (tests/test_thread_determinism.py).
"""

from collections import namedtuple

import numpy as np
from numba import njit, prange

from .parallel import THRESHOLDS, serial_and_parallel, use_threads

__all__ = ["Chunks", "RowChunks", "row_chunks", "chunk_count",
           "MAX_CHUNKS", "MIN_CHUNKS", "PAIRS_PER_CHUNK", "WINDOW_BUDGET"]

#: Pairs per chunk of a long list: the chunk count grows with the work
#: (chunks are handed out one at a time,
#: :class:`ase_mlg.parallel.dynamic_schedule`, so more chunks balance
#: threads that wake late; shorter ones cost more in window zeroing and
#: reduction than they balance).
PAIRS_PER_CHUNK = 20_000
#: Most chunks of a pair sum: 64 threads get one each on 10^6 atoms
#: (argon at a = 5.26 Å, rc + skin = 9.5 Å: 44 million pairs, 64 windows
#: take 5.3 N; at 5.72 Å 39 million and 5.4 N).
MAX_CHUNKS = 64
#: Fewest chunks of a list long enough to thread
#: (:data:`ase_mlg.parallel.THRESHOLDS` ``"pairs"``): two windows take at
#: most 2 N, within any budget.
MIN_CHUNKS = 2
#: Most buffer entries, in units of N, that the windows of all chunks may
#: take: fewer chunks are used where more would take more (never fewer
#: than :data:`MIN_CHUNKS`).  Windows widen as chunks thin (a chunk's halo
#: of neighbours stays rc + skin deep): on 10^6 argon atoms 16 chunks take
#: 2.1 N, 64 take 5.3 N (128 MB of force buffers at 24 bytes an entry, 430
#: MB with per-atom energies and virials at 80) and 256 take 17 N; 6 N is
#: what 64 chunks need there (3 N would leave 29).  Smaller lists fill the
#: budget with fewer chunks: 13 on 6,912 atoms, 35 on 108,000 (5.9 N each).
#: One thread runs the same windows (validation/chunk_cost.py measures the
#: cost against one chunk).
WINDOW_BUDGET = 6.0
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


def chunk_count(npairs):
    """Chunks of a pair sum of ``npairs`` list pairs before the window
    budget (:func:`row_chunks`): one below the threshold of threaded pair
    sums, else one per :data:`PAIRS_PER_CHUNK` pairs, from
    :data:`MIN_CHUNKS` to :data:`MAX_CHUNKS`.  A function of the list, not
    of the thread count, so that results are not either."""
    if npairs < THRESHOLDS["pairs"]:
        return 1
    return int(min(MAX_CHUNKS, max(MIN_CHUNKS, npairs // PAIRS_PER_CHUNK)))


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
        kernel = _mark_threaded if use_threads("marks", m) else _mark_serial
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
    """The :class:`RowChunks` of a half list: :func:`chunk_count` chunks,
    fewer while their windows take more than :data:`WINDOW_BUDGET` x N
    buffer entries and there are more than :data:`MIN_CHUNKS`.

    A function of the list alone (its pairs, rows and windows), so that
    every thread count runs the same chunks and gets the same bits;
    ``nthreads`` is accepted for compatibility and changes nothing (numba's
    thread count at the call decides how many threads share the chunks)."""
    m = int(rowptr[-1]) if len(rowptr) else 0
    n = max(len(rowptr) - 1, 1)
    nchunk = chunk_count(m)
    chunks = RowChunks(rowptr, nbr, nchunk)
    budget = WINDOW_BUDGET * n
    while chunks.entries > budget and chunks.nchunk > MIN_CHUNKS:
        # each chunk adds about the same halo to the windows: aim at the
        # count that fits, then step down if the model was short
        halo = (chunks.entries - n) / max(chunks.nchunk - 1, 1)
        fit = int(1 + (budget - n) / halo) if halo > 0 else chunks.nchunk - 1
        nchunk = max(MIN_CHUNKS, min(chunks.nchunk - 1, fit))
        chunks = RowChunks(rowptr, nbr, nchunk)
    return chunks


@njit(cache=True)
def local_rank(r, lo, n):
    """Index of rank ``r`` in the cyclic window starting at rank ``lo``."""
    x = r - lo
    return x + n if x < 0 else x
