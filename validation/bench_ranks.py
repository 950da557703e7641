"""MD across MPI ranks: ase-mlg against LAMMPS at equal ranks (issue 23.6).

    python validation/bench_ranks.py                  # 108,000 atoms
    python validation/bench_ranks.py --sizes 10976,108000,1048576 --procs 2

The scene is bench_md's: fcc argon at 90 K (a = 5.72 Å), LJ rc 8.5 Å,
skin 1 Å, 5 fs NVE.  Each figure is a fresh ``mpiexec -n P`` launch (1
thread a rank: ``NUMBA_NUM_THREADS=1``, ``OMP_NUM_THREADS=1``), repeated
``--procs`` times and interleaved; a launch warms up (numba's cache load,
the first list), then times ``--steps`` steps as one block of
``dyn.run`` (ase-mlg, ``ase_mlg.md.VelocityVerlet`` on
``ase_mlg.distribute(atoms)``) or ``run N pre no post no`` (LAMMPS
``lj/cut``, ``neighbor 1.0 bin``, ``neigh_modify every 1 delay 0 check
yes``), then the breakdown: ase-mlg's engine timings per step (halo
exchange, rebuilds = partition + migration + ghost lists, the local list,
the pair sum; the integrator and ASE the rest) beside LAMMPS's own
Pair/Neigh/Comm/Modify/Other from a second, untimed run.  On one rank
ase-mlg's script takes the serial calculator's path (since session 24: no
ghosts nor partition there), so its 1 -> 2 ranks scaling is against the
serial code, as LAMMPS's is against its own one rank.  Peak RSS is the
largest rank's.  ``OPENBLAS_NUM_THREADS`` is left as the user has it (a
user launching ``mpiexec`` does not set it; until session 22 this script set
it to 1, which hid 136 ms a BLAS product took in each rank's rebuild).  Also ase-mlg at 1 rank x 2 threads.  Medians over
launches; spread = max / min.
"""

import argparse
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from bench_common import cpu_model  # noqa: E402 (after the path)


def worker_mlg(natoms, steps, warm):
    from bench_common import fcc_argon, maxrss_mb, now

    from ase import units
    from ase_mlg import MLGCalculator, distribute
    from ase_mlg.md import VelocityVerlet
    from ase_mlg.parallel import config
    from ase_mlg.potentials import LennardJones

    atoms = distribute(fcc_argon(natoms))
    comm = atoms.comm
    atoms.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5), skin=1.0)
    dyn = VelocityVerlet(atoms, 5 * units.fs)
    dyn.run(warm)
    calc = atoms.calc
    one = comm.size == 1  # one rank takes the serial calculator's path: its own timings

    def timings():
        if one:
            t = calc.timings
            return {"check": t["check"], "list": t["list_build"], "kernel": t["kernel"]}
        return dict(calc._ranks.timings)

    def counts():
        if one:
            return {"rebuilds": calc.verlet_list.stats["list_builds"], "migrated": 0, "ghosts": 0}
        return dict(calc._ranks.counts)

    t0, c0 = timings(), counts()
    comm.Barrier()
    t = now()
    dyn.run(steps)
    comm.Barrier()
    wall = now() - t
    t1, c1 = timings(), counts()
    parts = {k: 1e3 * (t1[k] - t0[k]) / steps for k in t0}
    step_ms = 1e3 * wall / steps
    parts["integrator+ASE"] = step_ms - sum(parts.values())
    mem = comm.allgather(maxrss_mb())
    ghosts = comm.allgather(c1["ghosts"])
    owned = comm.allgather(len(atoms))
    pairs = comm.allgather(len((calc.verlet_list if one else calc._ranks.vl).pairs))
    if comm.rank == 0:
        cfg = config()
        print(json.dumps({"step_ms": step_ms, "parts": parts, "mem_mb": max(mem),
                          "rebuilds": c1["rebuilds"] - c0["rebuilds"],
                          "migrated": c1["migrated"] - c0["migrated"],
                          "ghosts": max(ghosts), "owned": [min(owned), max(owned)],
                          "pairs": max(pairs), "natoms": natoms,
                          "layer": cfg.get("threading_layer"), "threads": cfg.get("threads")}))


def worker_lammps(natoms, steps, warm, tmp):
    from bench_common import fcc_argon, maxrss_mb, now
    from bench_lammps import lammps_breakdown, lammps_start
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    log = os.path.join(tmp, f"lammps_{os.getpid()}.log")
    log = comm.bcast(log, root=0)
    lmp = lammps_start(fcc_argon(natoms), 1, "nve", log)
    lmp.command(f"run {warm}")
    comm.Barrier()
    t = now()
    lmp.command(f"run {steps} pre no post no")
    comm.Barrier()
    wall = now() - t
    lmp.command("run 0 pre no post yes")  # the running count of list builds
    lmp.command(f"run {steps} pre no post yes")
    mem = comm.allgather(maxrss_mb())
    lmp.close()
    if comm.rank == 0:
        with open(log) as f:
            parts = lammps_breakdown(f.read())
        print(json.dumps({"step_ms": 1e3 * wall / steps, "parts": parts, "mem_mb": max(mem)}))


