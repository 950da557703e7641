"""ASE's VelocityVerlet against ase_mlg.md.VelocityVerlet, and where the step goes.

One process, one fcc argon scene (that of ``validation/bench_md.py``:
LJ argon, sigma 3.405 Å, epsilon 0.0104 eV, rc 8.5 Å,
MLGCalculator skin 1 Å, 90 K, shuffled indices, 5 fs steps).  Both
integrators run the same atoms alternately (A, B, A, B, ... blocks of
``--steps`` steps), so that a busy machine's load falls on both alike.
With ``--langevin``, ASE's and ase-mlg's Langevin join the rotation.  Each block's time is split into the calculator's ``calculate`` (timed by
wrapping it) and the rest: the integrator, ASE's copies and checks, and
the observers.

Usage::

    python validation/bench_md_loop.py                       # 10,976 atoms
    python validation/bench_md_loop.py --langevin              # + Langevin
    python validation/bench_md_loop.py --natoms 108000 --blocks 6
"""

import argparse
import os
import time

import numpy as np
from ase import units
from ase.build import bulk
from ase.md.velocitydistribution import Stationary, thermalize_momenta
from ase.md.langevin import Langevin as ASELangevin
from ase.md.verlet import VelocityVerlet as ASEVelocityVerlet

import ase_mlg
from ase_mlg.md import Langevin, VelocityVerlet
from ase_mlg.potentials import LennardJones


def fcc_argon(natoms, seed=0):
    """validation/bench_md.py's scene: fcc argon (a = 5.72 Å, 4 m^3 atoms
    near ``natoms``) rattled by 0.05 Å, 90 K momenta, indices shuffled."""
    m = max(1, int(round((natoms / 4) ** (1 / 3))))
    atoms = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(m)
    rng = np.random.default_rng(seed)
    atoms.positions += rng.normal(scale=0.05, size=atoms.positions.shape)
    atoms.wrap()
    thermalize_momenta(atoms, temperature_K=90.0, rng=rng)
    Stationary(atoms)
    return atoms[rng.permutation(len(atoms))]


class _Timed:
    """Wraps ``calc.calculate`` and adds its wall time (s) to ``self.s``."""

    def __init__(self, calc):
        self.s = 0.0
        self.calls = 0
        inner = calc.calculate

        def calculate(*args, **kwargs):
            t = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.s += time.perf_counter() - t
                self.calls += 1
        calc.calculate = calculate


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--natoms", type=int, default=10976)
    ap.add_argument("--steps", type=int, default=20, help="steps per block")
    ap.add_argument("--blocks", type=int, default=10, help="blocks per integrator")
    ap.add_argument("--langevin", action="store_true",
                    help="ASE's Langevin and ase_mlg.md.Langevin too (fixcm=False)")
    args = ap.parse_args(argv)

    atoms = fcc_argon(args.natoms)
    atoms.calc = ase_mlg.MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5),
                                       skin=1.0)
    timer = _Timed(atoms.calc)
    dt = 5 * units.fs
    dyns = {"ASE VelocityVerlet": ASEVelocityVerlet(atoms, dt),
            "ase_mlg.md.VelocityVerlet": VelocityVerlet(atoms, dt)}
    if args.langevin:
        kw = dict(temperature_K=90.0, friction=0.01 / units.fs, fixcm=False)
        dyns["ASE Langevin"] = ASELangevin(atoms, dt, rng=np.random.default_rng(1), **kw)
        dyns["ase_mlg.md.Langevin"] = Langevin(atoms, dt, rng=np.random.default_rng(1), **kw)
    for dyn in dyns.values():          # JIT, first list build, warm caches
        dyn.run(args.steps)
    rec = {k: {"total": [], "calc": []} for k in dyns}
    for _ in range(args.blocks):
        for name, dyn in dyns.items():
            c0, t = timer.s, time.perf_counter()
            dyn.run(args.steps)
            rec[name]["total"].append((time.perf_counter() - t) / args.steps)
            rec[name]["calc"].append((timer.s - c0) / args.steps)
    print(f"{len(atoms):,} atoms, {args.blocks} interleaved blocks of {args.steps} steps, "
          f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'default')}, "
          f"list builds {atoms.calc.stats['list_builds']}")
    print("| integrator | ms/step (median of blocks) | min | calculator ms | rest ms |")
    print("|---|---|---|---|---|")
    for name, r in rec.items():
        tot, calc = 1e3 * np.array(r["total"]), 1e3 * np.array(r["calc"])
        print(f"| {name} | {np.median(tot):.2f} | {tot.min():.2f} | {np.median(calc):.2f} "
              f"| {np.median(tot - calc):.2f} |")


if __name__ == "__main__":
    main()
