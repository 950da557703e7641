"""Exact range queries on a Monotonic Logical Grid (DESIGN 2.5).

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
   into the axis-aligned box ``g +- r`` for any triclinic cell.
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

Full lists (``find_pairs``, default ``strategy="store"``): blocks are
scanned in a fixed number of chunks (8) on numba's thread count of Python
threads (the kernels release the GIL).  Each chunk scans only candidate
blocks ``B >= A`` (and, for ``B == A``, non-negative images and slots
``u >= t``), so every unordered pair {(i, j, S), (j, i, -S)} is met once;
it stores (slot i, slot j, image) and counts the pair at both atoms in its
own row of a (chunks x atoms) table.  Prefix sums over atoms, then chunks,
give every chunk its own cursor into every atom's segment, and a second
pass writes each pair at i and its mirror ``(j, i, -D, d, -S)`` at j (the
mirror is bitwise what ASE computes for it: IEEE negation is exact).  The
output is sorted by atom index ``i`` and, with the chunk count fixed,
identical for any number of threads.  Within one ``i`` pairs come in grid
order (deterministic for a given grid).  ``strategy="mirror"`` does the
same with a count pass instead of the scratch (no scratch memory, one scan
more); ``"direct"`` scans every atom's whole neighbourhood (count pass and
fill pass, ``prange`` over blocks).  ``half=True`` returns each unordered
pair once, grouped by grid block (for pair sums).
"""

import numpy as np
from numba import njit, prange

__all__ = ["BlockIndex", "find_pairs", "CUT_SCALAR", "CUT_RADII", "CUT_TABLE"]

CUT_SCALAR, CUT_RADII, CUT_TABLE = 0, 1, 2


# --------------------------------------------------------------------------
# gathering the grid into blocks
# --------------------------------------------------------------------------

