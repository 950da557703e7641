"""The Python-side engines of validation/bench_md.py (ase-mlg, asap3, ASE)
and what their worker processes measure: force calls, the MD step and its
breakdown (``calc.timings`` and the time inside ``calc.calculate``), peak
memory through a list rebuild, NVE/NPT, and what each ase-mlg worker runs
with (threading layer, threads, thread ids of its force kernel, where
ase_mlg was imported from), reported from inside the worker."""

import importlib
import json
import os
import sys
import sysconfig
import warnings

import numpy as np
from ase import units

from bench_common import (DT_FS, EPS, MOVE, P_BAR, PDAMP_FS, RC, SIGMA, SKIN, T_K, TDAMP_FS,
                          fcc_argon, maxrss_mb, now, thermalize_momenta, time_md)

TEMPLATE = {"mlg-exact": None, "mlg-w7": 7}
#: phases of MLGCalculator.calculate in ``calc.timings`` (cumulative s);
#: "grid" is part of "list_build"
PHASES = ("kernel", "list_build", "grid", "gather", "check")
#: the shared libraries whose presence in a worker says which runtimes it runs
RUNTIMES = ("libtbb", "libgomp", "libiomp", "libomp", "libmpi")

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


def own_verlet():
    """``ase_mlg.md.VelocityVerlet``, or the reason it is not importable."""
    try:
        return importlib.import_module("ase_mlg.md").VelocityVerlet, None
    except (ImportError, AttributeError) as e:
        return None, f"{type(e).__name__}: {e}"


# ---------------------------------------------- what an ase-mlg worker runs

def loaded_runtimes():
    """Threading/MPI runtimes mapped into this process (/proc/self/maps)."""
    try:
        with open("/proc/self/maps") as f:
            maps = f.read()
    except OSError:
        return None
    return sorted({m for m in RUNTIMES if m + "." in maps or m + "_" in maps})


def jsonable(d):
    return {k: (v if isinstance(v, (str, int, float, bool, type(None))) else str(v))
            for k, v in d.items()}


def threading_report(calc, probe=False):
    """From inside this worker, after its kernels ran: numba's threading
    layer (None if no threaded kernel was launched), thread count, the
    distinct thread ids of the last threaded force kernel
    (``calc.stats["threads_used"]``, once ase-mlg records it) and
    ``ase_mlg.parallel.config()`` where it exists (with its thread-id probe
    kernel if ``probe``: the facts worker only, never a measuring one)."""
    import numba
    try:
        layer = numba.threading_layer()
    except ValueError:  # no threaded kernel ran in this process
        layer = None
    out = {"layer": layer, "threads": numba.get_num_threads(),
           "threads_used": (getattr(calc, "stats", None) or {}).get("threads_used"),
           "runtimes": loaded_runtimes(), "config": None}
    import ase_mlg.parallel
    config = getattr(ase_mlg.parallel, "config", None)
    if config is not None:
        try:
            try:
                cfg = config(probe=probe)
            except TypeError:
                cfg = config()
            out["config"] = jsonable(cfg)
        except Exception as e:  # noqa: BLE001 - report it
            out["config"] = {"error": f"{type(e).__name__}: {e}"}
    return out


def install_facts():
    """Where this process's ase_mlg comes from: site-packages of a plain
    install, or a checkout / editable install (not what users get)."""
    import ase_mlg
    path = os.path.realpath(os.path.dirname(ase_mlg.__file__))
    sites = {os.path.realpath(sysconfig.get_paths()[k]) for k in ("purelib", "platlib")}
    editable = None
    try:
        from importlib.metadata import distribution
        d = distribution("ase-mlg")
        url = json.loads(d.read_text("direct_url.json") or "{}")
        editable = bool(url.get("dir_info", {}).get("editable", False))
        version = d.version
    except Exception:  # noqa: BLE001 - not installed as a distribution
        version = getattr(ase_mlg, "__version__", None)
    return {"mlg_path": path, "mlg_version": version, "editable": editable,
            "site_packages": any(path.startswith(s + os.sep) for s in sites),
            "venv": sys.prefix != sys.base_prefix, "prefix": sys.prefix}


# ------------------------------------------------------------ measurements

class CalcClock:
    """Seconds spent inside ``calc.calculate`` (wrapped on the instance)."""

    def __init__(self, calc):
        self.seconds, self.calls = 0.0, 0
        inner = calc.calculate

        def calculate(*args, **kwargs):
            t = now()
            try:
                return inner(*args, **kwargs)
            finally:
                self.seconds += now() - t
                self.calls += 1
        calc.calculate = calculate

    def mark(self, calc):
        t = getattr(calc, "timings", None)
        return self.seconds, self.calls, dict(t) if isinstance(t, dict) else None


def step_parts(before, after, steps, step_ms):
    """ms per step of each phase of ``calc.timings`` between two marks, the
    calculator's time, and the rest of the step (integrator + ASE)."""
    (s0, c0, t0), (s1, c1, t1) = before, after
    parts = {"step": step_ms}
    if t0 is not None and t1 is not None:
        for k in PHASES:
            if k in t0 and k in t1:
                parts[k] = 1e3 * (t1[k] - t0[k]) / steps
    # the phases inside calculate (ase-mlg merged "gather" into "check")
    inside = [parts.get(k) for k in ("kernel", "list_build", "gather", "check")
              if k in parts or t1 is None or k != "gather"]
    if c1 > c0:
        parts["calculator"] = 1e3 * (s1 - s0) / steps
    elif None not in inside:  # a loop that bypasses calc.calculate
        parts["calculator"] = sum(inside)
    if parts.get("calculator") is not None:
        parts["integrator"] = step_ms - parts["calculator"]
        if None not in inside:
            parts["other"] = parts["calculator"] - sum(inside)
    return parts


