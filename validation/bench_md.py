"""Time per MD step (VelocityVerlet, LJ argon liquid) against the peers.

Side by side in one run, on the same atoms: ASE's ``LennardJones``, asap3's
``LennardJones`` (if installed: ``pip install asap3``), a "vesin list rebuilt
every step + the package's numba pair kernel" baseline, and ``MLGCalculator``
exact (Verlet skin 0.3 Å, the default, and 1.0 Å) and template W = 7
(skin 1.0 Å).  LJ argon: sigma 3.405 Å, epsilon 0.0104 eV, rc 8.5 Å,
rho* = 0.8, 100 K, 5 fs.  Each tool runs ``--warm`` steps first (JIT warm-up
and list building, reported separately), then the median over ``--repeats``
blocks of ``--steps`` steps.  ASE is run only up to 11k atoms.  Prints times
and ratios to asap3 (or to vesin when asap3 is missing).  Usage::

    python validation/bench_md.py [--sizes 864,10976,108000] [--large]
"""

import argparse
import time

import numpy as np
from ase import units
from ase.calculators.calculator import Calculator, all_changes
from ase.calculators.lj import LennardJones as AseLJ
from ase.md.velocitydistribution import Stationary, thermalize_momenta
from ase.md.verlet import VelocityVerlet

from ase_mlg import MLGCalculator
from ase_mlg.potentials import LennardJones
from ase_mlg.scenes import lj_liquid

SIGMA, EPS, RC = 3.405, 0.0104, 8.5


class VesinNumba(Calculator):
    """Baseline: vesin half list every call + ase_mlg's generic pair kernel."""

    implemented_properties = ["energy", "forces", "stress"]

    def __init__(self):
        super().__init__()
        import vesin
        self.nl = vesin.NeighborList(cutoff=RC, full_list=False)
        self.pot = LennardJones(sigma=SIGMA, epsilon=EPS, rc=RC)

    def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        a = self.atoms
        i, j, D = self.nl.compute(a.positions, a.cell.array, True, quantities="ijD")
        r = self.pot.evaluate(a.numbers, i, j, D)
        self.results = {"energy": r["energy"], "forces": r["forces"],
                        "stress": -r["virial"].reshape(9)[[0, 4, 8, 5, 2, 1]] / a.get_volume()}


def tools(n):
    pot = LennardJones(sigma=SIGMA, epsilon=EPS, rc=RC)
    out = {}
    if n <= 12000:
        out["ase"] = lambda: AseLJ(sigma=SIGMA, epsilon=EPS, rc=RC)
    try:
        import asap3
        out["asap3"] = lambda: asap3.LennardJones([18], [EPS], [SIGMA], rCut=RC, modified=True)
    except ImportError:
        pass
    try:
        import vesin  # noqa: F401
        out["vesin+numba"] = VesinNumba
    except ImportError:
        pass
    out["mlg exact skin0.3"] = lambda: MLGCalculator(pot, skin=0.3)
    out["mlg exact skin1.0"] = lambda: MLGCalculator(pot, skin=1.0)
    out["mlg W=7 skin1.0"] = lambda: MLGCalculator(pot, template=7, skin=1.0)
    return out


def bench(atoms0, make, warm, steps, repeats):
    atoms = atoms0.copy()
    atoms.calc = make()
    dyn = VelocityVerlet(atoms, 5 * units.fs)
    t = time.perf_counter()
    dyn.run(warm)
    # the MLG calculators load kernels lazily on the first grid update and
    # list rebuild: keep stepping until both happened, so that JIT warm-up
    # stays out of the timing (and is reported)
    stats = getattr(atoms.calc, "stats", None)
    while stats is not None and stats["list_builds"] < 2:
        dyn.run(1)
    t_warm = time.perf_counter() - t
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        dyn.run(steps)
        ts.append((time.perf_counter() - t) / steps)
    return float(np.median(ts)), t_warm, atoms.get_total_energy()


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="864,10976,108000")
    p.add_argument("--large", action="store_true", help="add 1,048,576 atoms")
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--warm", type=int, default=3)
    args = p.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")] + ([1048576] if args.large else [])
    import numba
    print(f"LJ argon liquid MD step (VelocityVerlet 5 fs), numba threads "
          f"{numba.get_num_threads()}, median of {args.repeats} x {args.steps} steps")
    for n in sizes:
        atoms = lj_liquid(n, rho=0.8, seed=1)
        thermalize_momenta(atoms, temperature_K=100, rng=np.random.default_rng(1))
        Stationary(atoms)
        rows = {}
        for name, make in tools(n).items():
            steps = 2 if name == "ase" else args.steps
            reps = 3 if name == "ase" else args.repeats
            rows[name] = bench(atoms, make, args.warm if name != "ase" else 1, steps, reps)
        ref = "asap3" if "asap3" in rows else "vesin+numba"
        print(f"\nN = {len(atoms)}")
        print(f"{'tool':>20} {'ms/step':>10} {'warm-up s':>10} {'/ ' + ref:>12} "
              f"{'ase /':>8}")
        for name, (t, tw, e) in rows.items():
            ase_ratio = f"{rows['ase'][0] / t:8.1f}" if "ase" in rows else f"{'-':>8}"
            print(f"{name:>20} {t * 1e3:10.2f} {tw:10.2f} {t / rows[ref][0]:12.2f} "
                  f"{ase_ratio}")


if __name__ == "__main__":
    main()
