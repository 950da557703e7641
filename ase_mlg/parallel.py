"""The package's one threading policy: which threading layer numba uses,
when a kernel runs on threads, how its serial and threaded twins are
compiled, and how chunks of work are handed to Python threads
(docs/design.md §8).

The threading layer
-------------------
ase-mlg wants numba's TBB layer: it scales, launches in microseconds, and
is both fork-safe (the RDF backends and dask fork) and thread-safe (dask
workers and user threads launch kernels concurrently).  numba's ``tbbpool``
extension links ``libtbb.so.12`` by name with no RPATH, and the ``tbb``
wheel installs it into ``<prefix>/lib``, which is off the loader's path in
a virtual environment: from a plain ``pip install`` TBB never loaded.
Importing this module therefore loads ``libtbb`` by its full path from the
installed ``tbb`` distribution first (the loader then resolves
``tbbpool``'s dependency by its soname), selects ``"tbb"`` and starts the
layer, so :data:`LAYER` is the layer that really runs.

A user's choice is respected, never replaced: ``NUMBA_THREADING_LAYER``,
or ``numba.config.THREADING_LAYER`` set in code (to anything but
``"default"``) before ``import ase_mlg``.  libtbb is loaded by full path
for every choice that can use TBB (``default``, ``safe``, ``threadsafe``,
``forksafe``, ``tbb``), so numba's own selection finds it (these all
give TBB where it is installed); ``omp`` and ``workqueue`` are left as
they are.  If the user asked for ``tbb`` or ``safe`` (TBB only) and TBB
cannot load, the import fails with one line saying so, instead of
numba's "No threading layer could be loaded".  :func:`config` reports
the choice as ``user_choice``.

Where the user made no choice and TBB cannot load (no ``tbb`` wheel for
the platform), one :class:`ThreadingLayerWarning` says what is missing and
ase-mlg uses numba's ``workqueue`` layer, which is fork-safe but not
thread-safe: its threaded kernels are then launched one at a time under a
lock (:data:`SERIALISED`), so concurrent use still never crashes; a
user's choice of workqueue is serialised the same way.

GNU OpenMP (numba's Linux ``omp``) is thread-safe but not fork-safe: a
forked child that launches a parallel kernel hangs or dies.  When it is
the layer that runs -- started by numba parallel code that ran before
``import ase_mlg`` (the layer is chosen once per process, so ase-mlg
cannot change it), or chosen by the user (``omp``, or ``threadsafe``
without TBB) -- the import warns once (:class:`ThreadingLayerWarning`):
forked workers that run parallel kernels hang, and what to do.  A user
who chose ``omp`` made a choice, but the warning costs one line and saves
a hung pool, so they get it too; Intel OpenMP is fork-safe and gets none.
:func:`config` / ``ase_mlg.show_config()`` report it all.

When to thread
--------------
Waking threads costs microseconds per launch (TBB: ~6 µs, measured), and
an MD step launches tens of kernels, so short work runs serially.  The
break-even point depends on the work per item, so there is one threshold
per kind of item, all in :data:`THRESHOLDS` (the package's fixed
thresholds, not a setting: the tests reach the threaded paths with work
above them), and :func:`use_threads` threads work of at least that size:

* ``"sites"``: grid sites of a swap pass, a follow or a template scan;
* ``"atoms"``: atoms of a query, a gather or a reordering of rows;
* ``"pairs"``: pairs of a pair-potential sum or an RDF histogram;
* ``"marks"``: pairs of the pass that finds each row chunk's window
  (:mod:`ase_mlg.chunks`, once a list build): a byte written a pair, 1 ns,
  so threads save 0.4 ms a build at 10^4 atoms (0.8 -> 0.4 ms, 425,000
  pairs) and 2 ms at 10^5 (4.3 -> 2.2 ms), and their compilation costs
  1.3-2 s of a first call: threaded from 5 million pairs (about 10^5 atoms
  of a liquid at 9.5 Å).

Whatever the thread count, results are the same bits: kernels split work
into chunks fixed by the work (never by the thread count) or into
independent lines, and reduce in chunk order; one thread runs the same
chunks in chunk order.  The pair sum's chunks are a function of the list
alone (:func:`ase_mlg.chunks.row_chunks`), so forces, energy, stress,
per-atom energies and virials, and MD trajectories do not depend on
``NUMBA_NUM_THREADS`` or ``numba.set_num_threads``
(tests/test_thread_determinism.py).

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

Python threads
--------------
Kernels that fill their own slice of a shared output (the query's chunks
of blocks, the full list's groups of rows) are serial numba functions that
release the GIL, run on a small thread pool by :func:`run_chunks`.  One
pool per thread count, created under a lock and never shut down while
another caller may use it; the pools are dropped in a forked child, which
inherits the executors but not their threads.
"""

