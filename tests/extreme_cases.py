"""Extreme geometries, dynamics and arithmetic: the cases of issue 7.

Each check builds an extreme scene and compares ase_mlg against ASE
(``ase.neighborlist.neighbor_list``, ``ase.calculators.lj.LennardJones``),
or asserts a clear ``ValueError``/``TypeError`` naming the argument or atom.
A check returns a short result string ("pass ..." with what it measured, or
"clear error: <message>") or raises (failure).  ``tests/test_extremes.py``
runs every check of :data:`CHECKS` (and of ``bad_input_cases.CHECKS``) as a
test; ``validation/extremes.py`` runs those tests and tabulates the result
strings in ``validation/reports/extremes.md``.  Lengths in Å, energies in eV.
"""

import functools
import math
import os
import subprocess
import sys
import time

import numpy as np
from ase import Atoms
from ase.build import bulk
from ase.calculators.lj import LennardJones as ASELJ
from ase.neighborlist import neighbor_list as ase_nl

from ase_mlg import MLG, MLGCalculator, neighbor_list
from ase_mlg.potentials import LennardJones

SIGMA, EPS = 3.405, 0.0104
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def register(group, name, checks):
    """Decorator: append ``(group, name, function)`` to ``checks``."""
    def deco(f):
        checks.append((group, name, f))
        return f
    return deco


CHECKS = []  # (group, name, check) in the report's order
check = functools.partial(register, checks=CHECKS)


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------
def pairs_set(i, j, S):
    return sorted(zip(i.tolist(), j.tolist(), map(tuple, np.asarray(S).tolist())))


def compare_nl(atoms, cutoff, self_interaction=False, dtol=1e-9):
    """ase_mlg.neighbor_list == ASE's (same (i, j, S) set, same d, D)."""
    a = ase_nl("ijdDS", atoms, cutoff, self_interaction=self_interaction)
    b = neighbor_list("ijdDS", atoms, cutoff, self_interaction=self_interaction)
    ka = np.lexsort((a[4][:, 2], a[4][:, 1], a[4][:, 0], a[1], a[0]))
    kb = np.lexsort((b[4][:, 2], b[4][:, 1], b[4][:, 0], b[1], b[0]))
    assert len(a[0]) == len(b[0]), f"{len(b[0])} pairs, ASE {len(a[0])}"
    for q in (0, 1, 4):
        assert np.array_equal(a[q][ka], b[q][kb]), "pair sets differ from ASE"
    scale = max(1.0, float(np.abs(atoms.positions).max(initial=0)))
    assert np.allclose(a[2][ka], b[2][kb], rtol=0, atol=dtol * scale), "d differs"
    assert np.allclose(a[3][ka], b[3][kb], rtol=0, atol=dtol * scale), "D differs"
    return len(a[0])


def lj_pair(rc=8.5):
    return LennardJones(sigma=SIGMA, epsilon=EPS, rc=rc)


def ase_lj(rc=8.5):
    return ASELJ(sigma=SIGMA, epsilon=EPS, rc=rc)


def compare_calc(atoms, calc=None, rc=8.5, rtol=1e-10):
    """MLGCalculator == ase LJ (energy, forces, stress)."""
    ref = atoms.copy()
    ref.calc = ase_lj(rc)
    e0, f0 = ref.get_potential_energy(), ref.get_forces()
    if calc is None:
        calc = MLGCalculator(lj_pair(rc))
    atoms.calc = calc
    e1, f1 = atoms.get_potential_energy(), atoms.get_forces()
    fs = max(1e-12, float(np.abs(f0).max(initial=0)))
    assert abs(e1 - e0) <= rtol * max(1e-12, abs(e0)) + 1e-13 * len(atoms), \
        f"energy {e1!r} vs ASE {e0!r}"
    assert np.abs(f1 - f0).max(initial=0) <= rtol * fs + 1e-13, "forces differ from ASE"
    if atoms.cell.rank == 3:
        s0, s1 = ref.get_stress(), atoms.get_stress()
        assert np.abs(s1 - s0).max() <= rtol * max(1e-12, np.abs(s0).max()) + 1e-15, \
            "stress differs"
    return e1


