"""Every pair of atoms at every periodic image in reach: the neighbour list
of small systems (issue 24.1).

ML potentials ask for a neighbour list of 1-500 atoms at every step.  There
the exact block query (:mod:`ase_mlg.query`) costs what its set-up costs --
the grid's construction, the block index, the scan's room and codes, the
full list's row groups and cursors: about 30 Python-level steps, 0.3-0.9 ms
before the first pair on one to 60 atoms, where vesin and matscipy answer
in 13-60 µs.  This module answers from the arrays to ``ase.neighborlist``'s
in three compiled calls, after the cell's inverse (computed in Python
once per cell: :func:`_frame_of`): the fractional coordinates
(:func:`_reach`); for every pair of atoms ``i <= j`` the cell shifts ``S``
that can bring them within the cutoff, each image tested
(:func:`_half_pairs`; from :data:`SCREEN_ATOMS` atoms, where a cutoff
spans less than half of every periodic cell height, as in MD's cells,
only the partners a vectorised screen leaves: :func:`_screen`); the kept
pairs at both atoms (:func:`_full`).
Three kernels driven from Python, not one calling the others, because
numba optimizes a kernel with its callees' code linked in: each level
compiled the levels below once more (a first ``neighbor_list`` of 108
atoms 3.6 -> 2.7 s of compilation on AMD Zen 4; the two extra dispatches
cost 2 µs a call).

Which shifts are tested
-----------------------
With ``B`` the inverse of the (completed) cell, ``D @ B = f_j - f_i + S``
for the fractional coordinates ``f = x @ B``, and ``|(D @ B)_a| <= |D| |B[:,
a]| = |D| / h_a`` (``h_a`` the cell height; docs/design.md §6, step 3, the
same bound the grid coordinates rest on).  So a pair within ``rc`` has
``|f_j,a - f_i,a + S_a| < rc / h_a`` on every axis: on a periodic axis the
``S_a`` in that interval, padded for round-off, are all that can qualify
(however many: a cutoff larger than the cell, an atom and its own images);
on an open axis ``S_a = 0`` and the pair is dropped outright when the
interval misses 0.  Every tested image is decided as the block query
decides its candidates near the cutoff: ``D = x[j] - x[i] + S @ cell`` in
ASE's operation order (:func:`~ase_mlg.pairlist.ase_vector`) and ``d <
cutoff`` strictly, so the set of pairs is the large path's, and the pair
is written at both atoms by the large path's writer
(:func:`~ase_mlg.pairlist.put_pair`), the mirror as ``(j, i, -D, d, -S)``:
``i``, ``j``, ``S``, ``d`` and ``D`` are bitwise the large path's.

Order: sorted by ``i``, and within one ``i`` by ``j``, then ``S``
lexicographically (``np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i))``).  The
large path's order within one ``i`` is the grid's; ASE's is that of an
unstable sort.  ASE guarantees only the order by ``i``.

Why this is not a near-twin of the pair loops
---------------------------------------------
The package's pair loops walk a spatial structure: the block query
(``query._scan``) the blocks of the MLG with their bounding boxes, Boris's
template a window of sites, the pair kernels and the list writer
(``pairlist._write_pairs``) the rows of a :class:`~ase_mlg.pairlist.PairList`.
Each needs that structure built first, which is the cost this path exists to
avoid.  This loop has no structure: all ``n (n + 1) / 2`` atom pairs and an
image range per pair computed from fractional coordinates.  What a pair
*is* -- its ``D`` in ASE's order, its cutoff rule, its output entry and its
mirror -- is shared: :func:`~ase_mlg.pairlist.ase_vector` and
:func:`~ase_mlg.pairlist.put_pair` are the large path's own.  An O(n^2)
loop is the right tool only while ``n`` is small, so it stops where the
block query gets cheaper (:data:`MAX_WORK`) and the caller takes the large
path.

The call either answers or says "not mine" (None); it never raises on its
own.  Inputs it does not take -- a cell with a missing or degenerate
vector, atoms far out, cutoffs reaching a million images, too much work --
go to :class:`~ase_mlg.geometry.Box` or the large path, which raise the
errors the package always raised.
"""

import math

import numpy as np
from .jit import njit

from .geometry import Box, as_pbc
from .pairlist import PairList, PairOutput, ase_vector, put_pair, shift_codes

__all__ = ["all_pairs", "half_store", "store_list", "within_reach", "MAX_WORK"]

