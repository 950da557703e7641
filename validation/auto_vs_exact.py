"""template="auto" against exact mode and the narrowest passing template,
on the scenes of docs/design.md §9 (issue 18.3).

    python validation/auto_vs_exact.py [--natoms 4000] [--steps 20] [--repeats 3]

Per scene, three calculators on copies of the same atoms: exact mode
(``template=None``), ``template="auto"`` (default tolerance, missed <= 1e-4;
it runs the fastest mode meeting it) and ``AutoTemplate(select=
"narrowest")`` (the narrowest passing width whatever it costs: what "auto"
did before).  Printed: what auto chose and why, the list builds it timed at
its first check (ms), the first force call of each calculator (grid, check,
list build and pair sum: ms) and the median MD step (``VelocityVerlet``,
5 fs argon / 2 fs Cu-like from 100 / 300 K, skin 1 Å) over ``--repeats``
blocks of ``--steps`` steps, the blocks of the three modes interleaved so
that background load hits all alike.  Wall clock; numba's default threads.
"""

import argparse
import time

import numpy as np
from ase.md.velocitydistribution import thermalize_momenta
from ase.md.verlet import VelocityVerlet
from ase import units

from ase_mlg import MLGCalculator
from ase_mlg.autotemplate import AutoTemplate
from ase_mlg.scenes import make_scene

from make_tradeoff import potential  # the trade-off report's potentials per scene

KIND = {"liquid": "argon", "gas": "argon", "mixture": "mixture", "copper": "cu",
        "sheared": "cu", "slab": "cu", "nanoparticle": "cu", "small": "cu"}


def modes():
    return {"exact": lambda: None, "auto": lambda: "auto",
            "narrowest": lambda: AutoTemplate(select="narrowest")}


def run_scene(name, natoms, steps, repeats):
    kind = KIND[name]
    pot = potential(kind)
    base = make_scene(name, natoms)
    temp, dt = (100.0, 5.0) if kind != "cu" else (300.0, 2.0)
    thermalize_momenta(base, temperature_K=temp, rng=np.random.default_rng(0))
    runs, first = {}, {}
    for mode, template in modes().items():
        atoms = base.copy()
        atoms.calc = MLGCalculator(pot, template=template())
        t0 = time.perf_counter()
        atoms.get_forces()
        first[mode] = time.perf_counter() - t0
        runs[mode] = (atoms, VelocityVerlet(atoms, timestep=dt * units.fs), [])
    for _ in range(repeats):
        for mode, (atoms, md, times) in runs.items():
            t0 = time.perf_counter()
            md.run(steps)
            times.append((time.perf_counter() - t0) / steps)
    auto = runs["auto"][0].calc.auto
    rec = auto.history[0]
    narrow = runs["narrowest"][0].calc.auto.history[-1]["width"]
    secs = ", ".join(f"{k}: {1e3 * v:.1f}" for k, v in rec["seconds"].items())
    step = {m: 1e3 * float(np.median(t)) for m, (_, _, t) in runs.items()}
    print(f"{name:12s} N={len(base):5d}  auto -> "
          f"{'exact' if rec['width'] is None else 'W=%d' % rec['width']} "
          f"({rec['why']}; narrowest passing W={rec['candidate']}); "
          f"timed at check [ms] {secs}")
    print(f"{'':12s} first call [ms] exact {1e3 * first['exact']:.1f}, auto "
          f"{1e3 * first['auto']:.1f}, W={narrow} {1e3 * first['narrowest']:.1f}; "
          f"MD step [ms] exact {step['exact']:.2f}, auto {step['auto']:.2f} "
          f"({step['auto'] / step['exact']:.2f}x), W={narrow} "
          f"{step['narrowest']:.2f} ({step['narrowest'] / step['exact']:.2f}x); "
          f"auto checks {len(auto.history)}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--natoms", type=int, default=4000)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scenes", default=",".join(KIND))
    args = ap.parse_args(argv)
    # warm every kernel once so that no mode pays compilation in its timings
    run_scene("liquid", 500, 2, 1)
    run_scene("mixture", 500, 2, 1)
    print("-- measured --")
    for name in args.scenes.split(","):
        run_scene(name, args.natoms, args.steps, args.repeats)


if __name__ == "__main__":
    main()
