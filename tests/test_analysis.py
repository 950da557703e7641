"""RDFs through the MLG: InterRDF's counts bin by bin, get_rdf's numbers,
parallel backends, bad input, the ``rdf`` subcommand.

Data: MDAnalysisTests (``pip install MDAnalysisTests``): a TIP3P water box
in a strongly triclinic NPT cell (``PSF_TRICLINIC``/``DCD_TRICLINIC``, 125
waters), a 5-water box (``waterPSF``/``waterDCD``), solvated adenylate kinase
in a rhombic dodecahedron (``TPR``/``XTC``, 47,681 atoms) and solvated
cobrotoxin in a cubic box (``TPR_xvf``/``TRR_xvf``); plus ASE scenes of
``ase_mlg.scenes`` with random displacements, written by ASE to PDB (CRYST1
box) and read back by MDAnalysis.
"""

import argparse
import io
import os

import numpy as np
import pytest

mda = pytest.importorskip("MDAnalysis")
datafiles = pytest.importorskip("MDAnalysisTests.datafiles")

import ase.io  # noqa: E402
from ase.geometry.rdf import CellTooSmall as ASECellTooSmall  # noqa: E402
from ase.geometry.rdf import VolumeNotDefined as ASEVolumeNotDefined  # noqa: E402
from ase.geometry.rdf import get_rdf  # noqa: E402
from MDAnalysis.analysis.rdf import InterRDF  # noqa: E402

from ase_mlg.analysis import RDF, CellTooSmall, VolumeNotDefined, rdf  # noqa: E402
from ase_mlg.analysis.mda_kernels import fastns_max_cutoff  # noqa: E402
from ase_mlg.cli.rdf import add_parser as add_rdf_parser  # noqa: E402
from ase_mlg.cli.rdf import run as run_rdf_command  # noqa: E402
from ase_mlg.scenes import make_scene  # noqa: E402
from rdf_helpers import universe  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning",
                                        "ignore::UserWarning")


def displaced(atoms, nframes=3, amp=0.1):
    """Frames of a scene with Gaussian displacements (amp Å), seed per frame."""
    out = []
    for s in range(nframes):
        a = atoms.copy()
        a.positions += np.random.default_rng(s).normal(0.0, amp, a.positions.shape)
        out.append(a)
    return out


def both(g1, g2, stop=None, **kw):
    ref = InterRDF(g1, g2, **kw).run(stop=stop)
    got = RDF(g1, g2, **kw).run(stop=stop)
    return ref, got


def assert_same(ref, got):
    assert ref.results.count.sum() > 0
    np.testing.assert_array_equal(got.results.count, ref.results.count)
    np.testing.assert_array_equal(got.results.edges, ref.results.edges)
    np.testing.assert_array_equal(got.results.bins, ref.results.bins)
    np.testing.assert_array_equal(got.results.rdf, ref.results.rdf)
    if ref.norm == "rdf":
        assert got.results.volume_cum == ref.results.volume_cum


# --------------------------------------------------------------------------
# fixtures
# --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def water_tric():
    return universe(datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC)


@pytest.fixture(scope="module")
def scene_pdbs(tmp_path_factory):
    """ASE-written multi-frame PDBs of the scenes (CRYST1 box each frame)."""
    root = tmp_path_factory.mktemp("scenes")
    spec = {
        "liquid": displaced(make_scene("liquid", 500)),
        "copper_perfect": [make_scene("copper", 256)] * 2,
        "gas": displaced(make_scene("gas", 216), amp=0.5),
        "sheared": displaced(make_scene("sheared", 256)),
        "slab": displaced(make_scene("slab", 400)),
    }
    paths = {}
    for name, frames in spec.items():
        paths[name] = str(root / f"{name}.pdb")
        ase.io.write(paths[name], frames)
    return paths


# --------------------------------------------------------------------------
# InterRDF, bin by bin
# --------------------------------------------------------------------------

