"""2,000 NVE steps of a 10^4-atom liquid: the distributed energy trace against the serial one (issue 23.3).

    python validation/ranks_nve.py                 # the serial reference, saved
    mpiexec -n 2 python validation/ranks_nve.py    # then at 2 ranks: compared

Liquid argon (ase_mlg.scenes.lj_liquid, 10,976 atoms, rho* = 0.8, 120 K),
LJ rc 8.5 Å, skin 1 Å, 5 fs steps through ase_mlg.md.VelocityVerlet; the
total energy every 10 steps.  The serial run writes
/tmp/ase_mlg_ranks_nve.npy; a run on P ranks prints the largest relative
difference of its trace from it, the rebuilds and the migrations.
"""

import os
import sys

import numpy as np
from ase import units
from ase.md.velocitydistribution import Stationary, thermalize_momenta

from ase_mlg import MLGCalculator, distribute
from ase_mlg.md import VelocityVerlet
from ase_mlg.potentials import LennardJones
from ase_mlg.scenes import lj_liquid

STEPS = int(sys.argv[1]) if len(sys.argv) > 1 else 2000
REF = "/tmp/ase_mlg_ranks_nve.npy"

atoms = lj_liquid(10976, rho=0.8, seed=3)
thermalize_momenta(atoms, temperature_K=120, rng=np.random.default_rng(3))
Stationary(atoms)
serial = "PMI_RANK" not in os.environ and "OMPI_COMM_WORLD_RANK" not in os.environ
if not serial:
    atoms = distribute(atoms)
atoms.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5), skin=1.0)
dyn = VelocityVerlet(atoms, 5 * units.fs)
trace = []
dyn.attach(lambda: trace.append(atoms.get_potential_energy() + atoms.get_kinetic_energy()),
           interval=10)
dyn.run(STEPS)
trace = np.array(trace)
if serial:
    np.save(REF, trace)
    print(f"serial: {STEPS} steps, E from {trace[0]:.9f} to {trace[-1]:.9f} eV; saved {REF}")
elif atoms.comm.rank == 0:
    ref = np.load(REF)
    rel = np.abs(trace - ref) / np.abs(ref)
    eng = atoms.calc._ranks
    print(f"{atoms.comm.size} ranks: {STEPS} steps, largest relative difference of the energy "
          f"trace from the serial one {rel.max():.2e} (at step {10 * int(rel.argmax())}); "
          f"{eng.counts['rebuilds']} rebuilds, {eng.counts['migrated']} migrations")
