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
import qdldl
from scipy.sparse import csc_matrix

from vmp.graph_kernel import edge_terms
from vmp.types import FloatArray, relative, wrap_angle

__all__ = ["ROBUST_C2", "Edge", "Marginals", "PoseGraph"]

# A loop edge disagreeing by more than this (chi-square, 3 dof 99 %) is an outlier candidate.
ROBUST_C2 = 11.34
GNC_STEP = 1.4  # mu shrinks by this factor per round (the paper's value) ...
GNC_START = 1000.0  # ... from at most this: an edge this far out is out from the start
GNC_ITERATIONS = 10  # Levenberg-Marquardt iterations per round
# Levenberg-Marquardt stops when a step lowers the cost by less than this share, or when an
# undamped step (lambda at most UNDAMPED: Gauss-Newton's, not one the damping shortened) moves
# no coordinate by more than STEP_TOLERANCE (m, rad). A relative decrease of 1e-6 alone stops
# where a heavily damped step creeps on (Radish belgioioso: ATE 1.76 m rather than 0.48, worse
# than its odometry); the step rule leaves the Intel part's adjusted poses within 1e-7 m of
# running each round to its limit.
LM_TOLERANCE = 1e-12
STEP_TOLERANCE = 1e-5
# A graduated non-convexity round before the last only sets the weights of the next: it stops
# at steps under a millimetre (a milliradian), which move an edge's chi^2 by a few tenths
# against the mu c^2 of at least 11 that its weight compares it with. The last round runs to
# STEP_TOLERANCE. (Every round run to it, fr079 takes 11,201 linearisations and
# factorisations: the rounds converge linearly, the steps shrinking by a third each.)
GNC_STEP_TOLERANCE = 1e-3
UNDAMPED = 1e-5


@dataclass(frozen=True)
class Edge:
    """Milestone ``j`` seen from milestone ``i``: pose ``z`` of j in i's frame, information."""

    i: int
    j: int
    z: FloatArray
    information: FloatArray  # (3, 3)
    kind: str  # "path" or "loop"


class _Factor:
    """``LDL^T`` factorisations of symmetric positive definite matrices of one sparsity
    pattern, given as their upper triangles (CSC): QDLDL, after a fill-reducing order (AMD)
    found at the first and kept for the rest.

    The normal equations of one adjustment keep their pattern through every iteration and
    every robust round, so only the first factorisation orders. SuperLU, which scipy offers,
    orders and factorises the whole (unsymmetric) matrix each time: on fr079's last graph
    (1,287 unknowns) 2.27 ms a factorisation and solve, against 0.25 ms here (in turn on this
    machine); fr079 factorises some 8,000 times.
    """

    def __init__(self) -> None:
        self._solver: qdldl.Solver | None = None
        self._pattern: tuple[np.ndarray, np.ndarray] | None = None

    def solve(self, upper: csc_matrix, b: FloatArray) -> FloatArray | None:
        """``A^-1 b`` for the matrix ``A`` whose upper triangle is ``upper``; None when the
        factorisation breaks down (a pivot that is not positive: ``A`` is not positive
        definite to working precision)."""
        try:
            if self._solver is not None and self._same_pattern(upper):
                self._solver.update(upper, upper=True)
            else:  # qdldl's update would read the values in the old pattern's places
                self._solver = qdldl.Solver(upper, upper=True)
                self._pattern = (upper.indptr.copy(), upper.indices.copy())
        except RuntimeError:  # qdldl's constructor on a zero pivot
            self._solver = None
            return None
        if not (self._solver.factors()[1] > 0).all():  # update() does not say
            self._solver = None  # nothing to solve again with
            return None
        return self._solver.solve(b)

    def solve_again(self, b: FloatArray) -> FloatArray:
        """``A^-1 b`` for the matrix of the last :meth:`solve` that succeeded."""
        return self._solver.solve(b)

    def _same_pattern(self, upper: csc_matrix) -> bool:
        indptr, indices = self._pattern
        return np.array_equal(upper.indptr, indptr) and np.array_equal(upper.indices, indices)


