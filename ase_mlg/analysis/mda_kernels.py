"""MDAnalysis's distance arithmetic and the InterRDF / InterRDF_s count
kernels (docs/design.md §10).

InterRDF histograms what ``MDAnalysis.lib.distances.capped_distance``
returns.  :class:`MDAConvention` says, for one frame, which search that
would use (``_determine_method``), the float32 coordinates its C kernel
sees (wrapped by MDAnalysis's own C routines where it wraps) and its kind of
minimum image; the kernels recompute each candidate pair's distance with
the same arithmetic (MDAnalysis/lib/include/calc_distances.h), keep it by
the same inclusion test and bin it as InterRDF (``np.histogram``) or
InterRDF_s (truncation) does, so the counts agree bin for bin.  Distances
are in Å.
"""

import math
from collections import namedtuple

import numpy as np
from numba import prange

from MDAnalysis.lib import c_distances as _mda_c
from MDAnalysis.lib import distances as _mda_distances
from MDAnalysis.lib.mdamath import triclinic_vectors

from ..jit import njit
from ..parallel import serial_and_parallel, use_threads
from .pairs import chunk_bounds, chunk_totals

__all__ = ["MDAConvention", "Metric", "HistogramBins", "PairWeights", "SiteBins",
           "SiteMaps", "fastns_max_cutoff", "mda_counts", "mda_s_counts"]

#: How ``capped_distance`` measures and keeps a pair in one frame: an
#: :class:`MDAConvention`'s ``coords`` (float32 (n, 3), Å), ``kind``,
#: ``box``, ``half``, ``inv`` and ``nsgrid``, with the cutoff ``cut`` (rmax,
#: Å) and its square ``cut2`` (Å^2).  :meth:`MDAConvention.metric` builds it.
Metric = namedtuple("Metric", "coords kind box half inv nsgrid cut cut2")

#: InterRDF's bins: ``np.histogram``'s ``range`` (``first``, ``last``, Å)
#: and its ``edges`` (float64, Å).
HistogramBins = namedtuple("HistogramBins", "first last edges")

#: How many ordered pairs InterRDF counts for two atoms (see
#: :func:`_pair_weight`): multiplicities ``m1``, ``m2`` of each atom in g1,
#: g2; per atom the sorted exclusion keys ``kk1[kp1[a]:kp1[a + 1]]`` with
#: multiplicities ``kc1`` (likewise ``kp2``, ``kk2``, ``kc2``); ``use_keys``
#: whether any exclusion applies.
PairWeights = namedtuple("PairWeights", "m1 m2 kp1 kk1 kc1 kp2 kk2 kc2 use_keys")

#: InterRDF_s's bins: ``nbins`` over [``rmin``, ``rmax``) (Å).
SiteBins = namedtuple("SiteBins", "rmin rmax nbins")

#: The positions of each atom in ag1 and ag2 of InterRDF_s: atom x is at
#: ``pos1[ptr1[x]:ptr1[x + 1]]`` in ag1 (likewise ``ptr2``, ``pos2``).
SiteMaps = namedtuple("SiteMaps", "ptr1 pos1 ptr2 pos2")

_PLAIN, _ORTHO_LAZY, _ORTHO_ROUND, _TRICLINIC = 0, 1, 2, 3
_FLT_EPSILON = np.float32(np.finfo(np.float32).eps)
_FLT_MAX = float(np.finfo(np.float32).max)


@njit(cache=True)
def _c_round(s):
    """C ``round``: half away from zero (``np.round`` rounds half to even)."""
    t = np.trunc(s)
    f = s - t  # exact: the fractional part of a double is a double
    if f >= 0.5:
        t += 1.0
    elif f <= -0.5:
        t -= 1.0
    return t


