"""Tests for ase_mlg.potentials: agreement with ASE's LJ and Morse
calculators, finite differences, a plain-Python reference, bad input."""

import os
import subprocess
import sys

import numba
import numpy as np
import pytest
from ase import Atoms
from ase.build import bulk
from ase.calculators.calculator import PropertyNotImplementedError
from ase.calculators.lj import LennardJones as AseLJ
from ase.calculators.morse import MorsePotential as AseMorse
from ase.cluster import Icosahedron
from ase.neighborlist import neighbor_list
from ase.stress import full_3x3_to_voigt_6_stress
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from ase_mlg import MLGCalculator
from ase_mlg import potentials as P
from ase_mlg.pairsum import (PairError, SumList, SumTables,
                             first_bad_pair, is_built_in, pair_kernel)
from ase_mlg.chunks import RowChunks
from ase_mlg.pairfunctions import lennard_jones_shifted_r2, morse
from ase_mlg.potentials import (LennardJones, Morse, PairPotential,
                                lennard_jones_mixture)

import naive

AR = dict(sigma=3.405, epsilon=0.0104, rc=8.5)
CU = dict(epsilon=0.35, r0=2.55, rho0=6.0, rcut1=1.9, rcut2=2.7)
E_RTOL = 1e-10
F_RTOL, F_ATOL = 1e-9, 1e-12


# ---------------------------------------------------------------- helpers

def half_list(atoms, cutoff):
    """Each (i, j, S) once: i < j, or i == j with S lexicographically > 0."""
    i, j, d, D, S = neighbor_list('ijdDS', atoms, cutoff)
    s0, s1, s2 = S.T
    positive = (s0 > 0) | ((s0 == 0) & ((s1 > 0) | ((s1 == 0) & (s2 > 0))))
    keep = (i < j) | ((i == j) & positive)
    return i[keep], j[keep], D[keep], d[keep]


def run(pot, atoms, skin=0.7, **kw):
    # A skin beyond the cutoff checks that far pairs are ignored.
    i, j, D, d = half_list(atoms, pot.cutoff + skin)
    return pot.evaluate(atoms.numbers, i, j, D, d, **kw)


def voigt_per_atom(virials, volume):
    return np.array([full_3x3_to_voigt_6_stress(-w / volume)
                     for w in virials])


def fcc_ar(size=3, rattle=0.0, seed=1):
    atoms = bulk('Ar', 'fcc', a=5.26, cubic=True).repeat(size)
    if rattle:
        atoms.rattle(rattle, seed=seed)
    return atoms


def liquid_ar(seed=2):
    # Large random displacements of a slightly expanded fcc: liquid-like.
    atoms = bulk('Ar', 'fcc', a=5.6, cubic=True).repeat(3)
    rng = np.random.default_rng(seed)
    atoms.positions += rng.uniform(-0.6, 0.6, atoms.positions.shape)
    return atoms


def sheared(atoms):
    atoms = atoms.copy()
    shear = np.array([[1.0, 0.0, 0.0], [0.31, 1.0, 0.0], [-0.17, 0.22, 1.05]])
    atoms.set_cell(atoms.cell[:] @ shear, scale_atoms=True)
    atoms.rattle(0.05, seed=3)
    return atoms


def compare(atoms, pot, calc, stresses=True):
    res = run(pot, atoms)
    atoms = atoms.copy()
    atoms.calc = calc
    assert res['energy'] == pytest.approx(atoms.get_potential_energy(),
                                          rel=E_RTOL)
    np.testing.assert_allclose(res['energies'], atoms.get_potential_energies(),
                               rtol=E_RTOL, atol=1e-14)
    np.testing.assert_allclose(res['forces'], atoms.get_forces(),
                               rtol=F_RTOL, atol=F_ATOL)
    assert res['energies'].sum() == pytest.approx(res['energy'], rel=1e-12)
    np.testing.assert_allclose(res['virials'].sum(axis=0), res['virial'],
                               rtol=1e-12, atol=F_ATOL)
    volume = atoms.get_volume()
    np.testing.assert_allclose(
        full_3x3_to_voigt_6_stress(-res['virial'] / volume),
        atoms.get_stress(), rtol=F_RTOL, atol=F_ATOL)
    if stresses:
        np.testing.assert_allclose(
            voigt_per_atom(res['virials'], volume),
            atoms.get_stresses(), rtol=F_RTOL, atol=F_ATOL)
        np.testing.assert_allclose(
            -res['virials_voigt'] / volume,
            atoms.get_stresses(), rtol=F_RTOL, atol=F_ATOL)
        np.testing.assert_allclose(atoms.get_stresses().sum(axis=0),
                                   atoms.get_stress(), rtol=1e-12,
                                   atol=F_ATOL)
    return res


# ---------------------------------------------------------------- vs ASE

LJ_SYSTEMS = {
    'fcc': lambda: fcc_ar(3, rattle=0.1),
    'liquid': liquid_ar,
    'triclinic': lambda: sheared(fcc_ar(3)),
    'small_cell': lambda: fcc_ar(1, rattle=0.2),
}