#: Above this many tested images (atom pairs ``n (n + 1) / 2`` times the
#: images a pair spans, ``prod(2 rc / h_a + 1)`` over periodic axes:
#: :func:`work`) the block query can be faster.  Measured (one thread,
#: 'ijdS', this path's time over the block query's): fcc Cu at 5 Å 0.79 at
#: 500 atoms (work 4.7e5), 0.73 at 864 (1.2e6), 1.30 at 1,372 (2.6e6);
#: 216 waters at 6 Å 0.73 (9.4e5); LJ argon at 8.5 Å, where each atom has
#: ~50 neighbours to write, 1.07 at 500 atoms (5.0e5) and 2.2 at 1,000
#: (1.6e6).  6e5 keeps every scene here at or below break-even and 500
#: atoms of a metal at 5-6 Å on this path.
MAX_WORK = 6e5

#: From this many atoms :func:`_half_pairs` takes the partners
#: :func:`_screen` leaves (where a pair can be within the cutoff at its
#: nearest image only).  The screen saves more than it costs from about
#: 100 atoms (``half_store``, one thread, AMD Zen 3: fcc Cu at 5 Å 22 -> 24
#: µs at 32 atoms, 101 -> 81 at 108, 543 -> 247 at 256, 2,041 -> 741 at
#: 500; argon at 9.5 Å 574 -> 348 at 256), and a rebuild of 500 argon
#: atoms in MD 1.2 ms less; but its compilation (0.6 s, once per
#: environment) takes some 2,500 rebuilds of 256 atoms to repay (70,000
#: MD steps) against 500 of 500 atoms, and it would put a first force
#: call on 256 atoms past issue 24's 5 s.
SCREEN_ATOMS = 300
#: From this many atoms a rebuild takes the screen (a list of these atoms
#: kept across calls, :class:`~ase_mlg.verletlist.VerletList`: an MD run
#: or a ``NeighborList`` updated, where its compilation is repaid): a
#: first call never compiles it below :data:`SCREEN_ATOMS`.  A rebuild of
#: 256 argon atoms in MD (9.5 Å, every 27 steps) 1.29 -> 0.84 ms, and 0.70
#: with :func:`_store_rows`' flags; an MD step 0.147 -> 0.125 ms (one
#: thread, AMD Zen 3).  The first rebuild compiles it (0.6 s).
SCREEN_REBUILD_ATOMS = 100

# a periodic atom further than this many cells out goes to the large path:
# the image interval's round-off grows with the shift (docs/design.md §6)
_FAR_CELLS = 1024.0
_EMPTY_F = np.zeros(0)
_EMPTY_I = np.zeros(0, np.int64)
_EMPTY_TABLE = np.zeros((1, 1))
_NO_NBR, _NO_CODE = np.zeros(0, np.int32), np.zeros(0, np.uint8)


@njit(cache=True, no_cpython_wrapper=True)
def _pair_cutoff(cutoff, i, j):
    """The cutoff of the pair (i, j), Å: ``cutoff = (mode, cut, radii,
    types, table)`` gives the scalar ``cut``, ``radii[i] + radii[j]`` or
    ``table[types[i], types[j]]`` (``query.CUT_*``)."""
    mode, cut, radii, types, table = cutoff
    if mode == 0:
        return cut
    if mode == 1:
        return radii[i] + radii[j]
    return table[types[i], types[j]]


