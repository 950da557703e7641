"""A/B of two commits of ase-mlg: force call and MD step, interleaved processes.

A restructuring must not cost speed.  This script checks out two commits
(``--old``, ``--new``; default the previous session's end and the working
tree) into temporary git worktrees and runs, for every scene size and
thread count, ``--procs`` worker processes of each, alternating old, new,
old, new, ... so that a drift of the machine's speed hits both alike.  Each
worker imports ``ase_mlg`` from its tree (``PYTHONPATH``; the measuring code
is this directory's, the same for both), reports its threading layer and
the distinct thread ids of its force kernel, warms its kernels up (the
warm-up is reported, not timed), and measures with
``validation/bench_engines.py``'s definitions:

* force call: ``atoms.get_forces()`` after every atom moved ~0.01 Å rms
  from the same start (the pair list stays valid), ``--calls`` calls;
* MD step: ASE's ``VelocityVerlet`` and ``ase_mlg.md.VelocityVerlet``,
  5 fs, mean over ``--repeats`` blocks of ``--steps`` steps (list rebuilds
  paid in full).

The table gives the median over processes of each process's median (force
call) or mean (MD step), the spread over processes (min-max), and new/old.
Run it on a quiet machine.

Usage::

    python validation/ab_compare.py --old dcbf4ec --sizes 10976,108000 --threads 1,2
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def worker(natoms, calls, steps, repeats):
    from ase import units
    from ase.md.verlet import VelocityVerlet

    import ase_mlg
    from ase_mlg.md import VelocityVerlet as OwnVerlet
    from bench_common import DT_FS, fcc_argon, now, time_md
    from bench_engines import mlg_calc, time_force_calls

    atoms = fcc_argon(natoms)
    out = {"from": os.path.dirname(ase_mlg.__file__), "natoms": len(atoms)}
    dt = DT_FS * units.fs
    for name, make in (("ase_vv", VelocityVerlet), ("own_vv", OwnVerlet)):
        a = atoms.copy()
        a.calc = mlg_calc(None)
        t = now()
        a.get_forces()
        dyn = make(a, dt)
        while a.calc.stats["list_builds"] < 2:  # every kernel of a step ran
            dyn.run(1)
        out[name + "_warm_s"] = now() - t
        if name == "ase_vv":
            out["force_ms"] = float(np.median(time_force_calls(a, calls)))
        out[name + "_ms"] = time_md(dyn.run, steps, repeats)
        out["threads_used"] = a.calc.stats["threads_used"]
    from ase_mlg import parallel
    out["layer"] = parallel.LAYER
    return out


def run(tree, natoms, threads, p):
    env = dict(os.environ, PYTHONPATH=tree, NUMBA_NUM_THREADS=str(threads),
               OMP_NUM_THREADS=str(threads), OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.pop("LD_LIBRARY_PATH", None)
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", str(natoms),
           "--calls", str(p.calls), "--steps", str(p.steps), "--repeats", str(p.repeats)]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tempfile.gettempdir())
    if res.returncode:
        raise RuntimeError(f"worker failed in {tree}:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def worktree(repo, ref, where):
    path = os.path.join(where, ref.replace("/", "_"))
    subprocess.run(["git", "-C", repo, "worktree", "add", "--detach", "-f", path, ref],
                   check=True, capture_output=True)
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", default="dcbf4ec")
    ap.add_argument("--new", default=None, help="a commit (default: the working tree)")
    ap.add_argument("--sizes", default="10976,108000")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--procs", type=int, default=3)
    ap.add_argument("--calls", type=int, default=30)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--worker", type=int, default=None, help=argparse.SUPPRESS)
    p = ap.parse_args(argv)
    if p.worker is not None:
        print(json.dumps(worker(p.worker, p.calls, p.steps, p.repeats)))
        return
    repo = os.path.dirname(HERE)
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"old": worktree(repo, p.old, tmp),
                 "new": repo if p.new is None else worktree(repo, p.new, tmp)}
        try:
            rows = []
            for natoms in map(int, p.sizes.split(",")):
                for k in map(int, p.threads.split(",")):
                    res = {"old": [], "new": []}
                    for _ in range(p.procs):
                        for v in ("old", "new"):
                            res[v].append(run(trees[v], natoms, k, p))
                    rows.append((natoms, k, res))
                    report(rows[-1:], p, header=len(rows) == 1)
        finally:
            subprocess.run(["git", "-C", repo, "worktree", "prune"], capture_output=True)


def report(rows, p, header):
    if header:
        print(f"old = {p.old}, new = {p.new or 'working tree'}; {p.procs} processes each, "
              f"interleaved; ms: median over processes (min-max)\n")
        print("| atoms | threads | figure | old | new | new/old | layer, thread ids (old/new) |")
        print("|---|---|---|---|---|---|---|")
    for natoms, k, res in rows:
        n = res["new"][0]["natoms"]
        for key, label in (("force_ms", "force call"), ("ase_vv_ms", "MD step, ASE VV"),
                           ("own_vv_ms", "MD step, ase_mlg.md")):
            o = [r[key] for r in res["old"]]
            w = [r[key] for r in res["new"]]
            lay = (f"{res['old'][0]['layer']} {max(r['threads_used'] for r in res['old'])}/"
                   f"{res['new'][0]['layer']} {max(r['threads_used'] for r in res['new'])}")
            print(f"| {n:,} | {k} | {label} | {np.median(o):.2f} ({min(o):.2f}-{max(o):.2f}) | "
                  f"{np.median(w):.2f} ({min(w):.2f}-{max(w):.2f}) | "
                  f"{np.median(w) / np.median(o):.3f} | {lay} |", flush=True)


if __name__ == "__main__":
    main()
