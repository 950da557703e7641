"""Benchmark: ase_mlg.neighbor_list against vesin, matscipy and ASE.

One run times every tool side by side on the scenes of docs/design.md §9, checks
that all tools return the same pair set, measures peak memory per tool (each
in its own subprocess, high-water mark of the resident set reset just before
the call), and the time to *update* a list after one MD-like step
(``grid.update`` swap sweeps + exact query) against a vesin rebuild.

    python validation/bench_neighbor_list.py            # N = 1e3, 1e4, 1e5
    python validation/bench_neighbor_list.py --large    # ... and 1e6
    python validation/bench_neighbor_list.py --quick    # LJ liquid only
    python validation/bench_neighbor_list.py --scaling  # thread scaling only

The thread-scaling table (``--scaling``, also part of a full run) times
``neighbor_list("ijd", atoms, 8.5)`` on 97,556 atoms of argon (fcc a = 5.26
Å rattled by 0.25 Å, indices shuffled; issue 17) against vesin's full list
at equal threads.  Every figure comes from several fresh processes (one
tool and one thread count each, ``NUMBA_NUM_THREADS`` set before numba
starts, launched interleaved), each reporting from inside: numba's
threading layer after a parallel kernel ran, its thread count, the distinct
thread ids that kernel ran on, and ase-mlg's thread count for the list.
Median over processes of each process's median call; spread = p90 / p10
over all calls of all processes.

All lists are full lists ('ijd', each pair as i-j and j-i).  ase_mlg's list
is sorted by i (ASE semantics); vesin is timed both unsorted (its default)
and with ``sorted=True`` (sorted by i, what ``vesin.ase_neighbor_list``
does) -- the like-for-like comparison.  Times are medians of repeats; the
first ase_mlg call of the process (numba JIT compile or cache load) is
reported separately and excluded.  ASE runs only where it is predicted to
finish within ~60 s (from its time at the previous size).  Threads: the "1
thread" rows use numba.set_num_threads(1) and vesin n_threads=1 (matscipy
and ASE are serial anyway); the "all" rows use every core.
"""

import argparse
import json
import os
import subprocess
import sys
import time

# numba (omp layer), vesin and OpenBLAS each keep worker threads; with the
# default "active" wait policy idle OpenMP workers spin and starve the other
# runtimes on a small machine (measured: grid.update 0.6 ms -> 300 ms at 2
# threads).  Passive waiting must be chosen before the runtimes start.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np

SIGMA = 3.405


# --------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------