def _frame(cell, pbc):
    """The completed cell, its inverse and inverse heights, as
    :class:`~ase_mlg.geometry.Box` completes and checks a cell: a float64
    (10, 3) array that nothing writes after this (a writeable array, so
    that the kernels share one compiled type with the large path's), or
    None where Box must decide (a non-finite cell, a missing vector (but for
    no cell at all and no pbc, completed to the identity, as Box does), a
    volume Box could refuse).

    ``frame[0:3]`` is the cell the shifts refer to (Box's ``full``),
    ``frame[3:6]`` its inverse ``B``, ``frame[6]`` the inverse heights ``1
    / h_a = |B[:, a]|`` and ``frame[9, 0]`` the largest residual of ``cell
    @ B - I``.  Plain Python on Python floats (IEEE doubles, the kernels'
    arithmetic), memoised by :func:`_frame_of`: compiled it was 0.55-0.7 s
    of every first call, and a cell is the same across most calls."""
    (a, b, c), (d, e, f), (g, h, k) = cell.tolist()
    pbc = pbc.tolist()
    l0 = math.sqrt(a * a + b * b + c * c)
    l1 = math.sqrt(d * d + e * e + f * f)
    l2 = math.sqrt(g * g + h * h + k * k)
    if not (l0 - l0 == 0.0 and l1 - l1 == 0.0 and l2 - l2 == 0.0):  # NaN or inf
        return None
    # Box's threshold for a missing vector is 1e-12 of the scale: a length
    # near it is Box's call
    scale = max(max(l0, l1), max(l2, 1.0))
    lo, hi = 0.5e-12 * scale, 2e-12 * scale
    if l0 <= lo and l1 <= lo and l2 <= lo and not (pbc[0] or pbc[1] or pbc[2]):
        a, b, c = 1.0, 0.0, 0.0
        d, e, f = 0.0, 1.0, 0.0
        g, h, k = 0.0, 0.0, 1.0
        l0 = l1 = l2 = 1.0
    elif not (l0 > hi and l1 > hi and l2 > hi):
        return None
    # the inverse: cofactors over the determinant
    A, B, C = e * k - f * h, f * g - d * k, d * h - e * g
    det = a * A + b * B + c * C
    # Box refuses below 1e-9 of the vectors' product: near it, Box decides
    if not abs(det) > 2e-9 * l0 * l1 * l2:
        return None
    A, B, C = A / det, B / det, C / det
    D, E, F = (c * h - b * k) / det, (a * k - c * g) / det, (b * g - a * h) / det
    G, H, K = (b * f - c * e) / det, (c * d - a * f) / det, (a * e - b * d) / det
    frame = np.zeros((10, 3))
    frame[0, 0], frame[0, 1], frame[0, 2] = a, b, c
    frame[1, 0], frame[1, 1], frame[1, 2] = d, e, f
    frame[2, 0], frame[2, 1], frame[2, 2] = g, h, k
    frame[3, 0], frame[3, 1], frame[3, 2] = A, D, G
    frame[4, 0], frame[4, 1], frame[4, 2] = B, E, H
    frame[5, 0], frame[5, 1], frame[5, 2] = C, F, K
    frame[6, 0] = math.sqrt(A * A + B * B + C * C)
    frame[6, 1] = math.sqrt(D * D + E * E + F * F)
    frame[6, 2] = math.sqrt(G * G + H * H + K * K)
    # cell @ inverse - I, the largest entry
    worst = max(abs(a * A + b * B + c * C - 1.0), abs(d * D + e * E + f * F - 1.0))
    worst = max(worst, abs(g * G + h * H + k * K - 1.0))
    worst = max(worst, max(abs(a * D + b * E + c * F), abs(a * G + b * H + c * K)))
    worst = max(worst, max(abs(d * A + e * B + f * C), abs(d * G + e * H + f * K)))
    frame[9, 0] = max(worst, max(abs(g * A + h * B + k * C), abs(g * D + h * E + k * F)))
    return frame


@njit(cache=True, no_cpython_wrapper=True)
def _shifts(df, reach, periodic):
    """The shifts ``lo..hi`` of one axis that can bring a pair within
    reach: ``|df + S| <= reach`` (fractions of a cell) on a periodic axis,
    ``S = 0`` on an open one if ``|df| <= reach``; ``lo > hi`` for none."""
    if periodic:
        return int(np.ceil(-df - reach)), int(np.floor(-df + reach))
    if abs(df) > reach:
        return 0, -1
    return 0, 0


@njit(cache=True)
def _reach(pos, frame, pbc, mode, cut, radii, table, max_work, f, pad):
    """Write the fractional coordinates ``f`` (float64[3, N], by axis) of
    the atoms in the cell of ``frame`` (:func:`_frame`), the round-off
    ``pad[:3]`` of each axis's shift interval (fractions of a cell) and
    the largest cutoff ``pad[3]`` (Å); False where the input is the large
    path's (atoms far out, too many images or too much work, a cell whose
    inverse is not exact enough).  The arrays come from the caller:
    numba's ``np.empty`` compiled for 0.2 s of a first call."""
    n = pos.shape[0]
    rcmax = cut
    if mode == 1:
        for k in range(n):
            rcmax = max(rcmax, 2.0 * radii[k])
    elif mode == 2:
        for a in range(table.shape[0]):
            for c in range(table.shape[1]):
                rcmax = max(rcmax, table[a, c])
    # -- what this path takes: the rest is the large path's (its errors too)
    scale = 1.0
    images = 1.0
    for a in range(3):
        for c in range(3):
            scale = max(scale, abs(frame[a, c]))
        if pbc[a]:
            images *= 2.0 * rcmax * frame[6, a] + 1.0
    far = False
    for k in range(n):
        for a in range(3):
            scale = max(scale, abs(pos[k, a]))
            f[a, k] = pos[k, 0] * frame[3, a] + pos[k, 1] * frame[4, a] + pos[k, 2] * frame[5, a]
            far |= pbc[a] and not abs(f[a, k]) <= _FAR_CELLS
    if (far or scale > 1e8 * max(rcmax, 1.0) or not images < 1e6
            or not 0.5 * n * (n + 1) * images <= max_work or not frame[9, 0] < 1e-12):
        return False
    # round-off pads every shift interval: the coordinates' own (relative
    # 1e-9, as the block query pads) and the inverse's, which grows with
    # the shift
    for a in range(3):
        pad[a] = (1e-9 * (scale + rcmax) * frame[6, a] + 8.0 * max(frame[9, 0], 1e-16)
                  * (2.0 * _FAR_CELLS + rcmax * frame[6, a] + 2.0))
    pad[3] = rcmax
    return True


