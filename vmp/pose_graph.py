"""The milestone graph: milestones as nodes, measured relative poses as edges, and its adjustment.

Path edges join milestones recorded one after another; loop edges join a milestone to one the
robot returned to. Adjusting the graph spreads the disagreement a loop reveals over all the
milestones on the loop (the paper's figure 16: the first and the last milestone assemble the
whole map), by nonlinear least squares with a sparse Jacobian.

Loop edges are robust. The graph is first solved by least squares: from drifted poses a true
loop disagrees by the whole drift, and only the least-squares answer tells a loop that
disagrees with the rest. Where a loop edge still disagrees there (``chi^2`` above
``ROBUST_C2``), graduated non-convexity takes over (Yang, Antonante, Tzoumas, Carlone, "GNC for
robust spatial perception", RA-L 2020): loop edges weighted by the Geman-McClure function
``w = (mu c^2 / (chi^2 + mu c^2))^2`` while ``mu`` shrinks from a convex start to 1, so a
wrong loop loses its pull instead of bending the map. :attr:`PoseGraph.weights` holds each
edge's weight on its information after the last adjustment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csc_matrix, diags, identity
from scipy.sparse.linalg import splu

from vmp.types import FloatArray, relative, wrap_angle

__all__ = ["ROBUST_C2", "Edge", "PoseGraph"]

# A loop edge disagreeing by more than this (chi-square, 3 dof 99 %) is an outlier candidate.
ROBUST_C2 = 11.34
GNC_STEP = 1.4  # mu shrinks by this factor per round (the paper's value) ...
GNC_START = 1000.0  # ... from at most this: an edge this far out is out from the start
GNC_ITERATIONS = 10  # Levenberg-Marquardt iterations per round
# Levenberg-Marquardt stops when a step lowers the cost by less than this share. 1e-6 made
# most GNC rounds stop early and saved a third of fr079's adjustment time, but it also stopped
# where a heavily damped step crept on (Radish belgioioso: ATE 0.48 -> 1.76 m, worse than its
# odometry); a stopping rule that looks at the damping is future work.
LM_TOLERANCE = 1e-12


@dataclass(frozen=True)
class Edge:
    """Milestone ``j`` seen from milestone ``i``: pose ``z`` of j in i's frame, information."""

    i: int
    j: int
    z: FloatArray
    information: FloatArray  # (3, 3)
    kind: str  # "path" or "loop"


