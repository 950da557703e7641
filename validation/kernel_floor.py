"""How far the pair kernel is from a loop that does only LJ argon's work (issue 24.3).

The calculator's kernel (:mod:`ase_mlg.pairsum`) is general: any pair
function, species tables, per-atom energies and virials, the rmin check,
chunk windows for threads.  This script times it against two minimal loops
on the *same* list (the calculator's own, in grid order), one species, LJ in
ASE's expression (two divisions a pair), forces and energy only:

* ``one pass``: gather ``D``, test the cutoff, evaluate, accumulate and
  scatter in one loop over a row (the kernel's structure);
* ``three passes``: per row, gather the pairs within the cutoff into
  scratch (branch-free compaction), evaluate the pair function over them in
  a loop of its own (which LLVM vectorises), then accumulate and scatter.

All three give the same forces bit for bit where the kernel runs one chunk
(below 50,000 pairs); with several chunks its windows are summed in
another order (the last column: the largest difference over the largest
force).  The minimal loops
are not package code and not a path users get: they measure the floor a
specialised kernel could reach on this CPU.  Each variant runs in its own
process (``--procs`` of them; a variant compiled after another in one
process ran up to 1.4x slower on AMD Zen 4: JIT code placement), one numba
thread; the figure is the median over processes of each process's fastest
call, ns per listed pair.

    python validation/kernel_floor.py                 # 256, 500 and 4,000 atoms
    python validation/kernel_floor.py --sizes 256,500,10976 --procs 5
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from bench_common import cpu_model

VARIANTS = ("kernel", "one pass", "three passes")
SIGMA, EPS, RC = 3.405, 0.0104, 8.5


def _minimal_loops():
    import numba
    from numba import uint64 as U
    from ase_mlg.pairfunctions import lennard_jones_shifted_r2 as lj

    @numba.njit(error_model="numpy")
    def one_pass(X, sv, rowptr, nbr, code, p, cut2, fb):
        fb[:] = 0.0
        energy = 0.0
        for t in range(rowptr.shape[0] - 1):
            x0, x1, x2 = X[3 * t], X[3 * t + 1], X[3 * t + 2]
            f0 = f1 = f2 = 0.0
            for q in range(U(rowptr[t]), U(rowptr[t + 1])):
                u = U(3) * U(nbr[q])
                k = U(3) * U(code[q])
                dx = (X[u] - x0) + sv[k]
                dy = (X[u + U(1)] - x1) + sv[k + U(1)]
                dz = (X[u + U(2)] - x2) + sv[k + U(2)]
                r2 = dx * dx + dy * dy + dz * dz
                if r2 > cut2:
                    continue
                e, s = lj(r2, p)
                energy += e
                f0 += s * dx
                f1 += s * dy
                f2 += s * dz
                fb[u] -= s * dx
                fb[u + U(1)] -= s * dy
                fb[u + U(2)] -= s * dz
            fb[3 * t] += f0
            fb[3 * t + 1] += f1
            fb[3 * t + 2] += f2
        return energy

    @numba.njit(error_model="numpy")
    def three_passes(X, sv, rowptr, nbr, code, p, cut2, fb):
        fb[:] = 0.0
        energy = 0.0
        width = 1
        for t in range(rowptr.shape[0] - 1):
            width = max(width, rowptr[t + 1] - rowptr[t])
        bx, by, bz = np.empty(width), np.empty(width), np.empty(width)
        br, be, bs = np.empty(width), np.empty(width), np.empty(width)
        bu = np.empty(width, np.int64)
        for t in range(rowptr.shape[0] - 1):
            x0, x1, x2 = X[3 * t], X[3 * t + 1], X[3 * t + 2]
            m = 0
            for q in range(U(rowptr[t]), U(rowptr[t + 1])):
                u = U(3) * U(nbr[q])
                k = U(3) * U(code[q])
                dx = (X[u] - x0) + sv[k]
                dy = (X[u + U(1)] - x1) + sv[k + U(1)]
                dz = (X[u + U(2)] - x2) + sv[k + U(2)]
                r2 = dx * dx + dy * dy + dz * dz
                bx[m], by[m], bz[m], br[m], bu[m] = dx, dy, dz, r2, u
                m += 0 if r2 > cut2 else 1
            for h in range(m):
                be[h], bs[h] = lj(br[h], p)
            f0 = f1 = f2 = 0.0
            for h in range(m):
                s = bs[h]
                energy += be[h]
                f0 += s * bx[h]
                f1 += s * by[h]
                f2 += s * bz[h]
                u = U(bu[h])
                fb[u] -= s * bx[h]
                fb[u + U(1)] -= s * by[h]
                fb[u + U(2)] -= s * bz[h]
            fb[3 * t] += f0
            fb[3 * t + 1] += f1
            fb[3 * t + 2] += f2
        return energy

    return {"one pass": one_pass, "three passes": three_passes}


def worker(n, variant, calls):
    """The fastest of ``calls`` calls of one variant, ns per listed pair, and
    its forces' largest difference from the kernel's."""
    from ase_mlg import MLGCalculator
    from ase_mlg.pairsum import SumList, SumOutputs, SumTables, pair_kernel
    from ase_mlg.potentials import LennardJones
    from ase_mlg.scenes import lj_liquid

    atoms = lj_liquid(n, rho=0.8, seed=1)
    calc = atoms.calc = MLGCalculator(LennardJones(sigma=SIGMA, epsilon=EPS, rc=RC))
    atoms.get_forces()
    vl, pot = calc.verlet_list, calc.potential
    pl, chunks = vl.pairs, vl.chunks()
    lst = SumList(vl.X, vl.types, pl.rowptr, pl.nbr, vl.svec, pl.order)
    tab = SumTables(pot.squared, pot.params, pot._cut2, pot._rmin2, pot._check_rmin, False)
    fbuf, ebuf, vbuf = chunks.buffers(False, False)
    out = SumOutputs(fbuf, ebuf, vbuf, np.zeros((chunks.nchunk, 9)), np.empty((n, 3)),
                     np.empty(0), np.empty((0, 6)))
    kernel = pair_kernel(pot.pair, threaded=False, general=False)  # an MD step's
    kernel(lst, pl.code, tab, chunks.arrays, out)
    reference = out.forces[pl.order]  # row order
    if variant == "kernel":
        def call():
            kernel(lst, pl.code, tab, chunks.arrays, out)
        forces = out.forces[pl.order]
    else:
        loop = _minimal_loops()[variant]
        X, sv = vl.X.ravel(), np.ascontiguousarray(vl.svec).ravel()
        fb = np.zeros(3 * n)
        args = (X, sv, pl.rowptr, pl.nbr, pl.code, pot.params[0, 0], float(pot._cut2[0, 0]), fb)

        def call():
            loop(*args)
        call()
        forces = fb.reshape(n, 3)
    best = np.inf
    for _ in range(calls):
        t0 = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - t0)
    return {"ns_per_pair": best * 1e9 / len(pl.nbr), "pairs": int(len(pl.nbr)),
            "chunks": int(chunks.nchunk),
            "diff": float(np.abs(forces - reference).max() / np.abs(reference).max())}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="256,500,4000")
    ap.add_argument("--procs", type=int, default=3)
    ap.add_argument("--calls", type=int, default=1500)
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(int(args.worker[0]), args.worker[1], args.calls)))
        return
    import ase_mlg
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "OPENBLAS_NUM_THREADS": "1"}
    print(f"# {cpu_model()}; ase_mlg from {os.path.dirname(ase_mlg.__file__)}; one thread, "
          f"{args.procs} processes a figure (interleaved), fastest of {args.calls} calls each\n")
    print("| atoms | pairs (kernel chunks) | " + " | ".join(f"{v} (ns/pair)" for v in VARIANTS)
          + " | kernel / three passes | forces: max diff / max |F| |")
    print("|---|---|" + "---|" * len(VARIANTS) + "---|---|")
    for n in (int(s) for s in args.sizes.split(",")):
        runs = {v: [] for v in VARIANTS}
        for _ in range(args.procs):
            for v in VARIANTS:
                res = subprocess.run([sys.executable, __file__, "--calls", str(args.calls),
                                      "--worker", str(n), v], env=env, capture_output=True,
                                     text=True, check=True)
                runs[v].append(json.loads(res.stdout.strip().splitlines()[-1]))
        med = {v: float(np.median([r["ns_per_pair"] for r in runs[v]])) for v in VARIANTS}
        cells = " | ".join("%.2f (%.2f-%.2f)" % (med[v], min(r["ns_per_pair"] for r in runs[v]),
                                                 max(r["ns_per_pair"] for r in runs[v]))
                           for v in VARIANTS)
        diff = max(r["diff"] for v in VARIANTS for r in runs[v])
        print(f"| {n:,} | {runs['kernel'][0]['pairs']:,} ({runs['kernel'][0]['chunks']}) | {cells} | "
              f"{med['kernel'] / med['three passes']:.2f} | {diff:.1e} |")


if __name__ == "__main__":
    main()
