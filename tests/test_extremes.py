"""Numerical stability at the extremes (issue 7): nothing silently wrong.

Every extreme case of ``extreme_cases.py`` (geometry, dynamics, arithmetic)
and ``bad_input_cases.py`` runs here as ``test_extreme``, plus hypothesis
property tests against ``ase.neighborlist.neighbor_list`` and
``ase.calculators.lj.LennardJones``.  ``validation/extremes.py`` runs
``test_extreme`` and writes what each case measured to
``validation/reports/extremes.md``.
"""

import contextlib
import io
import math
import os
import subprocess
import sys
import tempfile
import threading
import traceback
import warnings

import numpy as np
import pytest
from ase import Atoms
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from ase_mlg import MLG, MLGCalculator, NeighborList, neighbor_list

import bad_input_cases
import extreme_cases as E

# the 1e6-atom sum is for the report; here a 108,000-atom system (~2 s)
os.environ.setdefault("EXTREMES_BIG_N", "108000")

CHECKS = E.CHECKS + bad_input_cases.CHECKS


def _show_warning(message, category, filename, lineno, file=None, line=None):
    (file or sys.stderr).write(warnings.formatwarning(message, category, filename, lineno,
                                                      line))


def cli_here(args, timeout=60):
    """``ase-mlg ARGS`` in this process, as ``bad_input_cases.run_cli``
    runs it in a new one: :func:`ase_mlg.cli.main` on a thread (a hang
    raises ``TimeoutExpired`` after ``timeout`` s), its stdout and stderr
    captured; warnings print to stderr under Python's default filters, and
    an exception that escapes ``main`` prints its traceback, exit status 1,
    as the interpreter would."""
    from ase_mlg.cli import main
    out, err = io.StringIO(), io.StringIO()
    status = []

    def run():
        try:
            status.append(main(list(args)))
        except SystemExit as exc:
            if isinstance(exc.code, str):
                print(exc.code, file=err)
            status.append(exc.code if isinstance(exc.code, int) else int(exc.code is not None))
        except BaseException:
            err.write(traceback.format_exc())
            status.append(1)

    with warnings.catch_warnings(), contextlib.redirect_stdout(out), \
            contextlib.redirect_stderr(err):
        warnings.resetwarnings()  # a fresh interpreter's filters
        for action, category in (("default", DeprecationWarning), ("ignore", DeprecationWarning),
                                 ("ignore", PendingDeprecationWarning),
                                 ("ignore", ImportWarning), ("ignore", ResourceWarning)):
            warnings.filterwarnings(action, category=category,
                                    module="__main__" if action == "default" else "",
                                    append=True)
        warnings.showwarning = _show_warning
        worker = threading.Thread(target=run, daemon=True)
        worker.start()
        worker.join(timeout)
    if worker.is_alive():
        raise subprocess.TimeoutExpired(["ase-mlg", *args], timeout)
    return subprocess.CompletedProcess(["ase-mlg", *args], status[0], out.getvalue(),
                                       err.getvalue())


def test_cli_here_reports_like_a_process():
    r = cli_here(["demo", "--natoms", "0"])
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.startswith("ase-mlg demo: error: argument --natoms")
    r = cli_here(["--version"])
    assert r.returncode == 0 and r.stdout.startswith("ase-mlg ") and r.stderr == ""


@pytest.mark.parametrize("group,name,check",
                         [pytest.param(group, name, f, id=f"{group}: {name}")
                          for group, name, f in CHECKS])
def test_extreme(group, name, check, record_property, monkeypatch, tmp_path):
    """One extreme case; ``validation/extremes.py`` reads the recorded
    ``extreme`` (group, name) and ``result`` (what it measured).  The
    command-line cases run ``ase-mlg`` in this process (:func:`cli_here`),
    and temporary files go to this test's directory."""
    record_property("extreme", (group, name))
    monkeypatch.setattr(bad_input_cases, "run_cli", cli_here)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    res = check()
    record_property("result", res)
    assert res.startswith("pass") or res.startswith("clear error"), res


