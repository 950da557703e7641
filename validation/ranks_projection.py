"""A scaling model of MD across MPI ranks, projected to 4,096 ranks (issue 23.6).

    python validation/bench_ranks.py --json /tmp/ranks.json   # the measurements
    python validation/ranks_projection.py /tmp/ranks.json      # the projection

A PROJECTION, not a measurement.  From one 2-rank ase-mlg run of
bench_ranks.py (the largest size in the file) it takes, per rank and per
step:

* the pair sum's time per owned atom (``kernel`` / owned: each pair is
  computed on one rank, so a rank's pairs follow its owned atoms),
* the list's time per local atom (``list``: builds amortised, the
  validity checks), and the rebuild's (partition, migration, ghost lists)
  per owned atom,
* the halo exchange's time per ghost (``halo`` / ghosts),
* the integrator's and ASE's time per owned atom,

and a latency per collective (5 a step: the state check, two flags, the
pair sum's error flag, the energy; plus 3 x 60 rounds of the partition's
bisection a rebuild, an upper bound: a rebuild keeps the partition in use
while it is within 1.05 and bisects only when it drifted past), ``ALPHA`` seconds x log2(P) (a tree; the 2-rank
measurement cannot separate it, so it is an assumption, printed).

The halo of a rank is the liquid's number density times the volume within
reach (cutoff + skin) of its block, Steiner's formula on the block that
``decomposition.factor_mlg`` picks (the rule the partition uses), checked
against the ghosts the 2-rank run measured; load imbalance from
validation/reports/load_balance.md (the MLG partitions' pairs max/mean of the
liquid: 1.000-1.001) is taken as 1.  Strong scaling: fixed N = 10^6 ... 10^9
atoms; weak: N / P fixed at the measured run's.
"""

import json
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from ase_mlg.decomposition import factor_mlg  # noqa: E402

DENSITY = 4 / 5.72 ** 3  # atoms / Å^3 (fcc argon at a = 5.72 Å, bench_ranks's scene)
REACH = 9.5  # Å: rc 8.5 + skin 1
ALPHA = 5e-6  # s per collective per tree level (an assumption: MPICH on one node ~1-5 us)
COLLECTIVES_PER_STEP = 5
BISECTION_ROUNDS = 3 * 60


def halo_atoms(natoms, nranks):
    """Ghosts per rank: density x the volume within REACH of a rank's block."""
    L = (natoms / DENSITY) ** (1 / 3)
    shape = [round((natoms) ** (1 / 3))] * 3
    dims = np.array(factor_mlg(shape, [L / shape[0]] * 3, nranks, REACH))
    e = L / dims
    cut = dims > 1
    r = REACH
    k = int(cut.sum())
    ec = e[cut]
    if k == 0:
        vol = 0.0
    elif k == 1:
        vol = 2 * r * L * L
    elif k == 2:
        vol = (2 * r * ec.sum() + math.pi * r * r) * L
    else:
        vol = (2 * r * (ec[0] * ec[1] + ec[0] * ec[2] + ec[1] * ec[2])
               + math.pi * r * r * ec.sum() + 4 / 3 * math.pi * r ** 3)
    return DENSITY * vol, tuple(int(d) for d in dims)


def rates(run):
    """Per-unit costs from one 2-rank launch (ms per step, counts)."""
    parts, owned = run["parts"], run["owned"][1]
    local = owned + run["ghosts"]
    return {"pair": parts["kernel"] / owned,
            "list": parts["list"] / local,
            "rebuild": parts["rebuild"] / owned,
            "ghost": parts["halo"] / max(run["ghosts"], 1),
            "check": parts.get("check", 0.0) / local,
            "atom": max(parts["integrator+ASE"], 0.0) / owned}


def step_ms(rate, natoms, nranks, rebuild_every):
    owned = natoms / nranks
    ghosts, dims = halo_atoms(natoms, nranks) if nranks > 1 else (0.0, (1, 1, 1))
    local = owned + ghosts
    levels = math.log2(nranks) if nranks > 1 else 0.0
    coll = 1e3 * ALPHA * levels * (COLLECTIVES_PER_STEP + BISECTION_ROUNDS / rebuild_every)
    t = (rate["pair"] * owned + (rate["list"] + rate["check"]) * local
         + rate["rebuild"] * owned + rate["ghost"] * ghosts + rate["atom"] * owned + coll)
    return t, ghosts / owned, dims


def main(path):
    data = json.load(open(path))
    size = max(data["results"], key=int)
    runs = [r for r in data["results"][size]["mlg 2x1"] if "error" not in r]
    run = sorted(runs, key=lambda r: r["step_ms"])[len(runs) // 2]  # the median launch
    rate = rates(run)
    rebuild_every = data["steps"] / max(run["rebuilds"], 1)
    n0 = int(size)
    model2, frac2, _ = step_ms(rate, n0, 2, rebuild_every)
    print(f"# PROJECTION (a model, not a measurement) from {data['cpu']}, one 2-rank run "
          f"of {n0:,} atoms (the median of {len(runs)} launches): measured {run['step_ms']:.2f} ms/step, the model gives "
          f"{model2:.2f}; measured ghosts/owned {run['ghosts'] / run['owned'][1]:.3f}, "
          f"Steiner {frac2:.3f}; collective latency {ALPHA * 1e6:.0f} us x log2(P) "
          f"(assumed); one rebuild per {rebuild_every:.0f} steps\n")
    t1 = step_ms(rate, n0, 1, rebuild_every)[0]
    print("## Strong scaling: ms per step (parallel efficiency against 1 rank of the same N)\n")
    Ps = [1, 8, 64, 512, 4096]
    print("| atoms | " + " | ".join(f"P = {p}" for p in Ps) + " |")
    print("|---|" + "---|" * len(Ps))
    for n in (10 ** 6, 10 ** 7, 10 ** 8, 10 ** 9):
        base = step_ms(rate, n, 1, rebuild_every)[0]
        cells = []
        for p in Ps:
            if n / p < 100:
                cells.append("-")
                continue
            t, frac, dims = step_ms(rate, n, p, rebuild_every)
            cells.append(f"{t:.3g} ({base / (p * t):.0%}, halo {frac:.2f})")
        print(f"| {n:.0e} | " + " | ".join(cells) + " |")
    print(f"\n## Weak scaling: {n0 // 2:,} atoms a rank, ms per step (efficiency against 1 rank)\n")
    print("| P | atoms | ms/step | efficiency | ghosts/owned | Px x Py x Pz |")
    print("|---|---|---|---|---|---|")
    for p in Ps:
        n = n0 // 2 * p
        t, frac, dims = step_ms(rate, n, p, rebuild_every)
        t_one = step_ms(rate, n0 // 2, 1, rebuild_every)[0]
        print(f"| {p} | {n:,} | {t:.2f} | {t_one / t:.0%} | {frac:.3f} | "
              f"{'x'.join(map(str, dims))} |")
    del t1


if __name__ == "__main__":
    main(sys.argv[1])
