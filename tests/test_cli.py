"""The command line: the demo runs end to end; bad input is one line, exit 2."""

import io
import subprocess
import sys

from ase_mlg.cli import demo, main


def test_demo_runs_and_reports():
    out = io.StringIO()
    grid = demo(natoms=500, steps=30, out=out, md_steps=20)
    text = out.getvalue()
    assert grid.is_monotone()
    assert "sweeps/step" in text and "W = 7" in text
    share7 = float(text.split("W = 7:")[1].split()[0])
    assert share7 > 0.95


def test_cli_bad_argument_is_one_line():
    res = subprocess.run([sys.executable, "-m", "ase_mlg.cli", "demo", "--natoms", "-3"],
                         capture_output=True, text=True)
    assert res.returncode == 2
    assert "natoms" in res.stderr and "Traceback" not in res.stderr


def test_main_returns_zero():
    assert main(["demo", "--natoms", "100", "--steps", "2"]) == 0


def test_demo_md_agrees_with_ase():
    out = io.StringIO()
    demo(natoms=256, steps=2, out=out, md_steps=30)
    text = out.getvalue()
    rel = float(text.split("rel. diff ")[1].split(")")[0])
    assert rel < 1e-10
    drift = float(text.split("total energy drift ")[1].split()[0])
    assert abs(drift) < 1e-4
    # the demo validates its own trajectory against MDAnalysis and ASE
    assert "identical to MDAnalysis InterRDF" in text
    assert "identical to ase.neighborlist.NeighborList" in text
    assert text.rstrip().endswith("verdict: PASS")
