"""Time per frame of RDFs: ase_mlg vs MDAnalysis InterRDF vs ASE get_rdf.

One run, one table: the LJ argon liquid scene (rho* = 0.8, ``ase_mlg.scenes``)
at N = 10^3 ... 10^5 atoms (10^6 with ``--large``), a short trajectory of
liquid-like motion (``PersistentWalk``, 0.05 Å rms per frame) in an in-memory
MDAnalysis universe, g(r) of all atoms up to ``--rmax`` Å.

Columns (seconds per frame, medians over ``--repeats`` runs of ``--frames``
frames; JIT compilation / cache loading excluded -- it is measured once,
before the table, and reported):

* ``mlg RDF``: :class:`ase_mlg.analysis.RDF` (MDAnalysis side, exact),
* ``InterRDF``: MDAnalysis's, same universe and settings (counts checked
  equal bin by bin),
* ``mlg rdf`` / ``get_rdf``: the ASE side, one frame as ``Atoms``; ASE only
  where the extrapolated time stays under ``--ase-budget`` seconds,

then the speed-up of ``mlg RDF`` over InterRDF.  A second table reports
dask scaling (2 workers, ``--dask-size`` atoms, ``--dask-frames`` frames) of
both RDF classes: wall times, the worker start-up (spawned processes,
imports, numba cache loading, the pickled universe) and the time per frame
without it.  Note that ase_mlg's numba kernels already use both cores in a
serial run, while InterRDF is single-threaded.

``--adk``: adenylate kinase in water (MDAnalysisTests ``TPR``/``XTC``, 10
frames), water oxygens x water oxygens (11,084 each), rmax 10 Å, 100 bins:
RDF vs InterRDF per frame (the speed the issue tracker asks to keep >= 5x),
and with ``--distributed 1 2 4`` frames per second on a local
``dask.distributed`` cluster (``dask scheduler`` and N ``dask worker``
processes started here, one thread each, stopped at the end), counts checked
against serial InterRDF.

Usage::

    python validation/bench_rdf.py --adk --distributed 1 2 4 --no-sizes

    python validation/bench_rdf.py            # 1e3, 1e4, 1e5
    python validation/bench_rdf.py --large    # adds 1e6
"""

import argparse
import importlib
import os
import platform
import statistics
import sys
import time
import warnings

import numpy as np


def _universe(natoms, frames, seed=0):
    """An in-memory MDAnalysis universe of the LJ liquid scene and the ASE
    image of its first frame."""
    import MDAnalysis as mda
    from ase_mlg.scenes import PersistentWalk, lj_liquid
    atoms = lj_liquid(natoms, seed=seed)
    walk = PersistentWalk(atoms.positions, 0.05, seed=seed)
    coords = [atoms.positions.copy()] + [walk.step().copy() for _ in range(frames - 1)]
    L = atoms.cell.lengths()
    u = mda.Universe.empty(len(atoms), trajectory=True)
    u.load_new(np.array(coords, dtype=np.float32),
               dimensions=[L[0], L[1], L[2], 90.0, 90.0, 90.0])
    return u, atoms


def _timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def _fmt(t):
    if t is None:
        return "--"
    return f"{t * 1e3:.1f} ms" if t < 1.0 else f"{t:.2f} s"


def warm_up(rmax, nbins):
    """First calls in this process: numba compilation or cache loading of
    the grid, query and histogram kernels (excluded from the table)."""
    from ase_mlg.analysis import RDF, rdf
    u, atoms = _universe(500, 2)
    t0 = time.perf_counter()
    RDF(u.atoms, u.atoms, nbins=nbins, range=(0.0, min(rmax, 10.0))).run()
    t1 = time.perf_counter()
    rdf(atoms, min(rmax, 10.0), nbins)
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1


def bench_size(natoms, args, ase_estimate):
    from ase.geometry.rdf import get_rdf
    from MDAnalysis.analysis.rdf import InterRDF
    from ase_mlg.analysis import RDF, rdf

    u, atoms = _universe(natoms, args.frames)
    n = len(atoms)
    kw = dict(nbins=args.nbins, range=(0.0, args.rmax))
    t_mlg, mine = _timed(lambda: RDF(u.atoms, u.atoms, **kw).run(), args.repeats)
    t_mlg /= args.frames
    # InterRDF at 1e6 atoms takes about a minute per frame: time one frame once
    big = n > 300_000
    stop = 1 if big else None
    t_mda, ref = _timed(lambda: InterRDF(u.atoms, u.atoms, **kw).run(stop=stop),
                        1 if big else args.repeats)
    t_mda /= 1 if big else args.frames
    same = np.array_equal(ref.results.count,
                          RDF(u.atoms, u.atoms, **kw).run(stop=stop).results.count
                          if big else mine.results.count)
    t_ase_mlg, _ = _timed(lambda: rdf(atoms, args.rmax, args.nbins), args.repeats)
    t_ase = None
    if ase_estimate is None or ase_estimate(n) < args.ase_budget:
        t_ase, _ = _timed(lambda: get_rdf(atoms, args.rmax, args.nbins), 1)
    return dict(n=n, mlg=t_mlg, mda=t_mda, ase_mlg=t_ase_mlg, ase=t_ase, same=same,
                stats=mine.grid_stats)


