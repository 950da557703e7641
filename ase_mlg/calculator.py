"""MLGCalculator: cutoff pair potentials through the MLG, as an ASE Calculator.

The calculator keeps the pairs within the potential's cutoff in one
:class:`~ase_mlg.verletlist.VerletList` for the life of the system (the
grid, the list built with a Verlet ``skin``, its validity test, its row
partition), from the exact query (``template=None``), Boris's W x W x W
template (``template=W``, approximate, docs/design.md §7) or the mode
:class:`ase_mlg.autotemplate.AutoTemplate` picks (``template="auto"``).
Distance vectors are recomputed every call from the current positions and
the list's cell shifts, ``D = positions[j] - positions[i] + S @ cell``, as
ASE does.  Counts are in ``calc.stats``, each phase's time in
``calc.timings``.
"""

import time

import numpy as np
from ase.calculators.calculator import Calculator, all_changes

from .autotemplate import parse_template
from .geometry import as_positions
from .potentials import PairPotential
from .verletlist import VerletList

__all__ = ["MLGCalculator"]

_CALCULATOR_KWARGS = {"label", "atoms", "directory"}


class MLGCalculator(Calculator):
    """Pair-potential calculator on a Monotonic Logical Grid.

    Parameters
    ----------
    potential : ase_mlg.potentials.PairPotential
        E.g. ``LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)``.
    template : None, odd int, "auto" or AutoTemplate
        ``None`` for exact pair sums; W for Boris's W x W x W template;
        ``"auto"`` (or an ``AutoTemplate(...)``) to let the policy pick;
        ``calc.template`` is the width in use (None: exact).
    tolerance : float or dict, optional
        Only with ``template="auto"``: ``{"missed": fraction of interacting
        pairs}`` and/or ``{"force": RMS force error, eV/Å}``; a float is the
        missed fraction.  Default ``{"missed": 1e-4}``.
    skin : float
        Verlet skin (Å); 0 rebuilds the list every call.  The default, 1 Å,
        is LAMMPS's choice for LJ (0.3 sigma); on LJ argon at 100 K
        (validation/bench_md.py) it ran MD 1.4-1.7x faster than ASE's 0.3 Å.
    grid_kwargs : dict, optional
        Passed to :class:`~ase_mlg.grid.MLG` (``method``, ``sweep_cap``, ...).

    Notes
    -----
    Properties: ``energy``, ``free_energy``, ``energies`` (eV), ``forces`` (eV/Å),
    ``stress`` and ``stresses`` (Voigt, eV/Å^3, ASE's sign; only for a cell of
    three dimensions), as ``ase.calculators.lj.LennardJones``.
    """

    implemented_properties = ["energy", "free_energy", "energies", "forces",
                              "stress", "stresses"]
    nolabel = True

    def __init__(self, potential, template=None, skin=1.0, grid_kwargs=None,
                 tolerance=None, **kwargs):
        if not isinstance(potential, PairPotential):
            raise TypeError("potential: expected an ase_mlg.potentials."
                            f"PairPotential, got {type(potential).__name__}")
        self.auto, template = parse_template(template, tolerance)
        unknown = sorted(set(kwargs) - _CALCULATOR_KWARGS)
        if unknown:
            # ASE's calculators store unknown keywords as parameters and
            # ignore them; a neighbour-list hook ignored would be a silent
            # wrong answer
            raise TypeError(
                f"MLGCalculator: unexpected keyword argument(s) {', '.join(map(repr, unknown))}"
                f"; MLGCalculator takes potential, template, skin, grid_kwargs, tolerance, "
                f"{', '.join(sorted(_CALCULATOR_KWARGS))} (it finds its own pairs on its MLG; "
                f"the potential's parameters go to the potential, e.g. Morse(epsilon=..., r0=...))")
        self._tolerance = tolerance
        self.grid_kwargs = dict(grid_kwargs or {})
        # the list keeps d < rc + skin; the potential keeps d <= rc (closed)
        self.verlet_list = VerletList(
            potential.cutoff, skin, closed=True,
            template=template if self.auto is None else self._choose,
            types=self._types_of,
            grid_kwargs=self.grid_kwargs)  # NPT keeps one grid: it follows the cell
        Calculator.__init__(self, **kwargs)
        self.potential = potential
        self.template = template
        self.skin = self.verlet_list.skin
        self._stress_wanted = False
        self._counts = dict.fromkeys(("calls", "pairs", "threads_used"), 0)
        self._kernel_seconds = 0.0

    def _types_of(self, numbers):
        return self.potential.prepare(numbers)[0]

    def _choose(self, grid, numbers):
        self.template = self.auto.choose(grid, self.potential, numbers)
        return self.template

    @property
    def grid(self):
        """The :class:`~ase_mlg.grid.MLG` the calculator keeps (None before
        the first call or after :meth:`reset`)."""
        return self.verlet_list.grid

    @property
    def stats(self):
        """``calls``, ``pairs`` (summed over calls), ``threads_used`` (by the
        last force kernel) and :attr:`VerletList.stats <ase_mlg.verletlist.VerletList.stats>`."""
        return {**self._counts, **self.verlet_list.stats}

    @property
    def timings(self):
        """Cumulative seconds of the list's phases (``check``, ``list_build``,
        ``grid``: :attr:`VerletList.timings <ase_mlg.verletlist.VerletList.timings>`),
        of the pair sum (``kernel``), and the number of ``calls``."""
        return {**self.verlet_list.timings, "kernel": self._kernel_seconds,
                "calls": float(self._counts["calls"])}

    def reset(self):
        Calculator.reset(self)
        if hasattr(self, "verlet_list"):
            self.verlet_list.reset()

    def check_state(self, atoms, tol=1e-15):
        """What changed since the last call (ASE's contract), by exact
        comparison of what a pair potential reads: a fifth of the cost of
        ASE's ``compare_atoms`` (a third of an MD step at 10^4 atoms), and
        stricter than its tolerance, so a call is at worst recomputed."""
        old = self.atoms
        if old is None or len(old) != len(atoms):
            return list(all_changes)
        return [name for name, a, b in (
            ("positions", old.positions, atoms.positions),
            ("numbers", old.numbers, atoms.numbers),
            ("cell", old.cell.array, atoms.cell.array),
            ("pbc", old.pbc, atoms.pbc)) if not np.array_equal(a, b)]

    def calculate(self, atoms=None, properties=("energy",),
                  system_changes=all_changes):
        # what changed is decided from the atoms by the list, not from
        # system_changes (ASE's get_properties passes all_changes, which
        # would drop a valid list on every call).  The stored atoms are
        # brought up to date in place when only positions or cell moved
        # (every MD step), not copied whole as ASE does: 0.5 ms at 10^5 atoms
        if atoms is not None:
            changes = list(all_changes) if self.atoms is None else self.check_state(atoms)
            if "numbers" in changes or "pbc" in changes:  # also: another length
                self.atoms = atoms.copy()
            elif changes:
                self.atoms.positions[:] = atoms.positions
                if "cell" in changes:
                    self.atoms.cell = atoms.cell.copy()
        atoms = self.atoms
        positions = atoms.positions
        if not (positions.dtype == np.float64 and positions.ndim == 2
                and positions.shape[1] == 3 and positions.flags.c_contiguous):
            positions = as_positions(positions)
        # NaN/inf positions fail the list's test, and the grid names the atoms
        cell, vl = atoms.cell.array, self.verlet_list
        vl.update(positions, cell, atoms.pbc, atoms.numbers)
        t0 = time.perf_counter()
        pl, chunks = vl.pairs, vl.row_partition()
        # the virial costs a tenth of the loop: only for callers that ask
        # for stress (once asked, always: barostats ask after the forces)
        self._stress_wanted |= "stress" in properties or "stresses" in properties
        res = self.potential.sum_pairs(
            vl.X, vl.types, pl.rowptr, pl.nbr, pl.code, vl.svec, pl.order,
            energies="energies" in properties, virials="stresses" in properties,
            virial=self._stress_wanted, chunks=chunks)
        self._kernel_seconds += time.perf_counter() - t0
        c = self._counts
        c.update(calls=c["calls"] + 1, pairs=c["pairs"] + len(pl), threads_used=chunks.threads_used())
        self.results.update(energy=res["energy"], free_energy=res["energy"],
                            forces=res["forces"])
        if "energies" in res:
            self.results["energies"] = res["energies"]
        if atoms.cell.rank == 3 and "virial" in res:
            volume = abs(np.linalg.det(cell))
            self.results["stress"] = -res["virial"] / volume
            if "virials_voigt" in res:
                self.results["stresses"] = -res["virials_voigt"] / volume

    def todict(self):
        """The calculator's parameters, JSON-serialisable: what .traj, .db
        and .json files record (ASE calls this)."""
        d = {"potential": self.potential.todict(),
             "template": "auto" if self.auto is not None else self.template,
             "skin": self.skin}
        if self._tolerance is not None:
            d["tolerance"] = self._tolerance
        if self.grid_kwargs:
            d["grid_kwargs"] = dict(self.grid_kwargs)
        return d

    def __repr__(self):
        rest = ", ".join(f"{k}={v!r}" for k, v in self.todict().items() if k != "potential")
        return f"MLGCalculator({self.potential!r}, {rest})"
