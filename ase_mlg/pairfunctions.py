"""The pair functions of the built-in potentials, compiled by numba.

A pair function maps a distance and a row of parameters to the pair energy
and its derivative: ``(r, p) -> (e, dE/dr)``, or in the squared form
``(r**2, p) -> (e, dE/dr / r)`` (no square root).  These follow ASE's
``ase.calculators.lj`` and ``ase.calculators.morse`` to the operation, so
energies and forces agree with ASE to rounding.  Units: Å, eV.
"""

import math

from .jit import njit

__all__ = ["lennard_jones_shifted_r2", "lennard_jones_smooth_r2",
           "lennard_jones_shifted", "lennard_jones_smooth", "morse"]


@njit(cache=True, inline='always', error_model='numpy')
def _lj(r2, sigma, epsilon):
    # Same operation order as ase.calculators.lj, so results agree to rounding.
    c6 = (sigma * sigma / r2) ** 3
    c12 = c6 * c6
    return 4.0 * epsilon * (c12 - c6), -24.0 * epsilon * (2.0 * c12 - c6) / r2


@njit(cache=True, error_model='numpy')
def lennard_jones_shifted_r2(r2, p):
    """Lennard-Jones shifted to zero at the cutoff (ASE ``smooth=False``),
    squared form (``squared=True`` in
    :class:`~ase_mlg.potentials.PairPotential`).

    ``p = [sigma (Å), epsilon (eV), shift (eV)]`` where ``shift`` is the
    unshifted energy at the cutoff.  Takes ``r**2`` (Å²) and returns
    ``(e, dE/dr / r)``: no square root, and the force is ASE's expression
    to the last bit.
    """
    e, du = _lj(r2, p[0], p[1])
    return e - p[2], du


@njit(cache=True, error_model='numpy')
def lennard_jones_smooth_r2(r2, p):
    """Lennard-Jones times ASE's C^1 cutoff function between ro and rc,
    squared form: ``r**2`` (Å²) -> ``(e, dE/dr / r)``.

    ``p = [sigma (Å), epsilon (eV), rc (Å), ro (Å)]``.
    """
    e, du = _lj(r2, p[0], p[1])
    rc2 = p[2] * p[2]
    ro2 = p[3] * p[3]
    if r2 < ro2:
        return e, du
    if r2 >= rc2:
        return 0.0, 0.0
    # ASE's cutoff function is a polynomial in r**2, hence the factor 2 below.
    den = (rc2 - ro2) ** 3
    fc = (rc2 - r2) ** 2 * (rc2 + 2.0 * r2 - 3.0 * ro2) / den
    dfc = 6.0 * (rc2 - r2) * (ro2 - r2) / den
    return fc * e, fc * du + 2.0 * dfc * e


@njit(cache=True, error_model='numpy')
def lennard_jones_shifted(r, p):
    """:func:`lennard_jones_shifted_r2` as a function of ``r``:
    ``(e, dE/dr)``."""
    e, du = lennard_jones_shifted_r2(r * r, p)
    return e, du * r


@njit(cache=True, error_model='numpy')
def lennard_jones_smooth(r, p):
    """:func:`lennard_jones_smooth_r2` as a function of ``r``:
    ``(e, dE/dr)``."""
    e, du = lennard_jones_smooth_r2(r * r, p)
    return e, du * r


@njit(cache=True, error_model='numpy')
def morse(r, p):
    """Morse potential with ASE's quintic cutoff between rcut1 and rcut2.

    ``p = [epsilon (eV), r0 (Å), rho0, rcut1 (Å), rcut2 (Å)]``; the cutoffs
    here are absolute, already multiplied by ``r0``.  Returns ``(e, dE/dr)``.
    """
    epsilon, r0, rho0, r1, r2 = p[0], p[1], p[2], p[3], p[4]
    expf = math.exp(rho0 * (1.0 - r / r0))
    e = epsilon * expf * (expf - 2.0)
    de = (-2.0 * epsilon * rho0 / r0) * expf * (expf - 1.0)
    s = 1.0 - (r - r1) / (r2 - r1)
    if s >= 1.0:
        return e, de
    if s <= 0.0:
        return 0.0, 0.0
    fc = 6.0 * s**5 - 15.0 * s**4 + 10.0 * s**3
    dfc = -(30.0 * s**4 - 60.0 * s**3 + 30.0 * s**2) / (r2 - r1)
    return e * fc, de * fc + e * dfc