import ctypes
import os
import sys
import threading
import types
import warnings

# numba's OpenMP threads spin while idle by default; on a 2-core machine that
# starves the main thread between parallel kernels (measured: serial swap
# sweeps of a 1,000-atom grid took 100 ms instead of 0.03 ms for the first
# seconds of a process).  Idle threads sleep instead, unless the user chose.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402
from numba import prange  # noqa: E402

from .jit import njit  # noqa: E402

__all__ = ["THRESHOLDS", "LAYER", "SERIALISED", "ThreadingLayerWarning",
           "config", "show_config", "dynamic_schedule", "use_threads", "threads_for", "serial_and_parallel",
           "run_chunks", "reduction_chunks"]


class ThreadingLayerWarning(RuntimeWarning):
    """numba's intended threading layer (TBB) could not load, or the layer
    that runs (GNU OpenMP) hangs forked workers."""


INTENDED_LAYER = "tbb"
_TBB_NAMES = ("libtbb.so.12", "libtbb.12.dylib", "tbb12.dll")


def _tbb_candidates():
    """Full paths of ``libtbb`` that the installed ``tbb`` distribution (or
    the environment's prefix) provides."""
    out = []
    try:
        from importlib.metadata import PackageNotFoundError, distribution
        try:
            dist = distribution("tbb")
            out += [dist.locate_file(f) for f in (dist.files or ())
                    if f.name in _TBB_NAMES]
        except PackageNotFoundError:
            pass
    except ImportError:  # pragma: no cover - importlib.metadata is stdlib
        pass
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        for sub in ("lib", "Library/bin"):
            out += [os.path.join(prefix, sub, n) for n in _TBB_NAMES]
    return [str(p) for p in out if os.path.exists(p)]


def _load_tbb():
    """Make numba's ``tbbpool`` importable; None on success, else why not."""
    try:
        import numba.np.ufunc.tbbpool  # noqa: F401
        return None
    except ImportError as err:
        first = str(err)
    candidates = _tbb_candidates()
    if not candidates:
        return (f"numba's TBB layer needs libtbb ({first}); no 'tbb' package "
                f"is installed for this platform")
    for path in candidates:
        try:
            ctypes.CDLL(path, mode=getattr(ctypes, "RTLD_GLOBAL", 0))
            import numba.np.ufunc.tbbpool  # noqa: F401,F811
            return None
        except (OSError, ImportError) as err:
            first = f"{path}: {err}"
    return f"numba's TBB layer did not load ({first})"


#: The choices of numba's threading layer that can use TBB (numba tries it
#: first for each), and those that need it.
_TBB_CHOICES = ("default", "safe", "threadsafe", "forksafe", "tbb")
_TBB_ONLY = ("safe", "tbb")


def _user_choice():
    """The threading layer the user asked numba for, lower case, or None:
    ``NUMBA_THREADING_LAYER`` (numba reads it into its config when it is
    imported), or ``numba.config.THREADING_LAYER`` set in code before
    ``import ase_mlg`` (the config differs from numba's ``"default"``);
    where both, the config, which is what numba obeys."""
    chosen = str(numba.config.THREADING_LAYER).lower()
    if "NUMBA_THREADING_LAYER" in os.environ or chosen != "default":
        return chosen
    return None


