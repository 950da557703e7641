"""The unit of parallel work of a pair sum: chunks of rows, the ranks
each chunk touches, and the reduction of the chunks' buffers.

A half list in grid order (:class:`~ase_mlg.pairlist.PairList`) has the
MLG's promise built in: the rows of a chunk of consecutive ranks are atoms
close in space, and their neighbours are close to them in rank.  A chunk's
pairs therefore touch a narrow *window* of ranks (its rows and the next
ranks within the list radius, plus the ranks across a periodic seam), so
its force buffer needs to cover only that window, not all N atoms
(docs/design.md §8).  A window is the set of rank *bins* (``2**shift``
consecutive ranks, at most :data:`_NBIN` bins) that the chunk's rows and
their neighbours fall in; the buffer holds those bins one after the other.
A contiguous interval from a chunk's first rank to its farthest neighbour
would also hold the ranks in between that no pair reaches (the MLG's
planes bend: on 10^6 argon atoms a few pairs reach six logical planes
ahead, most three): 5.4 N entries at 64 chunks against 3.1 N for the bins
touched (bins of 256 ranks), 121 against 70 MB of force buffers, the
same bits.

Buffers then cost ``~ (1 + overlap) N`` entries, instead of ``chunks x
N``.  The reduction sums, for every rank, the buffers of the chunks that
touched its bin, in chunk order (a chunk whose window missed the rank
added 0.0 there, which changes no sum): it reads each buffer entry once
and the result does not depend on which thread ran which chunk.

The chunks are a function of the list alone (:func:`row_chunks`): its pair
count, its atom count and the window budget, never numba's thread count.
One thread (``NUMBA_NUM_THREADS=1``, ``numba.set_num_threads(1)``) runs the
same chunks in chunk order that several threads share, so forces, energy,
stress and the per-atom energies and virials are the same bits at any
thread count (tests/test_thread_determinism.py).
"""

from collections import namedtuple

import operator

import numpy as np
from numba import prange

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
#: (argon at a = 5.72 Å, rc + skin = 9.5 Å: 39 million pairs, 64 windows
#: take 3.1 N).
MAX_CHUNKS = 64
#: Fewest chunks of a list long enough to thread
#: (:data:`ase_mlg.parallel.THRESHOLDS` ``"pairs"``): two windows take at
#: most 2 N, within any budget.
MIN_CHUNKS = 2
#: Most buffer entries, in units of N, that the windows of all chunks may
#: take: fewer chunks are used where more would take more (never fewer
#: than :data:`MIN_CHUNKS`).  Windows widen as chunks thin (a chunk's halo
#: of neighbours stays rc + skin deep).  Argon at a = 5.72 Å, rc + skin =
#: 9.5 Å, entries per N at 2, 8, 16, 64 and 256 chunks: 1.1, 1.4, 1.8, 3.1
#: and 4.1 on 10^6 atoms (64 chunks: 70 MB of force buffers at 24 bytes an
#: entry, 235 MB with per-atom energies and virials at 80); 1.2, 1.7, 2.3,
#: 3.2 and 6.0 on 108,000; 1.3, 2.4, 3.2, 5.9 and 10.5 on 6,912.  The lists
#: of liquids take their :func:`chunk_count` within the budget (13 chunks
#: on 6,912 atoms, 2.9 N; 21 on 10,976, 3.4 N; 64 on 108,000, 3.2 N); it
#: bounds lists whose neighbours lie far in rank.  One thread runs the
#: same windows (validation/chunk_cost.py measures the cost against one
#: chunk).
WINDOW_BUDGET = 6.0
_NBIN = 4096  # most rank bins: bins of 256 ranks on 10^6 atoms, 1 below 4,097

#: The arrays the pair kernel reads (one argument for numba).
#: ``rows`` int64[C + 1] (chunk ``c`` is rows ``rows[c]:rows[c + 1]``),
#: ``slot`` int64[C, B] (the buffer entry of the first rank of bin ``b``
#: in chunk ``c``'s window, -1 where the chunk does not touch the bin: rank
#: ``r`` is entry ``slot[c, r >> shift] + (r & (2**shift - 1))``),
#: ``shift`` int (bins of ``2**shift`` ranks), ``offset`` int64[C + 1]
#: (chunk ``c``'s buffer is entries ``offset[c]:offset[c + 1]``),
#: ``cover_ptr`` int64[B + 1] and ``cover`` int64[*] (the chunks touching
#: bin ``b``, ascending), ``thread`` int64[C] (out: the numba thread that
#: ran chunk ``c``).
Chunks = namedtuple("Chunks", "rows slot shift offset cover_ptr cover thread")