class Marginals:
    """The 3x3 marginal covariance of every node, from the Gauss-Newton information ``H``
    (its upper triangle) over the unknowns of nodes 1..n-1 (node 0 is fixed: zeros), solved
    for a node when it is first asked for.

    The information is factorised once (a chain plus loops); a node's block is three solves.
    A mapper asks for a few nodes between two adjustments (the anchor, the candidates of a
    loop), so solving them all would be most of an adjustment's time: a quarter of a second per
    adjustment on fr079's 500 milestones.
    """

    TRANSIENT = ("_factor",)  # rebuilt from the stored information when needed (vmp.state)

    def __init__(self, H_upper: csc_matrix, n: int, factor: _Factor | None = None) -> None:
        """``factor``: one that factorised matrices of this pattern before (its order is
        reused)."""
        H = csc_matrix(H_upper, copy=True)
        H.sort_indices()
        diagonal = H.indptr[1:] - 1  # the last entry of each column of an upper triangle
        if not np.array_equal(H.indices[diagonal], np.arange(H.shape[0])):
            raise ValueError("H_upper must store its whole diagonal")
        H.data[diagonal] += 1e-9  # in place: a sparse sum would drop the stored zeros
        self.data, self.indices, self.indptr = H.data, H.indices, H.indptr
        self.n = n
        self._solved: dict[int, FloatArray] = {}
        self._factor: _Factor | None = None
        self._factorise(factor)

    def _factorise(self, factor: _Factor | None = None) -> _Factor:
        """The information's factorisation; RuntimeError when it is singular (a node that
        nothing constrains)."""
        if self._factor is None:
            size = len(self.indptr) - 1
            factor = factor or _Factor()
            H = csc_matrix((self.data, self.indices, self.indptr), shape=(size, size))
            if factor.solve(H, np.zeros(size)) is None:
                raise RuntimeError("the graph's information is singular")
            self._factor = factor
        return self._factor

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, node: int) -> FloatArray:
        node = int(node)
        if not 0 <= node < self.n:
            raise IndexError(f"node {node} of {self.n}")
        if node == 0:
            return np.zeros((3, 3))
        block = self._solved.get(node)
        if block is None:
            factor = self._factorise()
            cols = 3 * (node - 1) + np.arange(3)
            unit = np.zeros(len(self.indptr) - 1)
            x = np.empty((3, 3))
            for k, col in enumerate(cols):  # three solves: qdldl takes one right-hand side
                unit[col] = 1.0
                x[:, k] = factor.solve_again(unit)[cols]
                unit[col] = 0.0
            block = self._solved[node] = 0.5 * (x + x.T)
        return block.copy()


