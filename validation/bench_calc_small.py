"""Benchmark: one force call of small systems, ase-mlg against asap3 (issue 24).

LJ argon liquid (``ase_mlg.scenes.lj_liquid(n, rho=0.8, seed=1)``; sigma
3.405 Å, epsilon 0.0104 eV, rc 8.5 Å shifted to zero at rc in both, skin
1 Å) at 256 and 500 atoms.  A force call comes after every atom moved ~0.01
Å rms from the same start (the pair lists stay valid); the figure is the
median of ``--calls`` calls after a warm-up, µs, in each of ``--procs``
processes (run interleaved across the engines), then the median over the
processes (the range beside it).  Each engine and thread count runs in its
own subprocess (``NUMBA_NUM_THREADS`` = ``OMP_NUM_THREADS``
= k, ``OPENBLAS_NUM_THREADS`` = 1), so the two never share a process.  Each
worker also checks its energy and forces against ``ase_mlg.potentials.
LennardJones`` evaluated on ASE's neighbour list (relative difference).

``--profile`` adds, for ase-mlg, the phases of a call (µs, medians, from
one more process whose timers are not in the table): ``calculate``, the
list's check and gather (``VerletList.kept``), ``sum_pairs`` and the part
of it inside the kernel; the rest of a call is ASE's ``get_property``
around ``calculate`` and the calculator's ``check_state``.

    python validation/bench_calc_small.py
    python validation/bench_calc_small.py --profile --threads 1
"""

import argparse
import json
import os
import subprocess
import sys
import time

SIGMA, EPS, RC, MOVE = 3.405, 0.0104, 8.5, 0.01


def scene(n):
    from ase_mlg.scenes import lj_liquid
    return lj_liquid(n, rho=0.8, seed=1)


def make_calc(engine):
    if engine == "asap3":
        import asap3
        return asap3.LennardJones([18], [EPS], [SIGMA], rCut=RC, modified=True)
    from ase_mlg import MLGCalculator
    from ase_mlg.potentials import LennardJones
    return MLGCalculator(LennardJones(sigma=SIGMA, epsilon=EPS, rc=RC))


def reference(atoms):
    """Energy and forces of the same potential on ASE's neighbour list."""
    from ase.neighborlist import neighbor_list
    from ase_mlg.potentials import LennardJones
    i, j, D = neighbor_list("ijD", atoms, RC)
    keep = i < j  # the cell is wider than 2 rc: no atom meets its own image
    res = LennardJones(sigma=SIGMA, epsilon=EPS, rc=RC).evaluate(
        atoms.numbers, i[keep], j[keep], D[keep], per_atom_virials=False)
    return res["energy"], res["forces"]


def worker(engine, n, calls, profile):
    import numpy as np
    atoms = scene(n)
    calc = make_calc(engine)
    atoms.calc = calc
    t = time.perf_counter()
    atoms.get_forces()
    first_s = time.perf_counter() - t
    rng = np.random.default_rng(1)
    base = atoms.get_positions()
    moves = [base + rng.normal(scale=MOVE / np.sqrt(3), size=base.shape)
             for _ in range(calls + 20)]
    phases = {}
    if profile and engine == "mlg":
        phases = instrument(calc)
    ts = []
    for k, x in enumerate(moves):
        atoms.set_positions(x)
        t = time.perf_counter()
        atoms.get_forces()
        if k >= 20:
            ts.append(time.perf_counter() - t)
        for v in phases.values():
            if k < 20:
                v.clear()
    e = atoms.get_potential_energy()
    f = atoms.get_forces()
    e_ref, f_ref = reference(atoms)
    out = {"us": 1e6 * float(np.median(ts)), "first_s": first_s,
           "de": abs(e - e_ref) / abs(e_ref),
           "df": float(np.abs(f - f_ref).max() / np.abs(f_ref).max()),
           "phases": {k: 1e6 * float(np.median(v)) for k, v in phases.items() if v}}
    if engine == "mlg":
        out["builds"] = calc.stats["list_builds"]
    print(json.dumps(out))


def instrument(calc):
    """Wrap the phases of an MLGCalculator call with timers (lists of s)."""
    phases = {"calculate": [], "kept": [], "sum_pairs": [], "kernel": []}
    vl, pot = calc.verlet_list, calc.potential

    def timed(obj, name, key):
        inner = getattr(obj, name)

        def f(*a, **k):
            t = time.perf_counter()
            try:
                return inner(*a, **k)
            finally:
                phases[key].append(time.perf_counter() - t)
        setattr(obj, name, f)

    timed(calc, "calculate", "calculate")
    timed(vl, "kept", "kept")
    timed(pot, "sum_pairs", "sum_pairs")
    import ase_mlg.pairsum as ps
    form, entries = ps._BUILT_IN[pot.pair]
    ps._BUILT_IN[pot.pair] = (form, {general: tuple(_timed_kernel(k, phases["kernel"])
                                                    for k in twins)
                                     for general, twins in entries.items()})
    return phases


def _timed_kernel(kernel, sink):
    def f(*a):
        t = time.perf_counter()
        kernel(*a)
        sink.append(time.perf_counter() - t)
    return f


def run(engine, n, threads, calls, profile):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads),
               OPENBLAS_NUM_THREADS="1")
    p = subprocess.run([sys.executable, __file__, "--worker", f"{engine},{n},{calls},{int(profile)}"],
                       env=env, capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(p.stderr)
    return json.loads(p.stdout.strip().splitlines()[-1])


def pick(runs):
    """The run of the median time (its phases and checks with it)."""
    return sorted(runs, key=lambda r: r["us"])[len(runs) // 2]


def cell(runs):
    us = sorted(r["us"] for r in runs)
    return f"{pick(runs)['us']:.0f} ({us[0]:.0f}-{us[-1]:.0f})" if len(us) > 1 else f"{us[0]:.0f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="256,500")
    ap.add_argument("--threads", default=f"1,{os.cpu_count()}")
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--procs", type=int, default=3)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        engine, n, calls, profile = a.worker.split(",")
        return worker(engine, int(n), int(calls), bool(int(profile)))
    import ase_mlg
    print(f"ase_mlg from {os.path.dirname(ase_mlg.__file__)}; {a.procs} processes a figure, "
          f"{a.calls} calls each\n")
    print("| atoms | threads | ase-mlg µs | asap3 µs | ratio | rel. dE mlg/asap3 | "
          "rel. dF mlg/asap3 | first call s (mlg) |")
    print("|---|---|---|---|---|---|---|---|")
    profiles = []
    for n in map(int, a.sizes.split(",")):
        for k in map(int, a.threads.split(",")):
            ms, ss = [], []
            for _ in range(a.procs):
                ms.append(run("mlg", n, k, a.calls, False))
                ss.append(run("asap3", n, k, a.calls, False))
            m, s = pick(ms), pick(ss)
            if a.profile:
                m["phases"] = run("mlg", n, k, a.calls, True)["phases"]
            print(f"| {n} | {k} | {cell(ms)} | {cell(ss)} | {m['us'] / s['us']:.2f} | "
                  f"{m['de']:.1e} / {s['de']:.1e} | {m['df']:.1e} / {s['df']:.1e} | "
                  f"{m['first_s']:.2f} |")
            if m["phases"]:
                profiles.append((n, k, m["phases"]))
    for n, k, ph in profiles:
        print(f"\nase-mlg phases, {n} atoms, {k} threads (µs, medians): "
              + ", ".join(f"{key} {v:.0f}" for key, v in ph.items()))


if __name__ == "__main__":
    main()
