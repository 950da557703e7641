"""Radial distribution functions through the MLG (DESIGN 1.3).

Two front ends share one pair source -- an :class:`~ase_mlg.grid.MLG` kept
across frames, queried exactly (:func:`ase_mlg.query.find_pairs`, half list)
or through Boris's template (:func:`ase_mlg.grid.template_pairs`):

* :class:`RDF`, the MDAnalysis side: a drop-in for
  :class:`MDAnalysis.analysis.rdf.InterRDF` (it subclasses it, so the
  constructor, ``results`` and normalisation are InterRDF's own), whose
  per-frame pair counts come from the grid.  Runs on MDAnalysis's
  ``serial``, ``multiprocessing`` and ``dask`` backends.
* :func:`rdf`, the ASE side: the numbers of :func:`ase.geometry.rdf.get_rdf`
  for one ``Atoms``, a list of them, or a trajectory file.
* :func:`add_rdf_parser` / :func:`run_rdf_command`: the ``ase-mlg rdf``
  subcommand.

How ``RDF`` reproduces InterRDF's counts bin by bin (MDAnalysis 2.11)
--------------------------------------------------------------------
InterRDF histograms, per frame, the distances that
``MDAnalysis.lib.distances.capped_distance(g1.positions, g2.positions,
range[1], box=ts.dimensions)`` returns.  Its conventions, all matched:

* *Ordered pairs, self pairs included.*  Every (atom of g1, atom of g2) pair
  is a pair, so with ``g1 == g2`` each unordered pair counts twice and each
  atom meets itself at d = 0 (first bin when ``range[0] == 0``).  An atom
  listed twice in a group counts twice.  Exclusions (``exclusion_block``,
  ``exclude_same``) remove pairs by their positions in g1/g2 or by residue/
  segment/chain, self pairs included, exactly as InterRDF masks them.
* *One distance per pair: MDAnalysis's minimum image.*  Beyond half the box
  InterRDF does **not** count the further images of a pair (it would need a
  list of all images); the grid finds every image, and the duplicates are
  folded so each ordered pair counts once, at MDAnalysis's distance.  When
  the search InterRDF would use refuses the cutoff for the box -- its grid
  search (``FastNS``), chosen when ``len(g1) * len(g2) >= 1e8`` or when
  rmax <= 0.3 x the box extent, accepts at most about half the smallest
  box width -- InterRDF raises, and so does ``RDF``
  (:meth:`RDF.check_range`): there is nothing to match.
* *Bit-identical distances.*  MDAnalysis computes distances from float32
  coordinates, wrapped into the box in float32 (grid search, triclinic
  brute force) or not (orthorhombic brute force), with a float32 difference
  and a double minimum image that is "lazy" (one box shift, grid search),
  ``round``-based (orthorhombic brute force) or the best of the 27
  neighbouring images (triclinic; for strongly skewed boxes this is not
  always the true nearest image, and InterRDF counts what it finds).  The
  grid supplies candidate pairs within ``rmax + tol`` (``tol`` bounds the
  float32 round-off); each candidate's distance is then recomputed by the
  same arithmetic as the C kernel InterRDF's ``capped_distance`` picks
  (``_determine_method``), the wrapping done by MDAnalysis's own C routines.
  Inclusion follows that kernel too (``d**2 <= rmax**2`` for the grid
  search, ``d <= rmax`` for brute force), and binning follows
  ``np.histogram`` (``edges[k] <= d < edges[k+1]``, the last bin closed).
  So the counts agree exactly even for distances on a bin edge.
* *MDAnalysis has no per-axis periodicity*: a box means periodic along all
  three cell vectors; no box (``ts.dimensions is None``) means no images.

Results are InterRDF's: ``results.bins``, ``results.edges`` (Å),
``results.count`` (float64 pair counts summed over frames),
``results.rdf`` and, for ``norm='rdf'``, ``results.volume_cum`` (Å^3); the
normalisation is InterRDF's ``_conclude``, inherited unchanged.

One grid is kept per run (per worker in parallel runs): ``MLG.update``
(swap sweeps) follows the atoms from frame to frame, and a new grid is built
when the box changes (NPT frames).  Nothing is stored per frame, so memory
does not grow with the trajectory.
"""

import functools
import math
import multiprocessing
import numbers
import os
import sys

import numpy as np
from numba import get_num_threads, njit, prange

from MDAnalysis.analysis.backends import BackendBase, BackendDask, BackendMultiprocessing
from MDAnalysis.analysis.rdf import InterRDF, InterRDF_s
from MDAnalysis.core.groups import UpdatingAtomGroup
from MDAnalysis.analysis.results import ResultsGroup
from MDAnalysis.lib import c_distances as _mda_c
from MDAnalysis.lib import distances as _mda_distances
from MDAnalysis.lib.mdamath import triclinic_vectors

from .template import template_pairs
from .query import exact_pairs
from .tracker import GridTracker

__all__ = ["RDF", "RDF_s", "DistributedBackend", "rdf", "CellTooSmall", "VolumeNotDefined",
           "add_rdf_parser", "run_rdf_command"]


# --------------------------------------------------------------------------
# argument checks shared by both front ends and the CLI
# --------------------------------------------------------------------------

def _check_nbins(nbins, name="nbins"):
    if isinstance(nbins, (bool, np.bool_)) or not isinstance(nbins, (numbers.Integral, np.integer)):
        raise ValueError(f"{name}: expected an integer number of bins, got {nbins!r}")
    if nbins < 1:
        raise ValueError(f"{name}: must be >= 1, got {nbins}")
    return int(nbins)


def _check_rmax(rmax, name="rmax"):
    try:
        r = float(rmax)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number (Å), got {rmax!r}") from None
    if not np.isfinite(r) or r <= 0:
        raise ValueError(f"{name}: must be finite and > 0 Å, got {rmax!r}")
    return r


def _check_template(template, name="template"):
    if template is None:
        return None
    if (isinstance(template, (bool, np.bool_))
            or not isinstance(template, (numbers.Integral, np.integer))
            or template < 1 or template % 2 == 0):
        raise ValueError(f"{name}: expected an odd template width W >= 1 "
                         f"(3, 5, 7, ...) or None for exact pairs, got {template!r}")
    return int(template)


# --------------------------------------------------------------------------
# the pair source: one MLG across frames
# --------------------------------------------------------------------------

class _PairSource:
    """Unordered pairs within a cutoff, from one MLG kept across frames
    (:class:`~ase_mlg.tracker.GridTracker`; a new box builds a new grid).

    ``template=None``: every pair with ``d < cutoff``, all images (exact
    query); an odd ``template`` W: the pairs Boris's W^3 half template
    sees (minimum image, approximate).
    """

    def __init__(self, template=None):
        self.template = template
        self.tracker = GridTracker(follow_cell=False)

    def __call__(self, positions, cell, pbc, cutoff, want_S=False):
        """Return ``i, j, S`` (S is None unless ``want_S``): each unordered
        pair once, ``i != j`` or an atom with its own periodic image."""
        g = self.tracker.follow(positions, cell, pbc)
        if self.template is not None:
            i, j, S, _ = template_pairs(g, self.template, cutoff)
            return i, j, (S if want_S else None)
        return exact_pairs(g, cutoff, shifts=want_S)

    def stats(self):
        st = self.tracker.stats
        return {"builds": st["builds"], "updates": st["updates"]}


