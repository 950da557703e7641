"""Cells, periodic boundaries and the shape of the grid a scene needs.

The MLG orders atoms by *grid coordinates* ``g = f * h``: fractional
coordinates ``f`` of the (completed) cell scaled by the cell heights ``h``
(distance between opposite faces, Å).  For an orthorhombic cell aligned with
the axes ``g`` is the Cartesian position; for a triclinic cell the monotone
order lives in fractional space while every distance is Cartesian
(docs/design.md §3).  Along a periodic axis the coordinate is wrapped into one period
``[origin, origin + h)``, the origin sitting in the widest empty gap so that a
slab with vacuum is not cut through the middle.

Nothing here knows about ASE ``Atoms``: positions, cell and pbc come in as
arrays, so the grid can be used from any code.
"""

import numba
import numpy as np

from .jit import njit

__all__ = ["Box", "as_pbc", "as_positions", "cell_change", "grid_shape", "same", "stored_atoms"]


def as_positions(positions, name="positions"):
    """Return ``positions`` as a C-contiguous float64 ``(N, 3)`` array.

    Raises
    ------
    TypeError
        If the array is not numeric.
    ValueError
        If the shape is not ``(N, 3)`` or an entry is NaN/inf (the message
        names the first offending atom).
    """
    arr = positions
    if not (type(arr) is np.ndarray and arr.dtype == np.float64 and arr.ndim == 2
            and arr.shape[1] == 3 and arr.flags.c_contiguous):
        arr = _numeric_positions(positions, name)
    if np.isfinite(arr).all():  # 30x faster than per row (1.4 ms at 10^5)
        return arr
    bad = ~np.isfinite(arr).all(axis=1)
    idx = np.flatnonzero(bad)
    raise ValueError(f"{name}: non-finite (NaN/inf) coordinates for atom(s) "
                     f"{idx[:10].tolist()}{' ...' if len(idx) > 10 else ''}")


