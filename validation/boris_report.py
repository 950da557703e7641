"""Boris 1985's statistics reproduced: writes validation/reports/boris.md + PNGs.

    python validation/boris_report.py                  # the report
    python validation/boris_report.py --sweeps-only    # section 1 to stdout

(a few minutes on the 2-core machine; ``pip install -e .`` first).  Source:
J. P. Boris, NRL Memorandum Report 5570 (1985), sections III and IV.A.
Three measurements:

1. **Swap sweeps per step** (Boris Fig. 3.4): his free-flight test -- 512
   point particles on an 8x8x8 MLG, periodic in x and y, reflecting walls in
   z, regular start, velocity components uniform in [-v, v] -- for
   per-step displacements dl_max = 0.025, 0.1, 0.4 spacings; the frequency
   distribution of sweeps per step.  We count the sweeps that swapped
   (``MLG.update(...)["sweeps"]``); counting the final sweep that confirms
   order too adds exactly 1.
2. **Close uncounters** (Boris Fig. 4.1): in the same test (dl_max = 0.1),
   for every particle, the particles *outside* its 5x5x5 logical template,
   binned by physical distance in shells of 0.1 spacing (Boris's 1 Å shells
   with his 10 Å spacing); with and without a ninth plane of holes.
3. **Sort vs recursive-split construction** (docs/design.md §3): share of the true
   pairs inside the W = 5, 7, 9 templates for a random liquid across N, at
   Boris's cutoff regime (0.9 spacing) and the LJ cutoff of docs/design.md §9
   (2.5 sigma = 2.32 spacings).

Distances are in units of the initial spacing Delta (Boris: 10 Å, i.e.
1e-7 cm).  Numba runs on one thread: the grids here are tiny and, on a
shared machine, thread wake-ups would dominate the time.
"""

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np

from ase_mlg import MLG
from ase_mlg.query import exact_pairs
from ase_mlg.template import template_pairs
from ase_mlg.scenes import random_points

REPORTS = Path(__file__).resolve().parent / "reports"
COMMAND = "python validation/boris_report.py"
SOURCE = "J. P. Boris, NRL Memorandum Report 5570 (1985), sections III and IV.A"
BORIS = {0.025: 2.85, 0.1: 4.0, 0.4: 5.0}  # mean swapping iterations per step
SHELL = 0.1          # shell thickness, spacings (Boris: 1 Å of a 10 Å spacing)
RMAX = 7.0           # largest distance binned, spacings
HALF = 2             # 5x5x5 template: logical offsets -2..2


# --------------------------------------------------------------------------
# 1. sweeps per step (Fig. 3.4)
# --------------------------------------------------------------------------

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


def sweep_statistics(steps, seeds):
    """Sweeps that swapped, per step, for each dl_max (all seeds pooled)."""
    out = {}
    for dl in BORIS:
        s, rebuilds = [], 0
        for seed in range(seeds):
            grid = None
            for _, grid, rec in simulate(dl, steps, seed):
                s.append(rec["sweeps"])
            rebuilds += grid.stats["rebuilds"]
        out[dl] = (np.array(s), rebuilds)
    return out


# --------------------------------------------------------------------------
# 2. close uncounters (Fig. 4.1)
# --------------------------------------------------------------------------

