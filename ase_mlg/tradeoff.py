"""The speed/accuracy trade of Boris's template, measured and reported
(docs/design.md §7).

Template mode (``MLGCalculator(template=W)``) misses the pairs whose atoms
sit further apart in the grid than W // 2 sites along some axis -- Boris's
"close uncounters" (1985, sec. IV.A) -- and sees **at most one image of each
pair, the minimum image**: a pair that interacts through several periodic
images (a cutoff longer than half a cell height, e.g. the 4-atom ``small``
scene) keeps one of them, and an atom never meets its own images.  On small
cells these misses show in the table.

Everything here is *measured*, never modelled: the missed pairs come from
the pair-set comparison of :mod:`ase_mlg.autotemplate` (the template's pairs
against the exact block query's, keyed by ``(i, j, cell shift)``), and the
times from force calls of :class:`~ase_mlg.calculator.MLGCalculator`.

* :func:`measure` -- one scene and one potential: for W = 3 ... 11 and exact
  mode, the fraction of interacting pairs missed, the distance of the closest
  missed pair, energy and force errors against exact mode, time per force
  call, and optionally the NVE energy drift of a short MD run.
* :class:`TradeoffResult` -- the rows, as a text table, markdown, JSON, and
  plots (:func:`plot_tradeoff`).

The policy that picks W for ``template="auto"`` is
:class:`ase_mlg.autotemplate.AutoTemplate`; ``ase-mlg tradeoff``
(:mod:`ase_mlg.cli.tradeoff`) runs :func:`measure` from the command line.

Units: Å, eV, eV/Å, seconds (times), ps (drift), fs (MD time step), K.
"""

import json
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .autotemplate import (WIDTHS, compare_pairs, energy_forces, exact_pair_set,
                           force_errors, parse_widths, template_pair_set)
from .calculator import MLGCalculator
from .grid import MLG
from .query import exact_pairs
from .template import template_pairs

__all__ = ["CLOCKS", "DIVERGED", "measure", "TradeoffResult", "plot_tradeoff"]


def check_number(value, name, kind=float, minimum=None, strict=False):
    """``value`` as a finite float (or an int), bounded below if asked.

    Parameters
    ----------
    value : object
        A number or its text (command-line options arrive as text).
    name : str
        What the value is called in the error message (an argument of
        :func:`measure`, or an option of ``ase-mlg tradeoff``).
    kind : {float, int}
        ``int`` also rejects floats with a fractional part.
    minimum : float, optional
        Lower bound, inclusive unless ``strict``.

    Raises
    ------
    ValueError
        One line starting ``"{name}:"``.
    """
    if kind is int and isinstance(value, float) and not value.is_integer():
        raise ValueError(f"{name}: expected an integer, got {value!r}")
    try:
        v = kind(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    if kind is float and not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    if minimum is not None and (v <= minimum if strict else v < minimum):
        raise ValueError(f"{name}: must be {'>' if strict else '>='} {minimum}, "
                         f"got {value!r}")
    return v


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
    widths = parse_widths(widths)
    md_steps = check_number(md_steps, "md_steps", int, minimum=0)
    repeats = check_number(repeats, "repeats", int, minimum=0) or 1
    timestep_fs = check_number(timestep_fs, "timestep_fs", minimum=0, strict=True)
    skin = check_number(skin, "skin", minimum=0)
    temperature_K = check_number(temperature_K, "temperature_K", minimum=0)
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
    e_ref, f_ref = energy_forces(potential, numbers, exact)

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
        energy, forces = energy_forces(potential, numbers, found)
        rms, fmax = force_errors(forces, f_ref)
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
