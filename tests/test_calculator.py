"""MLGCalculator against ASE's own LennardJones and MorsePotential."""

import numpy as np
import pytest
from ase.calculators.calculator import PropertyNotImplementedError
from ase.calculators.lj import LennardJones as AseLJ
from ase.calculators.morse import MorsePotential as AseMorse
from ase.md.velocitydistribution import thermalize_momenta
from ase.md.verlet import VelocityVerlet
from ase import units

from ase_mlg import MLGCalculator
from ase_mlg.potentials import LennardJones, Morse, lennard_jones_mixture
from ase_mlg.scenes import SCENES, make_scene

import naive

SCENE_NAMES = sorted(SCENES)
METAL = {"copper", "sheared", "slab", "small", "nanoparticle"}


def lj_params(name):
    # Cu-like LJ for the metal scenes (rc 5 Å as in docs/design.md §9), argon otherwise
    return (2.3, 0.4, 5.0) if name in METAL else (3.405, 0.0104, 8.5)


def scene(name, n=600):
    atoms = make_scene(name, n)
    atoms.rattle(0.05, seed=3)
    return atoms


def compare(atoms, ref_calc, calc):
    ref = atoms.copy()
    ref.calc = ref_calc
    ours = atoms.copy()
    ours.calc = calc
    e0, e1 = ref.get_potential_energy(), ours.get_potential_energy()
    assert e1 == pytest.approx(e0, rel=1e-10, abs=1e-12)
    np.testing.assert_allclose(ours.get_potential_energies(),
                               ref.get_potential_energies(), rtol=1e-10, atol=1e-12)
    f0, f1 = ref.get_forces(), ours.get_forces()
    np.testing.assert_allclose(f1, f0, rtol=1e-9, atol=1e-12 + 1e-9 * np.abs(f0).max())
    if atoms.cell.rank == 3:
        s0, s1 = ref.get_stress(), ours.get_stress()
        np.testing.assert_allclose(s1, s0, rtol=1e-9, atol=1e-12 + 1e-9 * np.abs(s0).max())
        # per-atom stresses sum to the stress
        np.testing.assert_allclose(ours.get_stresses().sum(axis=0), s1,
                                   rtol=1e-9, atol=1e-14)
    else:
        with pytest.raises(PropertyNotImplementedError):
            ours.get_stress()
    return ours


@pytest.mark.parametrize("name", SCENE_NAMES)
@pytest.mark.parametrize("smooth", [False, True])
def test_exact_lj_matches_ase(name, smooth):
    sigma, eps, rc = lj_params(name)
    atoms = scene(name)
    compare(atoms, AseLJ(sigma=sigma, epsilon=eps, rc=rc, smooth=smooth),
            MLGCalculator(LennardJones(sigma=sigma, epsilon=eps, rc=rc, smooth=smooth)))


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_exact_morse_matches_ase(name):
    atoms = scene(name)
    kw = dict(epsilon=0.35, r0=2.55, rho0=6.0)
    if name not in METAL:
        kw = dict(epsilon=0.0104, r0=3.8, rho0=6.0)
    compare(atoms, AseMorse(**kw), MLGCalculator(Morse(**kw)))


def test_big_triclinic_and_small_cell_many_images():
    # cutoff longer than the whole cell: each atom meets dozens of images
    atoms = make_scene("small")
    atoms.rattle(0.05, seed=1)
    compare(atoms, AseLJ(sigma=2.3, epsilon=0.4, rc=9.0),
            MLGCalculator(LennardJones(sigma=2.3, epsilon=0.4, rc=9.0)))


def test_forces_are_minus_energy_gradient_and_stress_is_strain_derivative():
    atoms = scene("liquid", 108)
    calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5, smooth=True))
    atoms.calc = calc
    f = atoms.get_forces()
    h = 1e-5
    for a, c in [(0, 0), (5, 1), (17, 2), (50, 0)]:
        p = atoms.positions.copy()
        p[a, c] += h
        atoms.positions = p
        ep = atoms.get_potential_energy()
        p[a, c] -= 2 * h
        atoms.positions = p
        em = atoms.get_potential_energy()
        p[a, c] += h
        atoms.positions = p
        assert f[a, c] == pytest.approx(-(ep - em) / (2 * h), rel=1e-5, abs=1e-8)
    stress = atoms.get_stress(voigt=False)
    cell0 = atoms.cell.array.copy()
    V = atoms.get_volume()
    for (k, l) in [(0, 0), (1, 2), (2, 1), (0, 1)]:
        eps = np.zeros((3, 3))
        eps[k, l] = h
        es = []
        for sgn in (1, -1):
            atoms.set_cell(cell0 @ (np.eye(3) + sgn * eps), scale_atoms=True)
            es.append(atoms.get_potential_energy())
        atoms.set_cell(cell0, scale_atoms=True)
        assert stress[k, l] == pytest.approx((es[0] - es[1]) / (2 * h) / V, rel=1e-5, abs=1e-10)


