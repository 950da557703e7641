"""Pair potentials evaluated by one generic numba kernel.

A pair potential is a numba-compiled pair function plus a table of parameter
rows, one row per species pair.  Every potential -- built-in or user-defined --
is evaluated by the fused kernel of :mod:`ase_mlg.pairsum` (through
:meth:`PairPotential.sum_pairs` and :meth:`PairPotential.evaluate`), with the
pair function inlined into its loop: the built-in pair functions have cached
kernels of their own, a user's pair function is a compile-time argument of
the generic kernel (:func:`ase_mlg.pairsum.pair_kernel`).

Units are those of ASE: distances in Å, energies in eV, forces in eV/Å,
virials in eV.

Writing your own pair potential
-------------------------------
1. Write the pair function.  It takes the distance ``r`` (Å, a float) and
   ``p``, the parameter row of the species pair (a C-contiguous float64 1-D
   array), and returns the pair energy (eV) and its derivative ``dE/dr``
   (eV/Å), both floats::

       @numba.njit(cache=True, error_model='numpy')
       def f(r, p):
           return e, dedr

   Its results count only for ``0 < r <= cutoff`` of the species pair
   (ASE's LJ keeps ``r == rc``; the kernel has no per-pair branch, so a pair
   at ``r = 0`` is evaluated too and then reported as an error), and it must
   not modify ``p`` (a view of the potential's table).  With
   ``error_model='numpy'`` it is also called on listed pairs just beyond
   the cutoff, results dropped (the loop vectorises); with numba's default
   error model, which raises, within the cutoff only.  Truncation, shifting
   or smoothing at the cutoff is the function's own business (see
   :func:`~ase_mlg.pairfunctions.lennard_jones_shifted`).  With
   ``error_model='numpy'`` a division by zero gives ``inf``, which the
   kernel reports with the offending pair; ``cache=True`` is recommended
   when the function lives in a file.  The function must compile for
   :data:`PAIR_SIGNATURE` (checked when the potential is built); the kernel
   takes it as a compile-time argument and inlines it, compiling the
   generic kernel for it once per process.

2. Build a :class:`PairPotential` with one row per *unordered* species pair
   (``('Ar', 'Kr')`` also defines ``('Kr', 'Ar')``) and a cutoff per pair, or a
   single cutoff for all pairs.  A single row instead of a dict makes the
   potential species-agnostic, like ASE's LJ and Morse calculators.

Examples
--------
A Buckingham potential for an argon-krypton mixture.  Buckingham energies
dive to minus infinity at short range, so ``rmin`` turns unphysically close
pairs into an error instead of a silent collapse.

>>> import numba, numpy as np
>>> from ase_mlg.potentials import PairPotential
>>> @numba.njit(error_model='numpy')
... def buckingham(r, p):
...     A, rho, C = p[0], p[1], p[2]
...     rep = A * np.exp(-r / rho)
...     return rep - C / r**6, -rep / rho + 6.0 * C / r**7
>>> pot = PairPotential(
...     buckingham,
...     params={('Ar', 'Ar'): [5000.0, 0.28, 60.0],
...             ('Ar', 'Kr'): [6000.0, 0.29, 90.0],
...             ('Kr', 'Kr'): [7000.0, 0.30, 130.0]},
...     cutoffs=8.0, rmin=1.5, nparams=3)
>>> pot.species
('Ar', 'Kr')
>>> res = pot.evaluate([18, 36], i=[0], j=[1], D=[[0.0, 0.0, 4.0]])
>>> bool(np.isclose(res['energy'], 6000 * np.exp(-4 / 0.29) - 90 / 4**6))
True

:func:`lennard_jones_mixture` is a worked example built the same way.
"""

import math
import re
from collections.abc import Mapping

import numba
import numpy as np
from ase.data import atomic_numbers, chemical_symbols
from numba import types as nbt
from numba.core.dispatcher import Dispatcher

from .pairfunctions import (lennard_jones_shifted, lennard_jones_shifted_r2,
                            lennard_jones_smooth, lennard_jones_smooth_r2, morse)
from .pairsum import (SumList, SumTables, bad_pair_error, built_in_form, is_built_in,
                      pair_kernel)
from .parallel import dynamic_schedule
from .chunks import RowChunks, row_chunks

