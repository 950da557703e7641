"""What a newcomer sees first (issue 18.6): bare ``ase-mlg`` shows examples
and the Python API, ``ase-mlg tradeoff`` keys its columns, and pytest says
what it is doing before the first dots."""

import io
import os
import re
import shlex

from ase_mlg.cli import _parser, main
from ase_mlg.cli import tradeoff as cli_tradeoff

# ``pytester`` runs a pytest session in this process
pytest_plugins = ["pytester"]

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_bare_command_shows_examples_and_the_python_api(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    examples = out.split("examples:\n", 1)[1].split("\n\n", 1)[0].splitlines()
    assert len(examples) >= 3
    for line in examples:
        # "  COMMAND  what it does": every command is one the parser accepts
        cmd = shlex.split(re.split(r"\s{2,}", line.strip())[0])
        assert cmd[0] == "ase-mlg"
        _parser().parse_args(cmd[1:])
    assert "import ase_mlg" in out and "MLGCalculator" in out and "README.md" in out


def test_tradeoff_table_has_a_key():
    args = _parser().parse_args(["tradeoff", "--natoms", "256", "--repeats", "1",
                                 "--widths", "3"])
    out = io.StringIO()
    result = cli_tradeoff.run(args, out=out)
    text = out.getvalue()
    assert "columns:" in text
    key = text.split("columns:\n", 1)[1].splitlines()
    heads = [h for h, *_ in result.columns()]
    assert len(key) == len(heads)
    for head, line in zip(heads, key):
        assert line.strip().startswith(head) and len(line.strip()) > len(head) + 10


def test_pytest_says_what_it_does_before_the_first_dots(pytester):
    """The repository's own pytest configuration and conftest, in a session
    run in this process (``pytester``: its output captured, its modules and
    working directory restored)."""
    res = pytester.runpytest_inprocess(
        "-q", "-p", "no:cacheprovider", "--collect-only", f"--rootdir={ROOT}",
        "-c", os.path.join(ROOT, "pyproject.toml"), os.path.join(ROOT, "tests", "test_layout.py"))
    lines = res.outlines
    assert res.ret == 0, "\n".join(res.outlines + res.errlines)
    assert lines[0].startswith("ase-mlg: collecting") and "compile" in lines[0]
    assert any(line.startswith("ase-mlg:") and "collected in" in line for line in lines)
