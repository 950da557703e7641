"""RDF on trajectories as users run it: updating selections (re-read every
frame, as InterRDF does), site-specific RDFs against InterRDF_s, frames
without a box, plain scripts with every backend, a real dask.distributed
cluster (scheduler and two worker processes on localhost) through the API
and the CLI's ``--scheduler``.

Data: MDAnalysisTests (TIP3P water in a triclinic NPT box, solvated
adenylate kinase, a membrane protein, a box-less DCD)."""

import json
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from MDAnalysis.analysis.rdf import InterRDF, InterRDF_s
from MDAnalysisTests import datafiles

from ase_mlg.analysis import RDF, RDF_s, DistributedBackend
from rdf_helpers import universe

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning",
                                        "ignore::UserWarning")


def same_counts(ref, got):
    np.testing.assert_array_equal(got.results.count, ref.results.count)
    np.testing.assert_array_equal(got.results.rdf, ref.results.rdf)


# --------------------------------------------------------------------------
# updating selections
# --------------------------------------------------------------------------

def test_updating_selection_issue_repro():
    """The issue's numbers: InterRDF 12337 pairs over 5 frames."""
    u = universe(datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC)
    g1 = u.select_atoms("name OH2 and prop z < 0.103", updating=True)
    g2 = u.select_atoms("name OH2")
    ref = InterRDF(g1, g2, nbins=40, range=(0, 8)).run(stop=5)
    got = RDF(g1, g2, nbins=40, range=(0, 8)).run(stop=5)
    sizes = [len(g1) for ts in u.trajectory[:5]]
    assert len(set(sizes)) > 1  # the selection changes size between frames
    assert ref.results.count.sum() == 12337
    same_counts(ref, got)


@pytest.mark.parametrize("sel1, sel2, kw", [
    # both groups updating, different sizes every frame
    ("name OH2 and prop z < 2.0", "name H1 and prop x > 10", dict(range=(0, 9), nbins=30)),
    # updating g1 against itself, with residue exclusion
    ("prop z < 3.0", "prop z < 3.0", dict(range=(0, 8), exclude_same="residue")),
    ("prop z < 3.0", "prop z < 3.0", dict(range=(0, 8), exclusion_block=(3, 3))),
])
def test_updating_selections_triclinic_water(sel1, sel2, kw):
    u = universe(datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC)
    g1 = u.select_atoms(sel1, updating=True)
    g2 = u.select_atoms(sel2, updating=True)
    assert len({len(g1) for ts in u.trajectory}) > 1
    ref = InterRDF(g1, g2, **kw).run()
    got = RDF(g1, g2, **kw).run()
    assert ref.results.count.sum() > 0
    same_counts(ref, got)


def test_updating_selection_solvated_protein():
    """Adenylate kinase: the waters within 3.5 Å of the protein (a different
    set, and number, every frame) against all water oxygens."""
    u = universe(datafiles.TPR, datafiles.XTC)
    shell = u.select_atoms("name OW and around 3.5 protein", updating=True)
    ow = u.select_atoms("name OW")
    sizes = [len(shell) for ts in u.trajectory[:3]]
    assert len(set(sizes)) == 3
    ref = InterRDF(shell, ow, nbins=50, range=(0, 10)).run(stop=3)
    got = RDF(shell, ow, nbins=50, range=(0, 10)).run(stop=3)
    same_counts(ref, got)


