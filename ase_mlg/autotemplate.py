"""The ``template="auto"`` policy and the pair-set comparison it measures with
(docs/design.md §7).

Template mode (``MLGCalculator(template=W)``) sums a pair potential over the
pairs found in a W x W x W logical window around each site of the MLG.  It
misses the pairs whose atoms sit further apart in the grid than W // 2 sites
along some axis -- Boris's "close uncounters" (1985, sec. IV.A) -- and it
sees at most one image of each pair, the minimum image.  What it misses is
*measured* here, never modelled: the set difference between the template's
interacting pairs and those of the exact block query (:mod:`ase_mlg.query`),
keyed by ``(i, j, cell shift)``.

* :class:`PairSet`, :func:`exact_pair_set`, :func:`template_pair_set`,
  :func:`compare_pairs` -- the interacting pairs of each list and which ones
  a candidate misses; :func:`energy_forces` / :func:`force_errors` -- what
  the misses cost in energy and forces.
* :class:`AutoTemplate` -- the policy behind ``MLGCalculator(template=
  "auto")``: the fastest mode that meets a tolerance -- the narrowest W that
  meets it, or exact mode where that is faster -- re-checked against the
  exact query every few list builds.

What the policy promises
------------------------
**Guaranteed** (measured): at every check the list built right after it
uses a width whose missed fraction and/or RMS force error, computed
against the exact query *at those positions* and for the pairs inside
the interaction cutoff, is within the tolerance -- or the calculator
uses exact mode.  At a check the narrowest such width is found (it
widens when the scene densifies -- compression, a crystal melting -- and
narrows again when it thins out), and it is used only if its list build
was *measured* faster than the exact query's at that check; otherwise
the calculator runs in exact mode until the next check.

Where a template pays (measured, ``validation/reports/tradeoff.md``):
only where a narrow window already finds every pair, i.e. dilute systems
(the gas: W = 3 at 0.76x the exact build).  In dense liquids and crystals
the width that misses at most 1e-4 of the pairs is 9 or 11 and scans
(W^3 - 1) / 2 sites per atom, 2.4-3.7x the exact query's cost, so "auto"
runs exact mode there.  The timings are one scan each, at the interaction
cutoff (the calculator builds its lists at ``cutoff + skin``, where the
exact query has more pairs to find while a template scans the same
sites: the comparison leans to exact mode), on whatever load the machine
has at that moment; the first check of a policy times each kind twice
and keeps the second, so kernel compilation and cache loading are not
counted.

**Not guaranteed**: anything between checks.  For the next K - 1 list
builds, and the steps in between that reuse a list (Verlet skin), the
template is not compared with the exact query; if the grid's local
order degrades or the density rises within that window, more pairs can
be missed than the tolerance allows until the next check.  A check costs
one exact query plus usually two template scans (a few list builds on
a dense scene), also while exact mode is in use; ``check_every=1``
checks every build.

Units: Å, eV, eV/Å.  The measurement built on these pieces (timings, NVE
drift, tables) is :mod:`ase_mlg.tradeoff`.
"""

import math
import time
from dataclasses import dataclass

import numpy as np

from .blocks import BlockIndex
from .pairsum import pair_vectors
from .query import exact_pairs, half_list, pair_list
from .template import template_pairs

__all__ = ["WIDTHS", "SELECT", "parse_widths", "parse_template", "PairSet", "exact_pair_set",
           "template_pair_set", "compare_pairs", "energy_forces", "force_errors",
           "AutoTemplate"]

#: Template widths measured by default (Boris used 3, 5 and 7).
WIDTHS = (3, 5, 7, 9, 11)

#: What :class:`AutoTemplate` selects among the modes meeting the tolerance.
SELECT = {"fastest": "the narrowest passing width, or exact mode where its "
                     "list build was measured faster",
          "narrowest": "the narrowest passing width, whatever it costs "
                       "(exact mode only when none passes)"}