def scene(name, n, seed=0):
    """(atoms, cutoff) for a scene of docs/design.md §9 of about n atoms."""
    import ase
    from ase.build import bulk
    from ase.cluster import Octahedron
    rng = np.random.default_rng(seed)
    if name in ("lj_liquid", "dilute_gas"):
        rho = (0.8 if name == "lj_liquid" else 0.05) / SIGMA ** 3
        L = (n / rho) ** (1 / 3)
        atoms = ase.Atoms(f"Ar{n}", positions=rng.random((n, 3)) * L,
                          cell=[L, L, L], pbc=True)
        return atoms, 2.5 * SIGMA
    if name in ("fcc_cu", "sheared"):
        k = max(1, round((n / 4) ** (1 / 3)))
        atoms = bulk("Cu", "fcc", a=3.61, cubic=True) * (k, k, k)
        if name == "sheared":
            cell = atoms.cell.array.copy()
            cell[1] += 0.9 * cell[0]
            cell[2] += 0.6 * cell[0] - 0.7 * cell[1]
            atoms.set_cell(cell, scale_atoms=False)
            atoms.wrap()
        atoms.rattle(0.05, rng=rng)
        return atoms, 5.0
    if name == "nanoparticle":
        size = 3
        while True:
            atoms = Octahedron("Cu", size, cutoff=max(0, size // 4),
                               latticeconstant=3.61)
            if len(atoms) >= n or size > 200:
                break
            size += 1
        atoms.pbc = False
        atoms.rattle(0.05, rng=rng)
        return atoms, 5.0
    if name == "slab":
        k = max(1, round((n / 4 / 2) ** (1 / 2)))
        nz = max(1, round(n / 4 / k / k))
        atoms = bulk("Cu", "fcc", a=3.61, cubic=True) * (k, k, nz)
        atoms.center(vacuum=10.0, axis=2)
        atoms.pbc = (True, True, False)
        atoms.rattle(0.05, rng=rng)
        return atoms, 5.0
    if name == "binary_mix":
        rho = 0.8 / SIGMA ** 3
        L = (n / rho) ** (1 / 3)
        numbers = np.where(rng.random(n) < 0.5, 18, 36)  # Ar / Kr
        atoms = ase.Atoms(numbers=numbers, positions=rng.random((n, 3)) * L,
                          cell=[L, L, L], pbc=True)
        return atoms, {("Ar", "Ar"): 8.5, ("Ar", "Kr"): 9.0, ("Kr", "Kr"): 9.5}
    if name == "small_cell":
        # cutoff larger than half the box (many images); n is ignored
        atoms = bulk("Cu", "fcc", a=3.61, cubic=True) * (2, 2, 2)
        atoms.rattle(0.05, rng=rng)
        return atoms, 9.0
    raise ValueError(name)


SCENES = ["lj_liquid", "fcc_cu", "dilute_gas", "nanoparticle", "sheared",
          "slab", "binary_mix", "small_cell"]


# --------------------------------------------------------------------------
# tools
# --------------------------------------------------------------------------

def boxed(atoms):
    """A copy with a real cell on open axes that have none (matscipy inverts
    the cell; vesin wants a box) -- enclosing the atoms, pbc unchanged.
    validation/bench_small.py uses it too."""
    cell = atoms.cell.array.copy()
    lengths = np.linalg.norm(cell, axis=1)
    if (lengths > 0).all():
        return atoms
    a = atoms.copy()
    ext = np.ptp(atoms.positions, axis=0) + 1.0
    for ax in range(3):
        if lengths[ax] == 0:
            cell[ax] = 0.0
            cell[ax, ax] = ext[ax]
    a.set_cell(cell, scale_atoms=False)
    return a


def run_tool(tool, atoms, cutoff, threads):
    """Return (i, j, d) of a full list, or None when the tool cannot do it."""
    if tool in ("matscipy", "vesin", "vesin_sorted"):
        atoms = boxed(atoms)
    if tool == "ase_mlg":
        import numba
        from ase_mlg.neighborlist import neighbor_list
        numba.set_num_threads(threads)
        return neighbor_list("ijd", atoms, cutoff)
    if tool.startswith("vesin"):
        import vesin
        if isinstance(cutoff, dict):
            return None
        nl = vesin.NeighborList(cutoff=float(cutoff), full_list=True,
                                sorted=(tool == "vesin_sorted"),
                                n_threads=threads)
        # copy=False: vesin's fastest call (its arrays, not copies); the
        # default copy=True adds ~100 ms at 7e6 pairs, which would flatter us
        i, j, d = nl.compute(atoms.positions, atoms.cell.array, atoms.pbc,
                             quantities="ijd", copy=False)
        return i, j, d
    if tool == "matscipy":
        from matscipy.neighbours import neighbour_list
        return neighbour_list("ijd", atoms, cutoff)
    if tool == "ase":
        from ase.neighborlist import neighbor_list
        return neighbor_list("ijd", atoms, cutoff)
    raise ValueError(tool)


def timed(f, repeats):
    ts = []
    out = None
    for _ in range(repeats):
        t = time.perf_counter()
        out = f()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), out


def same_pairs(a, b, n):
    """Same multiset of (i, j) and the same distances (1e-9 A)."""
    if a is None or b is None:
        return None
    ka = np.asarray(a[0], np.int64) * n + np.asarray(a[1], np.int64)
    kb = np.asarray(b[0], np.int64) * n + np.asarray(b[1], np.int64)
    if len(ka) != len(kb):
        return False
    oa = np.lexsort((a[2], ka))
    ob = np.lexsort((b[2], kb))
    return bool(np.array_equal(ka[oa], kb[ob])
                and np.allclose(np.asarray(a[2])[oa], np.asarray(b[2])[ob],
                                rtol=0, atol=1e-9))