@pytest.mark.parametrize('smooth', [False, True])
@pytest.mark.parametrize('system', sorted(LJ_SYSTEMS))
def test_lj_matches_ase(system, smooth):
    atoms = LJ_SYSTEMS[system]()
    compare(atoms, LennardJones(**AR, smooth=smooth),
            AseLJ(**AR, smooth=smooth))


def test_small_cell_has_self_images():
    # Guards the test above: rc > half the box really produces i == j pairs.
    atoms = fcc_ar(1, rattle=0.2)
    i, j, _, _ = half_list(atoms, AR['rc'])
    assert AR['rc'] > atoms.cell.lengths().max() / 2
    assert np.any(i == j)


def test_perfect_fcc_forces_vanish():
    res = compare(fcc_ar(3), LennardJones(**AR), AseLJ(**AR))
    np.testing.assert_allclose(res['forces'], 0.0, atol=F_ATOL)


@pytest.mark.parametrize('smooth', [False, True])
def test_lj_default_parameters_match_ase(smooth):
    # rc = 3 sigma and ro = 0.66 rc in reduced units.
    atoms = bulk('Ar', 'fcc', a=1.6, cubic=True).repeat(2)
    atoms.rattle(0.05, seed=4)
    pot = LennardJones(smooth=smooth)
    assert pot.rc == 3.0 and pot.ro == pytest.approx(1.98)
    compare(atoms, pot, AseLJ(smooth=smooth))


def nanoparticle():
    atoms = Icosahedron('Ar', noshells=3, latticeconstant=5.26)
    atoms.rattle(0.1, seed=5)
    return atoms


@pytest.mark.parametrize('smooth', [False, True])
def test_lj_nanoparticle_without_cell(smooth):
    atoms = nanoparticle()
    assert not atoms.pbc.any() and atoms.cell.rank == 0
    pot = LennardJones(**AR, smooth=smooth)
    res = run(pot, atoms)
    atoms.calc = AseLJ(**AR, smooth=smooth)
    assert res['energy'] == pytest.approx(atoms.get_potential_energy(),
                                          rel=E_RTOL)
    np.testing.assert_allclose(res['energies'], atoms.get_potential_energies(),
                               rtol=E_RTOL)
    np.testing.assert_allclose(res['forces'], atoms.get_forces(),
                               rtol=F_RTOL, atol=F_ATOL)
    # ASE has no stress without a cell; the virial is still well defined:
    # for a finite system it is sum_i r_i (x) F_i.
    with pytest.raises(PropertyNotImplementedError):
        atoms.get_stress()
    np.testing.assert_allclose(
        res['virial'], atoms.positions.T @ res['forces'], rtol=1e-9,
        atol=1e-10)


def test_lj_nanoparticle_in_vacuum_cell():
    # pbc=False but a 3-D cell: ASE's LJ reports stress (virial / volume).
    atoms = nanoparticle()
    atoms.center(vacuum=6.0)
    assert not atoms.pbc.any() and atoms.cell.rank == 3
    compare(atoms, LennardJones(**AR), AseLJ(**AR))


MORSE_SYSTEMS = {
    'fcc': lambda: bulk('Cu', 'fcc', a=3.61, cubic=True).repeat(3),
    'small_cell': lambda: bulk('Cu', 'fcc', a=3.61, cubic=True),
    'triclinic': lambda: sheared(bulk('Cu', 'fcc', a=3.61).repeat(3)),
}


@pytest.mark.parametrize('system', sorted(MORSE_SYSTEMS))
def test_morse_matches_ase(system):
    atoms = MORSE_SYSTEMS[system]()
    atoms.rattle(0.15, seed=6)
    pot = Morse(**CU)
    assert pot.cutoff == pytest.approx(2.7 * 2.55)  # rcut2 is in units of r0
    # ASE's Morse has no per-atom stresses.
    compare(atoms, pot, AseMorse(**CU), stresses=False)


def test_morse_defaults_match_ase():
    atoms = bulk('Cu', 'fcc', a=1.4, cubic=True).repeat(2)
    atoms.rattle(0.05, seed=7)
    compare(atoms, Morse(), AseMorse(), stresses=False)


def test_morse_nanoparticle_without_cell():
    atoms = Icosahedron('Cu', noshells=3, latticeconstant=3.61)
    atoms.rattle(0.1, seed=8)
    res = run(Morse(**CU), atoms)
    atoms.calc = AseMorse(**CU)
    assert res['energy'] == pytest.approx(atoms.get_potential_energy(),
                                          rel=E_RTOL)
    np.testing.assert_allclose(res['forces'], atoms.get_forces(),
                               rtol=F_RTOL, atol=F_ATOL)
    with pytest.raises(PropertyNotImplementedError):
        atoms.get_stress()


# ---------------------------------------------------------------- derivatives

def energy(pot, atoms):
    return run(pot, atoms)['energy']


DERIV_POTS = {
    'lj_smooth': lambda: LennardJones(**AR, smooth=True),
    'lj_shifted': lambda: LennardJones(**AR),
    'morse': lambda: Morse(**CU),
    'mixture': lambda: lennard_jones_mixture(
        {'Ar': 3.405, 'Kr': 3.65}, {'Ar': 0.0104, 'Kr': 0.0141}),
}


