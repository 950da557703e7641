"""Boris's W x W x W template: the approximate pair search of Boris 1985
§III, eq. 3.6 (docs/design.md §7).

Each site looks at the sites within ``W // 2`` index steps along every axis
(half of them: each unordered pair once) and keeps the pairs within the
cutoff.  Pairs whose atoms sit further apart in the grid are missed: the
price :mod:`ase_mlg.tradeoff` measures and :mod:`ase_mlg.autotemplate`
bounds.  This is a query on a grid, like :mod:`ase_mlg.query`, and reads the
grid through its read-only :meth:`~ase_mlg.grid.MLG.view`.
"""

from collections import namedtuple

import numpy as np
from numba import prange

from .parallel import serial_and_parallel, use_threads

__all__ = ["half_template", "template_pairs"]

# The grid as the template walk reads it: ``sites`` (flat, -1 for holes),
# the grid ``shape``, the periodic axes ``pbc``, the ``cell``, and the
# Cartesian ``positions`` and ``fractional`` coordinates of the atom of
# every site (site order: the walk then reads memory near the site instead
# of jumping by atom index).
_SiteFrame = namedtuple("_SiteFrame", "sites shape pbc cell positions fractional")

# The walk's output: ``counts`` (pairs per site, the counting run), and the
# pairs ``i``, ``j``, ``S``, ``D`` written from ``start[s]`` on (the filling
# run).
_TemplateOut = namedtuple("_TemplateOut", "counts start i j S D")