def bench_dask(natoms, args):
    """Serial vs dask (2 workers) over ``--dask-frames`` frames; the start-up
    of the worker processes (spawn, imports, numba cache loading, shipping
    the universe) is estimated by a dask run of one frame per worker."""
    from MDAnalysis.analysis.rdf import InterRDF
    from ase_mlg.analysis import RDF
    frames = max(4, args.dask_frames)
    u, atoms = _universe(natoms, frames)
    kw = dict(nbins=args.nbins, range=(0.0, args.rmax))
    rows = []
    for cls in (RDF, InterRDF):
        t0 = time.perf_counter()
        serial = cls(u.atoms, u.atoms, **kw).run()
        t1 = time.perf_counter()
        par = cls(u.atoms, u.atoms, **kw).run(backend="dask", n_workers=2)
        t2 = time.perf_counter()
        cls(u.atoms, u.atoms, **kw).run(stop=2, backend="dask", n_workers=2)
        t3 = time.perf_counter()
        ts, td, t2f = t1 - t0, t2 - t1, t3 - t2
        # t2f = start-up + one frame per worker (in parallel)
        per_frame_dask = (td - t2f) / (frames - 2)
        rows.append(dict(name=cls.__name__, n=len(atoms), frames=frames, serial=ts,
                         dask=td, startup=max(t2f - ts / frames, 0.0),
                         per_serial=ts / frames, per_dask=per_frame_dask,
                         same=np.array_equal(serial.results.count, par.results.count)))
    return rows


def bench_adk(args):
    """RDF vs InterRDF per frame on the adk waters (OW x OW)."""
    import MDAnalysis as mda
    from MDAnalysis.analysis.rdf import InterRDF
    from MDAnalysisTests.datafiles import TPR, XTC
    from ase_mlg.analysis import RDF
    u = mda.Universe(TPR, XTC)
    ow = u.select_atoms("name OW")
    kw = dict(nbins=100, range=(0.0, 10.0))
    RDF(ow, ow, **kw).run(stop=1)  # warm
    t_mlg, mine = _timed(lambda: RDF(ow, ow, **kw).run(), args.repeats)
    t_mda, ref = _timed(lambda: InterRDF(ow, ow, **kw).run(), 1)
    n = u.trajectory.n_frames
    return dict(n=len(ow), frames=n, mlg=t_mlg / n, mda=t_mda / n,
                same=np.array_equal(mine.results.count, ref.results.count), ref=ref)


