"""Declared dependency minimums are honest: every runtime and test
dependency has one, and .ci/oldest.txt (the constraints of CI's second run)
pins exactly those minimums, so CI tests the versions we declare."""

import os
import re
import sys
import tomllib

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
    py = meta["requires-python"]
    assert py == ">=3.11"
    assert sys.version_info >= (3, 11)
    assert set(pins) <= set(declared) | {"distributed"}


def test_ase_minimum_is_needed():
    """The code needs ASE 3.29's thermalize_momenta: the declared minimum
    is not lower than that."""
    import ase
    from ase.md.velocitydistribution import thermalize_momenta  # noqa: F401
    _, declared = _declared()
    assert tuple(int(x) for x in declared["ase"][0].split(".")[:2]) >= (3, 29)
    assert tuple(int(x) for x in ase.__version__.split(".")[:2]) >= (3, 29)