def half_template(width, shape, pbc):
    """Offsets of the half template of odd ``width`` W on a grid of ``shape``.

    Returns ``(offsets, self_inverse)``: an ``(M, 3)`` int array with one of
    every pair ``{d, -d}`` (M = (W^3 - 1)/2 on a large grid: 13, 62, 171 for
    W = 3, 5, 7, Boris 1985 eq. 3.6) and a bool array marking offsets equal
    to their own negation modulo a short periodic axis (both ends then visit
    the pair with the same offset; the kernel keeps it once).

    On a periodic axis shorter than W, the offsets are one full set of
    residues so that no site is visited twice.
    """
    if width < 1 or width % 2 == 0:
        raise ValueError(f"template: width must be an odd positive int, got {width}")
    h = width // 2
    ranges, canon = [], []
    for a in range(3):
        n = max(int(shape[a]), 1)
        if pbc[a] and 2 * h + 1 > n:
            lo = -((n - 1) // 2)
            ranges.append(np.arange(lo, lo + n))
            canon.append(lambda x, n=n, lo=lo: (x - lo) % n + lo)
        else:
            ranges.append(np.arange(-h, h + 1))
            canon.append(lambda x: x)
    grid = np.stack(np.meshgrid(*ranges, indexing="ij"), -1).reshape(-1, 3)
    neg = np.stack([canon[a](-grid[:, a]) for a in range(3)], -1)
    # keep d if d > -d lexicographically, or d == -d (self-inverse, not zero)
    key = lambda v: (v[:, 0] * 4096 + v[:, 1]) * 4096 + v[:, 2]
    kd, kn = key(grid), key(neg)
    nonzero = (grid != 0).any(axis=1)
    keep = nonzero & (kd >= kn)
    return (np.ascontiguousarray(grid[keep], dtype=np.int64),
            np.ascontiguousarray((kd == kn)[keep]))


def _template_scan(frame, offsets, selfinv, cutoff, out, fill):
    """For every site, walk the half template and keep pairs with d < cutoff
    (minimum image on periodic axes).

    Parameters
    ----------
    frame : _SiteFrame
        The grid, in site order.
    offsets, selfinv : arrays
        The half template (:func:`half_template`).
    cutoff : float
        Cutoff radius (Å).
    out : _TemplateOut
        Where the counts or the pairs go.
    fill : bool
        False: count the pairs of every site into ``out.counts``; True:
        write them from ``out.start[s]`` on.  The kernel runs once each
        way; the output order is fixed by the site order, so the parallel
        and serial runs agree.
    """
    # locals: the parallel lowering cannot read tuple fields inside prange
    sites, shape, pbc, cell = frame.sites, frame.shape, frame.pbc, frame.cell
    sp, sf = frame.positions, frame.fractional
    counts, start = out.counts, out.start
    out_i, out_j, out_S, out_D = out.i, out.j, out.S, out.D
    nx, ny, nz = shape[0], shape[1], shape[2]
    rc2 = cutoff * cutoff
    for s in prange(sites.size):
        a = sites[s]
        if a < 0:
            continue
        i = s // (ny * nz)
        j = (s // nz) % ny
        k = s % nz
        pos = start[s] if fill else 0
        cnt = 0
        for o in range(offsets.shape[0]):
            ti = i + offsets[o, 0]
            tj = j + offsets[o, 1]
            tk = k + offsets[o, 2]
            if ti < 0 or ti >= nx:
                if not pbc[0]:
                    continue
                # offsets are at most one period: no division needed
                ti += nx if ti < 0 else -nx
            if tj < 0 or tj >= ny:
                if not pbc[1]:
                    continue
                # offsets are at most one period: no division needed
                tj += ny if tj < 0 else -ny
            if tk < 0 or tk >= nz:
                if not pbc[2]:
                    continue
                # offsets are at most one period: no division needed
                tk += nz if tk < 0 else -nz
            t = (ti * ny + tj) * nz + tk
            b = sites[t]
            if b < 0 or (selfinv[o] and t <= s):
                continue
            S0 = 0.0
            S1 = 0.0
            S2 = 0.0
            if pbc[0]:
                S0 = -np.rint(sf[t, 0] - sf[s, 0])
            if pbc[1]:
                S1 = -np.rint(sf[t, 1] - sf[s, 1])
            if pbc[2]:
                S2 = -np.rint(sf[t, 2] - sf[s, 2])
            dx = sp[t, 0] - sp[s, 0] + S0 * cell[0, 0] + S1 * cell[1, 0] + S2 * cell[2, 0]
            dy = sp[t, 1] - sp[s, 1] + S0 * cell[0, 1] + S1 * cell[1, 1] + S2 * cell[2, 1]
            dz = sp[t, 2] - sp[s, 2] + S0 * cell[0, 2] + S1 * cell[1, 2] + S2 * cell[2, 2]
            r2 = dx * dx + dy * dy + dz * dz
            if r2 >= rc2:
                continue
            if fill:
                out_i[pos] = a
                out_j[pos] = b
                out_S[pos, 0] = int(S0)
                out_S[pos, 1] = int(S1)
                out_S[pos, 2] = int(S2)
                out_D[pos, 0] = dx
                out_D[pos, 1] = dy
                out_D[pos, 2] = dz
                pos += 1
            cnt += 1
        if not fill:
            counts[s] = cnt


_template_scan_serial, _template_scan_parallel = serial_and_parallel(_template_scan)


def template_pairs(grid, width, cutoff):
    """Pairs within ``cutoff`` found in the W x W x W half template.

    Each unordered pair is reported at most once, with the minimum image on
    periodic axes (template mode sees one image per pair: use the exact
    query when the cutoff exceeds half a cell height).

    Parameters
    ----------
    grid : MLG
    width : int
        Odd template width W (3, 5, 7, ...).
    cutoff : float
        Cutoff radius (Å); pairs with ``d < cutoff`` are kept.

    Returns
    -------
    i, j : int64 arrays
        Atom indices of each pair.
    S : int64 array (M, 3)
        Cell shift: ``D = positions[j] - positions[i] + S @ cell``.
    D : float64 array (M, 3)
        Distance vectors (Å).
    """
    cutoff = float(cutoff)
    if not np.isfinite(cutoff) or cutoff < 0:
        raise ValueError(f"cutoff: must be finite and >= 0, got {cutoff}")
    view = grid.view()
    offsets, selfinv = half_template(width, view.shape, view.box.pbc)
    shape = np.array(view.shape, dtype=np.int64)
    sites = view.sites
    pbc = view.box.pbc.copy()
    occ = sites >= 0
    sp = np.zeros((sites.size, 3))
    sp[occ] = view.positions[sites[occ]]
    sf = view.box.fractional(sp)
    counts = np.zeros(sites.size, dtype=np.int64)
    e_i = np.empty(0, np.int64)
    e_S = np.empty((0, 3), np.int64)
    e_D = np.empty((0, 3))
    frame = _SiteFrame(sites, shape, pbc, view.box.cell, sp, sf)
    scan = _template_scan_parallel if use_threads("sites", sites.size) else _template_scan_serial
    scan(frame, offsets, selfinv, cutoff, _TemplateOut(counts, counts, e_i, e_i, e_S, e_D), False)
    start = np.zeros(sites.size, dtype=np.int64)
    np.cumsum(counts[:-1], out=start[1:])
    m = int(counts.sum())
    i = np.empty(m, np.int64)
    j = np.empty(m, np.int64)
    S = np.empty((m, 3), np.int64)
    D = np.empty((m, 3))
    scan(frame, offsets, selfinv, cutoff, _TemplateOut(counts, start, i, j, S, D), True)
    return i, j, S, D
