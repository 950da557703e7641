"""The threading layer users get, and concurrent use (docs/design.md §8).

Each check runs in a fresh interpreter: numba's threading layer is chosen
once per process, at ``import ase_mlg``.  The fallback (TBB unavailable)
is forced by making numba's ``tbbpool`` module unimportable, exactly what a
platform without the ``tbb`` wheel sees."""

import os
import subprocess
import sys
import textwrap
from importlib.metadata import PackageNotFoundError, distribution

import pytest

# they assert that kernels ran on several threads: idle cores needed
pytestmark = pytest.mark.threads

try:
    distribution("tbb")
    HAVE_TBB = True
except PackageNotFoundError:
    HAVE_TBB = False

BLOCK_TBB = "import sys; sys.modules['numba.np.ufunc.tbbpool'] = None\n"

# two Python threads, each driving its own calculator through threaded
# kernels (6,912 atoms: above every threading threshold), against the same
# systems run one after the other
CONCURRENT = textwrap.dedent("""
    import threading, warnings
    import numpy as np
    from ase.build import bulk
    import ase_mlg
    from ase_mlg.potentials import LennardJones

    def system(seed):
        a = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(12)
        a.rattle(0.1, seed=seed)
        return a

    def run(atoms, out, k):
        atoms.calc = ase_mlg.MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
        f, used = [], 0
        for step in range(4):
            atoms.positions += 0.02
            f.append(atoms.get_forces().copy())
            used = max(used, atoms.calc.stats["threads_used"])
        out[k] = (np.array(f), used)

    def threads_seen(atoms, calls=50):
        # a loaded machine (CI runs two test suites at once) can leave TBB's
        # worker asleep through a short call: the most threads of many calls
        atoms.calc = ase_mlg.MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
        used = 0
        for step in range(calls):
            atoms.positions += 0.001
            atoms.get_forces()
            used = max(used, atoms.calc.stats["threads_used"])
            if used == 2:
                break
        return used

    serial = {}
    for k in range(2):
        run(system(k), serial, k)
    together = {}
    ts = [threading.Thread(target=run, args=(system(k), together, k)) for k in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    for k in range(2):
        assert np.array_equal(serial[k][0], together[k][0]), k
    c = ase_mlg.parallel.config()
    print("LAYER", c["threading_layer"], "SERIALISED", c["serialised"],
          "USED", max(max(v[1] for v in serial.values()), threads_seen(system(3))))
""")


def python(code, **env):
    full = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    full.update(NUMBA_NUM_THREADS="2", **env)
    return subprocess.run([sys.executable, "-c", code], capture_output=True,
                          text=True, timeout=300, env=full)


def test_tbb_loads_and_a_threaded_kernel_runs_on_two_threads():
    """From a plain pip install (CI's fresh venv): TBB, no warning, and the
    probe and the force kernel ran on two numba threads."""
    code = textwrap.dedent("""
        import warnings
        warnings.simplefilter("error")
        import numpy as np
        from ase.build import bulk
        import ase_mlg
        from ase_mlg.potentials import LennardJones
        c = ase_mlg.parallel.config()
        atoms = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(14)
        atoms.rattle(0.1, seed=1)
        atoms.calc = ase_mlg.MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
        used = 0
        for step in range(50):  # until seen: a loaded machine can leave a worker asleep
            atoms.positions += 0.01 if step < 10 else 1e-4
            atoms.get_forces()
            used = max(used, atoms.calc.stats["threads_used"])
            if step >= 9 and used == 2:
                break
        print("LAYER", c["threading_layer"], "PROBLEM", c["problem"],
              "PROBE", c["probe_threads"], "USED", used, "CHUNKS", atoms.calc.verlet_list.chunks().nchunk)
    """)
    res = python(code)
    assert res.returncode == 0, res.stderr[-3000:]
    words = res.stdout.split()
    got = dict(zip(words[::2], words[1::2]))
    if HAVE_TBB:
        assert got["LAYER"] == "tbb" and got["PROBLEM"] == "None", res.stdout
    else:  # no tbb wheel for this platform: the fallback, said once
        assert got["LAYER"] == "workqueue", res.stdout
    assert int(got["PROBE"]) == 2, res.stdout
    assert int(got["CHUNKS"]) > 2, res.stdout
    assert int(got["USED"]) == 2, res.stdout


