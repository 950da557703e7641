"""``ase-mlg tradeoff``: measure Boris's template against exact mode from the
command line (:func:`ase_mlg.tradeoff.measure`; docs/design.md §7).

Numbers are read as text and checked in :func:`run`, so every bad value
becomes a one-line ``ValueError`` naming its option (``ase-mlg`` prints it
and exits with status 2).
"""

import inspect
import os
import sys

from ..autotemplate import parse_widths
from ..calculator import MLGCalculator
from ..potentials import LennardJones, Morse
from ..scenes import make_scene
from ..tradeoff import CLOCKS, check_number, measure, plot_tradeoff

__all__ = ["add_parser", "run", "POTENTIALS"]

POTENTIALS = ("lj", "morse")


def _options(skin):
    """The options after STRUCTURE_FILE, in the order ``-h`` lists them:
    ``(flag, default, help, other add_argument keywords)``.  ``skin`` is
    the default of ``--skin``, Å."""
    return [
        ("--scene", None, "built-in scene: liquid (the default when no "
         "STRUCTURE_FILE is given), copper, gas, nanoparticle, sheared, slab, "
         "small, mixture", {}),
        ("--natoms", "4000", "approximate size of a built-in scene (default "
         "%(default)s)", {}),
        ("--cutoff", None, "cutoff radius, Å (default: 2.5 sigma for LJ, 2.7 r0 "
         "for Morse, ASE's Morse default)", {"metavar": "RC"}),
        ("--potential", "lj", "lj (default) or morse", {}),
        ("--sigma", "3.405", "LJ sigma, Å (default %(default)s, argon)", {}),
        ("--epsilon", None, "well depth, eV (default: LJ 0.0104, argon; Morse "
         "0.35)", {}),
        ("--smooth", False, "LJ with ASE's smooth cutoff function (default: "
         "shifted)", {"action": "store_true"}),
        ("--r0", "2.55", "Morse r0, Å (default %(default)s)", {}),
        ("--rho0", "6.0", "Morse rho0 (default %(default)s)", {}),
        ("--widths", "3,5,7,9,11", "comma-separated odd template widths "
         "(default %(default)s)", {}),
        ("--md", "0", "NVE VelocityVerlet steps per mode (default %(default)s: "
         "no MD)", {"metavar": "STEPS"}),
        ("--timestep", "2.0", "MD time step, fs (default %(default)s)", {}),
        ("--temperature", "100", "initial MD temperature, K (default "
         "%(default)s)", {}),
        ("--skin", str(skin), "MD Verlet skin, Å (default %(default)s, the same "
         "as MLGCalculator's)", {}),
        ("--repeats", "5", "timed repeats, the median is reported (default "
         "%(default)s)", {}),
        ("--seed", "0", "seed of the MD momenta (default %(default)s)", {}),
        ("--clock", "wall", "wall (default) or cpu: CPU time of the process, "
         "robust on a loaded machine with NUMBA_NUM_THREADS=1", {}),
        ("--json", False, "print JSON instead of the table",
         {"action": "store_true"}),
        ("--plot", None, "write tradeoff.png into DIR (created if missing)",
         {"metavar": "DIR"}),
    ]


def add_parser(subparsers):
    """Add ``tradeoff`` to an argparse ``subparsers`` object.

    Numbers are read as strings and checked by :func:`run`, so every bad
    value becomes a one-line ``ValueError`` naming the argument.
    """
    # the MD runs use the calculator's own default skin unless told otherwise
    skin = inspect.signature(MLGCalculator.__init__).parameters["skin"].default
    p = subparsers.add_parser(
        "tradeoff",
        help="measure template width W against exact mode: missed pairs, "
             "energy/force errors, time, NVE drift",
        description="Measure Boris's template (W = 3..11) against exact mode on "
                    "a structure file (any format ase.io.read reads) or a "
                    "built-in scene; with no arguments, the LJ argon liquid "
                    "(rho* 0.8) at rc = 2.5 sigma. Template mode sees one image "
                    "per pair.")
    p.add_argument("structure", nargs="?", metavar="STRUCTURE_FILE",
                   help="structure file readable by ase.io.read (its last "
                        "frame); instead of --scene")
    for flag, default, text, keywords in _options(skin):
        p.add_argument(flag, default=default, help=text, **keywords)
    return p


def _potential_from_args(args, cutoff):
    name = str(args.potential).lower()
    if name not in POTENTIALS:
        raise ValueError(f"--potential: expected one of {', '.join(POTENTIALS)}, "
                         f"got {args.potential!r}")
    if name == "lj":
        eps = 0.0104 if args.epsilon is None else args.epsilon
        return LennardJones(sigma=check_number(args.sigma, "--sigma", minimum=0, strict=True),
                            epsilon=check_number(eps, "--epsilon", minimum=0),
                            rc=cutoff, smooth=bool(args.smooth))
    eps = 0.35 if args.epsilon is None else args.epsilon
    r0 = check_number(args.r0, "--r0", minimum=0, strict=True)
    # Morse's cutoff is given in units of r0; keep ASE's ratio 1.9 / 2.7
    # between the start and the end of the cutoff function
    return Morse(epsilon=check_number(eps, "--epsilon", minimum=0), r0=r0,
                 rho0=check_number(args.rho0, "--rho0", minimum=0, strict=True),
                 rcut1=cutoff / r0 * 1.9 / 2.7, rcut2=cutoff / r0)


