"""One rank's share of a pair sum over a distributed system.

Each rank evaluates the potential on its *local system*: its owned atoms,
brought into its region, and its ghosts (:class:`~ase_mlg.ranks.halo.Halo`),
with the cell and the periodic axes that were not cut.  The serial machinery
runs on it unchanged: a :class:`~ase_mlg.verletlist.VerletList` (its own
MLG, exact query, row chunks and threads) and the potential's fused pair
sum.  Forces on owned atoms are then exact (every pair within the cutoff
of an owned atom is in the local list); the energy and the virial are the
sums over owned atoms of the per-atom energies and virials (half of each
pair on each atom, ASE's convention), added over ranks in rank order
(:func:`~ase_mlg.ranks.comm.ordered_sum`).  Pairs between two ghosts are
not this rank's work: they are dropped from the local list after each build
(:func:`_drop_ghost_pairs`), so a ghost's force is partial and never read.

The list is rebuilt on every rank together: a rank's list holds while its
own :meth:`VerletList.kept` bound holds, and a rebuild anywhere is a
rebuild everywhere (one all-gather of a flag a step), so the validity
rule is the serial one (``max |u| < skin / 2`` at a fixed cell; the
strain bound under NPT) applied to the largest displacement of any atom.
A rebuild recomputes the partition (balanced by the last list's work per
atom), migrates atoms and makes new ghost lists.
"""

import time

import numpy as np
from numba import njit

from ..verletlist import VerletList
from .comm import agree, any_rank, ordered_sum
from .halo import Halo, check_atoms, migrate
from .partition import Partition

__all__ = ["RankEngine"]


@njit(cache=True)
def _drop_ghost_pairs(rowptr, nbr, code, ghost):
    """Drop, in place, the pairs of a half list in compressed rows whose
    two atoms are ghosts (``ghost`` per row); one forward pass, the kept
    pairs in their order (within-cutoff-first rows stay so).  Returns the
    new pair count."""
    w = 0
    start = rowptr[0]
    for t in range(rowptr.shape[0] - 1):
        stop = rowptr[t + 1]
        for q in range(start, stop):
            u = nbr[q]
            if not (ghost[t] and ghost[u]):
                nbr[w] = u
                code[w] = code[q]
                w += 1
        rowptr[t + 1] = w
        start = stop
    return w


def _finite(atoms):
    """ValueError naming (by original index) atoms whose position is not finite."""
    bad = ~np.isfinite(atoms.arrays["positions"]).all(axis=1)
    if bad.any():
        names = atoms.indices[bad][:10].tolist()
        raise ValueError(f"positions: atoms {names} (original indices) are not finite")


