"""The speed/accuracy trade of Boris's template, measured (DESIGN 1.4, 2.6).

Template mode (``MLGCalculator(template=W)``) sums a pair potential over the
pairs found in a W x W x W logical window around each site of the MLG.  It
misses the pairs whose atoms sit further apart in the grid than W // 2 sites
along some axis -- Boris's "close uncounters" (1985, sec. IV.A) -- and it
sees **at most one image of each pair, the minimum image**: a pair that
interacts through several periodic images (a cutoff longer than half a cell
height, e.g. the 4-atom ``small`` scene) keeps one of them, and an atom never
meets its own images.  On small cells these misses show in the table.

Everything here is *measured*, never modelled: the missed pairs are the set
difference between the template's pairs and the exact pair list of the
block query (:mod:`ase_mlg.query`), keyed by ``(i, j, cell shift)``.

* :func:`measure` -- one scene and one potential: for W = 3 ... 11 and exact
  mode, the fraction of interacting pairs missed, the distance of the closest
  missed pair, energy and force errors against exact mode, time per force
  call, and optionally the NVE energy drift of a short MD run.
* :class:`TradeoffResult` -- the rows, as a text table, JSON, and plots
  (:func:`plot_tradeoff`).
* :class:`AutoTemplate` -- the policy behind ``MLGCalculator(template=
  "auto")``: pick the smallest W that meets a tolerance, re-check it against
  the exact query every few list builds.
* :func:`add_tradeoff_parser` / :func:`run_tradeoff_command` -- the
  ``ase-mlg tradeoff`` subcommand.

Units: Å, eV, eV/Å, seconds (times), ps (drift), fs (MD time step), K.
"""

import inspect
import json
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .grid import MLG
from .template import template_pairs
from .potentials import pair_vectors
from .query import exact_pairs

__all__ = ["WIDTHS", "CLOCKS", "DIVERGED", "PairSet", "exact_pair_set", "template_pair_set",
           "compare_pairs", "measure", "TradeoffResult", "plot_tradeoff",
           "AutoTemplate", "add_tradeoff_parser", "run_tradeoff_command"]

#: Template widths measured by default (Boris used 3, 5 and 7).
WIDTHS = (3, 5, 7, 9, 11)


# --------------------------------------------------------------------------
# pair sets and their comparison
# --------------------------------------------------------------------------

@dataclass
class PairSet:
    """A half list of *interacting* pairs (``d`` below the species pair's
    cutoff), each unordered pair once.

    Attributes
    ----------
    i, j : int64 (M,)
    S : int64 (M, 3)
        Cell shifts: ``D = positions[j] - positions[i] + S @ cell``.
    D : float64 (M, 3)
        Distance vectors, Å.
    d : float64 (M,)
        Distances, Å.
    """
    i: np.ndarray
    j: np.ndarray
    S: np.ndarray
    D: np.ndarray
    d: np.ndarray

    def __len__(self):
        return len(self.i)


def _interacting(potential, numbers, i, j, S, D, d):
    """Keep the pairs closer than their own species pair's cutoff (a mixture
    has several cutoffs; the lists are built at the largest)."""
    types, _, cutoffs = potential.prepare(numbers)
    keep = d < cutoffs[types[i], types[j]]
    return PairSet(np.asarray(i, np.int64)[keep], np.asarray(j, np.int64)[keep],
                   np.asarray(S, np.int64)[keep], D[keep], d[keep])


def exact_pair_set(grid, potential, numbers):
    """Every interacting pair of the grid's atoms, from the exact block query.

    Parameters
    ----------
    grid : MLG
    potential : PairPotential
    numbers : int array (N,)
        Atomic numbers (for per-species cutoffs).

    Returns
    -------
    PairSet
    """
    i, j, S = exact_pairs(grid, potential.cutoff)
    D, d = pair_vectors(grid.positions, i, j, S.astype(np.float64),
                        np.ascontiguousarray(grid.box.cell))
    return _interacting(potential, numbers, i, j, S, D, d)


def template_pair_set(grid, width, potential, numbers):
    """The interacting pairs found in the W x W x W half template (minimum
    image only).  Same parameters as :func:`exact_pair_set` plus the odd
    ``width``."""
    i, j, S, D = template_pairs(grid, width, potential.cutoff)
    d = np.sqrt(np.einsum("ij,ij->i", D, D))
    return _interacting(potential, numbers, i, j, S, D, d)


def _canonical(i, j, S):
    """Orient every pair the same way, ``(a, b, S)`` with ``a < b``, or
    ``a == b`` and the first non-zero shift positive: the two lists may
    report a pair from either end."""
    i, j, S = np.asarray(i, np.int64), np.asarray(j, np.int64), np.asarray(S, np.int64)
    first = np.where(S[:, 0] != 0, S[:, 0], np.where(S[:, 1] != 0, S[:, 1], S[:, 2]))
    flip = (i > j) | ((i == j) & (first < 0))
    a = np.where(flip, j, i)
    b = np.where(flip, i, j)
    return a, b, np.where(flip[:, None], -S, S)


