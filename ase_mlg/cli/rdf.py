"""``ase-mlg rdf``: g(r) of any trajectory MDAnalysis reads, counted through
the MLG (:class:`ase_mlg.analysis.RDF`; docs/design.md §10).

Bad input raises ``ValueError``/``OSError`` with a one-line message naming
the argument; :func:`ase_mlg.cli.main` prints it and exits with status 2.
"""

import importlib
import os
import sys

import numpy as np

from ..analysis import RDF, DistributedBackend
from ..analysis.checks import check_nbins, check_rmax, check_template, one_line
from .options import is_tty

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add the ``rdf`` subcommand to an ``argparse`` subparsers object and
    return its parser (``func`` default: :func:`run`)."""
    p = subparsers.add_parser(
        "rdf", help="radial distribution function of a trajectory through the MLG",
        description="g(r) of any trajectory MDAnalysis reads, counted through the "
                    "MLG; the numbers of MDAnalysis InterRDF.  Files in MDAnalysis's "
                    "order: ase-mlg rdf TOPOLOGY TRAJECTORY (as Universe(topology, "
                    "trajectory)), or one file holding both.")
    p.add_argument("files", metavar="FILE", nargs="+",
                   help="TOPOLOGY TRAJECTORY, or a single file with topology and "
                        "coordinates (PDB, GRO, ...)")
    p.add_argument("--select", default="all",
                   help="MDAnalysis selection of the first group (default: all)")
    p.add_argument("--select2", default=None,
                   help="selection of the second group (default: same as --select)")
    p.add_argument("--updating", action="store_true",
                   help="re-evaluate the selections every frame (e.g. 'around 3.5 "
                        "protein'), as select_atoms(..., updating=True)")
    p.add_argument("--rmin", type=float, default=0.0, help="smallest distance, Å (default 0)")
    p.add_argument("--rmax", type=float, default=15.0, help="largest distance, Å (default 15)")
    p.add_argument("--nbins", type=int, default=75, help="number of bins (default 75)")
    p.add_argument("--norm", choices=("rdf", "density", "none"), default="rdf",
                   help="normalisation: rdf = g(r) (needs a box), density = "
                        "count / shell volume (Å^-3), none = count per frame "
                        "(default rdf)")
    p.add_argument("--exclude-self", action="store_true",
                   help="drop each atom's pair with itself (d = 0); the same as "
                        "--exclusion-block 1 1 (needs the two groups equal)")
    p.add_argument("--exclusion-block", type=int, nargs=2, metavar=("N1", "N2"),
                   default=None,
                   help="drop pairs in the same block of N1 atoms of the first "
                        "group and N2 of the second (InterRDF's exclusion_block)")
    p.add_argument("--exclude-same", choices=("residue", "segment", "chain"),
                   default=None,
                   help="drop pairs of atoms in the same residue/segment/chain")
    p.add_argument("--plot", metavar="OUT.png", default=None, help="write a plot of g(r)")
    p.add_argument("--output", metavar="TABLE.txt", default=None,
                   help="write the table r, g(r), count here (default: stdout)")
    p.add_argument("--backend", choices=("serial", "multiprocessing", "dask"),
                   default="serial",
                   help="where frames run: serial (default; a progress bar when "
                        "stderr is a terminal), multiprocessing or dask processes "
                        "on this machine")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes for multiprocessing/dask (default 1); "
                        "with --scheduler, parts to split the frames into "
                        "(default: the cluster's workers)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run on a dask.distributed cluster, e.g. tcp://host:8786 "
                        "(start one with 'dask scheduler' and 'dask worker ADDRESS'; "
                        "workers must read the files at the same paths)")
    p.add_argument("--template", type=int, default=None, metavar="W",
                   help="count through the W^3 template (odd W) instead of exactly")
    p.add_argument("--start", type=int, default=None, help="first frame (default 0)")
    p.add_argument("--stop", type=int, default=None,
                   help="stop before this frame (default: the end)")
    p.add_argument("--step", type=int, default=None, help="frame step (default 1)")
    p.set_defaults(func=run)
    return p


def _open_universe(files):
    """``Universe(TOPOLOGY, TRAJECTORY)`` or ``Universe(FILE)``; a one-line
    OSError naming the argument when a file is missing or unreadable."""
    import warnings
    import MDAnalysis as mda
    if len(files) > 2:
        raise ValueError(f"FILE: expected TOPOLOGY TRAJECTORY or one file, got "
                         f"{len(files)} files")
    names = ("TOPOLOGY", "TRAJECTORY") if len(files) == 2 else ("FILE",)
    for name, path in zip(names, files):
        if not os.path.isfile(path):
            raise OSError(f"{name}: no such file {path!r}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # guessed attributes, missing masses ...
            return mda.Universe(*files)
    except Exception as exc:  # MDAnalysis raises many kinds for a bad file
        what = "FILE" if len(files) == 1 else "TOPOLOGY/TRAJECTORY"
        names = " with ".join(repr(os.path.basename(f)) for f in files)
        raise OSError(f"{what}: MDAnalysis cannot read {names}: "
                      f"{one_line(exc, 200)}") from None


def _select(u, selection, option, updating=False):
    try:
        g = u.select_atoms(selection, updating=updating)
    except Exception as exc:
        raise ValueError(f"{option}: invalid selection {selection!r}: {one_line(exc)}") from None
    if len(g) == 0 and not updating:
        raise ValueError(f"{option}: selection {selection!r} matched no atoms")
    return g


def _connect(address, timeout=10):
    try:
        from distributed import Client
    except ImportError:
        raise ValueError("--scheduler: dask.distributed is not installed "
                         "(pip install 'dask[distributed]')") from None
    try:
        return Client(address, timeout=timeout)
    except Exception as exc:  # OSError, TimeoutError, ValueError for bad addresses
        raise ValueError(f"--scheduler: cannot connect to {address!r}: "
                         f"{one_line(exc)}") from None


def run(args, out=None):
    """Run ``ase-mlg rdf`` for parsed ``args`` (see :func:`add_parser`).

    Writes the table (columns r [Å], g(r), count) to ``--output`` or
    ``out`` (default stdout), and a plot when ``--plot`` is given.  On
    stderr, one line per file written, and one note when bin 0 counted
    self pairs (InterRDF's default: each atom in both groups paired with
    itself at d = 0) saying how to drop them.  Bad input raises
    ``ValueError``/``OSError`` with a one-line message naming the
    argument.  Returns the finished :class:`RDF`.
    """
    out = sys.stdout if out is None else out
    check_rmax(args.rmax, "--rmax")
    check_nbins(args.nbins, "--nbins")
    if not (np.isfinite(args.rmin) and 0.0 <= args.rmin < args.rmax):
        raise ValueError(f"--rmin: need 0 <= rmin < rmax, got {args.rmin}")
    check_template(args.template, "--template")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers: must be >= 1, got {args.workers}")
    if args.scheduler is not None and args.backend != "serial":
        raise ValueError(f"--scheduler: runs on the cluster; drop --backend {args.backend}")
    block = args.exclusion_block
    if block is not None and min(block) < 1:
        raise ValueError(f"--exclusion-block: need two integers >= 1, got {block}")
    if args.exclude_self:
        if block is not None or args.exclude_same is not None:
            raise ValueError("--exclude-self: use it alone, not with --exclusion-block "
                             "or --exclude-same")
        if args.select2 is not None and args.select2 != args.select:
            raise ValueError("--exclude-self: needs the two groups equal (no --select2)")
        block = (1, 1)
    if block is not None and args.exclude_same is not None:
        raise ValueError("--exclude-same: cannot be combined with --exclusion-block")
    for option, path in (("--output", args.output), ("--plot", args.plot)):
        # fail before the run, not after it
        if path is not None and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            raise OSError(f"{option}: directory of {path!r} does not exist")
    u = _open_universe(args.files)
    g1 = _select(u, args.select, "--select", args.updating)
    g2 = (g1 if args.select2 is None
          else _select(u, args.select2, "--select2", args.updating))
    r = RDF(g1, g2, nbins=args.nbins, range=(args.rmin, args.rmax), norm=args.norm,
            template=args.template, exclusion_block=block,
            exclude_same=args.exclude_same)
    if args.backend == "dask":
        try:
            importlib.import_module("dask")  # only whether it imports matters here
        except ImportError:
            raise ValueError("--backend: dask is not installed") from None
    # frame 0 is checked before any work, so that the common bad file gives
    # one clean error line (non-finite coordinates, no box with --norm rdf,
    # rmax beyond the cell)
    bad = ~np.isfinite(u.atoms.positions).all(axis=1)
    if bad.any():
        raise ValueError(f"TRAJECTORY: frame 0 has non-finite coordinates for atom(s) "
                         f"{np.flatnonzero(bad)[:10].tolist()}")
    if u.dimensions is None and args.norm == "rdf":
        raise ValueError("--norm: the trajectory has no box, so g(r) (--norm rdf) is "
                         "undefined; use --norm density or --norm none")
    frames = dict(start=args.start, stop=args.stop, step=args.step)
    try:
        r.check_range()  # frame 0 now; later frames (NPT boxes) during the run
        if args.scheduler is not None:
            client = _connect(args.scheduler)
            with client:
                r.run(**frames, backend=DistributedBackend(client),
                      n_parts=args.workers)
        elif args.backend == "serial":
            # a progress bar only for a person watching a terminal
            r.run(**frames, verbose=is_tty(sys.stderr))
        else:
            r.run(**frames, backend=args.backend, n_workers=args.workers or 1)
    except ValueError as exc:
        if str(exc).startswith("range: rmax"):
            raise ValueError(f"--rmax: {one_line(exc)}") from None
        if str(exc).startswith("norm:"):
            raise ValueError(f"--norm: {one_line(exc)[6:]}") from None
        raise
    note = _self_pair_note(args, g1, g2, block)
    if note:
        print(note, file=sys.stderr)
    table = np.column_stack([r.results.bins, r.results.rdf, r.results.count])
    header = (f"ase-mlg rdf: {' '.join(args.files)}, {r.n_frames} frames, "
              f"{len(g1)} x {len(g2)} atoms, norm={args.norm}\n"
              "r/Angstrom  g(r)  count")
    if args.output is None:
        np.savetxt(out, table, fmt=("%.6f", "%.10g", "%.0f"), header=header)
    else:
        np.savetxt(args.output, table, fmt=("%.6f", "%.10g", "%.0f"), header=header)
        print(f"ase-mlg rdf: wrote {args.output} ({len(table)} rows: r/Å, g(r), "
              "count)", file=sys.stderr)
    if args.plot is not None:
        _plot(r, args.plot, f"{args.select} / {args.select2 or args.select}")
        print(f"ase-mlg rdf: wrote the plot {args.plot}", file=sys.stderr)
    return r


def _self_pair_note(args, g1, g2, block):
    """One line when bin 0 holds self pairs (an atom of both groups with
    itself, d = 0: InterRDF counts them unless excluded), else None.  For
    updating selections the atoms of both groups are counted at the frame
    the universe stands on."""
    if block is not None or args.exclude_same is not None or args.rmin > 0.0:
        return None
    both = np.intersect1d(g1.ix, g2.ix)
    if len(both) == 0:
        return None
    where = "a frame" if not args.updating else "in one frame (the selections update)"
    fix = ("add --exclude-self to drop them" if args.select2 in (None, args.select)
           else "--exclude-self needs one group; or choose disjoint selections")
    return (f"ase-mlg rdf: note: bin 0 counts {len(both)} self pairs {where} "
            f"(each atom in both groups with itself, d = 0), as MDAnalysis "
            f"InterRDF does by default; {fix}")


def _plot(r, path, label):
    # object-oriented Agg figure: no pyplot state, no display needed
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(6, 4))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.plot(r.results.bins, r.results.rdf, lw=1.5, label=label)
    ax.axhline(1.0, color="0.6", lw=0.8)
    ax.set_xlabel("r (Å)")
    ax.set_ylabel({"rdf": "g(r)", "density": "ρ(r) (Å$^{-3}$)",
                   "none": "count per frame"}[r.norm])
    ax.legend(frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