def clear_error(fn, words, exc=(ValueError, TypeError)):
    """fn() must raise exc whose message contains one of words; no numba."""
    try:
        fn()
    except exc as err:
        msg = str(err)
        assert "numba" not in msg.lower() and "TypingError" not in type(err).__name__, \
            f"numba leaked: {type(err).__name__}: {msg[:200]}"
        if isinstance(words, str):
            words = [words]
        assert any(w.lower() in msg.lower() for w in words), \
            f"message does not name {words}: {msg[:200]}"
        return "clear error: " + f"{type(err).__name__}: " + msg.split("\n")[0][:110]
    raise AssertionError("no error raised (silent result)")


def ar_liquid(n=256, rho=0.021, seed=0, jitter=0.1):
    """fcc-based argon liquid-like box, ~n atoms."""
    k = max(1, round((n / 4) ** (1 / 3)))
    a = (4 / rho) ** (1 / 3)
    at = bulk("Ar", "fcc", a=a, cubic=True).repeat(k)
    rng = np.random.default_rng(seed)
    at.positions += rng.normal(0, jitter, at.positions.shape)
    return at


def fcc(k=3, a=5.26):
    return bulk("Ar", "fcc", a=a, cubic=True).repeat(k)


def small_liquid():
    """32 argon atoms, the scene the bad-input checks spoil."""
    return ar_liquid(32, seed=17)


def subprocess_env(**extra):
    """The environment of a child Python that imports this checkout's
    ase_mlg (installed or not)."""
    env = dict(os.environ, **extra)
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    return env


# --------------------------------------------------------------------------
# 1. geometry
# --------------------------------------------------------------------------
L = 10.0


def _face_atoms(pbc):
    z = np.array([0.0, -0.0, L, np.nextafter(L, 0), np.nextafter(0, 1),
                  np.nextafter(0, -1), 5.0])
    rng = np.random.default_rng(1)
    pos = rng.choice(z, size=(40, 3))
    pos[:8] = [[x, y, w] for x in (0.0, L) for y in (-0.0, L) for w in (0.0, np.nextafter(L, 0))]
    return Atoms("Ar40", positions=pos, cell=[L, L, L], pbc=pbc)


@check("geometry", "atoms on faces/corners (0, -0.0, L, L-1ulp, +-1 denormal), pbc=True")
def g_faces_pbc():
    return f"pass ({compare_nl(_face_atoms(True), 3.0, True)} pairs == ASE)"


@check("geometry", "atoms on faces/corners, pbc=False")
def g_faces_open():
    return f"pass ({compare_nl(_face_atoms(False), 3.0)} pairs == ASE)"


@check("geometry", "atoms on faces/corners, calculator exact vs ASE LJ (distinct sites)")
def g_faces_calc():
    pos = np.array([[x, y, z] for x in (0.0, 5.0) for y in (-0.0, 5.0)
                    for z in (np.nextafter(L, 0), 5.0)])
    pos[0] = [np.nextafter(L, 0), L, 0.0]
    at = Atoms("Ar8", positions=pos, cell=[L, L, L], pbc=True)
    compare_calc(at, rc=6.0)
    return "pass (E, F, stress == ASE)"


@check("geometry", "atoms unwrapped +-1e4 cells away, pbc=True")
def g_far_unwrapped():
    at = ar_liquid(108)
    rng = np.random.default_rng(2)
    shift = rng.integers(-10000, 10001, size=(len(at), 3)) @ at.cell.array
    far = at.copy()
    far.positions += shift
    n = compare_nl(far, 6.0, dtol=1e-9)
    # energies equal to the wrapped system
    e_far = compare_calc(far, rc=6.0, rtol=1e-7)
    at.calc = MLGCalculator(lj_pair(6.0))
    e0 = at.get_potential_energy()
    assert abs(e_far - e0) <= 1e-7 * abs(e0), f"E far {e_far} vs wrapped {e0}"
    return f"pass ({n} pairs == ASE; |dE|/E = {abs(e_far - e0) / abs(e0):.1e})"


