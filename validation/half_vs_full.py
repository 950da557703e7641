"""Half list with per-thread force buffers (what the calculator runs) against
a full list (every pair twice, each chunk writes only its own rows: no
buffers): which is faster?  Issue 10, item 3.  Prints a table; run it on a
quiet machine, once per thread count:

    NUMBA_NUM_THREADS=2 python validation/half_vs_full.py

Both sides read the same list, built as the calculator builds it (exact
query at cutoff + 1 Å skin, each row's pairs within the cutoff first); the half side is
:meth:`PairPotential.sum_pairs`, the full side the gather loop below.
"""

import time

import numba
import numpy as np
from ase.build import bulk
from numba import prange

from ase_mlg import MLG
from ase_mlg.blocks import BlockIndex
from ase_mlg.chunks import row_chunks
from ase_mlg.potentials import LennardJones
from ase_mlg.query import half_list

SKIN = 1.0  # Å, the calculator's default


def full_from_half(pl):
    """The full list (both orientations) of a half PairList, same layout."""
    n = pl.natoms
    rows = np.repeat(np.arange(n), np.diff(pl.rowptr))
    mirror = pl.shifts[pl.code]
    neg = {tuple(s): k for k, s in enumerate(pl.shifts)}
    mcode = np.array([neg[tuple(-s)] for s in mirror], dtype=pl.code.dtype)
    keep = ~((pl.nbr == rows) & (pl.code == pl.zero_code))
    i = np.concatenate([rows, pl.nbr[keep]])
    j = np.concatenate([pl.nbr, rows[keep]]).astype(np.int32)
    c = np.concatenate([pl.code, mcode[keep]])
    o = np.argsort(i, kind="stable")
    rowptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(i, minlength=n), out=rowptr[1:])
    return rowptr, j[o], c[o]


@numba.njit(parallel=True, error_model="numpy")
def full_sum(pair, X, types, rowptr, nbr, code, svec, params, cut2, rows,
             order, forces, part):
    """Energy (eV, per chunk into ``part``) and forces (eV/Å, atom order)
    of a full list: each row gathers its own force, half of each pair
    energy; no write to another row, hence no buffers.  ``pair`` is a
    squared-form pair function, ``r**2 -> (e, dE/dr / r)``."""
    for c in prange(rows.shape[0] - 1):
        energy = 0.0
        for t in range(rows[c], rows[c + 1]):
            ta = types[t]
            f0 = f1 = f2 = 0.0
            for q in range(rowptr[t], rowptr[t + 1]):
                u = nbr[q]
                k = code[q]
                dx = (X[u, 0] - X[t, 0]) + svec[k, 0]
                dy = (X[u, 1] - X[t, 1]) + svec[k, 1]
                dz = (X[u, 2] - X[t, 2]) + svec[k, 2]
                r2 = dx * dx + dy * dy + dz * dz
                tb = types[u]
                if r2 > cut2[ta, tb]:
                    continue
                e, s = pair(r2, params[ta, tb])
                energy += 0.5 * e
                f0 += s * dx
                f1 += s * dy
                f2 += s * dz
            a = order[t]
            forces[a, 0] = f0
            forces[a, 1] = f1
            forces[a, 2] = f2
        part[c] = energy


def calculator_list(atoms, pot):
    """(PairList, positions in row order, shift vectors, row types) as
    :class:`ase_mlg.MLGCalculator` builds them."""
    n = len(atoms)
    rlist = pot.cutoff + SKIN
    pl = half_list(BlockIndex(MLG.from_atoms(atoms)), np.full(n, rlist), cut=rlist)
    cell = atoms.cell.array
    X = pl.positions(atoms.positions, cell)
    svec = np.ascontiguousarray(pl.shifts @ cell, dtype=np.float64)
    pl.inner_first(X, svec, pot.cutoff)
    types = np.ascontiguousarray(pot.prepare(atoms.numbers)[0][pl.order])
    return pl, X, svec, types


def median_ms(call, repeats=9):
    call()  # compile or load from cache
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        call()
        ts.append(time.perf_counter() - t)
    return 1e3 * np.median(ts)


def main():
    nth = numba.get_num_threads()
    pot = LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)
    assert pot.squared  # full_sum calls the squared form
    cut2 = pot.cutoffs ** 2
    print(f"threads {nth}")
    print("| atoms | half list + buffers (ms) | full list, no buffers (ms) | full / half |")
    print("|---|---|---|---|")
    for rep in (14, 30):
        atoms = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(rep)
        atoms.rattle(0.1, seed=2)
        n = len(atoms)
        pl, X, svec, types = calculator_list(atoms, pot)
        half = {}
        chunks = row_chunks(pl.rowptr, pl.nbr, nth)

        def run_half():
            half.update(pot.sum_pairs(X, types, pl.rowptr, pl.nbr, pl.code, svec,
                                      pl.order, virial=False, chunks=chunks))

        rowptr, nbr, code = full_from_half(pl)
        rows = np.searchsorted(rowptr, np.linspace(0, rowptr[-1], nth + 1)).astype(np.int64)
        rows[0], rows[-1] = 0, n
        forces, part = np.empty((n, 3)), np.empty(nth)

        def run_full():
            full_sum(pot.pair, X, types, rowptr, nbr, code, svec, pot.params,
                     cut2, rows, pl.order, forces, part)

        t_half, t_full = median_ms(run_half), median_ms(run_full)
        np.testing.assert_allclose(forces, half["forces"], atol=1e-12)
        np.testing.assert_allclose(part.sum(), half["energy"], rtol=1e-12)
        print(f"| {n:,} | {t_half:.2f} | {t_full:.2f} | {t_full / t_half:.2f} |")


if __name__ == "__main__":
    main()
