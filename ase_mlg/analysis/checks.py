"""Argument checks shared by both RDF front ends and ``ase-mlg rdf``, and
the one-line form of a caught exception's message for their errors.

Each check returns the value in its plain Python type or raises a one-line
``ValueError`` that names the argument (``name``: the keyword, or the CLI's
option).
"""

import numbers

import numpy as np

__all__ = ["check_nbins", "check_rmax", "check_template", "one_line"]


def check_nbins(nbins, name="nbins"):
    """A number of bins: an integer >= 1 (not a bool)."""
    if isinstance(nbins, (bool, np.bool_)) or not isinstance(nbins, (numbers.Integral, np.integer)):
        raise ValueError(f"{name}: expected an integer number of bins, got {nbins!r}")
    if nbins < 1:
        raise ValueError(f"{name}: must be >= 1, got {nbins}")
    return int(nbins)


def check_rmax(rmax, name="rmax"):
    """A largest distance (Å): finite and > 0."""
    try:
        r = float(rmax)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number (Å), got {rmax!r}") from None
    if not np.isfinite(r) or r <= 0:
        raise ValueError(f"{name}: must be finite and > 0 Å, got {rmax!r}")
    return r


def check_template(template, name="template"):
    """A template width: None (exact pairs) or an odd integer W >= 1."""
    if template is None:
        return None
    if (isinstance(template, (bool, np.bool_))
            or not isinstance(template, (numbers.Integral, np.integer))
            or template < 1 or template % 2 == 0):
        raise ValueError(f"{name}: expected an odd template width W >= 1 "
                         f"(3, 5, 7, ...) or None for exact pairs, got {template!r}")
    return int(template)


def one_line(exc, limit=300):
    """An exception's message on one line, cut to ``limit`` characters
    (MDAnalysis's format errors list every format it knows)."""
    msg = " ".join(str(exc).split()) or type(exc).__name__
    return msg if len(msg) <= limit else msg[:limit - 3] + "..."