@pytest.mark.parametrize("s1, s2, kw", [
    ("name OH2", "name OH2", dict(range=(0.0, 12.0))),
    # beyond half the box: one (minimum) image per pair, as InterRDF
    ("name OH2", "name H1 H2", dict(range=(0.0, 30.0), nbins=100)),
    ("all", "all", dict(range=(0.0, 8.0), exclude_same="residue")),
    ("all", "all", dict(range=(0.0, 8.0), exclusion_block=(3, 3))),
    ("all", "name OH2", dict(range=(1.0, 9.0), nbins=40, norm="density")),
])
def test_counts_match_interrdf_triclinic_water_box(water_tric, s1, s2, kw):
    ref, got = both(water_tric.select_atoms(s1), water_tric.select_atoms(s2), **kw)
    assert_same(ref, got)


def test_counts_match_interrdf_small_water_box_min_image():
    """5 waters in a 50 Å cube, range 40 Å > half the box: InterRDF counts
    each ordered pair once (brute force, round-based minimum image)."""
    u = universe(datafiles.waterPSF, datafiles.waterDCD)
    ref, got = both(u.atoms, u.atoms, range=(0.0, 40.0))
    assert ref.results.count.sum() == len(u.atoms) ** 2 * u.trajectory.n_frames
    assert_same(ref, got)


def test_counts_match_interrdf_solvated_protein():
    """Adenylate kinase in water, rhombic dodecahedron: 11,084 x 11,084
    water oxygens forces InterRDF's grid search (triclinic)."""
    u = universe(datafiles.TPR, datafiles.XTC)
    ow = u.select_atoms("name OW")
    ref, got = both(ow, ow, stop=2, range=(0.0, 10.0), nbins=100)
    assert_same(ref, got)
    ref, got = both(u.select_atoms("protein and name CA"), ow, stop=2,
                    range=(0.0, 12.0))
    assert_same(ref, got)


def test_counts_match_interrdf_cubic_solvated_protein():
    """Cobrotoxin in a cubic water box: orthorhombic grid search."""
    u = universe(datafiles.TPR_xvf, datafiles.TRR_xvf)
    ow = u.select_atoms("name OW")
    ref, got = both(ow, ow, range=(0.0, 10.0))
    assert_same(ref, got)


@pytest.mark.parametrize("name, rng, nbins", [
    ("liquid", (0.0, 14.0), 120),
    ("liquid", (0.0, 25.0), 120),          # beyond half the 29 Å box
    # a perfect lattice: many distances land exactly on bin edges and on rmax
    ("copper_perfect", (0.0, 7.22), 20),
    ("gas", (0.0, 30.0), 60),
    ("sheared", (0.0, 12.0), 120),          # triclinic, gamma = 26.6 deg
    # MDAnalysis has no per-axis pbc: the CRYST1 box makes z periodic too.
    # RDF follows InterRDF there; with rmax below the 20 Å vacuum the
    # images across it are out of range anyway.
    ("slab", (0.0, 9.0), 90),
])
def test_counts_match_interrdf_scenes(scene_pdbs, name, rng, nbins):
    u = universe(scene_pdbs[name])
    assert u.dimensions is not None
    ref, got = both(u.atoms, u.atoms, range=rng, nbins=nbins)
    assert_same(ref, got)
    if rng[1] > 0.5 * u.dimensions[:3].min():
        # one image per ordered pair (self pairs included), never more
        assert ref.results.count.sum() <= len(u.atoms) ** 2 * u.trajectory.n_frames


@pytest.mark.parametrize("rmax", [6.0, 8.0])
def test_counts_match_interrdf_on_bin_edges_across_the_box(rmax):
    """A simple cubic lattice (2 Å, float32-exact) in a 20 Å box: distances
    are exactly on bin edges and on rmax, also for pairs across the box.
    There MDAnalysis's minimum images differ in the last bits -- lazy (one
    box shift, exact; grid search, rmax = 6 <= 0.3 L) versus round-based
    with a float32 inverse box (brute force, rmax = 8) -- and so do bins."""
    grid = np.arange(10, dtype=np.float32) * 2 + 0.5
    pos = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), -1).reshape(-1, 3)
    u = mda.Universe.empty(len(pos), trajectory=True)
    u.load_new(pos[None], dimensions=[20, 20, 20, 90, 90, 90])
    ref, got = both(u.atoms, u.atoms, range=(0.0, rmax), nbins=int(rmax))
    assert_same(ref, got)


