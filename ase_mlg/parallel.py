"""How kernels are compiled for one thread and for many.

A kernel written once with ``prange`` is compiled twice: serial, for short
work where waking threads costs more than it saves, and threaded.  The two
must be compiled from *distinct* Python function objects: numba's on-disk
cache keys a compiled function by its qualified name, bytecode and
signature, not by its flags, so ``njit(cache=True)(f)`` and
``njit(cache=True, parallel=True)(f)`` share one cache entry, and the
threaded dispatcher then loads the serial machine code (measured: one
thread id inside ``prange``) or crashes when the entry was written by the
other.  :func:`serial_and_parallel` gives the threaded twin its own name.
"""

import types

import numba

__all__ = ["serial_and_parallel"]


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
