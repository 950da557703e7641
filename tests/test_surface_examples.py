"""Every example in examples/ runs as a script and reports what it promises.

They run as subprocesses with output to pipes, so this also checks that no
progress bar is drawn when output is not a terminal.  CI runs this file on
the newest and on the oldest declared dependency versions (.ci/run).
"""

import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(ROOT, "examples")


def _number(pattern, text):
    m = re.search(pattern, text)
    assert m, f"{pattern!r} not in output:\n{text}"
    return float(m.group(1))


def _run(name):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    res = subprocess.run([sys.executable, os.path.join(EXAMPLES, name)],
                         capture_output=True, text=True, timeout=300, env=env,
                         stdin=subprocess.DEVNULL)
    assert res.returncode == 0, res.stderr[-2000:]
    for stream in (res.stdout, res.stderr):
        assert "\r" not in stream and "%|" not in stream
    return res.stdout


def test_every_example_is_tested():
    names = sorted(f for f in os.listdir(EXAMPLES) if f.endswith(".py"))
    assert names == sorted(CHECKS)


def _nve_argon(out):
    assert _number(r"max deviation ([-+0-9.e]+) eV", out) < 1e-4
    assert "'grid_builds': 1" in out


def _nvt_langevin(out):
    assert abs(_number(r"last half: ([0-9.]+) ±", out) - 100) < 10


def _binary_mixture(out):
    assert abs(_number(r"energy drift ([-+0-9.e]+) eV/atom", out)) < 1e-4


def _relax_nanoparticle(out):
    e = re.search(r"E = ([-0-9.]+) -> ([-0-9.]+) \(FIRE\) -> ([-0-9.]+) eV/atom", out)
    assert e, out
    e0, e1, e2 = map(float, e.groups())
    assert e0 > e1 > e2
    assert _number(r"max force ([0-9.e+-]+) eV", out) <= 1e-4


CHECKS = {"nve_argon.py": _nve_argon, "nvt_langevin.py": _nvt_langevin,
          "binary_mixture.py": _binary_mixture,
          "relax_nanoparticle.py": _relax_nanoparticle}


@pytest.mark.parametrize("name", sorted(CHECKS))
def test_example(name):
    CHECKS[name](_run(name))