def launch(tool, nranks, threads, natoms, steps, warm, tmp):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads),
               PYTHONWARNINGS="ignore")
    mpiexec = os.path.join(os.path.dirname(sys.executable), "mpiexec")
    cmd = [mpiexec, "-n", str(nranks), sys.executable, __file__, "--worker", tool,
           "--atoms", str(natoms), "--steps", str(steps), "--warm", str(warm), "--tmp", tmp]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3000)
    lines = [line for line in out.stdout.splitlines() if line.startswith("{")]
    if out.returncode or not lines:
        return {"error": (out.stderr or out.stdout)[-400:]}
    return json.loads(lines[-1])


def med(rs, key):
    xs = [r[key] for r in rs if "error" not in r]
    return (float(np.median(xs)), max(xs) / min(xs)) if xs else (np.nan, np.nan)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="108000")
    ap.add_argument("--procs", type=int, default=2)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--warm", type=int, default=20)
    ap.add_argument("--worker")
    ap.add_argument("--atoms", type=int)
    ap.add_argument("--tmp", default="/tmp")
    ap.add_argument("--json", help="also write every launch's raw results here "
                    "(validation/ranks_projection.py reads it)")
    a = ap.parse_args()
    if a.worker == "mlg":
        return worker_mlg(a.atoms, a.steps, a.warm)
    if a.worker == "lammps":
        return worker_lammps(a.atoms, a.steps, a.warm, a.tmp)
    from bench_common import fcc_argon_size
    print(f"# MD across ranks, {cpu_model()}, {os.cpu_count()} cores; ms per 5 fs NVE step, "
          f"{a.steps} steps after {a.warm}, median of {a.procs} launches (spread max/min)")
    configs = [("lammps", 1, 1), ("lammps", 2, 1), ("mlg", 1, 1), ("mlg", 2, 1), ("mlg", 1, 2)]
    raw = {}
    for size in (int(s) for s in a.sizes.split(",")):
        n = fcc_argon_size(size)
        res = {c: [] for c in configs}
        for _ in range(a.procs):
            for c in configs:  # interleaved: drifts of the machine hit all alike
                res[c].append(launch(c[0], c[1], c[2], n, a.steps, a.warm, a.tmp))
        raw[n] = {f"{c[0]} {c[1]}x{c[2]}": res[c] for c in configs}
        print(f"\n## {n:,} atoms\n")
        print("| engine | ranks x threads | ms/step | spread | peak MB (largest rank) | breakdown ms/step |")
        print("|---|---|---|---|---|---|")
        for c in configs:
            ok = [r for r in res[c] if "error" not in r]
            if not ok:
                print(f"| {c[0]} | {c[1]} x {c[2]} | error: {res[c][0]['error'][-200:]!r} | | | |")
                continue
            ms, sp = med(ok, "step_ms")
            mem = float(np.median([r["mem_mb"] for r in ok]))
            parts = ok[0]["parts"] or {}
            brk = ", ".join(f"{k} {v:.2f}" for k, v in parts.items()
                            if isinstance(v, float) and k not in ("loop_ms",))
            extra = ""
            if c[0] == "mlg":
                extra = (f"; rebuilds {ok[0]['rebuilds']}, migrated {ok[0]['migrated']}, "
                         f"ghosts/rank {ok[0]['ghosts']}, layer {ok[0]['layer']}")
            print(f"| {'ase-mlg' if c[0] == 'mlg' else 'LAMMPS lj/cut'} | {c[1]} x {c[2]} | "
                  f"{ms:.2f} | {sp:.2f} | {mem:.0f} | {brk}{extra} |")
        l1, l2 = med(res[("lammps", 1, 1)], "step_ms")[0], med(res[("lammps", 2, 1)], "step_ms")[0]
        m1, m2 = med(res[("mlg", 1, 1)], "step_ms")[0], med(res[("mlg", 2, 1)], "step_ms")[0]
        mt = med(res[("mlg", 1, 2)], "step_ms")[0]
        print(f"\nase-mlg / LAMMPS at 2 ranks: {m2 / l2:.2f}x; 1 -> 2 ranks scaling: ase-mlg "
              f"{m1 / m2:.2f}x, LAMMPS {l1 / l2:.2f}x; ase-mlg 2 ranks x 1 thread against "
              f"1 rank x 2 threads: {m2 / mt:.2f}x the time")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"cpu": cpu_model(), "steps": a.steps, "results": raw}, f, indent=1)


if __name__ == "__main__":
    main()
