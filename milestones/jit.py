"""The one way the project compiles a kernel (``vmp.jit`` re-exports it): Numba in nopython
mode, without the GIL, cached on disk beside the module (or in the user's cache when that is
read-only).

The first run after an install compiles every kernel (about 6 s on this project's 2-core
machine); later runs load them (about 0.3 s). Where no cache location is writable at all, the
kernels are compiled anew in each process rather than not run.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from numba import njit

__all__ = ["kernel"]

F = TypeVar("F", bound=Callable)


def kernel(fn: F) -> F:
    """``fn`` compiled (see the module's docstring)."""
    try:
        return njit(cache=True, nogil=True)(fn)
    except RuntimeError:  # numba: "cannot cache function ...: no locator available"
        return njit(nogil=True)(fn)
