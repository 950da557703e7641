"""Results do not depend on the thread count (docs/design.md §8).

The pair sum's chunks are a function of the list alone
(:func:`ase_mlg.chunks.row_chunks`), one thread runs the same chunks in
chunk order that several threads share, and the list itself comes out the
same for any thread count: so energy, forces, stress, per-atom energies and
stresses, and MD trajectories are the same bits at 1, 2 and 4 numba
threads.  Each thread count of numba's pool is fixed at start-up
(``NUMBA_NUM_THREADS``), so those runs are fresh interpreters; within one
process ``numba.set_num_threads`` is checked too."""

import hashlib
import json
import os
import subprocess
import sys
import textwrap

import numba
import numpy as np
import pytest

# they assert that kernels ran on several threads: idle cores needed
pytestmark = pytest.mark.threads

# 6,912 argon atoms at liquid density (rc + skin = 9.5 Å: 3 x 10^5 list
# pairs): above parallel.THRESHOLDS for "atoms" and "pairs", so the list
# build, the gather and the pair sum all run their threaded paths
SYSTEM = textwrap.dedent("""
    import numpy as np
    from ase.build import bulk
    from ase_mlg import MLGCalculator
    from ase_mlg.potentials import LennardJones

    def argon():
        atoms = bulk("Ar", "fcc", a=5.26, cubic=True).repeat(12)
        atoms.rattle(0.15, seed=1)
        atoms = atoms[np.random.default_rng(2).permutation(len(atoms))]
        atoms.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
        return atoms
""")

CHILD = SYSTEM + textwrap.dedent("""
    import hashlib, json
    import numba
    from ase import units
    from ase.md.velocitydistribution import MaxwellBoltzmannDistribution
    from ase_mlg import parallel
    from ase_mlg.md import VelocityVerlet

    def h(x):
        return hashlib.sha1(np.ascontiguousarray(x).tobytes()).hexdigest()

    atoms = argon()
    calc = atoms.calc
    out = {"energy": atoms.get_potential_energy().hex(),
           "forces": h(atoms.get_forces()), "stress": h(atoms.get_stress()),
           "energies": h(atoms.get_potential_energies()),
           "stresses": h(atoms.get_stresses())}
    pl = calc.verlet_list.pairs
    out["list"] = h(np.concatenate([pl.order, pl.rowptr, pl.nbr, pl.code]))
    used = calc.stats["threads_used"]
    MaxwellBoltzmannDistribution(atoms, temperature_K=300, rng=np.random.default_rng(3))
    md = VelocityVerlet(atoms, 5 * units.fs)
    for step in range(30):
        md.run(1)
        used = max(used, calc.stats["threads_used"])
    out["positions"] = h(atoms.positions)
    out["momenta"] = h(atoms.get_momenta())
    out["md_energy"] = atoms.get_potential_energy().hex()
    # a loaded machine (CI runs two test suites at once) can leave TBB's
    # workers asleep through a short call: more calls, after the bits, until
    # a threaded kernel is seen on several threads
    for step in range(100):
        if used > 1 or numba.get_num_threads() == 1:
            break
        atoms.positions[0, 0] += 1e-4
        atoms.get_forces()
        used = max(used, calc.stats["threads_used"])
    print(json.dumps({"bits": out, "threads": numba.get_num_threads(), "used": used,
                      "natoms": len(atoms), "npairs": len(pl), "md_path": md.path,
                      "builds": calc.verlet_list.stats["list_builds"],
                      "nchunk": calc.verlet_list.chunks().nchunk,
                      "thresholds": parallel.THRESHOLDS}))
""")


def _child(nthreads):
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_NUM_THREADS")}
    env["NUMBA_NUM_THREADS"] = str(nthreads)
    res = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         timeout=300, env=env)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_same_bits_at_1_2_and_4_numba_threads():
    """Energy, forces, stress, per-atom energies and stresses, the list, and
    30 MD steps (list rebuilds and grid updates included) are the same bits
    in processes started with 1, 2 and 4 numba threads."""
    runs = {k: _child(k) for k in (1, 2, 4)}
    one = runs[1]
    for k, run in runs.items():
        assert run["threads"] == k
        differ = [key for key, value in one["bits"].items() if run["bits"][key] != value]
        assert not differ, (k, differ)
    for k, run in runs.items():
        assert run["nchunk"] == one["nchunk"], k
        if k > 1:  # the threaded kernel really ran on several threads
            assert run["used"] > 1, (k, run["used"])
    assert one["natoms"] >= one["thresholds"]["atoms"]
    assert one["npairs"] >= one["thresholds"]["pairs"]
    assert one["nchunk"] > 1  # the windowed, chunked path, on one thread too
    assert one["md_path"] == "compiled" and one["builds"] >= 2


def _hash(res):
    return {k: (v.hex() if isinstance(v, float) else
                hashlib.sha1(np.ascontiguousarray(v).tobytes()).hexdigest())
            for k, v in res.items()}


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="one numba thread")
def test_same_bits_after_set_num_threads():
    """In one process: a calculator (list build included) and the default
    chunks of ``sum_pairs`` at ``numba.set_num_threads(1)`` and ``(2)``."""
    namespace = {}
    exec(SYSTEM, namespace)
    from ase_mlg.chunks import row_chunks
    old = numba.get_num_threads()
    runs = {}
    try:
        for k in (1, 2, 1):
            numba.set_num_threads(k)
            atoms = namespace["argon"]()
            calc = atoms.calc
            got = {"energy": atoms.get_potential_energy(), "forces": atoms.get_forces(),
                   "stress": atoms.get_stress(), "energies": atoms.get_potential_energies(),
                   "stresses": atoms.get_stresses()}
            vl = calc.verlet_list
            pl = vl.pairs
            res = calc.potential.sum_pairs(vl.X, vl.types, pl.rowptr, pl.nbr, pl.code,
                                           vl.svec, pl.order, energies=True, virials=True)
            got.update({"sum_" + key: v for key, v in res.items()})
            runs.setdefault(k, []).append((_hash(got), vl, row_chunks(pl.rowptr, pl.nbr)))
    finally:
        numba.set_num_threads(old)
    first = runs[1][0][0]
    for bits, _, _ in runs[1] + runs[2]:
        differ = [key for key in first if bits[key] != first[key]]
        assert not differ, differ
    for _, vl, chunks in runs[1] + runs[2]:
        assert chunks.nchunk == vl.chunks().nchunk > 1
        assert vl.chunks(1) is vl.chunks(2) is vl.chunks()