def chunk_count(npairs):
    """Chunks of a pair sum of ``npairs`` list pairs before the window
    budget (:func:`row_chunks`): one below the threshold of threaded pair
    sums, else one per :data:`PAIRS_PER_CHUNK` pairs, from
    :data:`MIN_CHUNKS` to :data:`MAX_CHUNKS`.  A function of the list, not
    of the thread count, so that results are not either."""
    if npairs < THRESHOLDS["pairs"]:
        return 1
    return int(min(MAX_CHUNKS, max(MIN_CHUNKS, npairs // PAIRS_PER_CHUNK)))


def _mark_bins(rowptr, nbr, rows, shift, marks):
    """The rank bins (``2**shift`` ranks each) that every chunk touches:
    those of its rows and of their neighbours."""
    binsize = 1 << shift
    for c in prange(rows.shape[0] - 1):
        m = marks[c]
        m[:] = 0
        r0 = rows[c]
        r1 = rows[c + 1]
        if r1 <= r0:
            continue
        for b in range(r0 // binsize, (r1 - 1) // binsize + 1):
            m[b] = 1
        for q in range(rowptr[r0], rowptr[r1]):
            m[nbr[q] >> shift] = 1


_mark_serial, _mark_threaded = serial_and_parallel(_mark_bins)


def _chunks(rowptr, nbr, nchunk):
    """:class:`Chunks` of a half list (``rowptr`` int64[N + 1], ``nbr``
    int32[M] ranks) cut into ``nchunk`` chunks of about equal pair counts."""
    n = len(rowptr) - 1
    m = int(rowptr[-1]) if n >= 0 else 0
    nchunk = max(1, min(int(nchunk), max(n, 1)))
    rows = np.searchsorted(rowptr, np.linspace(0, m, nchunk + 1)).astype(np.int64)
    rows[0], rows[-1] = 0, max(n, 0)
    np.maximum.accumulate(rows, out=rows)
    shift = max(0, int(np.ceil(np.log2(max(n, 1) / _NBIN))))
    nbin = max(1, -(-n // (1 << shift)))
    if nchunk == 1:
        marks = np.ones((1, nbin), np.uint8)  # one chunk: every bin, no search
    else:
        marks = np.empty((nchunk, nbin), np.uint8)
        kernel = _mark_threaded if use_threads("marks", m) else _mark_serial
        kernel(rowptr, nbr, rows, shift, marks)
    # a chunk's buffer holds its touched bins one after the other, in bin
    # order: slot[c, b] is the entry of bin b's first rank (-1: untouched)
    counts = marks.sum(axis=1, dtype=np.int64)
    offset = np.zeros(nchunk + 1, np.int64)
    np.cumsum(counts << shift, out=offset[1:])
    touched = marks.astype(bool)
    within = (np.cumsum(marks, axis=1, dtype=np.int64) - 1) << shift
    slot = np.where(touched, within + offset[:-1, None], -1)
    cover_ptr = np.zeros(nbin + 1, np.int64)
    np.cumsum(touched.sum(axis=0), out=cover_ptr[1:])
    cover = np.nonzero(touched.T)[1].astype(np.int64)  # row-major: chunk order
    return Chunks(rows, np.ascontiguousarray(slot), shift, offset, cover_ptr, cover,
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
        self.nchunk = len(self.arrays.rows) - 1
        self.entries = int(self.arrays.offset[-1])
        self._buffers = {}
        self._memo = None

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

    def memo(self, key, make):
        """``make()``, made again only when ``key`` (a tuple) differs from
        the last call's in any item, compared by identity: what a pair sum
        hands its kernel for this list's arrays, kept with the list (and
        freed with it) rather than built every call."""
        memo = self._memo
        if memo is None or len(memo[0]) != len(key) or not all(map(operator.is_, memo[0], key)):
            memo = self._memo = (key, make())
        return memo[1]

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
