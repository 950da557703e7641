"""The settings of :class:`ase_mlg.MLGCalculator`: what each one takes,
checked all together before any takes effect.

A calculator's setting either takes effect or is refused (a ``TypeError``
or ``ValueError`` naming it): an ignored one would put numbers that were
never used into ``todict()``, hence into .traj and .db files.  The
calculator builds its pair list from the checked settings; ``set`` takes
the potential's own arguments too (``sigma=``, ``r0=``, ...), as ASE's LJ
honours ``set(sigma=...)``, by building a new potential of the same kind
(:meth:`ase_mlg.potentials.PairPotential.replace`).
"""

import inspect
import math
from collections.abc import Mapping

import numpy as np

from .autotemplate import parse_template
from .grid import MLG
from .potentials import PairPotential

__all__ = ["SETTINGS", "check_settings", "changed_settings", "setting", "refuse_unknown",
           "record"]

#: The calculator's own settings.
SETTINGS = ("potential", "template", "skin", "grid_kwargs", "tolerance")
_GRID_KWARGS = frozenset(inspect.signature(MLG).parameters) - {"positions", "cell", "pbc"}


def refuse_unknown(kwargs, calculator_kwargs):
    """TypeError for a keyword ``MLGCalculator`` does not take.  ASE's
    calculators store unknown keywords as parameters and ignore them; a
    neighbour-list hook ignored would be a silent wrong answer."""
    unknown = sorted(set(kwargs) - set(calculator_kwargs))
    if unknown:
        raise TypeError(
            f"MLGCalculator: unexpected keyword argument(s) {', '.join(map(repr, unknown))}"
            f"; MLGCalculator takes {', '.join(SETTINGS)}, "
            f"{', '.join(sorted(calculator_kwargs))} (it finds its own pairs on its MLG; "
            f"the potential's parameters go to the potential, e.g. Morse(epsilon=..., r0=...))")


def setting(name, doc, view=None):
    """A calculator property for setting ``name``: reads what is in force,
    and an assignment is ``calc.set(name=value)`` (it takes effect or is
    refused)."""
    def get(calc):
        value = calc._settings[name]
        return value if view is None else view(value)

    def put(calc, value):
        calc.set(**{name: value})
    return property(get, put, doc=doc + " Assigning is ``calc.set(...)``: the list is dropped.")


def check_settings(settings):
    """The settings (a dict keyed by :data:`SETTINGS`) checked and
    normalised, with the template policy: ``(settings, auto, width)``
    (see :func:`ase_mlg.autotemplate.parse_template`).

    Raises
    ------
    TypeError
        ``potential:`` not a PairPotential; ``grid_kwargs:`` not a dict or
        naming what :class:`~ase_mlg.grid.MLG` does not take.
    ValueError
        ``template:``, ``tolerance:`` or ``skin:`` out of range.
    """
    potential = settings["potential"]
    if not isinstance(potential, PairPotential):
        raise TypeError("potential: expected an ase_mlg.potentials."
                        f"PairPotential, got {type(potential).__name__}")
    auto, width = parse_template(settings["template"], settings["tolerance"])
    try:
        skin = float(settings["skin"])
    except (TypeError, ValueError):
        raise ValueError(f"skin: expected a number (Å), got {settings['skin']!r}") from None
    if not math.isfinite(skin) or skin < 0:
        raise ValueError(f"skin: must be finite and >= 0 (Å), got {skin}")
    grid_kwargs = settings["grid_kwargs"]
    if grid_kwargs is not None and not isinstance(grid_kwargs, Mapping):
        raise TypeError(f"grid_kwargs: expected a dict, got {type(grid_kwargs).__name__}")
    grid_kwargs = dict(grid_kwargs or {})
    unknown = sorted(set(grid_kwargs) - _GRID_KWARGS)
    if unknown:
        raise TypeError(f"grid_kwargs: MLG takes no {', '.join(map(repr, unknown))}; "
                        f"it takes {', '.join(sorted(_GRID_KWARGS))}")
    return {**settings, "skin": skin, "grid_kwargs": grid_kwargs}, auto, width


def record(settings, auto, width):
    """The settings in force as JSON-serialisable data (``calc.todict()``):
    the potential's record, ``template`` (``"auto"`` for the policy, else
    the width or None), ``skin``, and ``tolerance`` / ``grid_kwargs`` where
    given."""
    d = {"potential": settings["potential"].todict(),
         "template": "auto" if auto else width, "skin": settings["skin"]}
    if settings["tolerance"] is not None:
        d["tolerance"] = settings["tolerance"]
    if settings["grid_kwargs"]:
        d["grid_kwargs"] = dict(settings["grid_kwargs"])
    return d


def changed_settings(current, kwargs):
    """What ``calc.set(**kwargs)`` changes: ``(changed, new)``, the keys
    whose values differ from ``current`` (as ``set`` returns them) and the
    whole new settings dict (unchecked: :func:`check_settings` it).
    Keywords that are not :data:`SETTINGS` are the potential's arguments.

    Raises
    ------
    TypeError
        A keyword neither a setting nor an argument of the potential.
    """
    mine = {k: v for k, v in kwargs.items() if k in SETTINGS}
    of_potential = {k: v for k, v in kwargs.items() if k not in SETTINGS}
    if of_potential:
        base = mine.get("potential", current["potential"])
        try:
            mine["potential"] = base.replace(**of_potential)
        except TypeError as err:
            raise TypeError(f"set: {err}; MLGCalculator's own settings are "
                            f"{', '.join(SETTINGS)}") from None
    args = mine["potential"].todict() if of_potential else {}
    old_args = current["potential"].todict() if of_potential else {}
    changed = {k: v for k, v in kwargs.items()
               if (k in of_potential and not _same(args.get(k), old_args.get(k)))
               or (k in SETTINGS and not _same(v, current[k]))}
    return changed, {**current, **mine}


def _same(a, b):
    # potentials and policies by identity, numbers and dicts by value
    if a is b:
        return True
    if isinstance(a, (PairPotential, type(None))) or isinstance(b, (PairPotential, type(None))):
        return False
    try:
        return bool(np.array_equal(a, b)) if not isinstance(a, Mapping) else a == b
    except (TypeError, ValueError):
        return False