class _Normal:
    """The sparsity of the normal equations ``H dx = -g`` of one set of edges.

    Every edge touches the 3 + 3 unknowns of its two nodes (node 0's are fixed and dropped), so
    ``H`` is the sum of one 6 x 6 block per edge. The places of the block entries of ``H``'s
    upper triangle (all the factorisation reads) in a CSC matrix are found once; each
    iteration then adds the blocks up with one ``bincount`` instead of forming the Jacobian and
    ``J'J`` (which would be a third of an adjustment's time).
    """

    def __init__(self, i: np.ndarray, j: np.ndarray, n: int) -> None:
        size = 3 * (n - 1)
        self.size = size
        cols = (3 * (np.stack([i, j], axis=1) - 1)[:, :, None] + np.arange(3)).reshape(-1, 6)
        self.free = cols >= 0  # (m, 6): the unknowns an edge's residual moves
        rows = np.broadcast_to(cols[:, :, None], (len(i), 6, 6))
        colb = np.broadcast_to(cols[:, None, :], (len(i), 6, 6))
        self.keep = self.free[:, :, None] & self.free[:, None, :] & (rows <= colb)
        key = colb[self.keep] * size + rows[self.keep]  # column-major: CSC order
        every = np.arange(size)  # the diagonal is stored whole (damping adds to it)
        unique, slot = np.unique(np.concatenate([key, every * size + every]),
                                 return_inverse=True)
        self.slot = slot[:len(key)]
        self.indices = (unique % size).astype(np.int32)
        self.indptr = np.searchsorted(unique // size, np.arange(size + 1)).astype(np.int32)
        self.diagonal = slot[len(key):]  # the slot of each unknown's diagonal entry
        self.grad_slot = cols[self.free]

    def matrix(self, blocks: FloatArray) -> csc_matrix:
        """``H``'s upper triangle from the per-edge blocks ``(m, 6, 6)``."""
        data = np.bincount(self.slot, weights=blocks[self.keep], minlength=len(self.indices))
        return csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    def gradient(self, per_edge: FloatArray) -> FloatArray:
        """``g`` from the per-edge gradients ``(m, 6)``."""
        return np.bincount(self.grad_slot, weights=per_edge[self.free], minlength=self.size)


class PoseGraph:
    """Nodes indexed 0..N-1 (milestone rows); node 0 holds the map frame."""

    def __init__(self) -> None:
        self.edges: list[Edge] = []
        self.marginals: Marginals | None = None  # after optimize(); node 0 fixed
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
        i = np.array([e.i for e in self.edges])
        j = np.array([e.j for e in self.edges])
        z = np.array([e.z for e in self.edges])
        info = np.array([e.information for e in self.edges]) + np.eye(3) * 1e-12
        m = len(i)
        robust = np.array([e.kind == "loop" for e in self.edges])
        normal = _Normal(i, j, n)

        def linearise(p: FloatArray, w: FloatArray) -> tuple[float, csc_matrix, FloatArray,
                                                             FloatArray]:
            """The weighted cost, ``H`` and ``g`` of the normal equations, and each edge's
            unweighted chi^2."""
            chi2, blocks, grads = edge_terms(p, i, j, z, info, w)
            H = normal.matrix(blocks)
            g = normal.gradient(grads)
            return float(w @ chi2), H, g, chi2

        w = np.ones(m)
        factor = _Factor()  # one order for every factorisation of this pattern
        x, H, chi2 = self._levenberg_marquardt(poses.copy(), lambda p: linearise(p, w),
                                               max_iterations, normal.diagonal, factor)
        c2 = ROBUST_C2
        if (robust & (chi2 > c2)).any():
            mu = min(2.0 * float(chi2[robust].max()) / c2, GNC_START)
            while True:
                mu = max(mu / GNC_STEP, 1.0)
                w = np.where(robust, (mu * c2 / (chi2 + mu * c2)) ** 2, 1.0)
                x, H, chi2 = self._levenberg_marquardt(
                    x, lambda p, w=w: linearise(p, w), GNC_ITERATIONS, normal.diagonal, factor,
                    STEP_TOLERANCE if mu == 1.0 else GNC_STEP_TOLERANCE)
                if mu == 1.0:
                    break
        self.weights = w
        x[:, 2] = wrap_angle(x[:, 2])
        try:
            self.marginals = Marginals(H, n, factor)
        except RuntimeError:  # singular: an unconstrained node
            self.marginals = None
        return x

    @staticmethod
    def _levenberg_marquardt(x: FloatArray, linearise, max_iterations: int,
                             diagonal_slots: np.ndarray, factor: _Factor,
                             step_tolerance: float = STEP_TOLERANCE
                             ) -> tuple[FloatArray, csc_matrix, FloatArray]:
        """Minimise the cost ``linearise`` gives, from ``x`` (node 0 fixed), until an undamped
        step moves nothing by ``step_tolerance``; the diagonal of its ``H`` (an upper
        triangle) sits at ``diagonal_slots`` of the matrix's data, and ``factor`` solves the
        damped equations. Returns the poses, and ``H`` and each edge's chi^2 there."""

        def step(p: FloatArray, dx: FloatArray) -> FloatArray:
            q = p.copy()
            q[1:] += dx.reshape(-1, 3)
            q[1:, 2] = wrap_angle(q[1:, 2])
            return q

        cost, H, g, chi2 = linearise(x)
        slots = diagonal_slots
        lam = 1e-6
        for _ in range(max_iterations):
            damped = H.copy()
            damped.data[slots] += lam * np.maximum(H.data[slots], 1e-9)
            solved = factor.solve(damped, g)
            if solved is None:  # not positive definite to working precision: damp harder
                lam *= 10.0
                continue
            dx = -solved
            trial = step(x, dx)
            cost_t, H_t, g_t, chi2_t = linearise(trial)
            if cost_t <= cost:
                move = float(abs(dx).max())
                done = (cost - cost_t <= LM_TOLERANCE * max(cost, 1.0) or move < 1e-10
                        or (move < step_tolerance and lam <= UNDAMPED))
                x, H, g, cost, chi2 = trial, H_t, g_t, cost_t, chi2_t
                lam = max(lam / 10.0, 1e-12)
                if done:
                    break
            else:
                lam *= 10.0
                if lam > 1e8:
                    break
        return x, H, chi2

    def chi2(self, poses: FloatArray) -> float:
        """Sum of the squared, information-weighted edge errors."""
        if not self.edges:
            return 0.0
        i, j, z, sqrt_info = self._arrays()
        e = relative(poses[i], poses[j]) - z
        e[:, 2] = wrap_angle(e[:, 2])
        r = np.einsum("kab,kb->ka", sqrt_info, e)
        return float((r * r).sum())
