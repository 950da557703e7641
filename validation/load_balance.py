"""Load balance of MLG partitions against a regular spatial grid, measured
(issue 23, item 5): each decomposition computed alone, no ranks run.

Scenes (LJ argon, built here in numpy; every cell periodic):

* ``liquid``: fcc at rho* = 0.8 with 0.03 sigma Gaussian jitter, a cube;
* ``droplet``: a sphere cut from that liquid, in a periodic cube of vacuum
  (radius 0.35 of the edge);
* ``slab``: that liquid between two vapour regions (box 1 x 1 x 3, the
  liquid in the middle third, 5 % of the atoms as uniform vapour);
* ``particle``: a nanoparticle on a surface: an fcc argon sphere (30 % of the
  atoms, a = 5.26 Å) resting on an fcc(100) slab of edge 4 radii, 30 Å of
  vacuum above it.

For each scene one MLG and one half list at rc + skin = 8.5 + 1 Å
(:class:`ase_mlg.decomposition.Pairs`), then for every P: the MLG partition
weighted by work (``work``: atoms and pairs counted alike), the MLG
partition weighted by pairs alone (``pairs``), and the spatial grid of the
same P (equal boxes of the cell, LAMMPS's ``processors * * *``).  Columns:
max/mean over ranks of owned atoms, halo atoms and pairs (pairs across
ranks counted half to each side), of row pairs (each pair charged to its
row atom's owner: the half list's own orientation), the number of ranks
owning no atom, and the time to compute the owners (ms; the list and the
counts not included).  Definitions: ase_mlg/decomposition.py.

Usage::

    python validation/load_balance.py              # 10^6 atoms, P = 2, 8, 64, 512
    python validation/load_balance.py --big        # and 10^7 atoms at P = 4096 (+4 min, 6.4 GB)
    python validation/load_balance.py --natoms 100000 --ranks 2 8
"""

import argparse
import subprocess
import time

import numpy as np

from ase_mlg import MLG
from ase_mlg.decomposition import (Pairs, balanced_decomposition, mlg_decomposition,
                                   spatial_decomposition)

SIGMA = 3.405          # Å, argon
A_LIQUID = (4 / 0.8) ** (1 / 3) * SIGMA  # fcc constant at rho* = 0.8, Å
A_SOLID = 5.26         # Å, fcc argon
REACH = 8.5 + 1.0      # cutoff + skin, Å


def fcc(m, a, shape=None):
    """fcc points in ``shape`` (default m^3) cubic cells of edge a (Å)."""
    shape = (m, m, m) if shape is None else shape
    cells = np.indices(shape).reshape(3, -1).T.astype(np.float64)
    basis = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]])
    return ((cells[:, None, :] + basis[None]) * a).reshape(-1, 3)


def liquid(n, rng):
    """Jittered fcc cube of ~n atoms: positions, edge (Å)."""
    m = max(1, int(round((n / 4) ** (1 / 3))))
    x = fcc(m, A_LIQUID) + rng.normal(scale=0.03 * SIGMA, size=(4 * m ** 3, 3))
    return x, m * A_LIQUID