def _atoms_from_args(args):
    if (args.structure is None) == (args.scene is None):
        raise ValueError("STRUCTURE_FILE/--scene: give exactly one of a structure "
                         "file or --scene NAME")
    if args.scene is not None:
        natoms = check_number(args.natoms, "--natoms", int, minimum=0)
        if natoms < 1:
            raise ValueError(f"--natoms: must be >= 1, got {args.natoms!r}")
        try:
            return make_scene(args.scene, natoms), args.scene
        except ValueError as exc:
            raise ValueError(f"--scene: {exc}") from None
    from ase.io import read
    try:
        atoms = read(args.structure)
    except Exception as exc:  # ase.io raises many kinds for unreadable files
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"STRUCTURE_FILE: cannot read {args.structure!r}: {msg}") from None
    if isinstance(atoms, list):
        atoms = atoms[-1]
    if len(atoms) == 0:
        raise ValueError(f"STRUCTURE_FILE: {args.structure!r} holds no atoms")
    return atoms, str(args.structure)


def _parse_widths_text(text):
    try:
        values = [int(w) for w in str(text).split(",") if w.strip()]
    except ValueError:
        raise ValueError(f"--widths: expected comma-separated odd ints, got {text!r}") from None
    try:
        return parse_widths(values)
    except ValueError:
        raise ValueError(f"--widths: expected comma-separated odd positive ints, "
                         f"got {text!r}") from None


#: What each column of the table means (printed under it).
KEY = {
    "W": "template width (W x W x W sites), or exact mode",
    "pairs": "interacting pairs the mode finds (d < cutoff)",
    "missed": "fraction of the exact query's interacting pairs the mode misses",
    "closest miss Å": "distance of the closest missed pair (Boris's close uncounter)",
    "dE eV/atom": "energy error per atom against exact mode",
    "F rms eV/Å": "RMS over atoms of |F - F_exact|",
    "F max eV/Å": "largest |F - F_exact|",
    "search ms": "pair search alone (template scan or exact query)",
    "call ms": "one force call that builds its list (grid update, search, pair sum; skin 0)",
    "call/exact": "call ms / exact mode's call ms",
    "drift eV/atom/ps": "NVE drift: least-squares slope of the total energy per atom",
    "max|dE| eV/atom": "largest deviation of the total energy per atom in the run",
    "step ms": "median MD step with the skin list",
    "missed@end": "missed fraction on the grid the MD run carried to its end",
}


def key_lines(result):
    """The key to ``result.table()``'s columns, one line each."""
    heads = [h for h, *_ in result.columns()]
    width = max(len(h) for h in heads)
    return ["columns:"] + [f"  {h.ljust(width)}  {KEY[h]}" for h in heads]


def run(args, out=None):
    """Run ``ase-mlg tradeoff`` for parsed ``args``; print the table with
    the key to its columns (or JSON) to ``out`` (default stdout) and write
    the plot if asked.

    Returns
    -------
    TradeoffResult

    Raises
    ------
    ValueError
        One line naming the bad argument.
    """
    out = out or sys.stdout
    if args.structure is None and args.scene is None:
        args.scene = "liquid"  # the default: the LJ argon liquid
    if args.cutoff is None:
        # default: 2.5 sigma for LJ, ASE's Morse cutoff 2.7 r0 for Morse
        if str(args.potential).lower() == "morse":
            args.cutoff = 2.7 * check_number(args.r0, "--r0", minimum=0, strict=True)
        else:
            args.cutoff = 2.5 * check_number(args.sigma, "--sigma", minimum=0, strict=True)
    cutoff = check_number(args.cutoff, "--cutoff", minimum=0, strict=True)
    widths = _parse_widths_text(args.widths)
    md = check_number(args.md, "--md", int, minimum=0)
    timestep = check_number(args.timestep, "--timestep", minimum=0, strict=True)
    temperature = check_number(args.temperature, "--temperature", minimum=0)
    skin = check_number(args.skin, "--skin", minimum=0)
    repeats = check_number(args.repeats, "--repeats", int, minimum=0)
    if repeats < 1:
        raise ValueError(f"--repeats: must be >= 1, got {args.repeats!r}")
    seed = check_number(args.seed, "--seed", int, minimum=0)
    if args.clock not in CLOCKS:
        raise ValueError(f"--clock: expected one of {', '.join(CLOCKS)}, got {args.clock!r}")
    if args.plot is not None and os.path.exists(args.plot) and not os.path.isdir(args.plot):
        raise ValueError(f"--plot: {args.plot!r} exists and is not a directory")
    potential = _potential_from_args(args, cutoff)
    atoms, label = _atoms_from_args(args)
    result = measure(atoms, potential, widths=widths, md_steps=md,
                     timestep_fs=timestep, temperature_K=temperature, skin=skin,
                     repeats=repeats, seed=seed, label=label, clock=args.clock)
    if args.json:
        print(result.to_json(indent=1), file=out)
    else:
        print(result.table(), file=out)
        print("\n".join(key_lines(result)), file=out)
    if args.plot is not None:
        os.makedirs(args.plot, exist_ok=True)
        path = plot_tradeoff(result, os.path.join(args.plot, "tradeoff.png"))
        if not args.json:
            print(f"plot: {path}", file=out)
    return result
