"""The pose graph's per-edge terms compiled: each edge's error, its chi^2 and its 6 x 6 block and
6-gradient of the normal equations.

A Levenberg-Marquardt iteration of the pose graph linearises every edge; an adjustment runs
graduated non-convexity rounds of up to ten iterations each, and the Intel part's 133
adjustments make 3,641 linearisations. As a dozen NumPy ``einsum`` and array calls on
(edges, 3, 6) arrays they are about a sixth of mapping's time.
"""

from __future__ import annotations

import math

import numpy as np

from vmp.jit import kernel

__all__ = ["edge_terms"]


@kernel
def edge_terms(p, i, j, z, info, w):  # pragma: no cover - compiled
    """For poses ``p`` (n, 3) and edges ``i -> j`` measuring ``z`` (m, 3) with information
    ``info`` (m, 3, 3) and weights ``w`` (m,): each edge's unweighted chi^2 (m,), the blocks
    ``w D' Omega D`` (m, 6, 6) and gradients ``w D' Omega e`` (m, 6), ``D`` the Jacobian of
    the edge error (pose i in the frame of pose j, wrapped) by (pose_i, pose_j)."""
    m = i.shape[0]
    chi2 = np.empty(m)
    blocks = np.empty((m, 6, 6))
    grads = np.empty((m, 6))
    D = np.zeros((3, 6))
    e = np.empty(3)
    oe = np.empty(3)  # Omega e
    for k in range(m):
        a = i[k]
        b = j[k]
        c = math.cos(p[a, 2])
        s = math.sin(p[a, 2])
        dx = p[b, 0] - p[a, 0]
        dy = p[b, 1] - p[a, 1]
        e[0] = c * dx + s * dy - z[k, 0]
        e[1] = -s * dx + c * dy - z[k, 1]
        t = p[b, 2] - p[a, 2] - z[k, 2]
        e[2] = (t + math.pi) % (2.0 * math.pi) - math.pi
        D[0, 0] = -c
        D[0, 1] = -s
        D[1, 0] = s
        D[1, 1] = -c
        D[0, 2] = -s * dx + c * dy
        D[1, 2] = -c * dx - s * dy
        D[2, 2] = -1.0
        D[0, 3] = c
        D[0, 4] = s
        D[1, 3] = -s
        D[1, 4] = c
        D[2, 5] = 1.0
        om = info[k]
        chi = 0.0
        for r in range(3):
            oe[r] = om[r, 0] * e[0] + om[r, 1] * e[1] + om[r, 2] * e[2]
            chi += e[r] * oe[r]
        chi2[k] = chi
        wk = w[k]
        # W Omega D (3 x 6), then D' (W Omega D) and D' (W Omega e).
        for col in range(6):
            wod0 = wk * (om[0, 0] * D[0, col] + om[0, 1] * D[1, col] + om[0, 2] * D[2, col])
            wod1 = wk * (om[1, 0] * D[0, col] + om[1, 1] * D[1, col] + om[1, 2] * D[2, col])
            wod2 = wk * (om[2, 0] * D[0, col] + om[2, 1] * D[1, col] + om[2, 2] * D[2, col])
            for row in range(6):
                blocks[k, row, col] = D[0, row] * wod0 + D[1, row] * wod1 + D[2, row] * wod2
        for row in range(6):
            g = 0.0
            for r in range(3):
                g += D[r, row] * wk * oe[r]
            grads[k, row] = g
    return chi2, blocks, grads