@njit(cache=True)
def _mda_d2(W, a, b, kind, box, half, inv):
    """Squared distance (Å^2) of atoms a, b as MDAnalysis's C kernels
    compute it.

    ``W`` holds the float32 coordinates the kernel sees (wrapped or not);
    the difference is taken in float32, as ``a[0] - b[0]`` on ``float*``
    is in C, then promoted to double.  The result is symmetric in (a, b):
    every step commutes with negation.
    """
    dx0 = np.float64(W[a, 0] - W[b, 0])
    dx1 = np.float64(W[a, 1] - W[b, 1])
    dx2 = np.float64(W[a, 2] - W[b, 2])
    if kind == _ORTHO_LAZY:  # _minimum_image_ortho_lazy (grid search, orthorhombic)
        if dx0 > half[0]:
            dx0 -= box[0]
        elif dx0 <= -half[0]:
            dx0 += box[0]
        if dx1 > half[1]:
            dx1 -= box[1]
        elif dx1 <= -half[1]:
            dx1 += box[1]
        if dx2 > half[2]:
            dx2 -= box[2]
        elif dx2 <= -half[2]:
            dx2 += box[2]
    elif kind == _ORTHO_ROUND:  # minimum_image (brute force, orthorhombic)
        if box[0] > _FLT_EPSILON:
            s = inv[0] * dx0
            dx0 = box[0] * (s - _c_round(s))
        if box[1] > _FLT_EPSILON:
            s = inv[1] * dx1
            dx1 = box[1] * (s - _c_round(s))
        if box[2] > _FLT_EPSILON:
            s = inv[2] * dx2
            dx2 = box[2] * (s - _c_round(s))
    elif kind == _TRICLINIC:  # minimum_image_triclinic: best of 27 images, first wins
        dsq_min = _FLT_MAX
        m0 = 0.0
        m1 = 0.0
        m2 = 0.0
        for ix in range(-1, 2):
            rx = dx0 + box[0] * ix
            for iy in range(-1, 2):
                ry0 = rx + box[3] * iy
                ry1 = dx1 + box[4] * iy
                for iz in range(-1, 2):
                    rz0 = ry0 + box[6] * iz
                    rz1 = ry1 + box[7] * iz
                    rz2 = dx2 + box[8] * iz
                    dsq = rz0 * rz0 + rz1 * rz1 + rz2 * rz2
                    if dsq < dsq_min:
                        dsq_min = dsq
                        m0 = rz0
                        m1 = rz1
                        m2 = rz2
        dx0 = m0
        dx1 = m1
        dx2 = m2
    return dx0 * dx0 + dx1 * dx1 + dx2 * dx2


@njit(cache=True)
def _kept_distance(d2, nsgrid, cut, cut2):
    """The distance sqrt(d2) (Å) if ``capped_distance`` keeps the pair,
    else -1.0: its grid search (FastNS) keeps ``d2 <= cut**2``, brute force
    ``sqrt(d2) <= cut`` (a NaN is never kept)."""
    if nsgrid:
        if not d2 <= cut2:
            return -1.0
    d = np.sqrt(d2)
    if not nsgrid and not d <= cut:
        return -1.0
    return d


@njit(cache=True)
def _np_histogram_bin(x, first, last, denom, nb, edges):
    """The bin ``np.histogram(..., bins=nb, range=(first, last))`` puts x
    in, or -1: numpy's uniform-bin fast path, step by step."""
    if not (x >= first and x <= last):
        return -1
    k = int(((x - first) / denom) * nb)
    if k == nb:
        k -= 1
    if x < edges[k]:
        k -= 1
    if x >= edges[k + 1] and k != nb - 1:
        k += 1
    return k


@njit(cache=True)
def _pair_weight(a, b, m1, m2, kp1, kk1, kc1, kp2, kk2, kc2, use_keys):
    """Ordered (position of a in g1, position of b in g2) pairs InterRDF
    counts for atoms a, b: m1[a] m2[b], less the excluded ones.  The keys
    InterRDF compares (exclusion-block numbers, residue/segment/chain) are
    per *position*: atom a's keys in g1 are ``kk1[kp1[a]:kp1[a+1]]``
    (sorted), with multiplicities ``kc1``; likewise for g2.  An atom listed
    twice, in two blocks, has two keys."""
    w = m1[a] * m2[b]
    if use_keys and w != 0:
        i = kp1[a]
        ie = kp1[a + 1]
        j = kp2[b]
        je = kp2[b + 1]
        while i < ie and j < je:
            if kk1[i] == kk2[j]:
                w -= kc1[i] * kc2[j]
                i += 1
                j += 1
            elif kk1[i] < kk2[j]:
                i += 1
            else:
                j += 1
    return w


