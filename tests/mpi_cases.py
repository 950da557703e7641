"""Cases run under ``mpiexec -n P`` by tests/test_ranks.py (one process per rank).

    mpiexec -n P python tests/mpi_cases.py CASE OUTDIR

Each case writes what rank 0 (or every rank) saw under OUTDIR; the test
compares it with the serial calculator in its own process.  Cases:

* ``physics``: energy, forces (gathered, original order) and stress of
  every scene; an NVE run with its energy trace, migrations and final
  positions; a Langevin run; an MDLogger log and a trajectory file written
  by the dynamics; the partition's balance on a liquid-vapour slab.
* ``errors``: errors that must reach every rank (a non-finite atom on one
  rank, ranks holding different atoms, too many ranks for the grid); every
  rank writes the message it got.
* ``uncaught``: an exception escaping the script on rank 1 only, which
  must end every rank.
* ``no_mpi4py``: distribute under mpiexec with mpi4py unimportable.
"""

import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def scenes():
    """name -> (atoms, potential): the scenes of issue 23.3, ~500-900 atoms."""
    from ase.build import bulk

    from ase_mlg.potentials import LennardJones
    lj = LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5)
    rng = np.random.default_rng(7)
    out = {}
    liquid = bulk("Ar", "fcc", a=5.7, cubic=True).repeat((6, 6, 6))
    liquid.positions += rng.normal(0, 0.15, liquid.positions.shape)
    out["liquid"] = liquid
    drop = liquid.copy()
    c = drop.get_center_of_mass()
    drop = drop[np.linalg.norm(drop.positions - c, axis=1) < 14.0]
    drop.pbc = False
    out["droplet"] = drop
    slab = bulk("Ar", "fcc", a=5.7, cubic=True).repeat((6, 6, 3))
    slab.positions += rng.normal(0, 0.15, slab.positions.shape)
    slab.cell[2, 2] = 60.0
    slab.pbc = (True, True, False)
    out["slab"] = slab
    tri = bulk("Ar", "fcc", a=5.7).repeat((8, 8, 8))  # the 60-degree primitive cell
    tri.positions += rng.normal(0, 0.15, tri.positions.shape)
    out["triclinic"] = tri
    return {k: (a, lj) for k, a in out.items()}


def vapour_slab():
    """A liquid-vapour slab (~500 atoms, periodic): Ar liquid in the middle
    third of the cell, 10 % of the atoms as vapour above and below."""
    from ase import Atoms
    from ase.build import bulk
    liquid = bulk("Ar", "fcc", a=5.9, cubic=True).repeat((5, 5, 2))
    rng = np.random.default_rng(11)
    L, h = liquid.cell[0, 0], liquid.cell[2, 2]
    vap = rng.random((40, 3)) * [L, L, 2 * h]
    vap[:, 2] = np.where(vap[:, 2] < h, vap[:, 2], vap[:, 2] + h)
    x = np.concatenate([liquid.positions + [0, 0, h], vap])
    return Atoms("Ar%d" % len(x), positions=x, cell=[L, L, 3 * h], pbc=True)


def balance(atoms):
    """The live partition's choice on ``atoms`` after a first list: the
    imbalance (atoms, pairs) of the balanced partition and of the "work"
    weight on factor_mlg's dims, the choice, and the partition the next
    rebuild makes."""
    from ase_mlg import MLGCalculator
    from ase_mlg.potentials import LennardJones
    from ase_mlg.ranks import distribute
    from ase_mlg.ranks.partition import Partition, balanced_partition, imbalance
    p = distribute(atoms)
    p.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
    p.get_forces()
    eng, comm = p.calc._ranks, p.comm
    rows = eng._pairs(p)
    args = (comm, p.positions, p.cell.array, p.pbc, p.get_global_number_of_atoms(),
            8.5 + p.calc.skin)
    mean = sum(comm.allgather(rows.sum())) / p.get_global_number_of_atoms()
    work = Partition(*args, 1.0 + rows / mean)
    chosen = balanced_partition(*args, rows)
    before = eng.partition
    in_use = imbalance(comm, before, args[1], rows)
    eng._build(p)  # the next rebuild
    live = eng.partition
    return dict(balanced=np.array(imbalance(comm, chosen, args[1], rows)),
                work=np.array(imbalance(comm, work, args[1], rows)),
                choice=np.array([*chosen.dims, chosen.alpha]),
                live=np.array([*live.dims, np.nan if live.alpha is None else live.alpha]),
                kept=np.array(live is before), in_use=np.array(in_use))


def _md_system():
    from ase.build import bulk
    from ase.md.velocitydistribution import thermalize_momenta

    atoms = bulk("Ar", "fcc", a=5.7, cubic=True).repeat((6, 6, 6))
    atoms.positions += np.random.default_rng(1).normal(0, 0.1, atoms.positions.shape)
    thermalize_momenta(atoms, temperature_K=150, rng=np.random.default_rng(2))
    return atoms


def _nudge(atoms):
    """Move original atoms 3, 100 and 500 by 0.005 Å along x, in place."""
    ids = atoms.indices if hasattr(atoms, "indices") else np.arange(len(atoms))
    atoms.positions[np.isin(ids, [3, 100, 500]), 0] += 0.005