def test_counts_match_interrdf_without_box(tmp_path):
    """XYZ carries no box: no images, InterRDF's pseudo-box grid search."""
    path = str(tmp_path / "np.xyz")
    ase.io.write(path, displaced(make_scene("nanoparticle", 300), 2))
    u = universe(path)
    assert u.dimensions is None
    ref, got = both(u.atoms, u.atoms, range=(0.0, 10.0), norm="density")
    assert_same(ref, got)


def test_rmax_beyond_cell_raises_like_interrdf():
    u = universe(datafiles.TPR, datafiles.XTC)
    ow = u.select_atoms("name OW")
    with pytest.raises(ValueError, match="too large"):
        InterRDF(ow, ow, range=(0.0, 40.0)).run(stop=1)
    r = RDF(ow, ow, range=(0.0, 40.0))
    with pytest.raises(ValueError, match="rmax = 40 Å is beyond what this cell allows"):
        r.check_range()
    with pytest.raises(ValueError, match="rmax"):
        r.run(stop=1)
    # the largest cutoff FastNS accepts is accepted here too
    limit = fastns_max_cutoff(np.asarray(u.dimensions, np.float32))
    RDF(ow, ow, range=(0.0, limit)).check_range()


def test_rmax_refused_only_where_interrdf_refuses(water_tric):
    """375 atoms in a skewed NPT box: InterRDF's grid search (chosen while
    rmax <= 0.3 x the box extent, about 5.7 Å here) refuses 5 Å on the
    frames where its limit drops to 4.2-4.6 Å, while 8 Å goes to brute
    force and works.  RDF refuses and accepts the same."""
    g = water_tric.atoms
    with pytest.raises(ValueError, match="too large"):
        InterRDF(g, g, range=(0.0, 5.0)).run()
    with pytest.raises(ValueError, match="rmax = 5 Å is beyond"):
        RDF(g, g, range=(0.0, 5.0)).run()
    assert_same(*both(g, g, range=(0.0, 8.0)))


def test_grid_kept_across_frames_and_nothing_per_frame(water_tric):
    u = universe(datafiles.waterPSF, datafiles.waterDCD)  # fixed box
    r = RDF(u.atoms, u.atoms, range=(0.0, 20.0)).run()
    assert r.grid_stats == {"builds": 1, "updates": u.trajectory.n_frames - 1}
    # NPT: the box changes every frame, so the grid is rebuilt
    r = RDF(water_tric.atoms, water_tric.atoms, range=(0.0, 4.0)).run()
    assert r.grid_stats["builds"] == water_tric.trajectory.n_frames
    assert set(r.results.keys()) == {"count", "edges", "bins", "volume_cum", "rdf"}
    assert r._pairs is None


def test_template_counts_subset_of_exact(scene_pdbs):
    u = universe(scene_pdbs["liquid"])
    exact = RDF(u.atoms, u.atoms, range=(0.0, 8.0)).run().results.count
    wide = RDF(u.atoms, u.atoms, range=(0.0, 8.0), template=9).run().results.count
    narrow = RDF(u.atoms, u.atoms, range=(0.0, 8.0), template=3).run().results.count
    assert (wide <= exact).all() and (narrow <= wide).all()
    assert wide.sum() >= 0.99 * exact.sum()
    assert narrow.sum() < 0.9 * exact.sum()


def test_parallel_backends_identical_counts(water_tric):
    g = water_tric.atoms
    serial = RDF(g, g, range=(0.0, 10.0)).run()
    assert RDF.get_supported_backends() == ("serial", "multiprocessing", "dask")
    for backend in ("multiprocessing", "dask"):
        if backend == "dask":
            pytest.importorskip("dask")
        par = RDF(g, g, range=(0.0, 10.0)).run(backend=backend, n_workers=2)
        assert par.n_frames == serial.n_frames
        np.testing.assert_array_equal(par.results.count, serial.results.count)
        np.testing.assert_allclose(par.results.volume_cum, serial.results.volume_cum,
                                   rtol=1e-14)
        np.testing.assert_allclose(par.results.rdf, serial.results.rdf, rtol=1e-13)


# --------------------------------------------------------------------------
# bad input, MDAnalysis side
# --------------------------------------------------------------------------

