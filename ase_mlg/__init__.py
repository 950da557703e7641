"""ase-mlg: Boris's Monotonic Logical Grid for molecular dynamics in ASE.

Public names: :class:`MLG` (the grid), and -- as they land -- the
neighbour-list drop-ins and the calculator.
"""

from .grid import MLG

__version__ = "0.1.0"
__all__ = ["MLG"]
