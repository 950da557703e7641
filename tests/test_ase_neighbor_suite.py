"""ASE's own neighbour-list tests, run against ase_mlg.

Each test file of the installed ``ase.test.neighbor`` package is loaded
afresh with importlib (so ``ase`` itself is untouched), the neighbour-list
names in its namespace are replaced by ours, and every ``test_*`` function is
run here with all the parameter sets of its ``pytest.mark.parametrize``
marks.  The functions take no fixtures; a function that asks for one fails
(it is never skipped silently).

Replaced names (where a file imports them): ``neighbor_list``,
``primitive_neighbor_list``, ``first_neighbors``, ``NeighborList``,
``PrimitiveNeighborList``, ``NewPrimitiveNeighborList``,
``get_connectivity_matrix`` and ``build_neighbor_list``, every name of
``ase.neighborlist`` that builds or reads a list.  ``mic`` (a geometry helper
the tests use to build their reference) is ASE's in both modules.

Inapplicable tests: none.  Every test function of ``test_neighbor_kernel.py``,
``test_neighbor.py`` and ``test_neighbor_initialization.py`` runs; ASE marks
two of them ``slow``, which we ignore here (they take well under a second
with the MLG).  Nothing in these files tests ``max_nbins`` memory behaviour,
which would have been the one ASE internal we do not reproduce (we accept and
ignore ``max_nbins``).
"""

import inspect

import pytest

import ase.test.neighbor as _ase_neighbor_tests

import ase_mlg.neighborlist as mlg_nl

import peer_suite

FILES = ["test_neighbor_kernel.py", "test_neighbor.py",
         "test_neighbor_initialization.py"]
REPLACED = ["neighbor_list", "primitive_neighbor_list", "first_neighbors",
            "NeighborList", "PrimitiveNeighborList", "NewPrimitiveNeighborList",
            "get_connectivity_matrix", "build_neighbor_list"]


def _load(fname):
    return peer_suite.load(_ase_neighbor_tests, fname,
                           {name: getattr(mlg_nl, name) for name in REPLACED},
                           "_mlg_ase_suite_")


def _expand(func):
    """All keyword sets of the function's parametrize marks."""
    axes = []
    for mark in getattr(func, "pytestmark", []):
        if mark.name != "parametrize":
            continue
        names, values = mark.args[:2]
        names = [n.strip() for n in names.split(",")] if isinstance(names, str) \
            else list(names)
        sets = []
        for v in values:
            v = v.values if hasattr(v, "values") and not isinstance(v, tuple) else v
            sets.append(dict(zip(names, v if len(names) > 1 else (v,))))
        axes.append(sets)
    combos = [{}]
    for sets in axes:
        combos = [{**c, **s} for c in combos for s in sets]
    return combos


def _cases():
    cases = []
    for fname in FILES:
        mod = _load(fname)
        for name, func in peer_suite.peer_tests(mod):
            for kw in _expand(func):
                label = ",".join(f"{k}={getattr(v, '__name__', v)}"
                                 for k, v in sorted(kw.items()))
                cases.append(pytest.param(mod, name, kw,
                                          id=f"{fname[:-3]}::{name}[{label}]"))
    return cases


CASES = _cases()


def test_suite_is_complete():
    """Every test function of the ASE files is collected here (guards against
    a new ASE version adding tests we would silently not run), and every
    list-bound name of ase.neighborlist is one we replace."""
    import ase.neighborlist as ase_nl
    for name in REPLACED:
        assert getattr(mlg_nl, name) is not getattr(ase_nl, name)
    assert mlg_nl.mic is ase_nl.mic
    names = {p.values[1] for p in CASES}
    for fname in FILES:
        expected = {n for n, _ in peer_suite.peer_tests(_load(fname))}
        assert expected <= names


@pytest.mark.parametrize("mod,name,kwargs", CASES)
def test_ase_neighbor_suite(mod, name, kwargs):
    func = getattr(mod, name)
    params = inspect.signature(func).parameters
    missing = set(params) - set(kwargs)
    assert not missing, f"{name} needs fixtures {missing}: run it by hand"
    # the names are ours in the module the function runs in
    for rname in REPLACED:
        if rname in vars(mod):
            assert getattr(mod, rname) is getattr(mlg_nl, rname)
    func(**kwargs)
