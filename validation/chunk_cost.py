"""What the pair sum's fixed chunking costs: force calls and buffers, against
the thread-following chunking it replaced.

The pair sum's chunks used to follow numba's thread count (1 chunk on one
thread, 4 a thread on more, halved while their windows took more than 3 N
buffer entries but never below one a thread), so results changed with the
thread count.  They are now a function of the list alone
(:func:`ase_mlg.chunks.row_chunks`), the same at every thread count.
This script measures what that costs.  For every size and thread count a
fresh worker process (``NUMBA_NUM_THREADS``) builds the benchmark scene
(validation/bench_common.py: LJ argon, rc 8.5 Å, skin 1 Å, fcc at 5.72 Å,
indices shuffled) under :class:`ase_mlg.MLGCalculator`, warms its kernels
up (not timed), and times ``atoms.get_forces()`` after every atom moved
~0.01 Å rms from the same start (the list stays valid), ``--calls`` calls
per chunking, the chunkings interleaved call by call on the same list:

* ``fixed``: the package's chunks (what the calculator uses);
* ``old``: the thread-following chunks, rebuilt here as they were
  (``RowChunks`` of that count, handed to the calculator's list);
* ``fixed-b3``: the fixed rule with the window budget at 3 N (the old
  budget): fewer chunks, narrower buffers, less balance on many threads.

The table gives, per size, threads and chunking: the chunks, the buffer
entries over N (force buffers: 24 bytes an entry; with per-atom energies
and virials 80), the median and minimum force call (ms), and the median
over ``old``'s.  ``--entries-only`` prints the chunk counts and entries
without timing (cheap at 10^6 atoms).  Timings mean something on a quiet
machine only.

Usage::

    python validation/chunk_cost.py --sizes 10976,108000 --threads 1,2 --calls 30
    python validation/chunk_cost.py --sizes 1000000 --threads 1,2,64 --entries-only
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

OLD_CHUNKS_PER_THREAD, OLD_PAIRS_PER_CHUNK, OLD_BUDGET = 4, 20_000, 3.0


def old_chunks(rowptr, nbr, nthreads):
    """The thread-following chunks of before (chunking.row_chunks as it
    was): one chunk on one thread or a short list, else 4 a thread (at
    least 2 a thread, no shorter than 20,000 pairs where possible), halved
    while the windows take more than 3 N entries and a thread has more
    than one."""
    from ase_mlg.parallel import THRESHOLDS
    from ase_mlg.chunks import RowChunks
    m, n = int(rowptr[-1]), len(rowptr) - 1
    nth = nthreads if m >= THRESHOLDS["pairs"] else 1
    if nth <= 1:
        nchunk = 1
    else:
        by_size = max(2 * nth, m // OLD_PAIRS_PER_CHUNK)
        nchunk = max(1, min(OLD_CHUNKS_PER_THREAD * nth, by_size))
    while True:
        chunks = RowChunks(rowptr, nbr, nchunk)
        if chunks.entries <= OLD_BUDGET * n or nchunk <= nth:
            return chunks
        nchunk = max(nth, nchunk // 2)


def fixed_chunks(rowptr, nbr, budget=None):
    """The package's chunks, with the window budget ``budget`` (x N)
    instead of the package's where given."""
    from ase_mlg import chunks as chunking
    if budget is None:
        return chunking.row_chunks(rowptr, nbr)
    kept = chunking.WINDOW_BUDGET
    chunking.WINDOW_BUDGET = budget
    try:
        return chunking.row_chunks(rowptr, nbr)
    finally:
        chunking.WINDOW_BUDGET = kept


def chunkings(pl, nthreads):
    return {"fixed": fixed_chunks(pl.rowptr, pl.nbr),
            "old": old_chunks(pl.rowptr, pl.nbr, nthreads),
            "fixed-b3": fixed_chunks(pl.rowptr, pl.nbr, OLD_BUDGET)}


def use(vl, chunks):
    """Make the calculator's list hand out ``chunks`` (an instance
    attribute shadowing :meth:`VerletList.chunks`)."""
    vl.chunks = lambda nthreads=None: chunks


