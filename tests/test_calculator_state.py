"""What the calculator keeps between calls (issue 18, points 2 and 9).

ASE's ``get_properties`` (``calculate_properties``) and a bare
``calc.calculate(atoms)`` pass ``all_changes``; the calculator decides what
changed from the atoms, so a valid grid and pair list survive.  Keywords a
potential does not take are refused, and the error says what it takes."""

import platform

import numpy as np
import pytest
from ase.build import bulk
from ase.calculators.lj import LennardJones as AseLJ
from ase.calculators.mixing import SumCalculator
from ase.md.verlet import VelocityVerlet
from ase import units

from ase_mlg import MLGCalculator
from ase_mlg.potentials import LennardJones, Morse

AR = dict(sigma=3.405, epsilon=0.0104, rc=8.5)


def argon(n=4, seed=0):
    atoms = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(n)
    atoms.rattle(0.05, seed=seed)
    return atoms


def ase_results(atoms):
    a = atoms.copy()
    a.calc = AseLJ(**AR, smooth=False)
    return a.get_potential_energy(), a.get_forces()


def test_get_properties_keeps_grid_and_list():
    atoms = argon()
    atoms.calc = calc = MLGCalculator(LennardJones(**AR))
    rng = np.random.default_rng(1)
    for _ in range(6):
        atoms.positions += rng.normal(scale=0.005, size=atoms.positions.shape)
        props = atoms.get_properties(["energy", "forces", "stress"])
        e, f = ase_results(atoms)
        assert props["energy"] == pytest.approx(e, rel=1e-12)
        np.testing.assert_allclose(props["forces"], f, atol=1e-12)
    # 256 atoms: the list comes from every atom pair, with no grid
    assert calc.stats["grid_builds"] == 0 and calc.stats["list_builds"] == 1, calc.stats
    # a bare calculate(atoms) passes all_changes by default
    atoms.positions += 0.001
    calc.calculate(atoms)
    assert calc.stats["grid_builds"] == 0 and calc.stats["list_builds"] == 1, calc.stats


def test_sum_calculator_md_stays_on_one_grid():
    atoms = argon(6)  # 864 atoms: beyond allpairs.MAX_WORK, the lists are the grid's
    atoms.calc = SumCalculator([MLGCalculator(LennardJones(**AR)),
                                MLGCalculator(Morse(epsilon=1e-4, r0=4.0, rho0=3.0))])
    VelocityVerlet(atoms, 2 * units.fs).run(20)
    for calc in atoms.calc.mixer.calcs:
        assert calc.stats["grid_builds"] == 1, calc.stats
        assert calc.stats["calls"] >= 20


def test_real_changes_still_rebuild():
    atoms = argon()
    atoms.calc = calc = MLGCalculator(LennardJones(**AR))
    atoms.get_potential_energy()
    # same positions, other numbers: the list's types must be rebuilt
    atoms.numbers[:5] = 36
    calc.calculate(atoms, ["energy", "forces"])
    assert calc.stats["list_builds"] == 2
    # pbc off: another set of pairs, the answer must be ASE's
    atoms.numbers[:] = 18
    atoms.pbc = False
    calc.calculate(atoms, ["energy", "forces"])
    e, f = ase_results(atoms)
    assert calc.results["energy"] == pytest.approx(e, rel=1e-12)
    np.testing.assert_allclose(calc.results["forces"], f, atol=1e-12)
    assert calc.stats["list_builds"] == 3


def test_stored_atoms_hold_what_the_call_reads():
    """The calculator's copy of the atoms keeps numbers, positions, cell and
    pbc (what check_state compares), not the momenta (23 MB at 10^6
    atoms); new momenta are no system change, new positions are."""
    atoms = argon()
    atoms.set_momenta(np.ones((len(atoms), 3)))
    atoms.calc = calc = MLGCalculator(LennardJones(**AR))
    atoms.get_potential_energy()
    assert sorted(calc.atoms.arrays) == ["numbers", "positions"]
    np.testing.assert_array_equal(calc.atoms.cell.array, atoms.cell.array)
    assert not np.shares_memory(calc.atoms.positions, atoms.positions)
    atoms.set_momenta(2 * np.ones((len(atoms), 3)))
    assert calc.check_state(atoms) == []
    atoms.positions[0, 0] += 1e-3
    assert calc.check_state(atoms) == ["positions"]
    e, _ = ase_results(atoms)
    assert atoms.get_potential_energy() == pytest.approx(e, rel=1e-12)


@pytest.mark.parametrize("edits", [(), ("positions",), ("numbers",), ("cell",), ("pbc",),
                                   ("numbers", "pbc"), ("positions", "numbers", "cell", "pbc")])
