"""What ``ase-mlg rdf`` says besides its table (issue 18.5 and 18.6): one
note when bin 0 counted self pairs (InterRDF's default, kept) and how to
drop them; one line per file it wrote."""

import io

import numpy as np
import pytest
from MDAnalysisTests import datafiles

from ase_mlg.cli import _parser, main
from ase_mlg.cli.rdf import run

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")

WATER = [datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC, "--rmax", "8",
         "--nbins", "16", "--stop", "3"]


def parse(argv):
    """``ase-mlg rdf ARGV`` as the command line parses it."""
    return _parser().parse_args(["rdf"] + argv)


def rdf(argv, capsys):
    """What ``ase-mlg rdf`` (``ase_mlg.cli.main``'s ``rdf`` branch) does, in
    this process: the RDF it ran, its table and its stderr."""
    out = io.StringIO()
    r = run(parse(WATER + argv), out=out)
    return r, out.getvalue(), capsys.readouterr().err


def test_self_pairs_are_counted_and_said(capsys):
    r, table, err = rdf(["--select", "name OH2"], capsys)
    n = len(r.g1)
    # InterRDF's default is kept: each oxygen with itself in bin 0 ...
    assert np.loadtxt(io.StringIO(table))[0, 2] >= n * r.n_frames
    # ... and said in one line on stderr, with the way out
    notes = [line for line in err.splitlines() if "self pairs" in line]
    assert len(notes) == 1
    assert f"{n} self pairs" in notes[0] and "--exclude-self" in notes[0]
    assert "self pairs" not in table


def test_no_note_when_there_are_no_self_pairs(capsys):
    for argv in (["--select", "name OH2", "--exclude-self"],
                 ["--select", "name OH2", "--select2", "name H1 H2"],
                 ["--select", "name OH2", "--rmin", "0.5"],
                 ["--exclude-same", "residue"]):
        r, table, err = rdf(argv, capsys)
        assert "self pairs" not in err, argv
    # the excluded run has nothing left at d = 0
    r, table, _ = rdf(["--select", "name OH2", "--exclude-self"], capsys)
    assert np.loadtxt(io.StringIO(table))[0, 2] == 0


def test_overlapping_groups_get_the_note_without_exclude_self(capsys):
    _, _, err = rdf(["--select", "name OH2", "--select2", "name OH2 H1"], capsys)
    (note,) = [line for line in err.splitlines() if "self pairs" in line]
    assert "disjoint" in note


def test_written_files_are_said(tmp_path, capsys):
    table, png = tmp_path / "g.txt", tmp_path / "g.png"
    assert main(["rdf", *WATER, "--select", "name OH2", "--exclude-self",
                 "--output", str(table), "--plot", str(png)]) == 0
    out, err = capsys.readouterr()
    assert out == "" and table.exists() and png.exists()
    lines = err.strip().splitlines()
    assert f"wrote {table} (16 rows" in lines[-2]
    assert f"wrote the plot {png}" in lines[-1]