def test_updating_selection_empty_at_frame_0():
    u = universe(datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC)
    zmin = u.select_atoms("name OH2").positions[:, 2].min()
    g1 = u.select_atoms(f"name OH2 and prop z < {zmin}", updating=True)
    g2 = u.select_atoms("name OH2")
    sizes = [len(g1) for ts in u.trajectory]
    assert sizes[0] == 0 and max(sizes) > 0
    u.trajectory[0]
    ref = InterRDF(g1, g2, nbins=20, range=(0, 8)).run()
    got = RDF(g1, g2, nbins=20, range=(0, 8)).run()
    assert ref.results.count.sum() > 0
    np.testing.assert_array_equal(got.results.count, ref.results.count)
    # InterRDF normalises with len(g1) after the run (frame 0: empty): inf/nan
    np.testing.assert_array_equal(np.isnan(got.results.rdf), np.isnan(ref.results.rdf))
    # in parallel too
    par = RDF(g1, g2, nbins=20, range=(0, 8)).run(backend="multiprocessing", n_workers=2)
    np.testing.assert_array_equal(par.results.count, ref.results.count)


def test_static_empty_group_still_refused():
    u = universe(datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC)
    with pytest.raises(ValueError, match="g1: the atom group is empty"):
        RDF(u.select_atoms("name XX"), u.atoms)


# --------------------------------------------------------------------------
# InterRDF_s
# --------------------------------------------------------------------------

@pytest.mark.parametrize("rng", [(0.0, 15.0), (1.0, 13.0)])
def test_rdf_s_counts_match_interrdf_s(rng):
    u = universe(datafiles.GRO_MEMPROT, datafiles.XTC_MEMPROT)
    zn = u.select_atoms("name ZND")
    od = u.select_atoms("(name OD1 or name OD2) and sphzone 8.0 (name ZND)")
    ags = [[zn, od], [od, zn], [zn + zn[:1], od[:5]]]
    ref = InterRDF_s(u, ags, nbins=60, range=rng).run()
    got = RDF_s(u, ags, nbins=60, range=rng).run()
    assert sum(c.sum() for c in ref.results.count) > 0
    for a, b in zip(ref.results.count, got.results.count):
        np.testing.assert_array_equal(b, a)
    for a, b in zip(ref.results.rdf, got.results.rdf):
        np.testing.assert_array_equal(b, a)


def test_rdf_s_water_box_and_bad_input():
    u = universe(datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC)
    ags = [[u.select_atoms("resid 1:20 and name OH2"), u.select_atoms("name H1")]]
    ref = InterRDF_s(u, ags, nbins=25, range=(0, 7)).run()
    got = RDF_s(u, ags, nbins=25, range=(0, 7)).run()
    np.testing.assert_array_equal(got.results.count[0], ref.results.count[0])
    with pytest.raises(ValueError, match="ags"):
        RDF_s(u, [[u.atoms]])
    with pytest.raises(ValueError, match=r"ags\[0\]\[1\]"):
        RDF_s(u, [[u.atoms, u.select_atoms("name XX")]])
    with pytest.raises(ValueError, match="nbins"):
        RDF_s(u, ags, nbins=0)


# --------------------------------------------------------------------------
# no box
# --------------------------------------------------------------------------

def test_no_box_norm_rdf_fails_before_frame_0():
    u = universe(datafiles.PSF, datafiles.DCD)
    assert u.dimensions is None
    ca = u.select_atoms("name CA")
    r = RDF(ca, ca, range=(0, 10))
    with pytest.raises(ValueError, match="norm") as info:
        r.check_range()
    assert "\n" not in str(info.value) and "density" in str(info.value)
    with pytest.raises(ValueError, match="frame 0 has no box"):
        r.run()
    # density and none work, with InterRDF's counts
    ref = InterRDF(ca, ca, range=(0, 10), norm="density").run(stop=3)
    got = RDF(ca, ca, range=(0, 10), norm="density").run(stop=3)
    same_counts(ref, got)


# --------------------------------------------------------------------------
# plain scripts, python -c: every backend, no main guard
# --------------------------------------------------------------------------

