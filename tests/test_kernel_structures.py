"""Every named structure a kernel takes has one numba type.

The kernels take their arrays in namedtuples (issue 19).  numba 0.59, the
oldest version the package supports, dispatches a namedtuple argument of
four or more fields whose field types vary between calls to the wrong
overload now and then ("can't unbox array from PyObject": measured, 4 of
200 calls of a 4-field namedtuple whose one array alternated between uint8
and int32).  So a structure's fields must have the same types in every
call; what varies (the pairs' image codes: uint8 up to 256 images, int32
beyond) travels as an argument of its own.  This test runs the scenes that
make the types vary -- lists with few and with many images, every cutoff
form, per-atom energies and none, the RDFs -- in one process and reads the
signatures numba compiled.
"""

import sys

import numpy as np
from ase.build import bulk
from numba.core import types
from numba.core.dispatcher import Dispatcher

from ase_mlg import MLG, MLGCalculator
from ase_mlg.neighborlist import NeighborList, neighbor_list
from ase_mlg.potentials import LennardJones
from ase_mlg.query import exact_pairs


def _structures_seen():
    seen = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith("ase_mlg"):
            continue
        for value in vars(mod).values():
            disp = getattr(value, "_func", value)  # serialised threaded twins
            if not isinstance(disp, Dispatcher):
                continue
            for sig in disp.signatures:
                stack = list(sig)
                while stack:
                    t = stack.pop()
                    if isinstance(t, (types.NamedTuple, types.NamedUniTuple)):
                        cls = t.instance_class
                        seen.setdefault(f"{cls.__module__}.{cls.__name__}", set()).add(str(t))
                    if isinstance(t, types.BaseTuple):
                        stack.extend(t.types)
    return seen


def test_each_structure_has_one_type_whatever_the_codes():
    # 864 atoms: beyond the small-system path (allpairs.MAX_WORK), so the
    # calculator, neighbor_list and NeighborList take the block query
    few = bulk("Ar", "fcc", a=5.26, cubic=True).repeat(6)
    few.rattle(0.02, seed=1)
    many = bulk("Ar", "fcc", a=5.26)  # one atom: its own images, > 256 codes
    # the small path answers for one atom: the block query's scan with
    # int32 codes is run on its grid directly
    exact_pairs(MLG(many.positions, many.cell, many.pbc), 12.0)
    for atoms, rc in ((few, 6.0), (many, 12.0)):
        for energies in (False, True):
            atoms.calc = MLGCalculator(LennardJones(sigma=3.4, epsilon=0.0104, rc=rc))
            atoms.get_potential_energies() if energies else atoms.get_forces()
        for cutoff in (rc, [rc / 2] * len(atoms), {("Ar", "Ar"): rc}):
            neighbor_list("ijdDS", atoms, cutoff)
        for bothways in (False, True):
            NeighborList([rc / 2] * len(atoms), bothways=bothways).update(atoms)
    wide = {name: sorted(ts) for name, ts in _structures_seen().items() if len(ts) > 1}
    assert not wide, wide
    # the scenes did make both code dtypes (else this test proves nothing)
    from ase_mlg import query
    codes = {str(sig[-1].dtype) for sig in query._scan.signatures}
    assert codes == {"uint8", "int32"}, codes