@njit(cache=True)
def _half_pairs(pos, frame, pad, f, pbc, cutoff, self_interaction, i0, m, store, cand, cptr):
    """The pairs ``i <= j`` within the cutoff (``(mode, cut, radii,
    types, table)``: :func:`_pair_cutoff`), rows ``i0...`` on, in (i, j, S) order,
    from entry ``m`` of ``store`` (rows ``i, j, S``), in the cell of
    ``frame`` with :func:`_reach`'s ``f`` and ``pad``; the partners ``j``
    of row ``i`` are ``cand[cptr[i]:cptr[i + 1]]`` where ``cptr`` is not
    empty (:func:`_screen`), else every ``j >= i``.  Returns ``(m, i)``:
    rows before ``i`` are done (``i < n`` when row ``i`` ran out of room:
    grow the store and call again from it).  An atom's pairs with its own
    images (``i == j``) come both as S and -S (the full list writes each
    once; a half list keeps one: :func:`store_list`)."""
    n = pos.shape[0]
    full = frame[0:3]
    h0, h1, h2 = frame[6, 0], frame[6, 1], frame[6, 2]
    t0, t1, t2 = pad[0], pad[1], pad[2]
    p0, p1, p2 = pbc[0], pbc[1], pbc[2]
    screened = cptr.shape[0] > 0
    for i in range(i0, n):
        start = m
        fi0, fi1, fi2 = f[0, i], f[1, i], f[2, i]
        a0, a1 = (cptr[i], cptr[i + 1]) if screened else (i, n)
        for a in range(a0, a1):
            j = cand[a] if screened else a
            rc = _pair_cutoff(cutoff, i, j)
            if not rc > 0.0:
                continue
            lo0, hi0 = _shifts(f[0, j] - fi0, rc * h0 + t0, p0)
            lo1, hi1 = _shifts(f[1, j] - fi1, rc * h1 + t1, p1)
            lo2, hi2 = _shifts(f[2, j] - fi2, rc * h2 + t2, p2)
            # a cheap reject before the square root: sqrt(d2) < rc implies
            # d2 < rc^2 (1 + 1e-12) whatever the rounding
            rc2 = rc * rc * (1.0 + 1e-12)
            for S0 in range(lo0, hi0 + 1):
                for S1 in range(lo1, hi1 + 1):
                    for S2 in range(lo2, hi2 + 1):
                        if i == j and S0 == 0 and S1 == 0 and S2 == 0 \
                                and not self_interaction:
                            continue
                        Dx, Dy, Dz = ase_vector(pos, j, i, S0, S1, S2, full)
                        d2 = Dx * Dx + Dy * Dy + Dz * Dz
                        if d2 >= rc2:
                            continue
                        d = np.sqrt(d2)
                        if not d < rc:
                            continue
                        if m == store.shape[0]:
                            return start, i
                        store[m, 0] = i
                        store[m, 1] = j
                        store[m, 2] = S0
                        store[m, 3] = S1
                        store[m, 4] = S2
                        m += 1
    return m, n


