"""When the compiled MD step may run, and what it reads and writes.

The compiled step updates ``atoms.arrays['positions']`` and
``atoms.arrays['momenta']`` in place.  That is what ASE itself does:
``Atoms.set_positions`` and ``set_momenta`` end in ``set_array``, which
copies into the existing array (``b[:] = a``), so the array objects never
change and a calculator can only notice new positions by comparing them
with the copy of the atoms it stored at its last calculation (ASE's
``check_state``; ``MLGCalculator.check_state`` too).  In-place edits are
therefore seen exactly as ASE's own writes are (``tests/test_md.py``
checks it).

The step runs compiled only when it can reproduce ASE's step exactly:

* ``atoms`` is an :class:`ase.Atoms` whose position, momentum, mass and
  force methods are ASE's own (not a filter or a subclass that changes
  them);
* every constraint is a plain :class:`ase.constraints.FixAtoms`
  (fixed positions, zeroed momenta, as ASE applies them);
* positions and momenta are C-contiguous, writeable float64 ``(N, 3)``
  arrays and the masses are finite and positive.

Otherwise the step is ASE's own, unchanged (``path`` says which and why):
any other constraint is applied exactly as ASE applies it, at ASE's speed.
"""

import os

import numpy as np
from ase import Atoms
from ase.constraints import FixAtoms
from ase.data import atomic_masses
from ase.md.md import MolecularDynamics

from ..calculator import MLGCalculator
from ..ranks import RankEngine, Trajectory, is_distributed

__all__ = ["compiled_reason", "masses_now", "fixed_mask", "forces_now",
           "as_float_array", "is_mlg"]

_ATOMS_METHODS = ("set_positions", "get_positions", "set_momenta", "get_momenta",
                  "get_masses", "get_velocities", "get_forces", "set_array")


def _is_plain_atoms(atoms):
    if not isinstance(atoms, Atoms):
        return False
    cls = type(atoms)
    return cls is Atoms or all(getattr(cls, name) is getattr(Atoms, name)
                               for name in _ATOMS_METHODS)


def _state_array(a, n):
    return (isinstance(a, np.ndarray) and a.dtype == np.float64 and a.shape == (n, 3)
            and a.flags.c_contiguous and a.flags.writeable and a.flags.aligned)


def compiled_reason(atoms):
    """Why the compiled step cannot run on ``atoms`` (None: it can).

    Parameters
    ----------
    atoms : object
        What the integrator was given.

    Returns
    -------
    str or None
        A short reason, e.g. ``"constraint FixBondLength"``.
    """
    if not _is_plain_atoms(atoms):
        return f"atoms is a {type(atoms).__name__}, not a plain ase.Atoms"
    for c in atoms.constraints:
        if type(c) is not FixAtoms:
            return f"constraint {type(c).__name__}"
    n = len(atoms)
    arrays = atoms.arrays
    if not _state_array(arrays.get("positions"), n):
        return "positions are not a writeable C-contiguous float64 (N, 3) array"
    if not _state_array(arrays.get("momenta"), n):
        return "momenta are not a writeable C-contiguous float64 (N, 3) array"
    return None


def masses_now(atoms):
    """``atoms.get_masses()`` without its copy when the atoms store masses.

    Parameters
    ----------
    atoms : ase.Atoms

    Returns
    -------
    (N,) float64 C-contiguous array
        Masses (amu); a view of ``atoms.arrays['masses']`` when present
        (the kernels only read it).
    """
    m = atoms.arrays.get("masses")
    if m is None:
        m = atomic_masses[atoms.arrays["numbers"]]
    return np.ascontiguousarray(m, dtype=np.float64)


def fixed_mask(atoms):
    """Which atoms the atoms' FixAtoms constraints fix.

    Parameters
    ----------
    atoms : ase.Atoms
        Every constraint a FixAtoms (see :func:`compiled_reason`).

    Returns
    -------
    (N,) bool array
    """
    mask = np.zeros(len(atoms), dtype=np.bool_)
    for c in atoms.constraints:
        mask[c.index] = True
    return mask


def as_float_array(a, n, name="forces"):
    """``a`` as a C-contiguous float64 ``(N, 3)`` array (no copy if it is one).

    Raises
    ------
    ValueError
        If the shape is not ``(N, 3)``.
    """
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.shape != (n, 3):
        raise ValueError(f"{name}: expected shape ({n}, 3), got {a.shape}")
    return a


def rank_trajectory(atoms, trajectory, append):
    """The dynamics' ``trajectory`` argument for ``atoms``: a file name
    becomes a :class:`ase_mlg.ranks.Trajectory` on a distributed system
    (written once, by rank 0, in the original order); anything else as is."""
    if is_distributed(atoms) and isinstance(trajectory, (str, os.PathLike)):
        return Trajectory(trajectory, "a" if append else "w", atoms)
    return trajectory


def is_mlg(atoms):
    """Is the atoms' calculator an :class:`~ase_mlg.MLGCalculator` (exactly:
    a subclass may compute differently)?"""
    return type(atoms.calc) is MLGCalculator