def _offset(pbc):
    at = ar_liquid(108, seed=3)
    at.pbc = pbc
    calc0 = MLGCalculator(lj_pair(6.0))
    at.calc = calc0
    e0 = at.get_potential_energy()
    i0, j0, S0 = neighbor_list("ijS", at, 6.0)
    sh = at.copy()
    sh.positions += 1e6
    sh.calc = MLGCalculator(lj_pair(6.0))
    e1 = sh.get_potential_energy()
    i1, j1, S1 = neighbor_list("ijS", sh, 6.0)
    rel = abs(e1 - e0) / abs(e0)
    assert rel <= 1e-9, f"energy relative difference {rel:.2e} > 1e-9"
    if not pbc:
        assert pairs_set(i0, j0, S0) == pairs_set(i1, j1, S1), "pairs changed"
    else:
        # same pair graph, S relabelled by the wrap of the shifted origin
        assert sorted(zip(i0, j0)) == sorted(zip(i1, j1)), "pairs changed"
    return f"pass (|dE|/E = {rel:.1e}, {len(i0)} pairs identical)"


@check("geometry", "coordinates offset by 1e6 A, pbc=False")
def g_offset_open():
    return _offset(False)


@check("geometry", "coordinates offset by 1e6 A, pbc=True")
def g_offset_pbc():
    return _offset(True)


@check("geometry", "triclinic cells, angles 10..90 deg")
def g_angles():
    from ase.geometry import cellpar_to_cell
    out = []
    for ang in (10, 20, 45, 60, 89.9):
        cell = cellpar_to_cell([8, 9, 10, ang, ang, ang])
        rng = np.random.default_rng(int(ang * 10))
        at = Atoms("Ar30", scaled_positions=rng.random((30, 3)), cell=cell, pbc=True)
        out.append(compare_nl(at, 5.0))
    return f"pass (pairs == ASE at 10, 20, 45, 60, 89.9 deg: {out})"


@check("geometry", "cell thinner than the cutoff in one direction (1 A vs rc 6)")
def g_thin():
    rng = np.random.default_rng(5)
    at = Atoms("Ar20", scaled_positions=rng.random((20, 3)), cell=[8, 8, 1.0], pbc=True)
    n = compare_nl(at, 6.0)
    at2 = Atoms("Ar20", scaled_positions=rng.random((20, 3)) * [1, 1, 1],
                cell=[12, 12, 3.0], pbc=True)
    compare_calc(at2, rc=7.0)
    return f"pass ({n} pairs == ASE; calculator == ASE LJ)"


@check("geometry", "cutoff 1e-3 A .. 10x the cell")
def g_cutoffs():
    rng = np.random.default_rng(6)
    at = Atoms("Ar12", scaled_positions=rng.random((12, 3)), cell=[4, 5, 6], pbc=True)
    at.positions[1] = at.positions[0] + [5e-4, 0, 0]
    counts = [compare_nl(at, c) for c in (1e-3, 0.1, 1.0, 6.0, 20.0, 60.0)]
    return f"pass (pair counts == ASE: {counts})"


@check("geometry", "two atoms (open, periodic), NL and calculator")
def g_two():
    at = Atoms("Ar2", positions=[[0, 0, 0], [3.8, 0, 0]], cell=[20, 20, 20])
    compare_nl(at, 5.0)
    compare_calc(at)
    at.pbc = True
    compare_nl(at, 5.0)
    compare_calc(at)
    return "pass"


@check("geometry", "one atom interacting with its own images")
def g_one_images():
    at = Atoms("Ar", positions=[[0.3, 0.2, 0.1]], cell=[3.7, 3.9, 4.1], pbc=True)
    n = compare_nl(at, 8.5)
    compare_calc(at, rc=8.5)
    return f"pass ({n} image pairs == ASE; E, F, stress == ASE)"


@check("geometry", "all atoms at one point: neighbor list")
def g_one_point_nl():
    at = Atoms("Ar10", positions=np.full((10, 3), 2.5), cell=[5, 5, 5], pbc=False)
    n = compare_nl(at, 1.0)
    at.pbc = True
    n2 = compare_nl(at, 6.0)
    return f"pass ({n} open / {n2} periodic pairs == ASE)"


@check("geometry", "all atoms at one point: calculator raises ValueError")
def g_one_point_calc():
    at = Atoms("Ar10", positions=np.full((10, 3), 2.5), cell=[5, 5, 5], pbc=False)
    at.calc = MLGCalculator(lj_pair())
    return clear_error(at.get_potential_energy, ["atoms", "distance"])


