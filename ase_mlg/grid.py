"""The Monotonic Logical Grid: construction, maintenance, invariants.

N atoms live on the sites ``(i, j, k)`` of an ``(NX, NY, NZ)`` array so that
(Boris 1985, eq. 3.1)::

    X[i,j,k] <= X[i+1,j,k],  Y[i,j,k] <= Y[i,j+1,k],  Z[i,j,k] <= Z[i,j,k+1]

on the grid coordinates of :mod:`ase_mlg.geometry`.  Sites without an atom
are *holes*: they carry coordinates that respect the inequalities and never
interact.

Construction (DESIGN 2.1) is one recursive split, parameterised by the rule
that picks the axis:

* ``method="kd"`` (default): split the site box along its longest logical
  axis at the middle index and send the matching fraction of atoms (by that
  coordinate) to each half.  Local quality does not degrade with N.
* ``method="sort"``: split z first until every box is one plane, then y,
  then x.  Proportional binary splits of a z-sorted set *are* Boris's sort
  construction (sort into NZ planes, each plane by y into rows, each row by
  x, Boris 1985 sec. III), so the seed's baseline costs no second kernel.

Holes are distributed proportionally (every split sends the same fraction of
sites and atoms each way) and sit at the centre of their leaf's region, which
lies between the split values, so the order holds for them too.

Maintenance (DESIGN 2.2, Boris 1985 sec. III): after atoms move, odd-even
swap sweeps along every line of every axis restore the order; each swap
strictly lowers sum(i*X + j*Y + k*Z), so the sweeps terminate.  A cap on
sweeps falls back to a rebuild.

Periodic axes (DESIGN 2.4) -- the choice made here
---------------------------------------------------
A periodic line is *cyclic*: the site after ``NX-1`` is ``0`` one period
further on, and the order includes the seam condition
``X[NX-1] <= X[0] + L``.  Stored coordinates are continuous in time: on
``update`` each site's coordinate moves by the minimum-image displacement of
its atom, so an atom crossing a periodic face does **not** jump from one end
of its line to the other (that would cost O(NX) swaps); it simply carries a
coordinate beyond the face.  When it overtakes the first atom's image, a seam
swap exchanges the two and shifts their stored coordinates by one period,
which keeps every line's window exactly one period wide.  Each line's window
(its *phase*) then follows the centre of mass of its atoms, which wanders
slowly; a cheap monitor compares phases of neighbouring lines every
``monitor_every`` updates and rebuilds when two lines are out of register by
more than ``max_phase_lag`` spacings.  ``validation/periodic_drift.py``
measures sweeps per step and template quality over long periodic runs.
"""

from collections import namedtuple

import numpy as np
from numba import njit, prange

from .geometry import Box, as_positions, cell_change, grid_shape, wrap_origins
from .parallel import serial_and_parallel, use_threads

__all__ = ["MLG", "GridView", "half_template", "template_pairs"]

KD, SORT = 0, 1
_METHODS = {"kd": KD, "sort": SORT}


# --------------------------------------------------------------------------
# construction
# --------------------------------------------------------------------------

@njit(cache=True)
def _select(perm, a0, a1, target, g, axis):
    """Reorder perm[a0:a1] so that keys before ``target`` are <= keys from
    ``target`` on (nth-element, Hoare partition, median-of-three pivot:
    linear on average and safe with many equal keys)."""
    lo = a0
    hi = a1 - 1
    while hi > lo:
        mid = (lo + hi) // 2
        x, y, z = g[perm[lo], axis], g[perm[mid], axis], g[perm[hi], axis]
        pivot = max(min(x, y), min(max(x, y), z))
        i = lo
        j = hi
        while i <= j:
            while g[perm[i], axis] < pivot:
                i += 1
            while g[perm[j], axis] > pivot:
                j -= 1
            if i <= j:
                t = perm[i]
                perm[i] = perm[j]
                perm[j] = t
                i += 1
                j -= 1
        if target <= j:
            hi = j
        elif target >= i:
            lo = i
        else:
            break


