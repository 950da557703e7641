"""ase_mlg.md: the compiled VelocityVerlet and Langevin against ASE's classes.

The compiled step reproduces ASE's arithmetic operation by operation, so the
trajectories are compared to a tolerance far below any integrator error
(1e-10 Å after 50 steps) and, where the platform compiles without fused
multiply-adds (x86-64), bit for bit.  The Langevin thermostat is also
checked statistically against its target temperature.
"""

import platform
import warnings

import numpy as np
import pytest
from ase import units
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones as ASELennardJones
from ase.constraints import FixAtoms, FixCom
from ase.io import Trajectory
from ase.md.langevin import Langevin as ASELangevin
from ase.md.velocitydistribution import Stationary, thermalize_momenta
from ase.md.verlet import VelocityVerlet as ASEVelocityVerlet

import ase_mlg
import ase_mlg.md
from ase_mlg.md import Langevin, VelocityVerlet
from ase_mlg.potentials import LennardJones

SIGMA, EPS, RC = 3.405, 0.0104, 8.5    # Å, eV, Å
DT = 5 * units.fs
STEPS = 50
FIXED = [0, 7, 40]
BITWISE = platform.machine().lower() in ("x86_64", "amd64")


def argon(seed=0, temperature_K=120.0):
    """108 atoms of argon, fcc a = 5.26 Å rattled by 0.1 Å, momenta at
    ``temperature_K`` from a fixed seed, indices shuffled."""
    atoms = bulk("Ar", "fcc", a=5.26, cubic=True).repeat(3)
    rng = np.random.default_rng(seed)
    atoms.positions += rng.normal(scale=0.1, size=atoms.positions.shape)
    thermalize_momenta(atoms, temperature_K=temperature_K, rng=rng)
    Stationary(atoms)
    return atoms[rng.permutation(len(atoms))]


def make_calc(kind):
    if kind == "mlg":
        return ase_mlg.MLGCalculator(LennardJones(sigma=SIGMA, epsilon=EPS, rc=RC), skin=1.0)
    return ASELennardJones(sigma=SIGMA, epsilon=EPS, rc=RC, smooth=False)


def setup(kind, fixed=False, seed=0):
    atoms = argon(seed)
    if fixed:
        atoms.set_constraint(FixAtoms(indices=FIXED))
    atoms.calc = make_calc(kind)
    return atoms


def state(atoms):
    return (atoms.get_positions(), atoms.get_momenta(),
            atoms.get_potential_energy(), atoms.get_kinetic_energy())


def assert_same(ref, got):
    """Positions (Å), momenta, potential and kinetic energy (eV) agree to
    rounding, and bit for bit where the platform allows."""
    np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=1e-10)
    assert got[2] == pytest.approx(ref[2], rel=1e-12, abs=1e-12)
    assert got[3] == pytest.approx(ref[3], rel=1e-12, abs=1e-12)
    if BITWISE:
        np.testing.assert_array_equal(got[0], ref[0])
        np.testing.assert_array_equal(got[1], ref[1])


def langevin(cls, atoms, fixcm, seed=42, **kwargs):
    with warnings.catch_warnings():  # ASE's fixcm deprecation (3.28)
        warnings.simplefilter("ignore", FutureWarning)
        return cls(atoms, DT, temperature_K=100.0, friction=0.02 / units.fs,
                   fixcm=fixcm, rng=np.random.default_rng(seed), **kwargs)


# ------------------------------------------------------------ trajectories

@pytest.mark.parametrize("kind", ["mlg", "ase-lj"])
@pytest.mark.parametrize("fixed", [False, True], ids=["free", "FixAtoms"])
def test_verlet_follows_ases_trajectory(kind, fixed):
    ref, got = setup(kind, fixed), setup(kind, fixed)
    ASEVelocityVerlet(ref, DT).run(STEPS)
    dyn = VelocityVerlet(got, DT)
    dyn.run(STEPS)
    assert dyn.path == "compiled"
    assert dyn.nsteps == STEPS
    assert_same(state(ref), state(got))
    # the run moved the atoms (a step that did nothing would also "agree")
    assert np.abs(got.positions - argon().positions).max() > 0.1
    if fixed:
        np.testing.assert_array_equal(got.positions[FIXED], argon().positions[FIXED])
        np.testing.assert_array_equal(got.get_momenta()[FIXED], 0.0)


