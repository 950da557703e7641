"""ASE's own LJ and Morse calculator tests, run against MLGCalculator.

``ase/test/calculator/test_lj.py`` and ``test_morse.py`` of the installed
ASE are loaded afresh with importlib (``ase`` itself is untouched), their
calculator names are replaced by constructors of ours, and every ``test_*``
function runs here, as ``tests/test_ase_neighbor_suite.py`` does for the
neighbour list.

Replaced names:

* ``LennardJones`` -> ``MLGCalculator(ase_mlg.potentials.LennardJones(
  sigma, epsilon, rc, ro, smooth))``
* ``MorsePotential`` -> ``MLGCalculator(ase_mlg.potentials.Morse(epsilon,
  r0, rho0, rcut1, rcut2))``

ASE's keyword arguments map one to one.  ``MorsePotential(A=4.0, ...)`` in
``test_forces_and_stress`` passes a parameter ASE's Morse never reads (a
``Calculator`` stores unknown keywords and ignores them); the constructor
drops it likewise.  Everything else in the files (``fcut``, ``fcut_d``,
finite differences, ``Vibrations``) stays ASE's.

Fixtures: ``testdir`` (ASE's: run in a fresh temporary directory) is
provided; any other fixture a test asks for makes it fail, never skip.

Inapplicable: ``test_morse.py::test_override_neighbor_list`` checks that
``MorsePotential(neighbor_list=f)`` calls ``f``.  MLGCalculator finds its
pairs on its own grid and has no neighbour-list hook; in its place we check
that passing one is refused with a clear error (instead of being stored and
ignored, which would also break ``todict()``'s JSON).
"""

import inspect

import pytest

import ase.test.calculator as _ase_calc_tests

from ase_mlg import MLGCalculator
from ase_mlg import potentials as mlg_pot

import peer_suite

FILES = ["test_lj.py", "test_morse.py"]


def LennardJones(sigma=1.0, epsilon=1.0, rc=None, ro=None, smooth=False,
                 **kwargs):
    """``ase.calculators.lj.LennardJones``'s signature, our calculator."""
    return MLGCalculator(mlg_pot.LennardJones(sigma=sigma, epsilon=epsilon,
                                              rc=rc, ro=ro, smooth=smooth),
                         **kwargs)


def MorsePotential(epsilon=1.0, r0=1.0, rho0=6.0, rcut1=1.9, rcut2=2.7,
                   A=None, **kwargs):
    """``ase.calculators.morse.MorsePotential``'s signature, our calculator
    (``A`` is accepted and unused, as in ASE)."""
    return MLGCalculator(mlg_pot.Morse(epsilon=epsilon, r0=r0, rho0=rho0,
                                       rcut1=rcut1, rcut2=rcut2), **kwargs)


REPLACED = {"LennardJones": LennardJones, "MorsePotential": MorsePotential}
# tests that cannot apply: (file, test) -> (the reason, the error ASE's test
# then meets with ours, a regex); each runs, and must fail with that error,
# and a replacement check runs in its place
INAPPLICABLE = {
    ("test_morse.py", "test_override_neighbor_list"):
        ("MLGCalculator has no neighbour-list hook (it queries its own MLG)",
         "neighbor_list"),
}


MODULES = {fname: peer_suite.load(_ase_calc_tests, fname, REPLACED,
                                  "_mlg_ase_calc_suite_")
           for fname in FILES}


def _cases():
    cases = []
    for fname, mod in MODULES.items():
        for name, func in peer_suite.peer_tests(mod):
            assert not any(m.name == "parametrize"
                           for m in getattr(func, "pytestmark", [])), \
                f"{fname}::{name} is parametrized: expand it here"
            cases.append(pytest.param(fname, name, id=f"{fname[:-3]}::{name}"))
    return cases


CASES = _cases()


def test_suite_is_complete():
    """Both files are there, hold the tests we know, and every name we
    replace exists in them (a new ASE renaming one would otherwise leave
    ASE's calculator under test)."""
    names = {(p.values[0], p.values[1]) for p in CASES}
    assert ("test_lj.py", "test_bulk_stress") in names
    assert ("test_morse.py", "test_forces_and_stress") in names
    assert len(names) >= 10
    assert set(INAPPLICABLE) <= names
    assert vars(MODULES["test_lj.py"])["LennardJones"] is LennardJones
    assert vars(MODULES["test_morse.py"])["MorsePotential"] is MorsePotential


@pytest.mark.parametrize("fname,name", CASES)
def test_ase_calculator_suite(fname, name, tmp_path, monkeypatch):
    mod = MODULES[fname]
    func = getattr(mod, name)
    # the calculators in the module are ours
    for rname, ours in REPLACED.items():
        if rname in vars(mod):
            assert getattr(mod, rname) is ours
    kwargs = {}
    for pname in inspect.signature(func).parameters:
        assert pname == "testdir", f"{name} needs fixture {pname!r}: run it by hand"
        monkeypatch.chdir(tmp_path)
        kwargs[pname] = tmp_path
    if (fname, name) in INAPPLICABLE:
        # ASE's test fails on ours, for the reason given (once it passes,
        # the test applies: drop it from INAPPLICABLE) ...
        _reason, error = INAPPLICABLE[fname, name]
        with pytest.raises((TypeError, ValueError), match=error):
            func(**kwargs)
        # ... and in its place: the hook is refused, not stored and ignored
        def fake_neighbor_list(*args, **kw):
            raise RuntimeError("test_neighbor_list")
        with pytest.raises((TypeError, ValueError), match="neighbor_list"):
            mod.MorsePotential(A=4.0, epsilon=1.0, r0=2.55,
                               neighbor_list=fake_neighbor_list)
        return
    func(**kwargs)
