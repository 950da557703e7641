"""The communicator of a run over MPI ranks, and errors that reach every rank.

The engine is MPI through mpi4py (``pip install "ase-mlg[mpi]"`` pulls
mpi4py and the MPICH wheel; on a cluster, mpi4py built against the site's
MPI).  No other transport is used.  ``comm=None`` means
``ase.parallel.world``'s convention: mpi4py's ``COMM_WORLD`` when mpi4py
imports, else one rank (:class:`SerialComm`), so a script runs unchanged
from ``python md.py`` to ``mpiexec -n P python md.py``.

Errors: every step that can fail on one rank alone (bad input, an atom
sent flying, a lost atom) runs inside :func:`agree`, which makes every
rank learn of the failure at the same collective and raise the same
exception, with the failing ranks and their messages: never a hang of the
ranks that did not fail.  An exception outside ase-mlg's calls (the user's
script) ends every rank through the hook :func:`abort_on_exception`
installs (mpi4py's ``python -m mpi4py`` does the same).
"""

import os
import sys
import time
import traceback

import numpy as np

__all__ = ["SerialComm", "RankError", "resolve_comm", "agree", "any_rank", "ordered_sum",
           "abort_on_exception", "MPI_HINT"]

MPI_HINT = 'pip install "ase-mlg[mpi]" (mpi4py and MPICH)'
# set by the launchers of MPICH (hydra), Open MPI, Intel MPI and Slurm
_LAUNCHER_VARS = ("PMI_RANK", "PMI_SIZE", "PMIX_RANK", "OMPI_COMM_WORLD_SIZE",
                  "MPI_LOCALNRANKS", "SLURM_PROCID")


class RankError(RuntimeError):
    """An error on some ranks, raised on every rank."""


class SerialComm:
    """One rank: the subset of mpi4py's ``Comm`` that ase-mlg calls."""

    rank = 0
    size = 1

    def allgather(self, obj):
        return [obj]

    def alltoall(self, objs):
        return list(objs)

    def bcast(self, obj, root=0):
        return obj

    def gather(self, obj, root=0):
        return [obj]

    def Barrier(self):
        pass

    def Abort(self, code=1):
        os._exit(code)


def _launched_by_mpiexec():
    return any(int(os.environ.get(v, "0") or 0) > 0 for v in ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE")) \
        or any(v in os.environ for v in _LAUNCHER_VARS[:2])


def resolve_comm(comm=None):
    """An mpi4py communicator or :class:`SerialComm` for ``comm``.

    Parameters
    ----------
    comm : None, mpi4py.MPI.Comm, ase.parallel.world or SerialComm
        None: ``ase.parallel.world``'s rule (mpi4py's COMM_WORLD when
        mpi4py imports, else one rank).

    Raises
    ------
    ImportError
        Under ``mpiexec`` without mpi4py (each process would otherwise run
        the whole system alone), naming the install command.
    TypeError
        For anything that is not a communicator.
    """
    if comm is None:
        try:
            from mpi4py import MPI
        except ImportError:
            if _launched_by_mpiexec():
                raise ImportError("ase_mlg.distribute: running under mpiexec but mpi4py "
                                  f"is not installed; {MPI_HINT}") from None
            return SerialComm()
        _align_ase_world(MPI.COMM_WORLD)
        return MPI.COMM_WORLD
    if isinstance(comm, SerialComm):
        return comm
    inner = getattr(comm, "comm", None)  # ase.parallel.world and its MPI4PY
    if inner is None and type(comm).__name__ == "MPI" and hasattr(comm, "size"):
        inner = comm.comm  # ase's lazy wrapper resolves on first use
    if inner is not None:
        if type(inner).__name__ == "DummyMPI":
            return resolve_comm(None) if _launched_by_mpiexec() else SerialComm()
        return resolve_comm(getattr(inner, "comm", inner))
    if all(hasattr(comm, a) for a in ("allgather", "alltoall", "Isend", "Irecv", "rank", "size")):
        return comm
    raise TypeError(f"comm: expected an mpi4py communicator or ase.parallel.world, "
                    f"got {type(comm).__name__}")


def _align_ase_world(world):
    """Make ``ase.parallel.world`` mpi4py's world.  ASE picks its world at
    first use, from whether mpi4py was imported by then: a script that
    thermalised its atoms (which broadcasts through ``world``) before
    :func:`~ase_mlg.distribute` imported mpi4py would otherwise have every
    rank print ``parprint`` lines and write MDLogger's file as rank 0."""
    import ase.parallel as ap
    if ap.world.size != world.size:
        ap.world.comm = ap.MPI4PY(world)


def any_rank(comm, *flags):
    """For each flag, whether it is true on any rank (one small reduction)."""
    v = np.array([bool(f) for f in flags], dtype=np.int32)
    if comm.size > 1:
        from mpi4py import MPI
        comm.Allreduce(MPI.IN_PLACE, v, op=MPI.MAX)
    return [bool(x) for x in v]


def agree(comm, fn, *args, vote=None, **kwargs):
    """``fn(*args, **kwargs)`` on every rank; if it raised on any rank, the
    same exception on every rank.

    The ranks reduce one flag after ``fn`` (and, with ``vote``, whether
    ``vote(result)`` holds on any rank: then ``(result, any vote)`` is
    returned); only after a failure do they exchange the messages.  Call it
    on every rank at the same point of the run.  The first failing rank's
    exception type is raised where it is a ValueError, TypeError or
    ImportError (what a user catches), else :class:`RankError`; its message
    names the failing ranks.
    """
    try:
        out, err = fn(*args, **kwargs), None
    except Exception as e:  # noqa: BLE001 -- every rank must hear of any error
        out, err = None, (type(e).__name__, str(e), e)
    failed_somewhere, voted = any_rank(comm, err is not None,
                                       err is None and vote is not None and vote(out))
    if not failed_somewhere:
        return (out, voted) if vote is not None else out
    if comm.size == 1:
        raise err[2]
    errors = comm.allgather(None if err is None else err[:2])
    failed = [(r, e) for r, e in enumerate(errors) if e is not None]
    kind = failed[0][1][0]
    cls = {"ValueError": ValueError, "TypeError": TypeError,
           "ImportError": ImportError}.get(kind, RankError)
    text = "; ".join(f"rank {r}: {m}" for r, (_, m) in failed)
    if err is not None:
        raise cls(text) from err[2]
    raise cls(text)


def ordered_sum(comm, value):
    """The sum over ranks of ``value`` (a float or an array), added in rank
    order: the same bits on every rank and in every run at a fixed rank
    count (an MPI reduction may add in any order)."""
    parts = comm.allgather(np.asarray(value, dtype=np.float64))
    total = parts[0].copy()
    for p in parts[1:]:
        total = total + p
    return total


_hooked = False


def abort_on_exception(comm):
    """End every rank when an exception escapes the script on one of them
    (the ranks that did not fail would otherwise wait for it forever).
    Installed by :func:`ase_mlg.distribute` when there are several ranks;
    the traceback is printed first."""
    global _hooked
    if _hooked or comm.size == 1:
        return
    def hook(kind, value, tb):
        # one write, and a moment for the launcher to forward it before
        # Abort takes every process down
        text = "".join(traceback.format_exception(kind, value, tb))
        sys.stderr.write(f"ase-mlg: rank {comm.rank} of {comm.size} failed; ending every rank\n"
                         + text)
        sys.stderr.flush()
        time.sleep(0.5)
        comm.Abort(1)

    sys.excepthook = hook
    _hooked = True
