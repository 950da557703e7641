"""Every code block of README.md runs as written (issue 18.8).

``python`` blocks run as a reader who copies one would: each saved as its own
script in an empty directory and run by ``python block.py`` in a fresh
interpreter (so a recipe that starts processes, dask's ``LocalCluster``, must
carry its ``if __name__ == "__main__":`` guard).  ``bash`` blocks
are parsed: every ``ase-mlg`` command by the real command-line parser,
``pip install`` targets against pyproject's extras, ``pytest`` invocations
against the markers and paths they name; the README's first RDF command
also runs, in this process (``ase_mlg.cli.main``), on MDAnalysis's test
trajectory copied to ``topol.tpr`` and ``traj.xtc`` in an empty directory.  A command of any other kind fails here until this file learns
to check it.
"""

import os
import re
import shlex
import subprocess
import sys
import tomllib  # Python >= 3.11, as the package requires

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = os.path.join(ROOT, "README.md")
BLOCKS = re.findall(r"^```(\w+)\n(.*?)^```", open(README, encoding="utf-8").read(),
                    flags=re.S | re.M)
PYTHON = [code for lang, code in BLOCKS if lang == "python"]
BASH = [code for lang, code in BLOCKS if lang == "bash"]


def _commands(code):
    """Each command of a bash block: lines without comments, split at &&."""
    for line in code.splitlines():
        words = shlex.split(line, comments=True)
        cmd = []
        for w in words + ["&&"]:
            if w == "&&":
                if cmd:
                    yield cmd
                cmd = []
            else:
                cmd.append(w)


def test_the_readme_has_its_blocks():
    assert len(PYTHON) >= 3 and len(BASH) >= 2
    assert not [lang for lang, _ in BLOCKS if lang not in ("python", "bash")]


@pytest.mark.parametrize("code", PYTHON,
                         ids=[f"python{k}" for k in range(len(PYTHON))])
def test_python_block_runs(code, tmp_path):
    (tmp_path / "block.py").write_text(code, encoding="utf-8")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")  # as the README advises
    proc = subprocess.run([sys.executable, "block.py"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    rc = proc.returncode
    assert rc == 0, f"README block exited {rc}\n--- stderr ---\n{proc.stderr[-6000:]}"


def _pyproject():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        return tomllib.load(f)


def _check(cmd):
    from ase_mlg.cli import _parser
    if cmd[0] == "ase-mlg":
        try:
            _parser().parse_args(cmd[1:])
        except SystemExit as exc:
            raise AssertionError(f"ase-mlg rejects {shlex.join(cmd)}") from exc
    elif cmd[:2] == ["pip", "install"]:
        extras = _pyproject()["project"]["optional-dependencies"]
        for target in cmd[2:]:
            m = re.fullmatch(r"\.(?:\[([\w,-]+)\])?", target)
            assert m, target
            for extra in filter(None, (m.group(1) or "").split(",")):
                assert extra in extras, target
    elif cmd[:3] == ["python", "-m", "pytest"]:
        markers = " ".join(_pyproject()["tool"]["pytest"]["ini_options"]["markers"])
        args = iter(cmd[3:])
        for a in args:
            if a == "-m":
                for word in re.findall(r"\w+", next(args)):
                    assert word in ("not", "and", "or") or f"{word}:" in markers, word
            elif not a.startswith("-"):
                assert os.path.exists(os.path.join(ROOT, a)), a
    elif cmd[0] == "mpiexec":
        # mpiexec -n P python SCRIPT: a script of the repository (run by
        # tests/test_ranks.py and tests/test_surface_examples.py)
        assert cmd[1] == "-n" and int(cmd[2]) >= 1 and cmd[3] == "python", cmd
        assert os.path.exists(os.path.join(ROOT, cmd[4])), cmd[4]
    elif cmd[0] == "export":
        assert all(re.fullmatch(r"\w+=\S*", a) for a in cmd[1:]), cmd
    else:
        raise AssertionError(f"README command of an unchecked kind: {shlex.join(cmd)}")


@pytest.mark.parametrize("code", BASH, ids=[f"bash{k}" for k in range(len(BASH))])
def test_bash_block_parses(code):
    cmds = list(_commands(code))
    assert cmds
    for cmd in cmds:
        _check(cmd)


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_first_rdf_command_runs(tmp_path, monkeypatch, capsys):
    import shutil

    from MDAnalysisTests import datafiles

    from ase_mlg.cli import main
    import numpy as np
    cmd = next(c for code in BASH for c in _commands(code) if c[:2] == ["ase-mlg", "rdf"])
    argv = cmd[1:]
    assert argv[1:3] == ["topol.tpr", "traj.xtc"]
    # MDAnalysis's test files under the README's names, in an empty directory
    # (MDAnalysis writes the trajectory's offsets file beside it: here)
    shutil.copy(datafiles.TPR, tmp_path / "topol.tpr")
    shutil.copy(datafiles.XTC, tmp_path / "traj.xtc")
    monkeypatch.chdir(tmp_path)
    assert main(argv + ["--output", "g.txt"]) == 0
    err = capsys.readouterr().err
    table = np.loadtxt(tmp_path / "g.txt")
    # the example a user wants: no self pairs in the first bin, a plot written
    assert table[0, 2] == 0 and table[:, 2].sum() > 0
    assert "self pairs" not in err
    png = [a for a in argv if a.endswith(".png")]
    assert png and (tmp_path / png[0]).read_bytes()[:4] == b"\x89PNG"
