"""MLGCalculator: cutoff pair potentials through the MLG, as an ASE Calculator.

Per call the calculator needs the pairs within the potential's cutoff.  It
keeps one :class:`~ase_mlg.grid.MLG` for the life of the system and a pair
list built with a Verlet ``skin``:

* ``template=None`` (exact): the list holds *every* pair with
  ``d < cutoff + skin``, from the exact MLG query of :mod:`ase_mlg.query`.
  Until some atom has moved more than ``skin / 2`` since the list was built,
  no pair outside it can have come within the cutoff, so reusing it is exact.
* ``template=W`` (odd int): the list holds the pairs with
  ``d < cutoff + skin`` found in Boris's W x W x W half template
  (DESIGN 2.6).  Fast and approximate: the pairs the template misses are the
  price, and :mod:`ase_mlg.tradeoff` measures it.
* ``template="auto"``: W is the smallest width that meets ``tolerance``,
  chosen and re-checked against the exact query by
  :class:`ase_mlg.tradeoff.AutoTemplate` (see there for what is guaranteed
  at the checks and what is not between them).

When the list expires the grid is repaired by swap sweeps
(``MLG.update``), not rebuilt; it is rebuilt only when the number of atoms,
the cell or pbc change, or the sweep cap is hit.  Distance vectors are
recomputed every call from the current positions and the list's cell shifts,
``D = positions[j] - positions[i] + S @ cell``, exactly as ASE does.

Statistics (list builds, grid rebuilds, sweeps, swaps, pairs evaluated) are
in ``calc.stats``.
"""

import numpy as np
from ase.calculators.calculator import Calculator, all_changes
from ase.stress import full_3x3_to_voigt_6_stress

from .geometry import as_positions
from .grid import MLG, template_pairs
from .potentials import PairPotential, pair_vectors

__all__ = ["MLGCalculator"]


def _exact_half_pairs(grid, cutoff):
    """Every pair with d < cutoff once: (i, j, S)."""
    from .query import BlockIndex, find_pairs
    index = BlockIndex(grid)
    res = find_pairs(index, np.full(grid.natoms, cutoff), cut=cutoff,
                     half=True, quantities="ijS")
    return res["i"], res["j"], res["S"]