def deriv_atoms(name):
    if name == 'morse':
        atoms = bulk('Cu', 'fcc', a=3.61, cubic=True)
    else:
        atoms = bulk('Ar', 'fcc', a=5.3, cubic=True)
        atoms.numbers[[1, 3]] = 36
    atoms = sheared(atoms)
    atoms.rattle(0.2, seed=9)
    return atoms


@pytest.mark.parametrize('name', sorted(DERIV_POTS))
def test_forces_are_minus_energy_gradient(name):
    pot, atoms = DERIV_POTS[name](), deriv_atoms(name)
    forces = run(pot, atoms)['forces']
    h = 1e-5
    for a in range(len(atoms)):
        for x in range(3):
            plus, minus = atoms.copy(), atoms.copy()
            plus.positions[a, x] += h
            minus.positions[a, x] -= h
            fd = -(energy(pot, plus) - energy(pot, minus)) / (2 * h)
            assert forces[a, x] == pytest.approx(fd, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize('name', sorted(DERIV_POTS))
def test_virial_is_minus_strain_derivative(name):
    pot, atoms = DERIV_POTS[name](), deriv_atoms(name)
    virial = run(pot, atoms)['virial']
    h = 1e-6
    for x in range(3):
        for y in range(3):
            eps = np.zeros((3, 3))
            eps[x, y] = eps[y, x] = h / 2 if x != y else h
            es = []
            for sign in (1, -1):
                strained = atoms.copy()
                strained.set_cell(atoms.cell[:] @ (np.eye(3) + sign * eps),
                                  scale_atoms=True)
                es.append(energy(pot, strained))
            fd = (es[0] - es[1]) / (2 * h)
            assert -virial[x, y] == pytest.approx(fd, rel=1e-6, abs=1e-9)


# ---------------------------------------------------------------- references

SIGMA = {'Ar': 3.405, 'Kr': 3.65, 'Xe': 3.98}
EPSILON = {'Ar': 0.0104, 'Kr': 0.0141, 'Xe': 0.0194}


def ref_mixture_pair(r, a, b, rc=None):
    """naive.lj of the Lorentz-Berthelot pair a-b, cut at 3 sigma_ab or rc."""
    sigma, epsilon = naive.lorentz_berthelot(SIGMA[a], SIGMA[b], EPSILON[a], EPSILON[b])
    return naive.lj(r, sigma, epsilon, 3 * sigma if rc is None else rc)


def test_mixture_cluster_matches_brute_force():
    rng = np.random.default_rng(10)
    atoms = Icosahedron('Ar', noshells=3, latticeconstant=5.5)
    atoms.rattle(0.2, seed=11)
    atoms.numbers = rng.choice([18, 36, 54], size=len(atoms))
    pot = lennard_jones_mixture(SIGMA, EPSILON)
    assert pot.species == ('Ar', 'Kr', 'Xe')
    assert pot.cutoff == pytest.approx(3 * 3.98)
    res = run(pot, atoms)
    ref = naive.energy(atoms, ref_mixture_pair)
    assert res['energy'] == pytest.approx(ref, rel=E_RTOL)


def test_mixture_periodic_matches_brute_force():
    atoms = bulk('Ar', 'fcc', a=5.4, cubic=True)
    atoms.numbers[[0, 2]] = 36
    atoms = sheared(atoms)
    pot = lennard_jones_mixture({'Ar': 3.405, 'Kr': 3.65},
                                {'Ar': 0.0104, 'Kr': 0.0141}, rc=9.0)
    assert np.all(pot.cutoffs == 9.0)
    res = run(pot, atoms)
    ref = naive.energy(atoms, lambda r, a, b: ref_mixture_pair(
        r, a, b, rc=9.0), cutoff=9.0)
    assert res['energy'] == pytest.approx(ref, rel=E_RTOL)


def test_mixture_reduces_to_lennard_jones_for_one_species():
    atoms = fcc_ar(2, rattle=0.2)
    mix = run(lennard_jones_mixture({'Ar': 3.405}, {'Ar': 0.0104}, rc=8.5),
              atoms)
    lj = run(LennardJones(**AR), atoms)
    for key in ('energies', 'forces', 'virials'):
        np.testing.assert_allclose(mix[key], lj[key], rtol=1e-14, atol=0)


REF_POTS = {
    'lj': (lambda: LennardJones(**AR),
           lambda r, a, b: naive.lj(r, **AR)),
    'lj_smooth': (lambda: LennardJones(**AR, smooth=True),
                  lambda r, a, b: naive.lj_smooth(r, **AR, ro=0.66 * 8.5)),
    'morse': (lambda: Morse(**CU), lambda r, a, b: naive.morse(r, **CU)),
    'mixture': (lambda: lennard_jones_mixture(SIGMA, EPSILON),
                ref_mixture_pair),
}
BUILT = {name: make() for name, (make, _) in REF_POTS.items()}


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.filter_too_much])
@given(name=st.sampled_from(sorted(REF_POTS)),
       n=st.integers(2, 7),
       data=st.data())