def _asked(choice):
    """How the user asked for ``choice``, in their words."""
    env = os.environ.get("NUMBA_THREADING_LAYER")
    if env is not None and env.lower() == choice:
        return f"NUMBA_THREADING_LAYER={env}"
    return f"numba.config.THREADING_LAYER = {choice!r}"


def _one_line(err):
    return " ".join(str(err).split())


def _start_layer(choice):
    """Choose (unless the user did), start and verify numba's threading
    layer; returns ``(layer, problem, started_before)``."""
    from numba.np.ufunc import parallel as _npar
    if _npar._is_initialized:
        # numba parallel code ran before this import: the layer is fixed
        # for the life of the process
        return numba.threading_layer(), None, True
    problem = None
    if choice is None or choice in _TBB_CHOICES:
        problem = _load_tbb()
    if choice is None:
        numba.config.THREADING_LAYER = INTENDED_LAYER if problem is None else "workqueue"
    elif problem is not None and choice in _TBB_ONLY:
        # numba would say only "No threading layer could be loaded"
        raise ImportError(f"ase-mlg: {_asked(choice)} asks for numba's TBB layer, "
                          f"which cannot load: {problem}. Install TBB ('pip install "
                          f"tbb'), or choose no layer (ase-mlg then falls back to "
                          f"workqueue itself)")
    # start the layer now (no kernel is compiled): numba_threading_layer()
    # then names what really runs, and a failure shows at import, not in
    # the middle of an MD run
    try:
        _npar._launch_threads()
    except ValueError as err:  # an unknown or unloadable choice: one line
        raise ImportError(f"ase-mlg: numba's threading layer did not start "
                          f"({_asked(choice) if choice else 'the default'}): "
                          f"{_one_line(err)}") from None
    return numba.threading_layer(), problem, False


def _fork_hazard(layer, choice, started_before):
    """Why forked workers that run parallel kernels hang here, and what to
    do (one line), or None where the layer is fork-safe."""
    if layer != "omp":
        return None
    from numba.np.ufunc import omppool
    if getattr(omppool, "openmp_vendor", "GNU") != "GNU":
        return None  # Intel OpenMP survives a fork
    if started_before:
        why = "started by numba parallel code that ran before import ase_mlg"
        todo = ("import ase_mlg before any other numba parallel code (it then "
                "starts TBB), set NUMBA_THREADING_LAYER=workqueue, or use the "
                "'spawn' start method")
    else:
        why = _asked(choice) + ("" if choice == "omp" else ", and TBB did not load")
        todo = ("choose 'tbb' (NUMBA_THREADING_LAYER=tbb, 'pip install tbb') or "
                "'workqueue', or use the 'spawn' start method")
    return (f"numba's threading layer is GNU OpenMP ({why}), which is not fork-safe: "
            f"forked workers that run parallel kernels (multiprocessing 'fork' pools, "
            f"dask process workers) hang or die, and the RDF 'multiprocessing' and "
            f"'dask' backends refuse to start; {todo}")


_USER_CHOICE = _user_choice()
LAYER, _PROBLEM, _STARTED_BEFORE = _start_layer(_USER_CHOICE)
#: Threaded kernels are launched one at a time: the layer is not thread-safe.
SERIALISED = LAYER == "workqueue"
_FORK_HAZARD = _fork_hazard(LAYER, _USER_CHOICE, _STARTED_BEFORE)
_LAUNCH_LOCK = threading.RLock()  # re-entered: dynamic_schedule around a _Serialised launch
if _PROBLEM is not None and _USER_CHOICE is None:
    # a user's own choice is not warned about: numba gave what it asked for
    warnings.warn(f"ase-mlg: {_PROBLEM}. Using numba's '{LAYER}' layer instead: "
                  f"threaded kernels launched from several Python threads (dask "
                  f"workers, thread pools) run one at a time, and it is slower "
                  f"(~130 µs a launch against TBB's ~6 µs). Install TBB "
                  f"('pip install tbb') where it exists for the platform.",
                  ThreadingLayerWarning, stacklevel=2)
