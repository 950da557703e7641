"""The scenes of docs/design.md §9, built in code, and synthetic motion for the grid.

Every test, validation script, benchmark and the demo draws its systems from
here, so "the LJ liquid" means the same atoms everywhere.  Sizes are
approximate: lattice scenes round to whole unit cells.

Units: Å, and argon's sigma = 3.405 Å for the LJ scenes.
"""

import numpy as np
from ase import Atoms
from ase.build import bulk, fcc111
from ase.cluster import Octahedron

__all__ = ["SIGMA_AR", "random_points", "lj_liquid", "fcc_copper", "dilute_gas",
           "nanoparticle", "sheared_crystal", "slab", "small_cell",
           "binary_mixture", "SCENES", "make_scene", "PersistentWalk"]

SIGMA_AR = 3.405  # Å


def _fcc_repeats(natoms):
    return max(1, int(round((natoms / 4) ** (1 / 3))))


def random_points(natoms, density, seed=0):
    """Uniform random points in a periodic cube at ``density`` (Å^-3);
    the "random liquid" of docs/design.md §3 when density is 0.8 / sigma^3."""
    rng = np.random.default_rng(seed)
    L = (natoms / density) ** (1 / 3)
    return Atoms("Ar%d" % natoms, positions=rng.random((natoms, 3)) * L,
                 cell=[L, L, L], pbc=True)


def lj_liquid(natoms=4000, rho=0.8, jitter=0.03, seed=0):
    """LJ argon at reduced density ``rho`` in a periodic cube: an fcc lattice
    (4 m^3 atoms) with random displacements of ``jitter`` sigma, the usual
    start of a liquid MD run (no overlapping atoms, unlike random points)."""
    m = _fcc_repeats(natoms)
    a = (4 / rho) ** (1 / 3) * SIGMA_AR
    atoms = bulk("Ar", "fcc", a=a, cubic=True).repeat(m)
    rng = np.random.default_rng(seed)
    atoms.positions += rng.normal(scale=jitter * SIGMA_AR, size=atoms.positions.shape)
    atoms.wrap()
    return atoms


def fcc_copper(natoms=4000, a=3.61):
    """Perfect fcc copper, periodic cube."""
    return bulk("Cu", "fcc", a=a, cubic=True).repeat(_fcc_repeats(natoms))


def dilute_gas(natoms=1000, rho=0.05, seed=0):
    """Argon gas at reduced density ``rho``, periodic: a simple-cubic lattice
    with uniform random displacements large enough to erase the lattice
    locally but keeping every pair beyond sigma (random points would put
    some atoms on top of each other, which no MD run starts from)."""
    m = max(1, int(round(natoms ** (1 / 3))))
    a = (rho / SIGMA_AR ** 3) ** (-1 / 3)
    rng = np.random.default_rng(seed)
    base = np.stack(np.meshgrid(*[np.arange(m)] * 3, indexing="ij"), -1).reshape(-1, 3)
    amp = max(0.0, 0.5 * (a - SIGMA_AR))
    x = (base + 0.5) * a + rng.uniform(-amp, amp, base.shape)
    L = m * a
    return Atoms("Ar%d" % len(x), positions=x % L, cell=[L, L, L], pbc=True)


def nanoparticle(natoms=1000, a=3.61):
    """An fcc copper octahedron in vacuum, ``pbc=False``, no cell."""
    # an fcc octahedron of length l holds about 2 l^3 / 3 atoms
    length = max(2, int(round((1.5 * natoms) ** (1 / 3))))
    atoms = Octahedron("Cu", length, cutoff=0, latticeconstant=a)
    atoms.cell = np.zeros((3, 3))
    atoms.pbc = False
    return atoms


def sheared_crystal(natoms=4000, a=3.61, shear=2):
    """fcc copper in a strongly sheared triclinic cell.

    The cubic supercell (A, B, C) is replaced by the equivalent cell
    (A, B + shear*A, C + A): a unimodular change of basis, so the crystal is
    unchanged while the cell angle gamma drops to 26.6 degrees for shear=2.
    """
    atoms = fcc_copper(natoms, a)
    A, B, C = atoms.cell.array
    atoms.set_cell([A, B + int(shear) * A, C + A], scale_atoms=False)
    atoms.wrap()
    return atoms


def slab(natoms=2000, a=3.61, layers=6, vacuum=10.0):
    """Cu(111) slab with vacuum along z, ``pbc=(True, True, False)``."""
    per_layer = max(1, natoms // layers)
    m = max(2, int(round(per_layer ** 0.5)))
    atoms = fcc111("Cu", size=(m, m, layers), a=a, vacuum=vacuum)
    atoms.pbc = (True, True, False)
    return atoms


def small_cell(a=3.61):
    """A 4-atom fcc copper cube (3.61 Å): a 5 Å cutoff exceeds half the box,
    so every atom meets many images, its own included."""
    return bulk("Cu", "fcc", a=a, cubic=True)


def binary_mixture(natoms=4000, rho=0.8, fraction=0.5, seed=0):
    """An Ar/Kr mixture on a jittered fcc lattice (per-pair parameters and
    cutoffs via Lorentz-Berthelot mixing in the potentials)."""
    atoms = lj_liquid(natoms, rho=rho, seed=seed)
    rng = np.random.default_rng(seed + 1)
    numbers = np.where(rng.random(len(atoms)) < fraction, 36, 18)
    atoms.numbers = numbers
    return atoms


SCENES = {
    "liquid": lj_liquid,
    "copper": fcc_copper,
    "gas": dilute_gas,
    "nanoparticle": nanoparticle,
    "sheared": sheared_crystal,
    "slab": slab,
    "small": small_cell,
    "mixture": binary_mixture,
}


def make_scene(name, natoms=None, **kwargs):
    """Build a named scene of docs/design.md §9 (``natoms`` ignored by ``small``)."""
    try:
        builder = SCENES[name]
    except KeyError:
        raise ValueError(f"scene: unknown name {name!r}; choose from "
                         f"{sorted(SCENES)}") from None
    if name == "small" or natoms is None:
        return builder(**kwargs)
    return builder(natoms, **kwargs)


class PersistentWalk:
    """Liquid-like synthetic motion: every atom follows a velocity-persistent
    random walk, ``v <- a v + sqrt(1 - a^2) * sigma * xi``, ``x <- x + v``.

    ``step_rms`` is the rms displacement per step (Å); ``persistence`` (a)
    sets a correlation time of about 1 / (1 - a) steps, as velocities in a
    liquid decorrelate over a few collisions.  Positions are not wrapped:
    atoms cross periodic faces as in an unwrapped MD trajectory.
    """

    def __init__(self, positions, step_rms, persistence=0.95, seed=0):
        self.rng = np.random.default_rng(seed)
        self.positions = np.array(positions, dtype=float)
        self.a = float(persistence)
        self.sigma = float(step_rms) / np.sqrt(3.0)
        self.v = self.rng.normal(scale=self.sigma, size=self.positions.shape)

    def step(self):
        noise = self.rng.normal(scale=self.sigma, size=self.v.shape)
        self.v = self.a * self.v + np.sqrt(1 - self.a ** 2) * noise
        self.positions += self.v
        return self.positions