class RankEngine:
    """The pair sum of one rank (docs in the module).

    Parameters
    ----------
    potential : PairPotential
    skin : float
        Verlet skin (Å).
    grid_kwargs : dict
        For the local MLG.
    template : None
        Only the exact query: a template's pairs depend on each rank's own
        grid, so they would change with the rank count.
    """

    def __init__(self, potential, skin, grid_kwargs, template=None):
        if template is not None:
            raise ValueError(f"template: a distributed system takes the exact query "
                             f"(template=None), got {template!r}")
        self.potential, self.skin = potential, float(skin)
        self.vl = VerletList(potential.cutoff, self.skin, closed=True,
                             types=lambda z: potential.prepare(z)[0],
                             grid_kwargs=dict(grid_kwargs or {}))
        self.halo = self.partition = None
        self.counts = dict.fromkeys(("rebuilds", "migrated", "ghosts", "owned"), 0)
        self.timings = dict.fromkeys(("halo", "rebuild", "list", "kernel"), 0.0)
        self._key = None

    @staticmethod
    def union(comm, changes):
        """The changes seen on any rank, in ``all_changes``' order (ASE's
        ``check_state``, collective: one small reduction)."""
        from ase.calculators.calculator import all_changes
        names = list(all_changes)  # the same list on every rank: the flags line up
        seen = any_rank(comm, *(n in changes for n in names))
        return [n for n, s in zip(names, seen) if s]

    def _local(self, atoms, ghosts):
        x = atoms.arrays["positions"] + self.halo.own_images @ atoms.cell.array
        return np.ascontiguousarray(np.concatenate([x, ghosts]))

    def _rebuild(self, atoms):
        """New partition, migration, ghosts; returns the local positions."""
        comm = atoms.comm
        t0 = time.perf_counter()
        weight = self._work(atoms)
        part = Partition(comm, atoms.arrays["positions"], atoms.cell.array, atoms.pbc,
                         atoms.get_global_number_of_atoms(),
                         self.potential.cutoff + self.skin, weight)
        dest = part.owner(atoms.arrays["positions"])
        arrays, left = migrate(comm, dict(atoms.arrays), dest)
        atoms.arrays.clear()
        atoms.arrays.update(arrays)
        check_atoms(comm, atoms.indices, atoms.get_global_number_of_atoms())
        self.partition = part
        self.halo = Halo(comm, part, atoms.arrays["positions"], atoms.numbers)
        self.counts["rebuilds"] += 1
        self.counts["migrated"] += int(sum(comm.allgather(left)))
        self.counts["ghosts"], self.counts["owned"] = self.halo.nghost, len(atoms)
        self._key = (atoms.numbers.copy(), atoms.pbc.copy())
        self.timings["rebuild"] += time.perf_counter() - t0
        return self._local(atoms, self.halo.exchange(atoms.arrays["positions"], atoms.cell.array))

    def _work(self, atoms):
        """Work per owned atom from the last list (1 + pairs / mean pairs),
        or None before the first list or after the atoms changed."""
        pl, n = self.vl.pairs, len(atoms)
        if pl is None or self.halo is None or pl.natoms != n + self.halo.nghost:
            return None
        rank_deg = np.diff(pl.rowptr) + np.bincount(pl.nbr, minlength=pl.natoms)
        deg = np.empty(pl.natoms)
        deg[pl.order] = rank_deg
        deg = deg[:n]
        total = ordered_sum(atoms.comm, [deg.sum(), n])
        mean = total[0] / max(total[1], 1.0)
        return deg / mean + 1.0 if mean > 0 else None

    def _numbers(self, atoms):
        return np.concatenate([atoms.numbers, self.halo.ghost_numbers])

    def calculate(self, atoms, energies=False, virials=False, virial=False):
        """Results of ``atoms`` (a ParallelAtoms) on this rank: ``energy``
        and ``virial`` (eV) global, ``forces``, ``energies``,
        ``virials_voigt`` of the owned atoms.  Collective."""
        comm = atoms.comm
        changed = (self.halo is None or self._key is None
                   or not np.array_equal(self._key[0], atoms.numbers)
                   or not np.array_equal(self._key[1], atoms.pbc))
        _, rebuild = agree(comm, _finite, atoms, vote=lambda _: changed)
        if not rebuild:
            t0 = time.perf_counter()
            local = self._local(atoms, self.halo.exchange(atoms.arrays["positions"],
                                                          atoms.cell.array))
            self.timings["halo"] += time.perf_counter() - t0
            X, rebuild = agree(comm, self.vl.kept, local, atoms.cell.array, self.halo.pbc,
                               self._numbers(atoms), vote=lambda x: x is None)
        t0 = time.perf_counter()
        if rebuild:
            local = agree(comm, self._rebuild, atoms)
            agree(comm, self.vl.rebuild, local, atoms.cell.array, self.halo.pbc,
                  self._numbers(atoms))
            pl = self.vl.pairs
            ghost = np.ascontiguousarray(pl.order >= len(atoms))
            m = _drop_ghost_pairs(pl.rowptr, pl.nbr, pl.code, ghost)
            pl.nbr, pl.code = pl.nbr[:m], pl.code[:m]
        else:
            self.vl.keep(X, atoms.cell.array)
        t1 = time.perf_counter()
        self.timings["list"] += t1 - t0
        vl, pl = self.vl, self.vl.pairs
        res = agree(comm, self.potential.sum_pairs, vl.X, vl.types, pl.rowptr, pl.nbr,
                    pl.code, vl.svec, pl.order, energies=True, virials=virial or virials,
                    virial=False, chunks=vl.chunks())
        self.timings["kernel"] += time.perf_counter() - t1
        n = len(atoms)
        out = {"forces": np.ascontiguousarray(res["forces"][:n])}
        e = res["energies"][:n]
        out["energy"] = float(ordered_sum(comm, e.sum()))
        if energies:
            out["energies"] = np.ascontiguousarray(e)
        if virial or virials:
            v = res["virials_voigt"][:n]
            out["virial"] = ordered_sum(comm, v.sum(axis=0))
            if virials:
                out["virials_voigt"] = np.ascontiguousarray(v)
        return out
