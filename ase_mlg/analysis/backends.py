"""Where the frames of an RDF run go: MDAnalysis's multiprocessing and
dask backends with forked workers, and a ``dask.distributed`` cluster
(docs/design.md §10; threads per worker: §8).

Each worker builds its own grid and gets ``cpu_count // workers`` numba
threads; the analyses sum the partial counts, so parallel counts equal a
serial run's.
"""

import functools
import multiprocessing
import numbers
import os
import sys

import numpy as np

from MDAnalysis.analysis.backends import BackendBase, BackendDask, BackendMultiprocessing

__all__ = ["DistributedBackend", "configure"]


def _worker_threads(n_workers):
    """numba threads per worker process: the cores shared out, >= 1."""
    return max(1, (os.cpu_count() or 1) // max(1, int(n_workers)))


def _run_in_worker(func, nthreads, task):
    """Run one computation group in a worker with ``nthreads`` numba threads
    (workers share the cores; each would otherwise start one thread per
    core)."""
    import numba
    numba.set_num_threads(min(int(nthreads), numba.config.NUMBA_NUM_THREADS))
    return func(task)


def _fork_context(option="backend"):
    """The 'fork' multiprocessing context where workers can use it (Linux),
    else None (the platform's default start method).

    Forked workers need no ``if __name__ == "__main__":`` guard and see
    what a notebook or ``python -c`` defined.  They are safe with numba's
    TBB and workqueue threading layers (``import ase_mlg`` selects one); not
    with GNU OpenMP (numba parallel code ran before ``import ase_mlg``, or
    the user chose it) -- then a one-line error says what to do instead of
    a worker hanging or dying.
    """
    if not sys.platform.startswith("linux"):
        return None
    import numba
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel has run in this process yet
        layer = None
    if layer == "omp":
        from numba.np.ufunc import omppool
        if getattr(omppool, "openmp_vendor", "GNU") == "GNU":
            # the layer is fixed for the life of the process: the advice is
            # for the next run
            raise ValueError(
                f"{option}: numba's GNU OpenMP threading layer is running in this "
                "process, and forked workers that run parallel kernels hang or die; "
                "in a new process set NUMBA_THREADING_LAYER=tbb (or workqueue, or "
                "leave it unset) and import ase_mlg before any other numba parallel "
                "code, or use backend='serial' here")
    return multiprocessing.get_context("fork")


class _ForkMultiprocessing(BackendMultiprocessing):
    """MDAnalysis's multiprocessing backend with forked workers (the
    default start method is 'forkserver' from Python 3.14) and the cores
    shared between them."""

    def apply(self, func, computations):
        ctx = _fork_context()
        func = functools.partial(_run_in_worker, func, _worker_threads(self.n_workers))
        pool = multiprocessing.Pool if ctx is None else ctx.Pool
        with pool(processes=self.n_workers) as p:
            return p.map(func, computations)


class _ForkDask(BackendDask):
    """MDAnalysis's dask backend (``scheduler='processes'``) with forked
    workers: dask spawns by default, which needs a main guard."""

    def apply(self, func, computations):
        import dask
        ctx = _fork_context()
        func = functools.partial(_run_in_worker, func, _worker_threads(self.n_workers))
        if ctx is None:
            return super().apply(func, computations)
        with dask.config.set({"multiprocessing.context": "fork"}):
            return super().apply(func, computations)


class DistributedBackend(BackendBase):
    """Run an analysis on a ``dask.distributed`` cluster.

    ``RDF(...).run(backend=DistributedBackend(client))``: the frames are
    split into ``n_workers`` parts (default: one per worker the scheduler
    knows; ``run(n_parts=...)`` splits finer), each part is sent to the
    cluster with ``client.map`` and the partial counts are summed, so the
    counts equal a serial run's.

    Every worker must import ase_mlg and MDAnalysis and read the trajectory
    files at the same paths (a shared file system): the analysis object is
    pickled, and MDAnalysis reopens its files on the worker.  Start a
    cluster with ``dask scheduler`` (prints its address, e.g.
    ``tcp://10.0.0.1:8786``) and ``dask worker tcp://10.0.0.1:8786`` on each
    machine; then ``Client("tcp://10.0.0.1:8786")``.  Workers may run
    several threads: under the TBB layer kernels run concurrently, under the
    workqueue fallback their launches are serialised.  Use worker processes
    (``LocalCluster(processes=True)``, dask's default): the threads of an
    in-process cluster share this process's trajectory readers.

    Parameters
    ----------
    client : distributed.Client
    n_workers : int, optional
        Parts to split the frames into (default: the cluster's workers).
    """

    def __init__(self, client, n_workers=None):
        if not (hasattr(client, "map") and hasattr(client, "gather")
                and hasattr(client, "scheduler_info")):
            raise TypeError(f"client: expected a dask.distributed.Client, got "
                            f"{type(client).__name__}")
        if n_workers is None:
            n_workers = len(client.scheduler_info().get("workers", {}))
            if n_workers < 1:
                raise ValueError("client: the cluster has no workers")
        if (isinstance(n_workers, (bool, np.bool_))
                or not isinstance(n_workers, (numbers.Integral, np.integer))
                or n_workers < 1):
            raise ValueError(f"n_workers: expected an integer >= 1, got {n_workers!r}")
        self.client = client
        super().__init__(n_workers=int(n_workers))

    def apply(self, func, computations):
        futures = self.client.map(func, computations, pure=False)
        return self.client.gather(futures)


def configure(backend, n_workers, unsupported_backend, configure_backend):
    """The shared ``_configure_backend`` of RDF and RDF_s: forked built-in
    backends; DistributedBackend accepted as supported.

    ``configure_backend`` is the analysis's inherited
    ``AnalysisBase._configure_backend`` (bound), which checks the backend
    name and ``n_workers`` and builds MDAnalysis's executor.
    """
    if isinstance(backend, DistributedBackend):
        if n_workers is not None and n_workers != backend.n_workers:
            raise ValueError(f"n_workers: given as {n_workers} and as "
                             f"DistributedBackend(n_workers={backend.n_workers})")
        return backend
    executor = configure_backend(backend=backend, n_workers=n_workers,
                                 unsupported_backend=unsupported_backend)
    if type(executor) is BackendMultiprocessing:
        _fork_context()  # a clear error now rather than a dead worker later
        executor = _ForkMultiprocessing(n_workers=executor.n_workers)
    elif type(executor) is BackendDask:
        _fork_context()
        executor = _ForkDask(n_workers=executor.n_workers)
    return executor
