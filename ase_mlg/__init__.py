"""ase-mlg: Boris's Monotonic Logical Grid for molecular dynamics in ASE.

Public names: :class:`MLG` (the grid), the list-bound names of
``ase.neighborlist`` as drop-ins (:func:`neighbor_list`,
:func:`primitive_neighbor_list`, :class:`NeighborList`,
:class:`PrimitiveNeighborList`, :class:`NewPrimitiveNeighborList`,
:func:`first_neighbors`, :func:`get_connectivity_matrix`,
:func:`build_neighbor_list`; the whole module is
:mod:`ase_mlg.neighborlist`) and :class:`MLGCalculator` (pair potentials
through the grid).
"""

import os

# numba's OpenMP threads spin while idle by default; on a 2-core machine that
# starves the main thread between parallel kernels (measured: serial swap
# sweeps of a 1,000-atom grid took 100 ms instead of 0.03 ms for the first
# seconds of a process).  Idle threads sleep instead, unless the user chose.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# numba's threading layer: a fork-safe one, chosen before any parallel kernel
# runs, unless the user chose (NUMBA_THREADING_LAYER).  numba's default on
# Linux is GNU OpenMP, which kills a forked child that launches a parallel
# kernel; multiprocessing/dask workers fork (and must, to run from a plain
# script, ``python -c`` or a notebook).  'forksafe' is numba's TBB layer (the
# ``tbb`` package, a dependency) and, where TBB cannot load, 'workqueue'.
# Measured: a trivial prange kernel on 2 threads costs 6 us per launch under
# TBB (GNU OpenMP 26 us, workqueue 127 us).
if "NUMBA_THREADING_LAYER" not in os.environ:
    import numba as _numba

    _numba.config.THREADING_LAYER = "forksafe"
    del _numba

from .grid import MLG  # noqa: E402
from .neighborlist import (NeighborList, NewPrimitiveNeighborList,  # noqa: E402
                           PrimitiveNeighborList, build_neighbor_list,
                           first_neighbors, get_connectivity_matrix,
                           neighbor_list, primitive_neighbor_list)
from .calculator import MLGCalculator  # noqa: E402

__version__ = "0.1.0"
__all__ = ["MLG", "neighbor_list", "NeighborList", "MLGCalculator",
           "primitive_neighbor_list", "first_neighbors",
           "get_connectivity_matrix", "build_neighbor_list",
           "PrimitiveNeighborList", "NewPrimitiveNeighborList"]
