"""Radial distribution functions through the MLG (docs/design.md §10).

Two front ends share one pair source, a grid kept across frames and queried
exactly (:func:`ase_mlg.query.exact_pairs`) or through Boris's template
(:func:`ase_mlg.template.template_pairs`):

* :class:`RDF` / :class:`RDF_s`, the MDAnalysis side: drop-ins for
  ``MDAnalysis.analysis.rdf.InterRDF`` / ``InterRDF_s`` with their counts
  bin for bin, on MDAnalysis's serial, multiprocessing and dask backends or
  a ``dask.distributed`` cluster (:class:`DistributedBackend`);
* :func:`rdf`, the ASE side: the numbers of ``ase.geometry.rdf.get_rdf``
  for one ``Atoms``, a list of them, or a trajectory file.

The command line ``ase-mlg rdf`` lives in :mod:`ase_mlg.cli.rdf`.
"""

from .ase_rdf import CellTooSmall, VolumeNotDefined, rdf
from .backends import DistributedBackend
from .interrdf import RDF, RDF_s

__all__ = ["RDF", "RDF_s", "rdf", "DistributedBackend", "CellTooSmall", "VolumeNotDefined"]