def uncounter_statistics(dl, steps, seeds, burn_in, hole_plane):
    """Histograms over distance, per particle and step, of (a) particles
    outside the 5x5x5 template, (b) all particles, (c) the part of (a) whose
    pair straddles a periodic face (x or y), and (a) in the first and the
    second half of each run; plus the closest uncounter seen.

    Each unordered pair counts once for each of its two particles, as in
    Boris's "number of particles in each radial shell" around a particle.
    """
    n = 8
    L = float(n)
    npart = n ** 3
    I, J = np.triu_indices(npart, 1)
    edges = np.arange(0.0, RMAX + SHELL / 2, SHELL)
    hist = {k: np.zeros(len(edges) - 1)
            for k in ("outside", "all", "seam", "first", "second")}
    closest = np.inf
    samples = 0
    rebuilds = 0
    half = burn_in + (steps - burn_in) // 2
    for seed in range(seeds):
        grid = None
        for step, (x, grid, _) in enumerate(simulate(dl, steps, seed, n, hole_plane)):
            if step < burn_in:
                continue
            ijk = np.stack(np.unravel_index(grid.site_of_atom(), grid.shape), -1)
            dlog = np.abs(ijk[I] - ijk[J])
            dlog[:, :2] = np.minimum(dlog[:, :2], n - dlog[:, :2])  # periodic x, y
            miss = dlog.max(axis=1) > HALF
            xw = x.copy()
            xw[:, :2] %= L  # positions are unwrapped; faces are at 0 and L
            d = xw[J] - xw[I]
            seam = (np.abs(d[:, :2]) > L / 2).any(axis=1)
            d[:, :2] -= L * np.rint(d[:, :2] / L)  # minimum image in x, y
            r = np.sqrt(np.einsum("ij,ij->i", d, d))
            h = 2 * np.histogram(r[miss], edges)[0]
            hist["outside"] += h
            hist["first" if step < half else "second"] += h
            hist["all"] += 2 * np.histogram(r, edges)[0]
            hist["seam"] += 2 * np.histogram(r[miss & seam], edges)[0]
            if miss.any():
                closest = min(closest, float(r[miss].min()))
            samples += 1
        rebuilds += grid.stats["rebuilds"]
    norm = samples * npart
    out = {k: v / norm for k, v in hist.items()}
    out["first"] *= 2  # each half holds half of the samples
    out["second"] *= 2
    out.update(edges=edges, events=hist["outside"] / 2, closest=closest,
               samples=samples, rebuilds=rebuilds)
    return out


def cumulative_within(stats, r, key="outside"):
    """Uncounted particles within distance r, per particle and step (or,
    with ``key="events"``, the number of uncounted pairs seen)."""
    k = int(round(r / SHELL))
    return float(stats[key][:k].sum())


# --------------------------------------------------------------------------
# 3. construction: sort vs recursive split (docs/design.md §3)
# --------------------------------------------------------------------------

def construction_statistics(sizes, cutoffs_in_spacings, widths=(5, 7, 9)):
    """Template share (found / true pairs) for kd and sort grids."""
    rho = 0.8 / 3.405 ** 3  # random liquid of docs/design.md §3, Å^-3
    spacing = rho ** (-1 / 3)
    rows = []
    for n in sizes:
        atoms = random_points(n, rho, seed=1)
        for method in ("kd", "sort"):
            MLG.from_atoms(atoms, method=method)  # loads the kernel
            times = []
            for _ in range(3):
                t0 = time.process_time()
                grid = MLG.from_atoms(atoms, method=method)
                times.append(time.process_time() - t0)
            t_build = float(np.median(times))
            for rc_s in cutoffs_in_spacings:
                rc = rc_s * spacing
                true = len(exact_pairs(grid, rc)[0])
                shares = [len(template_pairs(grid, w, rc)[0]) / true for w in widths]
                rows.append({"N": n, "method": method, "rc": rc_s,
                             "build_us_per_atom": 1e6 * t_build / n,
                             **{f"W{w}": s for w, s in zip(widths, shares)}})
    return rows


# --------------------------------------------------------------------------
# the report
# --------------------------------------------------------------------------