@pytest.mark.parametrize("kind,fixcm,fixed", [("mlg", False, False), ("mlg", True, True),
                                              ("ase-lj", True, False),
                                              ("ase-lj", False, True)])
def test_langevin_follows_ases_trajectory_for_the_same_seed(kind, fixcm, fixed):
    ref, got = setup(kind, fixed), setup(kind, fixed)
    dref, dyn = langevin(ASELangevin, ref, fixcm), langevin(Langevin, got, fixcm)
    dref.run(STEPS)
    dyn.run(STEPS)
    assert dyn.path == "compiled"
    assert_same(state(ref), state(got))
    np.testing.assert_allclose(dyn.v, dref.v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dyn.rnd_pos, dref.rnd_pos, rtol=0, atol=1e-14)
    # ASE's setters recompute the coefficients for both alike
    for d in (dref, dyn):
        d.set_temperature(temperature_K=60.0)
        d.set_friction(0.05 / units.fs)
        d.run(10)
    assert_same(state(ref), state(got))


def test_any_calculator_emt_copper():
    out = []
    for cls in (ASEVelocityVerlet, VelocityVerlet):
        atoms = bulk("Cu", "fcc", a=3.6, cubic=True).repeat(3)
        atoms.rattle(0.05, seed=1)
        atoms.set_constraint(FixAtoms(indices=[1, 2]))
        atoms.calc = EMT()
        cls(atoms, 2 * units.fs).run(20)
        out.append(state(atoms))
    assert_same(*out)


def test_observers_that_move_atoms_are_seen():
    """An observer edits positions between steps: the next step's forces
    are those of the edited positions, as in ASE."""
    out = []
    for cls in (ASEVelocityVerlet, VelocityVerlet):
        atoms = setup("mlg")
        dyn = cls(atoms, DT)

        def kick(atoms=atoms):
            atoms.set_positions(atoms.positions + [0.0, 0.0, 0.01])
            atoms.positions[3] += 0.02         # in place, as scripts do
        dyn.attach(kick, interval=4)
        dyn.run(20)
        out.append(state(atoms))
    assert_same(*out)


def test_a_different_seed_gives_a_different_trajectory():
    a, b = setup("mlg"), setup("mlg")
    langevin(Langevin, a, False, seed=1).run(10)
    langevin(Langevin, b, False, seed=2).run(10)
    assert np.abs(a.positions - b.positions).max() > 1e-4


def test_langevin_holds_its_temperature():
    """Mean kinetic temperature over a run within 4 standard errors of the
    target, and resolved well enough that a 10% error would fail."""
    atoms = setup("mlg", seed=3)
    target = 90.0
    thermalize_momenta(atoms, temperature_K=target, rng=np.random.default_rng(5))
    dyn = Langevin(atoms, DT, temperature_K=target, friction=0.05 / units.fs, fixcm=False,
                   rng=np.random.default_rng(11))
    dyn.run(100)                      # equilibrate (1/friction = 4 steps)
    temps = []
    dyn.attach(lambda: temps.append(atoms.get_temperature()), interval=1)
    dyn.run(1500)
    # block averages: blocks of 50 steps are many correlation times long
    assert len(temps) == 1500
    blocks = np.asarray(temps).reshape(-1, 50).mean(axis=1)
    mean = blocks.mean()
    se = blocks.std(ddof=1) / np.sqrt(len(blocks))
    assert se < 0.025 * target
    assert abs(mean - target) < 4 * se, (mean, se)
    assert abs(mean - 1.1 * target) > 4 * se


# ---------------------------------------------------- ASE's machinery kept