# --------------------------------------------------------------------------
# memory, in a subprocess
# --------------------------------------------------------------------------

def _rss_kib(field):
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field):
                return int(line.split()[1])
    return 0


def memory_child(tool, name, n, threads):
    atoms, cutoff = scene(name, n)
    if tool == "ase_mlg":
        run_tool(tool, atoms[:8] if len(atoms) > 8 else atoms, 3.0, threads)  # JIT
    elif tool.startswith("vesin"):
        run_tool(tool, atoms[:8], 3.0, threads)
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")  # reset the high-water mark
    except OSError:
        pass
    base = _rss_kib("VmRSS")
    out = run_tool(tool, atoms, cutoff, threads)
    peak = _rss_kib("VmHWM")
    nbytes = sum(np.asarray(x).nbytes for x in out) if out is not None else 0
    print(json.dumps({"peak_mib": (peak - base) / 1024,
                      "output_mib": nbytes / 2 ** 20}))


def measure_memory(tool, name, n, threads):
    env = dict(os.environ)
    env["NUMBA_NUM_THREADS"] = str(max(threads, 1))
    r = subprocess.run([sys.executable, __file__, "--memory-child", tool, name,
                        str(n), str(threads)], capture_output=True, text=True,
                       env=env, timeout=900)
    try:
        return json.loads(r.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return {"peak_mib": float("nan"), "output_mib": float("nan"),
                "error": r.stderr[-300:]}


# --------------------------------------------------------------------------
# the benchmark
# --------------------------------------------------------------------------

def bench(sizes, scenes, threads_list, repeats_for, out):
    import numba

    from ase_mlg.neighborlist import neighbor_list
    rows = []
    # JIT warm-up, reported and excluded
    atoms, cutoff = scene("lj_liquid", 500)
    t = time.perf_counter()
    neighbor_list("ijd", atoms, cutoff)
    jit = time.perf_counter() - t
    t = time.perf_counter()
    neighbor_list("ijd", atoms, cutoff)
    warm = time.perf_counter() - t
    out(f"ase_mlg first call (JIT compile or cache load): {jit:.2f} s "
        f"(second call {warm * 1e3:.1f} ms) -- excluded from the table")
    layer, nthreads, ids = _probe_layer()
    out(f"numba threading layer: {layer} ({nthreads} threads, a parallel kernel "
        f"ran on {ids}), cores: {os.cpu_count()}")
    ase_time = {}
    for name in scenes:
        for n in (sizes if name != "small_cell" else [32]):
            atoms, cutoff = scene(name, n)
            natoms = len(atoms)
            reps = repeats_for(natoms)
            for threads in threads_list:
                res = {}
                outs = {}
                for tool in ("ase_mlg", "vesin", "vesin_sorted", "matscipy", "ase"):
                    if tool in ("matscipy", "ase") and threads != threads_list[0]:
                        continue
                    if tool == "ase":
                        prev = ase_time.get(name)
                        # ASE's bins are O(N) in a filled periodic box, but
                        # O(N^2) for atoms outside a non-periodic cell (a
                        # cluster in vacuum): predict accordingly
                        power = 2 if not atoms.pbc.any() else 1
                        if prev is not None and (prev[1] * (natoms / prev[0]) ** power
                                                 * 1.3 > 60):
                            res[tool] = None
                            continue
                    r = 1 if tool == "ase" else reps
                    if tool.startswith("vesin") and isinstance(cutoff, dict):
                        res[tool] = None
                        continue
                    try:
                        tt, o = timed(lambda: run_tool(tool, atoms, cutoff,
                                                       threads), r)
                    except Exception as err:  # a tool that cannot do the scene
                        out(f"  ({tool} failed on {name}: "
                            f"{type(err).__name__}: {str(err)[:80]})")
                        res[tool] = None
                        continue
                    res[tool] = tt
                    outs[tool] = o
                    if tool == "ase":
                        ase_time[name] = (natoms, tt)
                ref = outs["ase_mlg"]
                agree = {t: same_pairs(ref, o, natoms) for t, o in outs.items()
                         if t != "ase_mlg"}
                npairs = len(ref[0])
                row = dict(scene=name, n=natoms, threads=threads, pairs=npairs,
                           times=res, agree=agree)
                rows.append(row)
                out(_fmt_row(row))
    return rows


def _fmt(t):
    if t is None:
        return "      -"
    return f"{t * 1e3:8.1f}" if t < 10 else f"{t:7.1f}s"


def _fmt_row(row):
    t = row["times"]
    m = t.get("ase_mlg")
    ratio = lambda k: (f"{m / t[k]:6.2f}" if t.get(k) else "     -")
    bad = [k for k, v in row["agree"].items() if v is False]
    return (f"{row['scene']:13s} {row['n']:8d} {row['threads']:>3} "
            f"{row['pairs']:10d} | {_fmt(m)} {_fmt(t.get('vesin'))} "
            f"{_fmt(t.get('vesin_sorted'))} {_fmt(t.get('matscipy'))} "
            f"{_fmt(t.get('ase'))} | {ratio('vesin')} {ratio('vesin_sorted')} "
            f"{ratio('matscipy')} {ratio('ase')} | "
            f"{'same' if not bad else 'DIFFER: ' + ','.join(bad)}")


HEADER = (f"{'scene':13s} {'N':>8s} {'thr':>3} {'pairs':>10s} | "
          f"{'mlg ms':>8s} {'vesin':>8s} {'vesin_s':>8s} {'matscipy':>8s} "
          f"{'ase':>8s} | {'/ves':>6s} {'/ves_s':>6s} {'/msp':>6s} {'/ase':>6s} | pairs")


def bench_update(n, threads, out, steps=5, disp=0.03):
    """Update after one MD-like step: grid.update + exact query vs vesin
    rebuild (both full 'ijd' lists)."""
    import numba
    import vesin

    import ase_mlg
    from ase_mlg.neighborlist import neighbor_list
    numba.set_num_threads(threads)
    atoms, cutoff = scene("lj_liquid", n)
    rng = np.random.default_rng(1)
    grid = ase_mlg.MLG.from_atoms(atoms)
    neighbor_list("ijd", atoms, cutoff, grid=grid)
    vnl = vesin.NeighborList(cutoff=cutoff, full_list=True, n_threads=threads)
    vnls = vesin.NeighborList(cutoff=cutoff, full_list=True, sorted=True,
                              n_threads=threads)
    t_sweep, t_query, t_v, t_vs, sweeps = [], [], [], [], []
    for _ in range(steps):
        atoms.positions += rng.normal(scale=disp, size=atoms.positions.shape)
        t = time.perf_counter()
        rec = grid.update(atoms.positions)
        t_sweep.append(time.perf_counter() - t)
        sweeps.append(rec["sweeps"])
        t = time.perf_counter()
        mine = neighbor_list("ijd", atoms, cutoff, grid=grid)
        t_query.append(time.perf_counter() - t)
        t = time.perf_counter()
        vnl.compute(atoms.positions, atoms.cell.array, True, quantities="ijd")
        t_v.append(time.perf_counter() - t)
        t = time.perf_counter()
        theirs = vnls.compute(atoms.positions, atoms.cell.array, True,
                              quantities="ijd")
        t_vs.append(time.perf_counter() - t)
    ok = same_pairs(mine, theirs, len(atoms))
    upd = np.median(t_sweep) + np.median(t_query)
    out(f"update N={len(atoms)} threads={threads}: sweeps/step "
        f"{np.mean(sweeps):.1f}, grid.update {np.median(t_sweep) * 1e3:.1f} ms + "
        f"query {np.median(t_query) * 1e3:.1f} ms = {upd * 1e3:.1f} ms; vesin "
        f"rebuild {np.median(t_v) * 1e3:.1f} ms (sorted "
        f"{np.median(t_vs) * 1e3:.1f} ms); vesin/update = "
        f"{np.median(t_v) / upd:.2f} (sorted {np.median(t_vs) / upd:.2f}); "
        f"same pairs: {ok}")



# --------------------------------------------------------------------------
# thread scaling, one process per figure
# --------------------------------------------------------------------------

def argon_scene(seed=0):
    """97,556 atoms of argon: fcc a = 5.26 Å (29^3 cubic cells) rattled by
    0.25 Å, atom indices shuffled (issue 17); cutoff 8.5 Å."""
    from ase.build import bulk
    rng = np.random.default_rng(seed)
    atoms = bulk("Ar", "fcc", a=5.26, cubic=True) * (29, 29, 29)
    atoms.rattle(0.25, rng=rng)
    return atoms[rng.permutation(len(atoms))], 8.5


def _probe_layer():
    """numba's threading layer and the distinct thread ids of a prange
    kernel run in this process (the layer loads at the first one)."""
    import numba

    @numba.njit(parallel=True)
    def ids(out):
        for c in numba.prange(out.shape[0]):
            out[c] = numba.get_thread_id()
            x = 0.0
            for k in range(200000):  # long enough for every thread to take some
                x += k * 1e-9
            out[c] += 0 * int(x)
    out = np.zeros(64, np.int64)
    ids(out)
    return numba.threading_layer(), numba.get_num_threads(), len(set(out.tolist()))


def scaling_child(tool, threads, calls):
    """One measuring process: report (JSON, last line) its layer, threads
    and the time of each call after two warm-up calls."""
    atoms, cutoff = argon_scene()
    info = {"tool": tool, "threads": threads, "pid": os.getpid()}
    if tool == "ase_mlg":
        import ase_mlg
        from ase_mlg.parallel import threads_for
        info["ase_mlg"] = ase_mlg.__file__
        info["list_threads"] = threads_for("atoms", len(atoms))
        # numba's layer only where numba runs the work: a numba kernel in a
        # vesin process would start numba's OpenMP threads beside vesin's own
        # (two runtimes, spinning threads competing for the cores)
        info["layer"], info["numba_threads"], info["thread_ids"] = _probe_layer()
    else:
        info["layer"], info["numba_threads"], info["thread_ids"] = "-", "-", "-"
    ts = []
    for k in range(calls + 2):
        t = time.perf_counter()
        out = run_tool(tool, atoms, cutoff, threads)
        if k >= 2:
            ts.append(time.perf_counter() - t)
    info.update(times=ts, pairs=len(out[0]), n=len(atoms))
    print(json.dumps(info))


def _scaling_run(tool, threads, calls):
    env = dict(os.environ)
    env["NUMBA_NUM_THREADS"] = str(threads)
    env["OMP_NUM_THREADS"] = str(threads)
    r = subprocess.run([sys.executable, __file__, "--scaling-child", tool,
                        str(threads), str(calls)], capture_output=True,
                       text=True, env=env, timeout=900)
    try:
        return json.loads(r.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return {"tool": tool, "threads": threads, "error": r.stderr[-400:]}


def bench_scaling(threads_list, procs, calls, out):
    """The thread-scaling table (see the module doc)."""
    runs = {}
    for _ in range(procs):  # interleaved: every figure sees the same load
        for th in threads_list:
            for tool in ("ase_mlg", "vesin"):
                runs.setdefault((tool, th), []).append(_scaling_run(tool, th, calls))
    out(f"thread scaling: neighbor_list('ijd', argon, 8.5) vs vesin (full list); "
        f"{procs} processes x {calls} calls per figure, ms; cores: {os.cpu_count()}")
    out(f"{'tool':8s} {'thr':>3s} {'layer':>9s} {'ids':>3s} {'list thr':>8s} | "
        f"{'median':>8s} {'p10':>8s} {'p90':>8s} {'spread':>6s} | per process")
    med = {}
    for (tool, th), rs in runs.items():
        bad = [r for r in rs if "error" in r]
        good = [r for r in rs if "error" not in r]
        for r in bad:
            out(f"  {tool} {th} threads failed: {r['error']}")
        if not good:
            continue
        allt = np.concatenate([r["times"] for r in good]) * 1e3
        per = [float(np.median(r["times"]) * 1e3) for r in good]
        med[tool, th] = float(np.median(per))
        layers = ",".join(sorted({str(r["layer"]) for r in good}))
        ids = ",".join(sorted({str(r["thread_ids"]) for r in good}))
        lth = ",".join(sorted({str(r.get("list_threads", "-")) for r in good}))
        p10, p90 = np.percentile(allt, [10, 90])
        out(f"{tool:8s} {th:3d} {layers:>9s} {ids:>3s} {lth:>8s} | "
            f"{med[tool, th]:8.1f} {p10:8.1f} {p90:8.1f} {p90 / p10:6.2f} | "
            + " ".join(f"{x:.1f}" for x in per))
        if tool == "ase_mlg":
            pairs, n = good[0]["pairs"], good[0]["n"]
    if ("ase_mlg", threads_list[0]) in med:
        src = runs["ase_mlg", threads_list[0]][0].get("ase_mlg")
        out(f"N = {n}, pairs = {pairs}; ase_mlg from {src}")
    for th in threads_list:
        if ("ase_mlg", th) in med and ("vesin", th) in med:
            out(f"  {th} thread(s): ase_mlg / vesin = "
                f"{med['ase_mlg', th] / med['vesin', th]:.2f}")
    base = threads_list[0]
    for th in threads_list[1:]:
        for tool in ("ase_mlg", "vesin"):
            if (tool, base) in med and (tool, th) in med:
                out(f"  {tool} {base} -> {th} threads: "
                    f"{med[tool, base] / med[tool, th]:.2f}x")
    return runs


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--large", action="store_true", help="also N = 1e6")
    p.add_argument("--quick", action="store_true", help="LJ liquid only")
    p.add_argument("--scaling", action="store_true",
                   help="only the thread-scaling table (one process per figure)")
    p.add_argument("--procs", type=int, default=3,
                   help="processes per figure of the scaling table")
    p.add_argument("--calls", type=int, default=7,
                   help="timed calls per process of the scaling table")
    p.add_argument("--memory-child", nargs=4, help=argparse.SUPPRESS)
    p.add_argument("--scaling-child", nargs=3, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.memory_child:
        tool, name, n, threads = args.memory_child
        memory_child(tool, name, int(n), int(threads))
        return
    if args.scaling_child:
        tool, threads, calls = args.scaling_child
        scaling_child(tool, int(threads), int(calls))
        return
    sizes = [1000, 10000, 100000] + ([1000000] if args.large else [])
    scenes = ["lj_liquid"] if args.quick else SCENES
    ncores = os.cpu_count() or 1
    threads_list = [1] + ([ncores] if ncores > 1 else [])

    def out(s):
        print(s, flush=True)

    bench_scaling(threads_list, args.procs, args.calls, out)
    if args.scaling:
        return
    out("")
    out("times in ms (s where marked), medians; ratios = ase_mlg time / tool "
        "time (< 1: ase_mlg faster)")
    out(HEADER)
    bench(sizes, scenes, threads_list,
          lambda n: 7 if n <= 10000 else (3 if n <= 200000 else 1), out)
    out("")
    out("update after one MD-like step (LJ liquid, 0.03 A rms displacement):")
    for n in sizes[1:]:
        for th in threads_list:
            bench_update(n, th, out)
    out("")
    big = 100000
    out(f"peak memory above baseline (MiB, own subprocess; LJ liquid N={big}, "
        f"1 thread; 'output' = bytes of the returned arrays):")
    for tool in ("ase_mlg", "vesin", "vesin_sorted", "matscipy"):
        m = measure_memory(tool, "lj_liquid", big, 1)
        out(f"  {tool:13s} peak {m['peak_mib']:8.1f}  output {m['output_mib']:8.1f}"
            + (f"  ({m['error']})" if "error" in m else ""))


if __name__ == "__main__":
    main()