def test_fallback_warns_once_and_concurrent_threads_do_not_crash():
    """Without TBB: one ThreadingLayerWarning naming what is missing,
    workqueue with serialised launches, and two Python threads driving
    calculators at once give the serial results (workqueue alone aborts
    the process: 'Concurrent access has been detected')."""
    code = BLOCK_TBB + textwrap.dedent("""
        import warnings
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            import ase_mlg
            import ase_mlg.potentials, ase_mlg.calculator
        mine = [x for x in w if issubclass(x.category, ase_mlg.parallel.ThreadingLayerWarning)]
        assert len(mine) == 1, [str(x.message) for x in w]
        assert "TBB" in str(mine[0].message) and "workqueue" in str(mine[0].message)
    """) + CONCURRENT
    res = python(code)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "LAYER workqueue SERIALISED True" in res.stdout, res.stdout


def test_concurrent_threads_under_the_default_layer():
    res = python(CONCURRENT)
    assert res.returncode == 0, res.stderr[-3000:]
    assert ("LAYER tbb SERIALISED False" if HAVE_TBB else "SERIALISED True") in res.stdout
    assert "USED 2" in res.stdout, res.stdout


def test_user_choice_of_workqueue_is_serialised():
    res = python(CONCURRENT, NUMBA_THREADING_LAYER="workqueue")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "LAYER workqueue SERIALISED True" in res.stdout, res.stdout


def test_thread_pools_from_several_threads():
    """run_chunks from threads asking for different pool sizes: every call
    gets all its results (one thread used to shut down another's pool)."""
    import threading
    from ase_mlg.parallel import run_chunks
    errors, results = [], {}

    def work(k):
        try:
            for rep in range(50):
                out = run_chunks(lambda a, b: a * b, lambda ch: (ch, k), 6, 2 + k % 3)
                assert out == [ch * k for ch in range(6)]
            results[k] = True
        except Exception as err:  # noqa: BLE001 - reported below
            errors.append(repr(err))

    ts = [threading.Thread(target=work, args=(k,)) for k in range(6)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors and len(results) == 6, errors


def test_show_config_and_cli_info():
    import io
    import ase_mlg
    buf = io.StringIO()
    ase_mlg.show_config(file=buf)
    text = buf.getvalue()
    assert "threading layer:" in text and "numba" in text and "probe kernel ran on" in text
    res = subprocess.run([sys.executable, "-m", "ase_mlg.cli", "info"], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "threading layer:" in res.stdout


@pytest.mark.parametrize("nchunk", [2, 5, 16])
def test_windows_cover_every_pair_and_are_narrow(nchunk):
    """Every chunk's window holds its rows and every neighbour of them at
    distinct entries of its own part of the buffer, each bin's cover lists
    exactly the chunks that touch it, and on a periodic liquid the windows
    together stay far below nchunk x N."""
    import numpy as np
    from ase.build import bulk
    from ase_mlg import MLGCalculator
    from ase_mlg.chunks import RowChunks
    from ase_mlg.potentials import LennardJones
    atoms = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(10)
    atoms.rattle(0.2, seed=3)
    atoms = atoms[np.random.default_rng(0).permutation(len(atoms))]
    atoms.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
    atoms.get_forces()
    pl = atoms.calc.verlet_list.pairs
    ch = RowChunks(pl.rowptr, pl.nbr, nchunk)
    a, n = ch.arrays, pl.natoms
    mask = (1 << a.shift) - 1
    touched = np.zeros(a.slot.shape, bool)
    for c in range(ch.nchunk):
        r0, r1 = a.rows[c], a.rows[c + 1]
        ranks = np.unique(np.concatenate([np.arange(r0, r1), pl.nbr[pl.rowptr[r0]:pl.rowptr[r1]]]))
        touched[c, ranks >> a.shift] = True
        entry = a.slot[c, ranks >> a.shift] + (ranks & mask)
        assert (a.slot[c, ranks >> a.shift] >= 0).all(), c
        assert (entry >= a.offset[c]).all() and (entry < a.offset[c + 1]).all(), c
        assert len(np.unique(entry)) == len(ranks), c
    np.testing.assert_array_equal(a.slot >= 0, touched)
    for b in range(a.slot.shape[1]):
        np.testing.assert_array_equal(a.cover[a.cover_ptr[b]:a.cover_ptr[b + 1]],
                                      np.flatnonzero(touched[:, b]))
    assert ch.entries < 0.6 * nchunk * n + n