def worker(natoms, calls, entries_only):
    import numba

    from bench_common import MOVE, fcc_argon, now
    from bench_engines import mlg_calc

    atoms = fcc_argon(natoms)
    atoms.calc = calc = mlg_calc(None)
    nth = numba.get_num_threads()
    out = {"natoms": len(atoms), "threads": nth, "rows": {}}
    if entries_only:  # the list alone: no forces, no kernels
        from ase_mlg.verletlist import VerletList
        vl = VerletList.allocate(atoms.positions, atoms.cell.array, atoms.pbc,
                                 calc.potential.cutoff, skin=calc.skin)
        out["npairs"] = len(vl.pairs)
        for name, ch in chunkings(vl.pairs, nth).items():
            out["rows"][name] = {"nchunk": ch.nchunk, "entries": ch.entries / len(atoms)}
        return out
    atoms.get_forces()
    vl = calc.verlet_list
    out["npairs"] = len(vl.pairs)
    chunks = chunkings(vl.pairs, nth)
    builds = vl.stats["list_builds"]
    base = atoms.get_positions()
    rng = np.random.default_rng(1)
    times = {name: [] for name in chunks}
    used = dict.fromkeys(chunks, 0)
    for name, ch in chunks.items():  # warm-up: every chunking's buffers and kernels
        use(vl, ch)
        for _ in range(2):
            atoms.set_positions(base + rng.normal(scale=MOVE / np.sqrt(3), size=base.shape))
            atoms.get_forces()
    for _ in range(calls):
        for name, ch in chunks.items():
            use(vl, ch)
            atoms.set_positions(base + rng.normal(scale=MOVE / np.sqrt(3), size=base.shape))
            t = now()
            atoms.get_forces()
            times[name].append(1e3 * (now() - t))
            used[name] = max(used[name], calc.stats["threads_used"])
    if vl.stats["list_builds"] != builds:
        raise RuntimeError("the list was rebuilt during the timing: chunks went stale")
    for name, ch in chunks.items():
        out["rows"][name] = {"nchunk": ch.nchunk, "entries": ch.entries / len(atoms),
                             "median_ms": float(np.median(times[name])),
                             "min_ms": float(np.min(times[name])),
                             "threads_used": used[name]}
    return out


def run(natoms, threads, p):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads),
               OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", str(natoms),
           "--calls", str(p.calls)] + (["--entries-only"] if p.entries_only else [])
    res = subprocess.run(cmd, env=env, capture_output=True, text=True,
                         cwd=tempfile.gettempdir())
    if res.returncode:
        raise RuntimeError(f"worker failed:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def report(res, header, entries_only):
    if header:
        if entries_only:
            print("| atoms | pairs | threads | chunking | chunks | entries / N | force buffers MB |")
            print("|---|---|---|---|---|---|---|")
        else:
            print("| atoms | threads | chunking | chunks | entries / N | force call ms, "
                  "median (min) | / old | threads used |")
            print("|---|---|---|---|---|---|---|---|")
    n, k, rows = res["natoms"], res["threads"], res["rows"]
    for name, r in rows.items():
        if entries_only:
            print(f"| {n:,} | {res['npairs']:,} | {k} | {name} | {r['nchunk']} | "
                  f"{r['entries']:.2f} | {r['entries'] * n * 24 / 1e6:.1f} |", flush=True)
            continue
        ratio = r["median_ms"] / rows["old"]["median_ms"]
        print(f"| {n:,} | {k} | {name} | {r['nchunk']} | {r['entries']:.2f} | "
              f"{r['median_ms']:.2f} ({r['min_ms']:.2f}) | {ratio:.3f} | "
              f"{r['threads_used']} |", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10976,108000")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--calls", type=int, default=30, help="timed calls per chunking (>= 20)")
    ap.add_argument("--entries-only", action="store_true")
    ap.add_argument("--worker", type=int, default=None, help=argparse.SUPPRESS)
    p = ap.parse_args(argv)
    if p.worker is not None:
        print(json.dumps(worker(p.worker, p.calls, p.entries_only)))
        return
    first = True
    for natoms in map(int, p.sizes.split(",")):
        for k in map(int, p.threads.split(",")):
            report(run(natoms, k, p), first, p.entries_only)
            first = False


if __name__ == "__main__":
    main()