def time_force_calls(atoms, calls, seed=1):
    """ms of each of ``calls`` force calls, each after moving every atom
    ~MOVE Å rms from the same start (pair lists stay valid)."""
    rng = np.random.default_rng(seed)
    base = atoms.get_positions()
    atoms.get_forces()
    ts = []
    for _ in range(calls):
        atoms.set_positions(base + rng.normal(scale=MOVE / np.sqrt(3), size=base.shape))
        t = now()
        atoms.get_forces()
        ts.append(1e3 * (now() - t))
    atoms.set_positions(base)
    return ts


def run_md(atoms, dyn, p, clock):
    """Warm up ``dyn`` (ase-mlg: until its pair list was rebuilt once, so
    that every lazily loaded kernel of an MD step ran), then time it."""
    t = now()
    dyn.run(p["warm"])
    for _ in range(200):
        if list_builds(atoms) is None or list_builds(atoms)[0] >= 2:
            break
        dyn.run(1)
    warm_s = now() - t
    b0, m0 = list_builds(atoms), clock.mark(atoms.calc) if clock else None
    md_ms = time_md(dyn.run, p["steps"], p["repeats"])
    b1 = list_builds(atoms)
    nsteps = p["steps"] * p["repeats"]
    return {"md_ms": md_ms, "warm_s": warm_s, "builds": None if b0 is None else b1[0] - b0[0],
            "timed_steps": nsteps,
            "parts": step_parts(m0, clock.mark(atoms.calc), nsteps, md_ms) if clock else None}


def bench_python(atoms, calc, make_dyn, p, clock=False):
    """Force call and MD step of a Python-side calculator (ase-mlg, asap3, ASE)."""
    atoms = atoms.copy()
    atoms.calc = calc
    clock = CalcClock(calc) if clock else None
    t = now()
    epot0 = atoms.get_potential_energy() / len(atoms)
    first_call_s = now() - t
    calls = time_force_calls(atoms, p["calls"])
    r = run_md(atoms, make_dyn(atoms), p, clock)
    r.update(force_calls=calls, force_ms=float(np.median(calls)), epot0=epot0,
             warm_s=first_call_s + r["warm_s"])
    return r


def bench_ase_mlg(atoms, template, p):
    """ase-mlg under ASE's VelocityVerlet, then (a fresh calculator and copy
    of the atoms) under ase_mlg.md.VelocityVerlet where it is installed."""
    from ase.md.verlet import VelocityVerlet
    dt = DT_FS * units.fs
    calc = mlg_calc(template)
    r = bench_python(atoms, calc, lambda a: VelocityVerlet(a, dt), p, clock=True)
    r.update(threading_report(calc))
    own, why = own_verlet()
    r["own_error"] = why
    if own is not None:
        a = atoms.copy()
        a.calc = mlg_calc(template)
        clock = CalcClock(a.calc)
        a.get_forces()
        o = run_md(a, own(a, dt), p, clock)
        r.update(own_md_ms=o["md_ms"], own_parts=o["parts"], own_builds=o["builds"],
                 own_threads_used=a.calc.stats.get("threads_used"))
    return r


def bench_asap3(atoms, p):
    from asap3.md.verlet import VelocityVerlet  # asap3's compiled loop
    return bench_python(atoms, asap3_calc(), lambda a: VelocityVerlet(a, DT_FS * units.fs), p)


def bench_ase(atoms, p):
    from ase.md.verlet import VelocityVerlet
    q = dict(p, calls=min(p["calls"], 3), steps=min(p["steps"], 3),
             repeats=min(p["repeats"], 3), warm=1)
    return bench_python(atoms, ase_calc(), lambda a: VelocityVerlet(a, DT_FS * units.fs), q)


def memory_mlg(atoms, p):
    """Peak memory of ase-mlg through its first pair-list rebuild: one
    force call, then ASE's VelocityVerlet (``p["integrator"] == "own"``:
    ase_mlg.md's, as asap3 runs its own) until the list was built twice,
    then one step more on the rebuilt list."""
    if p.get("integrator") == "own":
        VelocityVerlet, why = own_verlet()
        if VelocityVerlet is None:
            raise ImportError(why)
    else:
        from ase.md.verlet import VelocityVerlet
    atoms.calc = mlg_calc(None)         # ase_mlg, numba and llvmlite imported
    before = maxrss_mb()
    atoms.get_forces()
    first = maxrss_mb()
    dyn = VelocityVerlet(atoms, DT_FS * units.fs)
    steps = 0
    while list_builds(atoms)[0] < 2 and steps < p["mem_max_steps"]:
        dyn.run(1)
        steps += 1
    dyn.run(1)
    return {"before_mb": before, "first_mb": first, "steps": steps + 1,
            "builds": list_builds(atoms)[0], **threading_report(atoms.calc)}


# ---------------------------------------------------------------- NVE / NPT

def liquid_argon(natoms, path, steps=400, seed=0):
    """An equilibrated argon liquid near 90 K and 1 bar, written to ``path``
    (an ASE .traj): fcc argon melted by ``steps`` NVE steps from 600 K, then
    ``steps`` Langevin steps at 90 K and ``steps`` isotropic MTK NPT steps
    at 90 K, 1 bar (the cell stays cubic), with asap3 if installed, else
    ase-mlg, so that the timed NPT run starts near equilibrium instead of
    from a hot, high-pressure configuration.  Runs in a worker, so that the
    lead process imports no engine (ase_mlg sets OMP_WAIT_POLICY)."""
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
    return {}


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
    if hasattr(a.calc, "stats"):
        out.update(threading_report(a.calc))
    return out