def parse_widths(widths):
    """Template widths as a sorted tuple of distinct odd ints >= 3.

    Raises
    ------
    ValueError
        One line starting ``widths:`` for a string, a non-integer or an even
        width, or one below 3 (W = 1 is the site alone: no pairs).
    """
    if isinstance(widths, (str, bytes)):
        raise ValueError(f"widths: expected a sequence of odd ints >= 3, got {widths!r}")
    try:
        ws = [int(w) for w in widths]
        if any(w != float(x) for w, x in zip(ws, widths)):
            raise ValueError
    except (TypeError, ValueError):
        raise ValueError(f"widths: expected odd ints >= 3, got {widths!r}") from None
    if not ws or any(not _is_width(w) for w in ws):
        raise ValueError(f"widths: expected odd ints >= 3 (W = 1 holds no pairs), "
                         f"got {list(widths)!r}")
    return tuple(sorted(set(ws)))


def _is_width(w):
    # a 1 x 1 x 1 template is the site alone: it finds no pair (E = 0)
    return w >= 3 and w % 2 == 1


def parse_template(template, tolerance=None):
    """``MLGCalculator``'s ``template`` and ``tolerance`` as ``(auto,
    width)``: the :class:`AutoTemplate` policy (None unless ``"auto"`` or
    an instance) and the fixed width (None: exact mode, or chosen by the
    policy).

    Raises
    ------
    ValueError
        ``template:`` an even, non-positive or non-integer width;
        ``tolerance:`` given without ``template="auto"``, or beside an
        AutoTemplate instance (set it there).
    """
    if isinstance(template, AutoTemplate):
        if tolerance is not None:
            raise ValueError("tolerance: set it on the AutoTemplate instance")
        return template, None
    if isinstance(template, str) and template == "auto":
        return AutoTemplate(tolerance), None
    if tolerance is not None:
        raise ValueError("tolerance: only used with template='auto'")
    if template is None:
        return None, None
    if isinstance(template, bool) or not isinstance(template, (int, np.integer)) \
            or not _is_width(template):
        raise ValueError(f"template: None (exact), 'auto' or an odd int >= 3 (W = 1 "
                         f"holds no pairs), got {template!r}")
    return None, int(template)


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


def _member(keys, sorted_keys):
    """``np.isin(keys, sorted_keys)`` for an ascending ``sorted_keys``."""
    if len(sorted_keys) == 0:
        return np.zeros(len(keys), bool)
    at = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    return sorted_keys[at] == keys


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
    # membership by binary search in the sorted keys (np.isin's unique-based
    # path cost 40 ms a call at 10^5 pairs, most of a template="auto" check)
    missed = ~_member(ke, np.sort(kf))
    extra = int((~_member(kf, np.sort(ke))).sum())
    n_missed = int(missed.sum())
    return {
        "pairs": len(exact), "found": len(found), "missed": n_missed,
        "extra": extra,
        "missed_fraction": n_missed / len(exact) if len(exact) else 0.0,
        "closest_missed": float(exact.d[missed].min()) if n_missed else None,
        "missed_mask": missed,
    }


def energy_forces(potential, numbers, pairs):
    """Energy (eV) and forces (eV/Å, (N, 3)) summed over the pairs of a
    :class:`PairSet` only."""
    res = potential.evaluate(numbers, pairs.i, pairs.j, pairs.D, pairs.d,
                             per_atom_virials=False)
    return res["energy"], res["forces"]


def force_errors(forces, reference):
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
        if key == "missed" and value >= 1:
            # a fraction of the interacting pairs: 1 allows missing them all
            raise ValueError(f"tolerance['missed']: a fraction of the interacting "
                             f"pairs, 0 <= missed < 1, got {value}")
        out[key] = value
    return out