def _pair_keys(sets, natoms):
    """One int64 key per pair for each set in ``sets`` (pair identity is
    ``(i, j, S)`` up to orientation).  Falls back to ranking rows when the
    packed key would overflow int64."""
    canon = [_canonical(s.i, s.j, s.S) for s in sets]
    h = max([int(np.abs(c[2]).max(initial=0)) for c in canon] + [0])
    base = 2 * h + 1
    if natoms * natoms * base ** 3 < 2 ** 62:
        keys = []
        for a, b, S in canon:
            k = a * natoms + b
            for c in range(3):
                k = k * base + (S[:, c] + h)
            keys.append(k)
        return keys
    rows = np.concatenate([np.column_stack([a, b, S]) for a, b, S in canon])
    _, ids = np.unique(rows, axis=0, return_inverse=True)
    cuts = np.cumsum([len(s) for s in sets])[:-1]
    return np.split(ids.reshape(-1).astype(np.int64), cuts)


def compare_pairs(exact, found, natoms):
    """Which interacting pairs a candidate list misses.

    Parameters
    ----------
    exact, found : PairSet
        The reference (every interacting pair) and the candidate list.
    natoms : int

    Returns
    -------
    dict
        ``pairs`` (true pairs), ``found``, ``missed`` (true pairs not in
        ``found``), ``extra`` (pairs of ``found`` that are not true pairs,
        0 for any correct list), ``missed_fraction`` (missed / pairs, 0 when
        there is no pair), ``closest_missed`` (Å, None if nothing is missed)
        and ``missed_mask`` (bool (len(exact),), not JSON).
    """
    ke, kf = _pair_keys([exact, found], natoms)
    missed = ~np.isin(ke, kf)
    extra = int((~np.isin(kf, ke)).sum())
    n_missed = int(missed.sum())
    return {
        "pairs": len(exact), "found": len(found), "missed": n_missed,
        "extra": extra,
        "missed_fraction": n_missed / len(exact) if len(exact) else 0.0,
        "closest_missed": float(exact.d[missed].min()) if n_missed else None,
        "missed_mask": missed,
    }


def _energy_forces(potential, numbers, pairs):
    res = potential.evaluate(numbers, pairs.i, pairs.j, pairs.D, pairs.d,
                             per_atom_virials=False)
    return res["energy"], res["forces"]


def _force_errors(forces, reference):
    """RMS and max over atoms of ``|F - F_ref|`` (eV/Å)."""
    if len(forces) == 0:
        return 0.0, 0.0
    err = np.sqrt(np.einsum("ij,ij->i", forces - reference, forces - reference))
    return float(np.sqrt(np.mean(err ** 2))), float(err.max())


# --------------------------------------------------------------------------
# the automatic template width (MLGCalculator(template="auto"))
# --------------------------------------------------------------------------

_TOLERANCE_KEYS = {"missed": "fraction of interacting pairs missed",
                   "force": "RMS force error, eV/Å"}


def _parse_tolerance(tolerance):
    if tolerance is None:
        tolerance = {"missed": 1e-4}
    elif not isinstance(tolerance, dict):
        tolerance = {"missed": tolerance}
    if not tolerance:
        raise ValueError("tolerance: give 'missed' and/or 'force'")
    out = {}
    for key, value in tolerance.items():
        if key not in _TOLERANCE_KEYS:
            raise ValueError(f"tolerance: unknown key {key!r}; use "
                             f"{', '.join(map(repr, _TOLERANCE_KEYS))}")
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"tolerance[{key!r}]: expected a number, got "
                             f"{value!r}") from None
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"tolerance[{key!r}]: must be finite and >= 0, "
                             f"got {value}")
        out[key] = value
    return out