def test_observers_irun_and_step_counts_as_ase():
    calls = {}
    dyns = {}
    for name, cls in [("ase", ASEVelocityVerlet), ("mlg", VelocityVerlet)]:
        atoms = setup("mlg")
        dyn = cls(atoms, DT)
        calls[name] = []
        dyn.attach(lambda d=dyn, c=calls[name]: c.append(("every3", d.nsteps)), interval=3)
        dyn.attach(lambda d=dyn, c=calls[name]: c.append(("at7", d.nsteps)), interval=-7)
        dyn.insert_observer(lambda d=dyn, c=calls[name]: c.append(("first", d.nsteps)),
                            interval=5)
        yields = list(dyn.irun(8))
        yields += list(dyn.irun(4))
        calls[name].append(("yields", tuple(yields)))
        dyns[name] = dyn
    assert calls["mlg"] == calls["ase"]
    assert ("at7", 7) in calls["mlg"] and ("every3", 12) in calls["mlg"]
    assert dyns["mlg"].nsteps == dyns["ase"].nsteps == 12
    assert dyns["mlg"].max_steps == dyns["ase"].max_steps == 12
    assert dyns["mlg"].get_time() == dyns["ase"].get_time()


@pytest.mark.parametrize("which", ["verlet", "langevin"])
def test_trajectory_and_log_match_ases(tmp_path, which):
    out = {}
    for name, cls in [("ase", (ASEVelocityVerlet, ASELangevin)),
                      ("mlg", (VelocityVerlet, Langevin))]:
        atoms = setup("mlg")
        traj, log = tmp_path / f"{name}.traj", tmp_path / f"{name}.log"
        kw = dict(trajectory=str(traj), logfile=str(log), loginterval=4)
        if which == "verlet":
            dyn = cls[0](atoms, DT, **kw)
        else:
            dyn = langevin(cls[1], atoms, False, **kw)
        dyn.run(20)
        dyn.close()
        with Trajectory(str(traj)) as t:
            frames = [(a.get_positions(), a.get_momenta(), a.get_potential_energy())
                      for a in t]
            description = t.description
        out[name] = (log.read_text(), frames, description)
    log_ase, frames_ase, desc_ase = out["ase"]
    log_mlg, frames_mlg, desc_mlg = out["mlg"]
    assert log_mlg == log_ase
    assert len(log_mlg.splitlines()) == 1 + 6       # header + steps 0, 4, ..., 20
    assert len(frames_mlg) == len(frames_ase) == 6
    for a, b in zip(frames_ase, frames_mlg):
        np.testing.assert_allclose(b[0], a[0], rtol=0, atol=1e-10)
        np.testing.assert_allclose(b[1], a[1], rtol=0, atol=1e-10)
        assert b[2] == pytest.approx(a[2], rel=1e-12)
    assert desc_mlg == desc_ase
    assert desc_mlg["md-type"] == ("VelocityVerlet" if which == "verlet" else "Langevin")


def test_append_trajectory(tmp_path):
    traj = str(tmp_path / "md.traj")
    atoms = setup("mlg")
    with VelocityVerlet(atoms, DT, trajectory=traj) as dyn:
        dyn.run(3)
    with VelocityVerlet(atoms, DT, trajectory=traj, append_trajectory=True) as dyn:
        dyn.run(2)
    with Trajectory(traj) as t:
        assert len(t) == 4 + 3


# --------------------------------------------------------- ASE's semantics

@pytest.mark.parametrize("kind", ["mlg", "ase-lj"])
def test_in_place_updates_are_seen_by_the_calculator(kind):
    """The step writes atoms.arrays in place (as ASE's set_array does); the
    calculator's stored copy differs, so it recomputes."""
    atoms = setup(kind)
    x, p = atoms.arrays["positions"], atoms.arrays["momenta"]
    e0 = atoms.get_potential_energy()
    dyn = VelocityVerlet(atoms, DT)
    dyn.run(1)
    assert atoms.arrays["positions"] is x and atoms.arrays["momenta"] is p
    assert not np.shares_memory(atoms.calc.atoms.positions, x)
    np.testing.assert_array_equal(atoms.calc.atoms.positions, x)  # computed here
    assert atoms.get_potential_energy() != e0
    # an in-place edit by hand is seen too
    x[0, 0] += 0.01
    assert "positions" in atoms.calc.check_state(atoms)