@check("geometry", "planar (monolayer) and linear (chain) systems")
def g_planar_linear():
    rng = np.random.default_rng(7)
    plane = Atoms("Ar50", positions=np.c_[rng.random((50, 2)) * 20, np.zeros(50)],
                  cell=[20, 20, 0], pbc=[True, True, False])
    chain = Atoms("Ar30", positions=np.c_[np.arange(30) * 3.8, np.zeros((30, 2))],
                  cell=[30 * 3.8, 0, 0], pbc=[True, False, False])
    free_chain = Atoms("Ar30", positions=np.c_[np.zeros(30), np.arange(30) * 3.8, np.zeros(30)])
    n = [compare_nl(x, 8.0) for x in (plane, chain, free_chain)]
    for x in (plane, chain, free_chain):
        compare_calc(x)
    return f"pass (pairs == ASE {n}; E, F == ASE)"


# --------------------------------------------------------------------------
# 2. dynamics
# --------------------------------------------------------------------------
def _step_sweep(step):
    at = ar_liquid(256, seed=8)
    spacing = (at.get_volume() / len(at)) ** (1 / 3)
    grid = MLG.from_atoms(at, sweep_cap=4)  # small cap: large steps must rebuild
    calc = MLGCalculator(lj_pair(), skin=0.3)
    rng = np.random.default_rng(9)
    worst = 0
    for _ in range(4):
        at.positions += rng.normal(0, step * spacing / math.sqrt(3), at.positions.shape)
        rec = grid.update(at.positions)
        assert rec["sweeps"] <= 4, "sweeps exceeded the cap"
        assert grid.is_monotone(), "grid not monotone after update"
        worst = max(worst, rec["sweeps"])
        compare_calc(at, calc, rtol=1e-9)
    return worst, grid.stats["rebuilds"]


@check("dynamics", "per-step displacement 1e-6..3 spacings: sweeps bounded, exact calculator")
def d_steps():
    out = []
    for step in (1e-6, 1e-3, 0.1, 0.5, 1.0, 3.0):
        sw, rb = _step_sweep(step)
        out.append(f"{step:g}:{sw}sw/{rb}rb")
    return ("pass (sweep_cap 4; per step size: max sweeps / rebuilds in 4 steps: "
            + ", ".join(out) + ")")


@check("dynamics", "crystal melting (fcc, random displacements growing to 2 A)")
def d_melt():
    at = fcc(4)
    ref = at.positions.copy()
    calc = MLGCalculator(lj_pair())
    rng = np.random.default_rng(10)
    for amp in (0.05, 0.2, 0.5, 1.0, 2.0):
        at.positions = ref + rng.normal(0, amp, ref.shape)
        compare_calc(at, calc, rtol=1e-9)
    return f"pass (5 stages == ASE; grid rebuilds {calc.stats['grid_rebuilds']})"


@check("dynamics", "gas condensing (positions scaled toward centre, open)")
def d_condense():
    rng = np.random.default_rng(11)
    pos = rng.random((150, 3)) * 80
    at = Atoms("Ar150", positions=pos)
    calc = MLGCalculator(lj_pair())
    c = pos.mean(axis=0)
    for s in (1.0, 0.8, 0.6, 0.45, 0.35):
        at.positions = c + (pos - c) * s
        compare_calc(at, calc, rtol=1e-9)
    return "pass (5 stages == ASE)"


@check("dynamics", "sudden 10% compression (cell and positions)")
def d_compress():
    at = ar_liquid(256, seed=12)
    calc = MLGCalculator(lj_pair())
    compare_calc(at, calc, rtol=1e-9)
    b, lb = calc.stats["grid_builds"], calc.stats["list_builds"]
    at.set_cell(at.cell * 0.9, scale_atoms=True)
    compare_calc(at, calc, rtol=1e-9)
    # an affine change keeps the grid's order; the pair list is kept only
    # while 0.9 (rc + skin) > rc, i.e. the skin covers the strain
    assert calc.stats["grid_builds"] == b, "grid rebuilt after an affine cell change"
    kept = 0.9 * (calc.potential.cutoff + calc.skin) > calc.potential.cutoff
    assert calc.stats["list_builds"] == lb + (not kept), "pair list kept/rebuilt wrongly"
    at.set_cell(at.cell * 0.85, scale_atoms=True)  # beyond the skin now
    compare_calc(at, calc, rtol=1e-9)
    return (f"pass (grid kept, list {'kept' if kept else 'rebuilt'} at 10%, "
            f"E/F/stress == ASE after 10% and 23.5%)")


