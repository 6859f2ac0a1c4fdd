"""The ICP iterations compiled: nearest reference point, point-to-line (and corner) residuals,
Huber weights and the Gauss-Newton step, one loop per registration.

An iteration on 170 points cost about 140 microseconds in NumPy: a k-d tree query of 50 (SciPy's
``cKDTree``, most of it call overhead on so few points) and some thirty array operations of a few
microseconds each. Mapping registers each scan three to five times, so those calls were about
40 % of mapping's time (docs/benchmarks.md, 2026-12-03). Compiled with Numba, the same arithmetic
with the nearest neighbour found in a grid of cells as wide as the widest correspondence gate
(KISS-ICP's voxel hash map, in a sorted array) costs a few microseconds an iteration.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["CELL", "cell_keys", "run_icp"]

CELL = 0.5  # cell side (m): the widest correspondence gate, so a gate looks at 3 x 3 cells
_OFFSET = 1 << 30  # cell coordinates are clipped to +-2^30 cells (5e8 m) and shifted positive
_STRIDE = 1 << 32


def cell_keys(points: np.ndarray) -> np.ndarray:
    """One integer per point naming the grid cell it lies in; the cells of one column are
    consecutive. :func:`run_icp` needs its reference's rows sorted by these keys."""
    cells = np.clip(np.floor(points / CELL), -_OFFSET, _OFFSET - 1).astype(np.int64) + _OFFSET
    return cells[:, 0] * _STRIDE + cells[:, 1]


@njit(cache=True, nogil=True)
def _nearest(cells_keys, ref, qx, qy, gate):  # pragma: no cover - compiled
    """Row of the reference point nearest to (qx, qy) closer than ``gate``, or -1."""
    reach = math.ceil(gate / CELL)
    cx = int(min(max(math.floor(qx / CELL), -_OFFSET), _OFFSET - 1)) + _OFFSET
    cy = int(min(max(math.floor(qy / CELL), -_OFFSET), _OFFSET - 1)) + _OFFSET
    best = -1
    best_d2 = gate * gate
    for col in range(cx - reach, cx + reach + 1):
        lo = np.searchsorted(cells_keys, col * _STRIDE + cy - reach)
        hi = np.searchsorted(cells_keys, col * _STRIDE + cy + reach, side="right")
        for k in range(lo, hi):
            dx = ref[k, 0] - qx
            dy = ref[k, 1] - qy
            d2 = dx * dx + dy * dy
            if d2 < best_d2:
                best_d2 = d2
                best = k
    return best


@njit(cache=True, nogil=True)
def run_icp(keys, ref, normals, line, corner, pts, x, y, th, corners, start_gate, min_gate,
            huber, corner_weight, tolerance, max_iterations):  # pragma: no cover - compiled
    """ICP of ``pts`` from (x, y, th): returns x, y, th, the last normal matrix H (3 x 3), the
    weighted residual RMS, the matched count, the summed weights, iterations and whether the
    last step was below ``tolerance``. (The same steps as the NumPy loop it replaced; see
    :func:`vmp.registration._icp`.)"""
    n = pts.shape[0]
    gate = start_gate
    converged = False
    it = 0
    H = np.zeros((3, 3))
    rms = np.inf
    matched_share = 0.0
    wsum = 0.0
    for it in range(1, max_iterations + 1):  # noqa: B007 - returned
        c = math.cos(th)
        s = math.sin(th)
        h00 = h01 = h02 = h11 = h12 = h22 = 0.0
        g0 = g1 = g2 = 0.0
        w_total = 0.0
        we2 = 0.0
        n_matched = 0
        for i in range(n):
            qx = pts[i, 0] * c - pts[i, 1] * s + x
            qy = pts[i, 0] * s + pts[i, 1] * c + y
            if not (math.isfinite(qx) and math.isfinite(qy)):
                continue
            k = _nearest(keys, ref, qx, qy, gate)
            if k < 0:
                continue
            if line[k]:
                nx = normals[k, 0]
                ny = normals[k, 1]
                e = (qx - ref[k, 0]) * nx + (qy - ref[k, 1]) * ny
                w = min(1.0, huber / max(abs(e), 1e-12))
                j2 = ny * qx - nx * qy
                h00 += w * nx * nx
                h01 += w * nx * ny
                h02 += w * nx * j2
                h11 += w * ny * ny
                h12 += w * ny * j2
                h22 += w * j2 * j2
                g0 += w * nx * e
                g1 += w * ny * e
                g2 += w * j2 * e
                w_total += w
                we2 += w * e * e
                n_matched += 1
            elif corners and corner[k]:
                ex = qx - ref[k, 0]
                ey = qy - ref[k, 1]
                a = math.sqrt(ex * ex + ey * ey)
                w = corner_weight * (1.0 if a <= huber else huber / max(a, 1e-12))
                # Two residuals, x and y: Jacobian rows (1, 0, -qy) and (0, 1, qx).
                h00 += w
                h02 += -w * qy
                h11 += w
                h12 += w * qx
                h22 += w * (qy * qy + qx * qx)
                g0 += w * ex
                g1 += w * ey
                g2 += w * (qx * ey - qy * ex)
                w_total += 2.0 * w
                we2 += w * (ex * ex + ey * ey)
                n_matched += 1
        if n_matched < 6:
            break
        H[0, 0] = h00
        H[0, 1] = H[1, 0] = h01
        H[0, 2] = H[2, 0] = h02
        H[1, 1] = h11
        H[1, 2] = H[2, 1] = h12
        H[2, 2] = h22
        wsum = w_total
        ok, dx, dy, dth = _solve_symmetric(h00, h01, h02, h11, h12, h22, g0, g1, g2)
        if not ok:
            break
        # Left-compose the step: rotate the pose about the origin, then translate.
        cd = math.cos(dth)
        sd = math.sin(dth)
        x, y = dx + cd * x - sd * y, dy + sd * x + cd * y
        th = (th + dth + math.pi) % (2 * math.pi) - math.pi
        rms = math.sqrt(we2 / wsum)
        matched_share = n_matched / n
        gate = min(gate, max(min_gate, 4.0 * rms + 0.02))
        if max(abs(dx), abs(dy), abs(dth)) < tolerance:
            converged = True
            break
    return x, y, th, H, rms, matched_share, wsum, it, converged


@njit(cache=True, nogil=True)
def _solve_symmetric(a, b, c, d, e, f, g0, g1, g2):  # pragma: no cover - compiled
    """``-(H + 1e-9 I)^-1 g`` for the symmetric ``H = [[a b c] [b d e] [c e f]]`` by its
    cofactors; ``ok`` is False when it is singular."""
    a += 1e-9
    d += 1e-9
    f += 1e-9
    ca = d * f - e * e
    cb = c * e - b * f
    cc = b * e - c * d
    det = a * ca + b * cb + c * cc
    if not math.isfinite(det) or det == 0.0:
        return False, 0.0, 0.0, 0.0
    cd = a * f - c * c
    ce = b * c - a * e
    cf = a * d - b * b
    return (True, -(ca * g0 + cb * g1 + cc * g2) / det, -(cb * g0 + cd * g1 + ce * g2) / det,
            -(cc * g0 + ce * g1 + cf * g2) / det)
