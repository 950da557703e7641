"""Brute-force references the tests judge ase_mlg against.

Plain numpy and plain Python, written to be obviously correct rather than
fast: every pair of atoms is looked at, over every periodic image that can
matter; pair energies are the textbook formulas evaluated one distance at a
time.  Lengths are in Å, energies in eV.  The tests import from here
(``from naive import ...``: pytest puts ``tests/`` on ``sys.path``).

Pairs
    :func:`image_shifts`, :func:`pairs`.
Pair energies (one distance ``r`` in Å -> eV)
    :func:`lj`, :func:`lj_smooth`, :func:`morse`, mixed by
    :func:`lorentz_berthelot`.
Totals
    :func:`energy`: the sum of a pair energy over all pairs of a structure.
Grid maintenance
    :func:`sweeps`: Boris's odd-even swap sweeps, phase by phase.
"""

import math

import numpy as np
from ase.cell import Cell

__all__ = ["image_shifts", "pairs", "lj", "lj_smooth", "morse",
           "lorentz_berthelot", "energy", "sweeps"]


# --------------------------------------------------------------------------
# pairs
# --------------------------------------------------------------------------

def image_shifts(positions, cell, pbc, cutoff):
    """Every lattice shift S (integer, one row each) for which some atom pair
    can be closer than ``cutoff`` (Å): along a periodic axis, as many cells
    as the cutoff spans plus the atoms' own spread in that axis, plus one;
    along an open axis, none.  ``cell`` may have zero rows on open axes."""
    frac = np.asarray(positions, float) @ np.linalg.inv(Cell(cell).complete())
    heights = 1.0 / np.linalg.norm(np.linalg.inv(Cell(cell).complete()), axis=0)
    ranges = []
    for a in range(3):
        if pbc[a] and len(frac):
            spread = frac[:, a].max() - frac[:, a].min()
            k = int(np.ceil(cutoff / heights[a] + spread)) + 1
            ranges.append(np.arange(-k, k + 1))
        else:
            ranges.append(np.array([0]))
    return np.stack(np.meshgrid(*ranges, indexing="ij"), -1).reshape(-1, 3)


def pairs(positions, cell, pbc, cutoff, self_interaction=False, slack=0.0):
    """All ordered pairs (i, j, S) with ``d < cutoff + slack``.

    Parameters
    ----------
    positions : (N, 3) array of float
        Cartesian positions (Å); atoms may lie outside the cell.
    cell : (3, 3) array of float
        Cell vectors as rows (Å).
    pbc : sequence of 3 bool
        Periodic axes.
    cutoff : float or (N, N) array of float
        The cutoff (Å), one for all pairs or one per pair (i, j).
    self_interaction : bool
        Keep (i, i, (0, 0, 0)), the atom and itself at distance 0.
    slack : float
        Also keep pairs up to ``slack`` Å beyond their cutoff (a caller that
        sets borderline pairs aside asks for them here).

    Returns
    -------
    dict
        ``{(i, j, S): (d, D)}`` with ``S`` a tuple of 3 ints, ``D = x[j] -
        x[i] + S @ cell`` (Å) and ``d = |D|`` (Å); both directions of each
        pair, each periodic image of it separately.
    """
    pos = np.asarray(positions, float)
    n = len(pos)
    cut = np.broadcast_to(np.asarray(cutoff, float), (n, n))
    cell = np.asarray(cell, float)
    shifts = image_shifts(pos, cell, pbc, cut.max(initial=0.0))
    sc = shifts @ cell
    out = {}
    for i in range(n):
        D = pos[None, :, :] - pos[i] + sc[:, None, :]  # (shift, j, xyz)
        d = np.sqrt((D * D).sum(2))
        for s, j in zip(*np.nonzero(d < cut[i][None, :] + slack)):
            S = tuple(int(x) for x in shifts[s])
            if i == j and S == (0, 0, 0) and not self_interaction:
                continue
            out[(i, int(j), S)] = (d[s, j], D[s, j])
    return out


# --------------------------------------------------------------------------
# pair energies: one distance r (Å) -> energy (eV)
# --------------------------------------------------------------------------

def lj(r, sigma, epsilon, rc):
    """Lennard-Jones 4 epsilon ((sigma/r)^12 - (sigma/r)^6), shifted to zero
    at ``rc`` and zero from there on (``sigma``, ``rc`` in Å, ``epsilon`` in
    eV)."""
    if r >= rc:
        return 0.0
    u = lambda x: 4 * epsilon * ((sigma / x) ** 12 - (sigma / x) ** 6)
    return u(r) - u(rc)


def lj_smooth(r, sigma, epsilon, rc, ro):
    """Lennard-Jones, unshifted, times ASE's smooth cutoff: 1 below ``ro``,
    falling to 0 at ``rc`` as (rc^2 - r^2)^2 (rc^2 + 2 r^2 - 3 ro^2) /
    (rc^2 - ro^2)^3 (lengths in Å, ``epsilon`` in eV)."""
    if r >= rc:
        return 0.0
    u = 4 * epsilon * ((sigma / r) ** 12 - (sigma / r) ** 6)
    if r < ro:
        return u
    fc = ((rc**2 - r**2) ** 2 * (rc**2 + 2 * r**2 - 3 * ro**2)
          / (rc**2 - ro**2) ** 3)
    return u * fc


