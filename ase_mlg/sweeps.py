"""Keeping the MLG in order as atoms move: the follow and the swap sweeps.

Maintenance (docs/design.md §4, Boris 1985 sec. III): after atoms move, odd-even
swap sweeps along every line of every axis restore the order; an interior
swap strictly raises sum(i*X + j*Y + k*Z) and leaves sum |g|^2 unchanged, a
seam swap lowers sum |g|^2, so the sweeps terminate (docs/design.md §4).  A cap on
sweeps falls back to a rebuild.

Periodic axes (docs/design.md §5) -- the choice made here
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

import numpy as np
from numba import prange

from .jit import njit
from .parallel import serial_and_parallel, use_threads

__all__ = ["sweep", "is_monotone", "take_positions", "follow"]



@njit(cache=True)
def _swap_sites(sites, coords, s, u):
    """Exchange everything stored at sites s and u (Boris's swap)."""
    a = sites[s]
    sites[s] = sites[u]
    sites[u] = a
    for c in range(3):
        x = coords[s, c]
        coords[s, c] = coords[u, c]
        coords[u, c] = x


@njit(cache=True)
def _flag_offsets(nx, ny, nz):
    """Where the line flags of axes 1 and 2 start in ``act`` (axis 0's at
    0): one flag per line, ``ny*nz`` lines along axis 0, ``nx*nz`` along 1."""
    off1 = ny * nz
    return off1, off1 + nx * nz


@njit(cache=True)
def _row(o, ny, nz):
    """``(i, j, first site)`` of row ``o = i*ny + j``, the line of sites
    ``(i, j, 0 .. nz-1)`` along axis 2."""
    return o // ny, o % ny, o * nz


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
    off1, off2 = _flag_offsets(nx, ny, nz)
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
                # stay continuous in space (docs/design.md §5)
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
    off1, off2 = _flag_offsets(nx, ny, nz)
    for o in prange(nx * ny):
        i, j, row = _row(o, ny, nz)
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


@njit(cache=True)
def _out_of_order(coords, s, c, idx, n, stride, first, period):
    """Whether site ``s``, number ``idx`` of the ``n`` sites of its line
    along axis ``c`` (neighbours ``stride`` sites apart, the line's first
    site ``first``), is out of order with a neighbour, or across the seam
    of a periodic line (``period > 0``)."""
    bad = ((idx > 0 and coords[s - stride, c] > coords[s, c])
           or (idx + 1 < n and coords[s, c] > coords[s + stride, c]))
    if period > 0.0:
        if idx == n - 1 and coords[s, c] > coords[first, c] + period:
            bad = True
        if idx == 0 and coords[s + (n - 1) * stride, c] > coords[s, c] + period:
            bad = True
    return bad


def _check_touched(coords, nx, ny, nz, axis, periods, act, touched):
    """After a pass along ``axis``: for every site it swapped, compare the
    new coordinates with the site's neighbours on the two other axes (and
    across their seams) and flag those lines where a pair is now out of
    order; clear ``touched``.  No coordinate is written here, so the reads
    do not race with anything, and flags are only set to 1: the flags are
    the same on any number of threads."""
    nyz = ny * nz
    off1, off2 = _flag_offsets(nx, ny, nz)
    p0, p1, p2 = periods[0], periods[1], periods[2]
    # axes and strides as values: a literal argument compiles the callee
    # once more for each value (0.4 s of a cold start)
    zero = axis - axis
    one, two = zero + 1, zero + 2
    for o in prange(nx * ny):
        i, j, row = _row(o, ny, nz)
        for k in range(nz):
            s = row + k
            if touched[s] == 0:
                continue
            touched[s] = 0
            if axis != 2 and nz > 1 and _out_of_order(coords, s, two, k, nz, one, row, p2):
                act[off2 + o] = 1
            if axis != 1 and ny > 1 and _out_of_order(coords, s, one, j, ny, nz,
                                                      i * nyz + k, p1):
                act[off1 + i * nz + k] = 1
            if axis != 0 and nx > 1 and _out_of_order(coords, s, zero, i, nx, nyz,
                                                      j * nz + k, p0):
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


def _sweeps(sites, coords, shape, periods, cap):
    """Swap sweeps until a full sweep makes no swap, or ``cap`` sweeps.

    A sweep is one pass along axis 0, then 1, then 2, each pass the even
    phase, the odd phase and the seam of every line (Boris 1985 sec. III).

    Returns (sweeps that swapped, total swaps, converged).

    The loop is Python and calls the serial or the threaded kernels (the
    threading policy, docs/design.md §8).  A numba function that calls a
    threaded (``parallel=True``) kernel caches the thread count it was
    compiled with and crashed (segfault) when loaded under another
    NUMBA_NUM_THREADS, so the threaded loop cannot be compiled; the serial
    one compiled whole saved only 20 µs an update (measured at 1,000 atoms:
    33 against 55 µs; the same at 10^4 atoms: 341 against 385 µs), paid
    once per list build, so both run this one loop.
    """
    nx, ny, nz = (int(s) for s in shape)
    threaded = use_threads("sites", sites.size)
    mark = _mark_parallel if threaded else _mark_serial
    axis_pass = _axis_pass_parallel if threaded else _axis_pass_serial
    check = _check_parallel if threaded else _check_serial
    # one flag per line of each axis: only lines out of order are visited
    act = np.zeros(ny * nz + nx * nz + nx * ny, dtype=np.uint8)
    # one byte per site: swapped in the current pass
    touched = np.zeros(sites.size, dtype=np.uint8)
    mark(coords, nx, ny, nz, periods, act)
    nsweep = 0
    nswap = 0
    while True:
        swaps = 0
        for axis in range(3):
            if shape[axis] >= 2:
                here = axis_pass(sites, coords, nx, ny, nz, axis, periods[axis],
                                 act, touched)
                if here:
                    check(coords, nx, ny, nz, axis, periods, act, touched)
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


def take_positions(pos, out, inverse, periods, limit, threaded):
    """Copy ``pos`` into ``out``; the number of atoms whose fractional
    coordinates are non-finite or beyond ``limit`` cells on a periodic axis
    (see :func:`_take_positions`)."""
    return (_take_parallel if threaded else _take_serial)(pos, out, inverse,
                                                          periods, limit)


def follow(sites, coords, pos, inverse, heights, periods, scale, threaded):
    """Move every site's stored coordinate with its atom (see
    :func:`_follow`), in place."""
    (_follow_parallel if threaded else _follow_serial)(sites, coords, pos, inverse,
                                                       heights, periods, scale)


def sweep(sites, coords, shape, periods, cap):
    """Swap sweeps until the grid is in order; see :func:`_sweeps`.
    Returns (sweeps that swapped, total swaps, converged)."""
    return _sweeps(sites, coords, shape, periods, cap)


def is_monotone(coords, shape, periods):
    """Whether eq. 3.1 and the seam condition hold on every line."""
    return bool(_monotone(coords, shape, periods))