# --------------------------------------------------------------------------
# property tests (hypothesis)
# --------------------------------------------------------------------------
L = 7.0
_special = st.sampled_from([0.0, -0.0, L, float(np.nextafter(L, 0)),
                            float(np.nextafter(L, 2 * L)), float(np.nextafter(0.0, -1)),
                            5e-324, L / 2])
_coord = st.one_of(_special, st.floats(-0.5 * L, 1.5 * L, allow_nan=False))


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(pos=st.lists(st.tuples(_coord, _coord, _coord), min_size=1, max_size=12),
       pbc=st.tuples(st.booleans(), st.booleans(), st.booleans()),
       cutoff=st.sampled_from([1e-3, 0.5, 2.0, 4.0, 9.0]),
       wraps=st.integers(-10000, 10000), offset=st.sampled_from([0.0, 1e6, -1e6]))
def test_faces_far_and_offsets_match_ase(pos, pbc, cutoff, wraps, offset):
    at = Atoms(f"Ar{len(pos)}", positions=np.array(pos), cell=[L, L, L], pbc=pbc)
    E.compare_nl(at, cutoff, self_interaction=False, dtol=1e-8)
    far = at.copy()
    far.positions[0] += wraps * L * np.array(pbc, dtype=float)
    E.compare_nl(far, cutoff, dtol=1e-8)
    sh = at.copy()
    sh.positions += offset
    i0, j0, d0 = neighbor_list("ijd", at, cutoff)
    i1, j1, d1 = neighbor_list("ijd", sh, cutoff)
    # same pairs up to pairs within rounding (1e6 * eps ~ 1e-10 A) of the cutoff
    k0, k1 = np.lexsort((d0, j0, i0)), np.lexsort((d1, j1, i1))
    if len(i0) == len(i1):
        assert np.array_equal(i0[k0], i1[k1]) and np.array_equal(j0[k0], j1[k1])
        assert np.allclose(d0[k0], d1[k1], atol=1e-8)
    else:
        near = np.abs(np.concatenate([d0, d1]) - cutoff) < 1e-8
        assert near.any()


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(alpha=st.floats(10, 90), beta=st.floats(10, 90), gamma=st.floats(10, 90),
       seed=st.integers(0, 2 ** 16), cutoff=st.floats(0.5, 8.0),
       pbc=st.tuples(st.booleans(), st.booleans(), st.booleans()))
def test_oblique_cells_match_ase(alpha, beta, gamma, seed, cutoff, pbc):
    from ase.geometry import cellpar_to_cell
    # (V / abc)^2 of the cell: > 0 exactly when the angles make one; the
    # cells drawn have a volume of at least 1 A^3 (V = 210 A^3 sqrt(vf))
    ca, cb, cg = (math.cos(math.radians(x)) for x in (alpha, beta, gamma))
    vf = 1 - ca * ca - cb * cb - cg * cg + 2 * ca * cb * cg
    assume(vf > (1 / 210) ** 2)
    cell = cellpar_to_cell([5, 6, 7, alpha, beta, gamma])  # a cell: no error
    assert abs(np.linalg.det(cell)) == pytest.approx(210 * math.sqrt(vf), rel=1e-9)
    rng = np.random.default_rng(seed)
    at = Atoms("Ar10", scaled_positions=rng.random((10, 3)), cell=cell, pbc=pbc)
    E.compare_nl(at, cutoff)