@njit(cache=True)
def _screen(f, frame, pad, pbc, self_interaction, flags, cand, cptr):
    """The partners that :func:`_half_pairs` tests, screened, where no
    periodic axis's shift interval at the largest cutoff spans half a
    cell, so that a pair can be within its cutoff at its nearest image
    (rint) only: row ``i``'s are ``cand[cptr[i]:cptr[i + 1]]``, the ``j >=
    i`` (``j > i`` without ``self_interaction``) within the largest cutoff
    ``pad[3]`` (Å, padded by 1e-12 relative) at their nearest image, in
    order.  ``f`` float64[6, N]: :func:`_reach`'s fractional coordinates
    by axis, then the Cartesian ones (Å); ``flags`` int64[N] of scratch;
    ``cand`` int64[N (N + 1) / 2].

    Each partner's test is a superset of ``_half_pairs``' own (the only
    image it can keep, within the cutoff), computed for a whole row
    without a branch and with the coordinates by axis, so that LLVM
    vectorises it (4 pairs an instruction with AVX2).  In MD the tests
    decide at random: their branches' mispredictions were half of a
    rebuild at 256 atoms, and the screen takes every pair beyond the
    cutoff off them.  A kernel of its own, called only where it pays
    (:data:`SCREEN_ATOMS`): it compiles for about half a second."""
    n = f.shape[1]
    full = frame[0:3]
    q0, q1, q2 = 1.0 if pbc[0] else 0.0, 1.0 if pbc[1] else 0.0, 1.0 if pbc[2] else 0.0
    rcmax = pad[3]
    r0, r1, r2 = (rcmax * frame[6, 0] + pad[0], rcmax * frame[6, 1] + pad[1],
                  rcmax * frame[6, 2] + pad[2])
    rc2 = rcmax * rcmax * (1.0 + 1e-12)
    c00, c01, c02 = full[0, 0], full[0, 1], full[0, 2]
    c10, c11, c12 = full[1, 0], full[1, 1], full[1, 2]
    c20, c21, c22 = full[2, 0], full[2, 1], full[2, 2]
    f0, f1, f2, x0, x1, x2 = f[0], f[1], f[2], f[3], f[4], f[5]
    c = 0
    cptr[0] = 0
    for i in range(n):
        fi0, fi1, fi2, xi0, xi1, xi2 = f0[i], f1[i], f2[i], x0[i], x1[i], x2[i]
        for j in range(i, n):
            g0, g1, g2 = f0[j] - fi0, f1[j] - fi1, f2[j] - fi2
            S0, S1, S2 = -np.rint(g0) * q0, -np.rint(g1) * q1, -np.rint(g2) * q2
            Dx = (x0[j] - xi0) + (S0 * c00 + S1 * c10 + S2 * c20)
            Dy = (x1[j] - xi1) + (S0 * c01 + S1 * c11 + S2 * c21)
            Dz = (x2[j] - xi2) + (S0 * c02 + S1 * c12 + S2 * c22)
            flags[j] = ((abs(g0 + S0) <= r0) & (abs(g1 + S1) <= r1) & (abs(g2 + S2) <= r2)
                        & (Dx * Dx + Dy * Dy + Dz * Dz < rc2))
        for j in range(i + (not self_interaction), n):
            kept = flags[j]
            cand[c] = j
            c += kept
        cptr[i + 1] = c


@njit(cache=True)
def _full(pos, frame, idx, m, want):
    """The full list of :func:`_half_pairs`'s rows ``idx[:m]``: every pair at
    both atoms, ordered by (i, j, S).  ``want``: bits 1, 2, 4, 8 for j, d,
    D, S.  Returns ``(i, j, d, D, S)``, the unwanted ones empty.

    A kernel of its own, called after the half list from Python, not
    calling it: numba optimizes a caller with its callees' code linked in,
    so a kernel that called the half list's kernels compiled them a second
    time (0.6 s of a first ``neighbor_list``)."""
    n = pos.shape[0]
    # every array is np.empty of one of four kinds (1-D/2-D, int64/float64):
    # each other numpy call would be one more implementation to compile.
    # No constant is passed to a kernel: numba compiles a callee once more
    # for each literal argument (measured: 0.7 s of a cold start)
    none = n - n
    # -- the full list: each pair at i, its mirror at j
    cur = np.empty(n + 1, np.int64)
    for a in range(n + 1):
        cur[a] = 0
    for k in range(m):
        cur[idx[k, 0] + 1] += 1
        if idx[k, 1] != idx[k, 0]:
            cur[idx[k, 1] + 1] += 1
    for a in range(n):
        cur[a + 1] += cur[a]
    total = cur[n]
    out = PairOutput(np.empty(total, np.int64),
                     np.empty(total if want & 1 else none, np.int64),
                     np.empty(total if want & 2 else none, np.float64),
                     np.empty((total if want & 4 else none, 3), np.float64),
                     np.empty((total if want & 8 else none, 3), np.int64),
                     want & 1 != 0, want & 2 != 0, want & 4 != 0, want & 8 != 0)
    # row r takes its mirrors (partners p < r, met while i = p) before its
    # own pairs (i = r), so each row comes out by (j, S) when a group of
    # mirrors is written backwards: -S descends where S ascends.  Every
    # entry's D is computed as ASE computes it, the mirror's too: its d is
    # bitwise the pair's, and D has no -0.0 that ASE's has not.  (One call
    # of the writer and of ase_vector: each call site of an inlined
    # function is one more copy of it to compile.)
    k = 0
    while k < m:
        i = idx[k, 0]
        j = idx[k, 1]
        e = k
        while e < m and idx[e, 0] == i and idx[e, 1] == j:
            e += 1
        for r in range(2 * (e - k) if j != i else e - k):
            q, a, b, sign = k + r, i, j, 1
            if r >= e - k:
                q, a, b, sign = e - 1 - (r - (e - k)), j, i, -1
            S0, S1, S2 = sign * idx[q, 2], sign * idx[q, 3], sign * idx[q, 4]
            Dx, Dy, Dz = ase_vector(pos, b, a, S0, S1, S2, frame[0:3])
            put_pair(out, cur[a], a, b, np.sqrt(Dx * Dx + Dy * Dy + Dz * Dz),
                     Dx, Dy, Dz, S0, S1, S2)
            cur[a] += 1
        k = e
    return out.out_i, out.out_j, out.out_d, out.out_D, out.out_S