@check("dynamics", "atoms added / removed between calculator calls")
def d_add_remove():
    at = ar_liquid(108, seed=13)
    calc = MLGCalculator(lj_pair(6.0))
    compare_calc(at, calc, rc=6.0)
    del at[[0, 5, 17]]
    compare_calc(at, calc, rc=6.0)
    at.append("Ar")
    at.positions[-1] = at.cell.sum(axis=0) / 2 + 0.37
    compare_calc(at, calc, rc=6.0)
    at += Atoms("Ar2", positions=[[1, 1, 1], [5, 1, 2]])
    compare_calc(at, calc, rc=6.0)
    # also when the count is unchanged but identities changed (remove one, add one)
    del at[3]
    at.append("Ar")
    at.positions[-1] = [2.2, 7.1, 3.3]
    compare_calc(at, calc, rc=6.0)
    return "pass (4 changes == ASE)"


# --------------------------------------------------------------------------
# 3. arithmetic
# --------------------------------------------------------------------------
@check("arithmetic", "float32 and non-contiguous positions (MLG, neighbor_list, calculator)")
def a_dtypes():
    at = ar_liquid(108, seed=14)
    pos64 = at.positions.copy()
    p32 = pos64.astype(np.float32)
    big = np.zeros((len(at), 6))
    big[:, ::2] = pos64
    nc = big[:, ::2]
    assert not nc.flags.c_contiguous
    for p in (p32, nc, np.asfortranarray(pos64)):
        g = MLG(p, at.cell.array, True)
        assert g.positions.dtype == np.float64 and g.is_monotone()
        from ase_mlg.neighborlist import primitive_neighbor_list
        r = primitive_neighbor_list("ijd", at.pbc, at.cell.array, p, 6.0)
        assert r[2].dtype == np.float64
    a32 = at.copy()
    a32.arrays["positions"] = p32  # ASE keeps whatever array is stored
    compare_nl(a32, 6.0, dtol=1e-5)  # ASE itself works in float32 here
    compare_calc(at.copy(), rc=6.0)
    b = at.copy()
    b.arrays["positions"] = np.asfortranarray(p32.astype(np.float64))
    b.calc = MLGCalculator(lj_pair(6.0))
    e64 = b.get_potential_energy()
    a32.calc = MLGCalculator(lj_pair(6.0))
    assert a32.get_potential_energy() == e64, "float32 input not computed in float64"
    return "pass (float32, strided, Fortran order; float64 results == ASE)"


def _big_energy(n):
    at = ar_liquid(n, seed=15)
    calc = MLGCalculator(lj_pair(8.5))
    at.calc = calc
    e = at.get_potential_energy()
    en = at.get_potential_energies()
    ref = math.fsum(en.tolist())
    rel = abs(e - ref) / abs(ref)
    return len(at), e, rel


@check("arithmetic", "total energy of ~1e6 atoms (EXTREMES_BIG_N) vs math.fsum of per-atom energies")
def a_big_sum():
    n = int(os.environ.get("EXTREMES_BIG_N", "1000000"))
    t = time.perf_counter()
    natoms, e, rel = _big_energy(n)
    assert rel <= 1e-12, f"relative error {rel:.2e}"
    return f"pass (N = {natoms}, |E - fsum|/|E| = {rel:.1e}, {time.perf_counter() - t:.1f} s)"


@check("arithmetic", "LJ at r -> 0 (1e-300 .. 1e-3 A): ValueError, not inf/NaN")
def a_r_to_zero():
    msgs = []
    for r in (0.0, 1e-300, 1e-160, 1e-30, 1e-3):
        at = Atoms("Ar2", positions=[[0, 0, 0], [r, 0, 0]])
        at.calc = MLGCalculator(lj_pair())
        try:
            f = at.get_forces()
        except ValueError as err:
            assert "numba" not in str(err)
            msgs.append(f"{r:g}: ValueError")
            continue
        assert np.isfinite(f).all() and np.isfinite(at.get_potential_energy()), \
            f"r = {r:g}: non-finite forces {f[0]}"
        msgs.append(f"{r:g}: finite")
    return "pass (" + ", ".join(msgs) + ")"


