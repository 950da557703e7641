"""``ase-mlg demo``: the package end to end on an embedded LJ argon liquid.

Build the MLG, move the atoms and repair the grid (sweeps, template
quality), run NVE MD with MLGCalculator against ASE's LennardJones, and
check the trajectory against MDAnalysis and ``ase.neighborlist``.
"""

import sys
import time

import numpy as np

from .options import is_tty

__all__ = ["demo"]


def _exact_pairs(atoms, rc):
    """Unordered pairs (i < j) within rc, by an independent method (a k-d
    tree on the wrapped periodic cube), to judge the template against."""
    from scipy.spatial import cKDTree
    L = atoms.cell[0, 0]
    return cKDTree(atoms.get_positions(wrap=True) % L, boxsize=L).query_pairs(rc)


def _warm_grid(atoms, step_rms, seed):
    """Build a throwaway grid of ``atoms`` and repair it through 12 steps of
    the walk (sweeps, seam swaps, the phase-lag monitor of every 10th
    update): numba compiles (first run) or loads (later runs) every kernel
    the timed build and walk use, so that their timings exclude it.  The
    same atoms, so the same serial or threaded kernels.  Returns seconds."""
    from ..grid import MLG
    from ..scenes import PersistentWalk
    t0 = time.perf_counter()
    grid = MLG.from_atoms(atoms)
    walk = PersistentWalk(atoms.positions, step_rms, seed=seed + 1)
    for _ in range(12):
        grid.update(walk.step())
    return time.perf_counter() - t0


def demo(natoms=4000, steps=500, seed=0, out=None, md_steps=200):
    """Build the MLG of an argon liquid, move the atoms, report sweeps and
    template quality.

    Parameters
    ----------
    natoms : int
        Approximate number of atoms (fcc lattice, 4 m^3).
    steps : int
        Steps of liquid-like motion (velocity-persistent random walk of
        0.02 mean spacings rms per step, unwrapped across periodic faces).
    seed : int
        Random seed of the liquid, the motion and the momenta.
    out : file, optional
        Where the narration goes (default: ``sys.stdout`` at the call);
        progress bars only if it is a terminal.
    md_steps : int
        Steps of NVE molecular dynamics with MLGCalculator (0 skips it).

    Returns
    -------
    dict
        The numbers the narration reports: ``natoms``, ``box`` and ``rc``
        (Å), ``shape``, ``holes`` and ``build_seconds`` of the grid,
        ``warmup_seconds`` (compiling or loading the grid's kernels, kept
        out of the timings),
        ``steps``, ``sweeps`` (mean, min, max per step), ``swaps_per_step``,
        ``rebuilds``, ``step_seconds_per_atom`` (walk included),
        ``monotone`` (after the walk), ``true_pairs`` and
        ``template_quality`` ({W: share of the true pairs found}), and
        ``md``: :func:`md_demo`'s record (None when ``md_steps`` is 0).
    """
    from tqdm import tqdm

    from ..grid import MLG
    from ..template import template_pairs
    from ..scenes import SIGMA_AR, PersistentWalk, lj_liquid

    out = sys.stdout if out is None else out

    def say(*a):
        print(*a, file=out, flush=True)

    atoms = lj_liquid(natoms, rho=0.8, seed=seed)
    rc = 2.5 * SIGMA_AR
    spacing = (atoms.get_volume() / len(atoms)) ** (1 / 3)
    say(f"ase-mlg demo: LJ argon liquid, {len(atoms)} atoms, rho* = 0.8, "
        f"box {atoms.cell[0, 0]:.2f} Å, rc = 2.5 sigma = {rc:.3f} Å")
    say("loading the grid's compiled kernels (a first run compiles them, "
        "some seconds, and caches them on disk)...")
    t_warm = _warm_grid(atoms, 0.02 * spacing, seed)
    say(f"kernels ready in {t_warm:.1f} s (not counted in the timings below)")
    t0 = time.perf_counter()
    grid = MLG.from_atoms(atoms)
    t_build = time.perf_counter() - t0
    say(f"grid {grid.shape} ({grid.nholes} holes), built in {1e3 * t_build:.1f} ms")
    walk = PersistentWalk(atoms.positions, 0.02 * spacing, seed=seed)
    sweeps = []
    t0 = time.perf_counter()
    say(f"moving the atoms {steps} steps, repairing the grid by swap sweeps...")
    for _ in tqdm(range(steps), desc="moving atoms", unit="step", file=out,
                  mininterval=0.5, disable=not is_tty(out)):
        sweeps.append(grid.update(walk.step())["sweeps"])
    dt = time.perf_counter() - t0
    sweeps = np.array(sweeps)
    st = grid.stats
    rec = dict(natoms=len(atoms), box=float(atoms.cell[0, 0]), rc=rc,
               shape=tuple(int(n) for n in grid.shape), holes=int(grid.nholes),
               build_seconds=t_build, warmup_seconds=t_warm, steps=steps,
               sweeps=dict(mean=float(sweeps.mean()), min=int(sweeps.min()),
                           max=int(sweeps.max())),
               swaps_per_step=st['swaps'] / steps, rebuilds=st['rebuilds'],
               step_seconds_per_atom=dt / steps / len(atoms),
               monotone=bool(grid.is_monotone()))
    sw = rec["sweeps"]
    say(f"{steps} updates: {sw['mean']:.2f} sweeps/step (min {sw['min']}, "
        f"max {sw['max']}), {rec['swaps_per_step']:.1f} swaps/step, "
        f"{rec['rebuilds']} rebuilds, {1e6 * rec['step_seconds_per_atom']:.3f} "
        f"µs/atom/step (incl. the random walk); monotone: {rec['monotone']}")
    atoms.positions = walk.positions
    true = len(_exact_pairs(atoms, rc))
    rec.update(true_pairs=true, template_quality={})
    say(f"template quality after the run (share of the {true} true pairs "
        "within rc found in the W^3 half template):")
    for w in (3, 5, 7, 9):
        found = len(template_pairs(grid, w, rc)[0])
        rec["template_quality"][w] = found / true
        say(f"  W = {w}: {found / true:.4f}")
    rec["md"] = md_demo(len(atoms), md_steps, seed, say, progress=is_tty(out))
    return rec


