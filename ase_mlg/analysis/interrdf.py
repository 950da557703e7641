"""The MDAnalysis front end: :class:`RDF` and :class:`RDF_s`, drop-ins for
:class:`MDAnalysis.analysis.rdf.InterRDF` and ``InterRDF_s`` whose per-frame
pair counts come from the grid (docs/design.md §10).  They subclass
MDAnalysis's classes, so the constructor, ``results`` and normalisation are
MDAnalysis's own, and run on its ``serial``, ``multiprocessing`` and
``dask`` backends (:mod:`ase_mlg.analysis.backends`).

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
  Like InterRDF the classes count self pairs silently (a drop-in that
  warned would break code that runs with warnings as errors);
  ``ase-mlg rdf`` says so in one line and names ``--exclude-self``.
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

import numpy as np

from MDAnalysis.analysis.rdf import InterRDF, InterRDF_s
from MDAnalysis.analysis.results import ResultsGroup
from MDAnalysis.core.groups import UpdatingAtomGroup
from MDAnalysis.lib.mdamath import triclinic_vectors

from .backends import configure
from .checks import check_nbins, check_rmax, check_template
from .mda_kernels import (HistogramBins, MDAConvention, PairWeights, SiteBins, SiteMaps,
                          mda_counts, mda_s_counts)
from .pairs import PairSource, n_chunks

__all__ = ["RDF", "RDF_s"]


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
    nbins = check_nbins(nbins)
    try:
        rmin, rmax = (float(x) for x in range)
    except (TypeError, ValueError):
        raise ValueError(f"range: expected (rmin, rmax) in Å, got {range!r}") from None
    check_rmax(rmax, "range: rmax")
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


def _fold_images(pi, pj, n):
    """Keep each unordered pair once, dropping further periodic images and
    an atom's own images (InterRDF counts one image per pair, and meets
    itself at d = 0 only)."""
    lo = np.minimum(pi, pj)
    hi = np.maximum(pi, pj)
    keep = lo != hi
    key = np.unique(lo[keep] * np.int64(n) + hi[keep])
    return key // n, key % n


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


class _GridFrames:
    """What RDF and RDF_s add to MDAnalysis's analysis classes around the
    per-frame counts: one pair source per run (per worker in parallel runs),
    its grid statistics after the run, and the forked/distributed backends
    (:mod:`ase_mlg.analysis.backends`).  Listed before InterRDF /
    InterRDF_s, so that ``super()`` reaches theirs."""

    _analysis_algorithm_is_parallelizable = True

    @classmethod
    def get_supported_backends(cls):
        return ("serial", "multiprocessing", "dask")

    def _prepare(self):
        super()._prepare()
        self._pairs = PairSource(self.template)

    def _conclude(self):
        super()._conclude()
        if self._pairs is not None:
            self.grid_stats = self._pairs.stats()
        self._pairs = None  # the grid is per run; do not keep or pickle it

    def _configure_backend(self, backend, n_workers, unsupported_backend=False):
        return configure(backend, n_workers, unsupported_backend,
                         super()._configure_backend)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_pairs"] = None  # workers build their own grid in _prepare
        return state


class RDF(_GridFrames, InterRDF):
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
        self.template = check_template(template)
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
                    self._pairs.reset()  # other atoms: a new grid

    # -- checks -------------------------------------------------------------
    def _convention(self, ts, pos32):
        box32 = _check_box(ts, self.norm)
        return MDAConvention(pos32, box32, len(self._in1), len(self._in2),
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
            bins = HistogramBins(float(self.rdf_settings["range"][0]), rmax,
                                 self.results.edges)
            weights = PairWeights(self._m1, self._m2, *self._keys, self._use_keys)
            counts = mda_counts(pi, pj, conv.metric(rmax), bins, weights,
                                n_chunks(len(pi)))
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


class RDF_s(_GridFrames, InterRDF_s):
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
        self.template = check_template(template)
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
            self._pairs.reset()
        box32 = _check_box(ts, self.norm)
        pos32 = np.ascontiguousarray(ts.positions[self._union], dtype=np.float32)
        rmin, rmax = (float(x) for x in self.rdf_settings["range"])
        pi, pj = _frame_candidates(self._pairs, ts, pos32, rmax)
        nbins = int(self.rdf_settings["bins"])
        bins = SiteBins(rmin, rmax, nbins)
        for i, (u1, u2, maps) in enumerate(self._maps):
            conv = MDAConvention(pos32, box32, len(u1), len(u2), u1, u2, rmax)
            mda_s_counts(pi, pj, conv.metric(rmax), bins, SiteMaps(*maps),
                         self.results.count[i])
        if self.norm == "rdf":
            self.results.volume_cum += ts.volume

