"""The package's one threading policy: when a kernel runs on threads, how
its serial and threaded twins are compiled, and how chunks of work are
handed to Python threads (docs/design.md §8).

When to thread
--------------
Waking threads costs microseconds per launch (TBB: ~6 µs, measured), and
an MD step launches tens of kernels, so short work runs serially.  The
break-even point depends on the work per item, so there is one threshold
per kind of item, all in :data:`THRESHOLDS` and read at call time through
:func:`use_threads` (a test may patch them):

* ``"sites"``: grid sites of a swap pass, a follow or a template scan;
* ``"atoms"``: atoms of a query, a gather or a row partition;
* ``"pairs"``: pairs of a pair-potential sum.

Whatever the thread count, results are reproducible: kernels split work
into a fixed number of chunks or into independent lines, and reduce in
chunk order.

Twins
-----
A kernel written once with ``prange`` is compiled twice: serial and
threaded.  The two must be compiled from *distinct* Python function
objects: numba's on-disk cache keys a compiled function by its qualified
name, bytecode and signature, not by its flags, so ``njit(cache=True)(f)``
and ``njit(cache=True, parallel=True)(f)`` share one cache entry, and the
threaded dispatcher then loads the serial machine code (measured: one
thread id inside ``prange``) or crashes when the entry was written by the
other.  :func:`serial_and_parallel` gives the threaded twin its own name.

The threading layer
-------------------
Importing this module (the grid does, so ``import ase_mlg`` does) selects
numba's fork-safe layer (TBB) unless ``NUMBA_THREADING_LAYER`` is set, and
lets idle OpenMP threads sleep (see the comments below).

Python threads
--------------
Kernels that fill their own slice of a shared output (the query's chunks
of blocks, the full list's groups of rows) are serial numba functions that
release the GIL, run on a small thread pool by :func:`run_chunks`.  The
pool is dropped in a forked child, which inherits the executor but not its
threads.
"""

import os
import types

# numba's OpenMP threads spin while idle by default; on a 2-core machine that
# starves the main thread between parallel kernels (measured: serial swap
# sweeps of a 1,000-atom grid took 100 ms instead of 0.03 ms for the first
# seconds of a process).  Idle threads sleep instead, unless the user chose.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402

# numba's threading layer: a fork-safe one, chosen before any parallel kernel
# runs, unless the user chose (NUMBA_THREADING_LAYER).  numba's default on
# Linux is GNU OpenMP, which kills a forked child that launches a parallel
# kernel; multiprocessing/dask workers fork (and must, to run from a plain
# script, ``python -c`` or a notebook).  'forksafe' is numba's TBB layer (the
# ``tbb`` package, a dependency) and, where TBB cannot load, 'workqueue'.
# Measured: a trivial prange kernel on 2 threads costs 6 us per launch under
# TBB (GNU OpenMP 26 us, workqueue 127 us).
if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "forksafe"

__all__ = ["THRESHOLDS", "use_threads", "threads_for", "serial_and_parallel",
           "run_chunks", "reduction_chunks"]

#: Work sizes from which kernels run threaded (measured on 2 and 16 cores:
#: below these, thread hand-offs cost more than they save).
THRESHOLDS = {"sites": 32768, "atoms": 5000, "pairs": 50_000}


def use_threads(kind, size):
    """Whether work of ``size`` items of ``kind`` (a key of
    :data:`THRESHOLDS`) runs on threads."""
    return size >= THRESHOLDS[kind]


def threads_for(kind, size):
    """Number of threads for work of ``size`` items of ``kind``: 1 below
    the threshold, numba's thread count above it."""
    return max(1, numba.get_num_threads()) if use_threads(kind, size) else 1


def reduction_chunks(n, per_chunk):
    """Chunks for a threaded reduction of ``n`` items into one buffer per
    chunk (the RDF histograms): eight a thread to balance them, and no more
    than one per ``per_chunk`` items so the buffers stay small.  Integer
    counts do not depend on the chunking."""
    return int(max(1, min(8 * numba.get_num_threads(), n // per_chunk + 1)))


def serial_and_parallel(func, cache=True, **flags):
    """``(serial, threaded)`` numba dispatchers of ``func``.

    Parameters
    ----------
    func : function
        Python source of the kernel (``prange`` loops run serially in the
        first twin).
    cache : bool
        On-disk cache for both twins (separate entries).
    **flags
        Further ``numba.njit`` options (``nogil``, ``error_model``, ...).
    """
    twin = types.FunctionType(func.__code__, func.__globals__,
                              func.__name__ + "_threaded", func.__defaults__,
                              func.__closure__)
    twin.__qualname__ = func.__qualname__ + "_threaded"
    twin.__module__ = func.__module__
    twin.__doc__ = func.__doc__
    return (numba.njit(cache=cache, **flags)(func),
            numba.njit(cache=cache, parallel=True, **flags)(twin))


_POOL = [None, 0]


def _reset_pool():
    _POOL[0], _POOL[1] = None, 0


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_reset_pool)


def run_chunks(func, args_of, nchunk, nth):
    """Run ``func(*args_of(ch))`` for every chunk ``ch`` on ``nth`` Python
    threads (``func`` must release the GIL); results in chunk order."""
    nth = min(nth, nchunk)
    if nth == 1:
        return [func(*args_of(ch)) for ch in range(nchunk)]
    if _POOL[1] != nth:
        from concurrent.futures import ThreadPoolExecutor
        if _POOL[0] is not None:
            _POOL[0].shutdown(wait=False)
        _POOL[0] = ThreadPoolExecutor(nth, thread_name_prefix="ase_mlg")
        _POOL[1] = nth
    return list(_POOL[0].map(lambda ch: func(*args_of(ch)), range(nchunk)))