def test_kernel_matches_plain_python(name, n, data):
    coords = data.draw(st.lists(st.floats(0.0, 12.0), min_size=3 * n,
                                max_size=3 * n))
    syms = data.draw(st.lists(st.sampled_from(['Ar', 'Kr', 'Xe']),
                              min_size=n, max_size=n))
    atoms = Atoms(syms, positions=np.reshape(coords, (n, 3)))
    i, j = np.triu_indices(n, k=1)
    D = atoms.positions[j] - atoms.positions[i]
    d = np.linalg.norm(D, axis=1)
    assume(d.min() > 2.0)
    pot, pair_energy = BUILT[name], REF_POTS[name][1]
    res = pot.evaluate(atoms.numbers, i, j, D)  # all pairs, far ones too
    ref = sum(pair_energy(r, syms[a], syms[b]) for a, b, r in zip(i, j, d))
    assert res['energy'] == pytest.approx(ref, rel=E_RTOL, abs=1e-14)
    np.testing.assert_allclose(res['forces'].sum(axis=0), 0.0, atol=1e-10)
    np.testing.assert_allclose(res['virial'], res['virial'].T, atol=1e-12)


# ---------------------------------------------------------------- kernel

@numba.njit(error_model='numpy')
def soft(r, p):
    return p[0] * (1.0 - r / p[1]) ** 2, -2.0 * p[0] / p[1] * (1.0 - r / p[1])


def test_user_potential_species_pairs_are_symmetric():
    pot = PairPotential(soft, {('Ar', 'Kr'): [2.0, 3.0],
                               (18, 18): [1.0, 3.0],
                               ('Kr', 'Kr'): [3.0, 3.0]},
                        cutoffs={('Kr', 'Ar'): 3.0, ('Ar', 'Ar'): 3.0,
                                 ('Kr', 'Kr'): 3.0})
    assert pot.species == ('Ar', 'Kr')
    np.testing.assert_array_equal(pot.params[0, 1], pot.params[1, 0])
    for numbers in ([18, 36], [36, 18]):
        res = pot.evaluate(numbers, [0], [1], [[0.0, 1.0, 0.0]])
        assert res['energy'] == pytest.approx(2.0 * (1 - 1 / 3) ** 2)
        np.testing.assert_allclose(res['forces'][0],
                                   [0.0, -4.0 / 3 * (1 - 1 / 3), 0.0])


def test_per_pair_cutoffs_and_index_types():
    pot = PairPotential(soft, {('Ar', 'Ar'): [1.0, 9.0],
                               ('Ar', 'Kr'): [1.0, 9.0],
                               ('Kr', 'Kr'): [1.0, 9.0]},
                        cutoffs={('Ar', 'Ar'): 2.0, ('Ar', 'Kr'): 4.0,
                                 ('Kr', 'Kr'): 6.0})
    D = np.array([[3.0, 0, 0], [3.0, 0, 0], [3.0, 0, 0]])
    numbers = [18, 18, 36, 36]
    for dtype in (np.int32, np.int64, np.uint16):
        i = np.array([0, 0, 2], dtype=dtype)
        j = np.array([1, 2, 3], dtype=dtype)
        res = pot.evaluate(numbers, i, j, D)
        # Ar-Ar at 3 > 2 is cut; Ar-Kr and Kr-Kr count.
        assert res['energy'] == pytest.approx(2 * (1 - 3 / 9) ** 2)
        assert res['energies'][1] == 0.0


def test_self_image_pair_has_energy_but_no_force():
    pot = LennardJones(**AR)
    res = pot.evaluate([18], [0], [0], [[4.0, 0.0, 0.0]])
    assert res['energy'] == pytest.approx(naive.lj(4.0, **AR))
    assert res['energies'][0] == res['energy']
    np.testing.assert_array_equal(res['forces'], 0.0)
    assert res['virial'][0, 0] != 0.0


def test_empty_pair_list():
    res = Morse().evaluate([29, 29], [], [], np.zeros((0, 3)))
    assert res['energy'] == 0.0
    assert res['virials'].shape == (2, 3, 3)
    for key in ('energies', 'forces', 'virial', 'virials', 'virials_voigt'):
        np.testing.assert_array_equal(res[key], 0.0)


def test_virial_layouts_agree():
    res = run(LennardJones(**AR), sheared(fcc_ar(1)))
    virials = res['virials']
    np.testing.assert_array_equal(virials, virials.transpose(0, 2, 1))
    np.testing.assert_array_equal(
        res['virials_voigt'],
        [full_3x3_to_voigt_6_stress(w) for w in virials])
    np.testing.assert_allclose(virials.sum(axis=0), res['virial'],
                               rtol=1e-12)
    assert np.all(res['virial'] != 0.0)


