"""A binary Ar/Kr Lennard-Jones mixture with Lorentz-Berthelot mixing.

Per-pair parameters and cutoffs (rc = 3 sigma_AB) through
`lennard_jones_mixture`, the worked example of a user pair potential; a short
NVE run reports energy conservation and the composition of neighbour shells.
"""

import numpy as np
from ase import units
from ase.md.velocitydistribution import Stationary, thermalize_momenta
from ase.md.verlet import VelocityVerlet
from tqdm import tqdm

import ase_mlg
from ase_mlg import MLGCalculator
from ase_mlg.potentials import lennard_jones_mixture
from ase_mlg.scenes import binary_mixture

atoms = binary_mixture(1372, rho=0.75, fraction=0.3, seed=5)
pot = lennard_jones_mixture(sigma={"Ar": 3.405, "Kr": 3.65},
                            epsilon={"Ar": 0.0104, "Kr": 0.0140})
atoms.calc = MLGCalculator(pot, skin=1.0)
thermalize_momenta(atoms, temperature_K=110, rng=np.random.default_rng(5))
Stationary(atoms)
dyn = VelocityVerlet(atoms, 4 * units.fs)
e = []
for _ in tqdm(range(100), desc="NVE mixture", unit="x10 steps", disable=None):
    dyn.run(10)
    e.append(atoms.get_total_energy() / len(atoms))
i, j = ase_mlg.neighbor_list("ij", atoms, 5.0)
kr = atoms.numbers == 36
print(f"{kr.sum()} Kr + {(~kr).sum()} Ar; energy drift {e[-1] - e[0]:+.2e} eV/atom over "
      f"{len(e) * 10} steps; Kr share among neighbours of Kr within 5 Å: "
      f"{kr[j[kr[i]]].mean():.3f} (bulk {kr.mean():.3f})")