def all_pairs(positions, cell, pbc, pair_cutoff, self_interaction=False,
              quantities="ijdDS", max_work=MAX_WORK):
    """``ase.neighborlist``'s arrays of a small system, or None where the
    large path must answer.

    Parameters
    ----------
    positions : (N, 3) float64, C-contiguous
        Cartesian positions (Å), checked (:func:`~ase_mlg.geometry.as_positions`).
    cell : (3, 3) float64
        Cell vectors as rows (Å); zero on open axes allowed.
    pbc : bool or 3 bools
    pair_cutoff : tuple
        ``(mode, cut, radii, types, table)`` as ``neighborlist._parse_cutoff``
        gives them: ``query.CUT_SCALAR`` with the cutoff ``cut`` (Å),
        ``CUT_RADII`` with per-atom ``radii`` (pairs within ``r_i + r_j``),
        ``CUT_TABLE`` with per-atom ``types`` and the ``table`` of pair
        cutoffs; the unused ones None.
    self_interaction : bool
        Keep (i, i, S = 0) (when its cutoff is > 0).
    quantities : str
        The letters of 'ijdDS' wanted ('i' always comes back).
    max_work : float
        Images to test at most (:data:`MAX_WORK`); beyond, None.

    Returns
    -------
    dict with 'i' and the wanted letters (int64 / float64 arrays, the large
    path's to the bit, ordered by (i, j, S)), or None.

    Raises
    ------
    ValueError
        Only :func:`~ase_mlg.geometry.as_pbc`'s and
        :class:`~ase_mlg.geometry.Box`'s: the errors the large path raises
        first on the same input.
    """
    args = _arguments(cell, pbc, pair_cutoff, self_interaction)
    if args is None:
        return None
    want = (("j" in quantities) | ("d" in quantities) << 1 | ("D" in quantities) << 2
            | ("S" in quantities) << 3)
    res = _call(positions, args, float(max_work))
    if res is None:
        return None
    frame, idx, m = res
    i, j, d, D, S = _full(positions, frame, idx, m, want)
    return {"i": i, "j": j, "d": d, "D": D, "S": S}


def half_store(positions, cell, pbc, pair_cutoff, self_interaction=False, room=None,
               max_work=MAX_WORK):
    """The half list of a small system as the kernel writes it: ``(store, m)``,
    ``store[:m]`` the rows ``(i, j, S0, S1, S2)`` (int64) of each pair within
    the cutoff with ``i <= j``, ordered by (i, j, S), ``D = x[j] - x[i] + S @
    cell``; an atom's pairs with its own images come as both S and -S (a half
    list keeps the lexicographically positive one: :func:`store_list`). None
    where the large path must answer. ``room``: the rows expected from the
    last list of these atoms, given on a rebuild (the store grows in Python
    when they are more: a growth cost a rebuild of 500 argon atoms at 9.5 Å
    0.9 ms; a rebuild takes the screen from :data:`SCREEN_REBUILD_ATOMS`).
    Parameters, pairs and errors are those of :func:`all_pairs`: its full
    list is this one's pairs and their mirrors. The Verlet list's builds at
    small sizes (:class:`~ase_mlg.verletlist.VerletList`)."""
    args = _arguments(cell, pbc, pair_cutoff, self_interaction)
    if args is None:
        return None
    res = _call(positions, args, float(max_work), room)
    if res is None:
        return None
    _, store, m = res
    return store, m


def store_list(order, store, m, x, cell, split=None):
    """The :class:`~ase_mlg.pairlist.PairList` of a small system's
    half-list rows (:func:`half_store`: ``store[:m]`` the rows ``(i,
    j, S0, S1, S2)`` ordered by (i, j, S), an atom's pairs with its own
    images as both S and -S), rows in ``order`` (the atom of each
    rank), every image 0.  Each pair once (of an atom and its own
    image, the lexicographically positive S), and with ``split`` (Å)
    each row's pairs within it at the positions ``x`` (cell ``cell``)
    first, each part in the store's order.  Two compiled passes: the
    numpy passes they replace (a mask, the pair vectors, a sort, the
    codes) were 5 of a rebuild's 8.3 ms on 500 argon atoms at 9.5 Å."""
    n = len(order)
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n)
    rowptr = np.zeros(n + 1, np.int64)
    box = np.zeros((2, 3), np.int64)  # the shifts' range, 0 included
    x = np.ascontiguousarray(x, np.float64)
    cell = np.ascontiguousarray(cell, np.float64)
    split2 = -1.0 if split is None else float(split) ** 2
    flag = np.empty(m, np.int8)  # numba's np.empty compiles for 0.2 s
    kept = _store_rows(store, m, rank, x, cell, split2, box, rowptr, _NO_NBR, _NO_CODE,
                       flag, False)
    sdim, shifts, dtype = shift_codes(box[0], box[1])
    nbr, code = np.empty(kept, np.int32), np.empty(kept, dtype)
    _store_rows(store, m, rank, x, cell, split2, box, rowptr, nbr, code, flag, True)
    slo = box[0]
    zero_code = int(((0 - slo[0]) * sdim[1] - slo[1]) * sdim[2] - slo[2])
    return PairList(order, rowptr, nbr, code, shifts, np.zeros((n, 3), np.int64), zero_code)


