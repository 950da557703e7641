"""Declared dependency minimums are honest: every runtime and test
dependency has one, and .ci/oldest.txt (the constraints of CI's second run)
pins exactly those minimums, so CI tests the versions we declare."""

import os
import re
import sys
import tomllib
from pathlib import Path

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _pins():
    pins = {}
    for line in open(os.path.join(ROOT, ".ci", "oldest.txt")):
        line = line.split("#")[0].strip()
        if line:
            name, version = line.split("==")
            pins[name.lower()] = version
    return pins


def _declared():
    meta = tomllib.load(open(os.path.join(ROOT, "pyproject.toml"), "rb"))["project"]
    reqs = list(meta["dependencies"]) + list(meta["optional-dependencies"]["test"])
    out = {}
    for req in reqs:
        req = req.split(";")[0].strip()
        m = re.fullmatch(r"([A-Za-z0-9_.-]+)(\[[a-z,]+\])?>=([0-9.]+)", req)
        assert m, f"{req!r}: every runtime and test dependency needs a >= minimum"
        out[m.group(1).lower()] = (m.group(3), m.group(2))
    return meta, out


def _same(a, b):
    pad = lambda v: [int(x) for x in v.split(".")] + [0] * (3 - len(v.split(".")))
    return pad(a) == pad(b)


def test_oldest_pins_are_the_declared_minimums():
    meta, declared = _declared()
    pins = _pins()
    for name, (minimum, extra) in declared.items():
        assert name in pins, f"{name} missing from .ci/oldest.txt"
        assert _same(pins[name], minimum), f"{name}: declared >={minimum}, pinned {pins[name]}"
        if extra == "[distributed]":
            assert _same(pins["distributed"], minimum)
    # the Python minimum is the one CI runs (python3 of this machine) or lower
    assert sys.version_info[:2] >= _python_minimum(meta)
    assert set(pins) <= set(declared) | {"distributed"}


def _python_minimum(meta):
    m = re.fullmatch(r">=(\d+)\.(\d+)", meta["requires-python"])
    assert m, f"requires-python {meta['requires-python']!r}: a >= X.Y minimum"
    return int(m.group(1)), int(m.group(2))


def test_readme_names_the_oldest_versions():
    """The README's list of the oldest versions CI runs ("(`.ci/oldest.txt`:
    Python 3.11, ASE 3.29, ...)") is .ci/oldest.txt's pins and the declared
    Python minimum."""
    meta, _ = _declared()
    pins = _pins()
    text = " ".join(open(os.path.join(ROOT, "README.md"), encoding="utf-8").read().split())
    m = re.search(r"\(`\.ci/oldest\.txt`: ([^);]*)[);]", text)
    assert m, "README: the oldest versions, after `.ci/oldest.txt`:"
    named = dict(item.rsplit(" ", 1) for item in m.group(1).split(", "))
    assert named.pop("Python") == "%d.%d" % _python_minimum(meta)
    assert len(named) >= 5
    for name, version in named.items():
        assert name.lower() in pins, f"README names {name}, not pinned in .ci/oldest.txt"
        assert _same(pins[name.lower()], version), f"{name}: README {version}, pinned {pins[name.lower()]}"


def test_ase_minimum_is_needed():
    """The code needs ASE 3.29's thermalize_momenta (new in 3.29): the
    package imports it, and the declared minimum is not lower than 3.29."""
    import ast
    from ase.md.velocitydistribution import thermalize_momenta  # noqa: F401
    users = []
    for path in sorted(Path(ROOT, "ase_mlg").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if (isinstance(node, ast.ImportFrom) and node.module == "ase.md.velocitydistribution"
                    and "thermalize_momenta" in {a.name for a in node.names}):
                users.append(path.name)
    assert users, "nothing imports thermalize_momenta: is ASE 3.29 still the minimum?"
    _, declared = _declared()
    assert tuple(int(x) for x in declared["ase"][0].split(".")[:2]) >= (3, 29)