if _FORK_HAZARD is not None:
    warnings.warn(f"ase-mlg: {_FORK_HAZARD}.", ThreadingLayerWarning, stacklevel=2)

#: The package's fixed work sizes from which kernels run threaded (measured
#: on 2 and 16 cores: below these, thread hand-offs cost more than they
#: save).  Fixed, not a setting: what a user sets is the thread count
#: (``numba.set_num_threads``).
THRESHOLDS = {"sites": 32768, "atoms": 5000, "pairs": 50_000, "marks": 5_000_000}


def use_threads(kind, size):
    """Whether work of ``size`` items of ``kind`` (a key of
    :data:`THRESHOLDS`) runs on threads.

    Never at one numba thread: a threaded twin launched on one thread
    still pays the layer's launch (a list's gather at 10,976 atoms 70 µs
    against its serial twin's 48 µs, AMD EPYC Zen 3).  The twins give the
    same bits, so the choice changes only the time."""
    return size >= THRESHOLDS[kind] and numba.get_num_threads() > 1


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


class _Serialised:
    """A threaded dispatcher launched under the process-wide lock (the
    workqueue layer aborts the process on concurrent launches)."""

    def __init__(self, dispatcher):
        self.dispatcher = dispatcher
        self.__name__ = dispatcher.__name__
        self.__doc__ = dispatcher.__doc__

    def __call__(self, *args):
        with _LAUNCH_LOCK:
            return self.dispatcher(*args)


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

    Notes
    -----
    Under a layer that is not thread-safe (:data:`SERIALISED`) the threaded
    twin is wrapped so that its launches hold a process-wide lock; call it
    from Python only.
    """
    twin = types.FunctionType(func.__code__, func.__globals__,
                              func.__name__ + "_threaded", func.__defaults__,
                              func.__closure__)
    twin.__qualname__ = func.__qualname__ + "_threaded"
    twin.__module__ = func.__module__
    twin.__doc__ = func.__doc__
    threaded = njit(cache=cache, parallel=True, **flags)(twin)
    return (njit(cache=cache, **flags)(func),
            _Serialised(threaded) if SERIALISED else threaded)


# -- the Python thread pools ---------------------------------------------------
_POOLS = {}
_POOL_LOCK = threading.Lock()


def _reset_pools():
    global _POOL_LOCK, _LAUNCH_LOCK
    _POOLS.clear()
    _POOL_LOCK = threading.Lock()
    _LAUNCH_LOCK = threading.RLock()  # re-entered: dynamic_schedule around a _Serialised launch


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_reset_pools)


def _pool(nth):
    with _POOL_LOCK:
        pool = _POOLS.get(nth)
        if pool is None:
            from concurrent.futures import ThreadPoolExecutor
            pool = _POOLS[nth] = ThreadPoolExecutor(nth, thread_name_prefix="ase_mlg")
        return pool


def run_chunks(func, args_of, nchunk, nth):
    """Run ``func(*args_of(ch))`` for every chunk ``ch`` on ``nth`` Python
    threads (``func`` must release the GIL); results in chunk order.  Safe
    to call from several Python threads at once."""
    nth = min(nth, nchunk)
    if nth == 1:
        return [func(*args_of(ch)) for ch in range(nchunk)]
    return list(_pool(nth).map(lambda ch: func(*args_of(ch)), range(nchunk)))


class dynamic_schedule:
    """Context for launching threaded kernels: iterations of ``prange`` are
    handed out one at a time (numba's chunk size 1) instead of in one
    static block per thread, so a thread that wakes late takes a smaller
    share instead of leaving its whole block to the others (static blocks
    made the 2-thread force call bimodal across processes); under
    :data:`SERIALISED` it also holds the launch lock.  numba's chunk size
    is per Python thread, and is restored on exit."""

    def __enter__(self):
        if SERIALISED:
            _LAUNCH_LOCK.acquire()
        self._old = numba.set_parallel_chunksize(1)
        return self

    def __exit__(self, *exc):
        numba.set_parallel_chunksize(self._old)
        if SERIALISED:
            _LAUNCH_LOCK.release()
        return False


# -- what runs -------------------------------------------------------------------
@njit(parallel=True, cache=True)
def _thread_probe(ids, spin):
    # each iteration records the numba thread that ran it; the spin keeps
    # every thread busy long enough for the pool's workers to take a share
    for c in prange(ids.shape[0]):
        ids[c] = numba.get_thread_id()
        x = 0.0
        for k in range(spin):
            x += 1e-9 * k * x + 1.0
        if x < 0.0:
            ids[c] = -1


def config(probe=True):
    """What the package runs with, from inside this process.

    Parameters
    ----------
    probe : bool
        Also run a threaded probe kernel (about 20 ms) and count the
        distinct numba threads that ran its iterations.

    Returns
    -------
    dict
        ``threading_layer`` (numba's, as it runs), ``intended_layer``,
        ``user_choice`` (the layer the user asked for, through
        ``NUMBA_THREADING_LAYER`` or ``numba.config.THREADING_LAYER``
        before ``import ase_mlg``, or None), ``started_before`` (numba
        parallel code had started the layer before ``import ase_mlg``),
        ``problem`` (why TBB did not load, or None), ``fork_hazard`` (why
        forked workers that run parallel kernels hang here, or None),
        ``serialised`` (threaded launches hold a lock), ``threads``
        (numba's thread count), ``cpus`` (usable by this process),
        ``probe_threads`` (distinct thread ids in the probe, or None), and
        the versions of python, numba, numpy, ase and tbb.
    """
    import numpy as np
    from importlib.metadata import PackageNotFoundError, version

    def ver(name):
        try:
            return version(name)
        except PackageNotFoundError:
            return None

    out = {"threading_layer": numba.threading_layer(),
           "intended_layer": INTENDED_LAYER, "user_choice": _USER_CHOICE,
           "started_before": _STARTED_BEFORE, "problem": _PROBLEM,
           "fork_hazard": _FORK_HAZARD, "serialised": SERIALISED, "threads": numba.get_num_threads(),
           "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
           else os.cpu_count(),
           "probe_threads": None, "python": sys.version.split()[0]}
    for name in ("ase-mlg", "numba", "numpy", "ase", "tbb"):
        out[name] = ver(name)
    if probe:
        ids = np.full(8 * out["threads"], -1, np.int64)
        with dynamic_schedule():
            _thread_probe(ids, 2_000_000)
        out["probe_threads"] = int(len(np.unique(ids)))
    return out


def show_config(file=None):
    """Print :func:`config` (the threading layer, thread counts, whether a
    threaded kernel really ran on several threads, versions)."""
    c = config()
    lines = [f"ase-mlg {c['ase-mlg']}  python {c['python']}  numba {c['numba']}  "
             f"numpy {c['numpy']}  ase {c['ase']}  tbb {c['tbb']}",
             f"threading layer: {c['threading_layer']} (intended: {c['intended_layer']}; "
             f"user choice: {c['user_choice'] or 'none'}"
             + ("; started before import ase_mlg" if c["started_before"] else "") + ")"
             + ("; launches serialised (the layer is not thread-safe)" if c["serialised"] else ""),
             f"threads: {c['threads']} numba threads on {c['cpus']} usable CPUs; "
             f"a threaded probe kernel ran on {c['probe_threads']} of them"]
    if c["problem"]:
        lines.append(f"problem: {c['problem']}")
    if c["fork_hazard"]:
        lines.append(f"fork: {c['fork_hazard']}")
    print("\n".join(lines), file=file)