class AutoTemplate:
    """Pick the smallest template width that meets a tolerance, and keep
    checking it (the policy behind ``MLGCalculator(template="auto")``).

    Parameters
    ----------
    tolerance : float or dict, optional
        A float is the largest fraction of interacting pairs the template may
        miss.  A dict may hold ``"missed"`` (that fraction) and/or
        ``"force"`` (largest RMS over atoms of ``|F_template - F_exact|``,
        eV/Å); every given bound must hold.  Default ``{"missed": 1e-4}``.
    widths : sequence of odd int
        Candidate widths, tried in ascending order.
    check_every : int
        Pair-list builds between checks (K).  A check also runs on the first
        build, whenever the calculator hands over a new grid (pbc or number
        of atoms changed), the cell changed (NPT: the grid is kept, the
        density is not) or the grid was rebuilt (sweep cap or periodic
        phase lag).

    Attributes
    ----------
    width : int or None
        The width in use; None means exact mode (no candidate met the
        tolerance, e.g. a cutoff that needs several images of a pair).
    history : list of dict
        One record per check: ``build`` (list-build count), ``width``,
        ``reason`` ("first", "every K", "new grid", "cell changed",
        "grid rebuilt"),
        ``tried`` (widths measured) and the measured ``missed_fraction`` /
        ``force_rms`` of the chosen width.

    Notes
    -----
    **Guaranteed** (measured): at every check the list built right after it
    uses a width whose missed fraction and/or RMS force error, computed
    against the exact query *at those positions* and for the pairs inside
    the interaction cutoff, is within the tolerance -- or the calculator
    falls back to exact mode.  At a check the smallest such width is taken,
    so W widens when the scene densifies (compression, a crystal melting)
    and narrows again when it thins out.

    **Not guaranteed**: anything between checks.  For the next K - 1 list
    builds, and the steps in between that reuse a list (Verlet skin), the
    template is not compared with the exact query; if the grid's local
    order degrades or the density rises within that window, more pairs can
    be missed than the tolerance allows until the next check.  A check costs
    one exact query plus usually two template scans (a few list builds on
    a dense scene); ``check_every=1`` checks every build.
    """

    def __init__(self, tolerance=None, widths=WIDTHS, check_every=10):
        self.tolerance = _parse_tolerance(tolerance)
        self.widths = _parse_widths(widths)
        if isinstance(check_every, bool) or not isinstance(check_every, (int, np.integer)) \
                or check_every < 1:
            raise ValueError(f"check_every: expected an int >= 1, got {check_every!r}")
        self.check_every = int(check_every)
        self.width = None
        self.history = []
        self._builds = 0
        self._since_check = 0
        self._grid = None
        self._cell = None
        self._grid_rebuilds = None
        self._ref, self._ref_key = None, None

    def _reason(self, grid):
        if self._grid is None:
            return "first"
        if grid is not self._grid:
            return "new grid"
        if not np.array_equal(grid.box.cell, self._cell):
            return "cell changed"
        if grid.stats["rebuilds"] != self._grid_rebuilds:
            return "grid rebuilt"
        if self._since_check >= self.check_every:
            return "every K"
        return None

    def evaluate(self, grid, potential, numbers, width):
        """Measure one width against the exact query on ``grid``.

        Returns a dict with ``missed_fraction``, ``force_rms`` (only if a
        force tolerance is set) and ``ok`` (all bounds met)."""
        exact, ref = self._reference(grid, potential, numbers)
        found = template_pair_set(grid, width, potential, numbers)
        rec = {"missed_fraction": compare_pairs(exact, found, len(numbers))["missed_fraction"]}
        ok = rec["missed_fraction"] <= self.tolerance.get("missed", math.inf)
        if "force" in self.tolerance:
            rec["force_rms"] = _force_errors(
                _energy_forces(potential, numbers, found)[1], ref)[0]
            ok = ok and rec["force_rms"] <= self.tolerance["force"]
        rec["ok"] = bool(ok)
        return rec

    def _reference(self, grid, potential, numbers):
        # one exact query (and exact forces) per check, shared by all widths
        key = (id(grid), grid.stats["updates"], grid.stats["rebuilds"])
        if self._ref_key != key:
            exact = exact_pair_set(grid, potential, numbers)
            forces = (_energy_forces(potential, numbers, exact)[1]
                      if "force" in self.tolerance else None)
            self._ref, self._ref_key = (exact, forces), key
        return self._ref

    def _search(self, grid, potential, numbers):
        """Smallest width meeting the tolerance: (width or None, its record,
        widths tried).

        The missed pairs can only shrink as W grows (the W template holds
        every site of the W - 2 one), so the search starts at the width in
        use: if it passes, narrower ones are tried until one fails; if not,
        wider ones until one passes.  For the missed fraction this is the
        answer of an ascending search from the smallest width, usually for
        two template scans instead of four; the RMS force error need not be
        monotone in W (missed forces can cancel), so with a force tolerance
        the result is the narrowest of the passing widths next to the one in
        use."""
        ws = self.widths
        start = ws.index(self.width) if self.width in ws else 0
        tried, best, rec_best = [], None, None
        rec = self.evaluate(grid, potential, numbers, ws[start])
        tried.append(ws[start])
        if rec["ok"]:
            best, rec_best = ws[start], rec
            for w in reversed(ws[:start]):
                rec = self.evaluate(grid, potential, numbers, w)
                tried.append(w)
                if not rec["ok"]:
                    break
                best, rec_best = w, rec
            return best, rec_best, tried
        for w in ws[start + 1:]:
            rec = self.evaluate(grid, potential, numbers, w)
            tried.append(w)
            if rec["ok"]:
                return w, rec, tried
        return None, rec, tried

    def choose(self, grid, potential, numbers):
        """Width for the list about to be built on ``grid`` (called by the
        calculator once per list build, after the grid is up to date).

        Returns
        -------
        int or None
            W, or None for exact mode.
        """
        self._builds += 1
        reason = self._reason(grid)
        if reason is None:
            self._since_check += 1
            return self.width
        chosen, rec, tried = self._search(grid, potential, numbers)
        if chosen is None:
            rec = {"missed_fraction": 0.0, **({"force_rms": 0.0}
                                              if "force" in self.tolerance else {})}
        rec.pop("ok", None)
        self.width = chosen
        self.history.append({"build": self._builds, "width": chosen,
                             "reason": reason, "tried": tried, **rec})
        self._grid, self._grid_rebuilds = grid, grid.stats["rebuilds"]
        self._cell = grid.box.cell.copy()
        self._since_check = 1
        self._ref, self._ref_key = None, None  # release the reference list
        return chosen

    def __repr__(self):
        return (f"AutoTemplate(tolerance={self.tolerance}, widths={self.widths}, "
                f"check_every={self.check_every}, width={self.width})")


