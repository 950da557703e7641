"""Bad input: every public entry point answers it with a clear error.

NaN/inf/strings/complex/wrong-shape positions, absurd cutoffs and cells,
unknown species, bad keyword arguments, and the ``ase-mlg`` command line:
each check asserts a ``ValueError``/``TypeError`` (or, for the CLI, one
line on stderr and a non-zero exit) whose message names the argument or atom,
with no numba traceback.  Checks are registered as in ``extreme_cases`` and
run by ``tests/test_extremes.py``.
"""

import functools
import os
import subprocess
import sys

import numpy as np

from ase_mlg import MLG, MLGCalculator, NeighborList, neighbor_list
from ase_mlg.potentials import LennardJones

from extreme_cases import clear_error, lj_pair, register, small_liquid, subprocess_env

CHECKS = []  # (group, name, check) in the report's order
check = functools.partial(register, checks=CHECKS)


def _bad_positions():
    out = {}
    base = small_liquid().positions
    nan = base.copy()
    nan[3, 1] = np.nan
    inf = base.copy()
    inf[5, 0] = np.inf
    out["NaN"] = (nan, ["atom", "nan"])
    out["inf"] = (inf, ["atom", "inf"])
    out["strings"] = (base.astype(str), ["positions"])
    out["complex"] = (base.astype(complex), ["positions", "complex"])
    out["shape (N, 2)"] = (base[:, :2], ["positions", "shape"])
    out["shape (N,)"] = (base[:, 0], ["positions", "shape"])
    return out


def _bad_pos_check(api):
    res = []
    at = small_liquid()
    for label, (p, words) in _bad_positions().items():
        if api == "MLG":
            f = lambda p=p: MLG(p, at.cell.array, True)
        elif api == "MLG.update":
            g = MLG(at.positions, at.cell.array, True)
            f = lambda p=p, g=g: g.update(p)
        elif api == "neighbor_list":
            from ase_mlg.neighborlist import primitive_neighbor_list
            f = lambda p=p: primitive_neighbor_list("ij", at.pbc, at.cell.array, p, 3.0)
        elif api == "neighbor_list(atoms)":
            if label.startswith("shape") or label == "strings":
                continue  # Atoms itself refuses these
            b = at.copy()
            b.arrays["positions"] = p
            f = lambda b=b: neighbor_list("ij", b, 3.0)
        elif api == "NeighborList":
            if label.startswith("shape") or label == "strings":
                continue
            b = at.copy()
            b.arrays["positions"] = p
            nl = NeighborList([1.5] * len(b))
            f = lambda b=b, nl=nl: nl.update(b)
        elif api == "MLGCalculator":
            if label.startswith("shape") or label == "strings":
                continue
            b = at.copy()
            b.arrays["positions"] = p
            b.calc = MLGCalculator(lj_pair(6.0))
            f = b.get_potential_energy
        clear_error(f, words)
        res.append(label)
    return "clear errors for " + ", ".join(res)


for _api in ("MLG", "MLG.update", "neighbor_list", "neighbor_list(atoms)",
             "NeighborList", "MLGCalculator"):
    check("bad input", f"{_api}: NaN/inf/strings/complex/wrong-shape positions")(
        (lambda api: lambda: _bad_pos_check(api))(_api))


@check("bad input", "cutoffs: negative, NaN, inf, string, complex, wrong length, "
                    "an integer no float holds")
def b_cutoffs():
    at = small_liquid()
    out = []
    for c in (-1.0, np.nan, np.inf, "abc", 1 + 2j, [1.0] * 3, [-1.0] * len(at), 10 ** 400,
              {("Ar", "Ar"): 10 ** 400}):
        out.append(clear_error(lambda c=c: neighbor_list("ij", at, c), "cutoff"))
    for c in (-1.0, np.nan, [1.0, 2.0]):
        out.append(clear_error(lambda c=c: NeighborList(c if isinstance(c, list) else [c] * len(at)).update(at)
                               if True else None, ["cutoff", "radii", "number"]))
    for kw in ({"rc": -1.0}, {"rc": np.nan}, {"sigma": -1}, {"sigma": "x"}):
        out.append(clear_error(lambda kw=kw: LennardJones(**kw), list(kw)))
    out.append(clear_error(lambda: MLGCalculator(lj_pair(), skin=-0.1), "skin"))
    out.append(clear_error(lambda: MLGCalculator(lj_pair(), skin=np.nan), "skin"))
    out.append(clear_error(lambda: MLGCalculator(lj_pair(), template=4), "template"))
    return f"clear errors ({len(out)} cases)"