def _nchunk(npair):
    """Chunks for the parallel histogram kernels: enough to balance the
    threads, few enough that the per-chunk histograms stay small."""
    return int(max(1, min(8 * get_num_threads(), npair // 8192 + 1)))


# --------------------------------------------------------------------------
# MDAnalysis's distance arithmetic (MDAnalysis/lib/include/calc_distances.h)
# --------------------------------------------------------------------------

_PLAIN, _ORTHO_LAZY, _ORTHO_ROUND, _TRICLINIC = 0, 1, 2, 3
_FLT_EPSILON = np.float32(np.finfo(np.float32).eps)
_FLT_MAX = float(np.finfo(np.float32).max)


@njit(cache=True, inline="always")
def _c_round(s):
    """C ``round``: half away from zero (``np.round`` rounds half to even)."""
    t = np.trunc(s)
    f = s - t  # exact: the fractional part of a double is a double
    if f >= 0.5:
        t += 1.0
    elif f <= -0.5:
        t -= 1.0
    return t


@njit(cache=True, inline="always")
def _mda_d2(W, a, b, kind, box, half, inv):
    """Squared distance of atoms a, b as MDAnalysis's C kernels compute it.

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


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
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


@njit(cache=True, parallel=True)
def _mda_counts(pi, pj, W, kind, box, half, inv, nsgrid, cut, cut2, first,
                last, edges, m1, m2, kp1, kk1, kc1, kp2, kk2, kc2, use_keys,
                nchunk):
    """Histogram of InterRDF's pair distances over the unordered candidate
    pairs (pi, pj), pi != pj, plus every atom with itself (d = 0)."""
    nb = edges.size - 1
    denom = last - first
    npair = pi.size
    hist = np.zeros((nchunk, nb), dtype=np.int64)
    for c in prange(nchunk):
        lo = npair * c // nchunk
        hi = npair * (c + 1) // nchunk
        for p in range(lo, hi):
            a = pi[p]
            b = pj[p]
            w = (_pair_weight(a, b, m1, m2, kp1, kk1, kc1, kp2, kk2, kc2, use_keys)
                 + _pair_weight(b, a, m1, m2, kp1, kk1, kc1, kp2, kk2, kc2, use_keys))
            if w == 0:
                continue
            d2 = _mda_d2(W, a, b, kind, box, half, inv)
            # capped_distance's inclusion test: FastNS keeps d2 <= cutoff**2,
            # brute force keeps sqrt(d2) <= cutoff
            if nsgrid:
                if not d2 <= cut2:
                    continue
            d = np.sqrt(d2)
            if not nsgrid and not d <= cut:
                continue
            k = _np_histogram_bin(d, first, last, denom, nb, edges)
            if k >= 0:
                hist[c, k] += w
    out = hist.sum(axis=0)
    k0 = _np_histogram_bin(0.0, first, last, denom, nb, edges)
    if k0 >= 0:
        for a in range(m1.size):
            out[k0] += _pair_weight(a, a, m1, m2, kp1, kk1, kc1, kp2, kk2, kc2,
                                    use_keys)
    return out


def _fastns_max_cutoff(box32):
    """The largest cutoff ``MDAnalysis.lib.nsgrid.FastNS`` accepts for a box
    (``FastNS._prepare_box``, float32 arithmetic as in its Cython)."""
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


class _MDAConvention:
    """What InterRDF's ``capped_distance`` does for one frame: which search
    (``_determine_method``), the float32 coordinates its C kernel sees, the
    minimum-image kind and box arrays, and its inclusion test."""

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
                limit = _fastns_max_cutoff(box32)
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


# --------------------------------------------------------------------------
# parallel backends: forked workers, a dask.distributed cluster
# --------------------------------------------------------------------------

def _worker_threads(n_workers):
    """numba threads per worker process: the cores shared out, >= 1."""
    return max(1, (os.cpu_count() or 1) // max(1, int(n_workers)))


def _run_in_worker(func, nthreads, task):
    """Run one computation group in a worker with ``nthreads`` numba threads
    (workers share the cores; each would otherwise start one thread per
    core)."""
    import numba
    numba.set_num_threads(min(int(nthreads), numba.config.NUMBA_NUM_THREADS))
    return func(task)


def _fork_context(option="backend"):
    """The 'fork' multiprocessing context where workers can use it (Linux),
    else None (the platform's default start method).

    Forked workers need no ``if __name__ == "__main__":`` guard and see
    what a notebook or ``python -c`` defined.  They are safe with numba's
    TBB and workqueue threading layers (``import ase_mlg`` selects one); not
    with GNU OpenMP once it has started threads in this process -- then a
    one-line error says what to do instead of a worker dying.
    """
    if not sys.platform.startswith("linux"):
        return None
    import numba
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel has run in this process yet
        layer = None
    if layer == "omp":
        from numba.np.ufunc import omppool
        if getattr(omppool, "openmp_vendor", "GNU") == "GNU":
            raise ValueError(
                f"{option}: numba's GNU OpenMP threading layer is running in this "
                "process and cannot be used by forked workers; set "
                "NUMBA_THREADING_LAYER=tbb (or workqueue), or import ase_mlg "
                "before any other numba parallel code")
    return multiprocessing.get_context("fork")


class _ForkMultiprocessing(BackendMultiprocessing):
    """MDAnalysis's multiprocessing backend with forked workers (the
    default start method is 'forkserver' from Python 3.14) and the cores
    shared between them."""

    def apply(self, func, computations):
        ctx = _fork_context()
        func = functools.partial(_run_in_worker, func, _worker_threads(self.n_workers))
        pool = multiprocessing.Pool if ctx is None else ctx.Pool
        with pool(processes=self.n_workers) as p:
            return p.map(func, computations)


class _ForkDask(BackendDask):
    """MDAnalysis's dask backend (``scheduler='processes'``) with forked
    workers: dask spawns by default, which needs a main guard."""

    def apply(self, func, computations):
        import dask
        ctx = _fork_context()
        func = functools.partial(_run_in_worker, func, _worker_threads(self.n_workers))
        if ctx is None:
            return super().apply(func, computations)
        with dask.config.set({"multiprocessing.context": "fork"}):
            return super().apply(func, computations)


class DistributedBackend(BackendBase):
    """Run an analysis on a ``dask.distributed`` cluster.

    ``RDF(...).run(backend=DistributedBackend(client))``: the frames are
    split into ``n_workers`` parts (default: one per worker the scheduler
    knows; ``run(n_parts=...)`` splits finer), each part is sent to the
    cluster with ``client.map`` and the partial counts are summed, so the
    counts equal a serial run's.

    Every worker must import ase_mlg and MDAnalysis and read the trajectory
    files at the same paths (a shared file system): the analysis object is
    pickled, and MDAnalysis reopens its files on the worker.  Start a
    cluster with ``dask scheduler`` (prints its address, e.g.
    ``tcp://10.0.0.1:8786``) and ``dask worker tcp://10.0.0.1:8786`` on each
    machine; then ``Client("tcp://10.0.0.1:8786")``.  Worker threads are
    fine with the TBB threading layer; under the workqueue fallback start
    workers with ``--nthreads 1``.

    Parameters
    ----------
    client : distributed.Client
    n_workers : int, optional
        Parts to split the frames into (default: the cluster's workers).
    """

    def __init__(self, client, n_workers=None):
        if not (hasattr(client, "map") and hasattr(client, "gather")
                and hasattr(client, "scheduler_info")):
            raise TypeError(f"client: expected a dask.distributed.Client, got "
                            f"{type(client).__name__}")
        if n_workers is None:
            n_workers = len(client.scheduler_info().get("workers", {}))
            if n_workers < 1:
                raise ValueError("client: the cluster has no workers")
        if (isinstance(n_workers, (bool, np.bool_))
                or not isinstance(n_workers, (numbers.Integral, np.integer))
                or n_workers < 1):
            raise ValueError(f"n_workers: expected an integer >= 1, got {n_workers!r}")
        self.client = client
        super().__init__(n_workers=int(n_workers))

    def apply(self, func, computations):
        futures = self.client.map(func, computations, pure=False)
        return self.client.gather(futures)


def _configure(self, backend, n_workers, unsupported_backend, configure):
    """The shared ``_configure_backend`` of RDF and RDF_s: forked built-in
    backends; DistributedBackend accepted as supported."""
    if isinstance(backend, DistributedBackend):
        if n_workers is not None and n_workers != backend.n_workers:
            raise ValueError(f"n_workers: given as {n_workers} and as "
                             f"DistributedBackend(n_workers={backend.n_workers})")
        return backend
    executor = configure(backend=backend, n_workers=n_workers,
                         unsupported_backend=unsupported_backend)
    if type(executor) is BackendMultiprocessing:
        _fork_context()  # a clear error now rather than a dead worker later
        executor = _ForkMultiprocessing(n_workers=executor.n_workers)
    elif type(executor) is BackendDask:
        _fork_context()
        executor = _ForkDask(n_workers=executor.n_workers)
    return executor


# --------------------------------------------------------------------------
# MDAnalysis front end
# --------------------------------------------------------------------------

def _is_updating(g):
    return isinstance(g, UpdatingAtomGroup)


def _key_csr(u, keys, nu):
    """Per atom (0..nu-1), the sorted distinct ``keys`` of its positions
    ``u`` and how often each occurs: (ptr, key, count) arrays."""
    u = np.asarray(u, np.int64)
    keys = np.asarray(keys, np.int64)
    order = np.lexsort((keys, u))
    uu, kk = u[order], keys[order]
    if uu.size:
        new = np.ones(uu.size, bool)
        new[1:] = (uu[1:] != uu[:-1]) | (kk[1:] != kk[:-1])
        starts = np.flatnonzero(new)
        cnt = np.diff(np.append(starts, uu.size))
        ua, ka = uu[starts], kk[starts]
    else:
        cnt = ua = ka = np.zeros(0, np.int64)
    ptr = np.zeros(nu + 1, np.int64)
    ptr[1:] = np.cumsum(np.bincount(ua, minlength=nu))
    return ptr, ka.astype(np.int64), cnt.astype(np.int64)


def _check_range_args(nbins, range):
    nbins = _check_nbins(nbins)
    try:
        rmin, rmax = (float(x) for x in range)
    except (TypeError, ValueError):
        raise ValueError(f"range: expected (rmin, rmax) in Å, got {range!r}") from None
    _check_rmax(rmax, "range: rmax")
    if not (np.isfinite(rmin) and 0.0 <= rmin < rmax):
        raise ValueError(f"range: need 0 <= rmin < rmax, got {range!r}")
    return nbins


def _check_distance_backend(backend):
    if str(backend).lower() not in ("serial", "openmp"):
        raise ValueError(f"backend: the distance backend must be 'serial' or "
                         f"'OpenMP' (whose numbers RDF reproduces), got {backend!r}")


def _frame_candidates(pairs, ts, pos32, rmax):
    """Candidate pairs (pi, pj) of the atoms at ``pos32`` for one frame:
    every pair whose MDAnalysis distance can be <= rmax, each unordered
    pair once (further periodic images folded)."""
    periodic = ts.dimensions is not None
    cell = (triclinic_vectors(ts.dimensions, dtype=np.float64) if periodic
            else np.zeros((3, 3)))
    # candidates must include every pair whose MDAnalysis distance is
    # <= rmax: its float32 wrapping/difference and float32 box differ
    # from the float64 distance by a few float32 ulps of the coordinates
    scale = float(np.abs(pos32).max()) + 3.0 * float(np.abs(cell).max()) + rmax
    tol = 4e-6 * scale + 1e-9
    pos = pos32.astype(np.float64)
    pi, pj, _ = pairs(pos, cell, periodic, rmax + tol)
    if periodic:
        heights = 1.0 / np.linalg.norm(np.linalg.inv(cell), axis=0)
        if 2.0 * (rmax + tol) >= heights.min():
            pi, pj = _fold_images(pi, pj, len(pos))
    return pi, pj


def _check_box(ts, norm):
    box = ts.dimensions
    if box is None:
        if norm == "rdf":
            raise ValueError(
                f"norm: frame {ts.frame} has no box, so norm='rdf' (which divides "
                "by the box volume) is undefined; use norm='density' or 'none' "
                "(CLI: --norm density)")
        return None
    box32 = np.asarray(box, dtype=np.float32)
    if not (box32[:3] > 0).all():
        raise ValueError(f"box: frame {ts.frame} has a zero-length cell vector "
                         f"{box32.tolist()}")
    return box32


class RDF(InterRDF):
    r"""Intermolecular pair distribution function through the MLG; a
    drop-in for :class:`MDAnalysis.analysis.rdf.InterRDF`.

    Counts are identical to InterRDF's, bin by bin (see the module
    docstring for how its pair and distance conventions are reproduced);
    the normalisation is InterRDF's own (inherited ``_conclude``):

    * ``norm='rdf'``: :math:`g(r) = \mathrm{count}(r) / (N_\mathrm{frames}
      \, V_\mathrm{shell}(r) \, N_{AB} / \langle V \rangle)`, with
      :math:`N_{AB} = n_A n_B` minus the excluded block pairs and
      :math:`\langle V \rangle` the mean box volume (Å^3);
    * ``norm='density'``: count / (N_frames V_shell) (Å^-3);
    * ``norm='none'``: count / N_frames.

    Parameters
    ----------
    g1, g2 : AtomGroup
        Groups of the same universe.  Updating groups
        (``select_atoms(..., updating=True)``) are re-read every frame, as
        InterRDF reads them, and may be empty on some frames; a static
        group must not be empty.
    nbins : int
        Number of bins (>= 1).
    range : (float, float)
        ``(rmin, rmax)`` in Å, ``0 <= rmin < rmax``.
    norm : {'rdf', 'density', 'none'}
        ``'rdf'`` needs a box on every frame (it divides by the mean box
        volume): without one, ``run`` raises a one-line ValueError at the
        first frame (InterRDF fails with ZeroDivisionError after the last).
    exclusion_block : (int, int), optional
        Mask pairs with ``pos1 // n1 == pos2 // n2`` (positions in g1, g2),
        as InterRDF; ``(1, 1)`` with ``g1 == g2`` removes the self pairs.
        An atom listed twice has two positions, as in InterRDF.
    exclude_same : {'residue', 'segment', 'chain'}, optional
    backend : {'serial', 'OpenMP'}
        InterRDF's *distance* backend (not :meth:`run`'s): both compute the
        same numbers, which is what is reproduced ('distopia' is not).
    template : odd int, optional
        Count pairs through Boris's W^3 template instead of the exact query
        (faster, may miss pairs; see ``ase_mlg.tradeoff``).
    **kwargs
        Passed to :class:`~MDAnalysis.analysis.base.AnalysisBase`
        (``verbose``).

    Attributes
    ----------
    results.bins, results.edges : ndarray
        Bin centres and edges (Å).
    results.count : ndarray
        Pair counts per bin, summed over frames (float64, as InterRDF).
    results.rdf : ndarray
    results.volume_cum : float
        Sum of box volumes over frames (Å^3), ``norm='rdf'`` only.
    grid_stats : dict
        Grids built and swap-sweep updates in the last serial run.

    Notes
    -----
    Parallel runs: ``run(backend="multiprocessing" | "dask", n_workers=k)``
    split the frames between worker processes, each with its own grid;
    counts and volumes are summed (:meth:`_get_aggregator`), so the counts
    equal the serial run's.  Workers are forked (on Linux), so a plain
    script, ``python -c`` and a notebook work without an
    ``if __name__ == "__main__":`` guard; ``import ase_mlg`` selects numba's
    fork-safe TBB threading layer for this.  The numba threads are shared
    out between the workers.  ``run(backend=DistributedBackend(client))``
    runs on a ``dask.distributed`` cluster.

    Examples
    --------
    >>> r = RDF(u.select_atoms("name OW"), u.select_atoms("name OW"),
    ...         nbins=100, range=(0, 10)).run()         # doctest: +SKIP
    >>> r.run(backend="multiprocessing", n_workers=2)    # doctest: +SKIP
    """

    _analysis_algorithm_is_parallelizable = True

    @classmethod
    def get_supported_backends(cls):
        return ("serial", "multiprocessing", "dask")

    def __init__(self, g1, g2, nbins=75, range=(0.0, 15.0), norm="rdf",
                 exclusion_block=None, exclude_same=None, backend="serial",
                 template=None, **kwargs):
        # InterRDF's own checks (norm, exclude_same) first, with its messages
        super().__init__(g1, g2, nbins=nbins, range=range, norm=norm,
                         exclusion_block=exclusion_block,
                         exclude_same=exclude_same, backend=backend, **kwargs)
        self.rdf_settings["bins"] = _check_range_args(nbins, range)
        for name, g in (("g1", g1), ("g2", g2)):
            if len(g) == 0 and not _is_updating(g):
                raise ValueError(f"{name}: the atom group is empty")
        if g1.universe is not g2.universe:
            raise ValueError("g2: must belong to the same universe as g1")
        _check_distance_backend(backend)
        if exclusion_block is not None:
            try:
                xa, xb = (int(x) for x in exclusion_block)
                ok = xa >= 1 and xb >= 1 and tuple(exclusion_block) == (xa, xb)
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(f"exclusion_block: expected two integers >= 1, got "
                                 f"{exclusion_block!r}")
        self.template = _check_template(template)
        self._updating = _is_updating(g1) or _is_updating(g2)
        self._ix = None
        self._setup_weights()
        self._pairs = None
        self.grid_stats = None

    def _setup_weights(self):
        """Atoms of g1 U g2 (the grid's atoms) and, per atom, how many
        times it sits in g1 and g2 and the keys InterRDF's exclusions use.
        Re-run on a frame where an updating group changed."""
        ix1, ix2 = self.g1.ix, self.g2.ix
        self._ix = (ix1.copy(), ix2.copy())
        n1 = len(ix1)
        self._union, inv = np.unique(np.concatenate([ix1, ix2]), return_inverse=True)
        inv = inv.reshape(-1)
        nu = len(self._union)
        u1, u2 = inv[:n1], inv[n1:]
        self._m1 = np.bincount(u1, minlength=nu).astype(np.int64)
        self._m2 = np.bincount(u2, minlength=nu).astype(np.int64)
        self._in1 = u1
        self._in2 = u2
        self._use_keys = False
        if self._exclusion_block is not None:
            xa, xb = self._exclusion_block
            keys1 = np.arange(n1) // xa
            keys2 = np.arange(len(ix2)) // xb
            self._use_keys = True
        elif self.exclude_same is not None:
            attr = getattr(self.g1.universe.atoms[self._union], self.exclude_same)
            _, codes = np.unique(np.asarray(attr), return_inverse=True)
            codes = codes.reshape(-1)
            keys1, keys2 = codes[u1], codes[u2]
            self._use_keys = True
        else:
            keys1 = keys2 = np.zeros(0, np.int64)
            u1 = u2 = np.zeros(0, np.int64)
        self._keys = _key_csr(u1, keys1, nu) + _key_csr(u2, keys2, nu)

    def _refresh(self):
        """Updating groups: re-read them (InterRDF reads ``g.positions`` of
        the current selection every frame)."""
        if self._updating:
            ix1, ix2 = self.g1.ix, self.g2.ix
            if not (np.array_equal(ix1, self._ix[0]) and np.array_equal(ix2, self._ix[1])):
                self._setup_weights()
                if self._pairs is not None:
                    self._pairs.tracker.reset()  # other atoms: a new grid

    # -- checks -------------------------------------------------------------
    def _convention(self, ts, pos32):
        box32 = _check_box(ts, self.norm)
        return _MDAConvention(pos32, box32, len(self._in1), len(self._in2),
                              self._in1, self._in2, self.rdf_settings["range"][1])

    def check_range(self, ts=None):
        """Raise ``ValueError`` if rmax is beyond what the cell of ``ts``
        (default: the current frame) allows, i.e. where InterRDF itself
        refuses the cutoff, or if ``norm='rdf'`` and the frame has no box;
        otherwise return None."""
        ts = self._trajectory.ts if ts is None else ts
        self._refresh()
        if len(self._in1) == 0 or len(self._in2) == 0:
            _check_box(ts, self.norm)
            return
        self._convention(ts, ts.positions[self._union])

    # -- AnalysisBase ---------------------------------------------------------
    def _prepare(self):
        super()._prepare()
        self._pairs = _PairSource(self.template)

    def _single_frame(self):
        ts = self._ts
        self._refresh()
        if len(self._in1) == 0 or len(self._in2) == 0:
            # an updating selection empty on this frame: no pairs (InterRDF's
            # capped_distance of an empty group), the volume still counts
            _check_box(ts, self.norm)
        else:
            pos32 = np.ascontiguousarray(ts.positions[self._union], dtype=np.float32)
            conv = self._convention(ts, pos32)
            rmax = float(self._maxrange)
            pi, pj = _frame_candidates(self._pairs, ts, pos32, rmax)
            counts = _mda_counts(
                pi, pj, conv.coords, conv.kind, conv.box, conv.half, conv.inv,
                conv.nsgrid, rmax, rmax * rmax, float(self.rdf_settings["range"][0]),
                rmax, self.results.edges, self._m1, self._m2, *self._keys,
                self._use_keys, _nchunk(len(pi)))
            self.results.count += counts
        if self.norm == "rdf":
            self.results.volume_cum += ts.volume

    def _get_aggregator(self):
        # frames split between workers: counts and volumes add up, the bins
        # are the same in every worker
        return ResultsGroup(lookup={
            "count": ResultsGroup.ndarray_sum,
            "volume_cum": ResultsGroup.ndarray_sum,
            "bins": ResultsGroup.ndarray_mean,
            "edges": ResultsGroup.ndarray_mean,
        })

    def _conclude(self):
        super()._conclude()
        if self._pairs is not None:
            self.grid_stats = self._pairs.stats()
        self._pairs = None  # the grid is per run; do not keep or pickle it

    def _configure_backend(self, backend, n_workers, unsupported_backend=False):
        return _configure(self, backend, n_workers, unsupported_backend,
                          super()._configure_backend)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_pairs"] = None  # workers build their own grid in _prepare
        return state


@njit(cache=True)
def _mda_s_counts(pi, pj, W, kind, box, half, inv, nsgrid, cut, cut2, rmin,
                  rmax, nbins, ptr1, pos1, ptr2, pos2, out):
    """InterRDF_s's per-site counts ``out[p, q, k]`` (p, q positions in
    ag1, ag2) over the unordered candidate pairs (pi, pj) and every atom
    with itself; bins as InterRDF_s: ``int((d - rmin) * nbins / (rmax -
    rmin))`` truncated toward zero, counted when 0 <= k < nbins."""
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
        if a == b:
            d2 = 0.0
        else:
            d2 = _mda_d2(W, a, b, kind, box, half, inv)
        if nsgrid:
            if not d2 <= cut2:
                continue
        d = np.sqrt(d2)
        if not nsgrid and not d <= cut:
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


class RDF_s(InterRDF_s):
    r"""Site-specific pair distribution functions through the MLG; a
    drop-in for :class:`MDAnalysis.analysis.rdf.InterRDF_s`.

    ``results.count[i][p, q]`` is the histogram of the distance between
    atom p of ``ags[i][0]`` and atom q of ``ags[i][1]``; counts are
    InterRDF_s's bin by bin (its distances, as for :class:`RDF`, and its
    bin arithmetic ``int((d - rmin) * nbins / (rmax - rmin))``), and the
    normalisation is its own (inherited).  One grid over all atoms of all
    pairs of groups, kept across frames.  Backends as :class:`RDF`.

    Parameters
    ----------
    u : Universe
        Kept for InterRDF_s's signature (it warns that it is superfluous).
    ags : list of [AtomGroup, AtomGroup]
    nbins, range, norm, density, backend
        As InterRDF_s (``density=True`` is the deprecated
        ``norm='density'``).
    template : odd int, optional
        Count through Boris's W^3 template instead of exactly.
    """

    _analysis_algorithm_is_parallelizable = True

    @classmethod
    def get_supported_backends(cls):
        return ("serial", "multiprocessing", "dask")

    def __init__(self, u, ags, nbins=75, range=(0.0, 15.0), norm="rdf",
                 density=False, backend="serial", template=None, **kwargs):
        try:
            pairs = [tuple(p) for p in ags]
        except TypeError:
            raise ValueError("ags: expected a list of [AtomGroup, AtomGroup] pairs") from None
        if not pairs or any(len(p) != 2 for p in pairs):
            raise ValueError("ags: expected a non-empty list of [AtomGroup, AtomGroup] pairs")
        super().__init__(u, ags, nbins=nbins, range=range, norm=norm,
                         density=density, backend=backend, **kwargs)
        self.rdf_settings["bins"] = _check_range_args(nbins, range)
        _check_distance_backend(backend)
        universe = pairs[0][0].universe
        for i, (a1, a2) in enumerate(pairs):
            for name, g in (("[0]", a1), ("[1]", a2)):
                if len(g) == 0:
                    raise ValueError(f"ags[{i}]{name}: the atom group is empty")
                if g.universe is not universe:
                    raise ValueError(f"ags[{i}]{name}: must belong to the universe "
                                     "of ags[0][0]")
        self.template = _check_template(template)
        self._pairs = None
        self.grid_stats = None

    def _setup_sites(self):
        ags = self.ags
        self._sizes = [(len(a1), len(a2)) for a1, a2 in ags]
        ixs = [np.asarray(g.ix) for pair in ags for g in pair]
        self._union, inv = np.unique(np.concatenate(ixs), return_inverse=True)
        inv = inv.reshape(-1)
        nu = len(self._union)
        self._maps = []
        off = 0
        for a1, a2 in ags:
            u1 = inv[off:off + len(a1)]
            off += len(a1)
            u2 = inv[off:off + len(a2)]
            off += len(a2)
            maps = []
            for u in (u1, u2):
                order = np.argsort(u, kind="stable")
                ptr = np.zeros(nu + 1, np.int64)
                ptr[1:] = np.cumsum(np.bincount(u, minlength=nu))
                maps += [ptr, order.astype(np.int64)]
            self._maps.append((u1, u2, maps))
        self._ix = ixs

    def _prepare(self):
        super()._prepare()
        self._pairs = _PairSource(self.template)
        self._setup_sites()

    def _single_frame(self):
        ts = self._ts
        ixs = [np.asarray(g.ix) for pair in self.ags for g in pair]
        if any(not np.array_equal(a, b) for a, b in zip(ixs, self._ix)):
            # updating groups: InterRDF_s sized its arrays at the first frame
            if [(len(a1), len(a2)) for a1, a2 in self.ags] != self._sizes:
                raise ValueError(f"ags: a group changed size at frame {ts.frame}; "
                                 "InterRDF_s keeps one count per atom pair")
            self._setup_sites()
            self._pairs.tracker.reset()
        box32 = _check_box(ts, self.norm)
        pos32 = np.ascontiguousarray(ts.positions[self._union], dtype=np.float32)
        rmin, rmax = (float(x) for x in self.rdf_settings["range"])
        pi, pj = _frame_candidates(self._pairs, ts, pos32, rmax)
        nbins = int(self.rdf_settings["bins"])
        for i, (u1, u2, maps) in enumerate(self._maps):
            conv = _MDAConvention(pos32, box32, len(u1), len(u2), u1, u2, rmax)
            _mda_s_counts(pi, pj, conv.coords, conv.kind, conv.box, conv.half,
                          conv.inv, conv.nsgrid, rmax, rmax * rmax, rmin, rmax,
                          nbins, *maps, self.results.count[i])
        if self.norm == "rdf":
            self.results.volume_cum += ts.volume

    def _conclude(self):
        super()._conclude()
        if self._pairs is not None:
            self.grid_stats = self._pairs.stats()
        self._pairs = None

    def _configure_backend(self, backend, n_workers, unsupported_backend=False):
        return _configure(self, backend, n_workers, unsupported_backend,
                          super()._configure_backend)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_pairs"] = None
        return state


def _fold_images(pi, pj, n):
    """Keep each unordered pair once, dropping further periodic images and
    an atom's own images (InterRDF counts one image per pair, and meets
    itself at d = 0 only)."""
    lo = np.minimum(pi, pj)
    hi = np.maximum(pi, pj)
    keep = lo != hi
    key = np.unique(lo[keep] * np.int64(n) + hi[keep])
    return key // n, key % n


# --------------------------------------------------------------------------
# ASE front end
# --------------------------------------------------------------------------

try:  # drop-in: catchable as ASE's exceptions and as ValueError
    from ase.geometry.rdf import CellTooSmall as _ASECellTooSmall
    from ase.geometry.rdf import VolumeNotDefined as _ASEVolumeNotDefined
except ImportError:  # pragma: no cover - very old ASE
    _ASECellTooSmall = _ASEVolumeNotDefined = Exception


class CellTooSmall(ValueError, _ASECellTooSmall):
    """rmax exceeds half a periodic cell height (``ase.geometry.rdf``)."""


class VolumeNotDefined(ValueError, _ASEVolumeNotDefined):
    """The cell has (nearly) zero volume (``ase.geometry.rdf``)."""


@njit(cache=True, parallel=True)
def _ase_counts(pi, pj, S, pos, cell, dr, nbins, centre, other, nchunk):
    """Counts per ``ceil(d / dr)`` index (0..nbins) over both orientations
    of each unordered pair, with get_rdf's arithmetic:
    ``d = sqrt(add.reduce((pos[j] + S @ cell - pos[i])**2))``."""
    npair = pi.size
    hist = np.zeros((nchunk, nbins + 1), dtype=np.int64)
    for c in prange(nchunk):
        lo = npair * c // nchunk
        hi = npair * (c + 1) // nchunk
        for p in range(lo, hi):
            a = pi[p]
            b = pj[p]
            s0 = np.float64(S[p, 0])
            s1 = np.float64(S[p, 1])
            s2 = np.float64(S[p, 2])
            # S @ cell, one output component at a time
            sx = s0 * cell[0, 0] + s1 * cell[1, 0] + s2 * cell[2, 0]
            sy = s0 * cell[0, 1] + s1 * cell[1, 1] + s2 * cell[2, 1]
            sz = s0 * cell[0, 2] + s1 * cell[1, 2] + s2 * cell[2, 2]
            for o in range(2):
                if o == 0:
                    if not (centre[a] and other[b]):
                        continue
                    dx = (pos[b, 0] + sx) - pos[a, 0]
                    dy = (pos[b, 1] + sy) - pos[a, 1]
                    dz = (pos[b, 2] + sz) - pos[a, 2]
                else:  # seen from b: offset -S
                    if not (centre[b] and other[a]):
                        continue
                    dx = (pos[a, 0] - sx) - pos[b, 0]
                    dy = (pos[a, 1] - sy) - pos[b, 1]
                    dz = (pos[a, 2] - sz) - pos[b, 2]
                d = np.sqrt(dx * dx + dy * dy + dz * dz)
                k = np.ceil(d / dr)
                if k <= nbins:
                    hist[c, int(k)] += 1
    return hist.sum(axis=0)


def _ase_skipped_centres(atoms, pi, pj, centre, other, rmax):
    """Centres get_rdf skips through ``np.count_nonzero(j_indices) == 0``.

    For a partial RDF, get_rdf skips a centre atom whose neighbour list
    (second element only, within the neighbour-list radius rmax + 0.6 Å:
    radii rmax/2 plus the default skin 0.3 each) holds nothing but atom 0
    -- a test meant for an empty list.  This matters only when atom 0 has
    the second element and the centre does not; reproduced here.
    """
    if not other[0]:
        return np.zeros(0, np.int64)
    cand = np.unique(np.concatenate([pi[(pj == 0) & centre[pi] & ~other[pi]],
                                     pj[(pi == 0) & centre[pj] & ~other[pj]]]))
    if cand.size == 0:
        return cand
    # centres with another second-element neighbour already in the list
    has = np.zeros(len(atoms), bool)
    m = other[pj] & (pj != 0)
    has[pi[m]] = True
    m = other[pi] & (pi != 0)
    has[pj[m]] = True
    cand = cand[~has[cand]]
    if cand.size == 0:
        return cand
    from ase.geometry import get_distances
    partners = np.flatnonzero(other)
    partners = partners[partners != 0]
    skip = []
    for c in cand:
        if partners.size:
            _, d = get_distances(atoms.positions[c], atoms.positions[partners],
                                 cell=atoms.cell, pbc=atoms.pbc)
            if (d < rmax + 0.6).any():
                continue
        skip.append(c)
    return np.array(skip, dtype=np.int64)


def _ase_frame(atoms, bin_edges, elements, volume, pairs, ase_quirk,
               distance_matrix=None):
    """One image's RDF, as ``ase.geometry.rdf._get_rdf_per_frame``."""
    from ase.geometry.rdf import check_cell_and_r_max
    from ase.symbols import symbols2numbers

    vol = atoms.cell.volume if volume is None else volume
    if vol < 1.0e-10:
        raise VolumeNotDefined(f"volume: the cell volume is {vol:g} Å^3; give a "
                               "periodic cell or volume=")
    rmax = bin_edges.max()
    nbins = bin_edges.size - 1
    try:
        check_cell_and_r_max(atoms, rmax)
    except _ASECellTooSmall as exc:
        raise CellTooSmall(f"rmax: {exc}") from None
    natoms = len(atoms)
    dr = float(rmax / nbins)
    if elements is None:
        centre = np.ones(natoms, bool)
        other = centre
        n = natoms
        rho = natoms / vol
        B = None
    else:
        A, B = symbols2numbers(elements)
        centre = atoms.numbers == A
        other = atoms.numbers == B
        n = int(centre.sum())
        rho = int(other.sum()) / vol
    if distance_matrix is not None:
        # get_rdf's own branch: the given distances, nothing to search
        if distance_matrix.shape != (natoms, natoms):
            raise ValueError(f"distance_matrix: shape {distance_matrix.shape} does not "
                             f"match {natoms} atoms")
        indices = np.asarray(np.ceil(distance_matrix / dr), dtype=int)
        if elements is None:
            x = indices.ravel()
        else:
            x = indices[np.flatnonzero(centre)][:, np.flatnonzero(other)].ravel()
        g = np.bincount(x, minlength=nbins + 1)[: nbins + 1].astype(float)
        shell_vols = 4.0 * math.pi * dr * (bin_edges**2 + bin_edges * dr + dr**2 / 3.0)
        g[1:] /= n * rho * shell_vols[:-1]
        return g[1:]
    # get_rdf keeps ceil(d / dr) <= nbins: d up to rmax plus round-off
    pi, pj, S = pairs(atoms.positions, atoms.cell.array, atoms.pbc,
                      float(rmax) * (1.0 + 1e-9) + 1e-12, want_S=True)
    if ase_quirk and B is not None and A != B:
        skip = _ase_skipped_centres(atoms, pi, pj, centre, other, rmax)
        if skip.size:
            centre = centre.copy()
            centre[skip] = False
    counts = _ase_counts(pi, pj, S, np.ascontiguousarray(atoms.positions, dtype=np.float64),
                         np.ascontiguousarray(atoms.cell.array, dtype=np.float64),
                         dr, nbins, centre, other, _nchunk(len(pi)))
    g = counts.astype(float)
    shell_vols = 4.0 * math.pi * dr * (bin_edges**2 + bin_edges * dr + dr**2 / 3.0)
    g[1:] /= n * rho * shell_vols[:-1]
    return g[1:]


def _iter_images(images):
    from ase import Atoms
    if isinstance(images, Atoms):
        yield images
    elif isinstance(images, (str, os.PathLike)):
        import ase.io
        path = os.fspath(images)
        if not os.path.isfile(path):
            raise OSError(f"atoms: no such file {path!r}")
        try:
            # only ASE's reading is inside the try: errors raised by the
            # caller's processing of a frame are not thrown in here
            yield from ase.io.iread(path)
        except (OSError, ValueError, KeyError, IndexError, TypeError,
                StopIteration, ase.io.formats.UnknownFileTypeError) as exc:
            raise OSError(f"atoms: ASE cannot read {path!r}: {_one_line(exc)}") from None
    else:
        yield from images


def rdf(atoms, rmax, nbins, distance_matrix=None, elements=None, no_dists=False,
        volume=None, template=None, ase_quirk=True):
    r"""Radial distribution function of ASE images through the MLG; the
    numbers of :func:`ase.geometry.rdf.get_rdf` (ASE 3.29).

    Normalisation (``get_rdf``'s, solid-state convention): per image, with
    :math:`\Delta r` = rmax / nbins and bin k covering
    :math:`((k-1)\Delta r, k\Delta r]` (index ``ceil(d / dr)``),

    .. math:: g(r_k) = \frac{\mathrm{count}_k}{n\,\rho\,
              4\pi\Delta r\,(e_k^2 + e_k\Delta r + \Delta r^2/3)}

    where :math:`e_k = (k-1)\Delta r`, count_k counts ordered pairs
    (centre i, neighbour j, any periodic image, j = i excluded at d = 0),
    :math:`n` is the number of centres and :math:`\rho` the number density
    of neighbours (Å^-3) over the cell volume (vacuum included).  Full RDF:
    every atom is a centre and a neighbour; ``elements=(A, B)``: centres of
    element A, neighbours of element B.  Distances and bin indices are
    computed with get_rdf's own arithmetic, so the bins hold the same pairs
    and the result agrees with ``get_rdf`` to the last bit in practice
    (tested to 1e-12).

    The arguments are ``get_rdf``'s, in its order (a positional
    ``get_rdf`` call works unchanged); ``template`` and ``ase_quirk`` are
    ours, after them.

    Parameters
    ----------
    atoms : Atoms, iterable of Atoms, or path
        One image, several, or an ASE-readable trajectory file (read frame
        by frame with ``ase.io.iread``: memory does not grow with its
        length).  Periodic cells need height >= 2 rmax on periodic axes.
    rmax : float
        Largest distance (Å).
    nbins : int
        Number of bins.
    distance_matrix : ndarray (natoms, natoms), optional
        Distances to histogram instead of searching pairs (as ``get_rdf``:
        e.g. ``atoms.get_all_distances(mic=True)``; used for every image).
    elements : (int | str, int | str), optional
        Partial RDF between two elements.
    no_dists : bool
        Return only g, not (g, r).
    volume : float, optional
        Volume (Å^3) used instead of each cell's volume.
    template : odd int, optional
        Count pairs through Boris's W^3 template (approximate) instead of
        the exact query.
    ase_quirk : bool
        Reproduce get_rdf's skipping of a partial-RDF centre whose only
        neighbours of the second element are images of atom 0 (ASE tests
        ``np.count_nonzero(j_indices) == 0`` for an empty neighbour list,
        which is also true for the list ``[0]``); False counts those pairs.

    Returns
    -------
    g : ndarray (nbins,)
        The RDF of the single image, or the mean over images of the
        per-image RDFs (as ``get_rdf`` of a list: ``np.mean(rdfs, axis=0)``).
    r : ndarray (nbins,)
        Bin midpoints (Å); not returned with ``no_dists=True``.

    Raises
    ------
    CellTooSmall
        (a ValueError and ``ase.geometry.rdf.CellTooSmall``) rmax too large.
    VolumeNotDefined
        (a ValueError and ``ase.geometry.rdf.VolumeNotDefined``) no volume.
    ValueError, OSError
        Bad rmax/nbins/elements, no images, unreadable file.
    """
    rmax = _check_rmax(rmax)
    nbins = _check_nbins(nbins)
    template = _check_template(template)
    if elements is not None:
        try:
            elements = list(elements)
        except TypeError:
            raise ValueError(f"elements: expected two elements, got {elements!r}") from None
        if len(elements) != 2:
            raise ValueError(f"elements: expected two elements, got {elements!r}")
        from ase.symbols import symbols2numbers
        try:
            symbols2numbers(elements)
        except (KeyError, ValueError, TypeError):
            raise ValueError(f"elements: unknown element in {elements!r}") from None
    if not isinstance(no_dists, (bool, np.bool_)) and no_dists not in (0, 1):
        raise TypeError(f"no_dists: expected True or False, got {no_dists!r}")
    if volume is not None:
        try:
            volume = float(volume)
        except (TypeError, ValueError):
            raise ValueError(f"volume: expected a number (Å^3), got {volume!r}") from None
    if distance_matrix is not None:
        try:
            distance_matrix = np.asarray(distance_matrix, dtype=float)
        except (TypeError, ValueError):
            raise ValueError("distance_matrix: expected a (natoms, natoms) array of "
                             "distances") from None
        if distance_matrix.ndim != 2 or distance_matrix.shape[0] != distance_matrix.shape[1]:
            raise ValueError(f"distance_matrix: expected a square (natoms, natoms) "
                             f"array, got shape {distance_matrix.shape}")
    bin_edges = np.linspace(0.0, rmax, nbins + 1)
    pairs = _PairSource(template)
    total = None
    nimages = 0
    # a running sum in image order is np.mean(rdfs, axis=0) to the last bit
    for image in _iter_images(atoms):
        g = _ase_frame(image, bin_edges, elements, volume, pairs, ase_quirk,
                       distance_matrix)
        total = g if total is None else total + g
        nimages += 1
    if nimages == 0:
        raise ValueError("atoms: no images given")
    r = 0.5 * (bin_edges[:-1] + bin_edges[1:])
    g = total / nimages
    return g if no_dists else (g, r)


# --------------------------------------------------------------------------
# command line: ase-mlg rdf
# --------------------------------------------------------------------------

def add_rdf_parser(subparsers):
    """Add the ``rdf`` subcommand to an ``argparse`` subparsers object and
    return its parser (``func`` default: :func:`run_rdf_command`)."""
    p = subparsers.add_parser(
        "rdf", help="radial distribution function of a trajectory through the MLG",
        description="g(r) of any trajectory MDAnalysis reads, counted through the "
                    "MLG; the numbers of MDAnalysis InterRDF.  Files in MDAnalysis's "
                    "order: ase-mlg rdf TOPOLOGY TRAJECTORY (as Universe(topology, "
                    "trajectory)), or one file holding both.")
    p.add_argument("files", metavar="FILE", nargs="+",
                   help="TOPOLOGY TRAJECTORY, or a single file with topology and "
                        "coordinates (PDB, GRO, ...)")
    p.add_argument("--select", default="all",
                   help="MDAnalysis selection of the first group (default: all)")
    p.add_argument("--select2", default=None,
                   help="selection of the second group (default: same as --select)")
    p.add_argument("--updating", action="store_true",
                   help="re-evaluate the selections every frame (e.g. 'around 3.5 "
                        "protein'), as select_atoms(..., updating=True)")
    p.add_argument("--rmin", type=float, default=0.0, help="smallest distance, Å (default 0)")
    p.add_argument("--rmax", type=float, default=15.0, help="largest distance, Å (default 15)")
    p.add_argument("--nbins", type=int, default=75, help="number of bins (default 75)")
    p.add_argument("--norm", choices=("rdf", "density", "none"), default="rdf",
                   help="normalisation: rdf = g(r) (needs a box), density = "
                        "count / shell volume (Å^-3), none = count per frame "
                        "(default rdf)")
    p.add_argument("--exclude-self", action="store_true",
                   help="drop each atom's pair with itself (d = 0); the same as "
                        "--exclusion-block 1 1 (needs the two groups equal)")
    p.add_argument("--exclusion-block", type=int, nargs=2, metavar=("N1", "N2"),
                   default=None,
                   help="drop pairs in the same block of N1 atoms of the first "
                        "group and N2 of the second (InterRDF's exclusion_block)")
    p.add_argument("--exclude-same", choices=("residue", "segment", "chain"),
                   default=None,
                   help="drop pairs of atoms in the same residue/segment/chain")
    p.add_argument("--plot", metavar="OUT.png", default=None, help="write a plot of g(r)")
    p.add_argument("--output", metavar="TABLE.txt", default=None,
                   help="write the table r, g(r), count here (default: stdout)")
    p.add_argument("--backend", choices=("serial", "multiprocessing", "dask"),
                   default="serial",
                   help="where frames run: serial (default; a progress bar when "
                        "stderr is a terminal), multiprocessing or dask processes "
                        "on this machine")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes for multiprocessing/dask (default 1); "
                        "with --scheduler, parts to split the frames into "
                        "(default: the cluster's workers)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run on a dask.distributed cluster, e.g. tcp://host:8786 "
                        "(start one with 'dask scheduler' and 'dask worker ADDRESS'; "
                        "workers must read the files at the same paths)")
    p.add_argument("--template", type=int, default=None, metavar="W",
                   help="count through the W^3 template (odd W) instead of exactly")
    p.add_argument("--start", type=int, default=None, help="first frame (default 0)")
    p.add_argument("--stop", type=int, default=None,
                   help="stop before this frame (default: the end)")
    p.add_argument("--step", type=int, default=None, help="frame step (default 1)")
    p.set_defaults(func=run_rdf_command)
    return p


