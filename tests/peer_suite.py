"""Run a peer's own test files against our drop-ins.

A test file of an installed package (ASE's ``ase/test/...``) is executed
afresh as a new module, so the package itself is untouched, and the names
it imported from the peer are then replaced by ours in that module's
namespace: its test functions, run from there, exercise our code with the
peer's own assertions.  Used by ``test_ase_calc_suite.py`` and
``test_ase_neighbor_suite.py``.
"""

import importlib.util
import inspect
import os

__all__ = ["load", "peer_tests"]


def load(package, fname, replacements, prefix):
    """The test file ``fname`` of ``package`` (a module object) as a fresh
    module named ``prefix + stem``, with every name of ``replacements``
    (name -> object) that the file defines set to ours."""
    path = os.path.join(os.path.dirname(package.__file__), fname)
    spec = importlib.util.spec_from_file_location(f"{prefix}{fname[:-3]}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    for name, ours in replacements.items():
        if name in vars(mod):
            setattr(mod, name, ours)
    return mod


def peer_tests(mod):
    """(name, function) of the module's ``test_*`` functions, by name."""
    return [(name, func) for name, func in sorted(vars(mod).items())
            if name.startswith("test_") and inspect.isfunction(func)]