SCRIPT = """
import json, sys, warnings
warnings.simplefilter("ignore")
import MDAnalysis as mda
from MDAnalysisTests.datafiles import PSF_TRICLINIC, DCD_TRICLINIC
from ase_mlg.analysis import RDF, DistributedBackend
u = mda.Universe(PSF_TRICLINIC, DCD_TRICLINIC)
g = u.select_atoms("name OH2")
out = {}
out["serial"] = RDF(g, g, nbins=20, range=(0, 8)).run().results.count.tolist()
for b in ("multiprocessing", "dask"):
    out[b] = RDF(g, g, nbins=20, range=(0, 8)).run(backend=b, n_workers=2).results.count.tolist()
if len(sys.argv) > 1:
    from distributed import Client
    with Client(sys.argv[1]) as client:
        r = RDF(g, g, nbins=20, range=(0, 8)).run(backend=DistributedBackend(client))
        out["distributed"] = r.results.count.tolist()
print("COUNTS", json.dumps(out))
"""


def _counts(stdout):
    line = [x for x in stdout.splitlines() if x.startswith("COUNTS ")]
    assert line, stdout
    return json.loads(line[-1][7:])


def _check_backends(res, expected):
    assert res.returncode == 0, res.stderr[-2000:]
    out = _counts(res.stdout)
    assert set(out) == expected
    assert sum(out["serial"]) > 0
    for b in expected:
        assert out[b] == out["serial"], b


def test_plain_script_every_backend(tmp_path, cluster):
    path = tmp_path / "plain.py"
    path.write_text(SCRIPT)
    res = subprocess.run([sys.executable, str(path), cluster["address"]],
                         capture_output=True, text=True, timeout=300, cwd=tmp_path)
    _check_backends(res, {"serial", "multiprocessing", "dask", "distributed"})


def test_python_c_every_backend(tmp_path):
    res = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True,
                         text=True, timeout=300, cwd=tmp_path)
    _check_backends(res, {"serial", "multiprocessing", "dask"})


