"""``Langevin``: ASE's NVT Langevin integrator with a compiled step."""

import numpy as np
from ase.md.langevin import Langevin as _ASELangevin

from ..ranks import is_distributed
from ..ranks.comm import ordered_sum
from .kernels import (LangevinCoefficients, NoiseCorrection, indexed_normals, langevin_drift,
                      langevin_kick, langevin_noise, no_fixed)
from .checks import check_dynamics_args, check_langevin_args
from .fastpath import (CompiledRefresh, as_float_array, compiled_reason, fixed_mask, forces_now,
                       rank_trajectory)

__all__ = ["Langevin"]


def _per_atom(c, n):
    """A coefficient of ``updatevars`` as a contiguous (N,) float64 array,
    or None when it is not one value per atom (a per-atom friction)."""
    a = np.asarray(c, dtype=np.float64)
    if a.ndim == 0:
        return np.full(n, float(a))
    if a.shape in ((n, 1), (n,)):
        return np.ascontiguousarray(a.reshape(n))
    return None


class Langevin(CompiledRefresh, _ASELangevin):
    """Langevin dynamics (NVT), a drop-in for :class:`ase.md.langevin.Langevin`.

    ASE's algorithm (Vanden-Eijnden and Ciccotti 2006, Eq. 23) with ASE's
    random draws: per step ``xi`` then ``eta``, each
    ``rng.standard_normal(size=(N, 3))``, so the same ``rng`` seed gives
    ASE's trajectory bit for bit.  Same constructor, observers, ``run`` /
    ``irun``, trajectory and log as ASE's class, which it subclasses; the
    position and velocity updates of :meth:`step` are fused compiled
    passes in place on the atoms' arrays.

    Parameters
    ----------
    atoms : ase.Atoms
        The system; its calculator gives the forces.
    timestep : float
        Time step in ASE time units, finite and > 0.
    temperature : float, optional
        Deprecated: the temperature in eV (as ASE).
    friction : float
        Friction coefficient in 1 / ASE time units, >= 0 (e.g.
        ``0.01 / ase.units.fs``).
    fixcm : bool, default True
        As ASE (deprecated there since 3.28, with its FutureWarning): keep
        the centre of mass still.
    temperature_K : float
        The target temperature (K), >= 0.
    rng : numpy Generator or RandomState, optional
        ``numpy.random`` when None, as in ASE.
    **kwargs
        ``trajectory``, ``logfile``, ``loginterval``, ``append_trajectory``,
        ``master``, ``comm``: as in ASE.

    Notes
    -----
    On a distributed system (:func:`ase_mlg.distribute`) the draws are keyed
    by each atom's original index and the step
    (:func:`~ase_mlg.md.kernels.indexed_normals`, seeded once from ``rng``),
    so the trajectory is the same at any rank count; ``fixcm`` sums over
    all ranks.

    FixAtoms runs compiled as ASE applies it; other constraints (e.g. ones
    that redistribute the noise), filters, and per-atom temperature or
    friction arrays run ASE's own step, unchanged; :attr:`path` says which
    path the last step took.
    """

    def __init__(self, atoms, timestep, temperature=None, friction=None, fixcm=True,
                 *, temperature_K=None, rng=None, **kwargs):
        check_dynamics_args(atoms, timestep, kwargs.get("loginterval", 1))
        check_langevin_args(temperature, temperature_K, friction, fixcm, rng)
        if "trajectory" in kwargs:
            kwargs["trajectory"] = rank_trajectory(atoms, kwargs["trajectory"],
                                                   kwargs.get("append_trajectory", False))
        self.path = None
        self._fresh = False
        self._seed, self._draws = None, 0
        super().__init__(atoms, timestep, temperature=temperature, friction=friction,
                         fixcm=fixcm, temperature_K=temperature_K, rng=rng, **kwargs)

    def _coefficients(self, n):
        """c1, c2 (floats) and c3, c4, c5, masses (N,) for the kernels, or
        None when ASE's step must run (per-atom friction, changed N)."""
        if np.ndim(self.c1) or np.ndim(self.c2):
            return None
        m = self.masses
        if getattr(m, "shape", None) != (n, 1):
            return None
        c = [_per_atom(x, n) for x in (self.c3, self.c4, self.c5)]
        if any(x is None for x in c):
            return None
        return (float(self.c1), float(self.c2), *c, np.ascontiguousarray(m.reshape(n)))

    def _buffers(self, n):
        v = getattr(self, "_v", None)
        if v is None or v.shape != (n, 3):
            self._v = np.empty((n, 3))
            self._rnd_pos = np.empty((n, 3))
            self._rnd_vel = np.empty((n, 3))
        return self._v, self._rnd_pos, self._rnd_vel

    def _draw(self, atoms, n):
        """xi and eta, (n, 3) standard normals: ASE's draws, in ASE's order and
        shapes (the same rng state gives the same noise; FixAtoms has no
        redistribute_forces_md to apply), or on a distributed system the
        draws keyed by original index."""
        if is_distributed(atoms):
            if self._seed is None:
                self._seed = atoms.comm.bcast(int(self.rng.random() * 2.0 ** 53), root=0)
            xi, eta = np.empty((n, 3)), np.empty((n, 3))
            indexed_normals(self._seed, self._draws, atoms.indices, xi, eta)
            self._draws += 1
            return xi, eta
        xi = self.rng.standard_normal(size=(n, 3))
        eta = self.rng.standard_normal(size=(n, 3))
        self.comm.broadcast(xi, 0)
        self.comm.broadcast(eta, 0)
        return (as_float_array(xi, n, "rng.standard_normal"),
                as_float_array(eta, n, "rng.standard_normal"))

    def step(self, forces=None):
        """One Langevin step; returns the forces at the new positions (eV/Å,
        read-only on the compiled path)."""
        atoms = self.atoms
        n = len(atoms)
        reason = compiled_reason(atoms)
        distributed = is_distributed(atoms)
        if distributed and reason is None:
            # the owned atoms changed at the last rebuild: their own coefficients
            self.masses = atoms.get_masses().reshape(-1, 1)
            self.updatevars()
        coef = None if reason is not None else self._coefficients(n)
        self._fresh = False
        if coef is None:
            self.path = "ase: " + (reason or "per-atom friction or temperature")
            self._untouched = None
            return super().step(forces)
        self.path = "compiled"
        c1, c2, c3, c4, c5, m = coef
        f, m_now, known = self._start(atoms, forces)
        xi, eta = self._draw(atoms, n)
        v, rnd_pos, rnd_vel = self._buffers(n)
        langevin_noise(xi, eta, c3, c4, c5, rnd_pos, rnd_vel)
        nall = atoms.get_global_number_of_atoms() if distributed else n
        if self.fix_com and distributed:
            factor = float(np.sqrt(nall / (nall - 1.0)))
            spos = ordered_sum(atoms.comm, rnd_pos.sum(axis=0))
            svel = ordered_sum(atoms.comm, (rnd_vel * self.masses).sum(axis=0))
        elif self.fix_com:
            factor = float(np.sqrt(n / (n - 1.0)))
            # numpy's sums, as ASE takes them, so that the rounding is ASE's
            spos = rnd_pos.sum(axis=0)
            svel = (rnd_vel * self.masses).sum(axis=0)
        else:
            factor, spos, svel = 1.0, np.zeros(3), np.zeros(3)
        fixed = fixed_mask(atoms) if atoms.constraints else no_fixed(n)
        x = atoms.arrays["positions"]
        p = atoms.arrays["momenta"]
        dt = float(self.dt)
        langevin_drift(x, v, p, f, m_now, m, rnd_pos, rnd_vel,
                       NoiseCorrection(bool(self.fix_com), spos, svel, factor, float(nall)),
                       LangevinCoefficients(c1, c2, dt), fixed)
        # ASE stores the velocity and the noise as attributes (Asap reads them)
        self.v, self.rnd_pos, self.rnd_vel = v, rnd_pos, rnd_vel
        # the step's arrays let go before the force call (see VelocityVerlet.step);
        # rnd_pos stays alive as ASE's attribute
        x = p = f = xi = eta = None
        if distributed:
            # atoms may migrate in the force call: the half step's state goes with them
            atoms.arrays["mlg_langevin_v"], atoms.arrays["mlg_langevin_rnd_vel"] = v, rnd_vel
            f = forces_now(atoms, known=known)
            v = self.v = atoms.arrays.pop("mlg_langevin_v")
            rnd_vel = self.rnd_vel = atoms.arrays.pop("mlg_langevin_rnd_vel")
            p, m = atoms.arrays["momenta"], np.ascontiguousarray(atoms.get_masses())
            fixed = no_fixed(len(p))
        else:
            f = forces_now(atoms, known=known)
            p = atoms.arrays["momenta"]
        langevin_kick(v, p, f, m, rnd_vel, c1, c2, fixed)
        self._end(atoms, m_now)
        ro = f.view()
        ro.flags.writeable = False
        return ro