@njit(cache=True)
def _gather(sites, coords, g, positions, cell, periods, shape, bs, nb):
    """Slot arrays in block-major order and the block/row/slab boxes.

    Returns ``slot_atom`` (-1: hole or padding), ``P`` (3, nslot): Cartesian
    position of the image that matches the stored coordinate (+inf for
    holes), ``G`` (3, nslot) stored grid coordinates, ``MS`` (nslot, 3)
    integer image of the stored coordinate, ``BB`` (nblk, 6) block boxes
    (lo0, lo1, lo2, hi0, hi1, hi2), ``R2`` (nbx*nby, 6) row boxes, ``S1``
    (nbx, 6) slab boxes, the global box ``glob`` (6,), the largest deviation
    of a stored coordinate from an exact image, and ``natom_blk`` (nblk,).
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    bx, by, bz = bs[0], bs[1], bs[2]
    nbx, nby, nbz = nb[0], nb[1], nb[2]
    bsz = bx * by * bz
    nblk = nbx * nby * nbz
    nslot = nblk * bsz
    slot_atom = np.full(nslot, -1, dtype=np.int64)
    P = np.full((3, nslot), np.inf)
    G = np.zeros((3, nslot))
    MS = np.zeros((nslot, 3), dtype=np.int64)
    BB = np.empty((nblk, 6))
    for b in range(nblk):
        for c in range(3):
            BB[b, c] = np.inf
            BB[b, 3 + c] = -np.inf
    natom_blk = np.zeros(nblk, dtype=np.int64)
    dev = 0.0
    for i in range(nx):
        I = i // bx
        ii = i - I * bx
        for j in range(ny):
            J = j // by
            jj = j - J * by
            for k in range(nz):
                K = k // bz
                kk = k - K * bz
                s = (i * ny + j) * nz + k
                b = (I * nby + J) * nbz + K
                t = b * bsz + (ii * by + jj) * bz + kk
                for c in range(3):
                    x = coords[s, c]
                    G[c, t] = x
                    if x < BB[b, c]:
                        BB[b, c] = x
                    if x > BB[b, 3 + c]:
                        BB[b, 3 + c] = x
                a = sites[s]
                slot_atom[t] = a
                if a < 0:
                    continue
                natom_blk[b] += 1
                m0 = 0
                m1 = 0
                m2 = 0
                for c in range(3):
                    diff = coords[s, c] - g[a, c]
                    m = 0.0
                    if periods[c] > 0.0:
                        m = np.rint(diff / periods[c])
                        diff -= m * periods[c]
                    if abs(diff) > dev:
                        dev = abs(diff)
                    if c == 0:
                        m0 = int(m)
                    elif c == 1:
                        m1 = int(m)
                    else:
                        m2 = int(m)
                MS[t, 0] = m0
                MS[t, 1] = m1
                MS[t, 2] = m2
                for c in range(3):
                    P[c, t] = positions[a, c] + (m0 * cell[0, c] + m1 * cell[1, c]
                                                 + m2 * cell[2, c])
    R2 = np.empty((nbx * nby, 6))
    S1 = np.empty((nbx, 6))
    glob = np.empty(6)
    for c in range(3):
        glob[c] = np.inf
        glob[3 + c] = -np.inf
    for I in range(nbx):
        for c in range(3):
            S1[I, c] = np.inf
            S1[I, 3 + c] = -np.inf
        for J in range(nby):
            r = I * nby + J
            for c in range(3):
                R2[r, c] = np.inf
                R2[r, 3 + c] = -np.inf
            for K in range(nbz):
                b = r * nbz + K
                for c in range(3):
                    R2[r, c] = min(R2[r, c], BB[b, c])
                    R2[r, 3 + c] = max(R2[r, 3 + c], BB[b, 3 + c])
            for c in range(3):
                S1[I, c] = min(S1[I, c], R2[r, c])
                S1[I, 3 + c] = max(S1[I, 3 + c], R2[r, 3 + c])
        for c in range(3):
            glob[c] = min(glob[c], S1[I, c])
            glob[3 + c] = max(glob[3 + c], S1[I, 3 + c])
    return slot_atom, P, G, MS, BB, R2, S1, glob, dev, natom_blk


class BlockIndex:
    """Blocked view of an MLG for exact range queries (see module doc).

    Built in O(N) from the grid's current state; rebuild it (cheap) after
    every ``grid.update``.
    """

    def __init__(self, grid, block=2):
        bs = np.broadcast_to(np.asarray(block, dtype=np.int64), (3,)).copy()
        if (bs < 1).any():
            raise ValueError(f"block: sizes must be >= 1, got {bs.tolist()}")
        shape = np.array(grid.shape, dtype=np.int64)
        bs = np.minimum(bs, np.maximum(shape, 1))
        nb = (shape + bs - 1) // bs
        self.grid = grid
        self.shape = shape
        self.bs = bs
        self.nb = nb
        self.positions = grid.positions
        box = grid.box
        self.cell = np.ascontiguousarray(box.full, dtype=np.float64)
        self.periods = np.ascontiguousarray(grid._periods, dtype=np.float64)
        n = grid.natoms
        if n:
            g = np.ascontiguousarray(box.fractional(grid.positions) * box.heights)
            (self.slot_atom, self.P, self.G, self.MS, self.BB, self.R2, self.S1,
             self.glob, self.dev, self.natom_blk) = _gather(
                grid._sites, grid._coords, g, grid.positions, self.cell,
                self.periods, shape, bs, nb)
            self.volume = float(abs(np.linalg.det(self.cell)))
            scale = max(1.0, float(np.abs(self.glob).max()),
                        float(np.abs(grid.positions).max()),
                        float(np.abs(self.cell).sum()))
        else:
            scale = 1.0
            self.dev = 0.0
            self.volume = 0.0
        self.scale = scale


# --------------------------------------------------------------------------
# the scan
# --------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _first_ge(arr, col, base, stride, n, q):
    """First index t in [0, n) with arr[base + t*stride, col] >= q (n if none)."""
    lo = 0
    hi = n
    while lo < hi:
        mid = (lo + hi) >> 1
        if arr[base + mid * stride, col] >= q:
            hi = mid
        else:
            lo = mid + 1
    return lo


@njit(cache=True, inline="always")
def _last_le(arr, col, base, stride, n, q):
    """Last index t in [0, n) with arr[base + t*stride, col] <= q (-1 if none)."""
    lo = 0
    hi = n
    while lo < hi:
        mid = (lo + hi) >> 1
        if arr[base + mid * stride, col] <= q:
            lo = mid + 1
        else:
            hi = mid
    return lo - 1


@njit(cache=True)
def _push(cand, ncand, b, m0, m1, m2):
    if ncand >= cand.shape[0]:
        new = np.empty((2 * cand.shape[0], 4), dtype=np.int64)
        new[:ncand] = cand[:ncand]
        cand = new
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
    IA = bmin // (nby * nbz)
    JA = (bmin // nbz) % nby
    KA = bmin % nbz
    I0 = max(_first_ge(S1, 3, 0, 1, nbx, qlo[0]), IA)
    I1 = _last_le(S1, 0, 0, 1, nbx, qhi[0])
    for I in range(I0, I1 + 1):
        if (S1[I, 1] > qhi[1] or S1[I, 4] < qlo[1]
                or S1[I, 2] > qhi[2] or S1[I, 5] < qlo[2]):
            continue
        rb = I * nby
        J0 = _first_ge(R2, 4, rb, 1, nby, qlo[1])
        if I == IA:
            J0 = max(J0, JA)
        J1 = _last_le(R2, 1, rb, 1, nby, qhi[1])
        for J in range(J0, J1 + 1):
            r = rb + J
            if (R2[r, 0] > qhi[0] or R2[r, 3] < qlo[0]
                    or R2[r, 2] > qhi[2] or R2[r, 5] < qlo[2]):
                continue
            bb = r * nbz
            K0 = _first_ge(BB, 5, bb, 1, nbz, qlo[2])
            if I == IA and J == JA:
                K0 = max(K0, KA)
            K1 = _last_le(BB, 2, bb, 1, nbz, qhi[2])
            for K in range(K0, K1 + 1):
                b = bb + K
                if (BB[b, 0] > qhi[0] or BB[b, 3] < qlo[0]
                        or BB[b, 1] > qhi[1] or BB[b, 4] < qlo[1]):
                    continue
                cand = _push(cand, ncand, b, m0, m1, m2)
                ncand += 1
    return cand, ncand


@njit(cache=True)
def _slot_values(slot_atom, positions, radii, types, mode):
    """Original positions, radius and type of every slot (block order)."""
    nslot = slot_atom.shape[0]
    Q = np.zeros((3, nslot))
    rs = np.zeros(nslot)
    ts = np.zeros(nslot, dtype=np.int64)
    for t in range(nslot):
        a = slot_atom[t]
        if a < 0:
            continue
        for c in range(3):
            Q[c, t] = positions[a, c]
        if mode == 1:
            rs[t] = radii[a]
        elif mode == 2:
            ts[t] = types[a]
    return Q, rs, ts


@njit(cache=True)
def _prepare(A, cand, cf, qlo, qhi, nb, bsz, slot_atom, BB, R2, S1, glob,
             periods, cell, pad, rat, half):
    """Candidate (block, image) list of query block ``A``: every block whose
    box meets A's box grown by the largest query radius of its atoms, for
    every periodic image ``m`` that can reach the global range of stored
    coordinates.  ``cf`` gets each candidate's box shifted to its image
    (0:6) and the Cartesian image shift (6:9).  With ``half``, candidates
    that only hold mirrors of pairs kept from the other side are dropped
    (block < A, or block == A with a negative image)."""
    # query radius of the block
    tA0 = A * bsz
    RA = 0.0
    for t in range(tA0, tA0 + bsz):
        a = slot_atom[t]
        if a >= 0 and rat[a] > RA:
            RA = rat[a]
    RA += pad
    # image ranges on periodic axes
    mlo0 = 0
    mhi0 = 0
    mlo1 = 0
    mhi1 = 0
    mlo2 = 0
    mhi2 = 0
    if periods[0] > 0.0:
        mlo0 = int(np.ceil((BB[A, 0] - RA - glob[3]) / periods[0]))
        mhi0 = int(np.floor((BB[A, 3] + RA - glob[0]) / periods[0]))
    if periods[1] > 0.0:
        mlo1 = int(np.ceil((BB[A, 1] - RA - glob[4]) / periods[1]))
        mhi1 = int(np.floor((BB[A, 4] + RA - glob[1]) / periods[1]))
    if periods[2] > 0.0:
        mlo2 = int(np.ceil((BB[A, 2] - RA - glob[5]) / periods[2]))
        mhi2 = int(np.floor((BB[A, 5] + RA - glob[2]) / periods[2]))
    ncand = 0
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
                    cand, qlo, qhi, nb, S1, R2, BB, m0, m1, m2, ncand,
                    A if half else 0)
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
        if half:
            # mirrors of pairs kept from the other side
            if B < A:
                continue
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


@njit(cache=True, parallel=True)
def _scan(chunks, nb, bsz, slot_atom, P, Q, G, MS, BB, R2, S1, glob, natom_blk,
          periods, cell, pad, ftol, rat, mode, cut, rs, ts, table,
          self_interaction, half, mirror, fill, counts, start, cur,
          out_i, out_j, out_d, out_D, out_S, want_j, want_d, want_D, want_S):
    """Count (``fill=False``: counts[a] per atom a) or write (``fill=True``,
    at ``start[a]``) all pairs (a, j, S) with d < cutoff(a, j).

    Candidates are tested on positions gathered in block order (``P``, in
    the frame of the stored coordinates); a pair whose fast distance is
    farther than ``ftol`` from its cutoff is decided by it, the others (and
    every pair written out) on ``D = q[j] - q[i] + S @ cell`` from the
    original positions ``Q``, as ASE computes it.

    ``half``: keep each unordered pair once (the one whose (slot, image)
    comes first); counts/start are then per *block* instead of per atom.

    ``mirror`` (with ``half``): a full list sorted by atom from the half
    scan.  ``cur[ch, a]`` counts (``fill=False``) the pairs chunk ``ch``
    gives atom ``a`` -- as first atom or as the mirrored second one -- and
    then (``fill=True``) is the cursor where chunk ``ch`` writes atom
    ``a``'s next pair; each chunk owns its row, so there are no races and
    the order is fixed by the (fixed) number of chunks.  ``out_i`` is filled
    by the caller.
    """
    nchunk = chunks.shape[0] - 1
    for ch in prange(nchunk):
        cand = np.empty((64, 4), dtype=np.int64)
        cf = np.empty((64, 9))
        hit = np.empty(bsz, dtype=np.int64)
        dist2 = np.empty(bsz)
        qlo = np.empty(3)
        qhi = np.empty(3)
        for A in range(chunks[ch], chunks[ch + 1]):
            if natom_blk[A] == 0:
                continue
            cand, cf, ncand = _prepare(A, cand, cf, qlo, qhi, nb, bsz,
                                       slot_atom, BB, R2, S1, glob, periods,
                                       cell, pad, rat, half)
            tA0 = A * bsz
            blkcount = 0
            for t in range(tA0, tA0 + bsz):
                a = slot_atom[t]
                if a < 0:
                    continue
                Ri = rat[a] + pad
                Rf = rat[a] + ftol
                Rf2 = Rf * Rf
                glo0 = G[0, t] - Ri
                ghi0 = G[0, t] + Ri
                glo1 = G[1, t] - Ri
                ghi1 = G[1, t] + Ri
                glo2 = G[2, t] - Ri
                ghi2 = G[2, t] + Ri
                px = P[0, t]
                py = P[1, t]
                pz = P[2, t]
                mt0 = MS[t, 0]
                mt1 = MS[t, 1]
                mt2 = MS[t, 2]
                ra = rs[t]
                ta = ts[t]
                n = 0
                pos = 0
                if fill:
                    if half:
                        pos = start[A] + blkcount
                    else:
                        pos = start[a]
                for c in range(ncand):
                    # branch-free box test, one branch
                    ok = ((cf[c, 0] <= ghi0) & (cf[c, 3] >= glo0)
                          & (cf[c, 1] <= ghi1) & (cf[c, 4] >= glo1)
                          & (cf[c, 2] <= ghi2) & (cf[c, 5] >= glo2))
                    if not ok:
                        continue
                    B = cand[c, 0]
                    m0 = cand[c, 1]
                    m1 = cand[c, 2]
                    m2 = cand[c, 3]
                    mzero = m0 == 0 and m1 == 0 and m2 == 0
                    qx = px - cf[c, 6]
                    qy = py - cf[c, 7]
                    qz = pz - cf[c, 8]
                    u0 = B * bsz
                    kmin = 0
                    if half and B == A and mzero:
                        kmin = t - u0
                    # branch-free pre-filter: compact the slots that pass
                    npass = 0
                    for k in range(bsz):
                        u = u0 + k
                        dx = P[0, u] - qx
                        dy = P[1, u] - qy
                        dz = P[2, u] - qz
                        d2f = dx * dx + dy * dy + dz * dz
                        hit[npass] = k
                        dist2[npass] = d2f
                        npass += (d2f < Rf2) & (k >= kmin)
                    for h in range(npass):
                        u = u0 + hit[h]
                        d2f = dist2[h]
                        if u == t and mzero and not self_interaction:
                            continue
                        if mode == 0:
                            rc = cut
                        elif mode == 1:
                            rc = ra + rs[u]
                        else:
                            rc = table[ta, ts[u]]
                        hi = rc + ftol
                        if d2f >= hi * hi:
                            continue
                        lo = rc - ftol
                        exact = fill or lo <= 0.0 or d2f >= lo * lo
                        if exact:
                            S0 = m0 + MS[u, 0] - mt0
                            S1_ = m1 + MS[u, 1] - mt1
                            S2 = m2 + MS[u, 2] - mt2
                            # as ASE: positions[j] - positions[i] + S @ cell
                            Dx = (Q[0, u] - Q[0, t]) + (
                                S0 * cell[0, 0] + S1_ * cell[1, 0] + S2 * cell[2, 0])
                            Dy = (Q[1, u] - Q[1, t]) + (
                                S0 * cell[0, 1] + S1_ * cell[1, 1] + S2 * cell[2, 1])
                            Dz = (Q[2, u] - Q[2, t]) + (
                                S0 * cell[0, 2] + S1_ * cell[1, 2] + S2 * cell[2, 2])
                            d = np.sqrt(Dx * Dx + Dy * Dy + Dz * Dz)
                            if not d < rc:
                                continue
                            if fill and mirror:
                                p = cur[ch, a]
                                cur[ch, a] = p + 1
                                if want_j:
                                    out_j[p] = slot_atom[u]
                                if want_d:
                                    out_d[p] = d
                                if want_D:
                                    out_D[p, 0] = Dx
                                    out_D[p, 1] = Dy
                                    out_D[p, 2] = Dz
                                if want_S:
                                    out_S[p, 0] = S0
                                    out_S[p, 1] = S1_
                                    out_S[p, 2] = S2
                                if not (u == t and mzero):
                                    jj = slot_atom[u]
                                    p = cur[ch, jj]
                                    cur[ch, jj] = p + 1
                                    if want_j:
                                        out_j[p] = a
                                    if want_d:
                                        out_d[p] = d
                                    if want_D:
                                        out_D[p, 0] = -Dx
                                        out_D[p, 1] = -Dy
                                        out_D[p, 2] = -Dz
                                    if want_S:
                                        out_S[p, 0] = -S0
                                        out_S[p, 1] = -S1_
                                        out_S[p, 2] = -S2
                            elif fill:
                                out_i[pos] = a
                                if want_j:
                                    out_j[pos] = slot_atom[u]
                                if want_d:
                                    out_d[pos] = d
                                if want_D:
                                    out_D[pos, 0] = Dx
                                    out_D[pos, 1] = Dy
                                    out_D[pos, 2] = Dz
                                if want_S:
                                    out_S[pos, 0] = S0
                                    out_S[pos, 1] = S1_
                                    out_S[pos, 2] = S2
                                pos += 1
                        if mirror and not fill and not (u == t and mzero):
                            # count the mirrored pair at its first atom
                            cur[ch, slot_atom[u]] += 1
                        n += 1
                blkcount += n
                if mirror:
                    if not fill:
                        cur[ch, a] += n
                elif not fill and not half:
                    counts[a] = n
            if not fill and half and not mirror:
                counts[A] = blkcount


@njit(cache=True, nogil=True)
def _scan_store(b0, b1, ch, nb, bsz, slot_atom, P, Q, G, MS, BB, R2, S1,
                glob, natom_blk, periods, cell, pad, ftol, rat, mode, cut,
                rs, ts, table, self_interaction, cur, cap, count_atoms):
    """One pass over blocks [b0, b1) of the half scan (see ``_scan``):
    count every kept pair at both its atoms in ``cur[ch]`` and store it as
    (slot i, slot j, image m) for :func:`_scatter`.  Runs without the GIL,
    one call per chunk on Python threads."""
    buf = np.empty((max(cap, 16), 5), dtype=np.int32)
    nbuf = 0
    cand = np.empty((64, 4), dtype=np.int64)
    cf = np.empty((64, 9))
    hit = np.empty(bsz, dtype=np.int64)
    dist2 = np.empty(bsz)
    qlo = np.empty(3)
    qhi = np.empty(3)
    for A in range(b0, b1):
        if natom_blk[A] == 0:
            continue
        cand, cf, ncand = _prepare(A, cand, cf, qlo, qhi, nb, bsz, slot_atom,
                                   BB, R2, S1, glob, periods, cell, pad, rat,
                                   True)
        tA0 = A * bsz
        for t in range(tA0, tA0 + bsz):
            a = slot_atom[t]
            if a < 0:
                continue
            Ri = rat[a] + pad
            Rf = rat[a] + ftol
            Rf2 = Rf * Rf
            glo0 = G[0, t] - Ri
            ghi0 = G[0, t] + Ri
            glo1 = G[1, t] - Ri
            ghi1 = G[1, t] + Ri
            glo2 = G[2, t] - Ri
            ghi2 = G[2, t] + Ri
            px = P[0, t]
            py = P[1, t]
            pz = P[2, t]
            ra = rs[t]
            ta = ts[t]
            n = 0
            for c in range(ncand):
                ok = ((cf[c, 0] <= ghi0) & (cf[c, 3] >= glo0)
                      & (cf[c, 1] <= ghi1) & (cf[c, 4] >= glo1)
                      & (cf[c, 2] <= ghi2) & (cf[c, 5] >= glo2))
                if not ok:
                    continue
                B = cand[c, 0]
                m0 = cand[c, 1]
                m1 = cand[c, 2]
                m2 = cand[c, 3]
                mzero = m0 == 0 and m1 == 0 and m2 == 0
                qx = px - cf[c, 6]
                qy = py - cf[c, 7]
                qz = pz - cf[c, 8]
                u0 = B * bsz
                kmin = 0
                if B == A and mzero:
                    kmin = t - u0
                npass = 0
                for k in range(bsz):
                    u = u0 + k
                    dx = P[0, u] - qx
                    dy = P[1, u] - qy
                    dz = P[2, u] - qz
                    d2f = dx * dx + dy * dy + dz * dz
                    hit[npass] = k
                    dist2[npass] = d2f
                    npass += (d2f < Rf2) & (k >= kmin)
                for h in range(npass):
                    u = u0 + hit[h]
                    d2f = dist2[h]
                    self0 = u == t and mzero
                    if self0 and not self_interaction:
                        continue
                    if mode == 0:
                        rc = cut
                    elif mode == 1:
                        rc = ra + rs[u]
                    else:
                        rc = table[ta, ts[u]]
                    hi = rc + ftol
                    if d2f >= hi * hi:
                        continue
                    lo = rc - ftol
                    if lo <= 0.0 or d2f >= lo * lo:
                        S0 = m0 + MS[u, 0] - MS[t, 0]
                        S1_ = m1 + MS[u, 1] - MS[t, 1]
                        S2 = m2 + MS[u, 2] - MS[t, 2]
                        Dx = (Q[0, u] - Q[0, t]) + (
                            S0 * cell[0, 0] + S1_ * cell[1, 0] + S2 * cell[2, 0])
                        Dy = (Q[1, u] - Q[1, t]) + (
                            S0 * cell[0, 1] + S1_ * cell[1, 1] + S2 * cell[2, 1])
                        Dz = (Q[2, u] - Q[2, t]) + (
                            S0 * cell[0, 2] + S1_ * cell[1, 2] + S2 * cell[2, 2])
                        if not np.sqrt(Dx * Dx + Dy * Dy + Dz * Dz) < rc:
                            continue
                    if nbuf >= buf.shape[0]:
                        new = np.empty((2 * buf.shape[0], 5), dtype=np.int32)
                        new[:nbuf] = buf[:nbuf]
                        buf = new
                    buf[nbuf, 0] = t
                    buf[nbuf, 1] = u
                    buf[nbuf, 2] = m0
                    buf[nbuf, 3] = m1
                    buf[nbuf, 4] = m2
                    nbuf += 1
                    if count_atoms and not self0:
                        cur[ch, slot_atom[u]] += 1
                    n += 1
            if count_atoms:
                cur[ch, a] += n
    return buf, nbuf


@njit(cache=True, nogil=True)
def _scatter(buf, nbuf, ch, cur, slot_atom, Q, MS, cell, out_j, out_d, out_D,
             out_S, want_j, want_d, want_D, want_S):
    """Write the stored half pairs of chunk ``ch`` at both atoms (cursor
    ``cur[ch, a]``), with D, d, S computed as ASE does; the mirror is
    ``(j, i, -D, d, -S)`` (bitwise what ASE computes for it)."""
    for e in range(nbuf):
        t = buf[e, 0]
        u = buf[e, 1]
        m0 = buf[e, 2]
        m1 = buf[e, 3]
        m2 = buf[e, 4]
        a = slot_atom[t]
        j = slot_atom[u]
        S0 = m0 + MS[u, 0] - MS[t, 0]
        S1_ = m1 + MS[u, 1] - MS[t, 1]
        S2 = m2 + MS[u, 2] - MS[t, 2]
        Dx = (Q[0, u] - Q[0, t]) + (
            S0 * cell[0, 0] + S1_ * cell[1, 0] + S2 * cell[2, 0])
        Dy = (Q[1, u] - Q[1, t]) + (
            S0 * cell[0, 1] + S1_ * cell[1, 1] + S2 * cell[2, 1])
        Dz = (Q[2, u] - Q[2, t]) + (
            S0 * cell[0, 2] + S1_ * cell[1, 2] + S2 * cell[2, 2])
        d = np.sqrt(Dx * Dx + Dy * Dy + Dz * Dz)
        p = cur[ch, a]
        cur[ch, a] = p + 1
        if want_j:
            out_j[p] = j
        if want_d:
            out_d[p] = d
        if want_D:
            out_D[p, 0] = Dx
            out_D[p, 1] = Dy
            out_D[p, 2] = Dz
        if want_S:
            out_S[p, 0] = S0
            out_S[p, 1] = S1_
            out_S[p, 2] = S2
        if u == t and m0 == 0 and m1 == 0 and m2 == 0:
            continue
        p = cur[ch, j]
        cur[ch, j] = p + 1
        if want_j:
            out_j[p] = a
        if want_d:
            out_d[p] = d
        if want_D:
            out_D[p, 0] = -Dx
            out_D[p, 1] = -Dy
            out_D[p, 2] = -Dz
        if want_S:
            out_S[p, 0] = -S0
            out_S[p, 1] = -S1_
            out_S[p, 2] = -S2


@njit(cache=True, nogil=True)
def _emit_half(buf, nbuf, off, slot_atom, Q, MS, cell, out_i, out_j, out_d,
               out_D, out_S, want_j, want_d, want_D, want_S):
    """Write the stored half pairs of one chunk at ``off``, ``off + 1``, ..."""
    for e in range(nbuf):
        t = buf[e, 0]
        u = buf[e, 1]
        S0 = buf[e, 2] + MS[u, 0] - MS[t, 0]
        S1_ = buf[e, 3] + MS[u, 1] - MS[t, 1]
        S2 = buf[e, 4] + MS[u, 2] - MS[t, 2]
        p = off + e
        out_i[p] = slot_atom[t]
        if want_j:
            out_j[p] = slot_atom[u]
        if want_d or want_D:
            Dx = (Q[0, u] - Q[0, t]) + (
                S0 * cell[0, 0] + S1_ * cell[1, 0] + S2 * cell[2, 0])
            Dy = (Q[1, u] - Q[1, t]) + (
                S0 * cell[0, 1] + S1_ * cell[1, 1] + S2 * cell[2, 1])
            Dz = (Q[2, u] - Q[2, t]) + (
                S0 * cell[0, 2] + S1_ * cell[1, 2] + S2 * cell[2, 2])
            if want_d:
                out_d[p] = np.sqrt(Dx * Dx + Dy * Dy + Dz * Dz)
            if want_D:
                out_D[p, 0] = Dx
                out_D[p, 1] = Dy
                out_D[p, 2] = Dz
        if want_S:
            out_S[p, 0] = S0
            out_S[p, 1] = S1_
            out_S[p, 2] = S2


_POOL = [None, 0]
MAX_IMAGES = 1e7  # periodic images per query: 2 rc / h + 1 per axis
PARALLEL_MIN_ATOMS = 5000  # below this, thread hand-offs cost more than they save


def _run_chunks(func, args_of, nchunk, natoms):
    """Run ``func(*args_of(ch))`` for every chunk, on numba's thread count
    of Python threads (the kernels release the GIL); results in chunk
    order.  Small systems run serially."""
    import numba
    nth = max(1, min(numba.get_num_threads(), nchunk))
    if nth == 1 or natoms < PARALLEL_MIN_ATOMS:
        return [func(*args_of(ch)) for ch in range(nchunk)]
    if _POOL[1] != nth:
        from concurrent.futures import ThreadPoolExecutor
        if _POOL[0] is not None:
            _POOL[0].shutdown(wait=False)
        _POOL[0] = ThreadPoolExecutor(nth, thread_name_prefix="ase_mlg")
        _POOL[1] = nth
    return list(_POOL[0].map(lambda ch: func(*args_of(ch)), range(nchunk)))


def find_pairs(index, rat, mode=CUT_SCALAR, cut=0.0, radii=None, types=None,
               table=None, self_interaction=False, half=False,
               quantities="ijdDS", nchunk=None, strategy="store"):
    """All pairs within the cutoff, exactly (see module doc).

    Parameters
    ----------
    index : BlockIndex
    rat : float64 array (N,)
        Per-atom query radius: an upper bound of the cutoff of every pair
        the atom is in (the scan's filter radius).
    mode : CUT_SCALAR | CUT_RADII | CUT_TABLE
        Pair cutoff ``cut``, ``radii[i] + radii[j]`` or
        ``table[types[i], types[j]]``; pairs with ``d < cutoff`` are kept.
    self_interaction : bool
        Keep the pair (i, i, S=0) when ``0 < cutoff``.
    half : bool
        Report each unordered pair {(i, j, S), (j, i, -S)} once (orientation
        given by the grid); then the output is grouped by grid block, not
        sorted by i.
    quantities : str
        Which of 'jdDS' to fill ('i' is always returned).
    strategy : "store", "mirror" or "direct"
        Full lists: scan half the pairs once, store them, then write each
        at both atoms ("store", default: one scan, about 20 bytes per
        unordered pair of scratch); scan half the pairs twice (count, then
        write at both atoms: "mirror", no scratch); or scan every atom's full
        neighbourhood twice ("direct").  Same pairs; the order within one
        ``i`` differs.

    Returns
    -------
    dict with keys 'i' and those of 'jdDS' requested: int64 / float64 arrays.
    """
    grid = index.grid
    n = grid.natoms
    want = {q: (q in quantities) for q in "jdDS"}
    if n == 0:
        return _empty(want)
    rat = np.ascontiguousarray(rat, dtype=np.float64)
    radii = np.zeros(n) if radii is None else np.ascontiguousarray(radii, dtype=np.float64)
    types = np.zeros(n, np.int64) if types is None else np.ascontiguousarray(types, dtype=np.int64)
    table = np.zeros((1, 1)) if table is None else np.ascontiguousarray(table, dtype=np.float64)
    Q, rs, ts = _slot_values(index.slot_atom, index.positions, radii, types, int(mode))
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
    nblk = int(np.prod(index.nb))
    bsz = int(np.prod(index.bs))
    e_i = np.empty(0, np.int64)
    e_f = np.empty(0)
    e_2 = np.empty((0, 3))
    e_2i = np.empty((0, 3), np.int64)
    e_c = np.empty((0, 0), np.int64)
    nslot = index.slot_atom.shape[0]
    if strategy == "store" and nslot < 2 ** 31 - 1:
        return _find_store(index, rat, Q, rs, ts, table, mode, cut, pad, ftol,
                           self_interaction, want, nblk, bsz, half)
    mirror = (not half) and strategy in ("mirror", "store")
    if mirror:
        nchunk = min(nblk, NCHUNK_MIRROR)
    elif nchunk is None:
        nchunk = min(nblk, 256)
    chunks = np.linspace(0, nblk, nchunk + 1).astype(np.int64)
    common = (chunks, index.nb, bsz, index.slot_atom, index.P, Q, index.G,
              index.MS, index.BB, index.R2, index.S1, index.glob,
              index.natom_blk, index.periods, index.cell, pad, ftol, rat,
              int(mode), float(cut), rs, ts, table,
              bool(self_interaction), bool(half or mirror), mirror)
    if mirror:
        cur = np.zeros((nchunk, n), dtype=np.int64)
        counts = e_i
        _scan(*common, False, counts, counts, cur, e_i, e_i, e_f, e_2, e_2i,
              False, False, False, False)
        total = cur.sum(axis=0)
        start = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(total, out=start[1:])
        # cursor of chunk ch for atom a: start[a] + pairs of earlier chunks
        np.cumsum(cur, axis=0, out=cur)
        _cursor(cur, start)
    else:
        cur = e_c
        counts = np.zeros(nblk if half else n, dtype=np.int64)
        _scan(*common, False, counts, counts, cur, e_i, e_i, e_f, e_2, e_2i,
              False, False, False, False)
        start = np.zeros(len(counts) + 1, dtype=np.int64)
        np.cumsum(counts, out=start[1:])
    m = int(start[-1])
    out_i = np.empty(m, np.int64)
    out_j = np.empty(m, np.int64) if want["j"] else e_i
    out_d = np.empty(m) if want["d"] else e_f
    out_D = np.empty((m, 3)) if want["D"] else e_2
    out_S = np.empty((m, 3), np.int64) if want["S"] else e_2i
    _scan(*common, True, counts, start, cur, out_i, out_j, out_d, out_D, out_S,
          want["j"], want["d"], want["D"], want["S"])
    if mirror:
        _repeat_index(start, out_i)
    res = {"i": out_i}
    for q, arr in (("j", out_j), ("d", out_d), ("D", out_D), ("S", out_S)):
        if want[q]:
            res[q] = arr
    return res


NCHUNK_MIRROR = 8


@njit(cache=True)
def _cursor(cur, start):
    """cur holds inclusive prefix sums over chunks; make it exclusive and
    add the atom's start."""
    nch, n = cur.shape
    for a in range(n):
        prev = 0
        for ch in range(nch):
            c = cur[ch, a]
            cur[ch, a] = start[a] + prev
            prev = c


@njit(cache=True)
def _repeat_index(start, out_i):
    for a in range(start.shape[0] - 1):
        for p in range(start[a], start[a + 1]):
            out_i[p] = a


def _find_store(index, rat, Q, rs, ts, table, mode, cut, pad, ftol,
                self_interaction, want, nblk, bsz, half):
    n = index.grid.natoms
    nchunk = min(nblk, NCHUNK_MIRROR)
    chunks = np.linspace(0, nblk, nchunk + 1).astype(np.int64)
    cur = np.zeros((1, 1) if half else (nchunk, n), dtype=np.int64)
    # scratch guess: half the pairs of a uniform system, grown on demand
    # (the radius is capped so that an absurd cutoff cannot overflow the guess)
    cap = int(8 + 0.6 * min(float(np.mean(rat)), 1e6) ** 3 * 4.19 * n
              / max(index.volume, 1e-300) * n / 2 / nchunk)
    cap = min(cap, 4 * n * 64 // nchunk + 64)
    args = (index.nb, bsz, index.slot_atom, index.P, Q, index.G, index.MS,
            index.BB, index.R2, index.S1, index.glob, index.natom_blk,
            index.periods, index.cell, pad, ftol, rat, int(mode), float(cut),
            rs, ts, table, bool(self_interaction), cur, cap, not half)
    bufs = _run_chunks(_scan_store,
                       lambda ch: (chunks[ch], chunks[ch + 1], ch) + args,
                       nchunk, n)
    if half:
        offs = np.zeros(nchunk + 1, dtype=np.int64)
        np.cumsum([nb_ for _, nb_ in bufs], out=offs[1:])
        m = int(offs[-1])
        res = _alloc(m, want)
        _run_chunks(_emit_half,
                    lambda ch: (bufs[ch][0], bufs[ch][1], offs[ch],
                                index.slot_atom, Q, index.MS, index.cell,
                                res["i"], res.get("j", _E_I), res.get("d", _E_F),
                                res.get("D", _E_2), res.get("S", _E_2I),
                                want["j"], want["d"], want["D"], want["S"]),
                    nchunk, n)
        return res
    total = cur.sum(axis=0)
    start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(total, out=start[1:])
    np.cumsum(cur, axis=0, out=cur)
    _cursor(cur, start)
    m = int(start[-1])
    e_i = np.empty(0, np.int64)
    out_i = np.empty(m, np.int64)
    out_j = np.empty(m, np.int64) if want["j"] else e_i
    out_d = np.empty(m) if want["d"] else np.empty(0)
    out_D = np.empty((m, 3)) if want["D"] else np.empty((0, 3))
    out_S = np.empty((m, 3), np.int64) if want["S"] else np.empty((0, 3), np.int64)
    _run_chunks(_scatter,
                lambda ch: (bufs[ch][0], bufs[ch][1], ch, cur, index.slot_atom,
                            Q, index.MS, index.cell, out_j, out_d, out_D, out_S,
                            want["j"], want["d"], want["D"], want["S"]),
                nchunk, n)
    del bufs
    _repeat_index(start, out_i)
    res = {"i": out_i}
    for q, arr in (("j", out_j), ("d", out_d), ("D", out_D), ("S", out_S)):
        if want[q]:
            res[q] = arr
    return res


_E_I = np.empty(0, np.int64)
_E_F = np.empty(0)
_E_2 = np.empty((0, 3))
_E_2I = np.empty((0, 3), np.int64)


def _alloc(m, want):
    res = {"i": np.empty(m, np.int64)}
    if want["j"]:
        res["j"] = np.empty(m, np.int64)
    if want["d"]:
        res["d"] = np.empty(m)
    if want["D"]:
        res["D"] = np.empty((m, 3))
    if want["S"]:
        res["S"] = np.empty((m, 3), np.int64)
    return res


def _empty(want):
    res = {"i": np.empty(0, np.int64)}
    if want["j"]:
        res["j"] = np.empty(0, np.int64)
    if want["d"]:
        res["d"] = np.empty(0)
    if want["D"]:
        res["D"] = np.empty((0, 3))
    if want["S"]:
        res["S"] = np.empty((0, 3), np.int64)
    return res