class AutoTemplate:
    """Run the fastest mode that meets a tolerance, and keep checking it
    (the policy behind ``MLGCalculator(template="auto")``).

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
    select : {"fastest", "narrowest"}
        ``"fastest"`` (default): the narrowest width meeting the tolerance
        if its list build (template scan and grid-order list, s) was
        measured faster than the exact query's at the check, else exact
        mode.  ``"narrowest"``: that width whatever it costs (Boris's
        trade, as :mod:`ase_mlg.tradeoff` measures it).

    Attributes
    ----------
    width : int or None
        The width in use; None means exact mode (no candidate met the
        tolerance, e.g. a cutoff that needs several images of a pair, or
        exact mode was measured faster).
    candidate : int or None
        The narrowest width that met the tolerance at the last check (None
        also when ``select="fastest"`` stopped searching: a failing width
        already cost more than exact mode).
    history : list of dict
        One record per check: ``build`` (list-build count), ``width`` (the
        mode chosen, None for exact), ``reason`` ("first", "every K", "new
        grid", "cell changed", "grid rebuilt"), ``candidate``, ``why``
        ("template faster", "exact faster", "narrowest", "no width meets the
        tolerance"), ``tried`` (widths measured), ``seconds`` (``{"exact":
        s, W: s, ...}``: the measured list builds) and the measured
        ``missed_fraction`` / ``force_rms`` of the chosen mode (0 for exact).

    Notes
    -----
    The tolerance is guaranteed at the checks, not between them: see the
    module docstring and docs/design.md §7.
    """

    def __init__(self, tolerance=None, widths=WIDTHS, check_every=10,
                 select="fastest"):
        self.tolerance = _parse_tolerance(tolerance)
        self.widths = parse_widths(widths)
        if isinstance(check_every, bool) or not isinstance(check_every, (int, np.integer)) \
                or check_every < 1:
            raise ValueError(f"check_every: expected an int >= 1, got {check_every!r}")
        if select not in SELECT:
            raise ValueError(f"select: expected one of {', '.join(map(repr, SELECT))}, "
                             f"got {select!r}")
        self.check_every = int(check_every)
        self.select = select
        self.width = None
        self.candidate = None
        self.history = []
        self._builds = 0
        self._since_check = 0
        self._grid = None
        self._cell = None
        self._generation = None
        self._ref, self._ref_key = None, None
        self._exact = None
        self._seconds = {}
        # kinds of scan timed once already: the first timing of each also
        # pays numba's compilation or cache load, so it is run twice
        self._warm = set()

    def _reason(self, grid):
        if self._grid is None:
            return "first"
        if grid is not self._grid:
            return "new grid"
        if not np.array_equal(grid.box.cell, self._cell):
            return "cell changed"
        if grid.generation != self._generation:
            return "grid rebuilt"
        if self._since_check >= self.check_every:
            return "every K"
        return None

    def _timed(self, kind, build):
        """``build()`` and the seconds it took; run twice the first time this
        policy times ``kind`` ("exact" or "template")."""
        if kind not in self._warm:
            build()
            self._warm.add(kind)
        t0 = time.perf_counter()
        out = build()
        return out, time.perf_counter() - t0

    def evaluate(self, grid, potential, numbers, width):
        """Measure one width against the exact query on ``grid``.

        Returns a dict with ``missed_fraction``, ``force_rms`` (only if a
        force tolerance is set), ``seconds`` (the template's list build:
        scan plus grid-order list, as the calculator builds it) and ``ok``
        (all bounds met)."""
        return self._evaluate(grid, potential, numbers, width, False)

    def _evaluate(self, grid, potential, numbers, width, stop_if_slower):
        """:meth:`evaluate`; with ``stop_if_slower``, a width whose list
        build took at least the exact query's time is not compared (``ok``
        is then None): it cannot be chosen, and the comparison costs more
        than the scans."""
        index, t_exact = self._exact_build(grid, potential)

        def build():
            i, j, S, D = template_pairs(grid, width, potential.cutoff)
            pair_list(index, i, j, S)
            return i, j, S, D

        (i, j, S, D), seconds = self._timed("template", build)
        self._seconds[width] = seconds
        if stop_if_slower and seconds >= t_exact:
            return {"seconds": seconds, "ok": None}
        exact, ref = self._reference(grid, potential, numbers)
        d = np.sqrt(np.einsum("ij,ij->i", D, D))
        found = _interacting(potential, numbers, i, j, S, D, d)
        rec = {"missed_fraction": compare_pairs(exact, found, len(numbers))["missed_fraction"]}
        ok = rec["missed_fraction"] <= self.tolerance.get("missed", math.inf)
        if "force" in self.tolerance:
            rec["force_rms"] = force_errors(
                energy_forces(potential, numbers, found)[1], ref)[0]
            ok = ok and rec["force_rms"] <= self.tolerance["force"]
        rec["seconds"] = seconds
        rec["ok"] = bool(ok)
        return rec

    def _key(self, grid):
        return (id(grid), grid.version)

    def _exact_build(self, grid, potential):
        """The exact query at this check, timed as the calculator's exact
        list build (half_list); (block index, seconds)."""
        if self._exact is None or self._exact[0] != self._key(grid):
            index = BlockIndex(grid)
            rc = float(potential.cutoff)
            pl, seconds = self._timed(
                "exact", lambda: half_list(index, np.full(grid.natoms, rc), cut=rc))
            self._exact = (self._key(grid), index, pl, seconds)
            self._seconds = {"exact": seconds}
        return self._exact[1], self._exact[3]

    def _reference(self, grid, potential, numbers):
        # the exact query's interacting pairs (and exact forces), built only
        # when a width is compared, once per check
        key = self._key(grid)
        if self._ref_key != key:
            self._exact_build(grid, potential)
            _, index, pl, _ = self._exact
            res = pl.arrays(index.positions, index.cell, half=True, quantities="ijS")
            i, j, S = res["i"], res["j"], res["S"]
            D, d = pair_vectors(grid.positions, i, j, S.astype(np.float64),
                                np.ascontiguousarray(grid.box.cell))
            exact = _interacting(potential, numbers, i, j, S, D, d)
            forces = (energy_forces(potential, numbers, exact)[1]
                      if "force" in self.tolerance else None)
            self._ref, self._ref_key = (exact, forces), key
        return self._ref

    def _search(self, grid, potential, numbers):
        """Narrowest width meeting the tolerance: (width or None, its record,
        widths tried, stopped).

        The missed pairs can only shrink as W grows (the W template holds
        every site of the W - 2 one), so the search starts at the width in
        use (the narrowest while exact mode runs): if it passes, narrower
        ones are tried until one fails; if not, wider ones until one
        passes.  For the missed fraction this is the answer of an ascending
        search from the smallest width, usually for two template scans
        instead of four; the RMS force error need not be monotone in W
        (missed forces can cancel), so with a force tolerance the result is
        the narrowest of the passing widths next to the one in use.

        With ``select="fastest"`` the upward search stops at the first width
        whose list build took at least the exact query's time (``stopped``
        True, width None): a wider template scans more sites, so none could
        be chosen.  In a dense scene a check is then one exact query and one
        W = 3 scan."""
        ws = self.widths
        fastest = self.select == "fastest"
        # from the width in use; from the cheapest scan while exact mode
        # runs (a probe that stops as soon as a scan costs more than exact)
        start = ws.index(self.width) if self.width in ws else 0
        tried, best, rec_best = [], None, None
        rec = self._evaluate(grid, potential, numbers, ws[start],
                             fastest and self.width is None)
        tried.append(ws[start])
        if rec["ok"] is None:
            return None, rec, tried, True
        if rec["ok"]:
            best, rec_best = ws[start], rec
            for w in reversed(ws[:start]):
                rec = self.evaluate(grid, potential, numbers, w)
                tried.append(w)
                if not rec["ok"]:
                    break
                best, rec_best = w, rec
            return best, rec_best, tried, False
        for w in ws[start + 1:]:
            rec = self._evaluate(grid, potential, numbers, w, fastest)
            tried.append(w)
            if rec["ok"] is None:
                return None, rec, tried, True
            if rec["ok"]:
                return w, rec, tried, False
        return None, rec, tried, False

    def choose(self, grid, potential, numbers):
        """Mode for the list about to be built on ``grid`` (called by the
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
        candidate, rec, tried, stopped = self._search(grid, potential, numbers)
        seconds = dict(self._seconds)
        if stopped:
            chosen, why = None, "exact faster"
        elif candidate is None:
            chosen, why = None, "no width meets the tolerance"
        elif self.select == "narrowest":
            chosen, why = candidate, "narrowest"
        elif seconds[candidate] < seconds["exact"]:
            chosen, why = candidate, "template faster"
        else:
            chosen, why = None, "exact faster"
        if chosen is None:
            rec = {"missed_fraction": 0.0, **({"force_rms": 0.0}
                                              if "force" in self.tolerance else {})}
        rec = {k: v for k, v in rec.items() if k not in ("ok", "seconds")}
        self.width, self.candidate = chosen, candidate
        self.history.append({"build": self._builds, "width": chosen,
                             "reason": reason, "candidate": candidate, "why": why,
                             "tried": tried, "seconds": seconds, **rec})
        self._grid, self._generation = grid, grid.generation
        self._cell = grid.box.cell.copy()
        self._since_check = 1
        # release the reference lists
        self._ref, self._ref_key, self._exact = None, None, None
        return chosen

    def __repr__(self):
        return (f"AutoTemplate(tolerance={self.tolerance}, widths={self.widths}, "
                f"check_every={self.check_every}, select={self.select!r}, "
                f"width={self.width})")
