"""How the package compiles its hot loops, written once: numba in nopython mode, cached on disk
(beside the modules in ``__pycache__``, or under ``NUMBA_CACHE_DIR``; an entry is kept for
the contents of its module and of the package modules it imports,
:func:`dmf_sim.core.kernel_cache.install_locators`), without the GIL (a
thread may integrate while another writes) and with numpy's error model (a division by zero
gives inf / nan as in the numpy reference paths, not an exception).

The kernels are written as plain Python functions and compiled at the end of their module with
:func:`jit`, so the same source is the readable version; without numba (a hard dependency, kept
optional for reading) :func:`jit` returns the function itself.
"""
from __future__ import annotations

try:
    import numba
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is a hard dependency, kept optional for reading
    HAVE_NUMBA = False

if HAVE_NUMBA:
    from dmf_sim.core.kernel_cache import install_locators

    # a cache entry keyed on every source it is compiled from, not on its own module's alone
    install_locators()

__all__ = ['HAVE_NUMBA', 'jit']


def jit(fn, fastmath: bool | set[str] = False):
    """``fn`` compiled the package's way (see the module docstring); ``fastmath``: numba's flags
    (False, or a set such as {'reassoc', 'contract'} where rounding-level differences from the
    reference are acceptable)."""
    if not HAVE_NUMBA:
        return fn
    return numba.njit(cache=True, nogil=True, error_model='numpy', fastmath=fastmath)(fn)
