"""Small dense systems (the 3 x 3 covariances of poses and increments) solved compiled.

NumPy's ``linalg.solve`` and ``linalg.inv`` spend about 6 microseconds on a 3 x 3 system, nearly
all of it the call's own overhead, and scan odometry makes five such calls a scan. These kernels
call the LAPACK routine both use (``dgesv``, which ``numpy.linalg.inv`` solves against the
identity), from SciPy's LAPACK, on the same column-major copies: the same numbers to the bit, in
under 2 microseconds. They call it directly rather than through Numba's ``np.linalg.solve``,
whose checks and messages take about 6 s to compile on the first run after an install (these
kernels: under 1 s).
"""

from __future__ import annotations

import llvmlite.binding as llvm
import numpy as np
from numba import types
from numba.extending import get_cython_function_address

from vmp.jit import kernel
from vmp.types import FloatArray

__all__ = ["inv", "solve"]

# dgesv(n, nrhs, a, lda, ipiv, b, ldb, info): every argument by pointer (Fortran). Called by a
# symbol the linker resolves in each process, so that the kernels calling it can be cached (a
# ctypes pointer would be baked into the compiled code).
_SYMBOL = "vmp_slam_dgesv"
llvm.add_symbol(_SYMBOL, get_cython_function_address("scipy.linalg.cython_lapack", "dgesv"))
_dgesv = types.ExternalFunction(_SYMBOL, types.void(*[types.voidptr] * 8))


@kernel
def _gesv(a, b_columns, nrhs):  # pragma: no cover - compiled
    """Solve ``a x = b`` in place of ``b_columns`` (column-major, ``nrhs`` columns); returns
    LAPACK's ``info`` (> 0: ``a`` is singular)."""
    n = a.shape[0]
    a_columns = a.T.copy()  # row-major a^T: a in column-major order, and a copy dgesv may spoil
    sizes = np.array([n, nrhs, n, n, 0], dtype=np.int32)  # n, nrhs, lda, ldb, info
    pivots = np.empty(n, dtype=np.int32)
    _dgesv(sizes[0:].ctypes, sizes[1:].ctypes, a_columns.ctypes, sizes[2:].ctypes,
           pivots.ctypes, b_columns.ctypes, sizes[3:].ctypes, sizes[4:].ctypes)
    return sizes[4]


@kernel
def _solve_vector(a, b):  # pragma: no cover - compiled
    x = b.copy()
    return x, _gesv(a, x, 1)


@kernel
def _solve_matrix(a, b):  # pragma: no cover - compiled
    x = b.T.copy()  # b^T row-major: b column-major
    return x.T, _gesv(a, x, b.shape[1])


@kernel
def _inverse(a):  # pragma: no cover - compiled
    x = np.eye(a.shape[0])  # symmetric: the same in either order
    info = _gesv(a, x, a.shape[0])
    # In C order, as NumPy's: a product with a column-major inverse sums in another order.
    return x.T.copy(), info


def _checked(x: FloatArray, info: int) -> FloatArray:
    if info > 0:
        raise np.linalg.LinAlgError("Singular matrix")
    return x


def _square(a: FloatArray) -> FloatArray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise np.linalg.LinAlgError(f"expected a square matrix, got shape {a.shape}")
    return a


def solve(a: FloatArray, b: FloatArray) -> FloatArray:
    """``numpy.linalg.solve(a, b)`` for a small square float ``a``; raises
    ``numpy.linalg.LinAlgError`` where ``a`` is singular."""
    a = _square(a)
    b = np.ascontiguousarray(b, dtype=np.float64)
    if b.shape[0] != a.shape[0] or b.ndim not in (1, 2):
        raise ValueError(f"b of shape {b.shape} does not fit a of shape {a.shape}")
    return _checked(*(_solve_vector(a, b) if b.ndim == 1 else _solve_matrix(a, b)))


def inv(a: FloatArray) -> FloatArray:
    """``numpy.linalg.inv(a)`` for a small square float ``a``."""
    return _checked(*_inverse(_square(a)))
