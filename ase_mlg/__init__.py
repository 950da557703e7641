"""ase-mlg: Boris's Monotonic Logical Grid for molecular dynamics in ASE.

Public names: :class:`MLG` (the grid), :func:`neighbor_list` and
:class:`NeighborList` (drop-ins for ``ase.neighborlist``) and
:class:`MLGCalculator` (pair potentials through the grid).
"""

import os

# numba's OpenMP threads spin while idle by default; on a 2-core machine that
# starves the main thread between parallel kernels (measured: serial swap
# sweeps of a 1,000-atom grid took 100 ms instead of 0.03 ms for the first
# seconds of a process).  Idle threads sleep instead, unless the user chose.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from .grid import MLG  # noqa: E402
from .neighborlist import NeighborList, neighbor_list  # noqa: E402
from .calculator import MLGCalculator  # noqa: E402

__version__ = "0.1.0"
__all__ = ["MLG", "neighbor_list", "NeighborList", "MLGCalculator"]