def md_demo(natoms, steps, seed, say, progress=None):
    """NVE MD of the liquid with MLGCalculator; energy conservation, and
    agreement and speed against ase.calculators.lj.LennardJones.
    ``progress``: draw progress bars (on stderr); default: when stderr is a
    terminal.

    Returns None when ``steps`` <= 0, else a dict: ``steps``,
    ``step_seconds`` (wall time per MD step, compilation excluded),
    ``warmup`` (:func:`_warm_md`'s record), ``drift`` (total
    energy change per atom at the end, eV/atom), ``max_drift`` (largest |dE|
    per atom, eV/atom), ``temperature`` (K), the calculator's
    ``grid_builds``, ``list_builds`` and ``sweeps``, ``energy`` and
    ``energy_ase`` (eV) of the last frame with a fresh calculator and with
    ASE's, their ``energy_rel_diff``, ``max_force_diff`` (eV/Å), the
    wall time of that force call (``force_call_seconds``, list built from
    scratch) and of ASE's (``force_call_ase_seconds``), and ``trajectory``:
    :func:`validate_trajectory`'s record."""
    from ase import units
    from ase.calculators.lj import LennardJones as AseLJ
    from ase.md.velocitydistribution import Stationary, thermalize_momenta
    from ase.md.verlet import VelocityVerlet
    from tqdm import tqdm

    from ..calculator import MLGCalculator
    from ..potentials import LennardJones
    from ..scenes import SIGMA_AR, lj_liquid

    if steps <= 0:
        return None
    if progress is None:
        progress = is_tty(sys.stderr)
    say(f"NVE MD with MLGCalculator, {steps} steps: loading the calculator's "
        "compiled kernels (compiled on a first run, about 15-20 s)...")
    params = dict(sigma=SIGMA_AR, epsilon=0.0104, rc=2.5 * SIGMA_AR)
    # a fresh start: the random walk above lets atoms overlap, which no MD
    # run would start from
    atoms = lj_liquid(natoms, rho=0.8, seed=seed)
    thermalize_momenta(atoms, temperature_K=100, rng=np.random.default_rng(seed))
    Stationary(atoms)
    warm = _warm_md(atoms, lambda: MLGCalculator(LennardJones(**params, smooth=True),
                                                 skin=1.0), seed)
    say(f"kernels ready in {warm['seconds']:.1f} s (a throwaway run through "
        f"{warm['list_builds']} list builds and {warm['sweeps']} sweeps; not "
        "counted in the timings below)")
    atoms.calc = MLGCalculator(LennardJones(**params, smooth=True), skin=1.0)
    dyn = VelocityVerlet(atoms, 5 * units.fs)
    dyn.run(1)
    frames = []
    dyn.attach(lambda: frames.append(atoms.copy()), interval=max(1, steps // 10))
    e0 = atoms.get_total_energy()
    energies = []
    t0 = time.perf_counter()
    for _ in tqdm(range(steps), desc="NVE MD (5 fs)", unit="step", mininterval=0.5,
                  disable=not progress):
        dyn.run(1)
        energies.append(atoms.get_total_energy())
    t_step = (time.perf_counter() - t0) / steps
    drift = (np.array(energies) - e0) / len(atoms)
    st = atoms.calc.stats
    rec = dict(steps=steps, step_seconds=t_step, warmup=warm,
               drift=float(drift[-1]), max_drift=float(np.abs(drift).max()),
               temperature=float(atoms.get_temperature()), grid_builds=st['grid_builds'],
               list_builds=st['list_builds'], sweeps=st['sweeps'])
    say(f"NVE MD, {steps} steps of 5 fs, exact mode (skin 1 Å): "
        f"{1e3 * t_step:.2f} ms/step; total energy drift "
        f"{drift[-1]:+.2e} eV/atom, max |dE| {np.abs(drift).max():.2e} eV/atom; "
        f"T = {atoms.get_temperature():.1f} K; grid built {st['grid_builds']}x, "
        f"pair list built {st['list_builds']}x, {st['sweeps']} sweeps")
    say("the same atoms with ase.calculators.lj.LennardJones...")
    ref = atoms.copy()
    ref.calc = AseLJ(**params, smooth=True)
    t0 = time.perf_counter()
    f_ref = ref.get_forces()
    e_ref = ref.get_potential_energy()
    t_ase = time.perf_counter() - t0
    ours = atoms.copy()
    ours.calc = MLGCalculator(LennardJones(**params, smooth=True), skin=0.0)
    ours.get_forces()
    ours.positions = ours.positions + 1e-9  # a fresh call, kernels warm
    t0 = time.perf_counter()
    f = ours.get_forces()
    e = ours.get_potential_energy()
    t_mlg = time.perf_counter() - t0
    rec.update(energy=float(e), energy_ase=float(e_ref),
               energy_rel_diff=float(abs(e - e_ref) / abs(e_ref)),
               max_force_diff=float(np.abs(f - f_ref).max()),
               force_call_seconds=t_mlg, force_call_ase_seconds=t_ase)
    say(f"against ase.calculators.lj.LennardJones on the same atoms: energy "
        f"{e:.8f} vs {e_ref:.8f} eV (rel. diff {abs(e - e_ref) / abs(e_ref):.1e}), "
        f"max force diff {np.abs(f - f_ref).max():.1e} eV/Å; one force call "
        f"{1e3 * t_mlg:.1f} ms (list built from scratch) vs {1e3 * t_ase:.0f} ms: "
        f"{t_ase / t_mlg:.0f}x faster")
    rec["trajectory"] = validate_trajectory(frames, say, progress=progress)
    return rec


def _warm_md(atoms, make_calc, seed):
    """Run every kernel the timed MD uses on a copy of ``atoms``: the first
    force call (grid and list build), an MD step that reuses the list, and
    one after a 0.3 Å rattle (beyond half the skin: the list is rebuilt and
    the grid repaired by swap sweeps).  The same number of atoms, so the
    same serial or threaded kernels.

    Returns a dict: ``seconds`` (wall time), ``list_builds`` and
    ``sweeps`` of the throwaway calculator."""
    from ase import units
    from ase.md.verlet import VelocityVerlet

    t0 = time.perf_counter()
    copy = atoms.copy()
    copy.calc = make_calc()
    dyn = VelocityVerlet(copy, 5 * units.fs)
    dyn.run(1)
    copy.get_total_energy()
    rng = np.random.default_rng(seed + 1)
    copy.positions = copy.positions + rng.normal(scale=0.3, size=copy.positions.shape)
    dyn.run(1)
    copy.get_total_energy()
    st = copy.calc.stats
    return dict(seconds=time.perf_counter() - t0, list_builds=int(st["list_builds"]),
                sweeps=int(st["sweeps"]))


def validate_trajectory(frames, say, progress=False):
    """Write the MD frames, then check them two ways: the RDF through the MLG
    against MDAnalysis InterRDF (bin by bin), and the pairs of
    ase_mlg.NeighborList against ase.neighborlist.NeighborList.
    ``progress``: MDAnalysis's progress bars for the two RDF runs.

    Returns a dict: ``frames``, ``atoms``, ``rmax`` (Å), ``rdf_identical``
    (counts equal to InterRDF's in every bin), ``peak_g`` and ``peak_r`` (Å)
    of the RDF's first peak, ``nl_entries``, ``nl_identical`` (the same
    neighbours as ASE's NeighborList for every atom) and ``verdict`` ("PASS"
    or "FAIL"; "FAIL" also raises RuntimeError after it is said)."""
    import os
    import tempfile
    import warnings

    import MDAnalysis as mda
    from ase.io import write
    from ase.neighborlist import NeighborList as AseNL
    from MDAnalysis.analysis.rdf import InterRDF

    from ..analysis import RDF
    from ..neighborlist import NeighborList

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "demo_md.pdb")
        write(path, frames)
        u = mda.Universe(path)
        rmax = 0.45 * min(frames[0].cell.lengths())
        # exclusion_block=(1, 1): an atom is not its own neighbour
        kw = dict(nbins=100, range=(0.0, rmax), exclusion_block=(1, 1))
        say(f"checking the trajectory: RDF of {len(frames)} frames through the "
            "MLG, then MDAnalysis InterRDF (a first run compiles the RDF's "
            "kernels, about 15 s)...")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # PDB frames carry no dt
            ours = RDF(u.atoms, u.atoms, **kw).run(verbose=bool(progress))
            ref = InterRDF(u.atoms, u.atoms, **kw).run(verbose=bool(progress))
        same_rdf = np.array_equal(ours.results.count, ref.results.count)
        peak = np.argmax(ours.results.rdf)
        rec = dict(frames=len(frames), atoms=len(u.atoms), rmax=float(rmax),
                   rdf_identical=bool(same_rdf), peak_g=float(ours.results.rdf[peak]),
                   peak_r=float(ours.results.bins[peak]))
        say(f"RDF of {len(frames)} frames ({path.rsplit(os.sep, 1)[-1]}, "
            f"{len(u.atoms)} atoms, rmax {rmax:.2f} Å): counts "
            f"{'identical to' if same_rdf else 'DIFFERENT from'} MDAnalysis "
            f"InterRDF in all 100 bins; first peak g = {ours.results.rdf.max():.2f} "
            f"at {ours.results.bins[np.argmax(ours.results.rdf)]:.2f} Å")
    say("checking the neighbour list of the last frame against "
        "ase.neighborlist.NeighborList...")
    atoms = frames[-1]
    cut = [4.0] * len(atoms)
    nl, ref_nl = NeighborList(cut, self_interaction=False, bothways=True), \
        AseNL(cut, self_interaction=False, bothways=True)
    nl.update(atoms)
    ref_nl.update(atoms)
    same_pairs = all(
        {(int(j), *map(int, s)) for j, s in zip(*nl.get_neighbors(a))}
        == {(int(j), *map(int, s)) for j, s in zip(*ref_nl.get_neighbors(a))}
        for a in range(len(atoms)))
    npairs = sum(len(nl.get_neighbors(a)[0]) for a in range(len(atoms)))
    say(f"neighbour list (radii 4 Å, bothways, {npairs} entries): "
        f"{'identical to' if same_pairs else 'DIFFERENT from'} ase.neighborlist.NeighborList")
    verdict = "PASS" if same_rdf and same_pairs else "FAIL"
    rec.update(nl_entries=int(npairs), nl_identical=bool(same_pairs), verdict=verdict)
    say(f"verdict: {verdict}")
    if verdict != "PASS":
        raise RuntimeError("demo validation failed: see above")
    return rec
