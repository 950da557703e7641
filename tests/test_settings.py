"""Every setting a user changes takes effect or is refused (issue 25, items
1-3): a new potential, ``calc.set``, assignments, meaningless values.

Each test compares with ASE's LJ or with a calculator built afresh with the
new settings: the settings are in force when the numbers are those of a
calculator that had them from the start.
"""

import json

import numpy as np
import pytest
from ase.build import bulk
from ase.calculators.lj import LennardJones as AseLJ

from ase_mlg import MLGCalculator
from ase_mlg.autotemplate import AutoTemplate, parse_widths
from ase_mlg.potentials import LennardJones, Morse, lennard_jones_mixture

AR = dict(sigma=3.405, epsilon=0.0104)


def argon(n=3, seed=1):
    atoms = bulk("Ar", "fcc", a=5.26, cubic=True).repeat(n)
    atoms.rattle(0.1, seed=seed)
    return atoms


def ase_energy(atoms, **kw):
    ref = atoms.copy()
    ref.calc = AseLJ(**{**AR, **kw})
    return ref.get_potential_energy(), ref.get_forces()


def fresh(atoms, *args, **kwargs):
    other = atoms.copy()
    other.calc = MLGCalculator(*args, **kwargs)
    return other.get_potential_energy(), other.get_forces()


def assert_is(atoms, ref):
    e, f = ref
    assert atoms.get_potential_energy() == pytest.approx(e, rel=1e-12, abs=1e-13)
    np.testing.assert_allclose(atoms.get_forces(), f, rtol=1e-10, atol=1e-12)


# -- item 1: a new potential brings its radius and its species ---------------

@pytest.mark.parametrize("reset", [True, False])
def test_a_new_potential_brings_its_cutoff(reset):
    atoms = argon()
    calc = MLGCalculator(LennardJones(**AR, rc=6.0))
    atoms.calc = calc
    assert_is(atoms, ase_energy(atoms, rc=6.0))
    calc.potential = LennardJones(**AR, rc=10.0)
    if reset:
        calc.reset()
    assert_is(atoms, ase_energy(atoms, rc=10.0))  # was the rc = 6 list: -8.449 vs -8.859
    assert calc.verlet_list.cutoff == 10.0


def test_a_new_potential_brings_its_species():
    atoms = argon()
    atoms.symbols[:] = "Kr"
    atoms.symbols[::2] = "Xe"
    one = lennard_jones_mixture({"Kr": 3.6, "Xe": 3.9}, {"Kr": 0.014, "Xe": 0.019}, rc=7.0)
    two = lennard_jones_mixture({"Ar": 3.4, "Kr": 3.6, "Xe": 3.9},
                                {"Ar": 0.0104, "Kr": 0.014, "Xe": 0.019}, rc=7.0)
    assert one.prepare(atoms.numbers)[0][0] != two.prepare(atoms.numbers)[0][0]  # types differ
    calc = MLGCalculator(one)
    atoms.calc = calc
    atoms.get_potential_energy()
    calc.potential = two
    assert_is(atoms, fresh(atoms, two))


def test_a_refused_potential_changes_nothing():
    atoms = argon()
    calc = MLGCalculator(LennardJones(**AR, rc=6.0))
    atoms.calc = calc
    e = atoms.get_potential_energy()
    with pytest.raises(TypeError, match="potential"):
        calc.potential = "LJ"
    assert calc.potential.rc == 6.0
    assert atoms.get_potential_energy() == e


# -- item 2: set() and assignments take effect --------------------------------

def test_set_sigma_and_skin_take_effect_as_ase_s_set():
    atoms = argon()
    calc = MLGCalculator(LennardJones(**AR, rc=8.0))
    atoms.calc = calc
    atoms.get_potential_energy()
    changed = calc.set(sigma=3.0, skin=0.0)
    assert changed == {"sigma": 3.0, "skin": 0.0}
    assert calc.skin == calc.verlet_list.skin == 0.0
    assert calc.potential.sigma == 3.0 and calc.potential.rc == 8.0  # rc stays, as ASE's
    ref = AseLJ(**AR, rc=8.0)
    ref.set(sigma=3.0)
    assert_is(atoms, ase_energy(atoms, sigma=3.0, rc=8.0))
    assert calc.set(sigma=3.0) == {}  # nothing changed: nothing returned, nothing dropped