def _numeric_positions(positions, name):
    """``positions`` as a C-contiguous float64 ``(N, 3)`` array, or the
    TypeError or ValueError :func:`as_positions` raises on its type or
    shape (the checks an ASE system's positions, float64 (N, 3) already,
    skip: 3 µs of a call on one atom)."""
    arr = np.asarray(positions)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number)
                                   or arr.dtype == bool):
        raise TypeError(f"{name}: expected a numeric array, got dtype {arr.dtype}")
    if np.iscomplexobj(arr):
        raise TypeError(f"{name}: complex coordinates are not allowed")
    if arr.ndim != 2 or arr.shape[1] != 3:
        if arr.size == 0 and arr.ndim <= 2:
            return np.zeros((0, 3))
        raise ValueError(f"{name}: expected shape (N, 3), got {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.float64)


def same(a, b):
    """``np.array_equal(a, b)`` for the arrays a force call compares (atomic
    numbers, positions, cell, pbc) without its numpy passes, which were a fifth of the
    calculator's own time at 256 atoms: integers and bools by their bytes, a
    few floats as Python lists (NaN is unequal, -0.0 equals 0.0, as there).
    Arrays over 64 KiB of the same dtype (positions from 2,731 atoms, numbers
    from 8,193) are compared word by word, compiled, with an early exit: 3 of
    them a step cost 30 µs as numpy passes at 10^4 atoms; a float's bits are
    stricter than its value only for -0.0 against 0.0, and equal NaN bits
    are equal (as ASE's own check_state finds them)."""
    if type(a) is not np.ndarray:
        a = np.asarray(a)
    if type(b) is not np.ndarray:
        b = np.asarray(b)
    if a.shape != b.shape:
        return False
    dtype = a.dtype
    if dtype.kind in "biu" and dtype == b.dtype and a.nbytes <= 1 << 16:
        return a.tobytes() == b.tobytes()
    if a.size <= 64:
        return a.tolist() == b.tolist()
    # positions after an MD step differ at once: a full pass only where the
    # first entries agree (NaN is unequal here too)
    if a.item(0) != b.item(0):
        return False
    if dtype == b.dtype and a.nbytes > 1 << 16 and a.nbytes % 8 == 0 \
            and a.flags.c_contiguous and b.flags.c_contiguous:
        return _same_words(a.reshape(-1).view(np.uint64), b.reshape(-1).view(np.uint64))
    return bool(np.array_equal(a, b))


@njit(cache=True, nogil=True)
def _same_words(a, b):
    # blocks without a branch (LLVM vectorises them), a test after each
    n = a.shape[0]
    for lo in range(0, n, 1024):
        diff = numba.uint64(0)
        for i in range(lo, min(lo + 1024, n)):
            diff |= a[i] ^ b[i]
        if diff:
            return False
    return True


def stored_atoms(old, atoms, positions_only=False):
    """A calculator's stored copy of ``atoms`` (an ASE ``Atoms``): ``old``
    with the positions and cell of ``atoms`` written into it where the atom
    count, numbers and pbc are the same (no new copy a call), else a new
    copy.  ``positions_only``: the caller knows that only the positions can
    differ (3 µs of a force call at 256 atoms saved).

    The copy keeps what a pair potential reads and the calculator's
    ``check_state`` compares (numbers, positions, cell, pbc), not the
    momenta, masses or other per-atom arrays that ``atoms.copy()`` takes:
    the momenta alone were 23 MB at 10^6 atoms.  The positions keep their
    dtype (another dtype is a new copy), so that complex or string positions
    are refused, not cast into the last call's array.  It carries the
    :func:`state_key` of what it was given as ``mlg_key``."""
    kind = old is not None and old is not atoms and old.positions.dtype == atoms.positions.dtype
    if positions_only and kind and old.positions.shape == atoms.positions.shape:
        old.positions[:] = atoms.positions
        return old
    if old is atoms:
        pass
    elif (not kind or len(old) != len(atoms) or not same(old.numbers, atoms.numbers)
            or not same(old.pbc, atoms.pbc)):
        old = atoms.copy()
        for name in [k for k in old.arrays if k not in ("numbers", "positions")]:
            del old.arrays[name]
    else:
        old.positions[:] = atoms.positions
        if not same(old.cell.array, atoms.cell.array):
            old.cell = atoms.cell.copy()
    old.mlg_key = state_key(old)
    return old


def state_key(atoms):
    """The atomic numbers, cell and pbc of ``atoms`` as one string of
    bytes: what a force call compares besides the positions, in one
    comparison (three took 3.6 µs of a 256-atom call).  Equal keys are
    equal arrays, bit for bit (stricter than :func:`same` for -0.0 against
    0.0 only, so at worst a call is repeated; NaN bits are equal, as ASE's
    check finds them)."""
    return atoms.arrays["numbers"].tobytes() + atoms.cell.array.tobytes() + atoms.pbc.tobytes()


def as_pbc(pbc):
    """Return ``pbc`` as a new bool array of 3.

    Raises
    ------
    ValueError
        If it is not a bool or 3 bools (numbers are read as bools).
    """
    pbc_arr = np.asarray(pbc)
    if pbc_arr.dtype == object or pbc_arr.dtype.kind not in "biuf" \
            or pbc_arr.shape not in ((), (3,)):
        raise ValueError(f"pbc: expected a bool or 3 bools, got {pbc!r}")
    return np.broadcast_to(pbc_arr.astype(bool), (3,)).copy()


class Box:
    """A cell with periodic boundary conditions.

    Parameters
    ----------
    cell : array_like, shape (3, 3) or (3,) or None
        Cell vectors as rows (Å).  Zero vectors are allowed on non-periodic
        axes (as in ASE); they are completed by unit vectors orthogonal to the
        others so that fractional coordinates always exist.
    pbc : bool or sequence of 3 bool
        Periodic axes.

    Raises
    ------
    ValueError
        If the cell has the wrong shape, is non-finite, or a periodic axis
        has no volume (zero vector, or cell vectors linearly dependent).
    """

    def __init__(self, cell=None, pbc=False):
        pbc = as_pbc(pbc)
        if cell is None:
            cell = np.zeros((3, 3))
        cell = np.asarray(cell)
        if cell.dtype == object or np.iscomplexobj(cell) or not (
                np.issubdtype(cell.dtype, np.number) or cell.dtype == bool):
            raise TypeError(f"cell: expected a real numeric array, got dtype {cell.dtype}")
        cell = cell.astype(np.float64)
        if cell.shape == (3,):
            cell = np.diag(cell)
        if cell.shape != (3, 3):
            raise ValueError(f"cell: expected shape (3, 3) or (3,), got {cell.shape}")
        if not np.isfinite(cell).all():
            raise ValueError("cell: contains NaN or inf")
        self.cell = np.ascontiguousarray(cell)
        self.pbc = pbc
        self.full = _complete_cell(self.cell, pbc)
        # which cell vectors were given (the others are completed)
        self.present = _present(self.cell)
        self.volume = abs(np.linalg.det(self.full))
        self.inverse = np.ascontiguousarray(np.linalg.inv(self.full))
        # height of the cell along each axis: volume / area of the opposite face
        # (= 1 / |reciprocal vector|); the grid coordinate of axis a is f_a * h_a.
        self.heights = 1.0 / np.linalg.norm(self.inverse, axis=0)

    @property
    def stretch(self):
        """How much longer a displacement can be in grid coordinates than in
        Cartesian ones: ``g = N x`` with ``N`` the unit face normals (rows),
        so ``|dg| <= sqrt(max eig N N^T) |dx|``; 1 for an orthorhombic cell."""
        N = self.inverse.T * self.heights[:, None]
        return float(np.sqrt(np.linalg.eigvalsh(N @ N.T).max()))

    def fractional(self, positions):
        """Fractional coordinates of ``positions`` (not wrapped)."""
        return positions @ self.inverse

    def same_as(self, other):
        return (np.array_equal(self.cell, other.cell)
                and np.array_equal(self.pbc, other.pbc))

    def __repr__(self):
        return f"Box(cell={self.cell.tolist()}, pbc={self.pbc.tolist()})"


def _present(cell):
    """Per axis, whether the cell vector is given (not zero), with the same
    threshold as :func:`_complete_cell`."""
    lengths = np.linalg.norm(cell, axis=1)
    return lengths > 1e-12 * max(lengths.max(), 1.0)


# A cell whose volume is below this fraction of the product of its vector
# lengths is treated as degenerate by :func:`cell_change` (``Box`` itself
# refuses 1e-9): the grid coordinates of such a flat cell say little about
# the atoms' neighbourhoods, so the grid is rebuilt for its shape.
FLAT_CELL = 1e-6


def cell_change(old, new):
    """How a grid built on ``old`` can follow a change of cell to ``new``.

    Grid coordinates are ``g_a = f_a h_a``.  When the cell changes affinely
    and the atoms move with it, the fractional coordinates ``f`` stay and
    every ``g_a`` is multiplied by ``h'_a / h_a > 0``, also the periodic
    image offsets ``m h_a`` stored by the grid (they become ``m h'_a``).
    Multiplying by a positive constant is monotone, so the grid's order
    survives exactly and only the atoms' own moves need swaps.

    Parameters
    ----------
    old, new : Box

    Returns
    -------
    reason : str or None
        None when the grid can keep its order (rescale by ``scale``), else
        why it must be rebuilt: ``"pbc changed"``; ``"cell rank changed"``
        (a cell vector appeared or vanished, so the completion of the cell,
        and with it the meaning of a grid coordinate, changed);
        ``"cell completion changed"`` (a completed vector turned: possible
        when two vectors are missing); ``"cell degenerate"`` (volume nearly
        zero, or the cell's handedness flipped, i.e. it passed through zero
        volume).
    scale : float64 array (3,) or None
        ``new.heights / old.heights`` when ``reason`` is None.
    """
    if not np.array_equal(old.pbc, new.pbc):
        return "pbc changed", None
    if not np.array_equal(old.present, new.present):
        return "cell rank changed", None
    for a in range(3):
        if not new.present[a] and np.dot(old.full[a], new.full[a]) < 0.5:
            return "cell completion changed", None
    det_old = np.linalg.det(old.full)
    det_new = np.linalg.det(new.full)
    norms = np.prod(np.linalg.norm(new.full, axis=1))
    if det_old * det_new <= 0.0 or not abs(det_new) > FLAT_CELL * norms:
        return "cell degenerate", None
    scale = new.heights / old.heights
    if not (np.isfinite(scale).all() and (scale > 0).all()):
        return "cell degenerate", None
    return None, scale


def _complete_cell(cell, pbc):
    """Replace missing (zero) vectors of non-periodic axes by orthonormal ones."""
    full = cell.copy()
    lengths = np.linalg.norm(cell, axis=1)
    scale = max(lengths.max(), 1.0)
    for a in range(3):
        if pbc[a] and lengths[a] <= 1e-12 * scale:
            raise ValueError(f"cell: periodic axis {a} has a zero cell vector "
                             "(zero-volume periodic cell)")
    missing = [a for a in range(3) if lengths[a] <= 1e-12 * scale]
    present = [a for a in range(3) if a not in missing]
    if len(missing) == 3:
        return np.eye(3)
    if len(missing) == 2:
        v = full[present[0]] / lengths[present[0]]
        # two unit vectors orthogonal to v
        trial = np.eye(3)[np.argmin(np.abs(v))]
        u = np.cross(v, trial)
        u /= np.linalg.norm(u)
        w = np.cross(v, u)
        full[missing[0]], full[missing[1]] = u, w
    elif len(missing) == 1:
        u = np.cross(full[present[0]], full[present[1]])
        n = np.linalg.norm(u)
        if n > 1e-12 * scale ** 2:
            full[missing[0]] = u / n
    # keep a right-handed-or-not cell as given; only check it has a volume
    det = np.linalg.det(full)
    if not abs(det) > 1e-9 * np.prod(np.maximum(np.linalg.norm(full, axis=1), 1e-300)):
        which = [a for a in range(3) if pbc[a]]
        raise ValueError("cell: the cell vectors are linearly dependent "
                         f"(zero-volume cell; periodic axes {which})")
    if len(missing) == 1 and np.dot(np.cross(full[(missing[0] + 1) % 3],
                                             full[(missing[0] + 2) % 3]),
                                    full[missing[0]]) < 0:
        full[missing[0]] *= -1.0
    return full


def wrap_origins(frac, pbc):
    """Per periodic axis, the fractional origin of the wrap: the middle of the
    widest empty gap when more than a quarter of the period is empty (a slab
    with vacuum), else 0 (a filled box keeps its own faces)."""
    origin = np.zeros(3)
    if len(frac) < 2:
        return origin
    for a in range(3):
        if not pbc[a]:
            continue
        w = frac[:, a] - np.floor(frac[:, a])
        # a gap wider than 1/4 holds a whole eighth of the period: with no
        # empty eighth the origin is 0, found without the sort (the sorts
        # were 15 ms of a 10^5-atom grid build)
        occupied = np.bincount(np.minimum((w * 8.0).astype(np.int64), 7),
                               minlength=8)
        if occupied.all():
            continue
        f = np.sort(w)
        gaps = np.diff(np.concatenate([f, [f[0] + 1.0]]))
        k = int(np.argmax(gaps))
        if gaps[k] > 0.25:
            origin[a] = (f[k] + 0.5 * gaps[k]) % 1.0
    return origin


def grid_shape(extent, periodic, natoms):
    """Shape ``(NX, NY, NZ)`` of a grid for ``natoms`` atoms spread over
    ``extent`` (Å, occupied extent per axis).

    Along axis a a grid with spacing d has about ``e_a / d`` layers on a
    periodic axis and ``e_a / d + 1`` on an open one (the end layers sit on
    the extremes).  We solve ``prod(layers) = natoms`` for d, round, and fix
    up so that ``NX*NY*NZ >= natoms`` with as few holes as rounding allows.
    A monolayer has ``e_z = 0`` and so gets NZ = 1, a chain NY = NZ = 1
    (docs/design.md §3).
    """
    n = int(natoms)
    if n <= 1:
        return (n, n, n)
    extent = np.asarray(extent, dtype=np.float64)
    # only ratios matter: work in units of the largest extent, so that the
    # bisection is well conditioned at any length scale (1e-200 Å or 1e6 Å),
    # and call an axis flat when it is a billionth of the largest
    scale = float(extent.max()) if extent.size else 0.0
    extent = extent / scale if scale > 0 else np.zeros(3)
    extent[extent < 1e-9] = 0.0
    # an axis with no extent holds one layer whatever its pbc
    c = np.where(np.asarray(periodic) & (extent > 0), 0.0, 1.0)
    if not (extent > 0).any():
        # all atoms at one point: no geometry to follow, use a cube
        m = int(np.ceil(n ** (1 / 3) - 1e-9))
        layers = np.array([m, m, m], dtype=float)
    else:
        def count(d):
            return np.prod(extent / d + c)
        lo, hi = 1e-12, 10.0
        for _ in range(200):  # bisection in log space: count(d) is decreasing
            mid = np.sqrt(lo * hi)
            if count(mid) > n:
                lo = mid
            else:
                hi = mid
        layers = extent / hi + c
    shape = np.maximum(1, np.rint(layers)).astype(np.int64)
    layers = np.maximum(layers, 1e-300)
    while np.prod(shape) < n:
        a = int(np.argmax(layers / shape))
        shape[a] += 1
    changed = True
    while changed:
        changed = False
        for a in np.argsort(layers / shape):
            if shape[a] > 1 and np.prod(shape) // shape[a] * (shape[a] - 1) >= n:
                shape[a] -= 1
                changed = True
                break
    return tuple(int(s) for s in shape)
