"""Small dense systems (the 3 x 3 covariances of poses and increments) solved compiled.

NumPy's ``linalg.solve`` and ``linalg.inv`` spend about 6 microseconds on a 3 x 3 system, nearly
all of it the call's own overhead, and scan odometry alone makes five such calls a scan (an
eighth of a tracked scan on ACES; docs/benchmarks.md, 2026-12-04). Compiled with Numba, the same
LAPACK routine (``gesv``, which ``numpy.linalg.inv`` also solves against the identity) gives the
same numbers, to the bit, in under 2 microseconds.
"""

from __future__ import annotations

import numpy as np

from vmp.jit import kernel
from vmp.types import FloatArray

__all__ = ["inv", "solve"]


@kernel
def _solve(a, b):  # pragma: no cover - compiled
    return np.linalg.solve(a, b)


def solve(a: FloatArray, b: FloatArray) -> FloatArray:
    """``numpy.linalg.solve(a, b)`` for a small square float ``a``; raises
    ``numpy.linalg.LinAlgError`` where ``a`` is singular."""
    return _solve(np.ascontiguousarray(a, dtype=np.float64),
                  np.ascontiguousarray(b, dtype=np.float64))


@kernel
def _inverse(a):  # pragma: no cover - compiled
    # In C order, as NumPy's: LAPACK leaves it in Fortran order, and a product with it then
    # sums in another order (the last bits of scan odometry's fused increment differed).
    return np.ascontiguousarray(np.linalg.solve(a, np.eye(a.shape[0])))


def inv(a: FloatArray) -> FloatArray:
    """``numpy.linalg.inv(a)`` for a small square float ``a``."""
    # The identity made and the result reordered inside the compiled call: 3.1 -> 1.5 us,
    # the same bits (100,000 random 3 x 3 covariances); scan odometry inverts 2.65 a scan.
    return _inverse(np.ascontiguousarray(a, dtype=np.float64))