def _marginals(jac, n: int, block: int = 64, dense_limit: int = 900) -> FloatArray | None:
    """The 3x3 marginal covariance of every node from the Gauss-Newton information ``J'J``.

    Up to ``dense_limit`` unknowns (300 nodes) one dense inverse is quickest. Beyond, the
    information is sparse (a chain plus loops), so it is factorised once and solved for
    ``block`` nodes' columns at a time, keeping only their diagonal blocks: a dense inverse
    of a thousand-node graph took most of a second per adjustment.
    """
    J = csc_matrix(jac)
    H = (J.T @ J + identity(J.shape[1], format="csc") * 1e-9).tocsc()
    if H.shape[0] <= dense_limit:  # a few hundred nodes: one dense inverse is quicker
        try:
            C = np.linalg.inv(H.toarray())
        except np.linalg.LinAlgError:
            return None
        if not np.isfinite(C).all():
            return None
        out = np.zeros((n, 3, 3))
        idx = np.arange(n - 1)
        out[1:] = C.reshape(n - 1, 3, n - 1, 3)[idx, :, idx, :]
        return out
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
        self.weights: FloatArray = np.zeros(0)  # each edge's residual scale after optimize()

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
        """Poses ``(N, 3)`` that best agree with every edge; node 0 stays where it is.

        Levenberg-Marquardt with the analytic Jacobian of the edge errors and a sparse
        factorisation of the normal equations (a chain plus loops: a few non-zeros a row).
        """
        poses = np.asarray(poses, dtype=np.float64)
        n = len(poses)
        if n < 2 or not self.edges:
            return poses.copy()
        i, j, z, sqrt_info = self._arrays()
        m = len(i)
        robust = np.array([e.kind == "loop" for e in self.edges])
        # Each edge's 3 residuals depend on the 3 coordinates of its two nodes; the columns of
        # node 0 (fixed) are dropped.
        k3 = 3 * np.arange(m)[:, None, None] + np.arange(3)[None, :, None]
        rows = np.broadcast_to(k3, (m, 3, 3))
        blocks = []
        for node in (i, j):
            c = 3 * (node - 1)[:, None, None] + np.arange(3)[None, None, :]
            blocks.append((node > 0, np.broadcast_to(c, (m, 3, 3))))

        def linearise(p: FloatArray, w: FloatArray) -> tuple[FloatArray, csc_matrix,
                                                             FloatArray]:
            """Weighted residuals, their Jacobian, and each edge's unweighted chi^2."""
            c, s = np.cos(p[i, 2]), np.sin(p[i, 2])
            d = p[j, :2] - p[i, :2]
            e = np.empty((m, 3))
            e[:, 0] = c * d[:, 0] + s * d[:, 1] - z[:, 0]
            e[:, 1] = -s * d[:, 0] + c * d[:, 1] - z[:, 1]
            e[:, 2] = wrap_angle(p[j, 2] - p[i, 2] - z[:, 2])
            A = np.zeros((m, 3, 3))  # d e / d pose_i
            A[:, 0, 0], A[:, 0, 1] = -c, -s
            A[:, 1, 0], A[:, 1, 1] = s, -c
            A[:, 0, 2] = -s * d[:, 0] + c * d[:, 1]
            A[:, 1, 2] = -c * d[:, 0] - s * d[:, 1]
            A[:, 2, 2] = -1.0
            B = np.zeros((m, 3, 3))  # d e / d pose_j
            B[:, 0, 0], B[:, 0, 1] = c, s
            B[:, 1, 0], B[:, 1, 1] = -s, c
            B[:, 2, 2] = 1.0
            r = np.einsum("kab,kb->ka", sqrt_info, e)
            chi2 = (r * r).sum(axis=1)
            scale = np.sqrt(w)
            r = (r * scale[:, None]).ravel()
            data, rr, cc = [], [], []
            for (free, cols), D in zip(blocks, (A, B), strict=True):
                W = np.einsum("kab,kbc->kac", sqrt_info, D) * scale[:, None, None]
                data.append(W[free].ravel())
                rr.append(rows[free].ravel())
                cc.append(cols[free].ravel())
            J = coo_matrix((np.concatenate(data), (np.concatenate(rr), np.concatenate(cc))),
                           shape=(3 * m, 3 * (n - 1))).tocsc()
            return r, J, chi2

        w = np.ones(m)
        x = self._levenberg_marquardt(poses.copy(), lambda p: linearise(p, w), max_iterations)
        _, J, chi2 = linearise(x, w)
        c2 = ROBUST_C2
        if (robust & (chi2 > c2)).any():
            mu = min(2.0 * float(chi2[robust].max()) / c2, GNC_START)
            while True:
                mu = max(mu / GNC_STEP, 1.0)
                w = np.where(robust, (mu * c2 / (chi2 + mu * c2)) ** 2, 1.0)
                x = self._levenberg_marquardt(x, lambda p, w=w: linearise(p, w), GNC_ITERATIONS)
                _, J, chi2 = linearise(x, w)
                if mu == 1.0:
                    break
        self.weights = w
        x[:, 2] = wrap_angle(x[:, 2])
        self.marginals = _marginals(J, n)
        return x

    @staticmethod
    def _levenberg_marquardt(x: FloatArray, linearise, max_iterations: int) -> FloatArray:
        """Minimise the squared residuals ``linearise`` gives, from ``x`` (node 0 fixed)."""

        def step(p: FloatArray, dx: FloatArray) -> FloatArray:
            q = p.copy()
            q[1:] += dx.reshape(-1, 3)
            q[1:, 2] = wrap_angle(q[1:, 2])
            return q

        r, J, _ = linearise(x)
        cost = float(r @ r)
        lam = 1e-6
        for _ in range(max_iterations):
            H = (J.T @ J).tocsc()
            g = J.T @ r
            diag = H.diagonal()
            try:
                dx = -splu((H + diags(lam * np.maximum(diag, 1e-9))).tocsc()).solve(g)
            except RuntimeError:  # singular: damp harder
                lam *= 10.0
                continue
            trial = step(x, dx)
            r_t, J_t, _ = linearise(trial)
            cost_t = float(r_t @ r_t)
            if cost_t <= cost:
                done = cost - cost_t <= LM_TOLERANCE * max(cost, 1.0) or abs(dx).max() < 1e-10
                x, r, J, cost = trial, r_t, J_t, cost_t
                lam = max(lam / 10.0, 1e-12)
                if done:
                    break
            else:
                lam *= 10.0
                if lam > 1e8:
                    break
        return x

    def chi2(self, poses: FloatArray) -> float:
        """Sum of the squared, information-weighted edge errors."""
        if not self.edges:
            return 0.0
        i, j, z, sqrt_info = self._arrays()
        e = relative(poses[i], poses[j]) - z
        e[:, 2] = wrap_angle(e[:, 2])
        r = np.einsum("kab,kb->ka", sqrt_info, e)
        return float((r * r).sum())
