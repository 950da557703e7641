"""The ``ase-mlg`` command line.

``ase-mlg demo`` runs the package end to end on an embedded LJ argon liquid.
Errors in user input print one line and exit with status 2.
"""

import argparse
import sys
import time

import numpy as np

__all__ = ["main", "demo"]


def _exact_pairs(atoms, rc):
    """Unordered pairs (i < j) within rc, by an independent method (a k-d
    tree on the wrapped periodic cube), to judge the template against."""
    from scipy.spatial import cKDTree
    L = atoms.cell[0, 0]
    return cKDTree(atoms.get_positions(wrap=True) % L, boxsize=L).query_pairs(rc)


def demo(natoms=4000, steps=500, seed=0, out=sys.stdout):
    """Build the MLG of an argon liquid, move the atoms, report sweeps and
    template quality.

    Parameters
    ----------
    natoms : int
        Approximate number of atoms (fcc lattice, 4 m^3).
    steps : int
        Steps of liquid-like motion (velocity-persistent random walk of
        0.02 mean spacings rms per step, unwrapped across periodic faces).
    """
    from tqdm import tqdm

    from .grid import MLG, template_pairs
    from .scenes import SIGMA_AR, PersistentWalk, lj_liquid

    def say(*a):
        print(*a, file=out, flush=True)

    atoms = lj_liquid(natoms, rho=0.8, seed=seed)
    rc = 2.5 * SIGMA_AR
    spacing = (atoms.get_volume() / len(atoms)) ** (1 / 3)
    say(f"ase-mlg demo: LJ argon liquid, {len(atoms)} atoms, rho* = 0.8, "
        f"box {atoms.cell[0, 0]:.2f} Å, rc = 2.5 sigma = {rc:.3f} Å")
    t0 = time.perf_counter()
    grid = MLG.from_atoms(atoms)
    say(f"grid {grid.shape} ({grid.nholes} holes), built in "
        f"{1e3 * (time.perf_counter() - t0):.1f} ms (includes loading compiled kernels)")
    walk = PersistentWalk(atoms.positions, 0.02 * spacing, seed=seed)
    sweeps = []
    t0 = time.perf_counter()
    for _ in tqdm(range(steps), desc="moving atoms", unit="step", file=out,
                  mininterval=0.5):
        sweeps.append(grid.update(walk.step())["sweeps"])
    dt = time.perf_counter() - t0
    sweeps = np.array(sweeps)
    st = grid.stats
    say(f"{steps} updates: {sweeps.mean():.2f} sweeps/step (min {sweeps.min()}, "
        f"max {sweeps.max()}), {st['swaps'] / steps:.1f} swaps/step, "
        f"{st['rebuilds']} rebuilds, {1e6 * dt / steps / len(atoms):.3f} µs/atom/step "
        f"(incl. the random walk); monotone: {grid.is_monotone()}")
    atoms.positions = walk.positions
    true = len(_exact_pairs(atoms, rc))
    say(f"template quality after the run (share of the {true} true pairs "
        "within rc found in the W^3 half template):")
    for w in (3, 5, 7, 9):
        found = len(template_pairs(grid, w, rc)[0])
        say(f"  W = {w}: {found / true:.4f}")
    return grid


def _positive_int(s):
    v = int(s)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def main(argv=None):
    parser = argparse.ArgumentParser(prog="ase-mlg", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="run the package end to end on an embedded argon liquid")
    p.add_argument("--natoms", type=_positive_int, default=4000)
    p.add_argument("--steps", type=_positive_int, default=500)
    p.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    try:
        if args.command == "demo":
            demo(args.natoms, args.steps, args.seed)
    except (ValueError, TypeError, OSError) as exc:
        print(f"ase-mlg {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
