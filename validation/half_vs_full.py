"""Half list with per-thread force buffers (what the calculator runs) against
a full list (every pair twice, each chunk writes only its own rows: no
buffers): which is faster?  Issue 10, item 3.  Prints a table; run it on a
quiet machine, once per thread count:

    NUMBA_NUM_THREADS=2 python validation/half_vs_full.py
"""

import inspect
import time

import numba
import numpy as np
from ase.build import bulk

import ase_mlg
import ase_mlg.potentials as P
from ase_mlg.potentials import LennardJones, lennard_jones_shifted_r2, shift_vectors


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


def full_kernel():
    """The calculator's kernel with the writes to the second atom removed
    and energies halved: the 'gather' variant of a full list."""
    src = inspect.getsource(P._pair_sum)
    for old, new in (("                F[u, 0] -= fx\n                F[u, 1] -= fy\n"
                      "                F[u, 2] -= fz\n", ""),
                     ("                erow += e\n", "                erow += 0.5 * e\n")):
        assert old in src
        src = src.replace(old, new)
    src = src.replace("def _pair_sum(", "def _full_sum(")
    g = dict(vars(P))
    exec(src, g)
    return numba.njit(parallel=True, error_model="numpy")(g["_full_sum"])


def main():
    kern_full = full_kernel()
    half = P._BUILT_IN[lennard_jones_shifted_r2][1]
    print(f"threads {numba.get_num_threads()}")
    print("| atoms | half list + buffers (ms) | full list, no buffers (ms) | full / half |")
    print("|---|---|---|---|")
    for rep in (14, 30):
        atoms = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(rep)
        atoms.rattle(0.1, seed=2)
        calc = ase_mlg.MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
        atoms.calc = calc
        atoms.get_forces()
        pl, pot = calc._list, calc.potential
        n = len(atoms)
        X = pl.positions(atoms.positions, atoms.cell.array)
        svec = shift_vectors(pl.shifts, atoms.cell.array)
        nth = numba.get_num_threads()
        times = {}
        for name, (rowptr, nbr, code), kern, nbuf in (
                ("half", (pl.rowptr, pl.nbr, pl.code), half, nth),
                ("full", full_from_half(pl), kern_full, nth)):
            m = rowptr[-1]
            rows = np.searchsorted(rowptr, np.linspace(0, m, nth + 1)).astype(np.int64)
            rows[0], rows[-1] = 0, n
            args = (True, X, calc._types, rowptr, nbr, code, svec, pot.params,
                    pot._cut2, pot._rmin2, False, False, rows, pl.order,
                    np.empty((nbuf, n, 3)), np.empty((nbuf, 0)), np.empty((nbuf, 0, 6)),
                    np.zeros((nbuf, 9)), np.empty((n, 3)), np.empty(0), np.empty((0, 6)))
            if name == "half":
                kern(args)
            else:
                kern(lennard_jones_shifted_r2, args)
            ts = []
            for _ in range(9):
                t = time.perf_counter()
                if name == "half":
                    kern(args)
                else:
                    kern(lennard_jones_shifted_r2, args)
                ts.append(time.perf_counter() - t)
            times[name] = 1e3 * np.median(ts)
            if name == "half":
                f_half = args[-3].copy()
            else:
                np.testing.assert_allclose(args[-3], f_half, atol=1e-12)
        print(f"| {n:,} | {times['half']:.2f} | {times['full']:.2f} | "
              f"{times['full'] / times['half']:.2f} |")


if __name__ == "__main__":
    main()
