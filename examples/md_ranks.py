"""NVE argon across MPI ranks: the same script from one rank to many.

    python examples/md_ranks.py                 # one rank
    mpiexec -n 2 python examples/md_ranks.py    # two ranks (pip install "ase-mlg[mpi]")

6,912 LJ argon atoms; every rank builds the same system, ``distribute``
keeps this rank's part (an MLG partition), and the calculator, ase-mlg's
VelocityVerlet, ASE's MDLogger and the trajectory work on it unchanged: the
log and md_ranks.traj are written once, by rank 0, in the original order.
The energies are the same at any rank count (to rounding).
"""

import numpy as np
from ase import units
from ase.md.velocitydistribution import Stationary, thermalize_momenta
from ase.parallel import parprint

from ase_mlg import MLGCalculator, distribute
from ase_mlg.md import VelocityVerlet
from ase_mlg.potentials import LennardJones
from ase_mlg.scenes import lj_liquid

atoms = lj_liquid(6912, rho=0.8, seed=1)
thermalize_momenta(atoms, temperature_K=120, rng=np.random.default_rng(1))
Stationary(atoms)
atoms = distribute(atoms)  # this rank's atoms, with their original .indices
atoms.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
dyn = VelocityVerlet(atoms, 5 * units.fs, logfile="-", loginterval=25,
                     trajectory="md_ranks.traj")
e0 = atoms.get_total_energy() / atoms.get_global_number_of_atoms()
dyn.run(100)
e1 = atoms.get_total_energy() / atoms.get_global_number_of_atoms()
engine = atoms.calc._ranks
parprint(f"{atoms.comm.size} rank(s): total energy per atom {e0:.6f} -> {e1:.6f} eV; "
         f"{engine.counts['rebuilds']} rebuilds, {engine.counts['migrated']} migrations")