__all__ = [
    'PairPotential',
    'LennardJones',
    'Morse',
    'lennard_jones_mixture',
    'lennard_jones_shifted',
    'lennard_jones_smooth',
    'morse',
    'PAIR_SIGNATURE',
]

#: Numba signature every pair function is compiled to: ``(r, p) -> (e, dedr)``.
PAIR_SIGNATURE = nbt.UniTuple(nbt.float64, 2)(nbt.float64, nbt.float64[::1])

# Voigt (N, 6) -> (N, 3, 3) by fancy indexing.
_VOIGT_TO_3X3 = np.array([[0, 5, 4], [5, 1, 3], [4, 3, 2]])


# ---------------------------------------------------------------- validation

def _number(name, value, minimum=None, strict=False):
    """Return ``value`` as a finite float, optionally bounded below."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be a number, got {value!r}') from None
    if not math.isfinite(x):
        raise ValueError(f'{name} must be finite, got {x}')
    if minimum is not None and (x <= minimum if strict else x < minimum):
        raise ValueError(
            f'{name} must be {">" if strict else ">="} {minimum}, got {x}')
    return x


def _atomic_number(species):
    if isinstance(species, str):
        if species not in atomic_numbers:
            raise ValueError(f'unknown element {species!r}')
        return atomic_numbers[species]
    if not (isinstance(species, (int, np.integer))
            and 0 < species < len(chemical_symbols)):
        raise ValueError(f'invalid element {species!r}')
    return int(species)


def _pair_key(key, what):
    if not (isinstance(key, tuple) and len(key) == 2):
        raise ValueError(f'{what} keys must be pairs like (\'Ar\', \'Kr\'), '
                         f'got {key!r}')
    return tuple(sorted(_atomic_number(s) for s in key))


def _pair_name(za, zb):
    return f'({chemical_symbols[za]}, {chemical_symbols[zb]})'


def _pair_dict(mapping, what):
    """``{(A, B): value}`` -> ``{(za, zb): value}`` with ``za <= zb``."""
    out = {}
    for key, value in mapping.items():
        zz = _pair_key(key, what)
        if zz in out and not np.array_equal(out[zz], value):
            raise ValueError(f'{what} for {_pair_name(*zz)} given twice with '
                             f'different values')
        out[zz] = value
    return out


def _row(value, name):
    try:
        row = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        row = None
    if row is None or row.ndim != 1:
        raise ValueError(f'{name} must be a 1-D sequence of numbers, '
                         f'got {value!r}')
    if not np.all(np.isfinite(row)):
        raise ValueError(f'{name} contains non-finite values: {row}')
    return row


# ---------------------------------------------------------------- potentials

class PairPotential:
    """A pair potential: a numba pair function plus per-species-pair tables.

    Parameters
    ----------
    pair : numba.njit function ``(r, p) -> (e, dedr)``
        Pair energy (eV) and its derivative (eV/Å) at distance ``r`` (Å) for
        the parameter row ``p`` (float64 1-D array).
    params : dict or sequence of float
        ``{(A, B): row}`` with ``A``, ``B`` element symbols or atomic numbers;
        one entry per unordered pair of the species involved (``(A, B)``
        also defines ``(B, A)``).  A single row applies to every pair of
        elements (species-agnostic potential).
    cutoffs : dict or float
        Cutoff per species pair (same keys as ``params``) or one for all, Å.
        Pairs with ``d > cutoff`` contribute nothing (``d == cutoff`` is
        kept, as in ASE's LJ).
    rmin : dict or float, optional
        Closer pairs raise ``ValueError`` (use for potentials that are
        singular or unphysical at short range), Å.  Pairs missing from a
        dict get 0.
    nparams : int, optional
        Expected row length; checked if given.

    Attributes
    ----------
    cutoff : float
        Largest cutoff over all species pairs, Å: the neighbour-list cutoff.
    species : tuple of str or None
        Element symbols in type-index order; None if species-agnostic.
    params, cutoffs, rmin : ndarray
        Tables ``float64[T, T, P]``, ``float64[T, T]``, ``float64[T, T]``.
    """

    def __init__(self, pair, params, cutoffs, rmin=0.0, nparams=None,
                 squared=False):
        if not isinstance(pair, Dispatcher):
            raise TypeError(f'pair function {pair!r} must be compiled with '
                            f'@numba.njit')
        self.pair = pair
        self.squared = bool(squared)
        # a built-in pair function's kernel has its form compiled in
        form = built_in_form(pair)
        if form is not None and form != self.squared:
            raise ValueError(f'pair function {pair.__name__} takes '
                             f'{"r**2" if form else "r"}: squared={form}, '
                             f'got squared={squared!r}')
        if isinstance(params, Mapping):
            self._init_species(params, cutoffs, rmin)
        else:
            self._init_agnostic(params, cutoffs, rmin)
        if nparams is not None and self.params.shape[2] != nparams:
            raise ValueError(f'parameter rows must have length {nparams}, '
                             f'got {self.params.shape[2]}')
        self.cutoff = float(self.cutoffs.max())
        # the kernel's tables: squared distances
        self._cut2 = self.cutoffs ** 2
        self._rmin2 = self.rmin ** 2
        self._check_rmin = bool((self.rmin > 0).any())
        # the kernel's tables by want_virial, made once: a new setting is a
        # new potential
        self._sum_tables = {w: SumTables(self.squared, self.params, self._cut2, self._rmin2,
                                         self._check_rmin, w) for w in (False, True)}
        self._check_pair_function()

    def _init_agnostic(self, params, cutoffs, rmin):
        if isinstance(cutoffs, Mapping) or isinstance(rmin, Mapping):
            raise ValueError('per-pair cutoffs/rmin need per-pair params '
                             '(a dict); got a single parameter row')
        self.species = None
        self.params = _row(params, 'params')[None, None, :].copy()
        cut = _number('cutoffs', cutoffs, 0.0, strict=True)
        self.cutoffs = np.full((1, 1), cut)
        self.rmin = np.full((1, 1), _number('rmin', rmin, 0.0))
        # Every element maps to type 0.
        self._type_of = np.zeros(len(chemical_symbols), dtype=np.int32)
        self._validate_rmin()

    def _init_species(self, params, cutoffs, rmin):
        rows = {zz: _row(v, f'params{_pair_name(*zz)}')
                for zz, v in _pair_dict(params, 'params').items()}
        zs = sorted({z for zz in rows for z in zz})
        pairs = [(a, b) for n, a in enumerate(zs) for b in zs[n:]]
        missing = [_pair_name(*zz) for zz in pairs if zz not in rows]
        if missing:
            raise ValueError(f'params missing for species pairs: '
                             f'{", ".join(missing)}')
        lengths = {len(r) for r in rows.values()}
        if len(lengths) > 1:
            detail = ', '.join(f'{_pair_name(*zz)}: {len(r)}'
                               for zz, r in rows.items())
            raise ValueError(f'parameter rows differ in length ({detail})')

        self.species = tuple(chemical_symbols[z] for z in zs)
        index = {z: t for t, z in enumerate(zs)}
        ntypes = len(zs)
        self.params = np.empty((ntypes, ntypes, lengths.pop()))
        self.cutoffs = self._pair_table(cutoffs, 'cutoffs', index, pairs,
                                        required=True)
        self.rmin = self._pair_table(rmin, 'rmin', index, pairs,
                                     required=False)
        for (za, zb), row in rows.items():
            self.params[index[za], index[zb]] = row
            self.params[index[zb], index[za]] = row
        self._type_of = np.full(len(chemical_symbols), -1, dtype=np.int32)
        self._type_of[zs] = np.arange(ntypes, dtype=np.int32)
        self._validate_rmin()

    @staticmethod
    def _pair_table(values, what, index, pairs, required):
        """Symmetric ``float64[T, T]`` table from a dict or one number."""
        # Cutoffs must be positive; rmin may be 0 (no limit).
        ntypes, strict = len(index), required
        if not isinstance(values, Mapping):
            value = _number(what, values, 0.0, strict)
            return np.full((ntypes, ntypes), value)
        given = _pair_dict(values, what)
        unknown = [_pair_name(*zz) for zz in given if zz not in pairs]
        if unknown:
            raise ValueError(f'{what} given for species pairs without params: '
                             f'{", ".join(unknown)}')
        missing = [_pair_name(*zz) for zz in pairs if zz not in given]
        if required and missing:
            raise ValueError(f'{what} missing for species pairs: '
                             f'{", ".join(missing)}')
        table = np.zeros((ntypes, ntypes))
        for zz, v in given.items():
            x = _number(f'{what}{_pair_name(*zz)}', v, 0.0, strict)
            table[index[zz[0]], index[zz[1]]] = x
            table[index[zz[1]], index[zz[0]]] = x
        return table

    def _validate_rmin(self):
        bad = np.argwhere(self.rmin >= self.cutoffs)
        if len(bad):
            ta, tb = bad[0]
            raise ValueError(f'rmin {self.rmin[ta, tb]} >= cutoff '
                             f'{self.cutoffs[ta, tb]} for species pair '
                             f'{self._type_name(ta, tb)}')

    def _type_name(self, ta, tb):
        """The species pair of type indices ``ta``, ``tb``, for messages."""
        if self.species is None:
            return '(any, any)'
        return f'({self.species[ta]}, {self.species[tb]})'

    def _check_pair_function(self):
        # Run the kernel on an empty list so a pair function with the wrong
        # signature fails here, with a readable message, not mid-simulation.
        # The built-in ones are known good: checking them compiled the serial
        # kernel (1.6 s from an empty cache) where a large system needs only
        # the threaded one.
        if is_built_in(self.pair):
            return
        try:
            # the pair function alone first: its return type must be a pair
            self.pair.compile(PAIR_SIGNATURE.args)
            ret = self.pair.overloads[PAIR_SIGNATURE.args].signature.return_type
            if ret != PAIR_SIGNATURE.return_type:
                raise TypeError(f'No conversion from {ret} to '
                                f'{PAIR_SIGNATURE.return_type}')
            self.sum_pairs(np.zeros((0, 3)), np.zeros(0, np.int32),
                           np.zeros(1, np.int64), np.zeros(0, np.int32),
                           np.zeros(0, np.uint8), np.zeros((1, 3)),
                           np.zeros(0, np.int64))
        except (TypeError, numba.core.errors.NumbaError) as err:
            text = re.sub(r'\x1b\[[0-9;]*m', '', str(err))
            lines = [ln for ln in text.splitlines() if ln.strip()]
            detail = next((ln for ln in lines if not ln.startswith('Failed')),
                          lines[0] if lines else '')
            raise TypeError(
                f'pair function {self.pair.__name__} must be numba code '
                f'f(r: float, p: float64[::1]) -> (energy, dE/dr): {detail}'
            ) from None

    def prepare(self, numbers):
        """Map atomic numbers to type indices.

        Parameters
        ----------
        numbers : int array (N,)
            Atomic numbers.

        Returns
        -------
        types : int32[N]
        params : float64[T, T, P]
        cutoffs : float64[T, T]
            Å.

        Raises
        ------
        ValueError
            If an atom's element has no parameters.
        """
        numbers = np.asarray(numbers)
        if numbers.ndim != 1 or (numbers.size and numbers.dtype.kind not in
                                 'iu'):
            raise ValueError('numbers must be a 1-D integer array')
        if numbers.size:
            bad = np.flatnonzero((numbers < 0) |
                                 (numbers >= len(chemical_symbols)))
            if len(bad):
                raise ValueError(f'atom {bad[0]} has invalid atomic number '
                                 f'{numbers[bad[0]]}')
        types = self._type_of[numbers.astype(np.intp)]
        bad = np.flatnonzero(types < 0)
        if len(bad):
            z = numbers[bad[0]]
            raise ValueError(
                f'no parameters for element {chemical_symbols[z]} (atom '
                f'{bad[0]}); this potential covers {", ".join(self.species)}')
        return types, self.params, self.cutoffs

    def evaluate(self, numbers, i, j, D, d=None, per_atom_virials=True):
        """Energy, forces and virials from a half pair list.

        Parameters
        ----------
        numbers : int array (N,)
            Atomic numbers.
        i, j : int array (M,)
            Half pair list: each interacting pair once (``i == j`` allowed
            for periodic images).
        D : float array (M, 3)
            Vector from atom ``i`` to (the image of) atom ``j``, Å.
        d : float array (M,), optional
            ``|D|``, Å; its shape is checked, its values are not used: the
            kernel computes the distance from ``D``.
        per_atom_virials : bool
            Also return ``virials`` and ``virials_voigt`` (costly; MD does
            not need them).

        Returns
        -------
        dict
            ``energy`` (eV), ``energies`` (N,) eV, ``forces`` (N, 3) eV/Å,
            ``virial`` (3, 3) eV, and with ``per_atom_virials`` also
            ``virials`` (N, 3, 3) eV and ``virials_voigt`` (N, 6) eV.  The virial is
            ``-sum_pairs D (x) dE/dD`` (``sum_i r_i (x) F_i`` for a finite
            system): ASE's stress is ``-virial / volume`` and ASE's per-atom
            ``stresses`` are ``-virials_voigt / volume``.

        Raises
        ------
        ValueError
            On malformed arrays, atom indices out of range, a pair closer than
            ``rmin`` or at distance 0, or a non-finite pair energy/force.
        """
        types = self.prepare(numbers)[0]
        n = len(types)
        i, j = _index_arrays(i, j)
        m = len(i)
        D = np.ascontiguousarray(D, dtype=np.float64)
        if D.shape != (m, 3):
            raise ValueError(f'D must have shape ({m}, 3), got {D.shape}')
        if d is not None and np.shape(d) != (m,):
            raise ValueError(f'd must have shape ({m},), got {np.shape(d)}')
        for name, a in (('i', i), ('j', j)):
            out = np.flatnonzero((a < 0) | (a >= n))
            if len(out):
                k = out[0]
                raise ValueError(f'pair {k}: atom index ({i[k]}, {j[k]}) out '
                                 f'of range for {n} atoms')
        # the same kernel as the calculator's: rows by i, every pair its
        # own "cell shift" D[k] from atoms at the origin (0 - 0 + D is D)
        perm = np.argsort(i, kind='stable')
        rowptr = np.zeros(n + 1, np.int64)
        np.cumsum(np.bincount(i, minlength=n), out=rowptr[1:])
        res = self.sum_pairs(np.zeros((n, 3)), types, rowptr,
                             j[perm].astype(np.int32), perm.astype(np.int32),
                             D, np.arange(n), energies=True,
                             virials=per_atom_virials)
        res['virial'] = res['virial'][_VOIGT_TO_3X3]
        if per_atom_virials:
            res['virials'] = res['virials_voigt'][:, _VOIGT_TO_3X3]
        return res

    def sum_pairs(self, X, types, rowptr, nbr, code, svec, order,
                  energies=False, virials=False, virial=True, chunks=None):
        """Energy, forces and virials over a half list in compressed rows.

        The calculator's path (:class:`ase_mlg.pairlist.PairList` in grid
        order).  Pair ``q`` of row ``t`` is
        ``D = X[nbr[q]] - X[t] + svec[code[q]]``; results come back in atom
        order, row ``t`` being atom ``order[t]``.

        Parameters
        ----------
        X : float64[N, 3]
            Positions in row order, Å.
        types : int32[N]
            Type index of each row: ``prepare(numbers)[0][order]`` (see
            :meth:`prepare`, which is in atom order).
        rowptr, nbr, code : int64[N + 1], int32[M], uint8[M] or int32[M]
        svec : float64[K, 3]
            Cartesian cell shift of each code, Å.
        order : int64[N]
            Atom of each row.
        energies, virials : bool
            Also return per-atom ``energies`` (N,) eV and
            ``virials_voigt`` (N, 6) eV.
        virial : bool
            Return the total ``virial``; MD without a barostat needs none
            (skipping it saves a tenth of the time).
        chunks : ase_mlg.chunks.RowChunks, optional
            The chunks of rows the work is cut into, built for this list
            (``RowChunks(rowptr, nbr, nchunk)``), reused with its buffers
            from call to call: the calculator's
            :class:`~ase_mlg.verletlist.VerletList` keeps one per list
            (:meth:`~ase_mlg.verletlist.VerletList.chunks`).
            Default: :func:`ase_mlg.chunks.row_chunks` of the list (a
            function of the list alone, one chunk on short lists), built
            anew each call.  Same chunks, same bits, at any thread count:
            on one numba thread the serial kernel runs them in chunk order,
            on more the threaded one shares them out.

        Returns
        -------
        dict
            ``energy`` (eV), ``forces`` (N, 3) eV/Å, ``virial`` (Voigt, 6)
            eV, and ``energies`` / ``virials_voigt`` if asked for.
        """
        n = len(order)
        if chunks is None:
            chunks = row_chunks(rowptr, nbr)
        elif not isinstance(chunks, RowChunks):
            raise TypeError(f'chunks must be an ase_mlg.chunks.RowChunks '
                            f'of this list or None, got {chunks!r}')
        threaded = chunks.nchunk > 1 and numba.get_num_threads() > 1
        # the kernel and its structures, made once per list and outputs
        # asked for (4 µs of a 256-atom force call when made every call)
        kernel, head, bufs = chunks.memo(
            (self, X, types, rowptr, nbr, code, svec, order, bool(energies), bool(virials),
             bool(virial), threaded),
            lambda: self._structures((X, types, rowptr, nbr, svec, order), code, chunks,
                                     energies, virials, virial, threaded))
        part = bufs[3]  # every entry written
        out = {'forces': np.empty((n, 3))}
        e_out = np.empty(n) if energies else _NONE
        v_out = np.empty((n, 6)) if virials else _NONE6
        try:
            args = (*head, (*bufs, out['forces'], e_out, v_out))
            if threaded:
                with dynamic_schedule():
                    kernel(*args)
            else:  # the schedule is the threads' only: 5 µs a call saved
                kernel(*args)
            chunk_sums = part.tolist()
            if any(c[8] or not (math.isfinite(c[0]) and math.isfinite(c[7]))
                   for c in chunk_sums):
                raise bad_pair_error(self, SumList._make(head[0]), code, SumTables._make(head[2]))
        except ArithmeticError as err:
            # pair functions compiled with error_model='python' raise; find
            # the pair in Python (error path only) to name it
            named = bad_pair_error(self, SumList._make(head[0]), code, cause=err)
            if named is None:
                raise
            raise named from None
        out['energy'] = math.fsum([c[0] for c in chunk_sums])
        if virial or virials:
            out['virial'] = part[:, 1:7].sum(axis=0)
        if energies:
            out['energies'] = e_out
        if virials:
            out['virials_voigt'] = v_out
        return out

    def _structures(self, lst, code, chunks, energies, virials, virial, threaded):
        """The kernel of :meth:`sum_pairs` and what it reads and writes but
        the per-atom outputs: ``(kernel, (lst, code, tables, chunks'
        arrays), (fbuf, ebuf, vbuf, part))``, as plain tuples (numba types
        named tuples' fields in Python: 3 µs a call)."""
        # one species' forces and energy (an MD step) take the kernel
        # compiled without the rest
        general = bool(virial or virials or energies or self._check_rmin
                       or self.params.shape[0] > 1)
        kernel = pair_kernel(self.pair, threaded, general, self.squared)
        head = (lst, code, tuple(self._sum_tables[bool(virial or virials)]),
                tuple(chunks.arrays))
        return kernel, head, (*chunks.buffers(energies, virials), np.empty((chunks.nchunk, 9)))

    def replace(self, **changes):
        """A new potential of the same kind with some constructor arguments
        changed (what ``MLGCalculator.set(sigma=...)`` uses; a potential
        itself is never changed in place).

        Raises
        ------
        TypeError
            An argument the kind does not take, or a potential built from a
            user pair function (no named arguments: build a new one).
        """
        if not hasattr(self, '_args'):
            raise TypeError(f'{type(self).__name__}: a potential built from a pair '
                            f'function has no named arguments to change '
                            f'({", ".join(map(repr, sorted(changes)))}); build a new one')
        return type(self)(**{**self._args, **changes})

    def todict(self):
        """The potential as JSON-serialisable data (for ``calc.todict()``,
        hence .traj, .db and .json files): ``kind`` and its parameters.

        ``LennardJones`` and ``Morse`` record their constructor's
        arguments; a user pair function is recorded by its module and name,
        with tables keyed by element pair (``"Ar-Kr"``, or ``"any-any"``).
        """
        if hasattr(self, '_args'):
            return {'kind': type(self).__name__, **self._args}
        names = (['any'] if self.species is None else list(self.species))
        table = (lambda a: {f'{names[x]}-{names[y]}': a[x, y].tolist()
                            for x in range(len(names))
                            for y in range(x, len(names))})
        return {'kind': 'PairPotential',
                'pair': f'{self.pair.__module__}.{self.pair.__qualname__}',
                'squared': self.squared, 'params': table(self.params),
                'cutoffs': table(self.cutoffs), 'rmin': table(self.rmin)}

    def __repr__(self):
        d = self.todict()
        kind = d.pop('kind')
        if kind == 'PairPotential':
            species = 'any' if self.species is None else ','.join(self.species)
            return (f'PairPotential(pair={self.pair.__name__}, '
                    f'species={species}, cutoff={self.cutoff:g})')
        return f'{kind}({", ".join(f"{k}={v!r}" for k, v in d.items())})'


# The outputs not asked for: zero-length, so never written
_NONE, _NONE6 = np.empty(0), np.empty((0, 6))


def _refuse_unknown(name, kwargs, accepted):
    """TypeError for keywords a potential does not take.  ASE's calculators
    store unknown keywords and ignore them (ASE's precon NEB test builds
    ``MorsePotential(A=4.0, ...)``); ignoring one here could be a silent
    wrong answer, so it is refused, naming what is taken."""
    if kwargs:
        raise TypeError(f"{name}: unexpected keyword argument(s) "
                        f"{', '.join(map(repr, sorted(kwargs)))}; {name} takes "
                        f"{', '.join(accepted)}")


class _Argument:
    """A constructor argument of a potential, read-only: the kernel's
    tables are computed from it once, so an assignment would be ignored
    (a silent wrong answer); ``replace`` or ``calc.set`` build a new one."""

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, obj, owner=None):
        return self if obj is None else obj._args[self.name]

    def __set__(self, obj, value):
        raise AttributeError(
            f"{type(obj).__name__}.{self.name} is read-only (the pair tables are "
            f"built from it): use potential.replace({self.name}=...) or "
            f"calc.set({self.name}=...)")


