"""``distribute`` and ``ParallelAtoms``: one rank's part of a system.

The user's script runs unchanged from ``python md.py`` (one rank) to
``mpiexec -n P python md.py``::

    atoms = distribute(atoms)              # this rank's atoms (asap3's MakeParallelAtoms)
    atoms.calc = MLGCalculator(LennardJones(...))
    dyn = ase_mlg.md.VelocityVerlet(atoms, 5 * units.fs, logfile="md.log")
    dyn.attach(Trajectory("md.traj", "w", atoms), interval=10)
    dyn.run(1000)

A :class:`ParallelAtoms` is an ``ase.Atoms`` of the atoms this rank owns,
with their original indices (:attr:`~ParallelAtoms.indices`).  Per-atom
quantities (positions, momenta, forces, ``energies``) are the owned
atoms'; the energy, the stress, the kinetic energy, the temperature and
the number of degrees of freedom are the whole system's (every rank gets
the same value), so ASE's ``MDLogger`` logs the system from rank 0.  The
owned set changes at list rebuilds (:mod:`ase_mlg.ranks.halo`): read the
arrays after a force call, never keep them across one.
"""

import hashlib

import numpy as np
from ase import Atoms
from ase.calculators.singlepoint import SinglePointCalculator

from .comm import abort_on_exception, agree, ordered_sum, resolve_comm
from .partition import Partition

__all__ = ["ParallelAtoms", "distribute", "is_distributed", "INDEX"]

#: The per-atom array holding each atom's index in the original system.
INDEX = "mlg_indices"


def is_distributed(atoms):
    """Is ``atoms`` one rank's part of a distributed system?"""
    return isinstance(atoms, ParallelAtoms)


class ParallelAtoms(Atoms):
    """The atoms one rank owns (made by :func:`distribute`).

    Attributes
    ----------
    comm : mpi4py communicator or SerialComm
    indices : (n,) int64
        Each owned atom's index in the original atoms.
    """

    def __init__(self, *args, comm=None, natoms=None, **kwargs):
        Atoms.__init__(self, *args, **kwargs)
        self.comm = comm
        self._natoms = natoms

    def copy(self):
        """A copy on this rank (the same communicator)."""
        atoms = Atoms.copy(self)
        atoms.comm, atoms._natoms = self.comm, self._natoms
        return atoms

    def __getitem__(self, i):
        part = Atoms.__getitem__(self, i)
        if isinstance(part, ParallelAtoms):  # a slice is this rank's business only
            plain = Atoms(cell=part.cell, pbc=part.pbc, info=part.info)
            plain.arrays = part.arrays
            return plain
        return part

    @property
    def indices(self):
        return self.arrays[INDEX]

    def get_global_number_of_atoms(self):
        """Atoms on all ranks (asap3's name)."""
        return self._natoms

    def get_kinetic_energy(self):
        """Kinetic energy of the whole system (eV)."""
        return float(ordered_sum(self.comm, Atoms.get_kinetic_energy(self)))

    def get_number_of_degrees_of_freedom(self):
        return 3 * self._natoms

    def gather(self, root=None):
        """The whole system as an ``ase.Atoms`` in the original order, with
        positions, momenta, every per-atom array and the calculator's
        results (a SinglePointCalculator); on every rank, or on ``root``
        only (None elsewhere).  Collective; for tests, small systems and
        writers, which hold what they write."""
        arrays = {k: v for k, v in self.arrays.items()}
        res = {}
        calc = self.calc
        if calc is not None:
            res = {k: v for k, v in calc.results.items()}
        local = (arrays, {k: v for k, v in res.items() if k in ("forces", "energies", "stresses")})
        parts = self.comm.allgather(local) if root is None else self.comm.gather(local, root=root)
        if parts is None:
            return None
        idx = np.concatenate([p[0][INDEX] for p in parts])
        order = np.argsort(idx, kind="stable")
        whole = Atoms(cell=self.cell, pbc=self.pbc, info=dict(self.info))
        whole.arrays = {k: np.concatenate([p[0][k] for p in parts])[order]
                        for k in parts[0][0] if k != INDEX}
        if calc is not None and res:
            results = {k: v for k, v in res.items() if k not in ("forces", "energies", "stresses")}
            for k in local[1]:
                results[k] = np.concatenate([p[1][k] for p in parts])[order]
            whole.calc = SinglePointCalculator(whole, **results)
        return whole


def _digest(atoms):
    h = hashlib.sha1()
    for a in (atoms.positions, atoms.numbers, atoms.cell.array, atoms.pbc):
        h.update(np.ascontiguousarray(a).tobytes())
    if atoms.has("momenta"):
        h.update(np.ascontiguousarray(atoms.arrays["momenta"]).tobytes())
    return h.hexdigest()


def _check_input(atoms):
    if not isinstance(atoms, Atoms) or isinstance(atoms, ParallelAtoms):
        raise TypeError(f"atoms: expected an ase.Atoms (the whole system on every rank), "
                        f"got {type(atoms).__name__}")
    if atoms.constraints:
        raise ValueError("atoms: constraints are not supported across ranks "
                         f"(got {', '.join(type(c).__name__ for c in atoms.constraints)})")
    if len(atoms) == 0:
        raise ValueError("atoms: no atoms to distribute")
    return _digest(atoms)


def distribute(atoms, comm=None, reach=None):
    """This rank's part of ``atoms``, as a :class:`ParallelAtoms`.

    Parameters
    ----------
    atoms : ase.Atoms
        The whole system, the same on every rank (as each rank builds it in
        the script).
    comm : mpi4py communicator or ase.parallel.world, optional
        Default ``ase.parallel.world``'s rule: mpi4py's ``COMM_WORLD``
        under ``mpiexec``, one rank under ``python``.
    reach : float, optional
        The cutoff + skin (Å) the first partition is shaped for; the
        calculator repartitions at its first call anyway.

    Raises
    ------
    ValueError
        If the ranks hold different atoms, on every rank; if the grid has
        too few planes for the ranks.
    ImportError
        Under ``mpiexec`` without mpi4py.
    """
    comm = resolve_comm(comm)
    abort_on_exception(comm)
    digest = agree(comm, _check_input, atoms)
    digests = comm.allgather(digest)
    differ = [r for r, d in enumerate(digests) if d != digests[0]]
    if differ:
        raise ValueError(f"distribute: ranks {differ} hold different atoms from rank 0 "
                         "(every rank must pass the same whole system)")
    n = len(atoms)
    sample = np.arange(comm.rank, n, comm.size)  # each rank weighs a share of the atoms
    part = agree(comm, Partition, comm, atoms.positions[sample], atoms.cell.array,
                 atoms.pbc, n, 8.0 if reach is None else float(reach))
    mine = np.flatnonzero(part.owner(atoms.positions) == comm.rank)
    out = ParallelAtoms(cell=atoms.cell.copy(), pbc=atoms.pbc.copy(), info=dict(atoms.info),
                        comm=comm, natoms=n)
    out.arrays = {k: np.ascontiguousarray(v[mine]) for k, v in atoms.arrays.items()}
    out.arrays[INDEX] = mine.astype(np.int64)
    if not out.has("momenta"):
        out.arrays["momenta"] = np.zeros((len(mine), 3))
    if atoms.calc is not None:
        atoms.calc.reset()
        out.calc = atoms.calc
    return out
