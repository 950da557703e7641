"""ase-mlg: Boris's Monotonic Logical Grid for molecular dynamics in ASE.

Public names: :class:`MLG` (the grid), :func:`neighbor_list` and
:class:`NeighborList` (drop-ins for ``ase.neighborlist``) and
:class:`MLGCalculator` (pair potentials through the grid).
"""

from .grid import MLG
from .neighborlist import NeighborList, neighbor_list
from .calculator import MLGCalculator

__version__ = "0.1.0"
__all__ = ["MLG", "neighbor_list", "NeighborList", "MLGCalculator"]
