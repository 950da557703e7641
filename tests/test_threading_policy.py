"""Every threaded numba kernel goes through the package's one threading
policy (ase_mlg/parallel.py, docs/design.md §8): ``serial_and_parallel``
compiles the threaded twin and, where the layer is not thread-safe
(workqueue), launches it under the process-wide lock.  A kernel compiled
with ``parallel=True`` anywhere else bypasses the lock, and two Python
threads launching it abort the process under workqueue ("Concurrent access
has been detected", issue 25.6).  Read from the source, so a new kernel is
caught whatever calls it."""

import ast
import importlib.util
import os
import subprocess
import sys
import textwrap
from pathlib import Path

# the package that is imported (its source, found without importing it)
PACKAGE = Path(importlib.util.find_spec("ase_mlg").origin).parent
ROOT = PACKAGE.parent

# the policy's own uses of parallel=True: the twin maker, and the probe of
# config(), which is launched under dynamic_schedule (and so under the lock)
ALLOWED = {("ase_mlg/parallel.py", "serial_and_parallel"),
           ("ase_mlg/parallel.py", "@_thread_probe")}


def _asks_for_threads(node):
    """Whether ``node`` asks numba for a threaded compilation: a keyword
    ``parallel=`` that is not the constant False (also inside ``dict(...)``),
    a ``{"parallel": ...}`` literal, or ``target="parallel"``."""
    if isinstance(node, ast.Call):
        for kw in node.keywords:
            if kw.arg == "parallel" and not (isinstance(kw.value, ast.Constant)
                                             and kw.value.value is False):
                return True
            if (kw.arg == "target" and isinstance(kw.value, ast.Constant)
                    and kw.value.value == "parallel"):
                return True
    if isinstance(node, ast.Dict):
        return any(isinstance(k, ast.Constant) and k.value == "parallel" for k in node.keys)
    return False


def threaded_sites(source, where):
    """``(where, owner, line)`` of each request for a threaded kernel;
    ``owner`` is the top-level function whose body holds it, ``@name`` for
    its decorators, or ``<module>``."""
    out = []
    for stmt in ast.parse(source, where).body:
        if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            parts = [(f"@{stmt.name}", d) for d in stmt.decorator_list]
            parts += [(stmt.name, b) for b in stmt.body]
        else:
            parts = [("<module>", stmt)]
        for owner, part in parts:
            out += [(where, owner, n.lineno) for n in ast.walk(part) if _asks_for_threads(n)]
    return out


def _package_sites():
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        out += threaded_sites(path.read_text(), path.relative_to(ROOT).as_posix())
    return out


def test_every_threaded_kernel_goes_through_the_policy():
    outside = [f"{w}:{line} ({owner})" for w, owner, line in _package_sites()
               if (w, owner) not in ALLOWED]
    assert outside == [], ("parallel=True outside ase_mlg.parallel.serial_and_parallel: "
                           + ", ".join(outside))


def test_the_allowed_sites_exist():
    """The allow list names what is there (a renamed probe or twin maker
    must not leave a stale exemption)."""
    assert {(w, owner) for w, owner, _ in _package_sites()} >= ALLOWED


def test_the_probe_is_launched_under_dynamic_schedule():
    tree = ast.parse((PACKAGE / "parallel.py").read_text())
    calls, guarded = [], []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id == "_thread_probe"):
            calls.append(node)
        if isinstance(node, ast.With) and any(
                isinstance(i.context_expr, ast.Call)
                and getattr(i.context_expr.func, "id", None) == "dynamic_schedule"
                for i in node.items):
            guarded += [n for n in ast.walk(node) if isinstance(n, ast.Call)]
    assert calls and all(c in guarded for c in calls)


def test_the_scan_finds_what_it_names():
    src = ("import numba\nfrom numba import njit\n"
           "@njit(cache=True, parallel=True)\ndef a(x):\n    return x\n"
           "def b(f):\n    return numba.njit(**dict(parallel=True))(f)\n"
           "FLAGS = {'parallel': True}\n"
           "v = numba.vectorize(['f8(f8)'], target='parallel')\n"
           "@njit(cache=True, parallel=False)\ndef c(x):\n    return x\n"
           "@njit(cache=True)\ndef d(x):\n    return x\n")
    assert [(o, line) for _, o, line in threaded_sites(src, "x.py")] == [
        ("@a", 3), ("b", 7), ("<module>", 8), ("<module>", 9)]


# two Python threads, each running the ASE and the MDAnalysis RDF on 4,000
# atoms (about 90,000 pairs within 8 Å: above THRESHOLDS["pairs"], so the
# threaded count kernels run), against the same runs one after the other
CONCURRENT_RDF = textwrap.dedent("""
    import threading
    import numpy as np
    import MDAnalysis as mda
    from ase.build import bulk
    import ase_mlg
    from ase_mlg.analysis import RDF, rdf, ase_rdf, mda_kernels

    a = bulk("Ar", "fcc", a=5.72, cubic=True).repeat(10)
    a.rattle(0.1, seed=1)

    def run():
        u = mda.Universe.empty(len(a), trajectory=True)
        u.atoms.positions = a.positions
        u.dimensions = list(a.cell.lengths()) + [90.0, 90.0, 90.0]
        out = []
        for rep in range(5):
            out.append(rdf(a, 8.0, 50)[0])
            out.append(RDF(u.atoms, u.atoms, nbins=50, range=(0.0, 8.0)).run().results.count)
        return out

    alone = run()
    together = {}
    ts = [threading.Thread(target=lambda k=k: together.__setitem__(k, run())) for k in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    for k in range(2):
        assert all(np.array_equal(x, y) for x, y in zip(alone, together[k])), k
    # the threaded twins ran (under workqueue they are wrapped in the lock)
    for twin in (ase_rdf._ase_counts_threaded, mda_kernels._mda_counts_threaded):
        assert getattr(twin, "dispatcher", twin).signatures, twin
    c = ase_mlg.parallel.config(probe=False)
    print("LAYER", c["threading_layer"], "SERIALISED", c["serialised"])
""")


def test_rdf_kernels_from_two_threads_under_workqueue():
    """Issue 25.6: the RDF count kernels launched from two Python threads
    under workqueue (threaded dask workers running RDF do the same) give the
    serial counts; they aborted the process (SIGABRT, rc 134) when they
    bypassed serial_and_parallel."""
    env = dict(os.environ, NUMBA_THREADING_LAYER="workqueue", NUMBA_NUM_THREADS="2")
    res = subprocess.run([sys.executable, "-c", CONCURRENT_RDF], capture_output=True,
                         text=True, timeout=300, env=env)
    assert res.returncode == 0, (res.returncode, res.stderr[-2000:])
    assert "LAYER workqueue SERIALISED True" in res.stdout, res.stdout


def test_one_numba_thread_takes_the_serial_kernels():
    """At one numba thread no threaded twin runs, however large the work
    (its launch would cost time for no parallelism); at two it does."""
    import numba

    from ase_mlg.parallel import THRESHOLDS, threads_for, use_threads
    old = numba.get_num_threads()
    big = 10 * max(THRESHOLDS.values())
    try:
        numba.set_num_threads(1)
        assert not any(use_threads(kind, big) for kind in THRESHOLDS)
        assert threads_for("pairs", big) == 1
        if numba.config.NUMBA_NUM_THREADS > 1:
            numba.set_num_threads(2)
            assert all(use_threads(kind, big) for kind in THRESHOLDS)
            assert not use_threads("pairs", THRESHOLDS["pairs"] - 1)
    finally:
        numba.set_num_threads(old)