def test_built_in_kernels_are_cached_user_kernels_compiled_once():
    # LJ and Morse run through cached kernels with the pair function
    # inlined; a user's pair function gets kernels of its own, made once
    # and compiled once per process (not cached on disk).
    atoms = fcc_ar(1, rattle=0.1)
    for pot in [*BUILT.values(), LennardJones(smooth=True)]:
        run(pot, atoms)
        assert is_built_in(pot.pair)
        for threaded in (False, True):
            k = pair_kernel(pot.pair, threaded)
            assert k is pair_kernel(pot.pair, threaded)  # one entry point each
    user = PairPotential(soft, [1.0, 2.0], 2.0)
    assert not is_built_in(user.pair)
    run(user, atoms)
    generic = pair_kernel(user.pair, False, True, user.squared)
    assert len(generic.overloads) >= 1  # the one the run compiled
    assert generic is pair_kernel(user.pair, False, True, user.squared)
    assert generic is not pair_kernel(user.pair, False, False, user.squared)
    assert generic is not pair_kernel(user.pair, False, True, not user.squared)
    assert pair_kernel(blows_up, False) is not generic


def test_user_kernels_made_from_threads_at_once_are_one():
    # Python threads asking for a new pair function's kernel at the same
    # moment all get the one kept (no lock a fork could inherit held)
    from concurrent.futures import ThreadPoolExecutor

    @numba.njit
    def fresh(r, p):
        return p[0] * r, p[0]
    with ThreadPoolExecutor(8) as pool:
        kernels = list(pool.map(lambda _: pair_kernel(fresh, True, False, False), range(32)))
    assert all(k is kernels[0] for k in kernels)
    assert kernels[0] is pair_kernel(fresh, True, False, False)


def test_forces_only_kernel_gives_the_general_kernels_bits():
    # one species' forces and energy run a kernel compiled without species
    # tables, the rmin count, the virial and per-atom outputs; it must give
    # the general kernel's bits, and every call that needs one of those
    # must take the general kernel
    atoms = liquid_ar()
    for pot in [*BUILT.values(), LennardJones(smooth=True),
                PairPotential(soft, [1.0, 2.0], 5.0)]:
        lean, full = atoms.copy(), atoms.copy()
        lean.calc, full.calc = MLGCalculator(pot), MLGCalculator(pot)
        f = lean.get_forces()
        props = full.get_properties(['forces', 'energy', 'stress', 'energies'])
        assert np.array_equal(f, props['forces']), pot
        assert lean.get_potential_energy() == props['energy'], pot
        for threaded in (False, True):
            assert pair_kernel(pot.pair, threaded, False) is not pair_kernel(
                pot.pair, threaded, True)


def test_built_in_pair_function_in_the_wrong_form_is_refused():
    # the built-in kernels have the pair function's form compiled in: a
    # table claiming the other form would be read as the wrong distance
    with pytest.raises(ValueError, match=r'lennard_jones_shifted_r2 takes '
                       r'r\*\*2: squared=True, got squared=False'):
        PairPotential(lennard_jones_shifted_r2, [3.4, 0.01, 0.0], 8.5)
    with pytest.raises(ValueError, match=r'morse takes r: squared=False'):
        PairPotential(morse, [1.0, 3.0, 6.0, 4.0, 5.0], 5.0, squared=True)
    assert PairPotential(morse, [1.0, 3.0, 6.0, 4.0, 5.0], 5.0).squared is False


def test_kernel_is_loaded_from_cache_in_a_new_process():
    # a sum over an empty list runs the serial kernel: loaded, not compiled
    code = ('import numpy as np; from ase_mlg import pairsum, potentials as P; '
            'P.LennardJones().sum_pairs(np.zeros((0, 3)), np.zeros(0, np.int32), '
            'np.zeros(1, np.int64), np.zeros(0, np.int32), np.zeros(0, np.uint8), '
            'np.zeros((1, 3)), np.zeros(0, np.int64)); '
            'k = pairsum.pair_kernel(P.lennard_jones_shifted_r2, False); '
            'print(sum(k.stats.cache_hits.values()))')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [os.path.dirname(os.path.dirname(P.__file__)),
         os.environ.get('PYTHONPATH', '')]))
    for _ in range(2):  # the first run may (re)write the cache
        out = subprocess.run([sys.executable, '-c', code], env=env,
                             capture_output=True, text=True, check=True)
    assert out.stdout.split()[-1] == '1'


def _calculators_list():
    """Argon atoms, LJ, and the list of an MLGCalculator after a force call."""
    atoms = fcc_ar(3, rattle=0.1)
    pot = LennardJones(**AR)
    atoms.calc = MLGCalculator(pot)
    atoms.get_forces()
    return atoms, pot, atoms.calc.verlet_list, atoms.calc.verlet_list.pairs