def _mda_counts(pi, pj, metric, bins, weights, nchunk):
    """:func:`mda_counts`'s kernel, ``nchunk`` chunks of pairs (integer
    counts: the same for any ``nchunk``)."""
    # fields read here: the parallel loop cannot read a namedtuple's
    W = metric.coords
    kind = metric.kind
    box = metric.box
    half = metric.half
    inv = metric.inv
    nsgrid = metric.nsgrid
    cut = metric.cut
    cut2 = metric.cut2
    first = bins.first
    last = bins.last
    edges = bins.edges
    m1 = weights.m1
    m2 = weights.m2
    kp1 = weights.kp1
    kk1 = weights.kk1
    kc1 = weights.kc1
    kp2 = weights.kp2
    kk2 = weights.kk2
    kc2 = weights.kc2
    use_keys = weights.use_keys
    nb = edges.size - 1
    denom = last - first
    hist = np.zeros((nchunk, nb), dtype=np.int64)
    for c in prange(nchunk):
        lo, hi = chunk_bounds(pi.size, c, nchunk)
        for p in range(lo, hi):
            a = pi[p]
            b = pj[p]
            w = (_pair_weight(a, b, m1, m2, kp1, kk1, kc1, kp2, kk2, kc2, use_keys)
                 + _pair_weight(b, a, m1, m2, kp1, kk1, kc1, kp2, kk2, kc2, use_keys))
            if w == 0:
                continue
            d = _kept_distance(_mda_d2(W, a, b, kind, box, half, inv), nsgrid, cut, cut2)
            if d < 0.0:
                continue
            k = _np_histogram_bin(d, first, last, denom, nb, edges)
            if k >= 0:
                hist[c, k] += w
    out = chunk_totals(hist)
    k0 = _np_histogram_bin(0.0, first, last, denom, nb, edges)
    if k0 >= 0:
        for a in range(m1.size):
            out[k0] += _pair_weight(a, a, m1, m2, kp1, kk1, kc1, kp2, kk2, kc2,
                                    use_keys)
    return out


# twins through the package's threading policy: the threaded one is launched
# under the launch lock where the layer is not thread-safe (workqueue aborts
# the process when two Python threads launch at once)
_mda_counts_serial, _mda_counts_threaded = serial_and_parallel(_mda_counts)


def mda_counts(pi, pj, metric, bins, weights, nchunk):
    """InterRDF's histogram (int64 per bin) over the unordered candidate
    pairs (pi, pj), pi != pj, plus every atom with itself (d = 0).

    ``metric`` (:data:`Metric`) measures and keeps the pairs as
    ``capped_distance``; ``bins`` (:data:`HistogramBins`) are
    ``np.histogram``'s; ``weights`` (:data:`PairWeights`) weigh each pair
    as :func:`_pair_weight` says; ``nchunk`` chunks of pairs when the
    pairs are many enough to thread (``ase_mlg.parallel.use_threads``),
    else one chunk, serially.
    """
    if use_threads("pairs", pi.size):
        return _mda_counts_threaded(pi, pj, metric, bins, weights, nchunk)
    return _mda_counts_serial(pi, pj, metric, bins, weights, 1)


@njit(cache=True)
def mda_s_counts(pi, pj, metric, bins, sites, out):
    """Add InterRDF_s's per-site counts to ``out[p, q, k]`` (p, q positions
    in ag1, ag2) over the unordered candidate pairs (pi, pj) and every atom
    with itself; bins (:data:`SiteBins`) as InterRDF_s: ``int((d - rmin) *
    nbins / (rmax - rmin))`` truncated toward zero, counted when 0 <= k <
    nbins.

    ``metric`` is :func:`mda_counts`'s; ``sites`` (:data:`SiteMaps`) says
    where each atom is in ag1 and ag2.
    """
    rmin = bins.rmin
    rmax = bins.rmax
    nbins = bins.nbins
    ptr1 = sites.ptr1
    pos1 = sites.pos1
    ptr2 = sites.ptr2
    pos2 = sites.pos2
    for t in range(pi.size + ptr1.size - 1):
        if t < pi.size:
            a = pi[t]
            b = pj[t]
        else:
            a = t - pi.size
            b = a
        if ptr1[a + 1] == ptr1[a] and ptr1[b + 1] == ptr1[b]:
            continue
        if ptr2[a + 1] == ptr2[a] and ptr2[b + 1] == ptr2[b]:
            continue
        # a serial kernel: the metric's fields are read where they are used
        if a == b:
            d2 = 0.0
        else:
            d2 = _mda_d2(metric.coords, a, b, metric.kind, metric.box, metric.half,
                         metric.inv)
        d = _kept_distance(d2, metric.nsgrid, metric.cut, metric.cut2)
        if d < 0.0:
            continue
        k = int((d - rmin) * nbins / (rmax - rmin))
        if k < 0 or k >= nbins:
            continue
        for o in range(2 if a != b else 1):
            x = a if o == 0 else b
            y = b if o == 0 else a
            for s in range(ptr1[x], ptr1[x + 1]):
                p = pos1[s]
                for r in range(ptr2[y], ptr2[y + 1]):
                    out[p, pos2[r], k] += 1.0