def _parse_widths(widths):
    if isinstance(widths, (str, bytes)):
        raise ValueError(f"widths: expected a sequence of odd ints, got {widths!r}")
    try:
        ws = [int(w) for w in widths]
        if any(w != float(x) for w, x in zip(ws, widths)):
            raise ValueError
    except (TypeError, ValueError):
        raise ValueError(f"widths: expected odd positive ints, got {widths!r}") from None
    if not ws or any(w < 1 or w % 2 == 0 for w in ws):
        raise ValueError(f"widths: expected odd positive ints, got {list(widths)!r}")
    return tuple(sorted(set(ws)))


# --------------------------------------------------------------------------
# the measurement
# --------------------------------------------------------------------------

#: Clocks for the timings: wall time, or CPU time of this process (all its
#: threads).  CPU time ignores the time spent waiting for a core, so on a
#: shared, overloaded machine it measures the work; with numba on several
#: threads it also counts their spinning.
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


def _interleaved_medians(funcs, repeats, clock=time.perf_counter):
    """Median time (s, on ``clock``) of each ``funcs[key]()`` over ``repeats`` rounds.

    One untimed call each first (loads/compiles the numba kernels, builds the
    grid).  The rounds visit every function in turn, so background load on a
    shared machine hits all of them alike and their ratios stay meaningful.
    """
    for f in funcs.values():
        f()
    times = {key: [] for key in funcs}
    for _ in range(repeats):
        for key, f in funcs.items():
            t0 = clock()
            f()
            times[key].append(clock() - t0)
    return {key: float(np.median(t)) for key, t in times.items()}


def _force_call(atoms, potential, width, grid_kwargs):
    """A function doing one force call that builds its pair list (skin 0):
    grid update, pair search and pair sum."""
    from .calculator import MLGCalculator
    a = atoms.copy()
    calc = MLGCalculator(potential, template=width, skin=0.0, grid_kwargs=grid_kwargs)
    a.calc = calc
    return lambda: calc.calculate(a, ["energy", "forces"], ["positions"])


#: An NVE run counts as diverged once its total energy has moved this far
#: from the start (eV/atom): no conserving integrator does that, and going on
#: would only feed atoms flying through each other to the grid.
DIVERGED = 1.0


def _md_run(atoms, potential, width, steps, timestep_fs, skin, grid_kwargs,
            clock=time.perf_counter):
    """NVE VelocityVerlet from ``atoms`` (momenta already set).

    Returns a dict: ``drift`` (least-squares slope of the total energy per
    atom, eV/atom/ps; None if the run diverged), ``max_energy_deviation``
    (eV/atom), ``time_step`` (median s per step; the first step, which
    builds the grid, is left out), ``md_failed_step`` (None, or the step at
    which the run diverged or a pair came closer than the potential allows),
    ``md_error`` (its one-line reason), and the calculator and atoms at the
    end (the calculator's grid has followed the run)."""
    from ase import units
    from ase.md.verlet import VelocityVerlet

    from .calculator import MLGCalculator
    a = atoms.copy()
    a.set_momenta(atoms.get_momenta())
    calc = MLGCalculator(potential, template=width, skin=skin, grid_kwargs=grid_kwargs)
    a.calc = calc
    dyn = VelocityVerlet(a, timestep_fs * units.fs)
    n = len(a)
    energies = [a.get_total_energy() / n]
    times = []
    failed, error = None, None
    for step in range(1, steps + 1):
        t0 = clock()
        try:
            dyn.run(1)
            e = a.get_total_energy() / n
        except ValueError as exc:  # e.g. two atoms on top of each other
            failed, error = step, " ".join(str(exc).split())
            break
        times.append(clock() - t0)
        energies.append(e)
        if not abs(e - energies[0]) < DIVERGED:
            failed, error = step, f"total energy moved by more than {DIVERGED} eV/atom"
            break
    e = np.array(energies) - energies[0]
    t_ps = np.arange(len(e)) * timestep_fs * 1e-3
    drift = float(np.polyfit(t_ps, e, 1)[0]) if len(e) > 1 and failed is None else None
    finite = e[np.isfinite(e)]
    return {"drift": drift,
            "max_energy_deviation": float(np.abs(finite).max()) if len(finite) else None,
            "time_step": float(np.median(times[1:] or times)) if times else None,
            "md_failed_step": failed, "md_error": error, "calc": calc, "atoms": a}