def test_sum_pairs_takes_row_chunks_or_none():
    # the calculator's entry point: chunks are a RowChunks of the list (or
    # None for row_chunks); a bare count is refused, not silently used.  On
    # the calculator's own list (one-byte image codes): a list with a code
    # per pair (int32) compiled a kernel for this test alone, 18 s of CI
    atoms, pot, vl, pl = _calculators_list()
    args = (vl.X, vl.types, pl.rowptr, pl.nbr, pl.code, vl.svec, pl.order)
    ase = atoms.copy()
    ase.calc = AseLJ(**AR)
    for chunks in (None, RowChunks(pl.rowptr, pl.nbr, 3)):
        res = pot.sum_pairs(*args, energies=True, chunks=chunks)
        assert res['energy'] == pytest.approx(ase.get_potential_energy(), rel=1e-12)
        np.testing.assert_allclose(res['forces'], ase.get_forces(), rtol=1e-10,
                                   atol=1e-13)
        np.testing.assert_allclose(res['energies'], ase.get_potential_energies(),
                                   rtol=1e-10, atol=1e-13)
    with pytest.raises(TypeError, match='RowChunks'):
        pot.sum_pairs(*args, chunks=3)


def test_sum_pairs_on_the_same_chunks_reads_each_calls_arrays():
    # the kernel's structures are kept with the chunks between calls
    # (RowChunks.memo): new positions or shift vectors (a new cell on the
    # same list), other outputs asked for, another potential, each on the
    # same chunks, give what fresh chunks give
    _, pot, vl, pl = _calculators_list()
    chunks = RowChunks(pl.rowptr, pl.nbr, 3)
    other = LennardJones(sigma=3.0, epsilon=0.02, rc=6.0)
    X2, svec2 = vl.X + 0.01, vl.svec * 1.01
    for p, X, svec, energies in ((pot, vl.X, vl.svec, False), (pot, X2, vl.svec, False),
                                 (pot, X2, svec2, False), (pot, X2, svec2, True),
                                 (other, X2, svec2, True), (pot, vl.X, vl.svec, False)):
        args = (X, vl.types, pl.rowptr, pl.nbr, pl.code, svec, pl.order)
        got = p.sum_pairs(*args, energies=energies, chunks=chunks)
        want = p.sum_pairs(*args, energies=energies,
                           chunks=RowChunks(pl.rowptr, pl.nbr, 3))
        assert got['energy'] == want['energy']
        np.testing.assert_array_equal(got['forces'], want['forces'])
        assert ('energies' in got) == energies
        if energies:
            np.testing.assert_array_equal(got['energies'], want['energies'])
        assert got['forces'] is not want['forces']


def test_first_bad_pair_names_the_pair_and_why():
    # the kernels' error vocabulary: the first flagged pair and a PairError
    X = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    lst = SumList(X, np.zeros(3, np.int32), np.array([0, 2, 3, 3]),
                  np.array([2, 1, 2], np.int32), np.zeros((1, 3)), np.arange(3))
    code = np.zeros(3, np.uint8)
    pot = LennardJones(**AR)
    tables = SumTables(True, pot.params, pot.cutoffs**2, pot.rmin**2, False,
                       True)
    q, why = first_bad_pair(pot.pair, lst, code, tables)
    assert (q, why) == (1, PairError.BAD_DISTANCE)
    assert isinstance(why, PairError)
    tables = tables._replace(rmin2=np.full((1, 1), 6.0**2))
    assert first_bad_pair(pot.pair, lst, code, tables) == (0, PairError.BELOW_RMIN)
    ok = lst._replace(rowptr=np.array([0, 1, 1, 1]))
    tables = tables._replace(rmin2=np.zeros((1, 1)))
    assert first_bad_pair(pot.pair, ok, code, tables) == (-1, PairError.OK)


def test_prepare():
    pot = lennard_jones_mixture(SIGMA, EPSILON)
    types, params, cutoffs = pot.prepare(np.array([54, 18, 36, 18]))
    assert types.dtype == np.int32
    np.testing.assert_array_equal(types, [2, 0, 1, 0])
    assert params.shape == (3, 3, 3) and cutoffs.shape == (3, 3)
    types, params, cutoffs = LennardJones().prepare([1, 18, 92])
    np.testing.assert_array_equal(types, 0)
    assert params.shape == (1, 1, 3) and cutoffs[0, 0] == 3.0


# ---------------------------------------------------------------- bad input

def test_zero_distance_names_atoms():
    atoms = Atoms('Ar3', positions=[[0, 0, 0], [3, 0, 0], [3, 0, 0]])
    with pytest.raises(ValueError, match=r'atoms 1 and 2 at distance 0 '):
        run(LennardJones(**AR), atoms)


def test_nan_distance():
    with pytest.raises(ValueError, match=r'atoms 0 and 1 at distance nan'):
        Morse().evaluate([1, 1], [0], [1], [[np.nan, 0, 0]])


def test_non_finite_lj_names_atoms():
    with pytest.raises(ValueError, match=r'atoms 0 and 1 at distance 1e-100'
                                         r'.*non-finite'):
        LennardJones().evaluate([1, 1], [0], [1], [[1e-100, 0, 0]])


def test_below_rmin():
    pot = PairPotential(soft, [1.0, 4.0], cutoffs=4.0, rmin=1.0)
    pot.evaluate([1, 1], [0], [1], [[1.5, 0, 0]])
    with pytest.raises(ValueError, match=r'atoms 1 and 0 at distance 0.5 '
                                         r'Å: closer than rmin 1.0'):
        pot.evaluate([1, 1], [1], [0], [[0.5, 0, 0]])
    # forces alone (an MD step's call) take the kernel that counts them too
    dimer = Atoms('H2', positions=[[0, 0, 0], [0.5, 0, 0]])
    dimer.calc = MLGCalculator(pot)
    with pytest.raises(ValueError, match=r'at distance 0.5 Å: closer than rmin 1.0'):
        dimer.get_forces()


