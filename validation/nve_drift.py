"""NVE energy drift: MLGCalculator (exact, W = 5, 7, 9) against ASE's LJ.

LJ argon liquid (sigma 3.405 Å, epsilon 0.0104 eV, rc 8.5 Å, rho* = 0.8,
500 atoms), started at 100 K, VelocityVerlet with a 10 fs step (0.0046 tau,
the usual 0.005 tau) for ``--steps`` steps from the same start for every
calculator.  Reports the total-energy drift per atom per ps (least-squares
slope), the largest deviation from the start, and the time per step.  Exact
mode must match ASE's run; template modes are reported.  Usage::

    python validation/nve_drift.py [--steps 10000] [--smooth]
"""

import argparse
import time

import numpy as np
from ase import units
from ase.calculators.lj import LennardJones as AseLJ
from ase.md.velocitydistribution import Stationary, thermalize_momenta
from ase.md.verlet import VelocityVerlet

from ase_mlg import MLGCalculator
from ase_mlg.potentials import LennardJones
from ase_mlg.scenes import lj_liquid

DT_FS = 10.0


def run(atoms0, calc, steps, every=10):
    atoms = atoms0.copy()
    atoms.calc = calc
    dyn = VelocityVerlet(atoms, DT_FS * units.fs)
    e = [atoms.get_total_energy()]
    t = time.perf_counter()
    for block in range(steps // every):
        try:
            dyn.run(every)
        except ValueError as err:
            # template misses let atoms run into each other: report, go on
            raise RuntimeError(f"unstable after ~{block * every} steps: {err}") from None
        e.append(atoms.get_total_energy())
    elapsed = time.perf_counter() - t
    e = (np.array(e) - e[0]) / len(atoms)
    t_ps = np.arange(len(e)) * every * DT_FS / 1000
    slope = np.polyfit(t_ps, e, 1)[0]
    return slope, np.abs(e).max(), elapsed / steps, atoms


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=10000)
    p.add_argument("--natoms", type=int, default=500)
    p.add_argument("--smooth", action="store_true", help="ASE's smooth LJ cutoff")
    p.add_argument("--skip-ase", action="store_true")
    p.add_argument("--widths", default="5,7,9", help="template widths to run")
    args = p.parse_args(argv)
    params = dict(sigma=3.405, epsilon=0.0104, rc=8.5, smooth=args.smooth)
    atoms = lj_liquid(args.natoms, rho=0.8, seed=7)
    thermalize_momenta(atoms, temperature_K=100, rng=np.random.default_rng(7))
    Stationary(atoms)
    runs = {}
    if not args.skip_ase:
        runs["ase LennardJones"] = AseLJ(**params)
    runs["mlg exact"] = MLGCalculator(LennardJones(**params), skin=1.0)
    for w in [int(x) for x in args.widths.split(",") if x]:
        runs[f"mlg W={w}"] = MLGCalculator(LennardJones(**params), template=w, skin=1.0)
    print(f"NVE LJ argon, {len(atoms)} atoms, {args.steps} steps of {DT_FS} fs "
          f"({args.steps * DT_FS / 1000:.0f} ps), smooth={args.smooth}")
    print(f"{'calculator':>18} {'drift eV/atom/ps':>17} {'max |dE| eV/atom':>17} "
          f"{'ms/step':>8} {'T_end K':>8}")
    for name, calc in runs.items():
        try:
            slope, dmax, t, end = run(atoms, calc, args.steps)
        except RuntimeError as err:
            print(f"{name:>18} {str(err)}")
            continue
        print(f"{name:>18} {slope:+17.2e} {dmax:17.2e} {t * 1e3:8.2f} "
              f"{end.get_temperature():8.1f}")


if __name__ == "__main__":
    main()