def test_step_returns_read_only_forces():
    atoms = setup("mlg")
    dyn = VelocityVerlet(atoms, DT)
    f = dyn.step()
    with pytest.raises(ValueError):
        f[0, 0] = 1.0
    np.testing.assert_array_equal(f, atoms.get_forces())


@pytest.mark.parametrize("cls", [VelocityVerlet, Langevin])
def test_a_step_lets_go_of_the_old_forces_before_the_force_call(cls):
    """The old forces (and, across ranks, the pre-migration positions and
    momenta) must be free when the calculator builds a list, the memory
    peak: the step holds no reference to them during its force call."""
    import weakref
    atoms = setup("mlg")
    dyn = (cls(atoms, DT) if cls is VelocityVerlet
           else cls(atoms, DT, temperature_K=120.0, friction=0.01, rng=np.random.default_rng(1)))
    dyn.run(1)
    calc, seen = atoms.calc, []
    old = weakref.ref(calc.results["forces"])
    real = calc.calculate

    def spy(*args, **kwargs):
        seen.append(old() is None)
        return real(*args, **kwargs)

    calc.calculate = spy
    dyn.run(1)
    assert seen == [True]


def test_other_constraints_run_ases_step():
    ref, got = setup("mlg"), setup("mlg")
    for a in (ref, got):
        a.set_constraint([FixCom(), FixAtoms(indices=FIXED)])
    ASEVelocityVerlet(ref, DT).run(10)
    dyn = VelocityVerlet(got, DT)
    dyn.run(10)
    assert dyn.path == "ase: constraint FixCom"
    np.testing.assert_array_equal(got.positions, ref.positions)
    np.testing.assert_array_equal(got.get_momenta(), ref.get_momenta())
    dl = langevin(Langevin, got, False)
    dl.run(1)
    assert dl.path == "ase: constraint FixCom"


def test_masses_are_read_every_step():
    ref, got = setup("mlg"), setup("mlg")
    dref, dyn = ASEVelocityVerlet(ref, DT), VelocityVerlet(got, DT)
    for d, a in ((dref, ref), (dyn, got)):
        d.run(5)
        a.set_masses(np.linspace(20.0, 60.0, len(a)))
        d.run(5)
    assert_same(state(ref), state(got))


# ------------------------------------------------------------- bad input

@pytest.mark.parametrize("kwargs,exc,word", [
    ({"timestep": "5"}, TypeError, "timestep"),
    ({"timestep": 0.0}, ValueError, "timestep"),
    ({"timestep": -DT}, ValueError, "timestep"),
    ({"timestep": np.nan}, ValueError, "timestep"),
    ({"loginterval": 0}, ValueError, "loginterval"),
    ({"loginterval": 1.5}, TypeError, "loginterval"),
])
def test_bad_arguments_name_themselves(kwargs, exc, word):
    atoms = setup("mlg")
    rest = dict(kwargs)
    timestep = rest.pop("timestep", DT)
    with pytest.raises(exc, match=word):
        VelocityVerlet(atoms, timestep, **rest)
    with pytest.raises(exc, match=word):
        Langevin(atoms, timestep, temperature_K=100, friction=0.01, fixcm=False, **rest)


@pytest.mark.parametrize("kwargs,exc,word", [
    ({"friction": None}, TypeError, "friction"),
    ({"friction": -0.01}, ValueError, "friction"),
    ({"friction": "0.01"}, TypeError, "friction"),
    ({"temperature_K": None}, TypeError, "temperature_K"),
    ({"temperature_K": -5.0}, ValueError, "temperature_K"),
    ({"temperature": 0.01}, TypeError, "temperature_K"),   # both given
    ({"fixcm": "yes"}, TypeError, "fixcm"),
    ({"rng": 42}, TypeError, "rng"),
])
def test_bad_langevin_arguments_name_themselves(kwargs, exc, word):
    args = {"temperature_K": 100.0, "friction": 0.01, "fixcm": False, **kwargs}
    with pytest.raises(exc, match=word):
        Langevin(setup("mlg"), DT, **args)