@pytest.mark.parametrize("name, value", [("skin", 3.0), ("template", 5), ("template", "auto"),
                                         ("grid_kwargs", {"method": "sort"})])
def test_assignment_takes_effect_and_todict_records_it(name, value):
    atoms = argon()
    calc = MLGCalculator(LennardJones(**AR, rc=6.0))
    atoms.calc = calc
    atoms.get_potential_energy()
    setattr(calc, name, value)
    want = {"template": None, "skin": 1.0, "grid_kwargs": None, name: value}
    assert_is(atoms, fresh(atoms, LennardJones(**AR, rc=6.0), **want))
    d = json.loads(json.dumps(calc.todict()))
    assert d[name] == value
    vl = calc.verlet_list
    if name == "skin":
        assert vl.skin == 3.0 and vl.rlist == 9.0
    elif value == 5:
        assert calc.template == vl.width == 5
    elif value == "auto":
        assert calc.auto is not None and callable(vl.template)
    else:
        assert calc.grid.method == "sort"
        with pytest.raises(TypeError):
            calc.grid_kwargs["method"] = "kd"  # a view: a mutation would be ignored


def test_potential_arguments_are_read_only():
    pot = LennardJones(**AR)
    with pytest.raises(AttributeError, match=r"sigma is read-only.*calc.set\(sigma"):
        pot.sigma = 2.0
    with pytest.raises(AttributeError, match="r0 is read-only"):
        Morse().r0 = 2.0
    assert pot.replace(sigma=2.0).sigma == 2.0 and pot.sigma == 3.405


def test_set_refuses_what_it_cannot_use_and_changes_nothing():
    atoms = argon()
    calc = MLGCalculator(LennardJones(**AR, rc=6.0))
    atoms.calc = calc
    e = atoms.get_potential_energy()
    with pytest.raises(TypeError, match=r"'r0'.*own settings are potential, template, skin"):
        calc.set(r0=1.0, skin=0.0)
    with pytest.raises(ValueError, match="skin"):
        calc.skin = -1.0
    with pytest.raises(TypeError, match="grid_kwargs: MLG takes no 'sweeps'"):
        calc.set(grid_kwargs={"sweeps": 3})
    with pytest.raises(TypeError, match="no named arguments"):
        MLGCalculator(lennard_jones_mixture({"Ar": 3.4}, {"Ar": 0.01})).set(sigma=3.0)
    assert calc.skin == 1.0 and calc.potential.rc == 6.0 and atoms.get_potential_energy() == e


# -- item 3: meaningless values refused ---------------------------------------

@pytest.mark.parametrize("kwargs, match", [
    ({"template": 1}, r"odd int >= 3 \(W = 1 holds no pairs\)"),
    ({"template": -3}, "odd int >= 3"),
    ({"template": "auto", "tolerance": {"missed": 2}}, r"0 <= missed < 1"),
    ({"template": "auto", "tolerance": 1.0}, r"0 <= missed < 1"),
    ({"template": "auto", "tolerance": {"force": -1}}, ">= 0"),
])
def test_meaningless_template_and_tolerance_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MLGCalculator(LennardJones(**AR), **kwargs)
    calc = MLGCalculator(LennardJones(**AR))
    with pytest.raises(ValueError, match=match):
        calc.set(**kwargs)
    assert calc.template is None and calc.auto is None


def test_width_one_is_refused_everywhere_widths_are_taken():
    with pytest.raises(ValueError, match="W = 1 holds no pairs"):
        parse_widths([1, 3])
    with pytest.raises(ValueError, match="widths"):
        AutoTemplate(widths=[1])
    with pytest.raises(ValueError, match=r"missed.*< 1"):
        AutoTemplate({"missed": 1.5})
