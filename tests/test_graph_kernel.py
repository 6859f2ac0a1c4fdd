"""The compiled edge terms of the pose graph (vmp.graph_kernel) against the same terms as NumPy
expressions."""

import numpy as np

from vmp.graph_kernel import edge_terms
from vmp.types import wrap_angle


def _numpy_terms(p, i, j, z, info, w):
    """Each edge's chi^2, ``w D' Omega D`` and ``w D' Omega e``, as NumPy wrote them."""
    m = len(i)
    c, s = np.cos(p[i, 2]), np.sin(p[i, 2])
    d = p[j, :2] - p[i, :2]
    e = np.empty((m, 3))
    e[:, 0] = c * d[:, 0] + s * d[:, 1] - z[:, 0]
    e[:, 1] = -s * d[:, 0] + c * d[:, 1] - z[:, 1]
    e[:, 2] = wrap_angle(p[j, 2] - p[i, 2] - z[:, 2])
    D = np.zeros((m, 3, 6))
    D[:, 0, 0], D[:, 0, 1] = -c, -s
    D[:, 1, 0], D[:, 1, 1] = s, -c
    D[:, 0, 2] = -s * d[:, 0] + c * d[:, 1]
    D[:, 1, 2] = -c * d[:, 0] - s * d[:, 1]
    D[:, 2, 2] = -1.0
    D[:, 0, 3], D[:, 0, 4] = c, s
    D[:, 1, 3], D[:, 1, 4] = -s, c
    D[:, 2, 5] = 1.0
    omega_e = np.einsum("kab,kb->ka", info, e)
    chi2 = (e * omega_e).sum(axis=1)
    wd = w[:, None, None] * np.einsum("kab,kbc->kac", info, D)
    blocks = np.einsum("kab,kac->kbc", D, wd)
    grads = np.einsum("kab,ka->kb", D, w[:, None] * omega_e)
    return chi2, blocks, grads


def test_edge_terms_are_the_numpy_expressions():
    rng = np.random.default_rng(5)
    n, m = 40, 120
    p = np.column_stack([rng.uniform(-30, 30, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    i = rng.integers(0, n, m)
    j = (i + rng.integers(1, n, m)) % n
    z = np.column_stack([rng.normal(0, 3, (m, 2)), rng.uniform(-4, 4, m)])  # unwrapped too
    a = rng.normal(0, 1, (m, 3, 3))
    info = a @ np.swapaxes(a, 1, 2) + np.eye(3)
    w = rng.uniform(0, 1, m)
    got = edge_terms(p, i, j, z, info, w)
    want = _numpy_terms(p, i, j, z, info, w)
    for g, wt in zip(got, want, strict=True):
        assert g.shape == wt.shape
        np.testing.assert_allclose(g, wt, rtol=1e-11, atol=1e-9)
    # The blocks are symmetric and the chi^2 non-negative, as normal equations need.
    np.testing.assert_allclose(got[1], np.swapaxes(got[1], 1, 2), rtol=1e-12, atol=1e-9)
    assert (got[0] >= 0).all()