def nve_drift(dt_fs, steps=200, n=256, seed=16):
    """Max |E - E0| per atom (eV) of velocity Verlet, LJ argon liquid."""
    from ase import units
    from ase.md.verlet import VelocityVerlet
    from ase.md.velocitydistribution import thermalize_momenta
    at = ar_liquid(n, rho=0.0205, seed=seed, jitter=0.05)
    at.calc = MLGCalculator(LennardJones(sigma=SIGMA, epsilon=EPS, rc=8.5, smooth=True))
    thermalize_momenta(at, temperature_K=100, rng=np.random.default_rng(seed))
    dyn = VelocityVerlet(at, timestep=dt_fs * units.fs)
    e0 = at.get_total_energy()
    worst = 0.0
    for _ in range(steps):
        dyn.run(1)
        e = at.get_total_energy()
        worst = max(worst, abs(e - e0))
        if not np.isfinite(e) or worst > 0.1 * len(at):
            # blown up (> 0.1 eV/atom): stop before atoms fly ~1e12 A away,
            # beyond where positions can be wrapped (the 'atoms ~1e12 A' check)
            return float("inf")
    return worst / len(at)


NVE_STEPS_FS = (0.1, 1.0, 2.0, 5.0, 10.0, 20.0, 40.0, 80.0, 160.0)


@check("arithmetic", "NVE energy conservation vs time step (LJ Ar, 256 atoms, 100 steps)")
def a_nve():
    rows = [(dt, nve_drift(dt, steps=100)) for dt in NVE_STEPS_FS]
    d = dict(rows)
    assert d[0.1] < d[1.0] < d[10.0], "small steps do not conserve energy better"
    stable = [dt for dt, x in rows if x < 1e-3]
    return ("pass (max |E - E0| per atom over 100 steps: "
            + ", ".join(f"{dt:g} fs {x:.1e} eV" for dt, x in rows)
            + f"; largest dt with drift < 1 meV/atom: {max(stable):g} fs; "
            "inf = blew up, > 0.1 eV/atom)")


FAR_SCRIPT = r'''
import numpy as np
from ase import Atoms
from ase.neighborlist import neighbor_list as anl
from ase_mlg import neighbor_list
rng = np.random.default_rng(0)
at = Atoms("Ar20", positions=rng.normal(0, SCALE, (20, 3)), cell=[10, 10, 10], pbc=True)
a = sorted(zip(*anl("ij", at, 5.0)))
b = sorted(zip(*neighbor_list("ij", at, 5.0)))
assert a == b, "pairs differ from ASE"
print(len(a))
'''


def far_atoms(scale, timeout=20):
    """neighbor_list of 20 atoms ~scale A from a 10 A periodic cell, in a
    subprocess (timeout, 2 GB address-space limit)."""
    code = ("import resource; resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))\n"
            + FAR_SCRIPT.replace("SCALE", repr(float(scale))))
    env = subprocess_env(OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    try:
        r = subprocess.run([sys.executable, "-c", code], capture_output=True,
                           text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"hang: neighbor_list not done in {timeout} s") from None
    last = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else "crash"
    if r.returncode != 0 and last.startswith("ValueError: positions: atom(s)"):
        return "clear error: " + last[:120]
    assert r.returncode == 0, last
    return f"pass ({int(r.stdout.split()[-1])} pairs == ASE)"


@check("geometry", "atoms ~1e8 A (1e7 cells) from the cell, not on cell multiples")
def g_far_1e8():
    return far_atoms(1e8)


@check("geometry", "atoms ~1e11 A (1e10 cells) from the cell, not on cell multiples")
def g_far_1e11():
    return far_atoms(1e11)


@check("geometry", "atoms ~1e12 A (1e11 cells) from the cell (e.g. after an NVE blow-up)")
def g_far_1e12():
    return far_atoms(1e12)


@check("geometry", "atoms 1e300 A from a periodic cell (MLG, neighbor_list, calculator)")
def g_far_1e300():
    at = small_liquid()
    at.positions[4] += 1e300
    out = [clear_error(lambda: MLG.from_atoms(at), ["atom(s) [4]"]),
           clear_error(lambda: MLG.from_atoms(small_liquid()).update(at.positions), ["atom(s) [4]"]),
           clear_error(lambda: neighbor_list("ij", at, 3.0), ["atom(s) [4]"])]
    at.calc = MLGCalculator(lj_pair(6.0))
    out.append(clear_error(at.get_potential_energy, ["atom(s) [4]"]))
    return out[0]
