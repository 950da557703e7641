"""Do sweeps per step and template quality stay flat over a long periodic run?

docs/design.md §5: on a periodic axis each line's window can wander as atoms
circulate, and lines out of register lose template quality.  The grid keeps
stored coordinates continuous across faces (seam swaps, no jumps) and a phase
monitor rebuilds when adjacent lines are more than ``max_phase_lag`` spacings
out of register (see ase_mlg/grid.py).  This script runs a random liquid at
0.8 sigma^-3 (sigma = 1) with velocity-persistent random-walk motion
(unwrapped: atoms cross the periodic faces) and prints, per window of steps,
the mean sweeps per step, the share of true pairs (rc = 2.5 sigma) inside
the 7x7x7 template, the phase lag and the rebuilds; then the linear trend of
sweeps and share per 1000 steps.  ``--no-monitor`` switches the remedy off to
show what it buys.  Usage::

    python validation/periodic_drift.py [--natoms 4000] [--steps 2000]
        [--step-rms 0.05] [--no-monitor]
"""

import argparse

import numpy as np
from scipy.spatial import cKDTree

from ase_mlg import MLG
from ase_mlg.template import template_pairs
from ase_mlg.scenes import PersistentWalk, random_points


def share(grid, L, rc=2.5, width=7):
    x = grid.positions % L
    true = len(cKDTree(x, boxsize=L).query_pairs(rc))
    return len(template_pairs(grid, width, rc)[0]) / true


def run(natoms, steps, step_rms, monitor=True, every=50, seed=0):
    atoms = random_points(natoms, 0.8, seed=seed)
    L = atoms.cell[0, 0]
    spacing = 0.8 ** (-1 / 3)
    kw = {} if monitor else {"max_phase_lag": np.inf}
    grid = MLG.from_atoms(atoms, **kw)
    walk = PersistentWalk(atoms.positions, step_rms * spacing, seed=seed)
    rows = []
    sweeps = []
    for step in range(1, steps + 1):
        rec = grid.update(walk.step())
        sweeps.append(rec["sweeps"])
        if step % every == 0:
            rows.append((step, np.mean(sweeps[-every:]), share(grid, L),
                         grid.phase_lag(), grid.stats["rebuilds"]))
    travelled = np.sqrt(np.mean(np.sum((walk.positions - atoms.positions) ** 2, 1)))
    return np.array(rows), np.array(sweeps), travelled / spacing, L / spacing


def trend(t, y):
    """Least-squares slope per 1000 steps and its standard error."""
    A = np.vstack([t, np.ones_like(t)]).T
    coef, res, *_ = np.linalg.lstsq(A, y, rcond=None)
    dof = max(len(t) - 2, 1)
    s2 = (res[0] if len(res) else 0.0) / dof
    se = np.sqrt(s2 / np.sum((t - t.mean()) ** 2))
    return 1000 * coef[0], 1000 * se


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--natoms", type=int, default=4000)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--step-rms", type=float, default=0.05,
                   help="rms displacement per step, in mean spacings")
    p.add_argument("--no-monitor", action="store_true")
    args = p.parse_args(argv)
    rows, sweeps, travelled, box = run(args.natoms, args.steps, args.step_rms,
                                       monitor=not args.no_monitor)
    print(f"random liquid N={args.natoms}, box {box:.1f} spacings, "
          f"{args.steps} steps of {args.step_rms} spacings rms; atoms travelled "
          f"{travelled:.1f} spacings rms; monitor {'off' if args.no_monitor else 'on'}")
    print(f"{'step':>6} {'sweeps/step':>11} {'share W=7':>9} {'phase lag':>9} {'rebuilds':>8}")
    for r in rows:
        print(f"{int(r[0]):6d} {r[1]:11.2f} {r[2]:9.4f} {r[3]:9.2f} {int(r[4]):8d}")
    t = np.arange(1, len(sweeps) + 1, dtype=float)
    s, se = trend(t, sweeps.astype(float))
    q, qe = trend(rows[:, 0], rows[:, 2])
    print(f"trend per 1000 steps: sweeps {s:+.3f} +- {se:.3f}, "
          f"share {q:+.4f} +- {qe:.4f}")


if __name__ == "__main__":
    main()