def forces_now(atoms, known=None):
    """The forces of ASE's ``atoms.get_forces(md=True)`` for the compiled step.

    With FixAtoms only, ``get_forces(md=True)`` applies no constraint (ASE
    constrains momenta in MD, not forces), so the forces are the
    calculator's.  An :class:`~ase_mlg.MLGCalculator` hands over its own
    result array (read only, never written): the same steps as ASE's
    ``Calculator.get_property`` without its final copy and without its
    ``atoms.copy()`` before ``calculate`` (``MLGCalculator.calculate``
    brings its stored atoms up to date in place).  ``check_state`` runs
    here, at most once a call: ``calculate`` does not repeat it.  Any other
    calculator goes through ``atoms.get_forces(md=True)``.

    Parameters
    ----------
    atoms : ase.Atoms
    known : list of str, optional
        What the caller knows changed since the calculator's last call
        (``[]``: nothing; ``["positions"]``: the positions it wrote itself,
        the calculator in step with the atoms before): ``check_state``'s
        comparison of every atom's position and number is skipped.  On a
        distributed system the ranks still take the union of what each saw
        (one small reduction, as ``check_state`` does), so every rank makes
        the same collective calls whatever each one knew.

    Returns
    -------
    (N, 3) float64 C-contiguous array
        Forces (eV/Å); the kernels must not write to it.
    """
    calc = atoms.calc
    if not is_mlg(atoms):
        return as_float_array(atoms.get_forces(md=True), len(atoms))
    if known is None or calc.atoms is None:
        changes = calc.check_state(atoms)
    elif is_distributed(atoms):
        changes = RankEngine.union(atoms.comm, known)
    else:
        changes = known
    if changes:
        # the stored atoms stay: calculate() updates their positions in
        # place instead of copying the whole Atoms object every step
        calc.results = {}
    if "forces" not in calc.results:
        calc.calculate(atoms, ["forces"], changes)
        if calc.atoms is None:
            # a calculate() that did not store the atoms would make every
            # later check see all changes (a force call per check)
            calc.atoms = atoms.copy()
    return as_float_array(calc.results["forces"], len(atoms))


class CompiledRefresh:
    """Mixin of the compiled integrators: what a step reads at its start,
    and ASE's ``_refresh_properties`` without its extra force call where
    the step left fresh results.

    ASE calls ``atoms.get_forces()`` there only to have the results cached
    for loggers and observers.  Right after a compiled step (irun calls
    this next, ``nsteps > 0``) the calculator holds the results of the
    current positions already (the step's second force call); otherwise,
    with MLGCalculator, caching needs no copy.

    Inside :meth:`run`, nothing but ASE's loop and the observers runs
    between two steps: no user code (``irun`` yields to it, ``run`` does
    not).  After a compiled step with an :class:`~ase_mlg.MLGCalculator`,
    and until an observer is due, the atoms are therefore as the step left
    them, and the next step takes that step's forces (and, on one process,
    masses) as they are: ASE's check of the state at a step's start (every
    position and atomic number compared with the calculator's copy; 0.11
    ms a step at 10,976 atoms on AMD Zen 3 once the pair sum has pushed
    them out of the cache) and the masses' lookup are skipped.  An
    observer due at a step (ASE's rule: ``interval > 0`` and ``nsteps %
    interval == 0``; any ``interval <= 0`` is taken as due) may edit the
    atoms, so the step after it checks them as ASE does.  On a distributed
    system the ranks still agree on what changed (:func:`forces_now`'s
    ``known``): an observer attached on one rank only checks there and
    the others follow.  Another Python thread editing the atoms during
    ``run`` is a race, in ASE as here.
    """

    _fresh = False
    _sealed = False     # inside run(), with MolecularDynamics.log (a no-op)
    _untouched = None   # (calculator, masses) the last step left, while they hold

    def run(self, steps=50):
        self._sealed = type(self).log is MolecularDynamics.log
        try:
            return super().run(steps)
        finally:
            self._sealed, self._untouched = False, None

    def call_observers(self):
        if any(i <= 0 or self.nsteps % i == 0 for _, i, _, _ in self.observers):
            self._untouched = None
        super().call_observers()

    def _start(self, atoms, forces):
        """Forces (eV/Å) and masses (amu) at a step's start, and what the
        step's force call after the drift may pass as :func:`forces_now`'s
        ``known`` (None: nothing; the calculator not an MLGCalculator or
        not in step with the atoms)."""
        kept, self._untouched = self._untouched, None
        n = len(atoms)
        if forces is not None:
            return as_float_array(forces, n), masses_now(atoms), None
        if not is_mlg(atoms):
            return forces_now(atoms), masses_now(atoms), None
        if kept is None or atoms.calc is not kept[0]:
            return forces_now(atoms), masses_now(atoms), ["positions"]
        # migration may have changed a rank's atoms in the last force call
        m = masses_now(atoms) if kept[1] is None else kept[1]
        return forces_now(atoms, known=[]), m, ["positions"]

    def _end(self, atoms, masses):
        """A compiled step ended: its results are fresh; inside run() its
        forces and masses hold until anything else may run."""
        self._fresh = True
        if self._sealed and is_mlg(atoms):
            self._untouched = (atoms.calc, None if is_distributed(atoms) else masses)

    def _refresh_properties(self):
        if self._fresh and self.nsteps > 0:
            self._fresh = False
            return
        if is_mlg(self.atoms) and compiled_reason(self.atoms) is None:
            forces_now(self.atoms)
        else:
            super()._refresh_properties()