@settings(max_examples=15, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(step=st.sampled_from([1e-6, 1e-4, 1e-2, 0.3, 1.0, 3.0]),
       seed=st.integers(0, 1000), skin=st.sampled_from([0.0, 0.3, 2.0]))
def test_random_walk_calculator_stays_exact(step, seed, skin):
    at = E.ar_liquid(108, seed=seed)
    spacing = (at.get_volume() / len(at)) ** (1 / 3)
    calc = MLGCalculator(E.lj_pair(6.0), skin=skin, grid_kwargs={"sweep_cap": 8})
    rng = np.random.default_rng(seed)
    for _ in range(3):
        at.positions += rng.normal(0, step * spacing / math.sqrt(3), at.positions.shape)
        E.compare_calc(at, calc, rc=6.0, rtol=1e-9)
        assert calc.grid.is_monotone()
        assert calc.grid.stats["last"] is None or calc.grid.stats["last"]["sweeps"] <= 8


@settings(max_examples=15, deadline=None)
@given(n=st.integers(1, 6), seed=st.integers(0, 1000), pbc=st.booleans())
def test_neighborlist_class_matches_ase_when_atoms_move(n, seed, pbc):
    from ase.neighborlist import NeighborList as ASENeighborList
    rng = np.random.default_rng(seed)
    at = Atoms(f"Ar{n}", positions=rng.random((n, 3)) * 6, cell=[6, 6, 6], pbc=pbc)
    ours = NeighborList([1.5] * n, skin=0.2, self_interaction=False, bothways=True)
    ref = ASENeighborList([1.5] * n, skin=0.2, self_interaction=False, bothways=True)
    for _ in range(3):
        at.positions += rng.normal(0, 0.5, at.positions.shape)  # > skin: rebuilds
        assert ours.update(at) == ref.update(at)
        for a in range(n):
            gi, go = ours.get_neighbors(a)
            ri, ro = ref.get_neighbors(a)
            assert sorted(zip(gi.tolist(), map(tuple, go.tolist()))) == \
                sorted(zip(ri.tolist(), map(tuple, ro.tolist())))


_bad_floats = st.sampled_from([np.nan, np.inf, -np.inf])


@settings(max_examples=20, deadline=None)
@given(bad=_bad_floats, atom=st.integers(0, 7), axis=st.integers(0, 2),
       api=st.sampled_from(["MLG", "nl", "calc"]))
def test_non_finite_positions_name_the_atom(bad, atom, axis, api):
    at = Atoms("Ar8", positions=np.random.default_rng(0).random((8, 3)) * 5,
               cell=[5, 5, 5], pbc=True)
    at.positions[atom, axis] = bad
    if api == "MLG":
        f = lambda: MLG.from_atoms(at)
    elif api == "nl":
        f = lambda: neighbor_list("ij", at, 2.0)
    else:
        at.calc = MLGCalculator(E.lj_pair(4.0))
        f = at.get_potential_energy
    with pytest.raises(ValueError) as exc:
        f()
    assert "numba" not in str(exc.value).lower()
    assert f"[{atom}]" in str(exc.value) or f" {atom}" in str(exc.value)


@settings(max_examples=20, deadline=None)
@given(cutoff=st.one_of(st.floats(max_value=-1e-300), _bad_floats,
                        st.complex_numbers(allow_nan=False, allow_infinity=False).filter(
                            lambda z: z.imag != 0)))
def test_bad_cutoffs_are_clear(cutoff):
    at = Atoms("Ar4", positions=np.random.default_rng(1).random((4, 3)) * 5,
               cell=[5, 5, 5], pbc=True)
    E.clear_error(lambda: neighbor_list("ij", at, cutoff), "cutoff")


def test_small_time_steps_conserve_energy_better():
    drifts = [E.nve_drift(dt, steps=60) for dt in (0.5, 5.0, 40.0)]
    assert drifts[0] < drifts[1] < drifts[2], drifts
    assert drifts[0] < 1e-8  # eV/atom over 60 steps of 0.5 fs


def test_float32_energy_equals_float64_of_same_values():
    at = E.ar_liquid(108, seed=3)
    p32 = at.positions.astype(np.float32)
    a = at.copy()
    a.arrays["positions"] = p32
    b = at.copy()
    b.positions = p32.astype(np.float64)
    a.calc = MLGCalculator(E.lj_pair(6.0))
    b.calc = MLGCalculator(E.lj_pair(6.0))
    assert a.get_potential_energy() == b.get_potential_energy()
    assert np.array_equal(a.get_forces(), b.get_forces())


def test_cli_timeouts_do_not_hang():
    r = cli_here(["rdf", "/no/such.xyz"], timeout=60)
    assert r.returncode != 0 and len(r.stderr.strip().splitlines()) == 1