def measure(atoms, potential, widths=WIDTHS, md_steps=0, timestep_fs=2.0,
            temperature_K=100.0, skin=0.3, repeats=5, seed=0, label=None,
            grid_kwargs=None, clock="wall"):
    """Measure template mode against exact mode on one scene.

    Template mode sees at most one image per pair (the minimum image): a
    pair interacting through several periodic images keeps one, an atom
    never meets its own images, so on cells shorter than twice the cutoff
    the misses show in the table.

    Parameters
    ----------
    atoms : ase.Atoms
        The scene.  Not modified.
    potential : ase_mlg.potentials.PairPotential
        Its (largest) cutoff is the list cutoff; a pair is *interacting*
        when closer than its species pair's cutoff.
    widths : sequence of odd int
        Template widths W; exact mode is always measured too.
    md_steps : int
        Steps of NVE MD per mode (0: none).  Every mode starts from the same
        positions and Maxwell-Boltzmann momenta (``temperature_K``,
        ``seed``) and uses ``MLGCalculator(template=W, skin=skin)``.
    timestep_fs : float
        VelocityVerlet time step, fs.
    temperature_K : float
        Initial temperature of the MD runs, K.
    skin : float
        Verlet skin of the MD runs, Å (the static errors use none).
    repeats : int
        Timed repeats per mode; the median is reported, after one untimed
        warm-up call.
    seed : int
        Momenta seed.
    label : str, optional
        Scene name for tables and plots.
    grid_kwargs : dict, optional
        Passed to :class:`~ase_mlg.grid.MLG`.
    clock : {"wall", "cpu"}
        Wall time, or CPU time of the process (robust on a shared machine
        when numba runs on one thread; see :data:`CLOCKS`).

    Returns
    -------
    TradeoffResult
        One row per width plus ``"exact"``.  Row keys:
        ``template`` (W or "exact"), ``pairs`` (interacting pairs found),
        ``missed`` and ``missed_fraction`` (of the true interacting pairs),
        ``extra`` (found pairs that are not true pairs; 0),
        ``closest_missed`` (Å or None), ``energy_error`` ((E - E_exact) / N,
        eV/atom), ``force_rms_error`` / ``force_max_error`` (over atoms of
        ``|F - F_exact|``, eV/Å), ``time_pairs`` (pair search alone, s),
        ``time_call`` (one force call that builds its list: grid update,
        search, pair sum; s) and ``time_ratio`` (``time_call`` over exact
        mode's).  With ``md_steps > 0`` also ``drift`` (slope of the total
        energy, eV/atom/ps; None if the run diverged),
        ``max_energy_deviation`` (eV/atom), ``time_step`` (median MD step,
        s), ``md_failed_step`` / ``md_error`` (the step at which the run
        diverged -- total energy off by more than :data:`DIVERGED` eV/atom,
        or atoms driven onto each other -- and why; None if it did not) and
        ``missed_fraction_end`` (on the grid the calculator carried through
        the run, at its final positions).
    """
    widths = _parse_widths(widths)
    md_steps = _nonnegative_int(md_steps, "md_steps")
    repeats = _nonnegative_int(repeats, "repeats") or 1
    timestep_fs = _positive_float(timestep_fs, "timestep_fs")
    skin = _nonnegative_float(skin, "skin")
    temperature_K = _nonnegative_float(temperature_K, "temperature_K")
    grid_kwargs = dict(grid_kwargs or {})
    if clock not in CLOCKS:
        raise ValueError(f"clock: expected one of {sorted(CLOCKS)}, got {clock!r}")
    tick = CLOCKS[clock]
    numbers = atoms.numbers
    n = len(atoms)
    if n == 0:
        raise ValueError("atoms: the scene has no atoms")
    grid = MLG.from_atoms(atoms, **grid_kwargs)
    exact = exact_pair_set(grid, potential, numbers)
    e_ref, f_ref = _energy_forces(potential, numbers, exact)

    modes = list(widths) + ["exact"]
    rows, searches, calls = [], {}, {}
    for mode in modes:
        width = None if mode == "exact" else mode
        if width is None:
            found = exact
            searches[mode] = lambda: exact_pairs(grid, potential.cutoff)
        else:
            found = template_pair_set(grid, width, potential, numbers)
            searches[mode] = lambda w=width: template_pairs(grid, w, potential.cutoff)
        calls[mode] = _force_call(atoms, potential, width, grid_kwargs)
        cmp = compare_pairs(exact, found, n)
        energy, forces = _energy_forces(potential, numbers, found)
        rms, fmax = _force_errors(forces, f_ref)
        rows.append({"template": mode, "pairs": cmp["found"], "missed": cmp["missed"],
                     "missed_fraction": cmp["missed_fraction"], "extra": cmp["extra"],
                     "closest_missed": cmp["closest_missed"],
                     "energy_error": (energy - e_ref) / n,
                     "force_rms_error": rms, "force_max_error": fmax})
    t_search = _interleaved_medians(searches, repeats, tick)
    t_call = _interleaved_medians(calls, repeats, tick)
    for row in rows:
        row["time_pairs"] = t_search[row["template"]]
        row["time_call"] = t_call[row["template"]]
        row["time_ratio"] = row["time_call"] / t_call["exact"] if t_call["exact"] > 0 else None

    if md_steps:
        from ase.md.velocitydistribution import Stationary, thermalize_momenta
        start = atoms.copy()
        thermalize_momenta(start, temperature_K=temperature_K,
                           rng=np.random.default_rng(seed))
        Stationary(start)
        for row in rows:
            width = None if row["template"] == "exact" else row["template"]
            md = _md_run(start, potential, width, md_steps, timestep_fs, skin,
                         grid_kwargs, tick)
            calc, end = md.pop("calc"), md.pop("atoms")
            missed_end = None
            if width is None:
                missed_end = 0.0
            elif md["md_failed_step"] is None:
                g = calc.grid
                g.update(end.positions)  # the grid at the final positions
                missed_end = compare_pairs(
                    exact_pair_set(g, potential, numbers),
                    template_pair_set(g, width, potential, numbers), n)["missed_fraction"]
            row.update(md, missed_fraction_end=missed_end)

    meta = {"scene": label or atoms.get_chemical_formula(), "natoms": n,
            "pbc": [bool(p) for p in atoms.pbc],
            "cell_lengths": [float(x) for x in atoms.cell.lengths()],
            "grid_shape": list(grid.shape), "grid_method": grid.method,
            "cutoff": potential.cutoff, "potential": repr(potential),
            "widths": list(widths), "md_steps": md_steps,
            "timestep_fs": timestep_fs, "temperature_K": temperature_K,
            "skin": skin, "repeats": repeats, "seed": seed, "clock": clock}
    return TradeoffResult(meta=meta, rows=rows)