@check("bad input", "unknown species in parameter tables / cutoff dicts")
def b_species():
    at = small_liquid()
    out = [clear_error(lambda: neighbor_list("ij", at, {("Ar", "Xx"): 3.0}), ["Xx", "element"])]
    from ase_mlg.potentials import lennard_jones_mixture
    pot = lennard_jones_mixture({"Kr": 3.6}, {"Kr": 0.014})
    b = at.copy()
    b.calc = MLGCalculator(pot)
    out.append(clear_error(b.get_potential_energy, ["atom", "Ar", "18"]))
    out.append(clear_error(lambda: lennard_jones_mixture({"Qq": 3.6}, {"Qq": 0.01}), ["Qq", "element"]))
    return "; ".join(out)


@check("bad input", "zero-volume periodic cells (zero vector, coplanar vectors)")
def b_zero_cell():
    at = small_liquid()
    out = []
    for cell in ([[0, 0, 0], [0, 5, 0], [0, 0, 5]],
                 [[5, 0, 0], [0, 5, 0], [5, 5, 0]], np.zeros((3, 3))):
        b = at.copy()
        b.set_cell(cell)
        b.pbc = True
        out.append(clear_error(lambda b=b: neighbor_list("ij", b, 3.0), "cell"))
        out.append(clear_error(lambda b=b: MLG.from_atoms(b), "cell"))
        b.calc = MLGCalculator(lj_pair(6.0))
        out.append(clear_error(b.get_potential_energy, "cell"))
        out.append(clear_error(lambda b=b: NeighborList([1.0] * len(b)).update(b), "cell"))
    return f"clear errors ({len(out)} cases)"


@check("bad input", "bad cell dtype/shape/NaN (MLG)")
def b_cell_dtype():
    at = small_liquid()
    out = []
    for cell, w in ((np.full((3, 3), np.nan), "cell"), (np.eye(2), "cell"),
                    ([["a"] * 3] * 3, "cell"), (np.eye(3) * (1 + 1j), "cell")):
        out.append(clear_error(lambda c=cell: MLG(at.positions, c, True), w))
    return f"clear errors ({len(out)} cases)"


@check("bad input", "MLG keyword arguments: sweep_cap, monitor_every, max_phase_lag, pbc, shape")
def b_mlg_kwargs():
    at = small_liquid()
    P, C = at.positions, at.cell.array
    out = []
    for kw, w in (({"sweep_cap": np.nan}, "sweep_cap"), ({"sweep_cap": "x"}, "sweep_cap"),
                  ({"sweep_cap": 0}, "sweep_cap"), ({"monitor_every": "x"}, "monitor_every"),
                  ({"max_phase_lag": np.nan}, "max_phase_lag"), ({"method": "x"}, "method"),
                  ({"pbc": "abc"}, "pbc"), ({"pbc": [True, False]}, "pbc"),
                  ({"shape": (1, 1, 1)}, "shape"), ({"shape": (-2, -2, -4)}, "shape")):
        kw = dict(kw)
        pbc = kw.pop("pbc", True)
        out.append(clear_error(lambda kw=kw, pbc=pbc: MLG(P, C, pbc, **kw), w))
    return f"clear errors ({len(out)} cases)"


@check("bad input", "neighbor_list cutoff 1e300 (finite but absurd)")
def b_cutoff_huge():
    return clear_error(lambda: neighbor_list("ij", small_liquid(), 1e300), "cutoff")


@check("bad input", "NeighborList cutoffs of strings / complex numbers")
def b_nl_cutoff_types():
    at = small_liquid()
    out = [clear_error(lambda: NeighborList(["a"] * len(at)).update(at), "cutoff"),
           clear_error(lambda: NeighborList([1j] * len(at)).update(at), "cutoff")]
    return out[0]


@check("bad input", "neighbor_list bad quantities / NeighborList misuse")
def b_quantities():
    at = small_liquid()
    out = [clear_error(lambda: neighbor_list("ijx", at, 3.0), "quantit"),
           clear_error(lambda: neighbor_list(5, at, 3.0), "quantit")]
    return "; ".join(out)


@check("bad input", "analysis.rdf: NaN positions, bad rmax/nbins, zero volume")
def b_rdf():
    from ase_mlg.analysis import rdf
    at = small_liquid()
    out = []
    nan = at.copy()
    nan.positions[2, 2] = np.nan
    out.append(clear_error(lambda: rdf([nan], 5.0, 10), ["atom", "nan", "position"]))
    for rmax in (-1.0, np.nan, np.inf, "x"):
        out.append(clear_error(lambda r=rmax: rdf([at], r, 10), "rmax"))
    for nb in (0, -3, 2.5, "x"):
        out.append(clear_error(lambda nb=nb: rdf([at], 5.0, nb), "nbins"))
    z = at.copy()
    z.set_cell([[0, 0, 0], [0, 5, 0], [0, 0, 5]])
    z.pbc = True
    out.append(clear_error(lambda: rdf([z], 3.0, 10), ["cell", "volume"]))
    return f"clear errors ({len(out)} cases)"


