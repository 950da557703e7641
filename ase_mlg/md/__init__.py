"""Compiled MD loops: drop-ins for ASE's ``VelocityVerlet`` and ``Langevin``.

``ase_mlg.md.VelocityVerlet`` and ``ase_mlg.md.Langevin`` subclass
:class:`ase.md.verlet.VelocityVerlet` and :class:`ase.md.langevin.Langevin`
(same arguments, observers, trajectory, log, ``run`` / ``irun``) and replace
only their ``step``: the position and momentum updates are fused numba
passes in place on the atoms' arrays (:mod:`ase_mlg.md.kernels`), which
reproduce ASE's arithmetic and so its trajectory bit for bit.  They work
with any ASE calculator; with :class:`~ase_mlg.MLGCalculator` the forces
are read without a copy.  FixAtoms runs compiled; other constraints run
ASE's own step (:mod:`ase_mlg.md.fastpath` says exactly when).
"""

from .langevin import Langevin
from .verlet import VelocityVerlet

__all__ = ["VelocityVerlet", "Langevin"]
