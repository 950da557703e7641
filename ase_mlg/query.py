"""Exact range queries on a Monotonic Logical Grid (docs/design.md §6).

The site array of an :class:`~ase_mlg.grid.MLG` is cut into aligned blocks
(``bx x by x bz`` sites, the last block of an axis possibly shorter).  For
every block we keep the bounding box of the *stored grid coordinates* of all
its sites (holes included), and the same for every slab ``I`` (all blocks
with block index ``I`` along axis 0) and every row ``(I, J)``.

Why the query is exact
----------------------
1. *Monotone bounds.*  Along a line of axis 0 the stored coordinates satisfy
   ``X[i] <= X[i+1]`` for ``0 <= i < NX-1`` (the MLG order; the periodic seam
   condition is not needed).  Take slabs ``I`` and ``I+1``.  Every site of
   slab ``I+1`` at ``(i, j, k)`` has the site ``(i - bx, j, k)`` of slab
   ``I`` on its line, with a smaller or equal X, so ``xmin(I) <= xmin(I+1)``;
   every site of slab ``I`` has the last site ``(NX-1, j, k)`` of its line,
   which lies in slab ``I+1`` or beyond, with a larger or equal X, so
   ``xmax(I) <= xmax(I+1)`` -- also when the last slab is short.  The same
   argument holds for rows ``(I, J)`` along axis 1 at fixed ``I`` and for
   blocks ``(I, J, K)`` along axis 2 at fixed ``(I, J)``.  Only comparisons
   inside a line, away from any seam, are used, so it holds on periodic axes
   too, whatever offset each cyclic line's window has.
2. *Contiguous ranges.*  With ``lo`` and ``hi`` both non-decreasing, the
   set ``{I : hi[I] >= qlo and lo[I] <= qhi}`` of slabs whose range meets a
   query interval is the index interval ``[first I with hi >= qlo, last I
   with lo <= qhi]``, found by two binary searches.  Slabs outside it cannot
   hold a site whose coordinate is in the query interval.  Inside it we test
   the full 3-D box of every slab, then search rows, then blocks, the same
   way; a block survives only if its box meets the query box.  So every site
   whose stored coordinates lie in the query box is in a surviving block.
3. *Spheres are boxes in grid space.*  Grid coordinates are ``g_a = f_a h_a``
   with ``h_a = 1/|b_a|`` the cell height (``b_a`` the reciprocal vector), so
   ``|dg_a| = h_a |D . b_a| <= |D|``: a Cartesian sphere of radius r maps
   into the axis-aligned box ``g +- r`` for any triclinic cell, and into the
   sphere of radius ``stretch * r`` (``g = N x``, ``N`` the unit normals,
   ``stretch**2`` the largest eigenvalue of ``N N^T``; 1 for orthorhombic
   cells), which each atom's row tests the candidate blocks' boxes against.
4. *Periodic images.*  A site's stored coordinate is ``g(atom) + m_s h``
   (``m_s`` an integer per periodic axis, recovered by rounding; the
   deviation from an exact multiple is measured every call and added to the
   padding).  The image ``m`` of site ``s`` sits at ``stored(s) + m h``, so
   a pair with cell shift ``S`` is found by querying the box shifted by
   ``-m h`` with ``m = S - m_s(j) + m_s(i)``.  For each query block we visit
   every integer ``m`` whose shifted box meets the global range of stored
   coordinates -- all images, however many (cutoffs larger than the cell,
   an atom with its own images).
5. *Exact distances.*  Candidates pass a cheap test on positions gathered in
   block order (with a relative tolerance), and are then decided on
   ``D = positions[j] - positions[i] + S @ cell`` and ``d < cutoff``
   (strict), computed as ``ase.neighborlist`` computes them.

Every box test is padded by ``2 * max deviation + 1e-9 * scale`` so
round-off can only add candidates, never lose one.

One scan, several outputs
-------------------------
The scan (:func:`_scan`) visits blocks in chunks on Python threads (the
kernel releases the GIL).  Each chunk scans only candidate blocks
``B >= A`` (and, for ``B == A``, non-negative images and slots ``u >= t``),
so every unordered pair {(i, j, S), (j, i, -S)} is met once, and writes it
as (rank of j, code of S) in the row of i: a :class:`PairList`, the half
list in compressed sparse rows, atoms numbered by their *rank* along the
grid's blocks.  The rows come out in rank order whatever the chunking, so
the list is the same for any number of threads.  Consumers read it: the
calculator sums pair potentials over it directly
(:mod:`ase_mlg.potentials`); :func:`find_pairs` writes ASE's arrays from
it, each pair once in grid order (``half=True``) or at both atoms sorted by
atom (the mirror is ``(j, i, -D, d, -S)``, bitwise what ASE computes for
it), in a fixed number of row groups with a cursor per group and atom, so
that the output too is the same for any number of threads.
"""

from collections import namedtuple

import numpy as np
from .jit import njit

