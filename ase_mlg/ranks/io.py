"""Writing a distributed system: one trajectory, by rank 0, in the original order.

ASE's own ``Trajectory`` called on a :class:`~ase_mlg.ranks.atoms.ParallelAtoms`
would write rank 0's part only.  :class:`Trajectory` gathers each frame to
rank 0 (:meth:`ParallelAtoms.gather` with ``root=0``: no other rank holds
the whole system) and writes it there with ASE's writer, so the file is
the serial run's file.  Every rank calls :meth:`Trajectory.write` (it is
collective), as every rank calls the dynamics' observers.
"""

from ase.parallel import DummyMPI

from .atoms import is_distributed

__all__ = ["Trajectory"]


class Trajectory:
    """A trajectory file of a distributed system (or of plain atoms).

    Parameters
    ----------
    filename : str or Path
    mode : "w" or "a"
    atoms : ParallelAtoms, optional
        Written when :meth:`write` is called without atoms (as
        ``dyn.attach(traj.write, interval)`` does).
    properties : list of str, optional
        As ASE's (``"energy"``, ``"forces"``, ``"stress"``, ...).
    """

    def __init__(self, filename, mode="w", atoms=None, properties=None):
        if mode not in ("w", "a"):
            raise ValueError(f"mode: expected 'w' or 'a', got {mode!r}")
        self.atoms = atoms
        comm = atoms.comm if is_distributed(atoms) else None
        self.master = comm is None or comm.rank == 0
        # imported here: ase.io costs a sixth of a second of every `import ase_mlg`
        from ase.io.trajectory import Trajectory as _ASETrajectory
        self._writer = (_ASETrajectory(filename, mode, properties=properties,
                                       master=True, comm=DummyMPI())
                        if self.master else None)

    def write(self, atoms=None, **kwargs):
        """Write one frame (collective on a distributed system)."""
        atoms = self.atoms if atoms is None else atoms
        atoms = getattr(atoms, "atoms", atoms)  # ASE's dynamics pass an Optimizable
        if is_distributed(atoms):
            atoms = atoms.gather(root=0)
        if self._writer is not None:
            self._writer.write(atoms, **kwargs)

    __call__ = write

    def set_description(self, description):
        """ASE's dynamics describe themselves in the file's header."""
        if self._writer is not None:
            self._writer.set_description(description)

    def __len__(self):
        return len(self._writer) if self._writer is not None else 0

    def close(self):
        if self._writer is not None:
            self._writer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
