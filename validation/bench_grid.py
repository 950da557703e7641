"""Build and update time per atom of the MLG, N = 10^3 ... 10^6.

Random liquid at 0.8 sigma^-3 (sigma = 1), periodic cube.  Build: kd and
sort constructions.  Update: one step of velocity-persistent random-walk
motion of 0.02 spacings rms (a typical MD step), i.e. minimum-image follow +
swap sweeps; the walk itself is not timed.  Medians of repeats; JIT warm-up
(loading the cached kernels) is done first and reported.  Update time per
atom must stay flat in N (linear scaling).  Usage::

    python validation/bench_grid.py [--max 1000000] [--repeats 5]
"""

import argparse
import time

import numba
import numpy as np

from ase_mlg import MLG
from ase_mlg.scenes import PersistentWalk, random_points


def median_time(fn, repeats):
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--max", type=int, default=1_000_000)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)
    t = time.perf_counter()
    small = random_points(1000, 0.8)
    g = MLG.from_atoms(small)
    MLG.from_atoms(small, method="sort")
    g.update(small.positions + 0.01)
    big = random_points(40000, 0.8)  # the threaded sweep kernels
    MLG.from_atoms(big).update(big.positions + 0.01)
    print(f"warm-up (load/compile kernels): {time.perf_counter() - t:.2f} s; "
          f"threads: {numba.get_num_threads()}")
    print(f"{'N':>9} {'build kd':>10} {'build sort':>10} {'update':>10} "
          f"{'sweeps':>6}   per atom: {'kd':>7} {'sort':>7} {'update':>7} (µs)")
    n = 1000
    while n <= args.max:
        atoms = random_points(n, 0.8, seed=1)
        kd = median_time(lambda: MLG.from_atoms(atoms), args.repeats)
        srt = median_time(lambda: MLG.from_atoms(atoms, method="sort"), args.repeats)
        grid = MLG.from_atoms(atoms)
        walk = PersistentWalk(atoms.positions, 0.02 * 0.8 ** (-1 / 3), seed=1)
        for _ in range(20):  # reach the steady state of sweeps
            grid.update(walk.step())
        ups, sw = [], []
        for _ in range(max(args.repeats, 10)):
            x = walk.step().copy()
            t = time.perf_counter()
            rec = grid.update(x)
            ups.append(time.perf_counter() - t)
            sw.append(rec["sweeps"])
        up = float(np.median(ups))
        print(f"{n:9d} {kd * 1e3:8.2f}ms {srt * 1e3:8.2f}ms {up * 1e3:8.3f}ms "
              f"{np.mean(sw):6.2f}   {'':>10}{kd / n * 1e6:7.3f} {srt / n * 1e6:7.3f} "
              f"{up / n * 1e6:7.3f}")
        n *= 10


if __name__ == "__main__":
    main()