@numba.njit(error_model='numpy')
def blows_up(r, p):
    return (p[0] / (r - 2.0), 0.0)


@numba.njit(error_model='numpy')
def bad_slope(r, p):
    return 1.0, p[0] / (r - 2.0)


@numba.njit  # error_model='python': division by zero raises in the kernel
def raises(r, p):
    return p[0] / (r - 2.0), 0.0


@pytest.mark.parametrize('func', [blows_up, bad_slope, raises])
def test_user_non_finite_names_atoms(func):
    pot = PairPotential(func, [1.0], cutoffs=3.0)
    D = [[0, 0, 1.0], [0, 0, 2.0]]
    with pytest.raises(ValueError, match=r'atoms 2 and 0 at distance 2 Å: '
                                         r'non-finite'):
        pot.evaluate([1, 1, 1], [0, 2], [1, 0], D)


@pytest.mark.parametrize('func', [blows_up, raises])
def test_user_pair_function_beyond_cutoff_dropped(func):
    # cutoff 1.5 Å, skin 3: atom 0's row lists atom 2 (1 Å) before atom 1
    # (2 Å); moved within the skin, atom 2 is 2 Å away and atom 1 1 Å.  A
    # function compiled with error_model='numpy' is evaluated on the pair
    # now beyond the cutoff (inf) and it is dropped; one that raises is not
    # called there
    pot = PairPotential(func, [1.0], cutoffs=1.5)
    atoms = Atoms('H3', positions=[[0, 0, 0], [0, 0, 2.0], [0, 1.0, 0]])
    atoms.calc = MLGCalculator(pot, skin=3.0)
    assert atoms.get_potential_energy() == -1.0
    atoms.positions = [[0, 0, 0], [0, 0, 1.0], [0, 2.0, 0]]
    assert atoms.get_potential_energy() == -1.0
    assert np.array_equal(atoms.get_forces(), np.zeros((3, 3)))
    assert atoms.calc.stats["list_builds"] == 1


@pytest.mark.parametrize('kwargs, message', [
    (dict(sigma=-1.0), 'sigma must be > 0'),
    (dict(sigma=0.0), 'sigma must be > 0'),
    (dict(sigma=np.nan), 'sigma must be finite'),
    (dict(epsilon=-0.1), 'epsilon must be >= 0'),
    (dict(epsilon=np.inf), 'epsilon must be finite'),
    (dict(rc=-2.0), 'rc must be > 0'),
    (dict(rc=np.inf), 'rc must be finite'),
    (dict(rc='far'), 'rc must be a number'),
    (dict(rc=2.0, ro=2.0), r'ro \(2.0\) must be smaller than rc \(2.0\)'),
    (dict(rc=2.0, ro=3.0, smooth=True), 'ro .* must be smaller than rc'),
    (dict(ro=-1.0), 'ro must be >= 0'),
])
def test_bad_lennard_jones(kwargs, message):
    with pytest.raises(ValueError, match=message):
        LennardJones(**kwargs)


