"""``VelocityVerlet``: ASE's NVE integrator with a compiled step."""

from ase.md.verlet import VelocityVerlet as _ASEVelocityVerlet

from .kernels import no_fixed, verlet_drift, verlet_drift_rattle, verlet_kick
from .checks import check_dynamics_args
from .fastpath import CompiledRefresh, compiled_reason, fixed_mask, forces_now, rank_trajectory

__all__ = ["VelocityVerlet"]


def _readonly(a):
    v = a.view()
    v.flags.writeable = False
    return v


class VelocityVerlet(CompiledRefresh, _ASEVelocityVerlet):
    """Velocity Verlet (NVE), a drop-in for :class:`ase.md.verlet.VelocityVerlet`.

    Same constructor, observers (``attach``), ``run`` / ``irun``,
    ``trajectory``, ``logfile``, ``loginterval``, ``nsteps`` and
    ``max_steps`` as ASE's class, which it subclasses; only :meth:`step`
    differs.  The step is one compiled pass before the force call and one
    after it, in place on ``atoms.arrays['positions']`` and
    ``['momenta']``, reproducing ASE's arithmetic (and so its trajectory)
    bit for bit.  It works with any ASE calculator; with an
    :class:`~ase_mlg.MLGCalculator` the forces are read without a copy.

    Parameters
    ----------
    atoms : ase.Atoms
        The system; its calculator gives the forces.
    timestep : float
        Time step in ASE time units (e.g. ``5 * ase.units.fs``), finite and > 0.
    trajectory : str, Path or Trajectory, optional
        As in ASE.
    logfile : str or file, optional
        As in ASE (``'-'``: standard output).
    loginterval : int, default 1
        Steps between log lines and trajectory frames, >= 1.
    **kwargs
        ``append_trajectory``, ``master``, ``comm``: as in ASE.

    Notes
    -----
    Constraints: :class:`ase.constraints.FixAtoms` runs compiled, exactly
    as ASE applies it (fixed atoms keep their positions, their momenta are
    zeroed, the other momenta go through ASE's RATTLE expression).  Any
    other constraint, a filter instead of an Atoms, or unusual position or
    momentum arrays run ASE's own step, unchanged; :attr:`path` says which
    path the last step took.
    """

    def __init__(self, atoms, timestep, trajectory=None, logfile=None,
                 loginterval=1, **kwargs):
        check_dynamics_args(atoms, timestep, loginterval)
        trajectory = rank_trajectory(atoms, trajectory, kwargs.get("append_trajectory", False))
        self.path = None
        self._fresh = False
        super().__init__(atoms, timestep, trajectory=trajectory, logfile=logfile,
                         loginterval=loginterval, **kwargs)

    def step(self, forces=None):
        """One velocity Verlet step; returns the forces at the new positions
        (eV/Å, read-only on the compiled path)."""
        atoms = self.atoms
        reason = compiled_reason(atoms)
        self._fresh = False
        if reason is not None:
            self.path, self._untouched = "ase: " + reason, None
            return super().step(forces)
        self.path = "compiled"
        n = len(atoms)
        f, m, known = self._start(atoms, forces)
        x = atoms.arrays["positions"]
        p = atoms.arrays["momenta"]
        dt = float(self.dt)
        if atoms.constraints:
            fixed = fixed_mask(atoms)
            verlet_drift_rattle(x, p, f, m, dt, fixed)
        else:
            fixed = no_fixed(n)
            verlet_drift(x, p, f, m, dt)
        # the calculator sees the new positions through check_state (the
        # arrays were written in place, as ASE's set_array does); momenta
        # are stored before the force call, as ASE does for Asap.  Read
        # them again after it: a distributed system migrates atoms there.
        # The step lets go of its arrays first, so that the old forces (and
        # a rank's pre-migration positions and momenta) are freed before the
        # rebuild's peak, not after: 37 MB a rank at 2 ranks of 10^6 atoms
        x = p = f = None
        f = forces_now(atoms, known=known)
        p = atoms.arrays["momenta"]
        verlet_kick(p, f, dt, fixed if len(fixed) == len(p) else no_fixed(len(p)))
        self._end(atoms, m)
        return _readonly(f)