def test_fork_safe_threading_layer_and_prange_scaling():
    """import ase_mlg starts numba's TBB layer wherever the tbb package is
    installed (a plain pip venv included: libtbb is off the loader's path
    there), else workqueue: a parallel kernel in the parent, then in
    forked children."""
    code = textwrap.dedent("""
        import ase_mlg, numba, multiprocessing
        import numpy as np
        from ase_mlg.analysis.mda_kernels import mda_counts  # noqa: F401 (parallel kernel module)
        from numba import njit, prange
        @njit(parallel=True)
        def total(a):
            s = 0.0
            for i in prange(a.size):
                s += a[i]
            return s
        a = np.ones(1000)
        assert total(a) == 1000.0
        print("LAYER", numba.threading_layer())
        with multiprocessing.get_context("fork").Pool(2) as p:
            print("CHILD", p.map(total, [a, a]))
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, env={k: v for k, v in os.environ.items()
                                           if k != "NUMBA_THREADING_LAYER"})
    assert res.returncode == 0, res.stderr[-2000:]
    from importlib.metadata import PackageNotFoundError, distribution
    try:
        distribution("tbb")
        assert "LAYER tbb" in res.stdout, res.stdout
    except PackageNotFoundError:
        assert "LAYER workqueue" in res.stdout, res.stdout
    assert "CHILD [1000.0, 1000.0]" in res.stdout


def test_gnu_openmp_in_parent_is_a_clear_error():
    code = textwrap.dedent("""
        import warnings; warnings.simplefilter("ignore")
        import MDAnalysis as mda
        from MDAnalysisTests.datafiles import PSF_TRICLINIC, DCD_TRICLINIC
        from ase_mlg.analysis import RDF
        u = mda.Universe(PSF_TRICLINIC, DCD_TRICLINIC)
        r = RDF(u.atoms, u.atoms, range=(0, 6)).run(stop=1)
        try:
            r.run(backend="multiprocessing", n_workers=2)
        except ValueError as exc:
            print("ERROR", exc)
    """)
    env = dict(os.environ, NUMBA_THREADING_LAYER="omp")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, env=env)
    assert res.returncode == 0, res.stderr[-2000:]
    line = [x for x in res.stdout.splitlines() if x.startswith("ERROR")]
    assert line and "NUMBA_THREADING_LAYER=tbb" in line[0] and line[0].startswith(
        "ERROR backend:")


# --------------------------------------------------------------------------
# a real dask.distributed cluster: scheduler + 2 workers on localhost
# --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    pytest.importorskip("distributed")
    root = tmp_path_factory.mktemp("cluster")
    sfile = root / "scheduler.json"
    env = dict(os.environ, DASK_DISTRIBUTED__WORKER__DAEMON="False")
    procs = [subprocess.Popen(
        [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
         "--no-dashboard", "--scheduler-file", str(sfile)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=root, env=env)]
    try:
        deadline = time.time() + 60
        while not sfile.exists() or not sfile.read_text().strip():
            assert time.time() < deadline, "dask scheduler did not start"
            assert procs[0].poll() is None, "dask scheduler exited"
            time.sleep(0.2)
        address = json.loads(sfile.read_text())["address"]
        for k in range(2):
            procs.append(subprocess.Popen(
                # two threads a worker, dask's default on a 2-core machine (the
                # README's recipe): two tasks launch kernels at once in one process
                [sys.executable, "-m", "dask", "worker", address, "--nthreads", "2",
                 "--no-dashboard", "--name", f"w{k}"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=root, env=env))
        from distributed import Client
        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=90)
        yield {"address": address, "procs": procs}
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    assert all(p.poll() is not None for p in procs)


def test_distributed_backend_matches_serial_interrdf(cluster):
    from distributed import Client
    u = universe(datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC)
    g1 = u.select_atoms("name OH2")
    g2 = u.select_atoms("name H1 H2")
    ref = InterRDF(g1, g2, nbins=40, range=(0, 9)).run()
    with Client(cluster["address"]) as client:
        backend = DistributedBackend(client)
        assert backend.n_workers == 2
        got = RDF(g1, g2, nbins=40, range=(0, 9)).run(backend=backend)
        # frames really went to both workers: each part runs on some worker
        fine = RDF(g1, g2, nbins=40, range=(0, 9)).run(backend=backend, n_parts=5)
        s = RDF_s(u, [[g1[:5], g2[:7]]], nbins=40, range=(0, 9)).run(backend=backend)
        with pytest.raises(ValueError, match="n_workers"):
            RDF(g1, g2).run(backend=backend, n_workers=3)
    assert got.n_frames == u.trajectory.n_frames
    same_counts(ref, got)
    np.testing.assert_array_equal(fine.results.count, ref.results.count)
    ref_s = InterRDF_s(u, [[g1[:5], g2[:7]]], nbins=40, range=(0, 9)).run()
    np.testing.assert_array_equal(s.results.count[0], ref_s.results.count[0])
    with pytest.raises(TypeError, match="client"):
        DistributedBackend("tcp://127.0.0.1:1")


def test_cli_scheduler(cluster, tmp_path):
    out = tmp_path / "g.txt"
    res = subprocess.run(
        [sys.executable, "-m", "ase_mlg.cli", "rdf", datafiles.PSF_TRICLINIC,
         datafiles.DCD_TRICLINIC, "--select", "name OH2", "--rmax", "8", "--nbins", "16",
         "--scheduler", cluster["address"], "--workers", "4", "--output", str(out)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "\r" not in res.stderr and "%|" not in res.stderr  # no progress bar
    u = universe(datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC)
    ow = u.select_atoms("name OH2")
    ref = InterRDF(ow, ow, nbins=16, range=(0, 8)).run()
    np.testing.assert_array_equal(np.loadtxt(out)[:, 2], ref.results.count)
    # an address nobody answers: one line naming the option
    from ase_mlg.cli.rdf import _connect
    with pytest.raises(ValueError, match=r"^--scheduler: cannot connect to") as info:
        _connect("tcp://127.0.0.1:9", timeout=1)
    assert "\n" not in str(info.value)