@pytest.mark.parametrize('kwargs, message', [
    (dict(epsilon=-1.0), 'epsilon must be >= 0'),
    (dict(r0=0.0), 'r0 must be > 0'),
    (dict(rho0=np.nan), 'rho0 must be finite'),
    (dict(rcut1=3.0, rcut2=2.0), r'rcut1 \(3.0\) must be smaller than rcut2'),
    (dict(rcut2=-1.0), 'rcut2 must be > 0'),
])
def test_bad_morse(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Morse(**kwargs)


ROWS = {('Ar', 'Ar'): [1.0, 2.0], ('Ar', 'Kr'): [1.0, 2.0],
        ('Kr', 'Kr'): [1.0, 2.0]}


@pytest.mark.parametrize('params, cutoffs, kw, message', [
    ({('Ar', 'Ar'): [1.0, 2.0], ('Kr', 'Kr'): [1.0, 2.0]}, 2.0, {},
     r'params missing for species pairs: \(Ar, Kr\)'),
    ({**ROWS, ('Kr', 'Kr'): [1.0]}, 2.0, {},
     r'parameter rows differ in length \(.*\(Kr, Kr\): 1'),
    (ROWS, 2.0, dict(nparams=3), 'parameter rows must have length 3, got 2'),
    ({**ROWS, ('Kr', 'Ar'): [5.0, 2.0]}, 2.0, {},
     r'params for \(Ar, Kr\) given twice'),
    ({**ROWS, ('Ar', 'Ar'): [1.0, np.nan]}, 2.0, {},
     r'params\(Ar, Ar\) contains non-finite'),
    ({**ROWS, ('Ar', 'Ar'): [[1.0, 2.0]]}, 2.0, {},
     r'params\(Ar, Ar\) must be a 1-D sequence'),
    ({**ROWS, ('Ar', 'Qq'): [1.0, 2.0]}, 2.0, {}, "unknown element 'Qq'"),
    ({**ROWS, ('Ar',): [1.0, 2.0]}, 2.0, {}, 'keys must be pairs'),
    (ROWS, {('Ar', 'Ar'): 2.0, ('Kr', 'Kr'): 2.0}, {},
     r'cutoffs missing for species pairs: \(Ar, Kr\)'),
    (ROWS, {('Ar', 'Ar'): 2.0, ('Ar', 'Kr'): 2.0, ('Kr', 'Kr'): 2.0,
            ('Ar', 'Xe'): 2.0}, {},
     r'cutoffs given for species pairs without params: \(Ar, Xe\)'),
    (ROWS, {('Ar', 'Ar'): 2.0, ('Ar', 'Kr'): -2.0, ('Kr', 'Kr'): 2.0}, {},
     r'cutoffs\(Ar, Kr\) must be > 0'),
    (ROWS, {('Ar', 'Ar'): 2.0, ('Ar', 'Kr'): np.nan, ('Kr', 'Kr'): 2.0}, {},
     r'cutoffs\(Ar, Kr\) must be finite'),
    (ROWS, np.inf, {}, 'cutoffs must be finite'),
    (ROWS, 0.0, {}, 'cutoffs must be > 0'),
    (ROWS, 2.0, dict(rmin={('Kr', 'Kr'): 2.5}),
     r'rmin 2.5 >= cutoff 2.0 for species pair \(Kr, Kr\)'),
    (ROWS, 2.0, dict(rmin=-1.0), 'rmin must be >= 0'),
    ([1.0, 2.0], {('Ar', 'Ar'): 2.0}, {}, 'per-pair cutoffs/rmin need'),
    ([1.0, 2.0], -3.0, {}, 'cutoffs must be > 0'),
    ({**ROWS, ('Ar', 0): [1.0, 2.0]}, 2.0, {}, 'invalid element 0'),
    ([1.0, 2.0], 2.0, dict(rmin=2.0), r'rmin 2.0 >= cutoff 2.0 .*\(any'),
])
def test_bad_tables(params, cutoffs, kw, message):
    with pytest.raises(ValueError, match=message):
        PairPotential(soft, params, cutoffs, **kw)


def test_bad_pair_functions():
    with pytest.raises(TypeError, match='must be compiled with @numba.njit'):
        PairPotential(lambda r, p: (0.0, 0.0), [1.0], 2.0)

    @numba.njit
    def one_value(r, p):
        return r

    with pytest.raises(TypeError, match='pair function one_value must be .*'
                                        'No conversion from float64'):
        PairPotential(one_value, [1.0], 2.0)


def test_missing_species_names_element_and_atom():
    pot = lennard_jones_mixture({'Ar': 3.4, 'Kr': 3.6}, {'Ar': 0.01,
                                                         'Kr': 0.014})
    with pytest.raises(ValueError, match=r'no parameters for element Xe '
                                         r'\(atom 2\).*Ar, Kr'):
        pot.prepare([18, 36, 54])
    with pytest.raises(ValueError, match='atom 1 has invalid atomic number'):
        pot.prepare([18, 300])
    with pytest.raises(ValueError, match='numbers must be a 1-D integer'):
        pot.prepare([18.0, 36.0])


def test_mixture_bad_input():
    with pytest.raises(ValueError, match='same elements'):
        lennard_jones_mixture({'Ar': 3.4}, {'Kr': 0.01})
    with pytest.raises(ValueError, match=r"sigma\['Ar'\] must be > 0"):
        lennard_jones_mixture({'Ar': -3.4}, {'Ar': 0.01})
    with pytest.raises(ValueError, match=r"epsilon\['Ar'\] must be finite"):
        lennard_jones_mixture({'Ar': 3.4}, {'Ar': np.nan})
    with pytest.raises(ValueError, match='rc must be > 0'):
        lennard_jones_mixture({'Ar': 3.4}, {'Ar': 0.01}, rc=0.0)


@pytest.mark.parametrize('i, j, D, d, message', [
    ([0], [2], [[1.0, 0, 0]], None,
     r'pair 0: atom index \(0, 2\) out of range for 2 atoms'),
    ([-1], [0], [[1.0, 0, 0]], None, r'atom index \(-1, 0\) out of range'),
    ([0, 1], [1], [[1.0, 0, 0]], None, 'i and j must be 1-D of equal length'),
    ([0.0], [1.0], [[1.0, 0, 0]], None, 'i must be integer'),
    ([0], [1], [[1.0, 0]], None, r'D must have shape \(1, 3\)'),
    ([0], [1], [[1.0, 0, 0]], [1.0, 2.0], r'd must have shape \(1,\)'),
])
def test_bad_pair_arrays(i, j, D, d, message):
    with pytest.raises(ValueError, match=message):
        LennardJones().evaluate([1, 1], i, j, D, d)


def test_module_docstring_example_runs():
    import doctest
    result = doctest.testmod(P)
    assert result.attempted > 0 and result.failed == 0