from .blocks import BlockIndex
from .pairlist import PairList, ase_vector, shift_codes
from .parallel import run_chunks, threads_for

__all__ = ["half_list", "pair_list", "find_pairs", "exact_pairs", "CUT_SCALAR",
           "CUT_RADII", "CUT_TABLE"]

CUT_SCALAR, CUT_RADII, CUT_TABLE = 0, 1, 2

# The scan's arguments besides the block index (:attr:`BlockIndex.blocks`),
# one structure per role; the kernels read their fields into locals.

# How far the scan looks: the per-atom query ``radius`` (atom order, an
# upper bound of every cutoff of the atom), the grid-space box ``pad``, the
# ``tolerance`` within which the fast distance does not decide, and the
# ``stretch`` of grid space (:attr:`ase_mlg.geometry.Box.stretch`).
_Reach = namedtuple("_Reach", "radius pad tolerance stretch")

# The pair cutoff: ``mode`` (CUT_SCALAR, CUT_RADII, CUT_TABLE) selects the
# scalar ``cutoff``, ``radii[t] + radii[u]`` or ``table[types[t],
# types[u]]``; ``radii``/``types`` are per slot (block order), empty where
# the mode ignores them.  ``self_interaction`` keeps (i, i, S=0).
# Only pairs with one of atoms ``0 .. nown - 1`` are wanted (half_list's
# ``owned``): ``owned`` (bool, per block) says whether the block holds one
# (a later atom's row skips the blocks without), ``far`` (3, nslot) is
# ``P`` with every other slot at +inf, what a later atom's row reads
# ((3, 0) where every pair is wanted).
_PairCutoff = namedtuple("_PairCutoff", "mode cutoff radii types table self_interaction "
                                        "owned nown far")

# How a kept pair is written: its image ``m`` as the code ``((m0 -
# shift_lo[0]) * shift_dim[1] + m1 - shift_lo[1]) * shift_dim[2] + m2 -
# shift_lo[2]``; with ``split2 >= 0`` each row holds its pairs with squared
# distance <= split2 first.
_RowFormat = namedtuple("_RowFormat", "shift_lo shift_dim split2")

# Where the pairs go: ``nbr`` (and the codes, beside it) from ``start`` on, at most ``cap``
# of them; ``rowcount`` (by rank) gets every row's length.
_Room = namedtuple("_Room", "nbr start cap rowcount")


# --------------------------------------------------------------------------
# the scan
# --------------------------------------------------------------------------

@njit(cache=True)
def _search(arr, col, base, n, q, right):
    """First index t in [0, n) with ``arr[base + t, col] >= q``, or
    ``> q`` when ``right`` (numpy's ``searchsorted`` sides); n if none."""
    lo = 0
    hi = n
    while lo < hi:
        mid = (lo + hi) >> 1
        x = arr[base + mid, col]
        if x > q or (x == q and not right):
            hi = mid
        else:
            lo = mid + 1
    return lo


@njit(cache=True)
def _overlap(box, base, n, qlo, qhi, a):
    """First and last of the ``n`` boxes from row ``base`` that can meet
    [qlo, qhi] along axis ``a``, along which their lows and highs are both
    monotone (docs/design.md §6): bisection on each."""
    right = n >= 0  # True as a value: a literal compiles _search once per value
    return (_search(box, 3 + a, base, n, qlo[a], not right),
            _search(box, a, base, n, qhi[a], right) - 1)


@njit(cache=True)
def _apart(box, r, qlo, qhi, a, b):
    """Box ``r`` (lows at columns 0-2, highs at 3-5) misses the query box
    [qlo, qhi] on axis ``a`` or ``b`` (the third axis was bisected)."""
    return (box[r, a] > qhi[a] or box[r, 3 + a] < qlo[a]
            or box[r, b] > qhi[b] or box[r, 3 + b] < qlo[b])


@njit(cache=True)
def _push(cand, ncand, b, m0, m1, m2):
    if ncand >= cand.shape[0]:
        # doubled by concatenation: a slice assignment compiles numba's
        # shape-error formatting (seconds from an empty cache)
        cand = np.concatenate((cand, cand))
    cand[ncand, 0] = b
    cand[ncand, 1] = m0
    cand[ncand, 2] = m1
    cand[ncand, 3] = m2
    return cand


