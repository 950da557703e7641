"""Build and update time per atom of the MLG, N = 10^3 ... 10^6.

Random liquid at 0.8 sigma^-3 (sigma = 1), periodic cube.  Build: kd and
sort constructions.  Update: one step of velocity-persistent random-walk
motion of 0.02 spacings rms (a typical MD step), i.e. minimum-image follow +
swap sweeps; the walk itself is not timed.  Medians of repeats; JIT warm-up
(loading the cached kernels) is done first and reported.  Update time per
atom must stay flat in N (linear scaling).

``--threads 1,2`` prints instead a table of ``MLG.update`` per atom at
10^4, 10^5, 10^6 (up to ``--max``), each thread count in its own process
(``NUMBA_NUM_THREADS`` is fixed when numba starts its threads), and the
speed-up over the first thread count.  ``--cell`` adds a small random cell
strain to every step (NPT-like: ``update(positions, cell)``, the positions
scaled with the cell).  Usage::

    python validation/bench_grid.py [--max 1000000] [--repeats 5]
    python validation/bench_grid.py --threads 1,2 [--min 10000] [--cell]
"""

import argparse
import json
import os
import subprocess
import sys
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


def warm_up():
    t = time.perf_counter()
    small = random_points(1000, 0.8)
    g = MLG.from_atoms(small)
    MLG.from_atoms(small, method="sort")
    g.update(small.positions + 0.01)
    big = random_points(40000, 0.8)  # the threaded sweep kernels
    g = MLG.from_atoms(big)
    g.update(big.positions + 0.01)
    return time.perf_counter() - t


def update_times(n, repeats, cell_strain):
    """Median seconds of ``MLG.update`` (and mean sweeps) at ``n`` atoms."""
    atoms = random_points(n, 0.8, seed=1)
    grid = MLG.from_atoms(atoms)
    walk = PersistentWalk(atoms.positions, 0.02 * 0.8 ** (-1 / 3), seed=1)
    cell = atoms.cell.array.copy()
    rng = np.random.default_rng(1)

    def step():
        nonlocal cell
        x = walk.step().copy()
        if not cell_strain:
            return x, None
        # a small random strain of the cell, positions scaled with it
        new = cell @ (np.eye(3) + rng.normal(scale=1e-4, size=(3, 3)))
        x = x @ np.linalg.solve(cell, new)
        cell = new
        return x, new

    for _ in range(20):  # reach the steady state of sweeps
        x, c = step()
        grid.update(x) if c is None else grid.update(x, c)
    ups, sw = [], []
    for _ in range(max(repeats, 10)):
        x, c = step()
        t = time.perf_counter()
        rec = grid.update(x) if c is None else grid.update(x, c)
        ups.append(time.perf_counter() - t)
        sw.append(rec["sweeps"])
    assert grid.stats["rebuilds"] == 0
    return float(np.median(ups)), float(np.mean(sw))


def thread_table(args):
    counts = [int(t) for t in args.threads.split(",")]
    sizes = []
    n = args.min
    while n <= args.max:
        sizes.append(n)
        n *= 10
    rows = {}
    for t in counts:
        env = dict(os.environ, NUMBA_NUM_THREADS=str(t))
        cmd = [sys.executable, __file__, "--worker", ",".join(map(str, sizes)),
               "--repeats", str(args.repeats)] + (["--cell"] if args.cell else [])
        res = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
        rows[t] = json.loads(res.stdout.strip().splitlines()[-1])
    print(f"MLG.update per atom (µs), median of {max(args.repeats, 10)} steps"
          f"{' with cell strain' if args.cell else ''}; each thread count in its own process")
    print(f"{'N':>9} " + " ".join(f"{f'{t} thr':>9}" for t in counts)
          + " " + " ".join(f"{f'x{t}/{counts[0]}':>7}" for t in counts[1:]) + f" {'sweeps':>6}")
    for i, n in enumerate(sizes):
        ts = [rows[t]["times"][i] for t in counts]
        print(f"{n:9d} " + " ".join(f"{x / n * 1e6:9.4f}" for x in ts) + " "
              + " ".join(f"{ts[0] / x:7.2f}" for x in ts[1:])
              + f" {rows[counts[0]]['sweeps'][i]:6.2f}")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--max", type=int, default=1_000_000)
    p.add_argument("--min", type=int, default=10_000)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", default=None,
                   help="comma-separated thread counts: update table, one process each")
    p.add_argument("--cell", action="store_true", help="strain the cell every step")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.threads:
        return thread_table(args)
    if args.worker:
        warm_up()
        out = {"times": [], "sweeps": []}
        for n in map(int, args.worker.split(",")):
            t, s = update_times(n, args.repeats, args.cell)
            out["times"].append(t)
            out["sweeps"].append(s)
        print(json.dumps(out))
        return
    print(f"warm-up (load/compile kernels): {warm_up():.2f} s; "
          f"threads: {numba.get_num_threads()}")
    print(f"{'N':>9} {'build kd':>10} {'build sort':>10} {'update':>10} "
          f"{'sweeps':>6}   per atom: {'kd':>7} {'sort':>7} {'update':>7} (µs)")
    n = 1000
    while n <= args.max:
        atoms = random_points(n, 0.8, seed=1)
        kd = median_time(lambda: MLG.from_atoms(atoms), args.repeats)
        srt = median_time(lambda: MLG.from_atoms(atoms, method="sort"), args.repeats)
        up, sw = update_times(n, args.repeats, args.cell)
        print(f"{n:9d} {kd * 1e3:8.2f}ms {srt * 1e3:8.2f}ms {up * 1e3:8.3f}ms "
              f"{sw:6.2f}   {'':>10}{kd / n * 1e6:7.3f} {srt / n * 1e6:7.3f} "
              f"{up / n * 1e6:7.3f}")
        n *= 10


if __name__ == "__main__":
    main()