def fastns_max_cutoff(box32):
    """The largest cutoff (Å) ``MDAnalysis.lib.nsgrid.FastNS`` accepts for
    a box ``[lx, ly, lz, alpha, beta, gamma]`` (``FastNS._prepare_box``,
    float32 arithmetic as in its Cython)."""
    tv = triclinic_vectors(box32).reshape(9)

    def degsin(deg):
        deg = np.float32(float(deg) * (math.pi / 180.0))
        return np.float32(math.sin(float(deg)))

    XX, YY, ZZ = tv[0], tv[4], tv[8]
    mc = np.float32(YY * degsin(box32[3]))
    for v in (ZZ * degsin(box32[3]), XX * degsin(box32[4]), ZZ * degsin(box32[4]),
              XX * degsin(box32[5]), YY * degsin(box32[5])):
        v = np.float32(v)
        if v < mc:
            mc = v
    return float(mc / np.float32(2))


class MDAConvention:
    """What InterRDF's ``capped_distance`` does for one frame: which search
    (``_determine_method``), the float32 coordinates its C kernel sees, the
    minimum-image kind and box arrays, and its inclusion test.

    Parameters
    ----------
    pos32 : ndarray (n, 3), float32
        Positions (Å) of the atoms the candidate pairs index.
    box32 : ndarray (6,), float32, or None
        ``ts.dimensions``: ``[lx, ly, lz, alpha, beta, gamma]`` (Å, degrees).
    n1, n2 : int
        Sizes of the two groups (``_determine_method`` looks at them).
    idx1, idx2 : ndarray of int
        The groups' rows of ``pos32`` (their extent matters without a box).
    maxrange : float
        rmax (Å).

    Attributes
    ----------
    nsgrid : bool
        True for the grid search (FastNS), False for brute force.
    coords, kind, box, half, inv
        The kernels' view of the frame (:meth:`metric`).
    """

    def __init__(self, pos32, box32, n1, n2, idx1, idx2, maxrange):
        if box32 is not None:
            if box32.shape != (6,):
                raise ValueError(f"box: expected [lx, ly, lz, alpha, beta, gamma], "
                                 f"got {box32!r}")
        # InterRDF passes g1.positions / g2.positions; _determine_method only
        # looks at their lengths, and at their extent when there is no box
        if box32 is None:
            p1, p2 = pos32[idx1], pos32[idx2]
        else:
            p1, p2 = np.empty((n1, 3), np.float32), np.empty((n2, 3), np.float32)
        method = _mda_distances._determine_method(p1, p2, maxrange, box=box32).__name__
        self.nsgrid = method == "_nsgrid_capped"
        if not self.nsgrid and method != "_bruteforce_capped":
            raise ValueError(f"MDAnalysis chose the unsupported search {method!r}")
        self.box = np.zeros(9, np.float32)
        self.half = np.zeros(3, np.float32)
        self.inv = np.zeros(3, np.float32)
        W = np.array(pos32, dtype=np.float32, order="C", copy=True)
        if box32 is None:
            self.kind = _PLAIN
            if self.nsgrid:
                # _nsgrid_capped without a box: coordinates shifted into a
                # pseudo-box, float32 arithmetic as in MDAnalysis
                lmin = W.min(axis=0)
                W -= lmin - 0.1 * maxrange
        else:
            tv = triclinic_vectors(box32)  # float32, as the C code gets it
            if self.nsgrid:
                triclinic = bool(tv[1, 0] != 0 or tv[2, 0] != 0 or tv[2, 1] != 0)
                limit = fastns_max_cutoff(box32)
                if maxrange > limit:
                    raise ValueError(
                        f"range: rmax = {float(maxrange):g} Å is beyond what this cell "
                        f"allows: InterRDF's grid search (used for {n1} x {n2} atoms) "
                        f"accepts at most {limit:.4f} Å for box {box32.tolist()}")
            else:
                triclinic = not np.all(box32[3:] == 90.0)
            if triclinic:
                self.kind = _TRICLINIC
                self.box[:] = tv.reshape(9)
                _mda_c.triclinic_pbc(W, tv)
            else:
                self.box[:3] = box32[:3]
                if self.nsgrid:
                    self.kind = _ORTHO_LAZY
                    self.half[:] = np.float32(0.5) * box32[:3]
                    _mda_c.ortho_pbc(W, box32)
                else:
                    self.kind = _ORTHO_ROUND
                    self.inv[:] = (1.0 / box32[:3].astype(np.float64)).astype(np.float32)
        self.coords = W

    def metric(self, cut):
        """The kernels' :data:`Metric` of this frame with the cutoff ``cut``
        (rmax, Å; ``cut2 = cut * cut``)."""
        cut = float(cut)
        return Metric(self.coords, self.kind, self.box, self.half, self.inv,
                      self.nsgrid, cut, cut * cut)