@pytest.mark.parametrize("kw, match", [
    (dict(nbins=0), "nbins"),
    (dict(nbins=2.5), "nbins"),
    (dict(range=(0.0, -1.0)), "rmax"),
    (dict(range=(0.0, float("nan"))), "rmax"),
    (dict(range=(5.0, 2.0)), "range"),
    (dict(range=3.0), "range"),
    (dict(template=4), "template"),
    (dict(norm="bad"), "norm"),
    (dict(exclude_same="molecule"), "exclude_same"),
    (dict(backend="distopia"), "backend"),
])
def test_bad_arguments_raise(water_tric, kw, match):
    with pytest.raises(ValueError, match=match):
        RDF(water_tric.atoms, water_tric.atoms, **kw)


def test_bad_groups_raise(water_tric):
    empty = water_tric.select_atoms("name XX")
    with pytest.raises(ValueError, match="g1: the atom group is empty"):
        RDF(empty, water_tric.atoms)
    with pytest.raises(ValueError, match="g2"):
        RDF(water_tric.atoms, empty)
    for block in [(0, 3), (3,), "ab", (1.5, 2)]:
        with pytest.raises(ValueError, match="exclusion_block"):
            RDF(water_tric.atoms, water_tric.atoms, exclusion_block=block)


def test_duplicate_atoms_count_twice(water_tric):
    g = water_tric.select_atoms("name OH2")
    twice = g + g[:10]
    ref, got = both(twice, g, range=(0.0, 8.0))
    assert_same(ref, got)


@pytest.mark.parametrize("block", [(3, 3), (2, 5), (1, 1)])
def test_exclusion_block_with_atom_listed_twice(water_tric, block):
    """An atom listed twice sits in two blocks (InterRDF masks by position
    in the group): accepted, counts and normalisation as InterRDF's."""
    twice = water_tric.atoms[:30] + water_tric.atoms[:9] + water_tric.atoms[60:90]
    other = water_tric.atoms[:45] + water_tric.atoms[3:6]
    ref, got = both(twice, other, stop=3, range=(0.0, 8.0), exclusion_block=block)
    assert_same(ref, got)
    # the masked pairs are really gone: fewer than without the exclusion
    assert got.results.count.sum() < RDF(twice, other, range=(0.0, 8.0)).run(
        stop=3).results.count.sum()


# --------------------------------------------------------------------------
# ASE side: get_rdf's numbers
# --------------------------------------------------------------------------

@pytest.mark.parametrize("name, natoms, rmax, nbins, elements", [
    ("liquid", 500, 12.0, 100, None),
    ("copper", 500, 7.22, 20, None),       # perfect lattice: ceil(d/dr) ties
    ("gas", 216, 20.0, 50, None),
    ("sheared", 2048, 5.5, 100, None),     # triclinic
    ("slab", 400, 6.0, 60, None),          # pbc (T, T, F)
    ("mixture", 500, 10.0, 80, ("Ar", "Kr")),
    ("mixture", 500, 10.0, 80, (36, 36)),
])
def test_rdf_matches_ase_get_rdf(name, natoms, rmax, nbins, elements):
    atoms = make_scene(name, natoms)
    images = [atoms] if name == "copper" else displaced(atoms)
    ref, r_ref = get_rdf(images, rmax, nbins, elements=elements)
    got, r_got = rdf(images, rmax, nbins, elements=elements)
    assert ref.sum() > 0
    np.testing.assert_array_equal(r_got, r_ref)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
    # one image: get_rdf of a single Atoms
    np.testing.assert_allclose(rdf(images[0], rmax, nbins, elements=elements)[0],
                               get_rdf(images[0], rmax, nbins, elements=elements)[0],
                               rtol=0, atol=1e-12)


def test_rdf_uses_get_rdf_arithmetic():
    """Two atoms across a periodic face, at a distance where get_rdf's
    ``(pos[j] + S @ cell) - pos[i]`` and ``(pos[j] - pos[i]) + S @ cell``
    differ in the last bit and ceil(d / dr) tells them apart (found by a
    random search)."""
    from ase import Atoms
    atoms = Atoms("Ar2", positions=[[9.78, 5.9, 3.2], [1.88, 6.73, 1.95]],
                  cell=[10.0, 10.0, 10.0], pbc=True)
    rmax = 3.68709830050014
    ref, _ = get_rdf(atoms, rmax, 10)
    assert ref.sum() > 0
    np.testing.assert_array_equal(rdf(atoms, rmax, 10)[0], ref)