def scene(name, n, seed=0):
    """Positions, cell (Å) and pbc of a scene of about n atoms."""
    rng = np.random.default_rng(seed)
    if name == "liquid":
        x, L = liquid(n, rng)
        return x % L, np.eye(3) * L, True
    if name == "droplet":
        x, L = liquid(int(n * 6 / np.pi * 1.05), rng)
        d = np.linalg.norm(x - 0.5 * L, axis=1)
        keep = np.argsort(d)[:n]
        R = d[keep].max()
        box = R / 0.35
        return x[keep] - 0.5 * L + 0.5 * box, np.eye(3) * box, True
    if name == "slab":
        nvap = int(0.05 * n)
        x, L = liquid(n - nvap, rng)
        vap = rng.random((nvap, 3)) * [L, L, 2 * L]
        vap[:, 2] = np.where(vap[:, 2] < L, vap[:, 2], vap[:, 2] + L)
        x = np.concatenate([(x % L) + [0, 0, L], vap])
        return x, np.diag([L, L, 3 * L]), True
    if name == "particle":
        npart = int(0.3 * n)
        R = (3 * npart / (4 * np.pi * 4 / A_SOLID ** 3)) ** (1 / 3)
        m = int(round(4 * R / A_SOLID))
        t = max(1, int(round((n - npart) / (4 * m * m))))
        sub = fcc(0, A_SOLID, (m, m, t))
        k = int(np.ceil(R / A_SOLID)) + 1
        ball = fcc(2 * k, A_SOLID) - k * A_SOLID
        ball = ball[np.argsort(np.linalg.norm(ball, axis=1))[:npart]]
        L = m * A_SOLID
        ball += [0.5 * L, 0.5 * L, t * A_SOLID + R]
        x = np.concatenate([sub, ball])
        return x, np.diag([L, L, t * A_SOLID + 2 * R + 30.0]), True
    raise ValueError(f"scene: unknown {name!r}")


def cpu_model():
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
    except OSError:
        return "unknown"
    lines = [ln.split(":", 1)[1].strip() for ln in out.splitlines()
             if ln.startswith("Model name")]
    return lines[0] if lines else "unknown"


def row(name, n, nranks, label, dec):
    s = dec.imbalance()
    dims = "x".join(map(str, dec.dims))
    if dec.alpha is not None:
        label = f"{label} (alpha {dec.alpha:g})"
    return (f"| {name} | {n:,} | {nranks} | {label} | {dims} | {s['atoms']:.3f} | "
            f"{s['halo']:.3f} | {s['pairs']:.3f} | {s['row_pairs']:.3f} | "
            f"{s['empty']} | {1e3 * dec.seconds:.0f} |")


def run(name, n, ranks, out):
    t0 = time.perf_counter()
    x, cell, pbc = scene(name, n)
    grid = MLG(x, cell, pbc)
    t1 = time.perf_counter()
    pairs = Pairs(grid, REACH)
    out.append(f"<!-- {name}: {grid.natoms} atoms, grid {grid.shape}, "
               f"{len(pairs):,} pairs; scene + MLG {t1 - t0:.1f} s, "
               f"half list + transpose {pairs.seconds:.1f} s -->")
    for nranks in ranks:
        for label, make in (("MLG balanced", lambda: balanced_decomposition(grid, nranks, pairs)),
                            ("MLG work", lambda: mlg_decomposition(grid, nranks, pairs)),
                            ("MLG pairs", lambda: mlg_decomposition(grid, nranks, pairs,
                                                                    weight="pairs")),
                            ("spatial", lambda: spatial_decomposition(grid, nranks, pairs))):
            out.append(row(name, grid.natoms, nranks, label, make()))
            print(out[-1], flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--natoms", type=float, default=1e6)
    ap.add_argument("--ranks", type=int, nargs="+", default=[2, 8, 64, 512])
    ap.add_argument("--scenes", nargs="+", default=["liquid", "droplet", "slab", "particle"])
    ap.add_argument("--big", action="store_true",
                    help="also 10^7 atoms at P = 4096 (measured: 4 min, 6.4 GB peak on 2 cores)")
    args = ap.parse_args()
    print(f"CPU: {cpu_model()}; rc + skin = {REACH} Å; max/mean over ranks\n")
    print("| scene | atoms | P | decomposition | Px x Py x Pz | owned atoms | halo atoms "
          "| pairs | row pairs | empty ranks | time (ms) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    notes = []
    for name in args.scenes:
        run(name, int(args.natoms), args.ranks, notes)
    if args.big:
        for name in args.scenes:
            run(name, 10 ** 7, [4096], notes)
    print()
    for line in notes:
        if line.startswith("<!--"):
            print(line[5:-4])


if __name__ == "__main__":
    main()