@njit(cache=True)
def _block_candidates(cand, qlo, qhi, nb, S1, R2, BB, m0, m1, m2, ncand,
                      bmin):
    """Append every block ``b >= bmin`` whose box meets [qlo, qhi] (slab ->
    row -> block, each level by binary search on its monotone axis)."""
    nbx, nby, nbz = nb[0], nb[1], nb[2]
    ax0 = bmin - bmin  # axes as values, not literals (see _overlap)
    ax1, ax2 = ax0 + 1, ax0 + 2
    IA = bmin // (nby * nbz)
    JA = (bmin // nbz) % nby
    KA = bmin % nbz
    I0, I1 = _overlap(S1, ax0, nbx, qlo, qhi, ax0)
    I0 = max(I0, IA)
    for I in range(I0, I1 + 1):
        if _apart(S1, I, qlo, qhi, ax1, ax2):
            continue
        rb = I * nby
        J0, J1 = _overlap(R2, rb, nby, qlo, qhi, ax1)
        if I == IA:
            J0 = max(J0, JA)
        for J in range(J0, J1 + 1):
            r = rb + J
            if _apart(R2, r, qlo, qhi, ax0, ax2):
                continue
            bb = r * nbz
            K0, K1 = _overlap(BB, bb, nbz, qlo, qhi, ax2)
            if I == IA and J == JA:
                K0 = max(K0, KA)
            for K in range(K0, K1 + 1):
                b = bb + K
                if _apart(BB, b, qlo, qhi, ax0, ax1):
                    continue
                cand = _push(cand, ncand, b, m0, m1, m2)
                ncand += 1
    return cand, ncand


@njit(cache=True)
def _slot_values(slot_atom, radii, types, mode):
    """Radius and type of every slot (block order), where the mode uses
    them (empty otherwise: no memory for what a scalar cutoff ignores)."""
    nslot = slot_atom.shape[0]
    rs = np.zeros(nslot if mode == 1 else 0)
    ts = np.zeros(nslot if mode == 2 else 0, dtype=np.int64)
    for t in range(nslot):
        a = slot_atom[t]
        if a < 0:
            continue
        if mode == 1:
            rs[t] = radii[a]
        elif mode == 2:
            ts[t] = types[a]
    return rs, ts


@njit(cache=True)
def _prepare(A, blocks, reach, cand, cf, qlo, qhi):
    """Candidate (block, image) list of query block ``A``: every block
    ``B >= A`` whose box meets A's box grown by the largest query radius of
    its atoms, for every periodic image ``m`` that can reach the global
    range of stored coordinates, but for those of ``A`` itself with a
    negative image (they only hold mirrors of pairs kept from the other
    side).

    ``cand`` (rows of block, m0, m1, m2) and ``cf`` (each candidate's box
    shifted to its image at 0:6, the Cartesian image shift at 6:9) are the
    caller's buffers, ``qlo``/``qhi`` scratch (3,).  Returns ``(cand, cf,
    ncand)``: the buffers, grown when they were short, and the count.
    """
    nb, bsz, slot_atom = blocks.nb, blocks.bsz, blocks.slot_atom
    BB, R2, S1, glob = blocks.BB, blocks.R2, blocks.S1, blocks.glob
    periods, cell = blocks.periods, blocks.cell
    rat, pad = reach.radius, reach.pad
    # query radius of the block
    tA0 = A * bsz
    RA = 0.0
    for t in range(tA0, tA0 + bsz):
        a = slot_atom[t]
        if a >= 0 and rat[a] > RA:
            RA = rat[a]
    RA += pad
    # image ranges on periodic axes
    mlo0 = mhi0 = mlo1 = mhi1 = mlo2 = mhi2 = 0
    if periods[0] > 0.0:
        mlo0 = int(np.ceil((BB[A, 0] - RA - glob[3]) / periods[0]))
        mhi0 = int(np.floor((BB[A, 3] + RA - glob[0]) / periods[0]))
    if periods[1] > 0.0:
        mlo1 = int(np.ceil((BB[A, 1] - RA - glob[4]) / periods[1]))
        mhi1 = int(np.floor((BB[A, 4] + RA - glob[1]) / periods[1]))
    if periods[2] > 0.0:
        mlo2 = int(np.ceil((BB[A, 2] - RA - glob[5]) / periods[2]))
        mhi2 = int(np.floor((BB[A, 5] + RA - glob[2]) / periods[2]))
    ncand = np.int64(0)  # not Literal[int](0), which compiles the callee twice
    for m0 in range(mlo0, mhi0 + 1):
        for m1 in range(mlo1, mhi1 + 1):
            for m2 in range(mlo2, mhi2 + 1):
                qlo[0] = BB[A, 0] - RA - m0 * periods[0]
                qhi[0] = BB[A, 3] + RA - m0 * periods[0]
                qlo[1] = BB[A, 1] - RA - m1 * periods[1]
                qhi[1] = BB[A, 4] + RA - m1 * periods[1]
                qlo[2] = BB[A, 2] - RA - m2 * periods[2]
                qhi[2] = BB[A, 5] + RA - m2 * periods[2]
                cand, ncand = _block_candidates(
                    cand, qlo, qhi, nb, S1, R2, BB, m0, m1, m2, ncand, A)
    if cf.shape[0] < ncand:
        cf = np.empty((cand.shape[0], 9))
    # per candidate: its box shifted to the image, and the Cartesian
    # image shift
    nkeep = 0
    for c in range(ncand):
        B = cand[c, 0]
        m0 = cand[c, 1]
        m1 = cand[c, 2]
        m2 = cand[c, 3]
        # mirrors of pairs kept from the other side
        if B == A and (m0 < 0 or (m0 == 0 and (m1 < 0 or (m1 == 0 and m2 < 0)))):
            continue
        cand[nkeep, 0] = B
        cand[nkeep, 1] = m0
        cand[nkeep, 2] = m1
        cand[nkeep, 3] = m2
        for ax in range(3):
            sh = (m0, m1, m2)[ax] * periods[ax]
            cf[nkeep, ax] = BB[B, ax] + sh
            cf[nkeep, 3 + ax] = BB[B, 3 + ax] + sh
        cf[nkeep, 6] = m0 * cell[0, 0] + m1 * cell[1, 0] + m2 * cell[2, 0]
        cf[nkeep, 7] = m0 * cell[0, 1] + m1 * cell[1, 1] + m2 * cell[2, 1]
        cf[nkeep, 8] = m0 * cell[0, 2] + m1 * cell[1, 2] + m2 * cell[2, 2]
        nkeep += 1
    ncand = nkeep
    return cand, cf, ncand


@njit(cache=True, nogil=True)
def _scan(b0, b1, blocks, reach, cutoff, fmt, room, out_c):
    """Half scan of blocks ``[b0, b1)``: every unordered pair
    {(i, j, S), (j, i, -S)} with d < cutoff(i, j) once.

    Parameters
    ----------
    b0, b1 : int
        Query blocks.
    blocks : Blocks
        The block index (:attr:`BlockIndex.blocks`).
    reach : _Reach
        Query radii, box padding and the fast distance's tolerance.
    cutoff : _PairCutoff
        The pair cutoff.
    fmt : _RowFormat
        Image codes and the row split.
    room : _Room
        Output room and row lengths.
    out_c : uint8[:] or int32[:]
        The pairs' image codes, beside ``room.nbr``.  Not a field of
        ``room``: its dtype depends on the number of images, and numba 0.59
        dispatches a namedtuple of four or more fields whose field types
        vary between calls to the wrong overload (fixed in later numba;
        tests/test_kernel_structures.py keeps every structure to one type).

    Returns
    -------
    end, count : int
        Blocks ``[b0, end)`` are done, with ``count`` pairs written.
        ``end < b1`` when block ``end`` ran out of room: nothing beyond
        ``room.cap`` is written, and the caller scans on from block ``end``
        into new room (a short guess costs one block again, not the chunk).

    Notes
    -----
    Candidates are tested on positions gathered in block order
    (``blocks.P``, in the frame of the stored coordinates); a pair whose
    fast distance is farther than ``reach.tolerance`` from its cutoff is
    decided by it, the others on ``D = x[j] - x[i] + S @ cell`` from the
    original positions ``blocks.positions``, as ASE computes it.  Each pair
    is kept from the side whose (block, image, slot) comes first: candidate
    blocks ``B >= A``, and for ``B == A`` the non-negative images and slots
    ``u >= t``.

    Kept pairs are written in row order (the row is the rank of slot ``t``)
    as the rank of ``u`` and the code of the image ``m`` (the cell shift of
    the pair is ``S = m + MS[u] - MS[t]``).  With ``fmt.split2 >= 0`` each
    row holds its pairs with (fast) squared distance ``<= split2`` first,
    then the others, each group in scan order: the force loop's cutoff
    branch is then predicted (this replaces a second pass over the list,
    :meth:`PairList.inner_first`, 17% of a build).  Runs without the GIL,
    one call per chunk of blocks on Python threads.
    """
    bsz, slot_atom, slot_rank = blocks.bsz, blocks.slot_atom, blocks.slot_rank
    P, pos, G, MS = blocks.P, blocks.positions, blocks.G, blocks.MS
    natom_blk, cell = blocks.natom_blk, blocks.cell
    rat, pad, ftol, stretch = reach.radius, reach.pad, reach.tolerance, reach.stretch
    mode, cut, self_interaction = cutoff.mode, cutoff.cutoff, cutoff.self_interaction
    rs, ts, table = cutoff.radii, cutoff.types, cutoff.table
    slo, sdim, split2 = fmt.shift_lo, fmt.shift_dim, fmt.split2
    out_j, lo, cap = room.nbr, room.start, room.cap
    rowcount = room.rowcount
    total = 0
    cand = np.empty((64, 4), dtype=np.int64)
    cf = np.empty((64, 9))
    later_j = np.empty(256, dtype=np.int64)  # a row's pairs beyond split2
    later_c = np.empty(256, dtype=np.int64)
    hit = np.empty(bsz, dtype=np.int64)
    pc = np.empty(64, dtype=np.int64)  # a row's candidate blocks
    dist2 = np.empty(bsz)
    d2all = np.empty(bsz)
    nown, far, owned = cutoff.nown, cutoff.far, cutoff.owned
    P0, P1, P2 = P[0], P[1], P[2]
    F0, F1, F2 = far[0], far[1], far[2]
    qlo = np.empty(3)
    qhi = np.empty(3)
    for A in range(b0, b1):
        if natom_blk[A] == 0:
            continue
        before = total
        cand, cf, ncand = _prepare(A, blocks, reach, cand, cf, qlo, qhi)
        tA0 = A * bsz
        for t in range(tA0, tA0 + bsz):
            a = slot_atom[t]
            if a < 0:
                continue
            Rf = rat[a] + ftol
            Rf2 = Rf * Rf
            # the sphere that holds every neighbour's stored grid
            # coordinate: the radius stretched to grid space, and each
            # stored coordinate's round-off (pad per axis) on three axes
            Rg = stretch * rat[a] + 1.7320508075688772 * pad
            Rg2 = Rg * Rg
            g0 = G[0, t]
            g1 = G[1, t]
            g2 = G[2, t]
            px = P[0, t]
            py = P[1, t]
            pz = P[2, t]
            ra = rs[t] if mode == 1 else 0.0
            ta = ts[t] if mode == 2 else 0
            own_t = a < nown
            Q0, Q1, Q2 = (P0, P1, P2) if own_t else (F0, F1, F2)
            n = 0
            nlater = 0
            # the blocks whose box meets the sphere (not the sphere's box:
            # 11.7 -> 9 blocks a row, fcc argon at 9.5 Å), compacted without
            # a branch, as the slots below (-7 % of the scan)
            if pc.shape[0] < ncand:
                pc = np.empty(2 * ncand, dtype=np.int64)
            npc = 0
            for c in range(ncand):
                e0 = max(cf[c, 0] - g0, 0.0, g0 - cf[c, 3])
                e1 = max(cf[c, 1] - g1, 0.0, g1 - cf[c, 4])
                e2 = max(cf[c, 2] - g2, 0.0, g2 - cf[c, 5])
                pc[npc] = c
                npc += e0 * e0 + e1 * e1 + e2 * e2 <= Rg2
            for ic in range(npc):
                c = pc[ic]
                B = cand[c, 0]
                if not (own_t or owned[B]):
                    continue
                m0 = cand[c, 1]
                m1 = cand[c, 2]
                m2 = cand[c, 3]
                mzero = m0 == 0 and m1 == 0 and m2 == 0
                qx = px - cf[c, 6]
                qy = py - cf[c, 7]
                qz = pz - cf[c, 8]
                u0 = B * bsz
                kmin = 0
                if B == A and mzero:  # the row's own slot and later ones
                    kmin = t - u0 + (0 if self_interaction else 1)
                # the pre-filter: the block's distances in a loop the
                # compiler vectorises (slices: no index wraparound), then
                # the slots that pass, compacted without a branch (one loop
                # doing both ran 18% slower: scalar, 4x unrolled, spilling)
                xa = Q0[u0:u0 + bsz]
                xb = Q1[u0:u0 + bsz]
                xc = Q2[u0:u0 + bsz]
                for k in range(bsz):
                    dx = xa[k] - qx
                    dy = xb[k] - qy
                    dz = xc[k] - qz
                    d2all[k] = dx * dx + dy * dy + dz * dz
                npass = 0
                for k in range(bsz):
                    d2f = d2all[k]
                    hit[npass] = k
                    dist2[npass] = d2f
                    npass += (d2f < Rf2) & (k >= kmin)
                while nlater + npass > later_j.shape[0]:
                    later_j = np.concatenate((later_j, later_j))
                    later_c = np.concatenate((later_c, later_c))
                for h in range(npass):
                    u = u0 + hit[h]
                    d2f = dist2[h]
                    if mode == 0:
                        rc = cut
                    elif mode == 1:
                        rc = ra + rs[u]
                    else:
                        rc = table[ta, ts[u]]
                    hi = rc + ftol
                    if d2f >= hi * hi:
                        continue
                    S0 = m0 + MS[u, 0] - MS[t, 0]
                    S1_ = m1 + MS[u, 1] - MS[t, 1]
                    S2 = m2 + MS[u, 2] - MS[t, 2]
                    lo_ = rc - ftol
                    if lo_ <= 0.0 or d2f >= lo_ * lo_:
                        # as ASE: positions[j] - positions[i] + S @ cell
                        # rare: pairs near the cutoff
                        Dx, Dy, Dz = ase_vector(pos, slot_atom[u], a, S0, S1_, S2, cell)
                        if not np.sqrt(Dx * Dx + Dy * Dy + Dz * Dz) < rc:
                            continue
                    code = ((m0 - slo[0]) * sdim[1] + m1 - slo[1]) * sdim[2] + m2 - slo[2]
                    # written to both places, kept in one: no branch on the
                    # split, a coin toss for pairs in the skin (scan -9 %)
                    rj = slot_rank[u]
                    if total < cap:
                        out_j[lo + total] = rj
                        out_c[lo + total] = code
                    later_j[nlater] = rj
                    later_c[nlater] = code
                    inner = np.int64((split2 < 0.0) | (d2f <= split2))
                    total += inner
                    n += inner
                    nlater += 1 - inner
            for k in range(nlater):
                if total < cap:
                    out_j[lo + total] = later_j[k]
                    out_c[lo + total] = later_c[k]
                total += 1
            n += nlater
            rowcount[slot_rank[t]] = n
        if total > cap:
            return A, before
    return b1, total


def _image_bounds(index, rmax, pad):
    """Bounds of the image ``m`` over every pair the scan can keep: the
    image range of the global box (as in ``_prepare``)."""
    glob, periods = index.glob, index.periods
    slo = np.zeros(3, np.int64)
    shi = np.zeros(3, np.int64)
    R = rmax + pad
    for c in range(3):
        if periods[c] > 0.0:
            mlo = int(np.ceil((glob[c] - R - glob[3 + c]) / periods[c]))
            mhi = int(np.floor((glob[3 + c] + R - glob[c]) / periods[c]))
            slo[c], shi[c] = mlo, mhi
    return slo, shi


MAX_IMAGES = 1e7  # periodic images per query: 2 rc / h + 1 per axis


def _compact_in_place(nbr, code, segs, lo, offs):
    """Move every chunk's pairs to their final offsets ``offs`` inside the
    first room (``nbr``/``code``, chunk ``ch``'s first piece at ``lo[ch]``;
    later pieces in their own arrays).  Targets and first pieces are both in
    chunk order, so first pieces moving down go in chunk order and those
    moving up in reverse order without overwriting a piece not yet moved
    (numpy copies overlapping slices correctly); the later pieces land last,
    in ranges no first piece occupies any more."""
    nchunk = len(segs)
    first = [segs[ch][0][3] for ch in range(nchunk)]
    for ch in range(nchunk):
        if offs[ch] < lo[ch] and first[ch]:
            nbr[offs[ch]:offs[ch] + first[ch]] = nbr[lo[ch]:lo[ch] + first[ch]]
            code[offs[ch]:offs[ch] + first[ch]] = code[lo[ch]:lo[ch] + first[ch]]
    for ch in range(nchunk - 1, -1, -1):
        if offs[ch] > lo[ch] and first[ch]:
            nbr[offs[ch]:offs[ch] + first[ch]] = nbr[lo[ch]:lo[ch] + first[ch]]
            code[offs[ch]:offs[ch] + first[ch]] = code[lo[ch]:lo[ch] + first[ch]]
    for ch in range(nchunk):
        w = offs[ch] + first[ch]
        for src_j, src_c, at, k in segs[ch][1:]:
            nbr[w:w + k] = src_j[at:at + k]
            code[w:w + k] = src_c[at:at + k]
            w += k


def half_list(index, rat, mode=CUT_SCALAR, cut=0.0, radii=None, types=None,
              table=None, self_interaction=False, pairs_per_atom=None,
              reuse=None, split=None, owned=None):
    """Every pair within the cutoff once, exactly (see module doc), as a
    :class:`PairList` in grid order.

    Parameters
    ----------
    index : BlockIndex
    rat : float64 array (N,)
        Per-atom query radius: an upper bound of the cutoff of every pair
        the atom is in (the scan's filter radius), Å.
    mode : CUT_SCALAR | CUT_RADII | CUT_TABLE
        Pair cutoff ``cut``, ``radii[i] + radii[j]`` or
        ``table[types[i], types[j]]``; pairs with ``d < cutoff`` are kept.
    self_interaction : bool
        Keep the pair (i, i, S=0) when ``0 < cutoff``.
    pairs_per_atom : float, optional
        Expected pairs per atom (e.g. from the previous list); sizes the
        output so that one scan suffices.  A short guess costs a second scan.
    split : float, optional
        Order each row's pairs within ``split`` (Å) first (the force loop's
        cutoff branch is then predicted); default: scan order.
    reuse : PairList, optional
        A previous list whose arrays may be overwritten (no reallocation in
        MD); it is consumed: its pair arrays are taken over, or released
        before new ones are allocated, so that two lists never coexist.
    owned : int, optional
        Only pairs with one of atoms ``0 .. owned - 1`` (a rank's own atoms,
        then its ghosts): the pairs of two later atoms are left out, not
        scanned.  Default: every pair.
    """
    grid = index.grid
    n = grid.natoms
    mode = int(mode)
    rat = np.ascontiguousarray(rat, dtype=np.float64)
    # a mode reads only its own per-atom values: none for the others
    radii = (np.zeros(n if mode == CUT_RADII else 0) if radii is None
             else np.ascontiguousarray(radii, dtype=np.float64))
    types = (np.zeros(n if mode == CUT_TABLE else 0, np.int64) if types is None
             else np.ascontiguousarray(types, dtype=np.int64))
    table = np.zeros((1, 1)) if table is None else np.ascontiguousarray(table, dtype=np.float64)
    if n == 0:
        sdim, shifts, dtype = shift_codes(np.zeros(3, np.int64), np.zeros(3, np.int64))
        return PairList(np.zeros(0, np.int64), np.zeros(1, np.int64),
                        np.zeros(0, np.int32), np.zeros(0, dtype), shifts,
                        np.zeros((0, 3), np.int64), 0)
    rs, ts = _slot_values(index.slot_atom, radii, types, mode)
    rmax = float(rat.max())
    # every periodic image within rmax is visited: refuse a cutoff that
    # would need more images than any computer can list, instead of hanging
    per = index.periods > 0
    if per.any():
        with np.errstate(over="ignore"):
            images = np.prod(2.0 * rmax / index.periods[per] + 1.0)
        if not images < MAX_IMAGES:
            raise ValueError(f"cutoff: {rmax:.6g} Å reaches ~{images:.3g} periodic "
                             f"images of the cell (limit {MAX_IMAGES:.0e})")
    # round-off only ever adds candidates: pad the grid-space boxes by the
    # measured deviation of stored coordinates plus a relative margin; the
    # fast distance decides only pairs farther than ftol from the cutoff
    pad = 2.0 * index.dev + 1e-9 * (index.scale + rmax)
    ftol = 1e-9 * (index.scale + rmax)
    index.refuse_far(rmax)
    slo, shi = _image_bounds(index, rmax, pad)
    sdim, shifts, dtype = shift_codes(slo, shi)
    zero_code = int(((0 - slo[0]) * sdim[1] - slo[1]) * sdim[2] - slo[2])
    nblk = int(np.prod(index.nb))
    nth = threads_for("atoms", n)
    # more chunks than threads balances dense and empty regions; the list
    # does not depend on the chunking (rows come out in rank order)
    nchunk = min(nblk, 1 if nth == 1 else 8 * nth)
    bounds = np.linspace(0, nblk, nchunk + 1).astype(np.int64)
    atoms_in = np.add.reduceat(index.natom_blk, bounds[:-1]) if nblk else np.zeros(0)
    # room for the pairs: a short guess costs a second scan into room of
    # the exact size, a long one memory (peak memory matters at 10^6
    # atoms).  In MD the previous list's count per chunk is the guess.
    prev = None if reuse is None else reuse.chunk_counts
    if prev is not None and len(prev) == nchunk and reuse.natoms == n:
        caps = (1.1 * prev).astype(np.int64) + 64
    else:
        margin = 1.15
        if pairs_per_atom is None:
            # a uniform density over the occupied box
            r = min(rmax, 1e6)
            ext = np.maximum(index.glob[3:] - index.glob[:3], r)
            pairs_per_atom = 0.5 * 4.19 * r ** 3 * n / max(float(np.prod(ext)), 1e-300)
            margin = 1.1
        pairs_per_atom = min(float(pairs_per_atom), 0.5 * n * (1 + 8 * 27) + 1)
        caps = (margin * pairs_per_atom * atoms_in).astype(np.int64) + 64
    rowcount = np.zeros(n, np.int64)
    blocks = index.blocks
    reach = _Reach(rat, pad, ftol, index.stretch * (1.0 + 1e-12))
    sa = index.slot_atom
    if owned is None:
        nown, owned_blk, far = n, np.ones(len(sa) // blocks.bsz, dtype=np.bool_), np.zeros((3, 0))
    else:
        nown = int(owned)
        owned_blk = ((sa >= 0) & (sa < nown)).reshape(-1, blocks.bsz).any(axis=1)
        far = index.P.copy()
        far[:, sa >= nown] = np.inf  # holes are at +inf in P already
    cutoff = _PairCutoff(mode, float(cut), rs, ts, table, bool(self_interaction), owned_blk,
                         nown, far)
    fmt = _RowFormat(slo, sdim, -1.0 if split is None else float(split) ** 2)
    lo = np.zeros(nchunk + 1, np.int64)
    np.cumsum(caps, out=lo[1:])
    total_cap = int(lo[-1])
    if (reuse is not None and reuse.nbr.base is not None
            and len(reuse.nbr.base) >= total_cap and reuse.code.dtype == dtype):
        nbr, code = reuse.nbr.base, reuse.code.base
    else:
        if reuse is not None:  # too small: free it before the new room
            reuse.nbr = reuse.code = None
        nbr = np.empty(total_cap, np.int32)
        code = np.empty(total_cap, dtype)
    # a chunk that runs out of room scans on into new room from the block
    # that overflowed, sized from the chunk's own count so far (the uniform
    # guess misses most at the chunk next to the periodic seam, which keeps
    # the pairs across it: measured, chunk 0 of 16 overflowed, and rescanning
    # it whole cost 14 ms on one thread).  segs[ch]: the chunk's pieces.
    atoms_before = np.concatenate([[0], np.cumsum(index.natom_blk)])
    segs = [None] * nchunk

    def scan(ch):
        b, end_b = bounds[ch], bounds[ch + 1]
        buf_j, buf_c, at, room = nbr, code, lo[ch], caps[ch]
        pieces = []
        total = 0
        while True:
            b, k = _scan(b, end_b, blocks, reach, cutoff, fmt,
                         _Room(buf_j, at, room, rowcount), buf_c)
            pieces.append((buf_j, buf_c, at, k))
            total += k
            if b == end_b:
                break
            done = atoms_before[b] - atoms_before[bounds[ch]]
            rest = atoms_before[end_b] - atoms_before[b]
            per = total / done if done else 2.0 * caps[ch] / max(1, atoms_in[ch])
            # the block that overflowed had more than room - k pairs: at least
            # double that, so that even one huge block gets through
            room = max(int(1.2 * per * rest) + 64, 2 * (room - k) + 1024)
            buf_j, buf_c, at = np.empty(room, np.int32), np.empty(room, dtype), 0
        segs[ch] = pieces
        return total
    found = np.array(run_chunks(scan, lambda ch: (ch,), nchunk, nth), dtype=np.int64)
    offs = np.zeros(nchunk + 1, np.int64)
    np.cumsum(found, out=offs[1:])
    if offs[-1] <= len(nbr):
        # everything fits in the first room (no chunk overflowed, or one did
        # and the others left slack): close the gaps in place, never in a
        # second full-size array (that copy doubled the list at the peak:
        # +195 MB at 10^6 atoms)
        _compact_in_place(nbr, code, segs, lo, offs)
    else:
        room = int(((1.1 * found).astype(np.int64) + 64).sum())
        nbr2 = np.empty(max(room, int(offs[-1])), np.int32)
        code2 = np.empty(len(nbr2), dtype)

        def move(ch):
            w = offs[ch]
            for src_j, src_c, at, k in segs[ch]:
                nbr2[w:w + k] = src_j[at:at + k]
                code2[w:w + k] = src_c[at:at + k]
                w += k
        run_chunks(move, lambda ch: (ch,), nchunk, nth)
        nbr, code = nbr2, code2
    segs = None
    m = int(offs[-1])
    rowptr = np.zeros(n + 1, np.int64)
    np.cumsum(rowcount, out=rowptr[1:])
    images = np.ascontiguousarray(index.MS[index.slot_atom >= 0])
    pl = PairList(index.order, rowptr, nbr[:m], code[:m], shifts, images,
                  zero_code)
    pl.chunk_counts = found
    return pl


def pair_list(index, i, j, S):
    """A :class:`PairList` in the grid order of ``index`` from a half list
    of atom pairs with cell shifts S (e.g. Boris's template,
    :func:`ase_mlg.template.template_pairs`)."""
    n = index.grid.natoms
    images = (np.ascontiguousarray(index.MS[index.slot_atom >= 0]) if n
              else np.zeros((0, 3), np.int64))
    return PairList.from_pairs(index.order, images, i, j, S)


def find_pairs(index, rat, mode=CUT_SCALAR, cut=0.0, radii=None, types=None,
               table=None, self_interaction=False, half=False,
               quantities="ijdDS"):
    """All pairs within the cutoff, exactly (see module doc), as
    ``ase.neighborlist`` returns them.

    Parameters are those of :func:`half_list`, and

    half : bool
        Report each unordered pair {(i, j, S), (j, i, -S)} once (orientation
        given by the grid), in grid order; otherwise both, sorted by ``i``
        (within one ``i`` in grid order: the same for any thread count).
    quantities : str
        Which of 'jdDS' to fill ('i' is always returned).

    Returns
    -------
    dict with keys 'i' and those of 'jdDS' requested: int64 / float64 arrays.
    """
    pl = half_list(index, rat, mode, cut, radii, types, table, self_interaction)
    return pl.arrays(index.positions, index.cell, half, quantities)


def exact_pairs(grid, cutoff, shifts=True):
    """Every pair of atoms closer than ``cutoff``, each unordered pair once.

    The exact query of a whole grid at one radius (docs/design.md §6): what
    the calculator's exact mode, the trade-off's reference and the RDFs
    count.

    Parameters
    ----------
    grid : MLG
        A grid holding the current positions.
    cutoff : float
        Radius (Å); pairs with ``d < cutoff``.
    shifts : bool
        Also return the cell shifts ``S`` (``D = x[j] - x[i] + S @ cell``).

    Returns
    -------
    i, j : int64 arrays
    S : int64 array (M, 3), or None without ``shifts``
        An atom may pair with its own periodic image (``i == j``, S != 0).
    """
    res = find_pairs(BlockIndex(grid), np.full(grid.natoms, float(cutoff)),
                     cut=float(cutoff), half=True,
                     quantities="ijS" if shifts else "ij")
    return res["i"], res["j"], res.get("S")