def _index_arrays(i, j):
    i = np.asarray(i)
    j = np.asarray(j)
    if i.ndim != 1 or i.shape != j.shape:
        raise ValueError(f'i and j must be 1-D of equal length, got shapes '
                         f'{i.shape} and {j.shape}')
    for name, a in (('i', i), ('j', j)):
        if a.size and a.dtype.kind not in 'iu':
            raise ValueError(f'{name} must be integer, got {a.dtype}')
    dtype = np.int32 if i.dtype == j.dtype == np.int32 else np.int64
    return (np.ascontiguousarray(i, dtype=dtype),
            np.ascontiguousarray(j, dtype=dtype))


class LennardJones(PairPotential):
    """Lennard-Jones, identical to ``ase.calculators.lj.LennardJones``.

    Parameters
    ----------
    sigma : float
        Å; the minimum is at ``2**(1/6) * sigma``.
    epsilon : float
        Well depth, eV.
    rc : float, optional
        Cutoff, Å; default ``3 * sigma``.
    ro : float, optional
        Onset of the smooth cutoff function, Å; default ``0.66 * rc``.
    smooth : bool
        False: energy shifted to 0 at ``rc`` (forces jump to 0 there).
        True: energy times a C^1 cutoff function going 1 -> 0 on [ro, rc].
    """

    sigma, epsilon, rc, ro, smooth = (_Argument() for _ in range(5))

    def __init__(self, sigma=1.0, epsilon=1.0, rc=None, ro=None,
                 smooth=False, **kwargs):
        _refuse_unknown('LennardJones', kwargs,
                        ('sigma', 'epsilon', 'rc', 'ro', 'smooth'))
        sigma = _number('sigma', sigma, 0.0, strict=True)
        epsilon = _number('epsilon', epsilon, 0.0)
        rc = 3 * sigma if rc is None else _number('rc', rc, 0.0, strict=True)
        ro = 0.66 * rc if ro is None else _number('ro', ro, 0.0)
        if ro >= rc:
            raise ValueError(f'ro ({ro}) must be smaller than rc ({rc})')
        self._args = dict(sigma=sigma, epsilon=epsilon, rc=rc, ro=ro,
                          smooth=bool(smooth))
        if self.smooth:
            super().__init__(lennard_jones_smooth_r2, [sigma, epsilon, rc, ro],
                             rc, squared=True)
        else:
            e0 = 4 * epsilon * ((sigma / rc) ** 12 - (sigma / rc) ** 6)
            super().__init__(lennard_jones_shifted_r2, [sigma, epsilon, e0], rc,
                             squared=True)


