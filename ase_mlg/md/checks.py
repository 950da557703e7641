"""Argument checks of the integrators: clear errors that name the argument.

ASE's integrators accept almost anything and fail later, deep in a step
(a string time step, a negative friction); these checks fail at
construction instead.
"""

import numbers

import numpy as np

__all__ = ["check_dynamics_args", "check_real", "check_langevin_args"]


def check_real(name, value, *, positive=False, nonnegative=False, allow_array=False):
    """Check that ``value`` is a finite real number (or, with
    ``allow_array``, an array of them) and return it unchanged.

    Raises
    ------
    TypeError
        If it is not a real number (bools and strings included).
    ValueError
        If it is not finite, or breaks ``positive`` / ``nonnegative``.
    """
    if isinstance(value, (bool, np.bool_)) or isinstance(value, (str, bytes)):
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__}")
    if isinstance(value, numbers.Real):
        arr = np.float64(value)
    elif allow_array:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise TypeError(f"{name}: expected a real number or an array of them, "
                            f"got {type(value).__name__}") from None
    else:
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    if positive and not np.all(arr > 0):
        raise ValueError(f"{name}: must be > 0, got {value!r}")
    if nonnegative and not np.all(arr >= 0):
        raise ValueError(f"{name}: must be >= 0, got {value!r}")
    return value


def check_dynamics_args(atoms, timestep, loginterval):
    """The arguments every integrator shares.

    Parameters
    ----------
    atoms : object
        Must have ASE's ``get_positions`` (an Atoms or a filter).
    timestep : float
        ASE time units; finite and > 0 (run backwards by negating the
        momenta).
    loginterval : int
        >= 1.
    """
    if not hasattr(atoms, "get_positions") or not hasattr(atoms, "get_masses"):
        raise TypeError(f"atoms: expected an ase.Atoms, got {type(atoms).__name__}")
    check_real("timestep", timestep, positive=True)
    if isinstance(loginterval, (bool, np.bool_)) or not isinstance(loginterval, numbers.Integral):
        raise TypeError(f"loginterval: expected an int, got {type(loginterval).__name__}")
    if loginterval < 1:
        raise ValueError(f"loginterval: must be >= 1, got {loginterval}")


def check_langevin_args(temperature, temperature_K, friction, fixcm, rng):
    """The arguments of :class:`~ase_mlg.md.Langevin` beyond the shared ones.

    Parameters
    ----------
    temperature : float or None
        eV (ASE's deprecated spelling); exactly one of it and ``temperature_K``.
    temperature_K : float or None
        K, >= 0 (an array of one per atom is accepted, as in ASE).
    friction : float
        1 / ASE time units, >= 0 (per-atom arrays accepted, as in ASE).
    fixcm : bool
    rng : object or None
        With a ``standard_normal(size=...)`` method (numpy's Generator or
        RandomState, or the ``numpy.random`` module).
    """
    if friction is None:
        raise TypeError("friction: missing (e.g. friction=0.01 / ase.units.fs)")
    check_real("friction", friction, nonnegative=True, allow_array=True)
    if (temperature is None) == (temperature_K is None):
        raise TypeError("temperature_K: give exactly one of temperature_K (K) "
                        "and temperature (eV, deprecated)")
    if temperature_K is not None:
        check_real("temperature_K", temperature_K, nonnegative=True, allow_array=True)
    else:
        check_real("temperature", temperature, nonnegative=True, allow_array=True)
    if not isinstance(fixcm, (bool, np.bool_)):
        raise TypeError(f"fixcm: expected a bool, got {type(fixcm).__name__}")
    if rng is not None and not callable(getattr(rng, "standard_normal", None)):
        raise TypeError(f"rng: expected a random number generator with a "
                        f"standard_normal method (e.g. numpy.random.default_rng(seed)), "
                        f"got {type(rng).__name__}")