def morse(r, epsilon, r0, rho0, rcut1, rcut2):
    """ASE's Morse: epsilon (e^(-2 rho0 (r/r0 - 1)) - 2 e^(-rho0 (r/r0 - 1)))
    (eV), switched off between ``rcut1 * r0`` and ``rcut2 * r0`` by the
    quintic 6 s^5 - 15 s^4 + 10 s^3 (``r0`` in Å; ``rho0``, ``rcut1``,
    ``rcut2`` dimensionless)."""
    r1, r2 = rcut1 * r0, rcut2 * r0
    if r >= r2:
        return 0.0
    e = epsilon * (math.exp(-2 * rho0 * (r / r0 - 1))
                   - 2 * math.exp(-rho0 * (r / r0 - 1)))
    if r <= r1:
        return e
    s = 1 - (r - r1) / (r2 - r1)
    return e * (6 * s**5 - 15 * s**4 + 10 * s**3)


def lorentz_berthelot(sigma_a, sigma_b, epsilon_a, epsilon_b):
    """Mixed LJ parameters of two species: (arithmetic mean of the sigmas
    (Å), geometric mean of the epsilons (eV))."""
    return (sigma_a + sigma_b) / 2, math.sqrt(epsilon_a * epsilon_b)


# --------------------------------------------------------------------------
# totals
# --------------------------------------------------------------------------

def energy(atoms, pair_energy, cutoff=math.inf):
    """Total energy (eV): half the sum over all ordered pairs (i, j, S) of
    :func:`pairs` closer than ``cutoff`` (Å) of ``pair_energy(r, symbol_i,
    symbol_j)``.  ``cutoff`` only bounds the images looked at (it must be
    finite along periodic axes); ``pair_energy`` applies its own cutoffs."""
    syms = atoms.get_chemical_symbols()
    found = pairs(atoms.positions, atoms.cell[:], atoms.pbc, cutoff)
    return sum(0.5 * pair_energy(d, syms[i], syms[j])
               for (i, j, _), (d, _) in found.items())


# --------------------------------------------------------------------------
# grid maintenance
# --------------------------------------------------------------------------

def sweeps(sites, coords, shape, periods, cap):
    """Boris's odd-even sweeps phase by phase in numpy (the definition the
    line-wise kernels with skipped in-order lines must reproduce).

    Parameters
    ----------
    sites : (prod(shape),) array of int
        Atom index at each grid site (-1: hole), C order.
    coords : (prod(shape), 3) array of float
        The coordinate each site is sorted by (grid units), C order.
    shape : (3,) array of int
        Grid shape.
    periods : (3,) array of float
        Period of each axis in coordinate units (0: open axis).
    cap : int
        Stop after this many sweeps.

    Returns
    -------
    (sites, coords, nsweep, nswap)
        The swept arrays, the sweeps that swapped and the swaps made.
    """
    S = sites.reshape(shape).copy()
    C = coords.reshape(tuple(shape) + (3,)).copy()
    nsweep = nswap = 0
    while True:
        swaps = 0
        for axis in range(3):
            n = shape[axis]
            if n < 2:
                continue
            Sa, Ca = np.moveaxis(S, axis, 0), np.moveaxis(C, axis, 0)  # views
            for parity in (0, 1):
                lo = np.arange(parity, n - 1, 2)
                bad = Ca[lo, ..., axis] > Ca[lo + 1, ..., axis]
                idx = np.nonzero(bad)
                i0, rest = lo[idx[0]], idx[1:]
                s0, s1 = Sa[(i0,) + rest].copy(), Sa[(i0 + 1,) + rest].copy()
                c0, c1 = Ca[(i0,) + rest].copy(), Ca[(i0 + 1,) + rest].copy()
                Sa[(i0,) + rest], Sa[(i0 + 1,) + rest] = s1, s0
                Ca[(i0,) + rest], Ca[(i0 + 1,) + rest] = c1, c0
                swaps += len(i0)
            if periods[axis] > 0:
                bad = Ca[-1, ..., axis] > Ca[0, ..., axis] + periods[axis]
                f, l = Ca[0][bad].copy(), Ca[-1][bad].copy()
                f[:, axis] += periods[axis]
                l[:, axis] -= periods[axis]
                Ca[0][bad], Ca[-1][bad] = l, f
                s0 = Sa[0][bad].copy()
                Sa[0][bad], Sa[-1][bad] = Sa[-1][bad], s0
                swaps += int(bad.sum())
        if swaps == 0:
            return S.ravel(), C.reshape(-1, 3), nsweep, nswap
        nsweep += 1
        nswap += swaps
        if nsweep >= cap:
            return S.ravel(), C.reshape(-1, 3), nsweep, nswap


def atom_pairs(pl):
    """A half list's pairs as sorted rows (i, j, S) of atoms, each unordered
    pair {(i, j, S), (j, i, -S)} written with i < j, or S > 0 for i == j:
    the same for any rank order or orientation."""
    t = np.repeat(np.arange(pl.natoms), np.diff(pl.rowptr))
    u = pl.nbr.astype(np.int64)
    i, j = pl.order[t], pl.order[u]
    S = pl.shifts[pl.code] + pl.images[u] - pl.images[t]
    flip = (i > j) | ((i == j) & (np.sign(S) @ [4, 2, 1] < 0))
    i, j = np.where(flip, j, i), np.where(flip, i, j)
    S = np.where(flip[:, None], -S, S)
    rows = np.column_stack([i, j, S])
    return rows[np.lexsort(rows.T[::-1])]