class MLGCalculator(Calculator):
    """Pair-potential calculator on a Monotonic Logical Grid.

    Parameters
    ----------
    potential : ase_mlg.potentials.PairPotential
        E.g. ``LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)``.
    template : None, odd int, "auto" or AutoTemplate
        ``None`` for exact pair sums; W for Boris's W x W x W template;
        ``"auto"`` to let :class:`ase_mlg.tradeoff.AutoTemplate` pick W
        (pass an ``AutoTemplate(...)`` instance to set its ``widths`` or
        ``check_every``).  ``calc.template`` is then the width in use
        (None: exact) and ``calc.auto.history`` records every check.
    tolerance : float or dict, optional
        Only with ``template="auto"``: ``{"missed": fraction of
        interacting pairs}`` and/or ``{"force": RMS force error, eV/Å}``; a
        float is the missed fraction.  Default ``{"missed": 1e-4}``.
    skin : float
        Verlet skin (Å).  The pair list is rebuilt when an atom has moved
        more than ``skin / 2``; 0 rebuilds it every call.  The default, 1 Å,
        is LAMMPS's choice for LJ (0.3 sigma); measured on LJ argon at 100 K
        (validation/bench_md.py) it ran MD 1.4-1.7x faster than ASE's 0.3 Å.
    grid_kwargs : dict, optional
        Passed to :class:`~ase_mlg.grid.MLG` (``method``, ``sweep_cap``, ...).

    Notes
    -----
    Properties: ``energy``, ``free_energy``, ``energies`` (eV),
    ``forces`` (eV/Å), ``stress`` and ``stresses`` (Voigt, eV/Å^3, ASE's
    sign), the last two only when the cell has three dimensions, as in
    ``ase.calculators.lj.LennardJones``.
    """

    implemented_properties = ["energy", "free_energy", "energies", "forces",
                              "stress", "stresses"]
    nolabel = True

    def __init__(self, potential, template=None, skin=1.0, grid_kwargs=None,
                 tolerance=None, **kwargs):
        if not isinstance(potential, PairPotential):
            raise TypeError("potential: expected an ase_mlg.potentials."
                            f"PairPotential, got {type(potential).__name__}")
        # template="auto": a policy object picks W at list builds (imported
        # here because ase_mlg.tradeoff imports this module)
        from .tradeoff import AutoTemplate
        self.auto = None
        if isinstance(template, AutoTemplate):
            if tolerance is not None:
                raise ValueError("tolerance: set it on the AutoTemplate instance")
            self.auto, template = template, None
        elif isinstance(template, str) and template == "auto":
            self.auto, template = AutoTemplate(tolerance), None
        elif tolerance is not None:
            raise ValueError("tolerance: only used with template='auto'")
        if template is not None:
            if isinstance(template, bool) or not isinstance(template, (int, np.integer)) \
                    or template < 1 or template % 2 == 0:
                raise ValueError("template: None (exact) or an odd positive int, "
                                 f"got {template!r}")
            template = int(template)
        skin = float(skin)
        if not np.isfinite(skin) or skin < 0:
            raise ValueError(f"skin: must be finite and >= 0, got {skin}")
        Calculator.__init__(self, **kwargs)
        self.potential = potential
        self.template = template
        self.skin = skin
        self.grid_kwargs = dict(grid_kwargs or {})
        self.grid = None
        self._list = None
        self.stats = {"calls": 0, "list_builds": 0, "grid_builds": 0,
                      "sweeps": 0, "swaps": 0, "grid_rebuilds": 0,
                      "pairs": 0}

    def reset(self):
        Calculator.reset(self)
        self.grid = None
        self._list = None

    # -- the pair list ------------------------------------------------------
    def _fresh_grid(self, atoms, positions):
        if (self.grid is None or self.grid.natoms != len(atoms)
                or not np.array_equal(self.grid.box.cell, atoms.cell.array)
                or not np.array_equal(self.grid.box.pbc, atoms.pbc)):
            self.grid = MLG(positions, atoms.cell.array, atoms.pbc,
                            **self.grid_kwargs)
            self.stats["grid_builds"] += 1
            return True
        return False

    def _build_list(self, atoms, positions):
        if not self._fresh_grid(atoms, positions):
            rec = self.grid.update(positions)
            self.stats["sweeps"] += rec["sweeps"]
            self.stats["swaps"] += rec["swaps"]
            self.stats["grid_rebuilds"] += int(rec["rebuilt"])
        rlist = self.potential.cutoff + self.skin
        if self.auto is not None:
            self.template = self.auto.choose(self.grid, self.potential, atoms.numbers)
        if self.template is None:
            i, j, S = _exact_half_pairs(self.grid, rlist)
        else:
            i, j, S, _ = template_pairs(self.grid, self.template, rlist)
        self._list = (i, j, S.astype(np.float64), positions.copy())
        self.stats["list_builds"] += 1

    def _list_valid(self, positions):
        if self._list is None or self.skin == 0.0:
            return False
        moved = positions - self._list[3]
        return float(np.einsum("ij,ij->i", moved, moved).max(initial=0.0)) \
            < (0.5 * self.skin) ** 2

    # -- ASE interface ------------------------------------------------------
    def check_state(self, atoms, tol=1e-15):
        """What changed since the last call (ASE's contract).

        A pair potential depends on positions, numbers, cell and pbc only, and
        exact comparison of those four costs a fifth of ASE's generic
        ``compare_atoms`` (which ran 12 ``np.isclose`` over every per-atom
        array: 3.5 ms per MD step at 10k atoms, a third of the step).  Exact
        equality is stricter than ASE's 1e-15 tolerance, so at worst a call
        is recomputed, never skipped.
        """
        old = self.atoms
        if old is None or len(old) != len(atoms):
            return list(all_changes)
        changes = []
        if not np.array_equal(old.positions, atoms.positions):
            changes.append("positions")
        if not np.array_equal(old.numbers, atoms.numbers):
            changes.append("numbers")
        if not np.array_equal(old.cell.array, atoms.cell.array):
            changes.append("cell")
        if not np.array_equal(old.pbc, atoms.pbc):
            changes.append("pbc")
        return changes

    def calculate(self, atoms=None, properties=("energy",),
                  system_changes=all_changes):
        Calculator.calculate(self, atoms, properties, system_changes)
        atoms = self.atoms
        positions = as_positions(atoms.positions)
        if self._list is not None and (
                "numbers" in system_changes or "cell" in system_changes
                or "pbc" in system_changes
                or len(positions) != len(self._list[3])):
            self._list = None
        if not self._list_valid(positions):
            self._build_list(atoms, positions)
        i, j, S, _ = self._list
        D, d = pair_vectors(positions, i, j, S, np.ascontiguousarray(atoms.cell.array))
        res = self.potential.evaluate(atoms.numbers, i, j, D, d,
                                      per_atom_virials="stresses" in properties)
        self.stats["calls"] += 1
        self.stats["pairs"] += len(i)
        self.results["energy"] = res["energy"]
        self.results["free_energy"] = res["energy"]
        self.results["energies"] = res["energies"]
        self.results["forces"] = res["forces"]
        if atoms.cell.rank == 3:
            volume = atoms.get_volume()
            self.results["stress"] = full_3x3_to_voigt_6_stress(-res["virial"] / volume)
            if "virials_voigt" in res:
                self.results["stresses"] = -res["virials_voigt"] / volume
