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
  (docs/design.md §7).  Fast and approximate: the pairs the template misses are the
  price, and :mod:`ase_mlg.tradeoff` measures it.
* ``template="auto"``: the fastest mode that meets ``tolerance``, exact mode
  included, as timed and re-checked against the exact query by
  :class:`ase_mlg.autotemplate.AutoTemplate` (see there for what is guaranteed
  at the checks and what is not between them).

When the list expires the grid is repaired by swap sweeps
(``MLG.update``), not rebuilt; it follows a changing cell (NPT) by rescaling
its stored coordinates, and is rebuilt only when the number of atoms or pbc
change, the cell degenerates, or the sweep cap is hit.  The force kernel's
unit of parallel work is :class:`ase_mlg.partition.RowChunks`, kept with the
list.  Distance vectors are
recomputed every call from the current positions and the list's cell shifts,
``D = positions[j] - positions[i] + S @ cell``, exactly as ASE does.

Statistics (list builds, grid rebuilds, sweeps, swaps, pairs evaluated, the
numba threads that ran the last force kernel) are in ``calc.stats``, the
time of each phase of a call in ``calc.timings``.
"""

import time

import numpy as np
from ase.calculators.calculator import Calculator, all_changes

from .autotemplate import AutoTemplate
from .geometry import as_positions
from .template import template_pairs
from .pairsum import shift_vectors
from .potentials import PairPotential
from .blocks import BlockIndex, block_for_radius
from .parallel import threads_for
from .partition import row_chunks
from .query import half_list, pair_list
from .tracker import GridTracker

__all__ = ["MLGCalculator"]


_EYE = np.eye(3)
_CALCULATOR_KWARGS = {"label", "atoms", "directory"}
# An atom that moved this many list radii since the list was built, or ten
# times the cell edges, has been sent flying (an exploding MD run), not moved.
ABSURD_LISTS = 100.0


class MLGCalculator(Calculator):
    """Pair-potential calculator on a Monotonic Logical Grid.

    Parameters
    ----------
    potential : ase_mlg.potentials.PairPotential
        E.g. ``LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)``.
    template : None, odd int, "auto" or AutoTemplate
        ``None`` for exact pair sums; W for Boris's W x W x W template;
        ``"auto"`` to let :class:`ase_mlg.autotemplate.AutoTemplate` pick W
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
        unknown = sorted(set(kwargs) - _CALCULATOR_KWARGS)
        if unknown:
            # ASE's calculators store unknown keywords as parameters and
            # ignore them; a neighbour-list hook ignored would be a silent
            # wrong answer
            raise TypeError(f"MLGCalculator: unexpected keyword argument(s) "
                            f"{', '.join(map(repr, unknown))}; MLGCalculator takes "
                            f"potential, template, skin, grid_kwargs, tolerance, "
                            f"{', '.join(sorted(_CALCULATOR_KWARGS))} (it finds its "
                            f"own pairs on its MLG; the potential's parameters go "
                            f"to the potential, e.g. Morse(epsilon=..., r0=...))")
        self._tolerance = tolerance
        Calculator.__init__(self, **kwargs)
        self.potential = potential
        self.template = template
        self.skin = skin
        self.grid_kwargs = dict(grid_kwargs or {})
        # NPT keeps one grid: it follows the cell (docs/design.md §4)
        self._tracker = GridTracker(follow_cell=True, **self.grid_kwargs)
        self._list = None
        self._chunks = None
        self._chunk_threads = 0
        self._stress_wanted = False
        self.stats = {"calls": 0, "list_builds": 0, "grid_builds": 0,
                      "sweeps": 0, "swaps": 0, "grid_rebuilds": 0,
                      "pairs": 0, "threads_used": 0}
        #: Cumulative wall time (s) of each phase of :meth:`calculate`:
        #: ``check`` (positions to row order and the list-validity test, one
        #: pass), ``list_build`` (rebuilds, the grid's part included),
        #: ``grid`` (grid updates and sweeps), ``kernel`` (the pair sum),
        #: and ``calls``.
        self.timings = dict.fromkeys(("check", "list_build", "grid",
                                      "kernel", "calls"), 0.0)

    @property
    def grid(self):
        """The :class:`~ase_mlg.grid.MLG` the calculator keeps (None before
        the first call or after :meth:`reset`)."""
        return self._tracker.grid

    def reset(self):
        Calculator.reset(self)
        self._tracker.reset()
        self._list = self._chunks = None

    # -- the pair list ------------------------------------------------------
    def _update_grid(self, atoms, positions):
        t = self._tracker
        t0 = time.perf_counter()
        t.follow(positions, atoms.cell.array, atoms.pbc)
        self.timings["grid"] += time.perf_counter() - t0
        self.stats.update(grid_builds=t.stats["builds"], sweeps=t.stats["sweeps"],
                          swaps=t.stats["swaps"], grid_rebuilds=t.stats["rebuilds"])

    def _build_list(self, atoms, positions):
        """Build the pair list; returns the positions in row order and the
        shift vectors it was partitioned with (the force call's inputs)."""
        old, self._list, self._chunks = self._list, None, None
        self._update_grid(atoms, positions)
        rc = self.potential.cutoff
        # the query keeps d < rlist; the potential keeps d <= rc
        rlist = rc + self.skin if self.skin > 0 else float(np.nextafter(rc, np.inf))
        if self.auto is not None:
            self.template = self.auto.choose(self.grid, self.potential, atoms.numbers)
        index = BlockIndex(self.grid, block_for_radius(self.grid, rlist))
        n = len(atoms)
        if self.template is None:
            hint = None if old is None or old.natoms != n else len(old) / max(n, 1)
            # pairs within rc first in each row, straight from the scan
            pl = half_list(index, np.full(n, rlist), cut=rlist,
                           pairs_per_atom=hint, reuse=old, split=rc)
        else:
            i, j, S, _ = template_pairs(self.grid, self.template, rlist)
            pl = pair_list(index, i, j, S)
        del old, index
        # the positions then, in row order (the validity test's reference),
        # and the kernel's positions through the per-call gather, so that it
        # is compiled or loaded here, not in the first call after
        ref = np.ascontiguousarray(positions[pl.order])
        X = pl.positions(positions, atoms.cell.array)
        svec = shift_vectors(pl.shifts, atoms.cell.array)
        if self.template is not None:
            pl.partition(X, svec, rc)  # the exact scan ordered its rows itself
        self._types = np.ascontiguousarray(self.potential.prepare(atoms.numbers)[0][pl.order])
        self._numbers = atoms.numbers.copy()
        self._pbc = atoms.pbc.copy()
        self._ref = ref
        self._ref_cell = atoms.cell.array.copy()
        self._rlist = rlist
        self._list = pl
        self.stats["list_builds"] += 1
        return X, svec

    def _valid_positions(self, positions, cell):
        """Positions in row order if the list still holds every pair within
        the cutoff, else None.

        A pair left out was at ``d0 >= rlist`` when the list was built.
        With ``M`` the affine map of the cell since then and ``u`` each
        atom's displacement beyond it, its distance now is at least
        ``smin(M) d0 - 2 max|u|`` (``smin`` the smallest singular value of
        M: the triangle inequality), so the list is valid while
        ``smin(M) rlist - 2 max|u| > rc``.  At fixed cell that is the usual
        Verlet test ``max|u| < skin / 2``; under NPT the skin covers
        displacement and strain together.  (LAMMPS's ``check_distance``
        bounds the strain by the box corners' displacement instead.)
        """
        if self._list is None:
            return None
        ref_cell = self._ref_cell
        if np.array_equal(cell, ref_cell):
            M, smin = _EYE, 1.0
        elif self.auto is not None:
            return None  # template="auto" re-checks its width when the cell changes
        elif abs(np.linalg.det(ref_cell)) < 1e-12 * max(np.abs(ref_cell).max(), 1.0) ** 3:
            return None
        else:
            M = np.linalg.solve(ref_cell, cell)
            smin = float(np.linalg.svd(M, compute_uv=False).min())
        pl = self._list
        X, umax = pl.gather_check(positions, cell, self._ref, np.ascontiguousarray(M))
        self._check_displacement(positions, M, umax, cell)
        if self.skin == 0.0:
            return None
        if M is _EYE:
            return X if umax < 0.5 * self.skin else None
        return X if smin * self._rlist - 2.0 * umax > self.potential.cutoff else None

    def _check_displacement(self, positions, M, umax, cell):
        limit = ABSURD_LISTS * self._rlist + 10.0 * float(np.linalg.norm(cell, axis=1).sum())
        if not umax > limit:  # NaN too: the grid update names those atoms
            return
        u = np.linalg.norm(positions[self._list.order] - self._ref @ M, axis=1)
        bad = np.sort(self._list.order[u > limit])
        raise ValueError(
            f"positions: atom(s) {bad[:10].tolist()}{' ...' if len(bad) > 10 else ''} "
            f"moved up to {u.max():.3g} Å since the pair list was built (limit "
            f"{limit:.3g} Å: {ABSURD_LISTS:g} list radii plus ten times the cell edges); "
            f"an exploding MD run? Check the time step and overlapping atoms in the "
            f"start.  calc.reset() accepts an unrelated configuration.")

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
        # ASE's Calculator.calculate copies the atoms again right after
        # get_property copied them (a full copy, momenta and all: 0.5 ms a
        # call at 10^5 atoms); the stored atoms are only brought up to date
        # in what a pair potential reads.  No files are written, so no
        # directory is made.
        if atoms is not None:
            old = self.atoms
            changes = list(all_changes) if old is None else self.check_state(atoms)
            if "numbers" in changes or "pbc" in changes:  # also: another length
                self.atoms = atoms.copy()
            elif changes:
                # positions or cell moved (every MD step): update the stored
                # state in place, one copy of the positions, not of the atoms
                old.positions[:] = atoms.positions
                if "cell" in changes:
                    old.cell = atoms.cell.copy()
        atoms = self.atoms
        positions = atoms.positions
        if not (positions.dtype == np.float64 and positions.ndim == 2
                and positions.shape[1] == 3 and positions.flags.c_contiguous):
            positions = as_positions(positions)
        # NaN/inf positions need no numpy pass here (2 ms at 10^5 atoms):
        # they fail the list test below, and the grid names the atoms
        cell = atoms.cell.array
        timings = self.timings
        t0 = time.perf_counter()
        # what changed is decided from the atoms against what the list was
        # built for, not from system_changes: ASE's get_properties and a bare
        # calculate(atoms) pass all_changes, which would drop a valid list and
        # grid on every call (the grid follows cell and pbc changes itself)
        if self._list is not None and (
                len(positions) != self._list.natoms
                or not np.array_equal(atoms.pbc, self._pbc)
                or not np.array_equal(atoms.numbers, self._numbers)):
            self._list = self._chunks = None
        # positions in grid order: neighbours are close in memory whatever
        # the atoms' index order
        X = self._valid_positions(positions, cell)
        t1 = time.perf_counter()
        timings["check"] += t1 - t0
        if X is not None:
            svec = shift_vectors(self._list.shifts, cell)
            t2 = time.perf_counter()
        else:
            X, svec = self._build_list(atoms, positions)
            t2 = time.perf_counter()
            timings["list_build"] += t2 - t1
        pl = self._list
        nthreads = threads_for("pairs", len(pl))
        if self._chunks is None or self._chunk_threads != nthreads:
            # the unit of parallel work, kept with its buffers for the list's life
            self._chunks = row_chunks(pl.rowptr, pl.nbr, nthreads)
            self._chunk_threads = nthreads
        # the virial costs a tenth of the loop: only for callers that ask
        # for stress (once asked, always: barostats ask after the forces)
        self._stress_wanted |= "stress" in properties or "stresses" in properties
        res = self.potential.sum_pairs(
            X, self._types, pl.rowptr, pl.nbr, pl.code, svec, pl.order,
            energies="energies" in properties, virials="stresses" in properties,
            virial=self._stress_wanted, chunks=self._chunks)
        timings["kernel"] += time.perf_counter() - t2
        timings["calls"] += 1
        self.stats["calls"] += 1
        self.stats["pairs"] += len(pl)
        self.stats["threads_used"] = self._chunks.threads_used()
        self.results["energy"] = res["energy"]
        self.results["free_energy"] = res["energy"]
        self.results["forces"] = res["forces"]
        if "energies" in res:
            self.results["energies"] = res["energies"]
        if atoms.cell.rank == 3 and "virial" in res:
            volume = abs(np.linalg.det(cell))
            self.results["stress"] = -res["virial"] / volume
            if "virials_voigt" in res:
                self.results["stresses"] = -res["virials_voigt"] / volume

    # -- recorded parameters ------------------------------------------------
    def todict(self):
        """The calculator's parameters, JSON-serialisable: what .traj, .db
        and .json files record (ASE calls this)."""
        if self.auto is not None:
            template = "auto"
        else:
            template = self.template
        d = {"potential": self.potential.todict(), "template": template,
             "skin": self.skin}
        if self._tolerance is not None:
            d["tolerance"] = self._tolerance
        if self.grid_kwargs:
            d["grid_kwargs"] = dict(self.grid_kwargs)
        return d

    def __repr__(self):
        d = self.todict()
        d.pop("potential")
        rest = ", ".join(f"{k}={v!r}" for k, v in d.items())
        return f"MLGCalculator({self.potential!r}, {rest})"
