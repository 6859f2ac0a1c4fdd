"""The compiled small solves (vmp.linalg) are NumPy's, to the bit and in its memory order."""

import numpy as np
import pytest

from vmp.linalg import inv, solve


def _covariances(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(11)
    out = []
    for _ in range(n):
        m = rng.normal(size=(3, 3)) * rng.uniform(1e-4, 1.0, 3)
        out.append(m @ m.T + np.diag(rng.uniform(1e-8, 1e-2, 3)))
    out.append(np.diag([1e4, 1e4, 1e-6]))  # an unconstrained direction beside a sure one
    return out


def test_solve_and_inv_are_numpys_to_the_bit():
    rng = np.random.default_rng(12)
    for a in _covariances(2000):
        b = rng.normal(size=3)
        assert np.array_equal(solve(a, b), np.linalg.solve(a, b))
        got, want = inv(a), np.linalg.inv(a)
        assert np.array_equal(got, want)
        # A product with it sums in the same order only in the same layout.
        assert got.flags.c_contiguous
        assert np.array_equal(got @ b, want @ b)


def test_a_singular_system_raises_as_numpy_does():
    with pytest.raises(np.linalg.LinAlgError):
        solve(np.zeros((3, 3)), np.ones(3))