class Morse(PairPotential):
    """Morse, identical to ``ase.calculators.morse.MorsePotential``.

    ``E(r) = epsilon * (exp(-2 rho0 (r/r0 - 1)) - 2 exp(-rho0 (r/r0 - 1)))``
    times a quintic cutoff going 1 -> 0 between ``rcut1 * r0`` and
    ``rcut2 * r0``.

    Parameters
    ----------
    epsilon : float
        Well depth, eV.
    r0 : float
        Position of the minimum, Å.
    rho0 : float
        Dimensionless stiffness; curvature at the minimum is
        ``2 epsilon (rho0 / r0)**2``.
    rcut1, rcut2 : float
        Start and end of the cutoff function, **in units of r0**.
    """

    epsilon, r0, rho0, rcut1, rcut2 = (_Argument() for _ in range(5))

    def __init__(self, epsilon=1.0, r0=1.0, rho0=6.0, rcut1=1.9, rcut2=2.7,
                 **kwargs):
        _refuse_unknown('Morse', kwargs, ('epsilon', 'r0', 'rho0', 'rcut1', 'rcut2'))
        epsilon = _number('epsilon', epsilon, 0.0)
        r0 = _number('r0', r0, 0.0, strict=True)
        rho0 = _number('rho0', rho0, 0.0, strict=True)
        rcut1 = _number('rcut1', rcut1, 0.0)
        rcut2 = _number('rcut2', rcut2, 0.0, strict=True)
        if rcut1 >= rcut2:
            raise ValueError(f'rcut1 ({rcut1}) must be smaller than rcut2 '
                             f'({rcut2})')
        self._args = dict(epsilon=epsilon, r0=r0, rho0=rho0, rcut1=rcut1,
                          rcut2=rcut2)
        super().__init__(morse, [epsilon, r0, rho0, rcut1 * r0, rcut2 * r0],
                         rcut2 * r0)