@njit(cache=True, no_cpython_wrapper=True)
def _kept_in_half(store, k):
    """Whether store row ``k`` is in a half list: every pair of two atoms,
    and a pair of an atom and its own image once, with ``S``
    lexicographically >= 0 (``S = 0``: the self-interaction)."""
    if store[k, 0] != store[k, 1]:
        return True
    s0, s1, s2 = store[k, 2], store[k, 3], store[k, 4]
    return s0 > 0 or (s0 == 0 and (s1 > 0 or (s1 == 0 and s2 >= 0)))


@njit(cache=True)
def _store_rows(store, m, rank, x, cell, split2, box, rowptr, nbr, code, flag, fill):
    """:func:`store_list`'s two passes, one kernel (one compilation
    on a first call: two were 0.64 s).  Without ``fill``: each pair's
    ``flag`` (int8[m]: 0 not in the half list, 1 kept within
    ``sqrt(split2)`` or with no split (``split2 < 0``), 2 kept beyond it,
    ``D = x[j] - x[i] + S @ cell``), each row's count of kept pairs
    (``rowptr``, cumulated) and their shifts' range (``box``, widened in
    place); returns the kept count.  With ``fill`` (after that pass, on
    its flags): each atom's pairs (one run of the store) into its row,
    flag 1 first, each part in the store's order, codes in the box ``box``
    (its first row the lowest shift); returns the kept count."""
    if not fill:
        split = split2 >= 0.0
        kept = 0
        for k in range(m):
            if _kept_in_half(store, k):
                Dx, Dy, Dz = ase_vector(x, store[k, 1], store[k, 0], store[k, 2],
                                        store[k, 3], store[k, 4], cell)
                flag[k] = 1 + ((Dx * Dx + Dy * Dy + Dz * Dz > split2) & split)
                rowptr[rank[store[k, 0]] + 1] += 1
                for a in range(3):
                    box[0, a] = min(box[0, a], store[k, 2 + a])
                    box[1, a] = max(box[1, a], store[k, 2 + a])
                kept += 1
            else:
                flag[k] = 0
        for t in range(rowptr.shape[0] - 1):
            rowptr[t + 1] += rowptr[t]
        return kept
    d1, d2 = box[1, 1] - box[0, 1] + 1, box[1, 2] - box[0, 2] + 1
    # each pair's place by its flag, not a branch on its distance: inside
    # and outside the split come at random in MD, and the mispredictions
    # were a third of a rebuild of 256 argon atoms (0.30 -> 0.25 ms)
    k0 = 0
    while k0 < m:
        i = store[k0, 0]
        k1 = k0
        inner = 0
        while k1 < m and store[k1, 0] == i:
            inner += flag[k1] == 1
            k1 += 1
        w = rowptr[rank[i]]
        out = w + inner
        for k in range(k0, k1):
            f = flag[k]
            if f == 0:
                continue
            q = out if f == 2 else w
            nbr[q] = rank[store[k, 1]]
            code[q] = ((store[k, 2] - box[0, 0]) * d1 + store[k, 3] - box[0, 1]) * d2 \
                + store[k, 4] - box[0, 2]
            out += f == 2
            w += f == 1
        k0 = k1
    return rowptr[-1]


def _arguments(cell, pbc, pair_cutoff, self_interaction):
    """The kernels' arguments, one type each (so that one compiled kernel
    serves every call): ``(cell, pbc, cutoff, self_interaction)`` with
    ``cutoff = (mode, cut, radii, types, table)`` (:func:`_pair_cutoff`),
    or None for a cell the kernels do not take."""
    if not (type(pbc) is np.ndarray and pbc.dtype == np.bool_ and pbc.shape == (3,)
            and pbc.flags.c_contiguous):
        pbc = as_pbc(pbc)
    if cell.shape != (3, 3) or cell.dtype != np.float64:
        return None
    mode, cut, radii, types, table = pair_cutoff
    cutoff = (int(mode), float(cut),
              _EMPTY_F if radii is None else np.ascontiguousarray(radii, np.float64),
              _EMPTY_I if types is None else np.ascontiguousarray(types, np.int64),
              _EMPTY_TABLE if table is None else np.ascontiguousarray(table, np.float64))
    return np.ascontiguousarray(cell), pbc, cutoff, bool(self_interaction)