# --------------------------------------------------------------------------
# output: table, JSON, plots
# --------------------------------------------------------------------------

def _fmt(value, spec):
    return "—" if value is None else format(value, spec)


# (header, key, format, scale): one list drives the table
_COLUMNS = [
    ("W", "template", "", 1),
    ("pairs", "pairs", "d", 1),
    ("missed", "missed_fraction", ".2e", 1),
    ("closest miss Å", "closest_missed", ".2f", 1),
    ("dE eV/atom", "energy_error", "+.2e", 1),
    ("F rms eV/Å", "force_rms_error", ".2e", 1),
    ("F max eV/Å", "force_max_error", ".2e", 1),
    ("search ms", "time_pairs", ".2f", 1e3),
    ("call ms", "time_call", ".2f", 1e3),
    ("call/exact", "time_ratio", ".2f", 1),
]
_MD_COLUMNS = [
    ("drift eV/atom/ps", "drift", "+.2e", 1),
    ("max|dE| eV/atom", "max_energy_deviation", ".2e", 1),
    ("step ms", "time_step", ".2f", 1e3),
    ("missed@end", "missed_fraction_end", ".2e", 1),
]


@dataclass
class TradeoffResult:
    """Rows of :func:`measure` plus what they were measured on (``meta``)."""
    meta: dict = field(default_factory=dict)
    rows: list = field(default_factory=list)

    def columns(self):
        md = self.meta.get("md_steps", 0) > 0
        return _COLUMNS + (_MD_COLUMNS if md else [])

    def _cells(self, row):
        cells = []
        for _, key, spec, scale in self.columns():
            v = row.get(key)
            if key == "drift" and row.get("md_failed_step") is not None:
                cells.append(f"diverged@{row['md_failed_step']}")
            elif not spec:
                cells.append(str(v))
            else:
                cells.append(_fmt(None if v is None else v * scale, spec))
        return cells

    def header(self):
        """One line: the scene, grid, potential and MD set-up."""
        m = self.meta
        head = (f"{m.get('scene')}: {m.get('natoms')} atoms, pbc "
                f"{''.join('T' if p else 'F' for p in m.get('pbc', []))}, grid "
                f"{'x'.join(map(str, m.get('grid_shape', [])))}, cutoff "
                f"{m.get('cutoff', 0):.3f} Å, {m.get('potential')}")
        if m.get("md_steps"):
            head += (f"; NVE {m['md_steps']} steps of {m['timestep_fs']:g} fs from "
                     f"{m['temperature_K']:g} K, skin {m['skin']:g} Å")
        return head

    def table(self):
        """A readable text table (the header line, then one line per mode)."""
        cells = [[h for h, *_ in self.columns()]] + [self._cells(r) for r in self.rows]
        width = [max(len(r[c]) for r in cells) for c in range(len(cells[0]))]
        lines = ["  ".join(s.rjust(w) for s, w in zip(r, width)) for r in cells]
        return "\n".join([self.header()] + lines)

    def markdown(self):
        """The same table as GitHub markdown (without the header line)."""
        cols = self.columns()
        out = ["| " + " | ".join(h.replace("|", "\\|") for h, *_ in cols) + " |",
               "|" + "---:|" * len(cols)]
        out += ["| " + " | ".join(self._cells(r)) + " |" for r in self.rows]
        return "\n".join(out)

    def to_dict(self):
        return {"meta": self.meta, "rows": self.rows}

    def to_json(self, **kwargs):
        """JSON text; ``TradeoffResult.from_json`` reads it back equal."""
        return json.dumps(self.to_dict(), allow_nan=False, **kwargs)

    @classmethod
    def from_dict(cls, data):
        return cls(meta=dict(data["meta"]), rows=[dict(r) for r in data["rows"]])

    @classmethod
    def from_json(cls, text):
        return cls.from_dict(json.loads(text))


