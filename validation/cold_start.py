"""The first call from an empty numba cache, as a fresh environment pays it (issue 24.2).

Each figure comes from ``--procs`` fresh processes, each with an empty
``NUMBA_CACHE_DIR`` of its own (nothing compiled before it), then one more
process on the cache it filled (warm: numba loads the kernels from disk):

* ``import ase_mlg``;
* the first ``neighbor_list("ijdS", atoms, 5.0)`` on fcc Cu, 108 atoms (the
  small-system path, ``ase_mlg/allpairs.py``), and the second call;
* the first force call of ``MLGCalculator``, the construction of the
  calculator and its potential included, on LJ argon (256 atoms of fcc
  argon at 5.26 Å, 0.05 Å noise, rc 8.5 Å), and a force call after a
  0.5 Å move (a list rebuild: the grid's update and sweeps);
* the first force call on 10,976 atoms (fcc argon at 5.72 Å), where every
  call takes the grid's exact block query;
* ``ase-mlg demo`` cold (empty cache) and warm (the cache it filled), wall
  time of the command.

Run it from the environment whose install you want to measure (a fresh venv
made as the README says) on a quiet machine::

    python validation/cold_start.py --procs 3
"""

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

PROBE = r"""
import json, sys, time
t0 = time.perf_counter()
import ase_mlg
t1 = time.perf_counter()
import numpy as np
from ase.build import bulk
from ase_mlg import MLGCalculator, neighbor_list
from ase_mlg.potentials import LennardJones
out = {"import_s": t1 - t0}
what = sys.argv[1]
if what == "nl":
    cu = bulk("Cu", "fcc", a=3.6, cubic=True).repeat(3)
    t = time.perf_counter(); neighbor_list("ijdS", cu, 5.0); out["first_s"] = time.perf_counter() - t
    t = time.perf_counter(); neighbor_list("ijdS", cu, 5.0); out["next_s"] = time.perf_counter() - t
else:
    m, a0 = (4, 5.26) if what == "force" else (14, 5.72)
    ar = bulk("Ar", "fcc", a=a0, cubic=True).repeat(m)
    ar.rattle(0.05, seed=1)
    t = time.perf_counter()  # the potential's construction included: it may compile
    ar.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
    ar.get_forces(); out["first_s"] = time.perf_counter() - t
    ar.positions += np.random.default_rng(0).normal(scale=0.5, size=ar.positions.shape)
    t = time.perf_counter(); ar.get_forces(); out["next_s"] = time.perf_counter() - t
    out["natoms"] = len(ar)
print("RESULT " + json.dumps(out))
"""

JOBS = [("nl", "first neighbor_list, Cu 108 atoms", "the second call"),
        ("force", "first force call, LJ argon 256 atoms", "after a 0.5 Å move (rebuild)"),
        ("force_large", "first force call, LJ argon 10,976 atoms", "after a 0.5 Å move (rebuild)")]


def probe(what, cache):
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, OPENBLAS_NUM_THREADS="1")
    res = subprocess.run([sys.executable, "-c", PROBE, what], env=env, capture_output=True,
                         text=True, timeout=900)
    line = [x for x in res.stdout.splitlines() if x.startswith("RESULT ")]
    if res.returncode or not line:
        raise RuntimeError(f"{what}: {res.stderr[-2000:]}")
    return json.loads(line[0][7:])


def demo(cache, cwd):
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, OPENBLAS_NUM_THREADS="1")
    # the command of this interpreter's environment, as a user of it runs it
    exe = os.path.join(os.path.dirname(sys.executable), "ase-mlg")
    if not os.path.exists(exe):
        exe = shutil.which("ase-mlg") or "ase-mlg"
    t = time.perf_counter()
    res = subprocess.run([exe, "demo"], env=env, capture_output=True, text=True,
                         timeout=1800, cwd=cwd)
    if res.returncode:
        raise RuntimeError(f"demo: {res.stderr[-2000:]}")
    return time.perf_counter() - t


def cell(xs, fmt="{:.2f}"):
    xs = [x for x in xs if x is not None]
    if not xs:
        return "—"
    return f"{fmt.format(float(np.median(xs)))} ({fmt.format(min(xs))}-{fmt.format(max(xs))})"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--procs", type=int, default=3, help="fresh processes per figure")
    ap.add_argument("--no-demo", action="store_true", help="skip ase-mlg demo")
    a = ap.parse_args(argv)
    import ase_mlg
    from bench_common import cpu_model
    cpu = cpu_model()
    print(f"# Cold start: python {platform.python_version()}, numba "
          f"{__import__('numba').__version__}, ase_mlg from {os.path.dirname(ase_mlg.__file__)}")
    print(f"# CPU: {cpu}; {os.cpu_count()} cores; {a.procs} fresh processes per figure "
          "(median, min-max), seconds\n")
    rows = []
    for what, label, next_label in JOBS:
        cold, warm = [], []
        for _ in range(a.procs):
            with tempfile.TemporaryDirectory() as cache:
                cold.append(probe(what, cache))
                warm.append(probe(what, cache))
        rows.append((label, cell([r["import_s"] for r in cold]), cell([r["first_s"] for r in cold]),
                     cell([r["first_s"] for r in warm]), cell([r["import_s"] for r in warm]),
                     next_label, cell([r["next_s"] for r in warm], "{:.4f}")))
    print("| call | import (cold) | first call, empty cache | first call, warm cache "
          "| import (warm) | then | that call (warm) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    if not a.no_demo:
        cold, warm = [], []
        for _ in range(a.procs):
            with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as cwd:
                cold.append(demo(cache, cwd))
                warm.append(demo(cache, cwd))
        ratio = [c / w for c, w in zip(cold, warm)]
        print(f"\n`ase-mlg demo`: cold {cell(cold, '{:.1f}')} s, warm {cell(warm, '{:.1f}')} s, "
              f"cold / warm {cell(ratio)}")


if __name__ == "__main__":
    main()