def lennard_jones_mixture(sigma, epsilon, rc=None):
    """Shifted Lennard-Jones for several species, Lorentz-Berthelot mixing.

    ``sigma_AB = (sigma_A + sigma_B) / 2``,
    ``epsilon_AB = sqrt(epsilon_A epsilon_B)``; each pair is shifted to 0 at
    its cutoff as in ``LennardJones(smooth=False)``.

    Parameters
    ----------
    sigma, epsilon : dict
        ``{element: value}`` in Å and eV, same elements in both.
    rc : float, optional
        Cutoff for all pairs, Å; default ``3 * sigma_AB`` per pair.

    Returns
    -------
    PairPotential
        Built from :func:`~ase_mlg.pairfunctions.lennard_jones_shifted_r2`
        (``squared=True``) with rows ``[sigma_AB, epsilon_AB, shift_AB]``.
    """
    if set(sigma) != set(epsilon):
        raise ValueError(f'sigma and epsilon must name the same elements, '
                         f'got {sorted(map(str, sigma))} and '
                         f'{sorted(map(str, epsilon))}')
    s = {k: _number(f'sigma[{k!r}]', v, 0.0, strict=True)
         for k, v in sigma.items()}
    e = {k: _number(f'epsilon[{k!r}]', v, 0.0) for k, v in epsilon.items()}
    if rc is not None:
        rc = _number('rc', rc, 0.0, strict=True)
    names = list(s)
    params, cutoffs = {}, {}
    for n, a in enumerate(names):
        for b in names[n:]:
            sab, eab = 0.5 * (s[a] + s[b]), math.sqrt(e[a] * e[b])
            rab = 3 * sab if rc is None else rc
            shift = 4 * eab * ((sab / rab) ** 12 - (sab / rab) ** 6)
            params[a, b] = [sab, eab, shift]
            cutoffs[a, b] = rab
    return PairPotential(lennard_jones_shifted_r2, params, cutoffs, nparams=3,
                         squared=True)
