"""ase-mlg with ASE's own neighbour-list names pointing at ours (issue 18.1).

Code that makes ASE's calculators or analysis run on the MLG rebinds
``ase.neighborlist``'s names to ase-mlg's (attribute by attribute, or the
whole module in ``sys.modules``).  Then nothing in ase-mlg may look ASE's
classes up by name at call time: ``NewPrimitiveNeighborList(sorted=True)``
used to, and called itself until RecursionError.  ASE's own
``test_equivalence_of_primitive_classes`` is run here, loaded afresh after
the rebinding so that its ``from ase.neighborlist import ...`` gets ours.
"""

import itertools
import sys

import numpy as np
import pytest

import ase.neighborlist as ase_nl
import ase.test.neighbor as _ase_neighbor_tests

import ase_mlg.neighborlist as mlg_nl

import peer_suite

REBOUND = ["neighbor_list", "primitive_neighbor_list", "first_neighbors",
           "NeighborList", "PrimitiveNeighborList", "NewPrimitiveNeighborList",
           "get_connectivity_matrix", "build_neighbor_list"]
TEST = "test_equivalence_of_primitive_classes"


def _ase_params():
    """Every keyword set of ASE's own parametrize marks on TEST."""
    func = getattr(peer_suite.load(_ase_neighbor_tests, "test_neighbor.py",
                                   {}, "_mlg_rebound_probe_"), TEST)
    axes = [(m.args[0], m.args[1]) for m in func.pytestmark
            if m.name == "parametrize"]
    names = [a[0] for a in axes]
    return [dict(zip(names, vals))
            for vals in itertools.product(*(a[1] for a in axes))]


PARAMS = _ase_params()


def _rebind_attributes(monkeypatch):
    for name in REBOUND:
        monkeypatch.setattr(ase_nl, name, getattr(mlg_nl, name))


def _rebind_module(monkeypatch):
    monkeypatch.setitem(sys.modules, "ase.neighborlist", mlg_nl)


def test_params_cover_the_sorted_case():
    # the four sorted=True cases are the ones that recursed
    assert len(PARAMS) == 8
    assert sum(p["sort"] for p in PARAMS) == 4


@pytest.mark.parametrize("rebind", [_rebind_attributes, _rebind_module],
                         ids=["attributes", "sys.modules"])
@pytest.mark.parametrize("kwargs", PARAMS,
                         ids=lambda kw: ",".join(f"{k}={v}"
                                                 for k, v in kw.items()))
def test_ase_equivalence_with_ase_names_rebound(monkeypatch, rebind, kwargs):
    rebind(monkeypatch)
    mod = peer_suite.load(_ase_neighbor_tests, "test_neighbor.py", {},
                          "_mlg_rebound_")
    # the ASE test really runs ours, through ASE's own import
    assert mod.NewPrimitiveNeighborList is mlg_nl.NewPrimitiveNeighborList
    assert mod.PrimitiveNeighborList is mlg_nl.PrimitiveNeighborList
    getattr(mod, TEST)(**kwargs)


def test_sorted_order_is_ases_when_rebound(monkeypatch):
    """The repro of the issue: ASE's 880 pairs, in ASE's order, with ASE's
    class name bound to ours while the list is built."""
    cell = [[0, 3.37316113, 3.37316113], [3.37316113, 0, 3.37316113],
            [3.37316113, 3.37316113, 0]]
    spos = np.array([[0, 0, 0], [.25, .25, .25]])
    kw = dict(skin=0, sorted=True, self_interaction=False, bothways=True,
              use_scaled_positions=True)
    ref = ase_nl.NewPrimitiveNeighborList([8.0, 8.0], **kw)
    ref.update([True] * 3, cell, spos)
    monkeypatch.setattr(ase_nl, "NewPrimitiveNeighborList",
                        mlg_nl.NewPrimitiveNeighborList)
    ours = ase_nl.NewPrimitiveNeighborList([8.0, 8.0], **kw)
    assert isinstance(ours, mlg_nl.NewPrimitiveNeighborList)
    ours.update([True] * 3, cell, spos)
    assert len(ours.pair_first) == len(ref.pair_first) == 880
    np.testing.assert_array_equal(ours.pair_first, ref.pair_first)
    np.testing.assert_array_equal(ours.pair_second, ref.pair_second)
    np.testing.assert_array_equal(ours.offset_vec, ref.offset_vec)
