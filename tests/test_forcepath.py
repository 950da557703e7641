"""The force path (issue 10, issue 12 items 1, 4, 7): grid-ordered fused
kernel, threads, NPT without rebuilds, LJ at the cutoff, recorded
parameters, exploding runs."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk
from ase.calculators.lj import LennardJones as AseLJ
from ase.io import read, write
from ase.md.nose_hoover_chain import MTKNPT
from ase.md.velocitydistribution import thermalize_momenta
from ase.md.verlet import VelocityVerlet

from ase_mlg import MLGCalculator
from ase_mlg.potentials import LennardJones, Morse, lennard_jones_mixture

import naive

AR = dict(sigma=3.405, epsilon=0.0104, rc=8.5)


def argon(n=4, rattle=0.1, seed=0, shuffle=True):
    atoms = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(n)
    atoms.rattle(rattle, seed=seed)
    if shuffle:
        atoms = atoms[np.random.default_rng(seed).permutation(len(atoms))]
    return atoms


def ase_ref(atoms, **kw):
    ref = atoms.copy()
    ref.calc = AseLJ(**{**AR, **kw})
    return ref.get_forces(), ref.get_stress(), ref.get_potential_energy()


def assert_like_ase(atoms, calc, **kw):
    ours = atoms.copy()
    ours.calc = calc
    f, s, e = ase_ref(atoms, **kw)
    assert ours.get_potential_energy() == pytest.approx(e, rel=1e-11, abs=1e-12)
    np.testing.assert_allclose(ours.get_forces(), f, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ours.get_stress(), s, rtol=1e-10, atol=1e-14)


# -- LJ pairs exactly at the cutoff (issue 12, item 1) ------------------------

@pytest.mark.parametrize("skin", [0.0, 1.0])
def test_lj_keeps_pairs_at_exactly_rc_as_ase(skin):
    one = Atoms("Ar", cell=[1, 1, 1], pbc=True)  # shells exactly at rc = 3
    ours = one.copy()
    ours.calc = MLGCalculator(LennardJones(), skin=skin)
    ref = one.copy()
    ref.calc = AseLJ()
    assert ours.get_stress()[0] == pytest.approx(ref.get_stress()[0], rel=1e-12)
    assert ref.get_stress()[0] == pytest.approx(-16.5857, rel=1e-4)
    two = Atoms("Ar2", positions=[[0, 0, 0], [3.0, 0, 0]])
    ours = two.copy()
    ours.calc = MLGCalculator(LennardJones(), skin=skin)
    ref = two.copy()
    ref.calc = AseLJ()
    f0 = ref.get_forces()
    assert abs(f0[0, 0]) > 1e-2
    np.testing.assert_allclose(ours.get_forces(), f0, rtol=1e-12)


# -- grid order, threads ------------------------------------------------------

def test_random_index_order_same_answer_as_sorted():
    atoms = argon(4, shuffle=False)
    perm = np.random.default_rng(5).permutation(len(atoms))
    a, b = atoms.copy(), atoms[perm]
    a.calc = MLGCalculator(LennardJones(**AR))
    b.calc = MLGCalculator(LennardJones(**AR))
    np.testing.assert_allclose(b.get_forces(), a.get_forces()[perm], rtol=1e-12, atol=1e-15)
    assert b.get_potential_energy() == pytest.approx(a.get_potential_energy(), rel=1e-13)
    assert_like_ase(b, MLGCalculator(LennardJones(**AR)))


def _calculator_list(atoms, pot, skin=1.0):
    """The kernel's inputs built the way the calculator's list is built
    (:class:`ase_mlg.verletlist.VerletList`, exact mode): an MLG of the
    atoms, the half list within rc + skin (pairs within rc first in each
    row), the positions in the images the list refers to, the shift
    vectors, the types in row order."""
    from ase_mlg.blocks import BlockIndex, block_for_radius
    from ase_mlg.grid import MLG
    from ase_mlg.pairsum import shift_vectors
    from ase_mlg.query import half_list
    cell = atoms.cell.array
    grid = MLG(atoms.positions, cell, atoms.pbc)
    rc = pot.cutoff
    rlist = rc + skin
    pl = half_list(BlockIndex(grid, block_for_radius(grid, rlist)),
                   np.full(len(atoms), rlist), cut=rlist, split=rc)
    X = pl.positions(atoms.positions, cell)
    svec = shift_vectors(pl.shifts, cell)
    types = np.ascontiguousarray(pot.prepare(atoms.numbers)[0][pl.order])
    return pl, (X, types, pl.rowptr, pl.nbr, pl.code, svec, pl.order)


def test_window_pass_threaded_twin_gives_the_serial_windows(monkeypatch):
    """The chunks' window pass runs threaded only from THRESHOLDS["marks"]
    pairs (10^5 atoms, beyond the tests' sizes): with the threshold
    lowered, the threaded twin gives the same chunks (windows, offsets,
    segments) as the serial one."""
    from ase_mlg import chunks, parallel
    atoms = argon(5)
    pl, _ = _calculator_list(atoms, LennardJones(**AR))
    assert len(pl) < parallel.THRESHOLDS["marks"]
    serial = chunks.RowChunks(pl.rowptr, pl.nbr, 7).arrays
    called = []
    monkeypatch.setitem(parallel.THRESHOLDS, "marks", 1)
    real = chunks._mark_threaded
    monkeypatch.setattr(chunks, "_mark_threaded",
                        lambda *a: (called.append(1), real(*a))[1])
    threaded = chunks.RowChunks(pl.rowptr, pl.nbr, 7).arrays
    assert called, "the threaded twin did not run"
    for name, a in zip(serial._fields, serial):
        if name != "thread":
            np.testing.assert_array_equal(getattr(threaded, name), a, err_msg=name)


def test_chunks_reproducible_and_agree_across_counts():
    """Every chunking of the calculator's list is ASE's answer (windowed
    buffers lose no pair), and the same chunks give the same bits."""
    from ase_mlg.chunks import RowChunks
    atoms = argon(5)
    pot = LennardJones(**AR)
    pl, args = _calculator_list(atoms, pot)
    keys = ("forces", "energies", "virials_voigt", "virial")
    runs = {}
    for k in (1, 2, 3, 7):
        chunks = RowChunks(pl.rowptr, pl.nbr, k)
        assert chunks.nchunk == k
        runs[k] = r = pot.sum_pairs(*args, energies=True, virials=True, chunks=chunks)
        # repeated with the same chunks (buffers reused) and with the same
        # chunks built anew: the same bits
        for again in (pot.sum_pairs(*args, energies=True, virials=True, chunks=chunks),
                      pot.sum_pairs(*args, energies=True, virials=True,
                                    chunks=RowChunks(pl.rowptr, pl.nbr, k))):
            for key in keys:
                np.testing.assert_array_equal(again[key], r[key])
            assert again["energy"] == r["energy"]
    a = atoms.copy()
    a.calc = AseLJ(**AR, smooth=False)
    e = a.get_potential_energy()
    fa = a.get_forces()
    sa = a.get_stress()
    ea = a.get_potential_energies()
    sta = a.get_stresses()
    volume = atoms.get_volume()
    # the brute-force oracle: every pair over every image that matters
    e_naive = naive.energy(atoms, lambda r, *_: naive.lj(r, **AR), cutoff=AR["rc"])
    assert e_naive == pytest.approx(e, rel=1e-10)
    for k, r in runs.items():
        assert r["energy"] == pytest.approx(e, rel=1e-10), k
        assert r["energy"] == pytest.approx(e_naive, rel=1e-10), k
        np.testing.assert_allclose(r["forces"], fa, rtol=0, atol=1e-10 * np.abs(fa).max())
        np.testing.assert_allclose(-r["virial"] / volume, sa, rtol=0,
                                   atol=1e-10 * np.abs(sa).max())
        np.testing.assert_allclose(r["energies"], ea, rtol=0,
                                   atol=1e-10 * np.abs(ea).max())
        np.testing.assert_allclose(-r["virials_voigt"] / volume, sta, rtol=0,
                                   atol=1e-10 * np.abs(sta).max())
    # and the chunkings agree with one another to rounding
    ref = runs[1]
    for k, r in runs.items():
        np.testing.assert_allclose(r["forces"], ref["forces"], rtol=0,
                                   atol=1e-12 * np.abs(ref["forces"]).max())
        assert r["energy"] == pytest.approx(ref["energy"], rel=1e-12)
        np.testing.assert_allclose(r["virial"], ref["virial"], rtol=1e-12)


def test_thread_counts_agree_in_subprocesses():
    code = ("import numpy as np, sys; sys.path.insert(0, %r); "
            "from test_forcepath import argon, AR; "
            "from ase_mlg import MLGCalculator; from ase_mlg.potentials import LennardJones; "
            "a = argon(8); a.calc = MLGCalculator(LennardJones(**AR)); "
            "f = a.get_forces(); a.positions += 0.01; g = a.get_forces(); "
            "sys.stdout.write(repr([f.tolist(), g.tolist(), a.get_stress().tolist()]))"
            ) % os.path.dirname(__file__)
    out = {}
    for k in ("1", "2"):
        env = dict(os.environ, NUMBA_NUM_THREADS=k)
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, check=True)
        out[k] = np.array(eval(r.stdout)[0]), np.array(eval(r.stdout)[1])
    for x, y in zip(out["1"], out["2"]):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-12 * np.abs(x).max())


# -- NPT without rebuilds (issue 10, item 4) ----------------------------------

def test_npt_keeps_grid_and_list_and_matches_ase():
    atoms = argon(5, rattle=0.2, seed=1)
    thermalize_momenta(atoms, temperature_K=90, rng=np.random.default_rng(2))
    calc = MLGCalculator(LennardJones(**AR))
    atoms.calc = calc
    dyn = MTKNPT(atoms, 5 * units.fs, temperature_K=90, pressure_au=1 * units.bar,
                 tdamp=100 * units.fs, pdamp=500 * units.fs)
    v0 = atoms.get_volume()
    dyn.run(40)
    assert atoms.get_volume() != v0  # the cell did move
    assert calc.stats["grid_builds"] == 1
    assert calc.stats["grid_rebuilds"] == 0
    assert calc.stats["list_builds"] <= 10
    assert_like_ase(atoms, calc)


@pytest.mark.parametrize("strain", [0.02, 0.15])
def test_strain_beyond_the_skin_rebuilds_the_list(strain):
    atoms = argon(4)
    calc = MLGCalculator(LennardJones(**AR), skin=1.0)
    atoms.calc = calc
    atoms.get_forces()
    rng = np.random.default_rng(3)
    eps = np.eye(3) + strain * (rng.random((3, 3)) - 0.5)
    atoms.set_cell(atoms.cell.array @ eps, scale_atoms=True)
    atoms.get_forces()
    smin = np.linalg.svd(eps, compute_uv=False).min()
    kept = smin * (AR["rc"] + 1.0) > AR["rc"]
    assert calc.stats["list_builds"] == 1 + (not kept)
    assert calc.stats["grid_builds"] == 0  # 256 atoms: every atom pair, no grid
    assert_like_ase(atoms, calc)


# -- recorded parameters (issue 12, item 4) -----------------------------------

@pytest.mark.parametrize("pot", [LennardJones(**AR), Morse(epsilon=0.3, r0=2.5),
                                 lennard_jones_mixture({"Ar": 3.4, "Kr": 3.6},
                                                       {"Ar": 0.01, "Kr": 0.014})])
def test_todict_is_json_and_reaches_trajectory_files(pot, tmp_path):
    calc = MLGCalculator(pot, template=7, skin=0.5)
    d = calc.todict()
    assert json.loads(json.dumps(d)) == d
    assert d["template"] == 7 and d["skin"] == 0.5
    assert d["potential"]["kind"] == type(pot).__name__
    atoms = argon(2)
    atoms.numbers[:5] = 36
    atoms.calc = calc
    atoms.get_potential_energy()
    write(tmp_path / "x.traj", atoms)
    assert read(tmp_path / "x.traj").calc.parameters == d
    assert repr(calc).startswith(f"MLGCalculator({type(pot).__name__}(")


def test_lennard_jones_recorded_by_its_arguments():
    d = MLGCalculator(LennardJones(**AR)).todict()
    assert d["potential"] == {"kind": "LennardJones", "sigma": 3.405, "epsilon": 0.0104,
                              "rc": 8.5, "ro": 0.66 * 8.5, "smooth": False}
    assert MLGCalculator(LennardJones(), template="auto").todict()["template"] == "auto"


def test_unknown_keyword_is_refused():
    with pytest.raises(TypeError, match="neighbor_list"):
        MLGCalculator(LennardJones(), neighbor_list=lambda *a: None)


# -- large moves rebuild, never refuse (issue 25, item 7) ----------------------

def test_a_dimer_pulled_apart_gives_ase_s_zero():
    atoms = Atoms("Ar2", positions=[[0, 0, 0], [0, 0, 3.8]])
    calc = MLGCalculator(LennardJones(**AR))
    atoms.calc = calc
    assert atoms.get_potential_energy() < 0
    atoms.positions[1, 2] = 1000.0
    ref = atoms.copy()
    ref.calc = AseLJ(**AR)
    assert atoms.get_potential_energy() == ref.get_potential_energy() == 0.0
    atoms.positions[1, 2] = 3.8  # and back: no error kept from the move
    assert atoms.get_potential_energy() < 0


def test_a_crystal_translated_by_100_cells_is_the_same_crystal():
    atoms = argon(3, rattle=0.05, shuffle=False)
    calc = MLGCalculator(LennardJones(**AR))
    atoms.calc = calc
    e0 = atoms.get_potential_energy()
    atoms.positions += 100 * atoms.cell.sum(axis=0)
    assert atoms.get_potential_energy() == pytest.approx(e0, rel=1e-10)
    assert_like_ase(atoms, MLGCalculator(LennardJones(**AR)))
    np.testing.assert_allclose(atoms.get_forces(), ase_ref(atoms)[0], rtol=1e-9, atol=1e-11)


def test_far_apart_frames_and_an_unrelated_structure_need_no_reset():
    atoms = argon(3)
    calc = MLGCalculator(LennardJones(**AR))
    atoms.calc = calc
    atoms.get_forces()
    atoms.positions += 1e5  # an unwrapped trajectory's far frame
    np.testing.assert_allclose(atoms.get_forces(), ase_ref(atoms)[0], rtol=1e-9, atol=1e-11)
    other = argon(3, rattle=0.3, seed=7)  # same N, unrelated
    other.calc = calc
    f, s, e = ase_ref(other)
    assert other.get_potential_energy() == pytest.approx(e, rel=1e-11)
    np.testing.assert_allclose(other.get_forces(), f, rtol=1e-10, atol=1e-12)


def test_overlapping_start_runs_as_ase_until_it_cannot():
    """Atoms squeezed together in the start fly apart as under ASE's LJ
    (forces equal to ASE's after the kick, the list rebuilt, no error);
    a start that sends atoms 2**36 cells away ends with the grid's error
    naming them (ASE goes on at 1e8 Å and beyond); coincident atoms, which
    ASE answers with nan, are named too."""
    atoms = argon(3, rattle=0.05, shuffle=False)
    atoms.positions[1] = atoms.positions[0] + [2.2, 0.0, 0.0]
    atoms.calc = MLGCalculator(LennardJones(**AR))
    VelocityVerlet(atoms, 5 * units.fs).run(20)
    assert atoms.calc.stats["list_builds"] > 1
    np.testing.assert_allclose(atoms.get_forces(), ase_ref(atoms)[0], rtol=1e-8, atol=1e-9)
    atoms.positions[1] = atoms.positions[0] + [0.9, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"^positions: atom\(s\) \[\d"):
        VelocityVerlet(atoms, 5 * units.fs).run(20)
    far = argon(3, shuffle=False)
    far.positions[5] += [3e10, 0.0, 0.0]  # 1e9 list radii: the query's margin would explode
    far.calc = MLGCalculator(LennardJones(**AR))
    with pytest.raises(ValueError, match=r"atom\(s\) \[5\] reach 3e\+10 Å.*exploding MD run"):
        far.get_potential_energy()
    still = argon(3, shuffle=False)
    still.positions[1] = still.positions[0]
    still.calc = MLGCalculator(LennardJones(**AR))
    with pytest.raises(ValueError, match="atoms (0 and 1|1 and 0) at distance 0"):
        still.get_potential_energy()


def test_exact_list_rows_hold_pairs_within_the_cutoff_first():
    """The scan writes each row's pairs within rc first (the force loop's
    cutoff branch is then predicted), and the list is still every pair
    within rc + skin: the same set as a list built without the split."""
    from ase_mlg.blocks import BlockIndex, block_for_radius
    from ase_mlg.pairsum import shift_vectors
    from ase_mlg.query import half_list
    atoms = argon(5, rattle=0.3)
    calc = MLGCalculator(LennardJones(**AR))
    atoms.calc = calc
    atoms.get_forces()
    pl = calc.verlet_list.pairs
    X = pl.positions(atoms.positions, atoms.cell.array)
    svec = shift_vectors(pl.shifts, atoms.cell.array)
    t = np.repeat(np.arange(pl.natoms), np.diff(pl.rowptr))
    d = np.linalg.norm(X[pl.nbr] - X[t] + svec[pl.code], axis=1)
    inner = d <= AR["rc"] + 1e-9
    outer = d > AR["rc"] - 1e-9
    for r in range(pl.natoms):
        a, b = pl.rowptr[r], pl.rowptr[r + 1]
        k = int(inner[a:b].sum())
        assert inner[a:a + k].all() and outer[a + k:b].all(), r
    assert 0 < inner.sum() < len(inner)
    rlist = AR["rc"] + 1.0
    plain = half_list(BlockIndex(calc.grid, block_for_radius(calc.grid, rlist)),
                      np.full(pl.natoms, rlist), cut=rlist)
    np.testing.assert_array_equal(naive.atom_pairs(pl), naive.atom_pairs(plain))

