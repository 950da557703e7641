"""Fused, compiled position and momentum updates of the MD integrators.

Each kernel is one pass over the atoms, in place on the arrays it is given
(``atoms.arrays['positions']``, ``atoms.arrays['momenta']`` and the
integrators' own buffers).  They reproduce ASE's numpy expressions
operation by operation, in the same order and with the same roundings
(numba compiles without fast-math, so no reassociation or fused
multiply-add), which is why the trajectories agree with ASE's bit for bit
and not only to a tolerance.  The ASE line each one replaces is quoted
beside it.

Units are ASE's: positions Å, momenta amu Å / (ASE time), forces eV/Å,
masses amu, time steps ASE time units.

The kernels divide under numpy's error model, as ASE's numpy expressions
do (a zero mass gives inf, not a ZeroDivisionError), and index their
(N, 3) arrays through flat views: the check Python's model puts before
every division, and the run-time row stride of 2-D indexing, kept the
compiler from vectorising the division (AMD Zen 4, 10,976 atoms: the drift
53 -> 26 µs, the same bits).
"""

from collections import namedtuple

import numba
import numpy as np
from ..jit import njit

from ..pairlist import flat

__all__ = ["verlet_drift", "verlet_drift_rattle", "verlet_kick",
           "langevin_noise", "langevin_drift", "langevin_kick", "no_fixed",
           "indexed_normals", "LangevinCoefficients", "NoiseCorrection"]

#: The scalar coefficients of a Langevin step: ``c1`` (ASE time) and ``c2``
#: (dimensionless) of ``Langevin.updatevars``, and the time step ``dt``
#: (ASE time units).
LangevinCoefficients = namedtuple("LangevinCoefficients", "c1 c2 dt")

#: ASE's ``fixcm`` correction of the Langevin noise: ``fixcm`` (bool),
#: ``spos`` = ``rnd_pos.sum(axis=0)`` and ``svel`` = ``(rnd_vel *
#: masses).sum(axis=0)`` ((3,) float64, numpy's sums so that the rounding is
#: ASE's), ``factor`` = ``sqrt(N / (N - 1))`` and ``natoms`` = N (float; the
#: whole system's on a distributed one); not read without ``fixcm``.
NoiseCorrection = namedtuple("NoiseCorrection", "fixcm spos svel factor natoms")


@njit(cache=True, error_model="numpy")
def verlet_drift(x, p, f, m, dt):
    """First half of a velocity Verlet step, no constraints.

    ``p += 0.5 dt f`` then ``x += dt p / m``, in place.

    Parameters
    ----------
    x : (N, 3) float64 array
        Positions (Å), updated in place.
    p : (N, 3) float64 array
        Momenta (amu Å / ASE time), updated in place.
    f : (N, 3) float64 array
        Forces (eV/Å) at ``x``.
    m : (N,) float64 array
        Masses (amu).
    dt : float
        Time step (ASE time units).
    """
    h = 0.5 * dt                               # ASE: 0.5 * self.dt * forces
    U = numba.uint64
    xf, pf, ff = flat(x), flat(p), flat(f)
    for a in range(U(x.shape[0])):
        ma = m[a]
        for c in range(U(3)):
            e = U(3) * a + c
            pc = pf[e] + h * ff[e]             # p += 0.5 * dt * forces
            pf[e] = pc
            xf[e] = xf[e] + dt * pc / ma       # r + self.dt * p / masses


@njit(cache=True, error_model="numpy")
def verlet_drift_rattle(x, p, f, m, dt, fixed):
    """First half of a velocity Verlet step with fixed atoms (FixAtoms).

    As :func:`verlet_drift`, then what ASE does when the atoms carry any
    constraint: fixed atoms keep their positions (``adjust_positions``) and
    every momentum is recomputed from the displacement,
    ``p = (x_new - x) m / dt`` (the first half of RATTLE), which rounds
    differently from the ``p`` it came from; fixed atoms get exactly 0.

    Parameters
    ----------
    x, p, f, m, dt
        As :func:`verlet_drift`.
    fixed : (N,) bool array
        True where the atom is fixed.
    """
    h = 0.5 * dt
    for a in range(x.shape[0]):
        ma = m[a]
        fix = fixed[a]
        for c in range(3):
            r = x[a, c]
            pc = p[a, c] + h * f[a, c]
            xn = r if fix else r + dt * pc / ma
            x[a, c] = xn
            # p = (atoms.get_positions() - r) * masses / self.dt
            p[a, c] = (xn - r) * ma / dt


