"""One MLG that follows a system across calls: MD steps, list builds,
trajectory frames.

Every list kept on a grid (:class:`ase_mlg.verletlist.VerletList`, for the
calculator, the neighbour lists and the RDFs) asks the same question at
each build: can the grid it holds be moved to the new positions by swap
sweeps (O(N), Boris 1985 §III), or must it be built anew (O(N log N))?
:class:`GridTracker` is the one answer:

* no grid yet, or a different number of atoms: build;
* other atoms that share most of the old ones (a rank's local system after
  migration, docs/design.md §11): ``MLG.renumber`` carries the grid over
  (the newcomers take holes near them, then the update below), or build;
* the same box (:meth:`ase_mlg.geometry.Box.same_as`: cell and pbc equal):
  ``MLG.update`` (swap sweeps; the grid itself rebuilds at its sweep cap
  or phase-lag limit);
* a new cell or pbc: with ``follow_cell=True`` the grid follows the cell
  (``MLG.update(positions, cell=, pbc=)`` rescales its coordinates, which
  keeps the order exactly under an affine change, docs/design.md §4);
  otherwise it is built anew.

The calculator follows the cell (NPT keeps one grid).  The neighbour lists
and the RDFs build anew on a new cell: their callers change cells between
unrelated structures as often as along a barostat, and their tests pin it.
"""
from .geometry import Box
from .grid import MLG

__all__ = ["GridTracker"]


class GridTracker:
    """Keeps one :class:`~ase_mlg.grid.MLG` following a system.

    Parameters
    ----------
    follow_cell : bool
        On a change of cell or pbc, let the grid follow it (True) or build
        a new grid (False).
    **grid_kwargs
        Passed to :class:`~ase_mlg.grid.MLG` at every build.

    Attributes
    ----------
    grid : MLG or None
        The grid after the last :meth:`follow` (a read-only view of its
        arrays is ``grid.view()``).
    stats : dict
        Cumulative ``grid_builds`` (new grids), ``grid_updates`` (grids
        moved by ``MLG.update``), ``sweeps``, ``swaps`` and
        ``grid_rebuilds`` (rebuilds inside ``MLG.update``: sweep cap, phase
        lag, cell rank), ``grid_carries`` (grids carried over to other
        atoms, :meth:`MLG.renumber`; counted in ``grid_updates`` too).
    """

    def __init__(self, follow_cell=True, **grid_kwargs):
        self.follow_cell = bool(follow_cell)
        self.grid_kwargs = grid_kwargs
        self.grid = None
        self.stats = {"grid_builds": 0, "grid_updates": 0, "sweeps": 0, "swaps": 0,
                      "grid_rebuilds": 0, "grid_carries": 0}

    def follow(self, positions, cell, pbc, renumber=None):
        """Move the grid to ``positions`` (Å) in ``cell`` with ``pbc``, or
        build it; returns the grid.  ``renumber``: the atoms are not those
        of the last call but share most of them (a rank's local system
        after migration): each old atom's index among ``positions`` or -1,
        and the grid is carried over (:meth:`MLG.renumber`) where it can be."""
        g = self.grid
        if g is None or (g.natoms != len(positions) if renumber is None
                         else g.natoms != len(renumber)):
            return self._build(positions, cell, pbc)
        if not (self.follow_cell or Box(cell, pbc).same_as(g.box)):
            return self._build(positions, cell, pbc)
        if renumber is not None:
            rec = g.renumber(renumber, positions, cell=cell, pbc=pbc)
            if rec is None:
                return self._build(positions, cell, pbc)
            self.stats["grid_carries"] += 1
        elif self.follow_cell:
            rec = g.update(positions, cell=cell, pbc=pbc)
        else:
            rec = g.update(positions)
        st = self.stats
        st["grid_updates"] += 1
        st["sweeps"] += rec["sweeps"]
        st["swaps"] += rec["swaps"]
        st["grid_rebuilds"] += int(rec["rebuilt"])
        return g

    def _build(self, positions, cell, pbc):
        self.grid = MLG(positions, cell, pbc, **self.grid_kwargs)
        self.stats["grid_builds"] += 1
        return self.grid

    def reset(self):
        """Forget the grid: the next :meth:`follow` builds one."""
        self.grid = None
