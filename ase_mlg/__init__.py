"""ase-mlg: Boris's Monotonic Logical Grid for molecular dynamics in ASE.

Public names: :class:`MLG` (the grid), the list-bound names of
``ase.neighborlist`` as drop-ins (:func:`neighbor_list`,
:func:`primitive_neighbor_list`, :class:`NeighborList`,
:class:`PrimitiveNeighborList`, :class:`NewPrimitiveNeighborList`,
:func:`first_neighbors`, :func:`get_connectivity_matrix`,
:func:`build_neighbor_list`; the whole module is
:mod:`ase_mlg.neighborlist`) and :class:`MLGCalculator` (pair potentials
through the grid) with its ``template="auto"`` policy :class:`AutoTemplate`;
:func:`show_config` prints the threading layer and versions in use;
:func:`distribute` is this MPI rank's part of a system (:mod:`ase_mlg.ranks`).
"""

# the threading layer and idle policy are set by ase_mlg.parallel, which the
# grid imports before any kernel runs (docs/design.md §8)
from .grid import MLG
from .neighborlist import (NeighborList, NewPrimitiveNeighborList,
                           PrimitiveNeighborList, build_neighbor_list,
                           first_neighbors, get_connectivity_matrix,
                           neighbor_list, primitive_neighbor_list)
from .autotemplate import AutoTemplate
from .calculator import MLGCalculator
from .ranks import distribute
from .parallel import show_config

__version__ = "0.1.0"
__all__ = ["show_config", "MLG", "distribute", "neighbor_list", "NeighborList", "MLGCalculator", "AutoTemplate",
           "primitive_neighbor_list", "first_neighbors",
           "get_connectivity_matrix", "build_neighbor_list",
           "PrimitiveNeighborList", "NewPrimitiveNeighborList"]
