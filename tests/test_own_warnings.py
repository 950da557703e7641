"""The package's own code raises no deprecation (issue 18.7).

Two guards: pyproject's pytest ``filterwarnings`` turns a deprecation
attributed to ase_mlg's modules or to the test modules into an error for
the whole test run, and the test here records every warning of a run
through the package's main paths (the demo: grid, calculator, MD, RDF and
neighbour lists; ase_mlg.md's integrators; template="auto"; the trade-off
measurement), failing on any deprecation whose frame is ase-mlg's code.
"""

import io
import os
import tomllib
import warnings

import numpy as np

import ase_mlg

PACKAGE = os.path.dirname(os.path.abspath(ase_mlg.__file__))
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KINDS = (DeprecationWarning, PendingDeprecationWarning, FutureWarning)


def test_pytest_makes_own_deprecations_errors():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        filters = tomllib.load(f)["tool"]["pytest"]["ini_options"]["filterwarnings"]
    for kind in KINDS:
        assert f"error::{kind.__name__}:ase_mlg" in filters
    assert any(f.startswith("error::DeprecationWarning:(test_") for f in filters)
    # and only for our modules: no blanket error for third-party warnings
    assert not [f for f in filters if f.count(":") < 3 and f.startswith("error")]


def test_main_paths_raise_no_deprecation_of_their_own():
    from ase import units
    from ase.md.velocitydistribution import thermalize_momenta

    from ase_mlg import MLGCalculator
    from ase_mlg.cli import demo
    from ase_mlg.md import Langevin, VelocityVerlet
    from ase_mlg.potentials import LennardJones
    from ase_mlg.scenes import make_scene
    from ase_mlg.tradeoff import measure

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        demo(natoms=256, steps=10, out=io.StringIO(), md_steps=10)
        pot = LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)
        atoms = make_scene("liquid", 256)
        thermalize_momenta(atoms, temperature_K=90, rng=np.random.default_rng(0))
        atoms.calc = MLGCalculator(pot, template="auto")
        VelocityVerlet(atoms, 5 * units.fs).run(5)
        Langevin(atoms, 5 * units.fs, temperature_K=90, friction=0.01 / units.fs,
                 fixcm=False, rng=np.random.default_rng(0)).run(5)
        measure(make_scene("liquid", 256), pot, widths=(5,))
    ours = [f"{w.filename}:{w.lineno}: {w.category.__name__}: {w.message}"
            for w in caught if issubclass(w.category, KINDS)
            and os.path.abspath(w.filename).startswith(PACKAGE)]
    assert not ours, "\n".join(ours)