@njit(cache=True, error_model="numpy")
def verlet_kick(p, f, dt, fixed):
    """Second half of a velocity Verlet step: ``p += 0.5 dt f``, in place;
    momenta of fixed atoms zeroed (``FixAtoms.adjust_momenta``).

    Parameters
    ----------
    p : (N, 3) float64 array
        Momenta (amu Å / ASE time), updated in place.
    f : (N, 3) float64 array
        Forces (eV/Å) at the new positions.
    dt : float
        Time step (ASE time units).
    fixed : (N,) bool array
        True where the atom is fixed (all False without constraints).
    """
    h = 0.5 * dt
    U = numba.uint64
    pf, ff = flat(p), flat(f)
    for a in range(U(p.shape[0])):
        keep = not fixed[a]
        for c in range(U(3)):
            e = U(3) * a + c
            pf[e] = pf[e] + h * ff[e] if keep else 0.0


@njit(cache=True, error_model="numpy")
def langevin_noise(xi, eta, c3, c4, c5, rnd_pos, rnd_vel):
    """The random displacements and velocity kicks of ASE's Langevin step.

    ``rnd_pos = c5 eta`` and ``rnd_vel = c3 xi - c4 eta``, into the given
    buffers.

    Parameters
    ----------
    xi, eta : (N, 3) float64 arrays
        Standard normal draws, in ASE's order (``xi`` first).
    c3, c4, c5 : (N,) float64 arrays
        Per-atom coefficients of ``Langevin.updatevars`` (Å/ASE time, 1/ASE
        time x Å, Å).
    rnd_pos, rnd_vel : (N, 3) float64 arrays
        Outputs (Å, Å / ASE time).
    """
    for a in range(xi.shape[0]):
        for c in range(3):
            rnd_pos[a, c] = c5[a] * eta[a, c]
            rnd_vel[a, c] = c3[a] * xi[a, c] - c4[a] * eta[a, c]


@njit(cache=True, error_model="numpy")
def langevin_drift(x, v, p, f, m_now, m, rnd_pos, rnd_vel, com, coef, fixed):
    """First half of ASE's Langevin step (Vanden-Eijnden and Ciccotti,
    Eq. 23), in place.

    ``v = p / m``; with ``com.fixcm`` the noise is made momentum-free and
    rescaled (``rnd_pos -= spos / N``, ``rnd_vel -= svel / (m N)``, both
    times ``factor``, written back to the buffers as ASE keeps them);
    ``v += c1 f / m - c2 v + rnd_vel``; ``x += dt v + rnd_pos`` except for
    fixed atoms; then ``v = (x_new - x - rnd_pos) / dt``.

    Parameters
    ----------
    x : (N, 3) float64 array
        Positions (Å), updated in place.
    v : (N, 3) float64 array
        Output: velocities (Å / ASE time) after the drift.
    p : (N, 3) float64 array
        Momenta (amu Å / ASE time), read.
    f : (N, 3) float64 array
        Forces (eV/Å) at ``x``.
    m_now : (N,) float64 array
        The atoms' masses now (amu; ASE's ``get_velocities`` divides by them).
    m : (N,) float64 array
        The masses the integrator was set up with (amu; ``self.masses``).
    rnd_pos, rnd_vel : (N, 3) float64 arrays
        From :func:`langevin_noise`; corrected in place when ``com.fixcm``.
    com : NoiseCorrection
        ASE's ``fixcm`` and the sums and factor of its centre-of-mass
        correction.
    coef : LangevinCoefficients
        ``c1``, ``c2`` of ``updatevars`` and the time step ``dt``.
    fixed : (N,) bool array
        True where the atom is fixed (FixAtoms).
    """
    fixcm = com.fixcm
    spos = com.spos
    svel = com.svel
    factor = com.factor
    c1 = coef.c1
    c2 = coef.c2
    dt = coef.dt
    n = x.shape[0]
    fn = com.natoms
    for a in range(n):
        mn = m_now[a]
        ma = m[a]
        fix = fixed[a]
        for c in range(3):
            rp = rnd_pos[a, c]
            rv = rnd_vel[a, c]
            if fixcm:
                rp = (rp - spos[c] / fn) * factor
                rv = (rv - svel[c] / (ma * fn)) * factor
                rnd_pos[a, c] = rp
                rnd_vel[a, c] = rv
            vc = p[a, c] / mn                               # get_velocities()
            vc = vc + ((c1 * f[a, c] / ma - c2 * vc) + rv)  # self.v += ...
            r = x[a, c]
            xn = r if fix else (r + dt * vc) + rp           # x + dt * v + rnd_pos
            x[a, c] = xn
            v[a, c] = ((xn - r) - rp) / dt                  # (x_new - x - rnd_pos) / dt


