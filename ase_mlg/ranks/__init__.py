"""MD across MPI ranks on MLG partitions (Boris 1985 §IV.A; docs/design.md §10).

* :func:`distribute` -- this rank's part of a system (:class:`ParallelAtoms`);
* :mod:`.partition` -- the MLG partition: blocks of the logical index space
  by weighted cuts;
* :mod:`.halo` -- ghosts, point-to-point exchange, migration and its checks;
* :mod:`.engine` -- one rank's pair sum on its owned atoms and ghosts;
* :mod:`.io` -- :class:`Trajectory`, written once by rank 0 in the original order;
* :mod:`.comm` -- the communicator (mpi4py), errors that reach every rank.
"""

from .atoms import INDEX, ParallelAtoms, distribute, is_distributed
from .comm import RankError
from .engine import RankEngine
from .io import Trajectory

__all__ = ["distribute", "ParallelAtoms", "is_distributed", "RankEngine", "RankError",
           "Trajectory", "INDEX"]