@check("bad input", "analysis.RDF: bad nbins/range")
def b_RDF():
    import MDAnalysis as mda
    from ase_mlg.analysis import RDF
    u = mda.Universe.empty(10, trajectory=True)
    u.atoms.positions = np.random.default_rng(0).random((10, 3)) * 10
    u.dimensions = [10, 10, 10, 90, 90, 90]
    out = []
    for kw, w in (({"nbins": 0}, "nbins"), ({"nbins": "x"}, "nbins"),
                  ({"range": (5.0, 1.0)}, "range"), ({"range": (0.0, np.nan)}, "range"),
                  ({"range": (-1.0, 5.0)}, "range")):
        out.append(clear_error(lambda kw=kw: RDF(u.atoms, u.atoms, **kw).run(), w))
    pos = u.atoms.positions
    pos[0] = np.nan
    u.atoms.positions = pos
    out.append(clear_error(lambda: RDF(u.atoms, u.atoms, nbins=10, range=(0, 4)).run(),
                           ["nan", "position", "atom"]))
    return f"clear errors ({len(out)} cases)"


def run_cli(args, timeout=60):
    return subprocess.run([sys.executable, "-m", "ase_mlg.cli", *args],
                          capture_output=True, text=True, timeout=timeout,
                          env=subprocess_env())


CLI_CASES = [
    (["demo", "--natoms", "0"], "natoms"),
    (["demo", "--natoms", "nan"], "natoms"),
    (["demo", "--steps", "-1"], "steps"),
    (["demo", "--md-steps", "-5"], "md-steps"),
    (["rdf", "/nonexistent.xyz"], "nonexistent"),
    (["rdf", "@TRAJ@", "--rmax", "nan"], "rmax"),
    (["rdf", "@TRAJ@", "--rmax", "-3"], "rmax"),
    (["rdf", "@TRAJ@", "--nbins", "0"], "nbins"),
    (["rdf", "@TRAJ@", "--rmax", "inf"], "rmax"),
    (["rdf", "@TRAJ@", "--template", "4"], "template"),
    (["rdf", "@TRAJ@", "--select", "name ZZZ"], "select"),
    (["rdf", "@NANTRAJ@"], ["nan", "position", "atom"]),
    (["tradeoff", "--scene", "liquid", "--natoms", "200", "--cutoff", "nan"], "cutoff"),
    (["tradeoff", "--scene", "liquid", "--natoms", "200", "--cutoff", "-1"], "cutoff"),
    (["tradeoff", "--scene", "liquid", "--natoms", "200", "--cutoff", "5", "--sigma", "inf"], "sigma"),
    (["tradeoff", "--scene", "liquid", "--natoms", "200", "--cutoff", "5", "--skin", "-1"], "skin"),
    (["tradeoff", "--scene", "nope", "--cutoff", "5"], "scene"),
    (["tradeoff", "--scene", "liquid", "--natoms", "200", "--cutoff", "5", "--widths", "4"], "widths"),
    (["tradeoff", "@NANXYZ@", "--cutoff", "5"], ["atom(s) [1]"]),
]


def _cli_files():
    import tempfile
    from ase.io import write
    d = tempfile.mkdtemp(prefix="extremes_")
    at = small_liquid()
    traj = os.path.join(d, "ok.xyz")
    write(traj, at, format="extxyz")
    bad = at.copy()
    bad.positions[1] = np.nan
    nantraj = os.path.join(d, "nan.pdb")
    write(nantraj, bad, format="proteindatabank")
    nanxyz = os.path.join(d, "nan.xyz")
    write(nanxyz, bad, format="extxyz")
    return {"@TRAJ@": traj, "@NANTRAJ@": nantraj, "@NANXYZ@": nanxyz}


def cli_case(args, words, files=None):
    files = files or _cli_files()
    args = [files.get(a, a) for a in args]
    try:
        r = run_cli(args, timeout=60)
    except subprocess.TimeoutExpired:
        raise AssertionError("hang (timeout 60 s)")
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert r.returncode != 0, f"exit 0 (stdout {r.stdout[:100]!r})"
    assert len(lines) == 1, f"{len(lines)} stderr lines: {r.stderr[-300:]!r}"
    assert "Traceback" not in r.stderr and "numba" not in r.stderr.lower()
    if isinstance(words, str):
        words = [words]
    assert any(w.lower() in lines[0].lower() for w in words), f"message {lines[0]!r}"
    return f"clear error (exit {r.returncode}): {lines[0][:100]}"


for _args, _words in CLI_CASES:
    check("bad input", "CLI: ase-mlg " + " ".join(a.strip("@").lower() if a.startswith("@") else a
                                                  for a in _args))(
        (lambda a, w: lambda: cli_case(a, w))(_args, _words))
