"""The ASE front end: :func:`rdf`, the numbers of
:func:`ase.geometry.rdf.get_rdf` (ASE 3.29) for one ``Atoms``, a list of
them, or a trajectory file, with the pairs counted through the grid
(docs/design.md §10).

Distances and bin indices are computed with get_rdf's own arithmetic, so the
bins hold the same pairs; :class:`CellTooSmall` and
:class:`VolumeNotDefined` are both ``ValueError``s and ASE's exceptions.
"""

import math
import os

import numpy as np
from numba import prange

from ..parallel import serial_and_parallel, use_threads
from .checks import check_nbins, check_rmax, check_template, one_line
from .pairs import PairSource, chunk_bounds, chunk_totals, n_chunks

__all__ = ["rdf", "CellTooSmall", "VolumeNotDefined"]


try:  # drop-in: catchable as ASE's exceptions and as ValueError
    from ase.geometry.rdf import CellTooSmall as _ASECellTooSmall
    from ase.geometry.rdf import VolumeNotDefined as _ASEVolumeNotDefined
except ImportError:  # pragma: no cover - very old ASE
    _ASECellTooSmall = _ASEVolumeNotDefined = Exception


class CellTooSmall(ValueError, _ASECellTooSmall):
    """rmax exceeds half a periodic cell height (``ase.geometry.rdf``)."""


class VolumeNotDefined(ValueError, _ASEVolumeNotDefined):
    """The cell has (nearly) zero volume (``ase.geometry.rdf``)."""


def _ase_counts(pi, pj, S, pos, cell, dr, nbins, centre, other, nchunk):
    """Counts per ``ceil(d / dr)`` index (0..nbins) over both orientations
    of each unordered pair, with get_rdf's arithmetic:
    ``d = sqrt(add.reduce((pos[j] + S @ cell - pos[i])**2))``; integer
    counts, the same for any ``nchunk``."""
    hist = np.zeros((nchunk, nbins + 1), dtype=np.int64)
    for c in prange(nchunk):
        lo, hi = chunk_bounds(pi.size, c, nchunk)
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
    return chunk_totals(hist)


# twins through the package's threading policy: the threaded one is launched
# under the launch lock where the layer is not thread-safe (workqueue aborts
# the process when two Python threads launch at once)
_ase_counts_serial, _ase_counts_threaded = serial_and_parallel(_ase_counts)


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
        return _normalised(np.bincount(x, minlength=nbins + 1)[: nbins + 1],
                           bin_edges, dr, n, rho)
    # get_rdf keeps ceil(d / dr) <= nbins: d up to rmax plus round-off
    pi, pj, S = pairs(atoms.positions, atoms.cell.array, atoms.pbc,
                      float(rmax) * (1.0 + 1e-9) + 1e-12, want_S=True)
    if ase_quirk and B is not None and A != B:
        skip = _ase_skipped_centres(atoms, pi, pj, centre, other, rmax)
        if skip.size:
            centre = centre.copy()
            centre[skip] = False
    if use_threads("pairs", len(pi)):
        count, nchunk = _ase_counts_threaded, n_chunks(len(pi))
    else:
        count, nchunk = _ase_counts_serial, 1
    counts = count(pi, pj, S, np.ascontiguousarray(atoms.positions, dtype=np.float64),
                   np.ascontiguousarray(atoms.cell.array, dtype=np.float64),
                   dr, nbins, centre, other, nchunk)
    return _normalised(counts, bin_edges, dr, n, rho)


def _normalised(counts, bin_edges, dr, n, rho):
    """get_rdf's g(r) from the counts per ``ceil(d / dr)`` index
    (0..nbins; index 0, d = 0, is dropped): each divided by ``n`` centres
    times the neighbour density ``rho`` (Å^-3) times its shell volume (Å^3)."""
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
            raise OSError(f"atoms: ASE cannot read {path!r}: {one_line(exc)}") from None
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
    rmax = check_rmax(rmax)
    nbins = check_nbins(nbins)
    template = check_template(template)
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
    pairs = PairSource(template)
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
