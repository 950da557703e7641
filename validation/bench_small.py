"""Benchmark: neighbour lists of small systems, the calls ML potentials make.

An ML potential asks for ``neighbor_list("ijdS", atoms, 5.0)`` on cells of
1-500 atoms at every step, so the fixed cost of a call matters there more
than its cost per pair (issue 24.1).  This prints, per scene, the time of
one call of ASE, vesin, matscipy and ase-mlg (median of ``--calls`` calls
after a warm-up; µs), and checks that all four return the same set of
``(i, j, S)`` (and the same distances to 1e-12 Å).

    python validation/bench_small.py             # the table
    python validation/bench_small.py --calls 50  # quicker

ASE gets fewer calls where it is slow (at most ``--ase-budget`` seconds a
scene, at least 5 calls); the number of calls is printed beside it.  One
process runs everything, one thread each (numba and vesin), so that no
tool's threads compete with another's on a small machine; the first
ase-mlg call of the process (cache load) is excluded, as every tool's
warm-up is.
"""

import argparse
import os
import platform
import subprocess
import sys
import time

# one thread each: the comparison is of one call's fixed cost, and OpenMP /
# OpenBLAS / numba pools spinning on 2 cores would measure each other
for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_neighbor_list import boxed  # noqa: E402


def cpu_model():
    """lscpu's 'Model name' (the platform's processor string elsewhere)."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        for line in out.splitlines():
            if line.startswith("Model name"):
                return line.split(":", 1)[1].strip()
    except (OSError, subprocess.CalledProcessError):
        pass
    return platform.processor() or "unknown"


def water_box(nmol=216, seed=0):
    """``nmol`` rigid-ish water molecules in a cube at 1 g/cm^3 (18.6 Å for
    216): 648 atoms, the usual small ML-potential test box."""
    import ase
    rng = np.random.default_rng(seed)
    k = round(nmol ** (1 / 3))
    L = (nmol * 18.015 / 0.6022) ** (1 / 3)  # Å: 1 g/cm^3
    grid = (np.indices((k, k, k)).reshape(3, -1).T + 0.5) * (L / k)
    O = grid + rng.normal(scale=0.3, size=grid.shape)
    pos = []
    for o in O:
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        v = rng.normal(size=3)
        v -= v.dot(u) * u
        v /= np.linalg.norm(v)
        h1 = o + 0.9572 * u
        h2 = o + 0.9572 * (np.cos(1.824) * u + np.sin(1.824) * v)
        pos += [o, h1, h2]
    atoms = ase.Atoms("OH2" * nmol, positions=pos, cell=[L, L, L], pbc=True)
    atoms.wrap()
    return atoms


def scenes():
    """(label, atoms, cutoff in Å)."""
    from ase.build import bulk, molecule
    rng = np.random.default_rng(0)

    def cu(k):
        a = bulk("Cu", "fcc", a=3.61, cubic=True) * (k, k, k)
        a.rattle(0.05, rng=rng)
        return a
    return [("Cu fcc, 1-atom primitive cell", bulk("Cu", "fcc", a=3.61), 5.0),
            ("Si diamond, 8 atoms", bulk("Si", "diamond", a=5.43, cubic=True), 5.0),
            ("C60, no pbc", molecule("C60"), 5.0),
            ("Cu, 108 atoms", cu(3), 5.0),
            ("Cu, 256 atoms", cu(4), 5.0),
            ("Cu, 500 atoms", cu(5), 5.0),
            ("Cu, 2,048 atoms", cu(8), 5.0),
            ("water, 648 atoms, rc 6 Å", water_box(), 6.0)]


def tools():
    """name -> f(atoms, cutoff) returning (i, j, d, S)."""
    import ase.neighborlist as ase_nl
    import matscipy.neighbours as msn
    import vesin

    import ase_mlg
    return {"ASE": lambda a, rc: ase_nl.neighbor_list("ijdS", a, rc),
            "vesin": lambda a, rc: vesin.ase_neighbor_list("ijdS", a, rc),
            # matscipy inverts the cell: a box on open axes without one
            "matscipy": lambda a, rc: msn.neighbour_list("ijdS", a, rc),
            "ase-mlg": lambda a, rc: ase_mlg.neighbor_list("ijdS", a, rc)}


def same_pairs(ref, other):
    """Whether two ``(i, j, d, S)`` lists hold the same pairs, distances to
    1e-12 Å."""
    def canon(r):
        i, j, d, S = (np.asarray(x) for x in r)
        o = np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i))
        return i[o], j[o], d[o], S[o]
    a, b = canon(ref), canon(other)
    if len(a[0]) != len(b[0]):
        return False
    return (all(np.array_equal(a[k], b[k]) for k in (0, 1, 3))
            and (len(a[2]) == 0 or np.abs(a[2] - b[2]).max() < 1e-12))


def timed(f, calls, budget=None):
    """Median of ``calls`` calls of ``f`` (s), after warm-up calls; with a
    ``budget`` (s), fewer calls (at least 5) where one call is slow."""
    t0 = time.perf_counter()
    f()
    once = time.perf_counter() - t0
    if budget is not None:
        calls = int(max(5, min(calls, budget / max(once, 1e-9))))
    for _ in range(min(5, calls)):
        f()
    ts = np.empty(calls)
    for k in range(calls):
        t0 = time.perf_counter()
        f()
        ts[k] = time.perf_counter() - t0
    return float(np.median(ts)), calls


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--calls", type=int, default=200, help="calls a figure (200)")
    p.add_argument("--ase-budget", type=float, default=3.0,
                   help="seconds of ASE calls a scene at most (3)")
    args = p.parse_args(argv)
    import numba
    import vesin  # noqa: F401  (imported before the header: versions)

    import ase_mlg
    numba.set_num_threads(1)
    print(f"# small-system neighbour lists: neighbor_list('ijdS', atoms, rc), "
          f"median of {args.calls} calls, µs")
    print(f"# CPU: {cpu_model()}, {os.cpu_count()} cores; numba "
          f"{numba.__version__}, 1 thread; ase-mlg {ase_mlg.__version__}; "
          f"python {platform.python_version()}")
    fns = tools()
    print("| scene | atoms | pairs | ASE | vesin | matscipy | ase-mlg | "
          "ase-mlg / vesin | same pairs |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, atoms, rc in scenes():
        ref = fns["ASE"](atoms, rc)
        times, same = {}, True
        for name, f in fns.items():
            a = boxed(atoms) if name == "matscipy" else atoms
            same &= same_pairs(ref, f(a, rc))
            t, calls = timed(lambda: f(a, rc), args.calls,
                             args.ase_budget if name == "ASE" else None)
            times[name] = (t, calls)
        cells = []
        for name in fns:
            t, calls = times[name]
            s = f"{t * 1e6:,.0f}"
            if calls != args.calls:
                s += f" ({calls} calls)"
            cells.append(s)
        ratio = times["ase-mlg"][0] / times["vesin"][0]
        print(f"| {label} | {len(atoms)} | {len(ref[0]):,} | " + " | ".join(cells)
              + f" | {ratio:.2f} | {'yes' if same else 'NO'} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
