"""One rank's share of a pair sum over a distributed system.

Each rank evaluates the potential on its *local system*: its owned atoms,
brought into its region, and its ghosts (:class:`~ase_mlg.ranks.halo.Halo`),
with the cell and the periodic axes that were not cut.  The serial machinery
runs on it unchanged: a :class:`~ase_mlg.verletlist.VerletList` (its own
MLG, exact query, row chunks and threads) and the potential's fused pair
sum.  Every pair within the cutoff of an owned atom is in the local list.

Each pair of the system is computed on one rank only (Newton's third law
across ranks, LAMMPS's ``newton on``): after each build the local list
keeps the pairs of two owned atoms, drops those of two ghosts, and keeps a
pair of an owned atom and a ghost on the rank that owns the lower original
index (:func:`_own_pairs`).  The ghosts' forces go back to their owners and
are added there (:meth:`Halo.add_back`); the energy and the virial are the
ranks' totals over their pairs, added in rank order
(:func:`~ase_mlg.ranks.comm.ordered_sum`): no per-atom energies needed.

The list is rebuilt on every rank together: a rank's list holds while its
own :meth:`VerletList.kept` bound holds, and a rebuild anywhere is a
rebuild everywhere (one reduction of a flag a step), so the validity
rule is the serial one (``max |u| < skin / 2`` at a fixed cell; the
strain bound under NPT) applied to the largest displacement of any atom.
A rebuild recomputes the partition (owned atoms and pairs balanced
together from the last list's pairs per atom,
:func:`~ase_mlg.ranks.partition.balanced_partition`), migrates atoms and
makes new ghost lists.
"""

import time

import numpy as np
from ..jit import njit

from ..geometry import same
from ..verletlist import VerletList, trim_heap
from .comm import agree, any_rank, ordered_sum
from .halo import Halo, check_atoms, migrate, shifted
from .partition import balanced_partition

__all__ = ["RankEngine"]


@njit(cache=True)
def _own_pairs(rowptr, nbr, code, ghost, index, image, degree):
    """Keep, in place, the pairs of a half list in compressed rows that
    this rank computes; returns the new pair count, and adds each row's
    kept pairs to its ``degree`` (the partition's work at the next
    rebuild, counted here rather than in a pass of its own).  Per row: ``ghost``,
    the original ``index`` and the cell ``image`` (its owner's position
    plus ``image @ cell``; owned atoms: the image that brings them into the
    region).  A pair of two owned atoms is kept, of two ghosts dropped; a
    pair of an owned atom and a ghost is kept when the owned atom has the
    lower original index (its mirror on the ghost's rank then has the
    higher one), and between two images of one atom when the ghost's image
    less the owned one's is lexicographically positive (its mirror has the
    negative): every pair of the system on one rank, once.  One forward
    pass; the kept pairs stay in their order."""
    w = 0
    start = rowptr[0]
    for t in range(rowptr.shape[0] - 1):
        stop = rowptr[t + 1]
        for q in range(start, stop):
            u = nbr[q]
            keep = True
            if ghost[t] and ghost[u]:
                keep = False
            elif ghost[t] or ghost[u]:
                o, g = (u, t) if ghost[t] else (t, u)
                if index[o] != index[g]:
                    keep = index[o] < index[g]
                else:
                    keep = False
                    for a in range(3):
                        d = image[g, a] - image[o, a]
                        if d != 0:
                            keep = d > 0
                            break
            if keep:
                nbr[w] = u
                code[w] = code[q]
                w += 1
                degree[t] += 1.0
                degree[u] += 1.0
        rowptr[t + 1] = w
        start = stop
    return w


def renumbering(old, new, pbc):
    """Each atom of the last local system's index in the new one (-1: gone),
    for :meth:`ase_mlg.grid.MLG.renumber` (every one gone where an atom of
    the new system is not unique, or two of the last one's are the same new
    atom: then the grid is built anew).

    ``old`` and ``new`` are ``(indices, images)``: a local atom is its
    index in the original atoms and its periodic image along the local
    system's open axes.  Along a periodic axis of the local system (``pbc``
    True) another image is the same site to the grid (an atom wrapped into
    the region), so it is not compared.  One integer key per atom, written
    in place column by column: the (N, 3) temporaries of whole-array
    arithmetic made this the peak of a rank's rebuild (+40 MB at 2 ranks of
    10^6 atoms)."""
    (oid, oim), (nid, nim) = old, new
    if len(oid) == 0 or len(nid) == 0:
        return np.full(len(oid), -1, dtype=np.int64)
    okey, nkey = oid.astype(np.int64), nid.astype(np.int64)
    for ax in np.flatnonzero(~np.broadcast_to(np.asarray(pbc, dtype=bool), (3,))):
        lo = min(oim[:, ax].min(), nim[:, ax].min())
        span = max(oim[:, ax].max(), nim[:, ax].max()) - lo + 1
        for key, im in ((okey, oim), (nkey, nim)):
            key *= span
            key += im[:, ax]
            key -= lo
    order = np.argsort(nkey)
    nkey = nkey[order]  # sorted
    if (nkey[1:] == nkey[:-1]).any():
        return np.full(len(oid), -1, dtype=np.int64)
    at = np.searchsorted(nkey, okey)
    np.minimum(at, len(nkey) - 1, out=at)
    found = nkey[at] == okey
    del nkey, okey
    out = order[at]
    out[~found] = -1
    hit = out[found]
    seen = np.zeros(len(order), dtype=bool)
    seen[hit] = True
    if np.count_nonzero(seen) != len(hit):
        out[:] = -1
    return out