def bench_distributed(workers, ref):
    """Frames per second of RDF on a local dask.distributed cluster of
    ``workers`` worker processes (one thread each); the cluster is started
    and stopped here.  The first run (imports, numba cache loading on the
    workers) is excluded; the median of 3 timed runs is reported."""
    import json
    import subprocess
    import tempfile
    import MDAnalysis as mda
    from distributed import Client
    from MDAnalysisTests.datafiles import TPR, XTC
    from ase_mlg.analysis import RDF, DistributedBackend
    u = mda.Universe(TPR, XTC)
    ow = u.select_atoms("name OW")
    kw = dict(nbins=100, range=(0.0, 10.0))
    with tempfile.TemporaryDirectory() as tmp:
        sfile = os.path.join(tmp, "scheduler.json")
        procs = [subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port",
             "0", "--no-dashboard", "--scheduler-file", sfile],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
        try:
            while not (os.path.exists(sfile) and open(sfile).read().strip()):
                time.sleep(0.2)
            address = json.load(open(sfile))["address"]
            for _ in range(workers):
                procs.append(subprocess.Popen(
                    [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1",
                     "--no-dashboard"],
                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            with Client(address) as client:
                client.wait_for_workers(workers, timeout=120)
                backend = DistributedBackend(client)
                RDF(ow, ow, **kw).run(backend=backend)  # warm the workers
                t, r = _timed(lambda: RDF(ow, ow, **kw).run(backend=backend), 3)
        finally:
            for p in procs[::-1]:
                p.terminate()
            for p in procs[::-1]:
                p.wait()
    return dict(workers=workers, fps=r.n_frames / t,
                same=np.array_equal(r.results.count, ref.results.count))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=float, nargs="+", default=[1e3, 1e4, 1e5])
    p.add_argument("--large", action="store_true", help="add N = 10^6")
    p.add_argument("--rmax", type=float, default=10.0, help="Å (default 10)")
    p.add_argument("--nbins", type=int, default=100)
    p.add_argument("--frames", type=int, default=3)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--ase-budget", type=float, default=60.0,
                   help="skip ASE get_rdf where it would take longer (s)")
    p.add_argument("--dask-size", type=float, default=1e5)
    p.add_argument("--dask-frames", type=int, default=12)
    p.add_argument("--no-dask", action="store_true")
    p.add_argument("--no-sizes", action="store_true", help="skip the LJ liquid table")
    p.add_argument("--adk", action="store_true",
                   help="RDF vs InterRDF per frame on the adk waters (MDAnalysisTests)")
    p.add_argument("--distributed", type=int, nargs="*", default=None, metavar="N",
                   help="with --adk: frames/s on local dask.distributed clusters of "
                        "N workers each")
    args = p.parse_args(argv)
    warnings.filterwarnings("ignore")
    sizes = [int(s) for s in args.sizes] + ([1_000_000] if args.large else [])

    # ase_mlg first: it sets OMP_WAIT_POLICY=PASSIVE before numba's OpenMP
    # layer starts (get_num_threads below starts it); spinning idle threads
    # otherwise starve the serial parts on 2 cores for seconds
    importlib.import_module("ase_mlg")
    import MDAnalysis
    import ase
    import numba
    print(f"# bench_rdf: LJ liquid (rho* 0.8), rmax {args.rmax} Å, {args.nbins} bins, "
          f"{args.frames} frames, median of {args.repeats}")
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"numba {numba.__version__} ({numba.get_num_threads()} threads), "
          f"MDAnalysis {MDAnalysis.__version__}, ase {ase.__version__}, "
          f"python {platform.python_version()}")
    print(f"# command: {' '.join([os.path.basename(sys.argv[0])] + sys.argv[1:])}")
    print(f"# load average at the start: "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if args.adk:
        row = bench_adk(args)
        print()
        print(f"adk waters: {row['n']:,} x {row['n']:,} OW, {row['frames']} frames, "
              "rmax 10 Å, 100 bins")
        print()
        print("| mlg RDF / frame | InterRDF / frame | speed-up | counts equal |")
        print("|---:|---:|---:|:---:|")
        print(f"| {_fmt(row['mlg'])} | {_fmt(row['mda'])} | {row['mda'] / row['mlg']:.1f}x "
              f"| {'yes' if row['same'] else 'NO'} |", flush=True)
        if args.distributed:
            print()
            print("dask.distributed, local scheduler + N workers (1 thread each):")
            print()
            print("| workers | frames/s | counts equal InterRDF |")
            print("|---:|---:|:---:|")
            for n in args.distributed:
                d = bench_distributed(n, row["ref"])
                print(f"| {d['workers']} | {d['fps']:.2f} | {'yes' if d['same'] else 'NO'} |",
                      flush=True)
        print(f"# load average: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
        if args.no_sizes:
            return
    w_mda, w_ase = warm_up(args.rmax, args.nbins)
    print(f"# JIT warm-up (first calls, excluded below): RDF {w_mda:.2f} s, "
          f"rdf {w_ase:.2f} s")
    print()
    print("| N atoms | mlg RDF | InterRDF | speed-up | counts equal | mlg rdf (ASE) "
          "| ASE get_rdf | grid builds/updates |")
    print("|---:|---:|---:|---:|:---:|---:|---:|:---:|")
    per_atom = None  # ASE's get_rdf is linear in N: extrapolate from the last size
    for natoms in sizes:
        est = None if per_atom is None else (lambda n, k=per_atom: k * n)
        row = bench_size(natoms, args, est)
        if row["ase"] is not None:
            per_atom = row["ase"] / row["n"]
        ase_txt = _fmt(row["ase"]) if row["ase"] is not None else (
            f"skipped (~{per_atom * row['n']:.0f} s)")
        st = row["stats"]
        print(f"| {row['n']:,} | {_fmt(row['mlg'])} | {_fmt(row['mda'])} | "
              f"{row['mda'] / row['mlg']:.1f}x | {'yes' if row['same'] else 'NO'} | "
              f"{_fmt(row['ase_mlg'])} | {ase_txt} | {st['builds']}/{st['updates']} |",
              flush=True)
    if not args.no_dask:
        print()
        print("dask, 2 workers (scheduler='processes'): wall times; 'per frame' "
              "excludes the worker start-up")
        print()
        print("| class | N atoms | frames | serial | dask x2 | start-up | per frame serial "
              "| per frame dask | scaling | counts equal |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|---:|:---:|")
        for r in bench_dask(int(args.dask_size), args):
            print(f"| {r['name']} | {r['n']:,} | {r['frames']} | {_fmt(r['serial'])} | "
                  f"{_fmt(r['dask'])} | {_fmt(r['startup'])} | {_fmt(r['per_serial'])} | "
                  f"{_fmt(r['per_dask'])} | {r['per_serial'] / r['per_dask']:.2f}x | "
                  f"{'yes' if r['same'] else 'NO'} |", flush=True)
    print()
    print(f"# load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())} "
          f"(other processes share the {os.cpu_count()} cores: compare ratios, "
          "not absolute times)")


if __name__ == "__main__":
    main()
