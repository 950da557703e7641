"""ase_mlg.jit: the kernels load from numba's cache without numba's registry
refresh (0.15 s of a process's first call), and say so where they cannot."""

import os
import subprocess
import sys
import warnings

import numpy as np

from ase_mlg import jit

# numba's refresh imports numba.np.linalg (its implementations of
# np.linalg) among some thirty modules; nothing in ase-mlg's kernels needs it
PROBE = r"""
import sys
from ase.build import bulk
from ase_mlg import neighbor_list
from ase_mlg.potentials import LennardJones
from ase_mlg import MLGCalculator
atoms = bulk("Cu", "fcc", a=3.6, cubic=True) * (2, 2, 2)
i, j, d = neighbor_list("ijd", atoms, 4.0)
atoms.calc = MLGCalculator(LennardJones(sigma=2.3, epsilon=0.4, rc=4.0))
print(len(i), repr(atoms.get_potential_energy()), "numba.np.linalg" in sys.modules)
"""


def test_a_warm_cache_loads_without_the_refresh(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    runs = [subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True,
                           text=True, timeout=600, stdin=subprocess.DEVNULL)
            for _ in range(2)]
    for r in runs:
        assert r.returncode == 0, r.stderr[-3000:]
    (n0, e0, cold), (n1, e1, warm) = (r.stdout.split() for r in runs)
    assert (n0, e0) == (n1, e1)  # the loaded kernels give the compiled ones' bits
    assert cold == "True"  # compiling refreshes the registries (numba's compiler)
    assert warm == "False"  # loading did not


def test_a_numba_whose_cache_differs_is_said_once(monkeypatch):
    monkeypatch.setattr(jit, "FunctionCache", None)
    monkeypatch.setattr(jit, "_WARNED", [])

    def twice(x):
        return 2.0 * x

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        kernels = [jit.njit(cache=True)(f) for f in (twice, lambda x: x)]
    said = [w for w in caught if "numba's own" in str(w.message)]
    assert len(said) == 1 and issubclass(said[0].category, RuntimeWarning)
    assert kernels[0](np.float64(1.5)) == 3.0
    assert type(kernels[0]._cache).__name__ == "FunctionCache"  # numba's own, enabled