def test_bad_atoms_and_forces():
    with pytest.raises(TypeError, match="atoms"):
        VelocityVerlet(None, DT)
    atoms = setup("mlg")
    with pytest.raises(ValueError, match="forces"):
        VelocityVerlet(atoms, DT).step(np.zeros((3, 3)))


def test_the_subpackage_exports():
    assert ase_mlg.md.__all__ == ["VelocityVerlet", "Langevin"]
    assert issubclass(ase_mlg.md.VelocityVerlet, ASEVelocityVerlet)
    assert issubclass(ase_mlg.md.Langevin, ASELangevin)


def _counting_checks(monkeypatch):
    calls = []
    real = ase_mlg.MLGCalculator.check_state
    monkeypatch.setattr(ase_mlg.MLGCalculator, "check_state",
                        lambda self, a, tol=1e-15: calls.append(1) or real(self, a, tol))
    return calls


@pytest.mark.parametrize("cls", [VelocityVerlet, "langevin"])
def test_run_checks_the_state_only_where_other_code_ran(monkeypatch, cls):
    """Inside ``run`` nothing but the integrator touches the atoms between
    steps unless an observer is due: a step takes the last step's forces
    without ASE's check, and the force call after the drift knows that only
    the positions moved (issue 24: 0.32 -> 0.18 ms a step outside the force
    call at 10,976 atoms).  The first step of a run, a step after a due
    observer, and every step of a user's ``irun`` loop check once; the
    forces stay those of the positions."""
    atoms = bulk("Ar", "fcc", a=5.26, cubic=True).repeat(3)
    atoms.rattle(0.05, seed=3)
    atoms.calc = ase_mlg.MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=6.0))
    dyn = (VelocityVerlet(atoms, 5 * units.fs) if cls is VelocityVerlet
           else langevin(Langevin, atoms, fixcm=True))
    dyn.run(1)
    calls = _counting_checks(monkeypatch)
    dyn.run(10)
    assert dyn.path == "compiled" and len(calls) == 1
    calls.clear()
    dyn.attach(lambda: None, interval=5)  # due at nsteps 15 and 20 of 12..21
    dyn.run(10)
    assert len(calls) == 1 + 2
    calls.clear()
    for _ in dyn.irun(5):  # user code may run at each yield
        pass
    assert len(calls) == 5
    ref = atoms.copy()
    ref.calc = ASELennardJones(sigma=3.405, epsilon=0.0104, rc=6.0)
    np.testing.assert_allclose(atoms.get_forces(), ref.get_forces(), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("interval", [3, -15])  # -15: once, inside run(6)
def test_edits_inside_irun_and_by_one_shot_observers_are_seen(interval):
    """What a user's ``irun`` loop or an observer due once (``interval <=
    0``) does to the atoms reaches the next step's forces, as in ASE."""
    out = []
    for cls in (ASEVelocityVerlet, VelocityVerlet):
        atoms = setup("mlg")
        dyn = cls(atoms, DT)
        dyn.attach(lambda atoms=atoms: atoms.positions.__setitem__(5, atoms.positions[5] + 0.03),
                   interval=interval)
        for k, _ in enumerate(dyn.irun(12)):
            if k == 7:
                atoms.positions[9] += 0.02
        dyn.run(6)
        out.append(state(atoms))
    assert_same(*out)


def test_zero_mass_is_named_not_a_zero_division():
    """A massless atom flies off as in ASE's numpy step (x += dt p / 0 is
    inf); the next force call names it, not a bare ZeroDivisionError from
    the compiled drift."""
    atoms = bulk("Ar", "fcc", a=5.26, cubic=True).repeat(3)
    atoms.rattle(0.01, seed=1)
    masses = atoms.get_masses()
    masses[5] = 0.0
    atoms.set_masses(masses)
    atoms.calc = ase_mlg.MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ASE's own zero-mass warning
        dyn = VelocityVerlet(atoms, 1.0)
        with pytest.raises(ValueError, match=r"atom\(s\) \[5\]"):
            dyn.run(2)
    assert dyn.path == "compiled"
