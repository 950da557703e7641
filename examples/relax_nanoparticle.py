"""Relax an LJ argon nanoparticle in vacuum (pbc=False) with FIRE, then BFGS.

An fcc octahedron with a slightly too large lattice constant and random
displacements relaxes to its LJ minimum; the grid follows the particle (no
cell needed).
"""

import numpy as np
from ase.cluster import Octahedron
from ase.optimize import BFGS, FIRE

from ase_mlg import MLGCalculator
from ase_mlg.potentials import LennardJones

sigma = 3.405
atoms = Octahedron("Ar", 7, cutoff=0, latticeconstant=1.6 * sigma)
atoms.rattle(0.1, seed=4)
atoms.calc = MLGCalculator(LennardJones(sigma=sigma, epsilon=0.0104, rc=3 * sigma, smooth=True))
e0 = atoms.get_potential_energy()
FIRE(atoms, logfile=None).run(fmax=0.01, steps=2000)
e1 = atoms.get_potential_energy()
BFGS(atoms, logfile=None).run(fmax=1e-4, steps=500)
e2 = atoms.get_potential_energy()
fmax = np.linalg.norm(atoms.get_forces(), axis=1).max()
print(f"{len(atoms)} atoms: E = {e0 / len(atoms):.5f} -> {e1 / len(atoms):.5f} (FIRE) -> "
      f"{e2 / len(atoms):.5f} eV/atom (BFGS), max force {fmax:.1e} eV/Å")