def _finite(atoms):
    """ValueError naming (by original index) atoms whose position is not finite."""
    pos = atoms.arrays["positions"]
    if np.isfinite(pos).all():  # as geometry.as_positions: per row took 0.8 ms a step
        return
    bad = ~np.isfinite(pos).all(axis=1)
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
        self.timings = dict.fromkeys(("halo", "check", "rebuild", "list", "kernel"), 0.0)
        self._key = self._buffer = self._local_numbers = self._ids = None
        self._degree = None  # pairs per owned atom in the last list
        self._choice = None  # the partition's (dims, alpha), tried first at a rebuild

    @staticmethod
    def union(comm, changes):
        """The changes seen on any rank, in ``all_changes``' order (ASE's
        ``check_state``, collective: one small reduction)."""
        from ase.calculators.calculator import all_changes
        names = list(all_changes)  # the same list on every rank: the flags line up
        seen = any_rank(comm, *(n in changes for n in names))
        return [n for n, s in zip(names, seen) if s]

    def _local(self, atoms):
        """The local system's positions now: the owned atoms in their
        region, then the ghosts, written in place into one buffer per
        build (a new one a step, and the owned atoms' shift kept as an
        (n, 3) array, were 25 MB a rank at 2 ranks of 10^6 atoms)."""
        n, cell = len(atoms), atoms.cell.array
        halo = self.halo
        buf = self._buffer
        if buf is None or len(buf) != n + halo.nghost:
            buf = self._buffer = np.empty((n + halo.nghost, 3))
        shifted(atoms.arrays["positions"], halo.own_images, cell, buf[:n])
        halo.exchange(atoms.arrays["positions"], cell, out=buf[n:])
        return buf

    def _kept(self, atoms, local, finite_unchecked):
        """The local list's positions if the list holds (VerletList.kept),
        the positions first tested for NaN and inf if ``finite_unchecked``."""
        if finite_unchecked:
            _finite(atoms)
        return self.vl.kept(local, atoms.cell.array, self.halo.pbc)

    def _rebuild(self, atoms):
        """New partition, migration, ghosts; returns the local positions."""
        comm = atoms.comm
        t0 = time.perf_counter()
        part = balanced_partition(comm, atoms.arrays["positions"], atoms.cell.array,
                                  atoms.pbc, atoms.get_global_number_of_atoms(),
                                  self.potential.cutoff + self.skin, self._pairs(atoms),
                                  first=self._choice, current=self.partition)
        self._choice = (part.dims, part.alpha) if part.alpha is not None else None
        dest = part.owner(atoms.arrays["positions"])
        arrays, left = migrate(comm, dict(atoms.arrays), dest)
        atoms.arrays.clear()
        atoms.arrays.update(arrays)
        check_atoms(comm, atoms.indices, atoms.get_global_number_of_atoms())
        self.partition = part
        self.halo = Halo(comm, part, atoms.arrays["positions"], atoms.numbers, atoms.indices)
        self.counts["rebuilds"] += 1
        self.counts["migrated"] += int(sum(comm.allgather(left)))
        self.counts["ghosts"], self.counts["owned"] = self.halo.nghost, len(atoms)
        self._key = (atoms.numbers.copy(), atoms.pbc.copy())
        self.timings["rebuild"] += time.perf_counter() - t0
        return self._local(atoms)

    def _pairs(self, atoms):
        """Pairs per owned atom in the last list (the partition's work), or
        None before the first list or after the atoms changed."""
        pl, n = self.vl.pairs, len(atoms)
        if (pl is None or self.halo is None or pl.natoms != n + self.halo.nghost
                or self._degree is None):
            return None
        return self._degree

    def _build(self, atoms):
        """Partition, migration, ghosts, the local list of this rank's pairs."""
        local = self._rebuild(atoms)
        t0 = time.perf_counter()
        halo, vl = self.halo, self.vl
        # the local atoms' numbers, fixed until the next build (a change of
        # numbers is a rebuild): not concatenated again every step
        self._local_numbers = np.concatenate([atoms.numbers, halo.ghost_numbers])
        ids = np.concatenate([atoms.indices, halo.ghost_indices])
        images = np.concatenate([halo.own_images, halo.ghost_images])
        # migration and new ghosts renumber the local atoms: the grid is
        # carried over to the new numbers (a new one cost 7x its update)
        renumber = None if self._ids is None else renumbering(self._ids, (ids, images), halo.pbc)
        # the last build's labels are let go before the list's build, the
        # rank's peak (18 MB at 2 ranks of 10^6 atoms); should the build
        # fail, the next one builds a new grid (the tracker's is dropped)
        self._ids = None
        try:
            # the ghosts' own pairs are left out of the scan (12.6 % of the
            # pairs at 2 ranks of 108,000 argon atoms)
            vl.rebuild(local, atoms.cell.array, halo.pbc, self._local_numbers,
                       renumber=renumber, owned=len(atoms))
        except BaseException:
            vl.reset()
            raise
        self._ids = (ids, images)
        pl = vl.pairs
        index = ids[pl.order]
        image = np.ascontiguousarray(images[pl.order])
        degree = np.zeros(pl.natoms)  # row order
        m = _own_pairs(pl.rowptr, pl.nbr, pl.code, np.ascontiguousarray(pl.order >= len(atoms)),
                       np.ascontiguousarray(index), image, degree)
        pl.nbr, pl.code = pl.nbr[:m], pl.code[:m]
        by_atom = np.empty(pl.natoms)
        by_atom[pl.order] = degree
        self._degree = by_atom[:len(atoms)]
        del index, image, degree, renumber
        # the list's own trim came before these temporaries were freed:
        # left resident, they raised a rank's memory by 25-60 MB from one
        # rebuild to the next (2 ranks of 10^6 atoms)
        trim_heap(pl.natoms)
        self.timings["list"] += time.perf_counter() - t0

    def calculate(self, atoms, changes=None, energies=False, virials=False, virial=False):
        """Results of ``atoms`` (a ParallelAtoms) on this rank: ``energy``
        and ``virial`` (eV) global, ``forces``, ``energies``,
        ``virials_voigt`` of the owned atoms, and ``moved_only`` (bool:
        the owned atoms are those of the last call, only their positions
        changed: no rebuild migrated any).  Collective.

        ``changes``: what the ranks agreed changed since the last call (the
        union of ``check_state``'s, as the calculator passes it; None: not
        known).  Where it is the positions at most, no rank's numbers, pbc
        or atom count changed, so the ranks skip their vote on a rebuild
        before the halo exchange, and test the positions for NaN and inf
        within the list's test: one reduction a step fewer, and no
        comparison of every atom's number."""
        comm = atoms.comm
        known = self.halo is not None and changes is not None and set(changes) <= {"positions"}
        rebuild = False
        if not known:
            # new numbers on any rank (its ghosts' too) are a rebuild on every
            # rank: the list's own test need not compare the local numbers
            changed = (self.halo is None or self._key is None
                       or not same(self._key[0], atoms.numbers)
                       or not same(self._key[1], atoms.pbc))
            _, rebuild = agree(comm, _finite, atoms, vote=lambda _: changed)
        if not rebuild:
            t0 = time.perf_counter()
            local = self._local(atoms)
            t1 = time.perf_counter()
            X, rebuild = agree(comm, self._kept, atoms, local, known, vote=lambda x: x is None)
            self.timings["halo"] += t1 - t0
            self.timings["check"] += time.perf_counter() - t1
        if rebuild:
            agree(comm, self._build, atoms)
        else:
            self.vl.keep(X, atoms.cell.array)
        t0 = time.perf_counter()
        vl, pl = self.vl, self.vl.pairs
        res = agree(comm, self.potential.sum_pairs, vl.X, vl.types, pl.rowptr, pl.nbr,
                    pl.code, vl.svec, pl.order, energies=energies, virials=virials,
                    virial=virial or virials, chunks=vl.chunks())
        t1 = time.perf_counter()
        self.timings["kernel"] += t1 - t0
        n, halo = len(atoms), self.halo
        out = {"energy": float(ordered_sum(comm, res["energy"])),
               "moved_only": bool(known and not rebuild)}
        # the ghosts' shares go home: forces (and per-atom values) of owned
        # atoms, added into the owned rows of the kernel's own new array
        # (a view; a copy was 12 MB a step on a rank of 10^6 atoms)
        for key, name in (("forces", "forces"), ("energies", "energies"),
                          ("virials_voigt", "virials_voigt")):
            if key in res:
                mine = res[key][:n]
                halo.add_back(res[key][n:], mine)
                out[name] = mine
        if "virial" in res:
            out["virial"] = ordered_sum(comm, res["virial"])
        self.timings["halo"] += time.perf_counter() - t1
        return out
