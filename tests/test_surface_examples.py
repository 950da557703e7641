"""Every example in examples/ runs as a script and reports what it promises.

They run as subprocesses with output to pipes, so this also checks that no
progress bar is drawn when output is not a terminal.  What they promise is
checked on the values the script computed (its globals after the run), not
on the sentences it prints.  CI runs this file on the newest and on the
oldest declared dependency versions (.ci/run).
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(ROOT, "examples")

# runs a script as `python SCRIPT` would (its folder first on sys.path, run
# as __main__), then writes the requested expressions over its globals as
# JSON to the file named next
_RUNNER = """\
import json, os, runpy, sys
script, out, wanted = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
sys.argv, sys.path[0] = [script], os.path.dirname(script)
g = runpy.run_path(script, run_name="__main__")
with open(out, "w") as f:
    json.dump({k: eval(v, g) for k, v in wanted.items()}, f,
              default=lambda x: x.tolist())
"""


def _run(name, tmp_path, **wanted):
    """Run examples/NAME as a script; return {key: value} of the ``wanted``
    expressions (key=expression) evaluated in the script's globals."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    out = tmp_path / "values.json"
    res = subprocess.run([sys.executable, "-c", _RUNNER, os.path.join(EXAMPLES, name),
                          str(out), json.dumps(wanted)],
                         capture_output=True, text=True, timeout=300, env=env,
                         stdin=subprocess.DEVNULL, cwd=tmp_path)  # files it writes land there
    assert res.returncode == 0, res.stderr[-2000:]
    for stream in (res.stdout, res.stderr):
        assert "\r" not in stream and "%|" not in stream
    return json.loads(out.read_text())


def test_every_example_is_tested():
    names = sorted(f for f in os.listdir(EXAMPLES) if f.endswith(".py"))
    assert names == sorted(CHECKS)


def _nve_argon(tmp_path):
    v = _run("nve_argon.py", tmp_path, energies="energies",
             grid_builds="atoms.calc.stats['grid_builds']")
    energies = np.array(v["energies"])  # eV/atom
    assert np.abs(energies - energies[0]).max() < 1e-4
    assert v["grid_builds"] == 1


def _nvt_langevin(tmp_path):
    v = _run("nvt_langevin.py", tmp_path, temps="temps")  # K
    assert abs(np.mean(v["temps"][50:]) - 100) < 10


def _binary_mixture(tmp_path):
    e = _run("binary_mixture.py", tmp_path, e="e")["e"]  # eV/atom
    assert abs(e[-1] - e[0]) < 1e-4


def _relax_nanoparticle(tmp_path):
    v = _run("relax_nanoparticle.py", tmp_path, energies="[e0, e1, e2]",
             fmax="fmax")
    e0, e1, e2 = v["energies"]  # eV: start, after FIRE, after BFGS
    assert e0 > e1 > e2
    assert v["fmax"] <= 1e-4  # eV/Å


def _md_ranks(tmp_path):
    # one rank here (python md_ranks.py); .ci/run runs it under mpiexec -n 2 and -n 3
    v = _run("md_ranks.py", tmp_path, e=("(e0, e1)"), ranks="atoms.comm.size",
             frames="len(__import__('ase.io', fromlist=['read']).read('md_ranks.traj', ':'))")
    e0, e1 = v["e"]  # eV/atom
    assert abs(e1 - e0) < 1e-4 and v["ranks"] == 1 and v["frames"] == 100 // 25 + 1


CHECKS = {"nve_argon.py": _nve_argon, "md_ranks.py": _md_ranks, "nvt_langevin.py": _nvt_langevin,
          "binary_mixture.py": _binary_mixture,
          "relax_nanoparticle.py": _relax_nanoparticle}


@pytest.mark.parametrize("name", sorted(CHECKS))
def test_example(name, tmp_path):
    CHECKS[name](tmp_path)