def test_check_state_names_what_changed_as_ase_does(edits):
    """check_state compares numbers, cell and pbc as one key of bytes kept
    with the stored atoms, then names the ones that changed: the names of
    ASE's own compare_atoms, for the smallest change of each; a stored copy
    without the key (assigned from outside) is compared field by field."""
    from ase.calculators.calculator import compare_atoms
    atoms = argon()
    atoms.calc = calc = MLGCalculator(LennardJones(**AR))
    atoms.get_potential_energy()
    assert calc.check_state(atoms) == []
    if "positions" in edits:
        atoms.positions[3, 1] += 1e-9
    if "numbers" in edits:
        atoms.numbers[7] = 36
    if "cell" in edits:
        atoms.cell[2, 2] *= 1.0 + 1e-15
    if "pbc" in edits:
        atoms.pbc[1] = False
    want = [k for k in ("positions", "numbers", "cell", "pbc") if k in edits]
    assert calc.check_state(atoms) == want
    assert set(compare_atoms(calc.atoms, atoms, tol=0.0)) == set(edits)
    calc.atoms = calc.atoms.copy()  # no key
    assert calc.check_state(atoms) == want


def test_a_refused_call_leaves_every_change_to_be_seen():
    """Complex positions on a later call are refused (a new copy keeps
    their dtype; they were cast into the last call's array, with a warning
    and an energy), and a call refused before the list took the atoms
    stores nothing: the next one, positions mended, sees the new cell and
    numbers (not compared again when ASE's check found them unchanged) and
    gives ASE's answer."""
    from ase_mlg.potentials import lennard_jones_mixture
    atoms = argon()
    atoms.calc = calc = MLGCalculator(lennard_jones_mixture(
        {"Ar": 3.405, "Kr": 3.6}, {"Ar": 0.0104, "Kr": 0.014}, rc=8.5))
    atoms.get_potential_energy()
    good = atoms.positions.copy()
    atoms.numbers[:7] = 36
    atoms.set_cell(atoms.cell * 1.01, scale_atoms=False)
    atoms.arrays["positions"] = good + 0.5j
    with pytest.raises(TypeError, match="positions"):
        atoms.get_potential_energy()
    assert calc.atoms is None
    atoms.arrays["positions"] = good
    fresh = atoms.copy()
    fresh.calc = MLGCalculator(calc.potential)
    assert atoms.get_potential_energy() == fresh.get_potential_energy()
    np.testing.assert_array_equal(atoms.get_forces(), fresh.get_forces())


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="malloc_trim is glibc's")
def test_builds_hand_freed_memory_back_on_glibc():
    """Lists from verletlist.TRIM_ATOMS atoms trim glibc's heap after a
    build (110 MB kept at 10^6 atoms otherwise): with glibc the trimmer is
    found."""
    from ase_mlg import verletlist
    assert verletlist._malloc_trim is not None
    assert verletlist._malloc_trim(0) in (0, 1)


@pytest.mark.parametrize("make, names", [
    (lambda: Morse(A=4.0, epsilon=1.0, r0=2.55), ("'A'", "epsilon, r0, rho0, rcut1, rcut2")),
    (lambda: LennardJones(sigma=1.0, cutoff=3.0), ("'cutoff'", "sigma, epsilon, rc, ro, smooth")),
    (lambda: MLGCalculator(Morse(), A=4.0), ("'A'", "potential, template, skin")),
])
def test_ignored_keywords_are_refused_naming_what_is_taken(make, names):
    with pytest.raises(TypeError) as info:
        make()
    for name in names:
        assert name in str(info.value)


@pytest.mark.parametrize("n", [3, 50, 3000, 9000])
@pytest.mark.parametrize("dtype", [np.float64, np.int64, np.bool_])
def test_same_is_array_equal(n, dtype):
    # small arrays by bytes or lists, large ones (over 64 KiB) word by word,
    # compiled: the answer is np.array_equal's, but for the sign of a large
    # float zero (stricter) and identical NaN bits (equal, as ASE's check)
    from ase_mlg.geometry import same
    rng = np.random.default_rng(n)
    a = (rng.normal(size=(n, 3)) * 10).astype(dtype)
    for where in (0, n // 2, n - 1):
        b = a.copy()
        b[where, 2] = b[where, 2] + 1 if dtype is not np.bool_ else not b[where, 2]
        assert not same(a, b) and not same(b, a)
    assert same(a, a.copy()) and not same(a, a[:-1])
    assert same(a, a.astype(np.float32)) == np.array_equal(a, a.astype(np.float32))
    if dtype is np.float64:
        z = a.copy()
        z[-1, -1] = 0.0
        nz = z.copy()
        nz[-1, -1] = -0.0
        assert same(z, nz) == (z.nbytes <= 1 << 16)
        nan = z.copy()
        nan[-1, -1] = np.nan
        assert same(nan, nan.copy()) == (z.nbytes > 1 << 16)
