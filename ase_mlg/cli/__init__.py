"""The ``ase-mlg`` command line.

``ase-mlg demo`` runs the package end to end on an embedded LJ argon liquid
(:mod:`ase_mlg.cli.demo`); ``ase-mlg rdf`` computes radial distribution
functions of trajectories (:mod:`ase_mlg.cli.rdf`); ``ase-mlg tradeoff``
measures the template's speed/accuracy trade (:mod:`ase_mlg.cli.tradeoff`);
``ase-mlg info`` prints the threading layer and versions in use; bare ``ase-mlg`` lists the commands, ``ase-mlg --version`` prints the
version.  Errors in user input print one line and exit with status 2.
Progress bars are drawn only when their stream is a terminal.

The library never imports this package: command-line code lives here only.
"""

import argparse
import sys

from . import rdf as _rdf
from . import tradeoff as _tradeoff
from .demo import demo
from .options import int_at_least, positive_int

__all__ = ["main", "demo"]


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage block): a CLI error is one
    line on stderr and exit status 2, like every other error here."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n")


# bare `ase-mlg` is a newcomer's first screen: what to type, and where the
# Python API is
_EPILOG = """\
examples:
  ase-mlg demo                        the package end to end (about a minute)
  ase-mlg rdf topol.tpr traj.xtc --select "name OW" --exclude-self --plot ow.png
  ase-mlg tradeoff --scene liquid     Boris's template against exact mode
  ase-mlg info                        threading layer and versions

in Python (the package is a library first):
  import ase_mlg
  from ase_mlg.potentials import LennardJones
  atoms.calc = ase_mlg.MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
  i, j, d = ase_mlg.neighbor_list("ijd", atoms, 5.0)   # ase.neighborlist's semantics
  see README.md (docs/design.md for the algorithms) and help(ase_mlg.MLGCalculator)
"""


def _parser():
    from .. import __version__
    parser = _Parser(
        prog="ase-mlg",
        description="Boris's Monotonic Logical Grid for molecular dynamics in "
                    "ASE. Run 'ase-mlg COMMAND -h' for a command's options.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version",
                        version=f"ase-mlg {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND",
                                title="commands")
    p = sub.add_parser(
        "demo", help="run the package end to end on an embedded argon liquid",
        description="Build the MLG of an LJ argon liquid, move the atoms and "
                    "repair the grid (sweeps, template quality), run NVE MD "
                    "with MLGCalculator against ASE's LennardJones, and check "
                    "the trajectory against MDAnalysis and ase.neighborlist.")
    p.add_argument("--natoms", type=positive_int, default=4000,
                   help="approximate number of atoms (default %(default)s)")
    p.add_argument("--steps", type=positive_int, default=500,
                   help="steps of liquid-like random motion to repair the grid "
                        "through (default %(default)s)")
    p.add_argument("--md-steps", type=int_at_least(0), default=200,
                   help="NVE MD steps of 5 fs with MLGCalculator; 0 skips the "
                        "MD and its checks (default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the liquid, the motion and the "
                        "momenta (default %(default)s)")
    _rdf.add_parser(sub)
    _tradeoff.add_parser(sub)
    sub.add_parser(
        "info", help="the threading layer, thread counts and versions in use",
        description="Print what ase-mlg runs with in this environment: numba's "
                    "threading layer (and why, if it is not TBB), numba's thread "
                    "count, whether a threaded probe kernel really ran on several "
                    "threads, and the versions of ase-mlg, numba, numpy, ASE and "
                    "tbb (ase_mlg.show_config() in Python).")
    return parser


def main(argv=None):
    """The ``ase-mlg`` command; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command is None:  # bare `ase-mlg`: list the commands
        parser.print_help()
        return 0
    import warnings
    try:
        # library warnings (e.g. MDAnalysis readers without time steps) are
        # not errors; a CLI error must stay one line on stderr
        warnings.simplefilter("ignore", UserWarning)
        if args.command == "demo":
            demo(args.natoms, args.steps, args.seed, md_steps=args.md_steps)
        elif args.command == "rdf":
            _rdf.run(args)
        elif args.command == "tradeoff":
            _tradeoff.run(args)
        elif args.command == "info":
            from .. import show_config
            show_config()
    except (ValueError, TypeError, OSError) as exc:
        msg = " ".join(str(exc).split())  # one line, whatever the exception said
        print(f"ase-mlg {args.command}: error: {msg}", file=sys.stderr)
        return 2
    return 0