def test_rdf_from_trajectory_file_streams(tmp_path):
    images = displaced(make_scene("liquid", 256), 4)
    path = str(tmp_path / "liquid.traj")
    ase.io.write(path, images)
    ref, _ = get_rdf(images, 9.0, 45)
    np.testing.assert_allclose(rdf(path, 9.0, 45)[0], ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rdf(iter(images), 9.0, 45)[0], ref, rtol=0, atol=1e-12)


def test_rdf_reproduces_ase_atom0_quirk():
    """get_rdf skips a partial-RDF centre whose only second-element
    neighbours are atom 0 (np.count_nonzero on the index list)."""
    atoms = make_scene("liquid", 256)
    atoms.numbers[0] = 36
    far = int(np.argmax(atoms.get_distances(0, range(len(atoms)), mic=True)))
    atoms.numbers[far] = 36
    ref, _ = get_rdf(atoms, 6.0, 60, elements=("Ar", "Kr"))
    got, _ = rdf(atoms, 6.0, 60, elements=("Ar", "Kr"))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
    counted, _ = rdf(atoms, 6.0, 60, elements=("Ar", "Kr"), ase_quirk=False)
    assert counted.sum() > got.sum() + 1.0


def test_rdf_without_cell_needs_volume():
    atoms = make_scene("nanoparticle", 200)
    with pytest.raises(VolumeNotDefined) as exc:
        rdf(atoms, 5.0, 50)
    assert isinstance(exc.value, ValueError) and isinstance(exc.value, ASEVolumeNotDefined)
    ref = get_rdf(atoms, 5.0, 50, volume=5000.0)[0]
    np.testing.assert_allclose(rdf(atoms, 5.0, 50, volume=5000.0)[0], ref,
                               rtol=0, atol=1e-12)


def test_rdf_bad_input(tmp_path):
    atoms = make_scene("liquid", 256)
    with pytest.raises(CellTooSmall, match="rmax") as exc:
        rdf(atoms, 15.0, 50)
    assert isinstance(exc.value, ValueError) and isinstance(exc.value, ASECellTooSmall)
    for kw, match in [(dict(rmax=0.0), "rmax"), (dict(rmax="a"), "rmax"),
                      (dict(nbins=0), "nbins"), (dict(elements=("Ar",)), "elements"),
                      (dict(elements=("Xx", "Ar")), "elements"),
                      (dict(template=2), "template")]:
        args = dict(rmax=5.0, nbins=10)
        args.update(kw)
        with pytest.raises(ValueError, match=match):
            rdf(atoms, **args)
    with pytest.raises(ValueError, match="atoms"):
        rdf([], 5.0, 10)
    with pytest.raises(OSError, match="no such file"):
        rdf(str(tmp_path / "missing.traj"), 5.0, 10)
    garbage = tmp_path / "garbage.traj"
    garbage.write_text("not a trajectory\n")
    with pytest.raises(OSError, match="cannot read"):
        rdf(str(garbage), 5.0, 10)


@pytest.mark.parametrize("elements", [None, ("Ar", "Kr")])
def test_rdf_takes_get_rdf_arguments_in_order(elements):
    """rdf(atoms, rmax, nbins, distance_matrix, elements, no_dists, volume):
    the same positional call as get_rdf, the same numbers."""
    atoms = make_scene("mixture", 256)
    for call in [(atoms, 6.0, 30, None, elements, False, None),
                 (atoms, 6.0, 30, None, elements, True, None),
                 (atoms, 6.0, 30, None, elements, False, 2.0 * atoms.get_volume()),
                 (atoms, 6.0, 30, atoms.get_all_distances(mic=True), elements, False, None)]:
        ref, got = get_rdf(*call), rdf(*call)
        if call[5]:  # no_dists: g only
            assert isinstance(got, np.ndarray) and got.shape == (30,)
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
        else:
            np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(got[1], ref[1])
            assert ref[0].sum() > 0
    # our options after get_rdf's
    g_exact = rdf(atoms, 6.0, 30, None, elements, True, None, None)
    g_templ = rdf(atoms, 6.0, 30, None, elements, True, None, 9)
    np.testing.assert_allclose(g_templ, g_exact, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="distance_matrix"):
        rdf(atoms, 6.0, 30, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="distance_matrix"):
        rdf(atoms, 6.0, 30, np.zeros(5))
    with pytest.raises(TypeError, match="no_dists"):
        rdf(atoms, 6.0, 30, no_dists="yes")
    with pytest.raises(ValueError, match="volume"):
        rdf(atoms, 6.0, 30, volume="big")


