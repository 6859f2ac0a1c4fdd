"""The milestone graph: milestones as nodes, measured relative poses as edges, and its adjustment.

Path edges join milestones recorded one after another; loop edges join a milestone to one the
robot returned to. Adjusting the graph spreads the disagreement a loop reveals over all the
milestones on the loop (the paper's figure 16: the first and the last milestone assemble the
whole map), by nonlinear least squares with a sparse Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix, csc_matrix, identity
from scipy.sparse.linalg import splu

from vmp.types import FloatArray, relative, wrap_angle

__all__ = ["Edge", "PoseGraph"]


@dataclass(frozen=True)
class Edge:
    """Milestone ``j`` seen from milestone ``i``: pose ``z`` of j in i's frame, information."""

    i: int
    j: int
    z: FloatArray
    information: FloatArray  # (3, 3)
    kind: str  # "path" or "loop"


def _marginals(jac, n: int, block: int = 64) -> FloatArray | None:
    """The 3x3 marginal covariance of every node from the Gauss-Newton information ``J'J``.

    The information is sparse (a chain plus loops), so it is factorised once and solved for
    ``block`` nodes' columns at a time, keeping only their diagonal blocks: a dense inverse
    of a thousand-node graph took most of a second per adjustment.
    """
    J = csc_matrix(jac)
    H = (J.T @ J + identity(J.shape[1], format="csc") * 1e-9).tocsc()
    try:
        lu = splu(H)
    except RuntimeError:  # singular: an unconstrained node
        return None
    out = np.zeros((n, 3, 3))
    m = n - 1
    for first in range(0, m, block):  # columns in blocks: memory stays O(N * block)
        nodes = np.arange(first, min(first + block, m))
        cols = (3 * nodes[:, None] + np.arange(3)).ravel()
        rhs = np.zeros((H.shape[0], len(cols)))
        rhs[cols, np.arange(len(cols))] = 1.0
        x = lu.solve(rhs)[cols].reshape(len(nodes), 3, len(nodes), 3)
        out[nodes + 1] = x[np.arange(len(nodes)), :, np.arange(len(nodes)), :]
    return out


class PoseGraph:
    """Nodes indexed 0..N-1 (milestone rows); node 0 holds the map frame."""

    def __init__(self) -> None:
        self.edges: list[Edge] = []
        self.marginals: FloatArray | None = None  # (N, 3, 3) after optimize(); node 0 fixed

    def add(self, i: int, j: int, z: FloatArray, covariance: FloatArray, kind: str) -> Edge:
        """Add an edge measured with ``covariance``."""
        info = np.linalg.inv(np.asarray(covariance, dtype=np.float64) + np.eye(3) * 1e-12)
        return self.add_information(i, j, z, 0.5 * (info + info.T), kind)

    def add_information(self, i: int, j: int, z: FloatArray, information: FloatArray,
                        kind: str) -> Edge:
        """Add an edge given its information matrix (as stored in a map file)."""
        if kind not in ("path", "loop"):
            raise ValueError(f"edge kind must be path or loop, got {kind!r}")
        edge = Edge(int(i), int(j), np.asarray(z, dtype=np.float64).copy(),
                    np.asarray(information, dtype=np.float64).copy(), kind)
        self.edges.append(edge)
        return edge

    def error(self, poses: FloatArray, edge: Edge) -> FloatArray:
        """How far the poses are from agreeing with one edge (pose in i's frame, wrapped)."""
        e = relative(poses[edge.i], poses[edge.j]) - edge.z
        e[2] = wrap_angle(e[2])
        return e

    def _arrays(self):
        i = np.array([e.i for e in self.edges])
        j = np.array([e.j for e in self.edges])
        z = np.array([e.z for e in self.edges])
        # Square roots of the informations, so that r = L^T e gives r.r = e^T Omega e.
        info = np.array([e.information for e in self.edges])
        sqrt_info = np.swapaxes(np.linalg.cholesky(info + np.eye(3) * 1e-12), 1, 2)
        return i, j, z, sqrt_info

    def optimize(self, poses: FloatArray, max_iterations: int = 50) -> FloatArray:
        """Poses ``(N, 3)`` that best agree with every edge; node 0 stays where it is."""
        poses = np.asarray(poses, dtype=np.float64)
        n = len(poses)
        if n < 2 or not self.edges:
            return poses.copy()
        i, j, z, sqrt_info = self._arrays()
        fixed = poses[0].copy()

        def residuals(flat: FloatArray) -> FloatArray:
            p = np.vstack([fixed, flat.reshape(-1, 3)])
            e = relative(p[i], p[j]) - z
            e[:, 2] = wrap_angle(e[:, 2])
            return np.einsum("kab,kb->ka", sqrt_info, e).ravel()

        # Each edge's 3 residuals depend on the 3 coordinates of its two nodes (node 0 fixed).
        k = np.arange(len(i))
        rows, cols = [], []
        for node in (i, j):
            free = node > 0
            r = 3 * k[free][:, None, None] + np.arange(3)[None, :, None]
            c = 3 * (node[free] - 1)[:, None, None] + np.arange(3)[None, None, :]
            rows.append(np.broadcast_to(r, (free.sum(), 3, 3)).ravel())
            cols.append(np.broadcast_to(c, (free.sum(), 3, 3)).ravel())
        sparsity = coo_matrix((np.ones(sum(len(r) for r in rows), dtype=np.int8),
                               (np.concatenate(rows), np.concatenate(cols))),
                              shape=(3 * len(i), 3 * (n - 1))).tocsr()
        sparsity.data[:] = 1
        x0 = poses[1:].ravel()
        sol = least_squares(residuals, x0, jac_sparsity=sparsity, method="trf",
                            x_scale="jac", max_nfev=max_iterations, xtol=1e-10, ftol=1e-10)
        out = np.vstack([fixed, sol.x.reshape(-1, 3)])
        out[:, 2] = wrap_angle(out[:, 2])
        self.marginals = _marginals(sol.jac, n)
        return out

    def chi2(self, poses: FloatArray) -> float:
        """Sum of the squared, information-weighted edge errors."""
        if not self.edges:
            return 0.0
        i, j, z, sqrt_info = self._arrays()
        e = relative(poses[i], poses[j]) - z
        e[:, 2] = wrap_angle(e[:, 2])
        r = np.einsum("kab,kb->ka", sqrt_info, e)
        return float((r * r).sum())