@njit(cache=True)
def _build(g, nx, ny, nz, lo0, hi0, method):
    """Recursive-split construction (see module docstring).

    Returns ``sites`` (flat, -1 for holes) and ``coords`` (flat sites x 3).
    """
    n = g.shape[0]
    nsite = nx * ny * nz
    sites = np.full(nsite, -1, dtype=np.int64)
    coords = np.empty((nsite, 3))
    perm = np.arange(n)
    # explicit DFS stack: box (6 ints) + atom range (2 ints), bounds (6 floats)
    cap = 256
    ibox = np.empty((cap, 8), dtype=np.int64)
    fbox = np.empty((cap, 6))
    ibox[0, 0], ibox[0, 1], ibox[0, 2] = 0, 0, 0
    ibox[0, 3], ibox[0, 4], ibox[0, 5] = nx, ny, nz
    ibox[0, 6], ibox[0, 7] = 0, n
    for a in range(3):
        fbox[0, a] = lo0[a]
        fbox[0, 3 + a] = hi0[a]
    top = 1
    if nsite == 0:
        top = 0
    lengths = np.empty(3, dtype=np.int64)
    while top > 0:
        top -= 1
        b = ibox[top].copy()
        f = fbox[top].copy()
        for a in range(3):
            lengths[a] = b[3 + a] - b[a]
        ns = lengths[0] * lengths[1] * lengths[2]
        a0, a1 = b[6], b[7]
        m = a1 - a0
        if ns == 1:
            s = (b[0] * ny + b[1]) * nz + b[2]
            if m == 1:
                sites[s] = perm[a0]
                for a in range(3):
                    coords[s, a] = g[perm[a0], a]
            else:  # a hole: the centre of its leaf's region
                for a in range(3):
                    coords[s, a] = 0.5 * (f[a] + f[3 + a])
            continue
        # pick the axis to split
        axis = 0
        if method == KD:
            best = -1.0
            for a in range(3):
                # longest logical axis; ties go to the larger physical extent
                key = lengths[a] + 1e-9 * min(f[3 + a] - f[a], 1e8) / 1e8
                if lengths[a] > 1 and key > best:
                    best = key
                    axis = a
        else:  # Boris's order: planes (z), then rows (y), then x
            axis = 2 if lengths[2] > 1 else (1 if lengths[1] > 1 else 0)
        c0 = b[axis]
        c1 = b[3 + axis]
        cmid = c0 + (c1 - c0) // 2
        nleft = ns // lengths[axis] * (cmid - c0)
        nright = ns - nleft
        ml = (m * nleft + ns // 2) // ns  # proportional share of atoms
        ml = max(m - nright, min(nleft, ml))
        lo, hi = f[axis], f[3 + axis]
        prop = lo + (hi - lo) * nleft / ns
        if 0 < ml < m:
            _select(perm, a0, a1, a0 + ml, g, axis)
            maxl = g[perm[a0], axis]
            for t in range(a0 + 1, a0 + ml):
                maxl = max(maxl, g[perm[t], axis])
            minr = g[perm[a0 + ml], axis]
            for t in range(a0 + ml + 1, a1):
                minr = min(minr, g[perm[t], axis])
            split = 0.5 * (maxl + minr)
            split = min(max(split, maxl), minr)  # guard rounding
        elif ml == 0 and m > 0:
            minr = g[perm[a0], axis]
            for t in range(a0 + 1, a1):
                minr = min(minr, g[perm[t], axis])
            split = min(prop, minr)
        elif ml == m and m > 0:
            maxl = g[perm[a0], axis]
            for t in range(a0 + 1, a1):
                maxl = max(maxl, g[perm[t], axis])
            split = max(prop, maxl)
        else:
            split = prop
        if top + 2 > cap:
            raise RuntimeError("MLG construction stack overflow")
        # right half
        ibox[top] = b
        ibox[top, axis] = cmid
        ibox[top, 6] = a0 + ml
        fbox[top] = f
        fbox[top, axis] = split
        top += 1
        # left half
        ibox[top] = b
        ibox[top, 3 + axis] = cmid
        ibox[top, 7] = a0 + ml
        fbox[top] = f
        fbox[top, 3 + axis] = split
        top += 1
    return sites, coords


# --------------------------------------------------------------------------
# maintenance: odd-even swap sweeps (Boris 1985 sec. III)
# --------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _swap_sites(sites, coords, s, u):
    """Exchange everything stored at sites s and u (Boris's swap)."""
    a = sites[s]
    sites[s] = sites[u]
    sites[u] = a
    for c in range(3):
        x = coords[s, c]
        coords[s, c] = coords[u, c]
        coords[u, c] = x


def _axis_pass(sites, coords, nx, ny, nz, axis, period, act, touched):
    """One sweep of Boris's odd-even swaps along every line of one axis
    (Boris 1985 sec. III): the even phase, the odd phase and, on a periodic
    axis, the seam, done line by line.

    The phases of one axis touch only pairs inside a line, so a line can run
    all of them before the next line starts, with the result of phase-major
    order bit for bit; lines are independent, so they run in parallel and
    give the same answer on any number of threads.  Lines are handed out in
    chunks of ``_CHUNK`` neighbouring lines (neighbouring in memory on the
    strided axes 0 and 1): a chunk's sites share cache lines, so each pass
    reads the coordinates once instead of once per phase.

    ``act`` holds one flag per line of each axis (axis 0 at 0, axis 1 at
    ny*nz, axis 2 at ny*nz + nx*nz).  A line whose flag is 0 is in order
    and is skipped (it would make no swap).  A line that swaps keeps its
    flag, one that does not is in order and drops it; swapped sites are
    marked in ``touched`` for :func:`_check_touched`, which flags the lines
    of the other axes they put out of order.  Returns the swaps.
    """
    off1 = ny * nz
    off2 = off1 + nx * nz
    if axis == 0:
        n, stride, nouter, base_off = nx, ny * nz, 1, 0
    elif axis == 1:
        n, stride, nouter, base_off = ny, nz, nx, off1
    else:
        n, stride, nouter, base_off = nz, 1, nx * ny, off2
    nchunk = (stride + _CHUNK - 1) // _CHUNK
    swaps = 0
    for w in prange(nouter * nchunk):
        o = w // nchunk
        c0 = (w % nchunk) * _CHUNK
        c1 = min(c0 + _CHUNK, stride)
        for inner in range(c0, c1):
            line = o * stride + inner
            if act[base_off + line] == 0:
                continue
            first = o * n * stride + inner
            here = 0
            for parity in range(2):
                for i in range(parity, n - 1, 2):
                    s = first + i * stride
                    u = s + stride
                    if coords[s, axis] > coords[u, axis]:
                        _swap_sites(sites, coords, s, u)
                        touched[s] = 1
                        touched[u] = 1
                        here += 1
            if period > 0.0:
                # the seam: site n-1 precedes site 0 of the next period; a
                # swap shifts both stored coordinates by one period so they
                # stay continuous in space (DESIGN 2.4)
                last = first + (n - 1) * stride
                if coords[last, axis] > coords[first, axis] + period:
                    _swap_sites(sites, coords, first, last)
                    coords[first, axis] -= period
                    coords[last, axis] += period
                    touched[first] = 1
                    touched[last] = 1
                    here += 1
            if here == 0:
                act[base_off + line] = 0
            swaps += here
    return swaps


def _mark_disorder(coords, nx, ny, nz, periods, act):
    """Set the flag of every line with a pair out of order (or a violated
    seam) after the follow; the other flags stay 0.

    One streaming pass in storage order over rows (i, j): the neighbours
    along axes 2, 1 and 0 are 24 bytes, ``24 nz`` and ``24 ny nz`` bytes
    ahead, so each coordinate is read from memory about once, where visiting
    every line of every axis would read it three times through strided
    lines.  Lines in order make no swap in a pass, so the sweeps may skip
    them: the result is exactly that of sweeping every line.  Flags are only
    ever set to 1, so rows writing the same flag concurrently agree.
    """
    nyz = ny * nz
    off1 = nyz
    off2 = off1 + nx * nz
    for o in prange(nx * ny):
        i = o // ny
        j = o % ny
        row = o * nz
        for k in range(nz):
            s = row + k
            if k + 1 < nz and coords[s, 2] > coords[s + 1, 2]:
                act[off2 + o] = 1
            if j + 1 < ny and coords[s, 1] > coords[s + nz, 1]:
                act[off1 + i * nz + k] = 1
            if i + 1 < nx and coords[s, 0] > coords[s + nyz, 0]:
                act[j * nz + k] = 1
        if periods[2] > 0.0 and nz > 1:
            if coords[row + nz - 1, 2] > coords[row, 2] + periods[2]:
                act[off2 + o] = 1
        if periods[1] > 0.0 and ny > 1 and j == ny - 1:
            for k in range(nz):
                if coords[row + k, 1] > coords[i * nyz + k, 1] + periods[1]:
                    act[off1 + i * nz + k] = 1
        if periods[0] > 0.0 and nx > 1 and i == nx - 1:
            for k in range(nz):
                if coords[row + k, 0] > coords[j * nz + k, 0] + periods[0]:
                    act[j * nz + k] = 1


def _check_touched(coords, nx, ny, nz, axis, periods, act, touched):
    """After a pass along ``axis``: for every site it swapped, compare the
    new coordinates with the site's neighbours on the two other axes (and
    across their seams) and flag those lines where a pair is now out of
    order; clear ``touched``.  No coordinate is written here, so the reads
    do not race with anything, and flags are only set to 1: the flags are
    the same on any number of threads."""
    nyz = ny * nz
    off1 = nyz
    off2 = off1 + nx * nz
    p0, p1, p2 = periods[0], periods[1], periods[2]
    for o in prange(nx * ny):
        i = o // ny
        j = o % ny
        row = o * nz
        for k in range(nz):
            s = row + k
            if touched[s] == 0:
                continue
            touched[s] = 0
            if axis != 2 and nz > 1:
                bad = ((k > 0 and coords[s - 1, 2] > coords[s, 2])
                       or (k + 1 < nz and coords[s, 2] > coords[s + 1, 2]))
                if p2 > 0.0:
                    if k == nz - 1 and coords[s, 2] > coords[row, 2] + p2:
                        bad = True
                    if k == 0 and coords[row + nz - 1, 2] > coords[s, 2] + p2:
                        bad = True
                if bad:
                    act[off2 + o] = 1
            if axis != 1 and ny > 1:
                bad = ((j > 0 and coords[s - nz, 1] > coords[s, 1])
                       or (j + 1 < ny and coords[s, 1] > coords[s + nz, 1]))
                if p1 > 0.0:
                    if j == ny - 1 and coords[s, 1] > coords[i * nyz + k, 1] + p1:
                        bad = True
                    if j == 0 and coords[s + (ny - 1) * nz, 1] > coords[s, 1] + p1:
                        bad = True
                if bad:
                    act[off1 + i * nz + k] = 1
            if axis != 0 and nx > 1:
                bad = ((i > 0 and coords[s - nyz, 0] > coords[s, 0])
                       or (i + 1 < nx and coords[s, 0] > coords[s + nyz, 0]))
                if p0 > 0.0:
                    if i == nx - 1 and coords[s, 0] > coords[j * nz + k, 0] + p0:
                        bad = True
                    if i == 0 and coords[s + (nx - 1) * nyz, 0] > coords[s, 0] + p0:
                        bad = True
                if bad:
                    act[j * nz + k] = 1


# Lines per work item of a pass (see _axis_pass).  16 lines x 24 bytes fill
# six cache lines per step along a strided line.
_CHUNK = 16

# Each pass is compiled twice: threads pay off only on large grids, and on
# small ones the cost of waking them (tens of launches per MD step) would
# dominate.  Both give the same answer (independent lines).  The twins need
# distinct cache entries (see ase_mlg.parallel).
_axis_pass_serial, _axis_pass_parallel = serial_and_parallel(_axis_pass)
_mark_serial, _mark_parallel = serial_and_parallel(_mark_disorder)
_check_serial, _check_parallel = serial_and_parallel(_check_touched)


@njit(cache=True)
def _sweeps_serial(sites, coords, nx, ny, nz, periods, cap, act, touched):
    """The sweep loop of :func:`_sweeps` compiled whole for small grids (one
    call per update instead of three per sweep; serial kernels only)."""
    _mark_serial(coords, nx, ny, nz, periods, act)
    nsweep = 0
    nswap = 0
    shape = (nx, ny, nz)
    while True:
        swaps = 0
        for axis in range(3):
            if shape[axis] >= 2:
                here = _axis_pass_serial(sites, coords, nx, ny, nz, axis,
                                         periods[axis], act, touched)
                if here:
                    _check_serial(coords, nx, ny, nz, axis, periods, act, touched)
                swaps += here
        if swaps == 0:
            return nsweep, nswap, True
        nsweep += 1
        nswap += swaps
        if nsweep >= cap:
            return nsweep, nswap, False


def _sweeps(sites, coords, shape, periods, cap):
    """Swap sweeps until a full sweep makes no swap, or ``cap`` sweeps.

    A sweep is one pass along axis 0, then 1, then 2, each pass the even
    phase, the odd phase and the seam of every line (Boris 1985 sec. III).

    Returns (sweeps that swapped, total swaps, converged).

    On large grids the loop is Python on purpose: a numba function that
    calls a threaded (``parallel=True``) kernel caches the thread count it
    was compiled with and crashed (segfault) when loaded under another
    NUMBA_NUM_THREADS.  Small grids run the whole loop in one serial
    compiled call.
    """
    nx, ny, nz = (int(s) for s in shape)
    # one flag per line of each axis: only lines out of order are visited
    act = np.zeros(ny * nz + nx * nz + nx * ny, dtype=np.uint8)
    # one byte per site: swapped in the current pass
    touched = np.zeros(sites.size, dtype=np.uint8)
    if not use_threads("sites", sites.size):
        return _sweeps_serial(sites, coords, nx, ny, nz, periods, cap, act, touched)
    _mark_parallel(coords, nx, ny, nz, periods, act)
    nsweep = 0
    nswap = 0
    while True:
        swaps = 0
        for axis in range(3):
            if shape[axis] >= 2:
                here = _axis_pass_parallel(sites, coords, nx, ny, nz, axis,
                                           periods[axis], act, touched)
                if here:
                    _check_parallel(coords, nx, ny, nz, axis, periods, act, touched)
                swaps += here
        if swaps == 0:
            return nsweep, nswap, True
        nsweep += 1
        nswap += swaps
        if nsweep >= cap:
            return nsweep, nswap, False


@njit(cache=True)
def _monotone(coords, shape, periods):
    """Check eq. 3.1 (plus the seam condition on periodic axes)."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    c = coords.reshape((nx, ny, nz, 3))
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if i + 1 < nx and c[i, j, k, 0] > c[i + 1, j, k, 0]:
                    return False
                if j + 1 < ny and c[i, j, k, 1] > c[i, j + 1, k, 1]:
                    return False
                if k + 1 < nz and c[i, j, k, 2] > c[i, j, k + 1, 2]:
                    return False
    for axis in range(3):
        n = shape[axis]
        if periods[axis] > 0.0 and n > 1:
            for i in range(nx):
                for j in range(ny):
                    for k in range(nz):
                        idx = (i, j, k)[axis]
                        if idx != n - 1:
                            continue
                        if axis == 0:
                            first = c[0, j, k, 0]
                        elif axis == 1:
                            first = c[i, 0, k, 1]
                        else:
                            first = c[i, j, 0, 2]
                        if c[i, j, k, axis] > first + periods[axis]:
                            return False
    return True


def _take_positions(pos, out, inverse, periods, limit):
    """Copy ``pos`` into ``out`` and count the atoms whose fractional
    coordinates are non-finite, or beyond ``limit`` cells on a periodic
    axis (the caller then raises the detailed error).  A non-finite
    position always gives a non-finite fractional coordinate (the inverse
    has no zero row), so this is also the NaN/inf check."""
    bad = 0
    for i in prange(pos.shape[0]):
        p0 = pos[i, 0]
        p1 = pos[i, 1]
        p2 = pos[i, 2]
        out[i, 0] = p0
        out[i, 1] = p1
        out[i, 2] = p2
        for c in range(3):
            f = p0 * inverse[0, c] + p1 * inverse[1, c] + p2 * inverse[2, c]
            if not np.isfinite(f) or (periods[c] > 0.0 and abs(f) > limit):
                bad += 1
    return bad


def _follow(sites, coords, pos, inverse, heights, periods, scale):
    """Rescale every stored coordinate by ``scale`` (per axis, > 0: the
    cell changed, see :meth:`MLG.update`), then move each site's coordinate
    by its atom's displacement in grid coordinates ``g = (pos @ inverse) *
    heights``, taking the minimum image on periodic axes so stored
    coordinates stay continuous (an atom crossing a periodic face keeps
    going instead of jumping).  Multiplication by a positive constant is
    monotone, so the rescale keeps every line in order.

    Atoms are in the user's order, so reading ``pos`` in site order is a
    random gather.  It is done first for a block of sites in a tight loop
    (many cache misses in flight at once), then the arithmetic; one loop
    doing both kept too few misses in flight (measured 70 ms -> see
    validation/bench_grid.py at 10^6 atoms).
    """
    nsite = sites.size
    nblock = (nsite + _FOLLOW_BLOCK - 1) // _FOLLOW_BLOCK
    for b in prange(nblock):
        s0 = b * _FOLLOW_BLOCK
        s1 = min(s0 + _FOLLOW_BLOCK, nsite)
        buf = np.empty((s1 - s0, 3))
        for s in range(s0, s1):
            a = sites[s]
            if a >= 0:
                buf[s - s0, 0] = pos[a, 0]
                buf[s - s0, 1] = pos[a, 1]
                buf[s - s0, 2] = pos[a, 2]
        for s in range(s0, s1):
            if sites[s] < 0:
                for c in range(3):
                    coords[s, c] *= scale[c]
                continue
            p0 = buf[s - s0, 0]
            p1 = buf[s - s0, 1]
            p2 = buf[s - s0, 2]
            for c in range(3):
                x = coords[s, c] * scale[c]
                g = (p0 * inverse[0, c] + p1 * inverse[1, c] + p2 * inverse[2, c]) * heights[c]
                d = g - x
                if periods[c] > 0.0:
                    d -= periods[c] * np.rint(d / periods[c])
                coords[s, c] = x + d


_FOLLOW_BLOCK = 1024


_take_serial, _take_parallel = serial_and_parallel(_take_positions)
_follow_serial, _follow_parallel = serial_and_parallel(_follow)


# --------------------------------------------------------------------------
# Boris's template (DESIGN 2.6)
# --------------------------------------------------------------------------

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


def _template_scan(sites, shape, pbc, offsets, selfinv, sp, sf,
                   cell, cutoff, counts, out_i, out_j, out_S, out_D, start,
                   fill):
    """``sp``/``sf``: Cartesian/fractional positions in *site* order, so the
    template walk reads memory near the site instead of jumping by atom
    index.  For every site, walk the half template and keep pairs with d < cutoff
    (minimum image on periodic axes).  Run twice: ``fill=False`` counts pairs
    per site, ``fill=True`` writes them at ``start[s]``; the output order is
    fixed by the site order, so the parallel and serial runs agree."""
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
    offsets, selfinv = half_template(width, grid.shape, grid.box.pbc)
    shape = np.array(grid.shape, dtype=np.int64)
    sites = grid.sites.reshape(-1)
    pbc = grid.box.pbc.copy()
    occ = sites >= 0
    sp = np.zeros((sites.size, 3))
    sp[occ] = grid.positions[sites[occ]]
    sf = grid.box.fractional(sp)
    counts = np.zeros(sites.size, dtype=np.int64)
    e_i = np.empty(0, np.int64)
    e_S = np.empty((0, 3), np.int64)
    e_D = np.empty((0, 3))
    args = (sites, shape, pbc, offsets, selfinv, sp, sf, grid.box.cell, cutoff)
    scan = _template_scan_parallel if use_threads("sites", sites.size) else _template_scan_serial
    scan(*args, counts, e_i, e_i, e_S, e_D, counts, False)
    start = np.zeros(sites.size, dtype=np.int64)
    np.cumsum(counts[:-1], out=start[1:])
    m = int(counts.sum())
    i = np.empty(m, np.int64)
    j = np.empty(m, np.int64)
    S = np.empty((m, 3), np.int64)
    D = np.empty((m, 3))
    scan(*args, counts, i, j, S, D, start, True)
    return i, j, S, D


# --------------------------------------------------------------------------
# the grid object
# --------------------------------------------------------------------------

# Periodic coordinates further than this many cells from the cell cannot be
# wrapped to better than ~2**36 * 2**-52 = 1.5e-5 of a cell; beyond it the exact
# query was measured to fail (MemoryError at 1e11 cells), so refuse clearly.
MAX_CELLS = 2.0 ** 36


def _check_fractional(frac, pbc):
    bad = ~np.isfinite(frac).all(axis=1)
    if pbc.any():
        bad |= (np.abs(frac[:, pbc]) > MAX_CELLS).any(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise ValueError(
            f"positions: atom(s) {idx[:10].tolist()}{' ...' if len(idx) > 10 else ''} "
            f"are more than 2**36 (7e10) cells from the cell (or overflow); they cannot "
            f"be wrapped without losing precision -- wrap them (atoms.wrap()) first")


def _int_arg(name, value, minimum):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer, float, np.floating)):
        raise TypeError(f"{name}: expected an int, got {value!r}")
    if not np.isfinite(value) or int(value) != value or value < minimum:
        raise ValueError(f"{name}: must be an int >= {minimum}, got {value!r}")
    return int(value)


GridView = namedtuple("GridView", "sites coordinates periods shape positions box")


def _read_only(a):
    v = a.view()
    v.flags.writeable = False
    return v


class MLG:
    """A Monotonic Logical Grid of atoms (Boris 1985).

    Parameters
    ----------
    positions : array_like, shape (N, 3)
        Cartesian positions (Å).  Any float dtype or memory layout; computed
        in float64.
    cell : array_like, shape (3, 3), optional
        Cell vectors as rows (Å).  May be zero on non-periodic axes.
    pbc : bool or 3 bools
        Periodic axes.  Only periodic axes wrap (coordinates and template).
    method : {"kd", "sort"}
        Construction: recursive median split (default) or Boris's sort.
    shape : 3 ints, optional
        Force the grid shape (``NX*NY*NZ >= N``); by default it follows the
        occupied extent and dimensionality of the atoms (DESIGN 2.3).
    sweep_cap : int
        Maximum swap sweeps per update before falling back to a rebuild.
    monitor_every : int
        Updates between checks of line registration on periodic axes.
    max_phase_lag : float
        Rebuild when two lines of a periodic axis are out of register by more
        than this many site spacings.

    Attributes
    ----------
    shape : tuple (NX, NY, NZ)
    sites : int64 array (NX, NY, NZ)
        Atom index at each site, -1 for a hole.  Every atom appears once.
    positions : float64 array (N, 3)
        The positions the grid was last built or updated with (Å).
    box : :class:`ase_mlg.geometry.Box`
        Cell and pbc.
    stats : dict
        Cumulative ``updates``, ``sweeps``, ``swaps``, ``rebuilds`` and the
        ``last`` update's record.
    """

    def __init__(self, positions, cell=None, pbc=False, method="kd",
                 shape=None, sweep_cap=64, monitor_every=10,
                 max_phase_lag=1.5):
        if not isinstance(method, str) or method not in _METHODS:
            raise ValueError(f"method: expected 'kd' or 'sort', got {method!r}")
        sweep_cap = _int_arg("sweep_cap", sweep_cap, 1)
        monitor_every = _int_arg("monitor_every", monitor_every, 0)
        try:
            max_phase_lag = float(max_phase_lag)
        except (TypeError, ValueError):
            raise TypeError(f"max_phase_lag: expected a number, got {max_phase_lag!r}") from None
        if not max_phase_lag > 0:  # also NaN
            raise ValueError(f"max_phase_lag: must be > 0, got {max_phase_lag}")
        self.method = method
        self.box = Box(cell, pbc)
        self.sweep_cap = sweep_cap
        self.monitor_every = monitor_every
        self.max_phase_lag = max_phase_lag
        self._forced_shape = None if shape is None else tuple(int(s) for s in shape)
        self.stats = {"updates": 0, "sweeps": 0, "swaps": 0, "rebuilds": 0,
                      "last": None}
        self._build(as_positions(positions))

    @classmethod
    def from_atoms(cls, atoms, **kwargs):
        """Grid of an ASE ``Atoms`` object (positions, cell, pbc)."""
        return cls(atoms.positions, atoms.cell.array, atoms.pbc, **kwargs)

    # -- construction -----------------------------------------------------
    def _grid_coordinates(self, positions):
        frac = self.box.fractional(positions)
        _check_fractional(frac, self.box.pbc)
        self._origin = wrap_origins(frac, self.box.pbc)
        for a in range(3):
            if self.box.pbc[a]:
                f = frac[:, a] - self._origin[a]
                frac[:, a] = f - np.floor(f) + self._origin[a]
        return np.ascontiguousarray(frac * self.box.heights)

    def _build(self, positions):
        n = len(positions)
        self.positions = positions.copy()
        self.natoms = n
        g = self._grid_coordinates(positions) if n else np.zeros((0, 3))
        pbc = self.box.pbc
        h = self.box.heights
        if n:
            lo, hi = g.min(axis=0), g.max(axis=0)
            extent = hi - lo
            for a in range(3):
                if pbc[a]:
                    # a periodic axis filled with atoms spans its whole period
                    if self._origin[a] == 0.0:
                        lo[a], hi[a] = 0.0, h[a]
                        extent[a] = h[a]
        else:
            lo = hi = extent = np.zeros(3)
        # a periodic axis with a vacuum gap is gridded over its occupied
        # extent, like an open axis
        filled = pbc & (self._origin == 0.0) if n else pbc
        shape = self._forced_shape or grid_shape(extent, filled, n)
        if np.prod(shape) < n or min(shape) < (1 if n else 0):
            raise ValueError(f"shape: {shape} has fewer sites than the {n} atoms")
        self.shape = tuple(int(s) for s in shape)
        self._periods = np.where(pbc, h, 0.0)
        sites, coords = _build(g, *self.shape, lo.astype(np.float64),
                               hi.astype(np.float64), _METHODS[self.method])
        self._sites = sites
        self._coords = coords
        self._since_monitor = 0

    def rebuild(self, positions=None):
        """Construct the grid anew (O(N log N))."""
        pos = self.positions if positions is None else as_positions(positions)
        self._build(pos)
        self.stats["rebuilds"] += 1

    # -- public views -------------------------------------------------------
    def view(self):
        """Read-only views of the grid's own arrays (no copies), for the
        queries built on it.

        Returns
        -------
        GridView
            ``sites`` (int64, flat, atom at each site or -1), ``coordinates``
            (float64, (nsites, 3), the stored grid coordinates the order holds
            on, Å), ``periods`` (float64, 3, cell height on periodic axes,
            0 on open ones, Å), ``shape``, ``positions`` (Å) and ``box``.
        """
        return GridView(_read_only(self._sites), _read_only(self._coords),
                        _read_only(self._periods), self.shape,
                        _read_only(self.positions), self.box)

    @property
    def sites(self):
        return self._sites.reshape(self.shape)

    @property
    def nholes(self):
        return int(np.prod(self.shape)) - self.natoms

    def coordinates(self):
        """Grid coordinates of every site, shape ``(NX, NY, NZ, 3)`` (Å).

        These are the numbers the monotone order holds on (holes included):
        fractional coordinates times cell heights, continuous in time across
        periodic faces (see the module docstring)."""
        return self._coords.reshape(self.shape + (3,)).copy()

    def site_of_atom(self):
        """Flat site index of each atom (inverse of ``sites``)."""
        inv = np.empty(self.natoms, dtype=np.int64)
        occ = np.flatnonzero(self._sites >= 0)
        inv[self._sites[occ]] = occ
        return inv

    def is_monotone(self):
        """True when eq. 3.1 holds on every line (and the seam condition on
        periodic axes)."""
        if self._sites.size == 0:
            return True
        return bool(_monotone(self._coords, np.array(self.shape), self._periods))

    # -- maintenance ----------------------------------------------------------
    def update(self, positions, cell=None, pbc=None):
        """Follow the atoms to ``positions`` and restore the order by swap
        sweeps (O(N), Boris 1985 sec. III); rebuild if the sweep cap is hit
        or periodic lines have drifted out of register.

        Parameters
        ----------
        positions : array_like, shape (N, 3)
            New Cartesian positions (Å), N as at construction.
        cell : array_like, shape (3, 3) or (3,), optional
            New cell (NPT).  An affine change of the cell keeps the grid:
            every stored grid coordinate, periodic image offsets and holes
            included, is multiplied by ``h'_a / h_a`` (new over old cell
            height per axis, > 0), which keeps the order exactly (see
            :func:`ase_mlg.geometry.cell_change`); then the usual follow and
            sweeps.  The grid is rebuilt instead when a cell vector appears
            or vanishes, or the cell degenerates (``reason`` says which).
        pbc : bool or 3 bools, optional
            New periodic axes; a change rebuilds the grid.

        Returns
        -------
        dict
            ``sweeps`` (sweeps that swapped), ``swaps``, ``rebuilt`` (bool)
            and ``reason`` (None, "sweep cap", "phase lag", "pbc changed",
            "cell rank changed", "cell completion changed" or "cell
            degenerate").  Also added to ``stats``.

        Raises
        ------
        ValueError
            If N differs from the grid's (build a new grid), a position is
            not finite or too far from the cell, or the new cell has no
            volume on a periodic axis.
        """
        # the common case (a float64 C array) skips as_positions' numpy
        # passes: the copy kernel below checks finiteness in parallel
        if not (type(positions) is np.ndarray and positions.dtype == np.float64
                and positions.ndim == 2 and positions.shape[1] == 3
                and positions.flags.c_contiguous):
            positions = as_positions(positions)
        if len(positions) != self.natoms:
            raise ValueError(f"positions: grid holds {self.natoms} atoms, got "
                             f"{len(positions)}; build a new grid (or call rebuild)")
        box, reason, scale = self.box, None, None
        if cell is not None or pbc is not None:
            box = Box(self.box.cell if cell is None else cell,
                      self.box.pbc if pbc is None else pbc)
            if box.same_as(self.box):
                box = self.box
            else:
                reason, scale = cell_change(self.box, box)
        periods = np.where(box.pbc, box.heights, 0.0)
        # validate against the new cell before any state changes, so a bad
        # call leaves the grid as it was
        pos = np.empty((self.natoms, 3))
        par = use_threads("sites", self._sites.size)
        take = _take_parallel if par else _take_serial
        if take(positions, pos, box.inverse, periods, MAX_CELLS):
            as_positions(positions)  # raises the NaN/inf error
            _check_fractional(box.fractional(positions), box.pbc)
            raise ValueError("positions: non-finite fractional coordinates")
        self.positions = pos
        rec = {"sweeps": 0, "swaps": 0, "rebuilt": False, "reason": None}
        if reason is not None:
            self.box = box
            self.rebuild(pos)
            rec["rebuilt"], rec["reason"] = True, reason
        elif self.natoms:
            if box is not self.box:
                self.box = box
                self._periods = periods
            if scale is None:
                scale = np.ones(3)
            follow = _follow_parallel if par else _follow_serial
            follow(self._sites, self._coords, pos, box.inverse, box.heights,
                   self._periods, scale)
            sweeps, swaps, ok = _sweeps(self._sites, self._coords,
                                        np.array(self.shape), self._periods,
                                        self.sweep_cap)
            rec["sweeps"], rec["swaps"] = int(sweeps), int(swaps)
            if not ok:
                rec["rebuilt"], rec["reason"] = True, "sweep cap"
            elif self.box.pbc.any() and self.monitor_every > 0:
                self._since_monitor += 1
                if self._since_monitor >= self.monitor_every:
                    self._since_monitor = 0
                    if self.phase_lag() > self.max_phase_lag:
                        rec["rebuilt"], rec["reason"] = True, "phase lag"
            if rec["rebuilt"]:
                self.rebuild(pos)
        else:
            self.box = box
            self._periods = periods
        st = self.stats
        st["updates"] += 1
        st["sweeps"] += rec["sweeps"]
        st["swaps"] += rec["swaps"]
        st["last"] = rec
        return rec

    def phase_lag(self):
        """Largest misregistration between adjacent lines of a periodic
        axis, in site spacings.

        A line's phase is the mean offset of its stored coordinates from the
        evenly spaced positions ``(i + 1/2) L / n``; seam swaps preserve it,
        so it follows the line's centre of mass (DESIGN 2.4).  Adjacent lines
        whose phases differ by p spacings pair site i with site i - p.
        """
        c = self._coords.reshape(self.shape + (3,))
        worst = 0.0
        for a in range(3):
            n = self.shape[a]
            if not self.box.pbc[a] or n < 2:
                continue
            spacing = self._periods[a] / n
            ideal = (np.arange(n) + 0.5) * spacing
            x = np.moveaxis(c[..., a], a, -1) - ideal
            phase = x.mean(axis=-1) / spacing  # (lines over the other two axes)
            for ax in range(2):
                if phase.shape[ax] > 1:
                    worst = max(worst, float(np.abs(np.diff(phase, axis=ax)).max()))
        return worst

    def __repr__(self):
        return (f"MLG(natoms={self.natoms}, shape={self.shape}, holes={self.nholes}, "
                f"method={self.method!r}, pbc={self.box.pbc.tolist()})")
