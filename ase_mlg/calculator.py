"""MLGCalculator: cutoff pair potentials through the MLG, as an ASE Calculator.

The calculator keeps the pairs within the potential's cutoff in one
:class:`~ase_mlg.verletlist.VerletList` for the life of the system, from
the exact query (``template=None``), Boris's W x W x W template
(``template=W``, approximate, docs/design.md §7) or the mode
:class:`ase_mlg.autotemplate.AutoTemplate` picks (``template="auto"``).
Distances are recomputed every call from the current positions and the
list's cell shifts, as ASE does.
"""

import time
from types import MappingProxyType

import numpy as np
from ase.calculators.calculator import Calculator, all_changes

from .geometry import as_positions, same, state_key, stored_atoms
from .ranks import RankEngine, is_distributed
from .settings import changed_settings, check_settings, record, refuse_unknown, setting
from .verletlist import VerletList

__all__ = ["MLGCalculator"]

_CALCULATOR_KWARGS = {"label", "atoms", "directory"}


class MLGCalculator(Calculator):
    """Pair-potential calculator on a Monotonic Logical Grid.

    Parameters
    ----------
    potential : ase_mlg.potentials.PairPotential
        E.g. ``LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)``.
    template : None, odd int >= 3, "auto" or AutoTemplate
        ``None`` for exact pair sums; W for Boris's W x W x W template;
        ``"auto"`` (or an ``AutoTemplate(...)``) to let the policy pick;
        ``calc.template`` is the width in use (None: exact).
    tolerance : float or dict, optional
        Only with ``template="auto"``: ``{"missed": fraction of interacting
        pairs, < 1}`` and/or ``{"force": RMS force error, eV/Å}``; a float is
        the missed fraction.  Default ``{"missed": 1e-4}``.
    skin : float
        Verlet skin (Å); 0 rebuilds the list every call.  The default, 1 Å,
        is LAMMPS's for LJ (0.3 sigma): MD 1.4-1.7x faster than ASE's 0.3 Å.
    grid_kwargs : dict, optional
        Passed to :class:`~ase_mlg.grid.MLG` (``method``, ``sweep_cap``, ...).

    Notes
    -----
    Properties: ``energy``, ``free_energy``, ``energies`` (eV), ``forces`` (eV/Å),
    ``stress`` and ``stresses`` (Voigt, eV/Å^3, ASE's sign; only for a cell of
    three dimensions), as ``ase.calculators.lj.LennardJones``.

    A setting takes effect or is refused (:mod:`ase_mlg.settings`):
    ``calc.set(skin=0.5, sigma=3.0)`` or ``calc.potential = Morse(...)``
    drops the results and the list (ASE's reset semantics).
    """

    implemented_properties = ["energy", "free_energy", "energies", "forces", "stress", "stresses"]
    nolabel = True

    def __init__(self, potential, template=None, skin=1.0, grid_kwargs=None,
                 tolerance=None, **kwargs):
        refuse_unknown(kwargs, _CALCULATOR_KWARGS)
        self._configure(dict(potential=potential, template=template, tolerance=tolerance,
                             skin=skin, grid_kwargs=grid_kwargs))
        Calculator.__init__(self, **kwargs)
        # the stored atoms are ours, updated in place (stored_atoms): ASE's
        # copy before every calculation took a fifth of a call at 256 atoms
        self.use_cache, self._stored, self._stress_wanted = False, None, False
        self._counts, self._last_chunks = dict.fromkeys(("calls", "pairs"), 0), None
        self._kernel_seconds = 0.0

    def _configure(self, settings):
        """Put the checked settings in force with a new list (or refuse them)."""
        settings, auto, width = check_settings(settings)
        # the list keeps d < rc + skin; the potential keeps d <= rc (closed)
        vl = VerletList(settings["potential"].cutoff, settings["skin"], closed=True,
                        template=width if auto is None else self._choose,
                        types=self._types_of,
                        grid_kwargs=settings["grid_kwargs"])  # NPT: the grid follows the cell
        self._settings, self.auto, self._width, self.verlet_list = settings, auto, width, vl
        self._ranks = None  # a distributed system's engine (ase_mlg.ranks), made when needed

    def set(self, **kwargs):
        """Change settings (:data:`~ase_mlg.settings.SETTINGS`) or the potential's
        arguments (``sigma=``: a new potential of its kind); returns the changed
        ones, and drops the results and the list (ASE's LJ keeps its results
        until the atoms change).  A refused value changes nothing."""
        if not kwargs:
            return {}
        changed, settings = changed_settings(self._settings, kwargs)
        if changed:
            self._configure(settings)
            Calculator.reset(self)
        return changed

    potential = setting("potential", "The pair potential.")
    skin = setting("skin", "Verlet skin, Å.")
    tolerance = setting("tolerance", "The ``template='auto'`` tolerance (None: its default).")
    grid_kwargs = setting("grid_kwargs", "What the grid is built with (a read-only view).",
                          view=MappingProxyType)

    template = property(lambda self: self._width, lambda self, v: self.set(template=v),
                        doc="The template width in use (None: exact); assigning None, W, "
                            "'auto' or an AutoTemplate is ``calc.set(template=...)``.")

    _types_of = lambda self, z: self.potential.prepare(z)[0]  # noqa: E731 (the potential in force)

    def _choose(self, grid, numbers):
        self._width = self.auto.choose(grid, self.potential, numbers)
        return self._width

    grid = property(lambda self: self.verlet_list.grid, doc="The MLG kept (None before a call).")

    stats = property(lambda self: {**self._counts, "threads_used": 0 if self._last_chunks is None
                                   else self._last_chunks.threads_used(), **self.verlet_list.stats},
                     doc="``calls``, ``pairs`` (summed), ``threads_used`` (last call), the list's.")

    timings = property(lambda self: {**self.verlet_list.timings, "kernel": self._kernel_seconds,
                                     "calls": float(self._counts["calls"])},
                       doc="Seconds of the list's phases (``check``, ``list_build``, ``grid``), "
                           "of the pair sum (``kernel``), and the number of ``calls``.")

    def reset(self):
        Calculator.reset(self)
        self.verlet_list.reset()
        self._ranks = self._stored = None

    def check_state(self, atoms, tol=1e-15):
        """What changed since the last call (ASE's contract), compared exactly (at worst
        a call is repeated), agreed by all ranks: one computing alone would wait forever."""
        old = self.atoms
        if old is None or len(old) != len(atoms):
            changes = list(all_changes)
        else:  # numbers, cell, pbc: one key of bytes (stored_atoms), then which changed
            a, b = old.arrays, atoms.arrays
            changes = [] if same(a["positions"], b["positions"]) else ["positions"]
            if getattr(old, "mlg_key", None) != state_key(atoms):
                changes += [k for k, x, y in (("numbers", a["numbers"], b["numbers"]),
                                              ("cell", old.cell.array, atoms.cell.array),
                                              ("pbc", old.pbc, atoms.pbc)) if not same(x, y)]
        return RankEngine.union(atoms.comm, changes) if is_distributed(atoms) else changes

    def calculate(self, atoms=None, properties=("energy",),
                  system_changes=all_changes):
        # the virial costs a tenth of the loop: only once stress was asked for
        self._stress_wanted |= "stress" in properties or "stresses" in properties
        want = dict(energies="energies" in properties, virials="stresses" in properties,
                    virial=self._stress_wanted)
        if is_distributed(atoms):  # the engine refuses a template at any rank count
            self._ranks = self._ranks or RankEngine(self.potential, self.skin, self.grid_kwargs,
                                                    "auto" if self.auto else self._width)
        if is_distributed(atoms) and atoms.comm.size > 1:  # one rank: no ghosts, serial's path
            res = self._ranks.calculate(atoms, system_changes, **want)
            self.atoms = self._stored = stored_atoms(self._stored, atoms, res["moved_only"])
        else:
            res = self._calculate_here(atoms, want, system_changes)
        self.results.update(energy=res["energy"], free_energy=res["energy"],
                            forces=res["forces"])
        if "energies" in res:
            self.results["energies"] = res["energies"]
        if "virial" in res and self.atoms.cell.rank == 3:
            volume = abs(np.linalg.det(self.atoms.cell.array))
            self.results["stress"] = -res["virial"] / volume
            if "virials_voigt" in res:
                self.results["stresses"] = -res["virials_voigt"] / volume

    def _calculate_here(self, atoms, want, system_changes):
        changed = {*system_changes}  # ASE's, trusted: the stored atoms in place (0.5 ms at 10^5)
        atoms = self._stored = stored_atoms(self._stored, self.atoms if atoms is None else atoms,
                                            positions_only=changed <= {"positions"})
        self.atoms = None  # until the list holds them: a call failing on the way sees all next
        positions = atoms.positions  # NaN/inf fail the list's test; the grid names the atoms
        if not (positions.dtype == np.float64 and positions.flags.c_contiguous):
            positions = as_positions(positions)
        cell, vl = atoms.cell.array, self.verlet_list
        self._last_chunks = None  # its buffers die with its list (+12 % of the peak at 10^6)
        vl.update(positions, cell, atoms.pbc, atoms.numbers, numbers_same="numbers" not in changed,
                  box_same=not changed & {"cell", "pbc"})
        self.atoms = atoms
        t0 = time.perf_counter()
        pl, chunks = vl.pairs, vl.chunks()
        res = self.potential.sum_pairs(vl.X, vl.types, pl.rowptr, pl.nbr, pl.code, vl.svec,
                                       pl.order, chunks=chunks, **want)
        self._kernel_seconds += time.perf_counter() - t0
        c = self._counts
        c.update(calls=c["calls"] + 1, pairs=c["pairs"] + len(pl))
        self._last_chunks = chunks
        return res

    def todict(self):
        """The settings in force, JSON-serialisable (what .traj, .db, .json record)."""
        return record(self._settings, self.auto is not None, self._width)

    def __repr__(self):
        rest = ", ".join(f"{k}={v!r}" for k, v in self.todict().items() if k != "potential")
        return f"MLGCalculator({self.potential!r}, {rest})"