def test_md_reuses_grid_and_list_and_stays_exact():
    atoms = scene("liquid", 500)
    thermalize_momenta(atoms, temperature_K=120, rng=np.random.default_rng(0))
    ref = atoms.copy()
    pot = LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)
    atoms.calc = MLGCalculator(pot, skin=0.5)
    ref.calc = AseLJ(sigma=3.405, epsilon=0.0104, rc=8.5)
    dyn, dref = VelocityVerlet(atoms, 5 * units.fs), VelocityVerlet(ref, 5 * units.fs)
    for _ in range(10):
        dyn.run(5)
        dref.run(5)
        np.testing.assert_allclose(atoms.get_forces(), ref.get_forces(), atol=1e-9)
        assert atoms.get_potential_energy() == pytest.approx(ref.get_potential_energy(), rel=1e-9)
    st = atoms.calc.stats
    # 500 atoms: the lists come from every atom pair, with no grid
    # (VerletList.build); test_forcepath's NPT run keeps one grid
    assert st["grid_builds"] == 0
    assert 1 < st["list_builds"] < st["calls"]
    grid = atoms.calc.grid  # built when asked for, at the last build's positions
    assert grid.natoms == len(atoms) and grid.is_monotone() and st["grid_builds"] == 0
    assert atoms.calc.stats["grid_builds"] == 1


def test_template_mode_is_approximate_but_close_and_counts_pairs():
    atoms = scene("liquid", 2000)
    pot = LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)
    exact = atoms.copy()
    exact.calc = MLGCalculator(pot)
    e0 = exact.get_potential_energy()
    errs = []
    for w in (5, 7, 9):
        a = atoms.copy()
        a.calc = MLGCalculator(pot, template=w)
        errs.append(abs(a.get_potential_energy() - e0) / len(a))
        assert a.calc.stats["pairs"] <= exact.calc.stats["pairs"]
    assert errs[0] > errs[1] >= errs[2]
    assert errs[2] < 1e-6


def test_binary_mixture_matches_brute_force():
    atoms = make_scene("mixture", 256)
    sigma, epsilon = {"Ar": 3.405, "Kr": 3.6}, {"Ar": 0.0104, "Kr": 0.014}
    pot = lennard_jones_mixture(sigma=sigma, epsilon=epsilon, rc=8.5)
    atoms.calc = MLGCalculator(pot)
    e = atoms.get_potential_energy()

    def pair(r, a, b):  # Lorentz-Berthelot LJ, shifted at rc = 8.5 Å
        return naive.lj(r, *naive.lorentz_berthelot(sigma[a], sigma[b], epsilon[a],
                                                    epsilon[b]), 8.5)

    ref = naive.energy(atoms, pair, cutoff=pot.cutoff)
    assert e == pytest.approx(ref, rel=1e-12)


@pytest.mark.parametrize("kwargs,match", [
    (dict(template=4), "template"),
    (dict(template=0), "template"),
    (dict(template=True), "template"),
    (dict(skin=-1.0), "skin"),
    (dict(skin=float("nan")), "skin"),
])
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MLGCalculator(LennardJones(), **kwargs)


def test_bad_potential_type():
    with pytest.raises(TypeError, match="potential"):
        MLGCalculator(AseLJ())


def test_coincident_atoms_and_nan_positions_are_named():
    atoms = scene("liquid", 108)
    atoms.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
    p = atoms.positions.copy()
    p[7] = p[3]
    atoms.positions = p
    with pytest.raises(ValueError, match=r"\b3\b.*\b7\b|\b7\b.*\b3\b"):
        atoms.get_potential_energy()
    p[7, 1] = np.nan
    atoms.positions = p
    with pytest.raises(ValueError, match="7"):
        atoms.get_forces()