def plot_sweeps(stats, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    top = 10
    for k, (dl, (s, _)) in enumerate(stats.items()):
        freq = np.bincount(np.minimum(s, top), minlength=top + 1) / len(s)
        ax.bar(np.arange(top + 1) + (k - 1) * 0.27, freq, width=0.27,
               color=["0.9", "0.6", "0.2"][k], edgecolor="k",
               label=f"dl_max = {dl} Δ: mean {s.mean():.2f} (Boris {BORIS[dl]})")
    ax.plot([4], [0.38], "r*", ms=12, label="Boris: 0.38 at 4 sweeps (dl_max 0.1 Δ)")
    ax.set_xlabel(f"swap sweeps per step ({top} = {top} or more)")
    ax.set_ylabel("frequency")
    ax.set_title("Boris 1985 Fig. 3.4: 512 particles, 8x8x8, free flight")
    ax.set_ylim(0, 0.62)  # room for the legend above the bars
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_uncounters(runs, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for label, st in runs.items():
        mid = 0.5 * (st["edges"][1:] + st["edges"][:-1])
        keep = st["outside"] > 0
        a1.semilogy(mid[keep], st["outside"][keep], "o-", ms=3, label=label)
        share = np.divide(st["outside"], st["all"], out=np.zeros_like(st["all"]),
                          where=st["all"] > 0)
        a2.semilogy(mid[share > 0], share[share > 0], "o-", ms=3, label=label)
    for ax in (a1, a2):
        ax.set_xlabel("distance (spacings Δ; Boris: ×10 Å)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    a1.set_ylabel("uncounted particles per shell, per particle and step")
    a2.set_ylabel("share of the shell's particles uncounted")
    fig.suptitle("Boris 1985 Fig. 4.1: particles outside the 5x5x5 template, "
                 f"shells of {SHELL} Δ")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_construction(rows, path, widths=(5, 7, 9)):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    cuts = sorted({r["rc"] for r in rows})
    fig, axes = plt.subplots(1, len(cuts), figsize=(5.5 * len(cuts), 4.2))
    for ax, rc in zip(np.atleast_1d(axes), cuts):
        for k, w in enumerate(widths):
            for method, ls in (("kd", "-"), ("sort", "--")):
                sel = [r for r in rows if r["rc"] == rc and r["method"] == method]
                ax.semilogx([r["N"] for r in sel], [r[f"W{w}"] for r in sel], ls,
                            marker="o", color=f"C{k}", label=f"{method} W={w}")
        ax.set_title(f"random liquid, rc = {rc} spacings")
        ax.set_xlabel("N")
        ax.set_ylabel("share of true pairs in the template")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--burn-in", type=int, default=100)
    p.add_argument("--sizes", default="512,1000,8000,64000")
    p.add_argument("--out", default=str(REPORTS),
                   help="folder of boris.md and boris/*.png (default: %(default)s)")
    p.add_argument("--sweeps-only", action="store_true",
                   help="print section 1 (sweeps per step) and write nothing")
    args = p.parse_args(argv)
    numba.set_num_threads(1)
    t_start = time.time()

    sweeps = sweep_statistics(args.steps, args.seeds)
    if args.sweeps_only:
        print("\n".join(sweeps_section(sweeps, args, figure=False)))
        return
    out = Path(args.out)
    (out / "boris").mkdir(parents=True, exist_ok=True)
    plot_sweeps(sweeps, out / "boris" / "sweeps.png")
    runs = {"8x8x8, no holes": uncounter_statistics(0.1, args.steps, args.seeds,
                                                    args.burn_in, False),
            "8x8x9, 64 holes": uncounter_statistics(0.1, args.steps, args.seeds,
                                                    args.burn_in, True)}
    plot_uncounters(runs, out / "boris" / "uncounters.png")
    sizes = [int(s) for s in args.sizes.split(",")]
    cons = construction_statistics(sizes, (0.9, 2.32))
    plot_construction(cons, out / "boris" / "construction.png")
    elapsed = time.time() - t_start

    md = report(sweeps, runs, cons, args, elapsed)
    (out / "boris.md").write_text(md)
    print(md)


def sweeps_section(sweeps, args, figure=True):
    """Section 1 of the report (markdown lines): sweeps per step against
    Boris's Fig. 3.4; ``figure`` links boris/sweeps.png."""
    lines = [
        "## 1. Swap sweeps per step (Fig. 3.4)",
        "",
        "Boris's free-flight test: 512 point particles, 8x8x8 MLG, periodic in x "
        "and y, reflecting walls in z, regular start, velocity components uniform "
        "in [−v, v]; dl_max = v·dt is the largest per-component displacement per "
        "step. We count the sweeps that swapped (the final sweep that only confirms "
        "order is not counted; counting it adds exactly 1).",
        "",
    ]
    if figure:
        lines += ["![sweeps](boris/sweeps.png)", ""]
    lines += [
        "| dl_max / Δ | Boris mean | ours | difference | "
        + " | ".join(f"P({k})" for k in range(9)) + " | P(≥9) | grid rebuilds |",
        "|---:|---:|---:|---:|" + "---:|" * 10 + "---:|",
    ]
    for dl, (s, rebuilds) in sweeps.items():
        freq = np.bincount(np.minimum(s, 9), minlength=10) / len(s)
        lines.append(f"| {dl} | {BORIS[dl]} | {s.mean():.2f} | "
                     f"{100 * (s.mean() / BORIS[dl] - 1):+.1f} % | "
                     + " | ".join(f"{f:.3f}" for f in freq) + f" | {rebuilds} |")
    s01 = sweeps[0.1][0]
    f01 = np.bincount(s01, minlength=12) / len(s01)
    mode = int(np.argmax(f01))
    tail = [f01[k] / f01[k + 1] for k in range(mode, min(len(f01) - 1, mode + 4))
            if f01[k + 1] > 0]
    lines += [
        "",
        f"At dl_max = 0.1 Δ Boris reports frequency 0.38 at 4 sweeps and under 10 % "
        f"of steps needing 6 or more; we find {f01[4]:.2f} at 4 "
        f"({100 * (f01[4] / 0.38 - 1):+.0f} %) and {100 * (s01 >= 6).mean():.1f} % at 6 "
        f"or more. Beyond the mode ({mode}) each extra sweep is "
        f"{', '.join(f'{t:.1f}' for t in tail)} times rarer than the one before "
        "(Boris: \"a factor of two or three for each extra iteration\").",
        "",
        "Where we differ: the means agree within "
        f"{max(abs(s.mean() / BORIS[dl] - 1) for dl, (s, _) in sweeps.items()) * 100:.1f} %, "
        "the 0.1 Δ distribution matches the two numbers Boris gives for it. "
        "His run length and number of runs are not given, and the runs differ "
        "in details he does not describe: how a particle crossing a periodic "
        "face re-enters its line (ours: cyclic lines with a seam swap, README and "
        "docs/design.md §5), and whether the grid is ever rebuilt (ours rebuilds when "
        "periodic lines fall out of register: "
        + ", ".join(f"{reb} time(s) at {dl} Δ" for dl, (_, reb) in sweeps.items())
        + f" in {args.seeds} x {args.steps} steps; a rebuild returns the grid to "
        "its construction order and lowers the next steps' counts). We count the "
        "sweeps that swapped; counting the final confirming sweep would put every "
        "mean about 1 above Boris's, so his \"iterations\" most likely count the "
        "sweeps that swapped.",
        "",
    ]
    return lines


def report(sweeps, runs, cons, args, elapsed):
    lines = [
        "# Boris 1985 reproduced: sweep counts, close uncounters, construction",
        "",
        "Generated by `validation/boris_report.py`; regenerate, after "
        "`pip install -e .` in the checkout, with",
        "",
        "```bash",
        COMMAND,
        "```",
        "",
        f"({elapsed / 60:.1f} min; {args.steps} steps x {args.seeds} seeds per case.) "
        f"Source: {SOURCE}. Distances are in units of the initial spacing Δ "
        "(Boris's Δ = 10 Å).",
        "",
        *sweeps_section(sweeps, args),
        "## 2. Close uncounters with the 5x5x5 template (Fig. 4.1)",
        "",
        f"Same test at dl_max = 0.1 Δ, first {args.burn_in} steps (regular start) "
        "left out; for every particle, the particles logically outside its 5x5x5 "
        f"template binned by physical distance (minimum image in x, y) in shells of "
        f"{SHELL} Δ (Boris: 1 Å). Per particle and step.",
        "",
        "![uncounters](boris/uncounters.png)",
        "",
        "| run | samples | within 0.5 Δ | within 1 Δ | within 2 Δ | ratio 2 Δ / 1 Δ "
        "| ratio 1 Δ / 0.5 Δ | closest (Δ) | grid rebuilds |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, st in runs.items():
        c05, c1, c2 = (cumulative_within(st, r) for r in (0.5, 1.0, 2.0))
        ratio = lambda a, b: f"{a / b:.0f}" if b > 0 else "∞ (none within)"
        lines.append(f"| {label} | {st['samples'] * 512} particle-steps | {c05:.2e} | "
                     f"{c1:.2e} | {c2:.2e} | {ratio(c2, c1)} | {ratio(c1, c05)} | "
                     f"{st['closest']:.2f} | {st['rebuilds']} |")
    st = runs["8x8x8, no holes"]
    c05, c1, c2 = (cumulative_within(st, r) for r in (0.5, 1.0, 2.0))
    n03, n05 = (cumulative_within(st, r, "events") for r in (0.3, 0.5))
    c03 = cumulative_within(st, 0.3)
    seam05 = cumulative_within(st, 0.5, "seam") / c05 if c05 else 0.0
    seam2 = cumulative_within(st, 2.0, "seam") / c2 if c2 else 0.0

    def share_below(r):
        k = int(round(r / SHELL))
        return st["outside"][:k].sum() / max(st["all"][:k].sum(), 1e-300)

    # halves agree when their event counts differ by less than 3 sigma
    a, b = (cumulative_within(st, 0.5, k) * st["samples"] * 512 / 4
            for k in ("first", "second"))
    stationary = abs(a - b) < 3 * np.sqrt(max(a + b, 1))

    def ratio_of(stats, key):
        lo = cumulative_within(stats, 0.5, key)
        return cumulative_within(stats, 1.0, key) / lo if lo else float("inf")

    share = np.divide(st["outside"], st["all"], out=np.zeros_like(st["all"]),
                      where=st["all"] > 0)
    holes = runs["8x8x9, 64 holes"]
    lines += [
        "",
        "Boris: an uncounted particle is about 100 times less likely within 10 Å "
        "(1 Δ) than within 20 Å (2 Δ), another 100 times less likely within 5 Å "
        "(0.5 Δ), and none was seen closer than about 3 Å (0.3 Δ); the plane of "
        "holes changed \"essentially\" nothing.",
        "",
        f"Ours (no holes): {c2 / c1:.0f}x from 2 Δ to 1 Δ (Boris ~100: agrees), "
        + (f"{c1 / c05:.0f}x from 1 Δ to 0.5 Δ (Boris ~100)" if c05 > 0
           else "no uncounter at all within 0.5 Δ")
        + f"; closest {st['closest']:.2f} Δ = {10 * st['closest']:.1f} Å (Boris: about "
        "3 Å). With holes: "
        f"{cumulative_within(holes, 0.5) / c05:.2f}x the no-hole rate within 0.5 Δ and "
        f"{cumulative_within(holes, 2.0) / c2:.2f}x within 2 Δ"
        + (" -- little change, as Boris found." if all(
            0.5 < cumulative_within(holes, r) / max(cumulative_within(st, r), 1e-300) < 2
            for r in (0.5, 1.0, 2.0)) else " -- unlike Boris, a change beyond a factor 2."),
        "",
        f"Within 1 Δ against within 0.5 Δ the counts differ {c1 / c05:.0f}x: "
        f"{share_below(1.0) / share_below(0.5):.1f}x from the share of particles "
        "that is uncounted and "
        f"{cumulative_within(st, 1.0, 'all') / cumulative_within(st, 0.5, 'all'):.1f}x "
        "from the number of particles in the sphere (8x for a uniform gas). "
        "Uncounted shares per shell are in the table below.",
        "",
        "Why the short-range numbers differ -- what we could rule out, and what "
        "is left:",
        "",
        f"* *Sample size and run length.* Uncounters closer than 0.3 Δ come at "
        f"{c03:.1e} per particle-step ({int(n03)} pairs in "
        f"{st['samples'] * 512:,} particle-steps), so any run longer than "
        f"{np.log(2) / c03 / 512:,.0f} steps of 512 particles is more likely than "
        "not to show one; and the rates "
        + ("do not change along the run" if stationary else
           "change along the run (so run length matters)")
        + ": within 0.5 Δ "
        f"{cumulative_within(st, 0.5, 'first'):.2e} in the first half of the runs "
        f"and {cumulative_within(st, 0.5, 'second'):.2e} in the second, the "
        f"1 Δ / 0.5 Δ factor {ratio_of(st, 'first'):.0f} and "
        f"{ratio_of(st, 'second'):.0f} (±{100 / np.sqrt(max(n05, 1)):.0f} % "
        f"counting error on {int(n05)} pairs within 0.5 Δ).",
        f"* *Not the periodic seam.* {100 * seam05:.0f} % of our uncounters within "
        f"0.5 Δ straddle a periodic face in x or y ({100 * seam2:.0f} % within "
        "2 Δ): the cyclic lines of docs/design.md §5 do not make them.",
        "* *Left open.* Boris's factor of 100 and his 3 Å floor are readings of a "
        "log-scale histogram we have only as text; he does not give his run "
        "length, the order of his swap passes, or how his periodic lines close; "
        "and many MLGs fit the same positions (his Fig. 3.2), so two swap "
        "schedules can settle in grids with different short-range defects. We "
        f"reproduce his long-range factor (2 Δ / 1 Δ: {c2 / c1:.0f}) and the "
        "steep fall, not his short-range factor: ours is "
        f"{100 / (c1 / c05):.1f}x smaller than 100, and we do see uncounters "
        "below 3 Å.",
        "* *Holes.* Ours keep their coordinates and are only moved by swaps "
        "(Boris: moved to the mean of their six logical neighbours), and the "
        "construction spreads them through the grid instead of a ninth plane.",
        "",
        f"Per shell ({SHELL} Δ = Boris's 1 Å): uncounted particles per particle "
        "and step, and the share of the shell's particles that is uncounted.",
        "",
        "| shell (Å, Δ = 10 Å) | no holes | with holes | share uncounted (no holes) |",
        "|---|---:|---:|---:|",
    ]
    for k in range(int(round(3.0 / SHELL))):
        lo = 10 * st["edges"][k]
        lines.append(f"| {lo:.0f}-{lo + 10 * SHELL:.0f} | {st['outside'][k]:.2e} | "
                     f"{holes['outside'][k]:.2e} | {share[k]:.2e} |")
    lines += [
        "",
        "## 3. Sort vs recursive-split construction across N (docs/design.md §3)",
        "",
        "Random liquid (uniform random points at 0.8 σ⁻³, σ = 3.405 Å), share of "
        "the true pairs within rc that the W^3 template finds, freshly built grid. "
        "rc = 0.9 Δ is Boris's regime (\"a 5x5x5 template is adequate provided "
        "the critical radius is somewhat less than the average separation\"); "
        "rc = 2.32 Δ is the LJ cutoff 2.5 σ of docs/design.md §9.",
        "",
        "![construction](boris/construction.png)",
        "",
        "| N | method | rc (Δ) | build µs/atom | W=5 | W=7 | W=9 |",
        "|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in cons:
        lines.append(f"| {r['N']} | {r['method']} | {r['rc']} | "
                     f"{r['build_us_per_atom']:.2f} | {r['W5']:.4f} | {r['W7']:.4f} | "
                     f"{r['W9']:.4f} |")
    get = {(r["N"], r["method"], r["rc"]): r for r in cons}
    nmin, nmax = min(r["N"] for r in cons), max(r["N"] for r in cons)
    k_lo, k_hi = get[nmin, "kd", 2.32], get[nmax, "kd", 2.32]
    s_lo, s_hi = get[nmin, "sort", 2.32], get[nmax, "sort", 2.32]
    b_kd, b_sort = get[nmax, "kd", 0.9], get[nmax, "sort", 0.9]
    st = runs["8x8x8, no holes"]
    free_flight_miss = cumulative_within(st, 0.9) / max(cumulative_within(st, 0.9, "all"), 1e-300)
    lines += [
        "",
        f"At rc = 2.32 Δ the W = 7 share of the sort construction falls from "
        f"{s_lo['W7']:.3f} (N = {nmin}) to {s_hi['W7']:.3f} (N = {nmax}); the kd "
        f"construction's stays at {k_lo['W7']:.3f} → {k_hi['W7']:.3f} (docs/design.md §3 "
        "quotes 0.90 → 0.69 for sort and 0.994 for kd at N = 1k-64k: reproduced). "
        "Rows of a sorted plane are independent samples, so neighbouring rows "
        "drift out of alignment by O(sqrt(NX)) spacings as N grows; the kd split "
        "shares no such long independent lines, and its share does not fall "
        f"with N. In Boris's regime (rc = 0.9 Δ) the 5x5x5 template finds "
        f"{get[nmin, 'sort', 0.9]['W5']:.3f} of the pairs on his sort construction "
        f"at N = {nmin} and {b_sort['W5']:.3f} at N = {nmax}; on the kd grid "
        f"{get[nmin, 'kd', 0.9]['W5']:.4f} and {b_kd['W5']:.4f}. For comparison, in "
        "the free-flight run of section 2 (512 particles, grid maintained by "
        f"swaps) it misses {free_flight_miss:.1e} of the particles within 0.9 Δ. "
        "Boris's \"adequate\" for 5x5x5 holds at his 512 particles; at 10^4-10^5 "
        "particles it needs the kd construction. Construction times are CPU "
        "medians of 3 after a warm-up (both O(N log N)).",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