@njit(cache=True, error_model="numpy")
def langevin_kick(v, p, f, m, rnd_vel, c1, c2, fixed):
    """Second half of ASE's Langevin step, in place:
    ``v += c1 f / m - c2 v + rnd_vel``, ``p = v m`` (0 for fixed atoms).

    Parameters
    ----------
    v : (N, 3) float64 array
        Velocities (Å / ASE time), updated in place.
    p : (N, 3) float64 array
        Output: momenta (amu Å / ASE time).
    f : (N, 3) float64 array
        Forces (eV/Å) at the new positions.
    m : (N,) float64 array
        The integrator's masses (amu).
    rnd_vel : (N, 3) float64 array
        The step's velocity kicks (Å / ASE time).
    c1, c2 : float
        Coefficients of ``updatevars``.
    fixed : (N,) bool array
        True where the atom is fixed.
    """
    for a in range(v.shape[0]):
        ma = m[a]
        fix = fixed[a]
        for c in range(3):
            vc = v[a, c]
            vc = vc + ((c1 * f[a, c] / ma - c2 * vc) + rnd_vel[a, c])
            v[a, c] = vc
            p[a, c] = 0.0 if fix else vc * ma


def no_fixed(n):
    """The all-False mask of ``n`` atoms (no FixAtoms)."""
    return np.zeros(n, dtype=np.bool_)


@njit(cache=True, error_model="numpy")
def _mix64(z):
    # splitmix64's finaliser (Steele, Lea and Flood 2014): a bijection of
    # 64-bit words whose outputs pass BigCrush for consecutive inputs
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, error_model="numpy")
def indexed_normals(seed, step, indices, xi, eta):
    """Standard normal draws keyed by (seed, step, atom index, component):
    the noise of a distributed Langevin run, the same for an atom whichever
    rank owns it (so the trajectory does not depend on the rank count).

    Each (atom, step) gets the 64-bit key ``mix(seed + mix(step) + index)``;
    the six draws of ``xi`` then ``eta`` come from the counters key + 1..6
    through splitmix64 and the Box-Muller transform.

    Parameters
    ----------
    seed, step : int
        The run's seed (from its rng) and the step number.
    indices : (n,) int64
        Original indices of the atoms.
    xi, eta : (n, 3) float64
        Outputs.
    """
    gamma = np.uint64(0x9E3779B97F4A7C15)
    base = np.uint64(seed) + _mix64(np.uint64(step) * gamma)
    scale = 1.0 / 9007199254740992.0  # 2^-53
    for a in range(indices.shape[0]):
        key = _mix64(base + np.uint64(indices[a]) * gamma)
        for c in range(3):
            for which in range(2):
                k = np.uint64(2 * c + which)
                u1 = (float(_mix64(key + (k + np.uint64(1)) * gamma) >> np.uint64(11)) + 1.0) * scale
                u2 = float(_mix64(key + (k + np.uint64(7)) * gamma) >> np.uint64(11)) * scale
                g = np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
                if which == 0:
                    xi[a, c] = g
                else:
                    eta[a, c] = g