def plot_tradeoff(results, path, title=None):
    """Error against cost, one curve per scene, written as a PNG.

    Panels: missed fraction and RMS force error against time per force call
    relative to exact mode (each point a width W; exact mode sits at x = 1
    with error 0); with MD, the |drift| of the total energy against time per
    MD step relative to exact mode (exact mode's own drift drawn too;
    diverged runs left out).  Zero errors, and the round-off force errors of
    widths that miss nothing, are drawn as open triangles on the panel's
    floor, since a log axis has no zero.

    Parameters
    ----------
    results : TradeoffResult or list of them
    path : str or Path
        PNG file to write.

    Returns
    -------
    str
        The path written.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    if isinstance(results, TradeoffResult):
        results = [results]
    md = any(r.meta.get("md_steps", 0) > 0 for r in results)
    panels = [("missed_fraction", "time_ratio", "missed fraction of pairs",
               "force call time / exact"),
              ("force_rms_error", "time_ratio", "RMS force error (eV/Å)",
               "force call time / exact")]
    if md:
        panels.append(("drift", "time_step", "|NVE drift| (eV/atom/ps)",
                       "MD step time / exact"))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.4))

    def value(row, key, exact):
        v = row.get(key)
        if v is None or exact.get(key) in (None, 0):
            return None
        return abs(v) if key == ykey or key == "time_ratio" else v / exact[key]

    def nothing_missed(row, key):
        # with every pair found, force differences are summation-order
        # round-off (1e-17 eV/Å); draw them on the floor with the zeros
        return key != "drift" and row.get("missed") == 0

    for ax, (ykey, xkey, ylabel, xlabel) in zip(axes, panels):
        positive = [abs(row[ykey]) for r in results for row in r.rows
                    if row.get(ykey) and not nothing_missed(row, ykey)]
        floor = min(positive) / 10 if positive else 1e-12
        for n, r in enumerate(results):
            exact = next((row for row in r.rows if row["template"] == "exact"), None)
            if exact is None:
                continue
            # exact mode is drawn only where its value is not 0 (the drift);
            # diverged MD runs have no drift and are left out
            pts = [(value(row, xkey, exact), abs(row[ykey]), row) for row in r.rows
                   if row.get(ykey) is not None
                   and (row["template"] != "exact" or row[ykey])]
            pts = [(x, y, row) for x, y, row in pts if x is not None]
            if not pts:
                continue
            x = np.array([p[0] for p in pts])
            y = np.array([p[1] for p in pts])
            color = f"C{n % 10}"
            zero = (y == 0) | np.array([nothing_missed(p[2], ykey) for p in pts])
            yy = np.where(zero, floor, y)
            ax.plot(x, yy, "-", color=color, alpha=0.6, label=r.meta.get("scene"))
            ax.plot(x[~zero], y[~zero], "o", color=color)
            ax.plot(x[zero], yy[zero], "v", mfc="none", color=color)
            for xi, yi, (_, _, row) in zip(x, yy, pts):
                ax.annotate("exact" if row["template"] == "exact" else str(row["template"]),
                            (xi, yi), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.axvline(1.0, color="k", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel(xlabel + " (dotted: exact mode)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    fig.suptitle(title or "Template width W: error against cost (labels: W)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


# --------------------------------------------------------------------------
# the ase-mlg tradeoff subcommand
# --------------------------------------------------------------------------

def _number(value, name, cast=float):
    try:
        v = cast(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    if cast is float and not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    return v


def _positive_float(value, name):
    v = _number(value, name)
    if v <= 0:
        raise ValueError(f"{name}: must be > 0, got {value!r}")
    return v


def _nonnegative_float(value, name):
    v = _number(value, name)
    if v < 0:
        raise ValueError(f"{name}: must be >= 0, got {value!r}")
    return v


def _nonnegative_int(value, name):
    if isinstance(value, float) and not value.is_integer():
        raise ValueError(f"{name}: expected an integer, got {value!r}")
    v = _number(value, name, int)
    if v < 0:
        raise ValueError(f"{name}: must be >= 0, got {value!r}")
    return v


POTENTIALS = ("lj", "morse")


def add_tradeoff_parser(subparsers):
    """Add ``tradeoff`` to an argparse ``subparsers`` object.

    Numbers are read as strings and checked by :func:`run_tradeoff_command`,
    so every bad value becomes a one-line ``ValueError`` naming the
    argument.
    """
    from .calculator import MLGCalculator
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
    p.add_argument("--scene", help="built-in scene: liquid (the default when "
                   "no STRUCTURE_FILE is given), copper, gas, nanoparticle, "
                   "sheared, slab, small, mixture")
    p.add_argument("--natoms", default="4000",
                   help="approximate size of a built-in scene (default %(default)s)")
    p.add_argument("--cutoff", metavar="RC",
                   help="cutoff radius, Å (default: 2.5 sigma for LJ, "
                        "2.7 r0 for Morse, ASE's Morse default)")
    p.add_argument("--potential", default="lj",
                   help="lj (default) or morse")
    p.add_argument("--sigma", default="3.405",
                   help="LJ sigma, Å (default %(default)s, argon)")
    p.add_argument("--epsilon", default=None,
                   help="well depth, eV (default: LJ 0.0104, argon; Morse 0.35)")
    p.add_argument("--smooth", action="store_true",
                   help="LJ with ASE's smooth cutoff function (default: shifted)")
    p.add_argument("--r0", default="2.55",
                   help="Morse r0, Å (default %(default)s)")
    p.add_argument("--rho0", default="6.0",
                   help="Morse rho0 (default %(default)s)")
    p.add_argument("--widths", default="3,5,7,9,11",
                   help="comma-separated odd template widths (default %(default)s)")
    p.add_argument("--md", default="0", metavar="STEPS",
                   help="NVE VelocityVerlet steps per mode (default %(default)s: "
                        "no MD)")
    p.add_argument("--timestep", default="2.0",
                   help="MD time step, fs (default %(default)s)")
    p.add_argument("--temperature", default="100",
                   help="initial MD temperature, K (default %(default)s)")
    p.add_argument("--skin", default=str(skin),
                   help="MD Verlet skin, Å (default %(default)s, the same as "
                        "MLGCalculator's)")
    p.add_argument("--repeats", default="5",
                   help="timed repeats, the median is reported (default %(default)s)")
    p.add_argument("--seed", default="0",
                   help="seed of the MD momenta (default %(default)s)")
    p.add_argument("--clock", default="wall",
                   help="wall (default) or cpu: CPU time of the process, robust "
                        "on a loaded machine with NUMBA_NUM_THREADS=1")
    p.add_argument("--json", action="store_true",
                   help="print JSON instead of the table")
    p.add_argument("--plot", metavar="DIR",
                   help="write tradeoff.png into DIR (created if missing)")
    return p


def _potential_from_args(args, cutoff):
    from .potentials import LennardJones, Morse
    name = str(args.potential).lower()
    if name not in POTENTIALS:
        raise ValueError(f"--potential: expected one of {', '.join(POTENTIALS)}, "
                         f"got {args.potential!r}")
    if name == "lj":
        eps = 0.0104 if args.epsilon is None else args.epsilon
        return LennardJones(sigma=_positive_float(args.sigma, "--sigma"),
                            epsilon=_nonnegative_float(eps, "--epsilon"),
                            rc=cutoff, smooth=bool(args.smooth))
    eps = 0.35 if args.epsilon is None else args.epsilon
    r0 = _positive_float(args.r0, "--r0")
    # Morse's cutoff is given in units of r0; keep ASE's ratio 1.9 / 2.7
    # between the start and the end of the cutoff function
    return Morse(epsilon=_nonnegative_float(eps, "--epsilon"), r0=r0,
                 rho0=_positive_float(args.rho0, "--rho0"),
                 rcut1=cutoff / r0 * 1.9 / 2.7, rcut2=cutoff / r0)


def _atoms_from_args(args):
    from .scenes import make_scene
    if (args.structure is None) == (args.scene is None):
        raise ValueError("STRUCTURE_FILE/--scene: give exactly one of a structure "
                         "file or --scene NAME")
    if args.scene is not None:
        natoms = _nonnegative_int(args.natoms, "--natoms")
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


def run_tradeoff_command(args, out=None):
    """Run ``ase-mlg tradeoff`` for parsed ``args``; print the table (or
    JSON) to ``out`` (default stdout) and write the plot if asked.

    Returns
    -------
    TradeoffResult

    Raises
    ------
    ValueError
        One line naming the bad argument.
    """
    import os
    import sys
    out = out or sys.stdout
    if args.structure is None and args.scene is None:
        args.scene = "liquid"  # the default: the LJ argon liquid
    if args.cutoff is None:
        # default: 2.5 sigma for LJ, ASE's Morse cutoff 2.7 r0 for Morse
        if str(args.potential).lower() == "morse":
            args.cutoff = 2.7 * _positive_float(args.r0, "--r0")
        else:
            args.cutoff = 2.5 * _positive_float(args.sigma, "--sigma")
    cutoff = _positive_float(args.cutoff, "--cutoff")
    widths = _parse_widths_text(args.widths)
    md = _nonnegative_int(args.md, "--md")
    timestep = _positive_float(args.timestep, "--timestep")
    temperature = _nonnegative_float(args.temperature, "--temperature")
    skin = _nonnegative_float(args.skin, "--skin")
    repeats = _nonnegative_int(args.repeats, "--repeats")
    if repeats < 1:
        raise ValueError(f"--repeats: must be >= 1, got {args.repeats!r}")
    seed = _nonnegative_int(args.seed, "--seed")
    if args.clock not in CLOCKS:
        raise ValueError(f"--clock: expected one of {', '.join(CLOCKS)}, got {args.clock!r}")
    if args.plot is not None and os.path.exists(args.plot) and not os.path.isdir(args.plot):
        raise ValueError(f"--plot: {args.plot!r} exists and is not a directory")
    potential = _potential_from_args(args, cutoff)
    atoms, label = _atoms_from_args(args)
    result = measure(atoms, potential, widths=widths, md_steps=md,
                     timestep_fs=timestep, temperature_K=temperature, skin=skin,
                     repeats=repeats, seed=seed, label=label, clock=args.clock)
    print(result.to_json(indent=1) if args.json else result.table(), file=out)
    if args.plot is not None:
        os.makedirs(args.plot, exist_ok=True)
        path = plot_tradeoff(result, os.path.join(args.plot, "tradeoff.png"))
        if not args.json:
            print(f"plot: {path}", file=out)
    return result


def _parse_widths_text(text):
    try:
        values = [int(w) for w in str(text).split(",") if w.strip()]
    except ValueError:
        raise ValueError(f"--widths: expected comma-separated odd ints, got {text!r}") from None
    try:
        return _parse_widths(values)
    except ValueError:
        raise ValueError(f"--widths: expected comma-separated odd positive ints, "
                         f"got {text!r}") from None