# --------------------------------------------------------------------------
# the rdf subcommand
# --------------------------------------------------------------------------

def parse(argv):
    parser = argparse.ArgumentParser(prog="ase-mlg")
    add_rdf_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["rdf"] + argv)


def test_cli_rdf_table_plot_progress(scene_pdbs, tmp_path, capsys):
    table, png = tmp_path / "g.txt", tmp_path / "g.png"
    args = parse([scene_pdbs["liquid"], "--rmax", "12", "--nbins", "60",
                  "--output", str(table), "--plot", str(png)])
    assert args.func is run_rdf_command
    r = run_rdf_command(args)
    data = np.loadtxt(table)
    assert data.shape == (60, 3)
    u = universe(scene_pdbs["liquid"])
    ref = InterRDF(u.atoms, u.atoms, nbins=60, range=(0.0, 12.0)).run()
    np.testing.assert_allclose(data[:, 0], ref.results.bins, atol=1e-6)
    np.testing.assert_array_equal(data[:, 2], ref.results.count)
    np.testing.assert_allclose(data[:, 1], ref.results.rdf, rtol=1e-9)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert r.n_frames == 3
    # stderr is not a terminal here: no progress bar
    assert "100%" not in capsys.readouterr().err


def test_cli_rdf_progress_bar_only_on_a_terminal(scene_pdbs, monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    for tty in (True, False):
        err = Terminal() if tty else io.StringIO()
        monkeypatch.setattr("sys.stderr", err)
        run_rdf_command(parse([scene_pdbs["liquid"], "--rmax", "8"]), out=io.StringIO())
        assert ("100%" in err.getvalue()) is tty  # MDAnalysis's tqdm bar


def test_cli_rdf_topology_selections_parallel(water_tric):
    out = io.StringIO()
    # MDAnalysis's order: Universe(topology, trajectory)
    args = parse([datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC,
                  "--select", "name OH2", "--select2", "name H1 H2", "--rmax", "8",
                  "--nbins", "16", "--backend", "multiprocessing", "--workers", "2"])
    run_rdf_command(args, out=out)
    data = np.loadtxt(io.StringIO(out.getvalue()))
    ref = InterRDF(water_tric.select_atoms("name OH2"),
                   water_tric.select_atoms("name H1 H2"), nbins=16,
                   range=(0.0, 8.0)).run()
    np.testing.assert_array_equal(data[:, 2], ref.results.count)


@pytest.mark.parametrize("argv, exc, name", [
    (["{missing}"], OSError, "FILE"),
    (["{garbage}"], OSError, "FILE"),
    (["{tpr}", "{missing}"], OSError, "TRAJECTORY"),
    (["{missing}", "{xtc}"], OSError, "TOPOLOGY"),
    (["{liquid}", "{liquid}", "{liquid}"], ValueError, "FILE"),
    (["{dcd_nobox}", "{psf_nobox}"], OSError, "TOPOLOGY/TRAJECTORY"),
    (["{psf_nobox}", "{dcd_nobox}", "--select", "name CA"], ValueError, "--norm"),
    (["{liquid}", "--exclude-self", "--select2", "name Ar and index 1:10"], ValueError,
     "--exclude-self"),
    (["{liquid}", "--exclusion-block", "0", "1"], ValueError, "--exclusion-block"),
    (["{liquid}", "--exclusion-block", "1", "1", "--exclude-same", "residue"],
     ValueError, "--exclude-same"),
    (["{liquid}", "--scheduler", "tcp://127.0.0.1:9", "--backend", "dask"], ValueError,
     "--scheduler"),
    (["{liquid}", "--select", "name XX"], ValueError, "--select"),
    (["{liquid}", "--select2", "name and"], ValueError, "--select2"),
    (["{liquid}", "--rmax", "0"], ValueError, "--rmax"),
    (["{liquid}", "--rmax", "-3"], ValueError, "--rmax"),
    (["{liquid}", "--nbins", "0"], ValueError, "--nbins"),
    (["{liquid}", "--template", "4"], ValueError, "--template"),
    (["{liquid}", "--rmin", "20"], ValueError, "--rmin"),
    (["{liquid}", "--workers", "0", "--backend", "dask"], ValueError, "--workers"),
    (["{liquid}", "--output", "{tmp}/no/such/dir/g.txt"], OSError, "--output"),
    (["{tpr}", "{xtc}", "--select", "name OW", "--rmax", "40"], ValueError, "--rmax"),
])
def test_cli_rdf_errors_name_the_argument(scene_pdbs, tmp_path, argv, exc, name):
    garbage = tmp_path / "garbage.dcd"
    garbage.write_bytes(b"\x00\x01 not a dcd file" * 10)
    paths = dict(missing=str(tmp_path / "missing.dcd"), garbage=str(garbage),
                 liquid=scene_pdbs["liquid"], xtc=datafiles.XTC, tpr=datafiles.TPR,
                 psf_nobox=datafiles.PSF, dcd_nobox=datafiles.DCD,
                 tmp=str(tmp_path))
    args = parse([a.format(**paths) for a in argv])
    with pytest.raises(exc) as info:
        run_rdf_command(args, out=io.StringIO())
    msg = str(info.value)
    assert msg.startswith(name) and "\n" not in msg and len(msg) < 400
    assert not os.path.exists(tmp_path / "g.txt")


def test_cli_rdf_exclusions_and_updating(water_tric):
    """--exclude-self, --exclusion-block, --exclude-same and --updating give
    InterRDF's counts with the matching arguments."""
    ow = water_tric.select_atoms("name OH2")
    every = water_tric.atoms
    cases = [
        (["--select", "name OH2", "--exclude-self"], (ow, ow, dict(exclusion_block=(1, 1)))),
        (["--exclusion-block", "3", "3"], (every, every, dict(exclusion_block=(3, 3)))),
        (["--exclude-same", "residue"], (every, every, dict(exclude_same="residue"))),
    ]
    for argv, (g1, g2, kw) in cases:
        out = io.StringIO()
        run_rdf_command(parse([datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC,
                               "--rmax", "8", "--nbins", "12", "--stop", "4"] + argv),
                        out=out)
        ref = InterRDF(g1, g2, nbins=12, range=(0.0, 8.0), **kw).run(stop=4)
        data = np.loadtxt(io.StringIO(out.getvalue()))
        np.testing.assert_array_equal(data[:, 2], ref.results.count)
        np.testing.assert_allclose(data[:, 1], ref.results.rdf, rtol=1e-9)
    # without the exclusion the d = 0 self pairs are there
    plain = InterRDF(ow, ow, nbins=12, range=(0.0, 8.0)).run(stop=4)
    assert plain.results.count[0] > 0
    out = io.StringIO()
    run_rdf_command(parse([datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC,
                           "--select", "name OH2 and prop z < 2", "--updating",
                           "--select2", "name OH2", "--rmax", "8", "--nbins", "12"]),
                    out=out)
    upd = water_tric.select_atoms("name OH2 and prop z < 2", updating=True)
    ref = InterRDF(upd, ow, nbins=12, range=(0.0, 8.0)).run()
    np.testing.assert_array_equal(np.loadtxt(io.StringIO(out.getvalue()))[:, 2],
                                  ref.results.count)


def test_cli_rdf_help_for_every_option():
    parser = argparse.ArgumentParser(prog="ase-mlg")
    sub = parser.add_subparsers(dest="command")
    p = add_rdf_parser(sub)
    for action in p._actions:
        assert action.help, action.dest
    text = p.format_help()
    assert "TOPOLOGY TRAJECTORY" in text and "--scheduler" in text