def md_runs(make, nsteps=150, logfile=None, trajectory=None):
    """For NVE then Langevin, each on ``make()`` (plain or distributed
    atoms): (energy trace, final positions in original order, (migrations,
    grids carried over)).
    The NVE run writes ``logfile`` and ``trajectory``."""
    from ase import units

    from ase_mlg import MLGCalculator
    from ase_mlg.md import Langevin, VelocityVerlet
    from ase_mlg.potentials import LennardJones
    from ase_mlg.ranks import is_distributed

    out = []
    for kind in ("nve", "nvt"):
        a = make()
        a.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
        if kind == "nve":
            dyn = VelocityVerlet(a, 5 * units.fs, logfile=logfile, trajectory=trajectory,
                                 loginterval=25)
        else:
            dyn = Langevin(a, 5 * units.fs, temperature_K=120, friction=0.02,
                           rng=np.random.default_rng(5))  # fixcm: sums over ranks
        trace = []
        dyn.attach(lambda: trace.append(a.get_potential_energy() + a.get_kinetic_energy()),
                   interval=10)
        # an observer that edits the atoms (the next step must see it), and
        # one attached on rank 0 only (the ranks must still agree every step)
        dyn.attach(_nudge, 7, a)
        if not is_distributed(a) or a.comm.rank == 0:
            dyn.attach(lambda: None, interval=3)
        dyn.run(nsteps)
        whole = a.gather() if is_distributed(a) else a
        # migrations, and grids carried over to a rank's new local atoms
        moves = ((a.calc._ranks.counts["migrated"], a.calc._ranks.vl.stats["grid_carries"])
                 if is_distributed(a) else (0, 0))
        out.append((np.array(trace), whole.positions.copy(), moves))
        logfile = trajectory = None
        if hasattr(dyn, "closelater"):
            dyn.close()
    return out


def physics(outdir):
    from ase_mlg import MLGCalculator
    from ase_mlg.ranks import distribute
    res = {}
    rank = None
    for name, (atoms, pot) in scenes().items():
        p = distribute(atoms)
        rank = p.comm.rank
        p.calc = MLGCalculator(pot)
        e, s = p.get_potential_energy(), p.get_stress() if atoms.cell.rank == 3 and atoms.pbc.all() else None
        f = p.get_forces()
        whole = p.gather()
        assert np.array_equal(whole.positions, atoms.positions)
        res[f"{name}_energy"] = np.array(e)
        res[f"{name}_forces"] = whole.get_forces()
        res[f"{name}_local"] = np.array(np.abs(f - whole.get_forces()[p.indices]).max())
        if s is not None:
            res[f"{name}_stress"] = s
    (nve, x_nve, mig), (nvt, x_nvt, _) = md_runs(
        lambda: distribute(_md_system()), logfile=os.path.join(outdir, "md.log"), trajectory=os.path.join(outdir, "md.traj"))
    res.update(nve=nve, x_nve=x_nve, nvt=nvt, x_nvt=x_nvt, migrated=np.array(mig[0]),
               carried=np.array(mig[1]))  # rank 0's
    if p.comm.size > 1:  # one rank takes the serial calculator's path: no partition
        res.update({f"balance_{k}": v for k, v in balance(vapour_slab()).items()})
    if rank == 0:
        np.savez(os.path.join(outdir, "physics.npz"), **res)


def _message(fn):
    try:
        fn()
    except Exception as e:  # noqa: BLE001 -- the message is what is checked
        return f"{type(e).__name__}: {e}"
    return "no error"


def errors(outdir):
    from ase.build import bulk

    from ase_mlg import MLGCalculator
    from ase_mlg.potentials import LennardJones
    from ase_mlg.ranks import distribute
    atoms = _md_system()
    p = distribute(atoms)
    rank = p.comm.rank
    p.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
    p.get_forces()
    got = {}
    if rank == 1:
        p.positions[3] = np.nan
        got["flying_index"] = int(p.indices[3])

    def forces():
        p.calc.results.clear()
        p.get_forces()
    got["flying"] = _message(forces)
    # finite but 2**30 cells out: int32 images refuse it on every rank (the
    # others are then not left waiting in the halo's collectives)
    far = distribute(atoms)
    far.calc = MLGCalculator(LennardJones(sigma=3.405, epsilon=0.0104, rc=8.5))
    far.get_forces()
    if rank == 1:
        far.positions[5, 0] = 1e13
        got["far_index"] = int(far.indices[5])

    def far_forces():
        far.calc.results.clear()
        far.get_forces()
    got["far"] = _message(far_forces)
    other = _md_system()
    if rank == 1:
        other.positions[0] += 0.01
    got["different"] = _message(lambda: distribute(other))
    tiny = bulk("Ar", "fcc", a=5.7)  # one atom: a grid of one site for P >= 2 ranks
    got["too_many"] = _message(lambda: distribute(tiny))
    with open(os.path.join(outdir, f"errors_{rank}.json"), "w") as fh:
        json.dump(got, fh)


def uncaught(outdir):
    from ase_mlg.ranks import distribute
    p = distribute(_md_system())
    if p.comm.rank == 1:
        raise RuntimeError("rank 1 fails alone")
    p.comm.Barrier()  # the other ranks would wait here forever
    with open(os.path.join(outdir, "barrier_passed"), "w") as fh:
        fh.write("yes")


def no_mpi4py(outdir):
    class Hide:  # import mpi4py now raises ImportError, as where it is not installed
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] == "mpi4py":
                raise ModuleNotFoundError("No module named 'mpi4py'")

    sys.meta_path.insert(0, Hide())
    from ase_mlg.ranks import distribute
    msg = _message(lambda: distribute(_md_system()))
    with open(os.path.join(outdir, f"no_mpi4py_{os.getpid()}.txt"), "w") as fh:
        fh.write(msg)


if __name__ == "__main__":
    case, outdir = sys.argv[1], sys.argv[2]
    {"physics": physics, "errors": errors, "uncaught": uncaught,
     "no_mpi4py": no_mpi4py}[case](outdir)
