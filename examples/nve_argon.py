"""NVE molecular dynamics of liquid argon with the MLG calculator.

864 LJ argon atoms (sigma 3.405 Å, epsilon 0.0104 eV, rc 8.5 Å) at
rho* = 0.8, 120 K, VelocityVerlet with a 5 fs step.  Prints the total energy
drift and the calculator's grid statistics.  Runs in a few seconds.
"""

import numpy as np
from ase import units
from ase.md.velocitydistribution import Stationary, thermalize_momenta
from ase.md.verlet import VelocityVerlet
from tqdm import tqdm

from ase_mlg import MLGCalculator
from ase_mlg.potentials import LennardJones
from ase_mlg.scenes import lj_liquid

atoms = lj_liquid(864, rho=0.8, seed=1)
thermalize_momenta(atoms, temperature_K=120, rng=np.random.default_rng(1))
Stationary(atoms)
atoms.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5, smooth=True),
                           skin=1.0)
dyn = VelocityVerlet(atoms, timestep=5 * units.fs)
energies = []
for _ in tqdm(range(200), desc="NVE", unit="x10 steps", disable=None):
    dyn.run(10)
    energies.append(atoms.get_total_energy() / len(atoms))
energies = np.array(energies)
print(f"total energy per atom: start {energies[0]:.6f} eV, end {energies[-1]:.6f} eV, "
      f"max deviation {np.abs(energies - energies[0]).max():.2e} eV")
print(f"temperature {atoms.get_temperature():.1f} K; calculator stats {atoms.calc.stats}")
