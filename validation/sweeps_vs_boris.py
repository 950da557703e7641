"""Mean swap sweeps per step against Boris 1985, Fig. 3.4.

Boris's test problem (sec. III): 512 point particles on an 8x8x8 MLG,
periodic in x and y, reflecting walls in z at 0 and 8 spacings, started on a
regular lattice with velocity components uniform in [-v, v], free flight.
The fastest particle moves dl_max = 0.025, 0.1 or 0.4 spacings per step; he
reports 2.85 / 4.0 / 5.0 swapping iterations per step on average.

We run the same problem (dl_max read as the largest per-component
displacement, v * dt) and count, per step, the sweeps that swapped
(``MLG.update(...)["sweeps"]``) and, as the alternative convention, that plus
the final sweep that confirms order.  Usage::

    python validation/sweeps_vs_boris.py [--steps 2000] [--seeds 3]
"""

import argparse

import numpy as np

from ase_mlg import MLG

BORIS = {0.025: 2.85, 0.1: 4.0, 0.4: 5.0}


def simulate(dl_max, steps, seed, n=8, hole_plane=False):
    """Boris's free-flight test, one step at a time.

    Yields ``(positions, grid, record)`` after every step: positions in units
    of the initial spacing (unwrapped in x and y), the MLG that followed
    them, and its ``update`` record.  ``hole_plane=True`` adds a ninth plane
    of n^2 holes, as in Boris's second Fig. 4.1 run (his holes move to the
    mean of their six logical neighbours; ours keep their coordinates and
    are only moved by swaps).
    """
    rng = np.random.default_rng(seed)
    spacing = 1.0
    L = n * spacing
    grid_pts = (np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1)
                .reshape(-1, 3) + 0.5) * spacing
    x = grid_pts.copy()
    v = rng.uniform(-1, 1, x.shape) * dl_max * spacing
    shape = (n, n, n + 1) if hole_plane else (n, n, n)
    grid = MLG(x, [L, L, L], (True, True, False), shape=shape)
    for _ in range(steps):
        x = x + v
        # reflecting walls in z
        low, high = x[:, 2] < 0, x[:, 2] > L
        x[low, 2] *= -1
        x[high, 2] = 2 * L - x[high, 2]
        v[low | high, 2] *= -1
        rec = grid.update(x)
        yield x, grid, rec


def run(dl_max, steps, seed, n=8):
    """Sweeps per step of one run, and the number of grid rebuilds."""
    sweeps, grid = [], None
    for _, grid, rec in simulate(dl_max, steps, seed, n):
        sweeps.append(rec["sweeps"])
    return np.array(sweeps), grid.stats["rebuilds"] if grid else 0


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--seeds", type=int, default=3)
    args = p.parse_args(argv)
    print(f"Boris 1985 Fig. 3.4 test: 512 particles, 8x8x8, pbc=(T,T,F), "
          f"{args.steps} steps x {args.seeds} seeds")
    print(f"{'dl_max':>8} {'Boris':>6} {'ours':>6} {'ours+1':>7} {'ratio':>6} "
          f"{'ratio+1':>7} {'rebuilds':>8}  distribution of sweeps (0..8+)")
    for dl, ref in BORIS.items():
        runs = [run(dl, args.steps, seed) for seed in range(args.seeds)]
        s = np.concatenate([r[0] for r in runs])
        rebuilds = sum(r[1] for r in runs)
        hist = np.bincount(np.minimum(s, 8), minlength=9) / len(s)
        print(f"{dl:8.3f} {ref:6.2f} {s.mean():6.2f} {s.mean() + 1:7.2f} "
              f"{s.mean() / ref:6.2f} {(s.mean() + 1) / ref:7.2f}  "
              + " ".join(f"{h:.2f}" for h in hist))


if __name__ == "__main__":
    main()