def _one_line(exc, limit=300):
    """An exception's message on one line, cut to ``limit`` characters
    (MDAnalysis's format errors list every format it knows)."""
    msg = " ".join(str(exc).split()) or type(exc).__name__
    return msg if len(msg) <= limit else msg[:limit - 3] + "..."


def _open_universe(files):
    import warnings
    import MDAnalysis as mda
    if len(files) > 2:
        raise ValueError(f"FILE: expected TOPOLOGY TRAJECTORY or one file, got "
                         f"{len(files)} files")
    names = ("TOPOLOGY", "TRAJECTORY") if len(files) == 2 else ("FILE",)
    for name, path in zip(names, files):
        if not os.path.isfile(path):
            raise OSError(f"{name}: no such file {path!r}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # guessed attributes, missing masses ...
            return mda.Universe(*files)
    except Exception as exc:  # MDAnalysis raises many kinds for a bad file
        what = "FILE" if len(files) == 1 else "TOPOLOGY/TRAJECTORY"
        names = " with ".join(repr(os.path.basename(f)) for f in files)
        raise OSError(f"{what}: MDAnalysis cannot read {names}: "
                      f"{_one_line(exc, 200)}") from None


def _select(u, selection, option, updating=False):
    try:
        g = u.select_atoms(selection, updating=updating)
    except Exception as exc:
        raise ValueError(f"{option}: invalid selection {selection!r}: {_one_line(exc)}") from None
    if len(g) == 0 and not updating:
        raise ValueError(f"{option}: selection {selection!r} matched no atoms")
    return g


def _connect(address, timeout=10):
    try:
        from distributed import Client
    except ImportError:
        raise ValueError("--scheduler: dask.distributed is not installed "
                         "(pip install 'dask[distributed]')") from None
    try:
        return Client(address, timeout=timeout)
    except Exception as exc:  # OSError, TimeoutError, ValueError for bad addresses
        raise ValueError(f"--scheduler: cannot connect to {address!r}: "
                         f"{_one_line(exc)}") from None


def run_rdf_command(args, out=None):
    """Run ``ase-mlg rdf`` for parsed ``args`` (see :func:`add_rdf_parser`).

    Writes the table (columns r [Å], g(r), count) to ``--output`` or
    ``out`` (default stdout), and a plot when ``--plot`` is given.  Bad
    input raises ``ValueError``/``OSError`` with a one-line message naming
    the argument.  Returns the finished :class:`RDF`.
    """
    out = sys.stdout if out is None else out
    _check_rmax(args.rmax, "--rmax")
    _check_nbins(args.nbins, "--nbins")
    if not (np.isfinite(args.rmin) and 0.0 <= args.rmin < args.rmax):
        raise ValueError(f"--rmin: need 0 <= rmin < rmax, got {args.rmin}")
    _check_template(args.template, "--template")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers: must be >= 1, got {args.workers}")
    if args.scheduler is not None and args.backend != "serial":
        raise ValueError(f"--scheduler: runs on the cluster; drop --backend {args.backend}")
    block = args.exclusion_block
    if block is not None and min(block) < 1:
        raise ValueError(f"--exclusion-block: need two integers >= 1, got {block}")
    if args.exclude_self:
        if block is not None or args.exclude_same is not None:
            raise ValueError("--exclude-self: use it alone, not with --exclusion-block "
                             "or --exclude-same")
        if args.select2 is not None and args.select2 != args.select:
            raise ValueError("--exclude-self: needs the two groups equal (no --select2)")
        block = (1, 1)
    if block is not None and args.exclude_same is not None:
        raise ValueError("--exclude-same: cannot be combined with --exclusion-block")
    for option, path in (("--output", args.output), ("--plot", args.plot)):
        # fail before the run, not after it
        if path is not None and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            raise OSError(f"{option}: directory of {path!r} does not exist")
    u = _open_universe(args.files)
    g1 = _select(u, args.select, "--select", args.updating)
    g2 = (g1 if args.select2 is None
          else _select(u, args.select2, "--select2", args.updating))
    r = RDF(g1, g2, nbins=args.nbins, range=(args.rmin, args.rmax), norm=args.norm,
            template=args.template, exclusion_block=block,
            exclude_same=args.exclude_same)
    if args.backend == "dask":
        try:
            import dask  # noqa: F401
        except ImportError:
            raise ValueError("--backend: dask is not installed") from None
    # frame 0 is checked before any work, so that the common bad file gives
    # one clean error line (non-finite coordinates, no box with --norm rdf,
    # rmax beyond the cell)
    bad = ~np.isfinite(u.atoms.positions).all(axis=1)
    if bad.any():
        raise ValueError(f"TRAJECTORY: frame 0 has non-finite coordinates for atom(s) "
                         f"{np.flatnonzero(bad)[:10].tolist()}")
    if u.dimensions is None and args.norm == "rdf":
        raise ValueError("--norm: the trajectory has no box, so g(r) (--norm rdf) is "
                         "undefined; use --norm density or --norm none")
    frames = dict(start=args.start, stop=args.stop, step=args.step)
    try:
        r.check_range()  # frame 0 now; later frames (NPT boxes) during the run
        if args.scheduler is not None:
            client = _connect(args.scheduler)
            with client:
                r.run(**frames, backend=DistributedBackend(client),
                      n_parts=args.workers)
        elif args.backend == "serial":
            # a progress bar only for a person watching a terminal
            r.run(**frames, verbose=bool(getattr(sys.stderr, "isatty", None)
                                         and sys.stderr.isatty()))
        else:
            r.run(**frames, backend=args.backend, n_workers=args.workers or 1)
    except ValueError as exc:
        if str(exc).startswith("range: rmax"):
            raise ValueError(f"--rmax: {_one_line(exc)}") from None
        if str(exc).startswith("norm:"):
            raise ValueError(f"--norm: {_one_line(exc)[6:]}") from None
        raise
    table = np.column_stack([r.results.bins, r.results.rdf, r.results.count])
    header = (f"ase-mlg rdf: {' '.join(args.files)}, {r.n_frames} frames, "
              f"{len(g1)} x {len(g2)} atoms, norm={args.norm}\n"
              "r/Angstrom  g(r)  count")
    if args.output is None:
        np.savetxt(out, table, fmt=("%.6f", "%.10g", "%.0f"), header=header)
    else:
        np.savetxt(args.output, table, fmt=("%.6f", "%.10g", "%.0f"), header=header)
    if args.plot is not None:
        _plot(r, args.plot, f"{args.select} / {args.select2 or args.select}")
    return r


def _plot(r, path, label):
    # object-oriented Agg figure: no pyplot state, no display needed
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(6, 4))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.plot(r.results.bins, r.results.rdf, lw=1.5, label=label)
    ax.axhline(1.0, color="0.6", lw=0.8)
    ax.set_xlabel("r (Å)")
    ax.set_ylabel({"rdf": "g(r)", "density": "ρ(r) (Å$^{-3}$)",
                   "none": "count per frame"}[r.norm])
    ax.legend(frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
