"""The milestone graph and its adjustment: sparse least squares, marginals."""

import math

import numpy as np
import pytest

from vmp.pose_graph import PoseGraph
from vmp.types import compose, relative


def test_loop_closure_spreads_the_drift_and_keeps_node_zero():
    true = np.array([[0, 0, 0], [4, 0, math.pi / 2], [4, 4, math.pi], [0, 4, -math.pi / 2]],
                    dtype=float)
    g = PoseGraph()
    drifted = [true[0]]
    for a in range(3):
        z = relative(true[a], true[a + 1]) + [0.0, 0.0, 0.02]  # a heading bias per edge
        g.add(a, a + 1, z, np.diag([1e-4, 1e-4, 1e-4]), "path")
        drifted.append(compose(drifted[-1], z))
    g.add(3, 0, relative(true[3], true[0]), np.diag([1e-4, 1e-4, 1e-4]), "loop")
    drifted = np.array(drifted)
    fixed = g.optimize(drifted)
    err_before = np.hypot(*(drifted[:, :2] - true[:, :2]).T).max()
    err_after = np.hypot(*(fixed[:, :2] - true[:, :2]).T).max()
    assert err_after < err_before / 3
    np.testing.assert_array_equal(fixed[0], drifted[0])
    assert g.chi2(fixed) < g.chi2(drifted) / 10
    assert g.marginals is not None and np.all(g.marginals[0] == 0)


@pytest.mark.parametrize("kind", ["path", "loop"])
def test_edge_kinds(kind):
    g = PoseGraph()
    assert g.add(0, 1, np.zeros(3), np.eye(3), kind).kind == kind
    with pytest.raises(ValueError):
        g.add(0, 1, np.zeros(3), np.eye(3), "teleport")


def test_marginals_equal_the_dense_inverse_blocks():
    from scipy.sparse import csr_matrix, triu
    from scipy.sparse import random as sparse_random

    from vmp.pose_graph import Marginals
    from vmp.state import decode, encode

    n = 40
    m = 3 * (n - 1)
    J = sparse_random(200, m, density=0.05, random_state=2) + csr_matrix(np.eye(200, m))
    H = (J.T @ J).tocsc()
    cov = np.linalg.inv(H.toarray() + np.eye(m) * 1e-9)
    got = Marginals(triu(H, format="csc"), n)  # the upper triangle is what it reads
    idx = np.arange(n - 1)[:, None] * 3 + np.arange(3)
    want = cov[idx[:, :, None], idx[:, None, :]]
    for node in (5, 1, 39, 5):  # solved when asked, once
        np.testing.assert_allclose(got[node], want[node - 1], atol=1e-10)
    assert np.all(got[0] == 0) and len(got) == n
    with pytest.raises(IndexError):
        got[n]
    # A checkpoint keeps the information, not the factorisation, and solves again from it.
    tree, arrays = encode(got)
    again = decode(tree, arrays)
    np.testing.assert_allclose(again[7], want[6], atol=1e-10)
    np.testing.assert_allclose(again[5], want[4], atol=1e-10)


def _ring(n: int = 40, radius: float = 10.0) -> np.ndarray:
    a = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return np.column_stack([radius * np.cos(a), radius * np.sin(a), a + math.pi / 2])


def test_a_wrong_loop_edge_loses_its_pull():
    """The answer with a wrong loop edge added is the answer without it."""
    true = _ring()
    rng = np.random.default_rng(3)
    g = PoseGraph()
    drifted = [true[0]]
    for a in range(len(true) - 1):  # odometry as noisy as its covariance says
        z = relative(true[a], true[a + 1]) + rng.normal(0, math.sqrt(1e-3), 3)
        g.add(a, a + 1, z, np.diag([1e-3, 1e-3, 1e-3]), "path")
        drifted.append(compose(drifted[-1], z))
    for a, b in ((39, 0), (30, 2), (20, 35)):  # true loops
        g.add(a, b, relative(true[a], true[b]), np.diag([1e-4, 1e-4, 1e-4]), "loop")
    drifted = np.array(drifted)
    right = g.optimize(drifted)
    assert (g.weights > 0.9).all()  # nothing to discount
    g.add(10, 25, np.array([0.5, 0.0, 0.0]), np.diag([1e-4, 1e-4, 1e-4]), "loop")  # wrong
    robust = g.optimize(drifted)
    assert np.hypot(*(robust[:, :2] - right[:, :2]).T).max() < 0.05
    assert g.weights[-1] < 0.01 and (g.weights[:-1] > 0.9).all(), g.weights[-4:]
    assert (g.weights[:-4] == 1.0).all()  # path edges are never scaled


def test_true_loops_close_from_far_drift():
    """A drift of metres makes a true loop disagree hugely at first: least squares closes it
    before the robust pass could discount it."""
    true = _ring()
    g = PoseGraph()
    drifted = [true[0]]
    for a in range(len(true) - 1):
        z = relative(true[a], true[a + 1]) + [0.0, 0.0, 0.03]
        g.add(a, a + 1, z, np.diag([1e-3, 1e-3, 1e-3]), "path")
        drifted.append(compose(drifted[-1], z))
    g.add(39, 0, relative(true[39], true[0]), np.diag([1e-4, 1e-4, 1e-4]), "loop")
    drifted = np.array(drifted)
    fixed = g.optimize(drifted)
    assert np.hypot(*(drifted[39, :2] - drifted[0, :2])) > 5.0
    e = relative(fixed[39], fixed[0]) - relative(true[39], true[0])
    assert np.hypot(e[0], e[1]) < 0.05 and g.weights[-1] > 0.5


def test_the_factorisation_solves_each_pattern_it_is_given():
    from scipy.sparse import csc_matrix, triu

    from vmp.pose_graph import _Factor

    rng = np.random.default_rng(4)
    factor = _Factor()
    for density in (0.3, 0.3, 0.6):  # the second reuses the first's order, the third cannot
        B = rng.random((12, 12)) * (rng.random((12, 12)) < density)
        A = B @ B.T + np.eye(12)
        b = rng.random(12)
        x = factor.solve(triu(csc_matrix(A), format="csc"), b)
        np.testing.assert_allclose(A @ x, b, atol=1e-10)
    singular = np.ones((3, 3))
    assert factor.solve(triu(csc_matrix(singular), format="csc"), np.ones(3)) is None
    factor.solve(triu(csc_matrix(np.eye(3) + 0.5), format="csc"), np.ones(3))
    assert factor.solve(triu(csc_matrix(singular), format="csc"), np.ones(3)) is None  # updated
