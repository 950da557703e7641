"""How the package's kernels are compiled: ``numba.njit``, with an on-disk
cache that loads a kernel without numba's registry refresh.

numba's cache (``numba.core.caching.Cache.load_overload``) refreshes the
target context before it loads a cached kernel: it imports numba's
implementation modules (linalg, random generators, typed containers,
datetime, ...) and installs their typing and lowering registries.  That
costs every process 0.15 s and 10 MB at its first cached call (a first
``neighbor_list`` on a warm cache 0.20 -> 0.045 s, AMD EPYC Zen 3,
numba 0.59 and 0.68), and loading object code needs none of it:

* the C helpers and math symbols the kernels link against are registered
  when the context is created, not by the refresh;
* the NRT (numba's allocator), which the refresh would also start, is
  started here;
* a threaded kernel's ``reload_init`` (the threading layer's launch) runs
  on load as before.

A kernel missing from the cache (a new signature, an empty cache) is
compiled by numba's compiler, which refreshes the context itself.  The
cache's files, keys and invalidation are numba's own: only the load
differs.  If numba's internals are not those this was written against, the
kernels use numba's own cache, and a warning says so once.
"""

import warnings

import numba

__all__ = ["njit"]

try:
    from numba.core.caching import FunctionCache
    from numba.core.runtime import rtsys
except ImportError:  # pragma: no cover - a numba whose internals moved
    FunctionCache = rtsys = None


if FunctionCache is not None:
    class _Cache(FunctionCache):
        """numba's function cache, whose load skips the registry refresh."""

        def load_overload(self, sig, target_context):
            rtsys.initialize(target_context)
            with self._guard_against_spurious_io_errors():
                return self._load_overload(sig, target_context)


_WARNED = []


def _cached(dispatcher):
    """``dispatcher`` with the package's cache (numba's own where its
    internals differ, said once)."""
    if FunctionCache is not None and hasattr(FunctionCache, "_load_overload") \
            and hasattr(dispatcher, "_cache"):
        dispatcher._cache = _Cache(dispatcher.py_func)
        return dispatcher
    if not _WARNED:
        _WARNED.append(True)
        warnings.warn(f"ase-mlg: numba {numba.__version__}'s cache internals differ from "
                      "those ase_mlg.jit was written for: kernels load through numba's own "
                      "cache (about 0.15 s more on a process's first call)", RuntimeWarning,
                      stacklevel=3)
    dispatcher.enable_caching()
    return dispatcher


def njit(*args, **options):
    """``numba.njit``; with ``cache=True`` the cache above.

    Used as ``@njit(cache=True, ...)``, exactly as numba's; ``@njit`` and
    explicit signatures are numba's own (no kernel here is compiled
    eagerly).
    """
    if not options.get("cache") or args:
        return numba.njit(*args, **options)
    options = dict(options, cache=False)
    return lambda func: _cached(numba.njit(**options)(func))