def within_reach(natoms, max_work=MAX_WORK):
    """Whether ``natoms`` atoms may take this path: their atom pairs alone,
    at one image each, are within ``max_work`` (a further test counts the
    images).  False: :func:`half_store` and :func:`all_pairs` answer None."""
    return 0.5 * natoms * (natoms + 1) <= max_work


def _call(positions, args, max_work, room=None):
    """The half list's rows ``(frame, store, m)``, ``store[:m]`` = (i, j,
    S) in (i, j, S) order (:func:`_half_pairs`), on Box's
    completed cell where :func:`_frame` leaves the cell to it (Box
    completes a missing vector of an open axis, or raises what the large
    path raises); None where the large path must answer."""
    cell, pbc, cutoff, self_interaction = args
    n = len(positions)
    if not within_reach(n, max_work):
        # beyond the work bound whatever the images (one at least): the
        # large path's, without compiling the kernel for nothing (3 s of a
        # first call of 10^4 atoms)
        return None
    frame = _frame_of(cell, pbc)
    if frame is None:
        frame = _frame_of(np.ascontiguousarray(Box(cell, pbc).full), pbc)
        if frame is None:
            return None
    mode, cut, radii, _, table = cutoff
    f, pad = np.empty((3, n)), np.empty(4)
    if not _reach(positions, frame, pbc, mode, cut, radii, table, max_work, f, pad):
        return None
    # room for 32 pairs an atom (a metal or an ML model's 5-6 Å in one
    # go) unless the caller knows better, doubled here, in Python, when a
    # row runs out (module doc: why no kernel drives the loop)
    store = np.empty((32 * n + 64 if room is None else int(room) + 64, 5), np.int64)
    cand, cptr = _screened(positions, frame, pad, f, pbc, self_interaction,
                           SCREEN_ATOMS if room is None else SCREEN_REBUILD_ATOMS)
    m = i = 0
    while True:
        m, i = _half_pairs(positions, frame, pad, f, pbc, cutoff, self_interaction, i, m,
                           store, cand, cptr)
        if i == n:
            return frame, store, m
        store = np.concatenate((store, np.empty_like(store)))


def _screened(positions, frame, pad, f, pbc, self_interaction, screen_from):
    """:func:`_screen`'s partners ``(cand, cptr)`` where it runs: at
    ``screen_from`` atoms and more (:data:`SCREEN_ATOMS`, or
    :data:`SCREEN_REBUILD_ATOMS` where the caller knows the room: it
    rebuilds a list it kept), where no periodic axis's shift interval at
    the largest cutoff spans half a cell; else two empty arrays
    (:func:`_half_pairs` tests every pair)."""
    n = len(positions)
    h, rcmax = frame[6], pad[3]
    if n < screen_from or not all(not p or 2.0 * (rcmax * h[a] + pad[a]) < 1.0
                                   for a, p in enumerate(pbc.tolist())):
        return _EMPTY_I, _EMPTY_I
    fx = np.concatenate((f, positions.T))
    cand, cptr = np.empty(n * (n + 1) // 2, np.int64), np.empty(n + 1, np.int64)
    _screen(fx, frame, pad, pbc, self_interaction, np.empty(n, np.int64), cand, cptr)
    return cand, cptr


_FRAMES = {}


def _frame_of(cell, pbc):
    """:func:`_frame` of ``cell`` and ``pbc``, memoised: most calls see the
    cell of the call before (MD at constant volume, a trajectory's frames),
    and a cached frame costs 1 µs against 10-15.  Nothing writes the
    arrays, so threads may share them."""
    key = (cell.tobytes(), pbc.tobytes())
    try:
        return _FRAMES[key]
    except KeyError:
        pass
    if len(_FRAMES) >= 64:
        _FRAMES.clear()
    frame = _FRAMES[key] = _frame(cell, pbc)
    return frame


def work(n, cell, pbc, rc):
    """The kernel's work estimate for ``n`` atoms at cutoff ``rc`` (Å): atom
    pairs times the images one spans (what :data:`MAX_WORK` bounds)."""
    pbc = as_pbc(pbc)
    h = Box(cell, pbc).heights
    return 0.5 * n * (n + 1) * float(np.prod(np.where(pbc, 2.0 * rc / h + 1.0, 1.0)))
