"""The ICP iterations compiled: nearest reference point, point-to-line (and corner) residuals,
Huber weights and the Gauss-Newton step, one loop per registration.

An iteration on 170 points costs about 140 microseconds in NumPy: a k-d tree query of 50 (SciPy's
``cKDTree``, most of it call overhead on so few points) and some thirty array operations of a few
microseconds each. Mapping registers each scan three to five times, so in NumPy those calls
would be about 40 % of mapping's time. Compiled with Numba, the same arithmetic
with the nearest neighbour found in a grid of cells as wide as the widest correspondence gate
(KISS-ICP's voxel hash map, in a sorted array; for a dense reference such as a saved map, with a
table of where each cell starts) costs a few microseconds an iteration. The same cells serve the
share of a scan a map explains and a scan's likelihood in a map.
"""

from __future__ import annotations

import math

import numpy as np

from vmp.jit import kernel

__all__ = ["CELL", "cell_index", "cell_keys", "count_near", "fit_covariance",
           "likelihood_sum", "point_normals", "run_icp"]

# Cell side (m): ICP's widest correspondence gate, so a gate looks at 3 x 3 cells at most.
CELL = 0.5
_OFFSET = 1 << 30  # cell coordinates are clipped to +-2^30 cells (5e8 m) and shifted positive
_STRIDE = 1 << 32
# Widens the cells looked at about a point (m): a partner exactly at the gate on a cell border
# is not lost to rounding.
_SLACK = 1e-9
# ICP asked to (:func:`run_icp`'s ``revisit``) stops, unconverged, when a step comes back to
# where one of this many steps before it started: its correspondences alternate between two
# sets or a few (a point between neighbouring points of a saved map's wall band) and the steps
# cycle for ever. Unstopped, such cycles (of 2 to 13 steps) run 119 of ACES's 498 tracking
# registrations against its saved map to the 30 iterations' cap, half of that ICP's time.
CYCLE = 10
# How near (m, rad) such a step must come back: a cycle closing, not a step shrinking on its
# way to converge (within ICP's tolerance of 5e-4, 52 of 82 such stops in a simulated band map
# would have converged, some 2 cm away; within 1e-9, every one runs to the cap, tested).
REVISIT = 1e-9
# A column's rows are looked up cell by cell in a hash table (:func:`cell_index`) up to this
# many (ICP's widest gate touches three), else by binary search.
HASHED_ROWS = 4
# A reference gets a table of its cells (:func:`cell_index`) when its bounding box holds at
# most this many cells a point.
DENSE = 4


def cell_keys(points: np.ndarray) -> np.ndarray:
    """One integer per point naming the grid cell it lies in; the cells of one column are
    consecutive. :func:`run_icp` needs its reference's rows sorted by these keys."""
    cells = np.clip(np.floor(points / CELL), -_OFFSET, _OFFSET - 1).astype(np.int64) + _OFFSET
    return cells[:, 0] * _STRIDE + cells[:, 1]


def cell_index(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
    """What the kernels look a sorted reference's cells up in: its ``keys`` (sorted), and
    where they are dense (a map: at least a point for every four cells of their bounding
    box), a table of where each cell's rows start, columns by rows, with the box's first
    column and row; else a hash table of the cells that hold points (a scan: 180 points
    spread over 80 m), rows ``(cell key, first row, end)``, ``-1`` keys empty, with the
    column and row ``-1``.

    In a table a cell's rows are found at once; in the keys, by two binary searches a column
    (about 200 ns each among a saved map's 53,000 points, most of what finding a point's
    nearest neighbour would cost). In a hash table, by a probe or two a cell: among a scan's
    180 points the two searches would still be most of scan odometry's ICP."""
    keys = np.ascontiguousarray(keys, dtype=np.int64)
    if len(keys) == 0:
        return keys, np.zeros((0, 0), dtype=np.int64), 0, 0
    col0, row0, col1, row1 = _box(keys)
    n_cols, n_rows = col1 - col0 + 1, row1 - row0 + 1
    if n_cols * (n_rows + 1) > DENSE * len(keys):
        return keys, _cell_hash(keys), -1, -1
    # Row r of column c: the first point at or after cell (col0 + c, row0 + r); r = n_rows
    # is the column's end.
    starts = ((col0 + np.arange(n_cols, dtype=np.int64))[:, None] * _STRIDE
              + row0 + np.arange(n_rows + 1, dtype=np.int64)[None, :])
    table = np.searchsorted(keys, starts.ravel()).reshape(n_cols, n_rows + 1)
    return keys, np.ascontiguousarray(table, dtype=np.int64), col0, row0


@kernel
def _box(keys):  # pragma: no cover - compiled
    """The first and last column and row of the cells ``keys`` (sorted, not empty)."""
    row0 = row1 = keys[0] % _STRIDE
    for k in keys:
        row = k % _STRIDE
        row0 = min(row0, row)
        row1 = max(row1, row)
    return keys[0] // _STRIDE, row0, keys[-1] // _STRIDE, row1


@kernel
def _cell_hash(keys):  # pragma: no cover - compiled
    """The hash table of sorted ``keys``' cells (:func:`cell_index`): at most half full,
    probed linearly from :func:`_slot`. (In NumPy calls it would take as long as sorting
    and indexing a scan's points besides: a keyframe is made every few scans.)"""
    cells = 1
    for i in range(1, keys.shape[0]):
        if keys[i] != keys[i - 1]:
            cells += 1
    size = 8
    while size < 2 * cells:
        size *= 2
    table = np.full((size, 3), -1, dtype=np.int64)
    mask = size - 1
    start = 0
    for i in range(1, keys.shape[0] + 1):
        if i < keys.shape[0] and keys[i] == keys[start]:
            continue
        j = _slot(keys[start], mask)
        while table[j, 0] >= 0:
            j = (j + 1) & mask
        table[j, 0] = keys[start]
        table[j, 1] = start
        table[j, 2] = i
        start = i
    return table


@kernel
def _slot(key, mask):  # pragma: no cover - compiled
    """Where a cell ``key`` is first looked for in a hash table of ``mask + 1`` rows."""
    return ((key // _STRIDE) * 73856093 ^ (key % _STRIDE) * 19349663) & mask


@kernel
def _hashed_rows(table, key):  # pragma: no cover - compiled
    """The rows ``lo:hi`` of the cell ``key`` in a hash table (:func:`_cell_hash`); -1, -1
    when it holds no point."""
    mask = table.shape[0] - 1
    j = _slot(key, mask)
    while table[j, 0] >= 0:
        if table[j, 0] == key:
            return table[j, 1], table[j, 2]
        j = (j + 1) & mask
    return -1, -1


@kernel
def _cell(v):  # pragma: no cover - compiled
    """The (shifted) cell coordinate of one coordinate ``v``, as :func:`cell_keys` has it."""
    return int(min(max(math.floor(v / CELL), -_OFFSET), _OFFSET - 1)) + _OFFSET


@kernel
def _column_rows(cells, col, row_lo, row_hi):  # pragma: no cover - compiled
    """The sorted rows ``lo:hi`` in column ``col`` of cells, rows ``row_lo`` to ``row_hi``
    (one range: a column's cells are consecutive in the sort), looked up in ``cells``
    (:func:`cell_index`)."""
    keys, table, col0, row0 = cells
    if table.shape[0] == 0 or (col0 < 0 and row_hi - row_lo >= HASHED_ROWS):
        return (np.searchsorted(keys, col * _STRIDE + row_lo),
                np.searchsorted(keys, col * _STRIDE + row_hi, side="right"))
    if col0 < 0:  # hashed: from the first cell that holds points to the end of the last
        lo = hi = -1
        for row in range(row_lo, row_hi + 1):
            start, end = _hashed_rows(table, col * _STRIDE + row)
            if start >= 0:
                if lo < 0:
                    lo = start
                hi = end
        return (lo, hi) if lo >= 0 else (0, 0)
    c = col - col0
    if c < 0 or c >= table.shape[0]:
        return 0, 0
    last = table.shape[1] - 1
    return (table[c, min(max(row_lo - row0, 0), last)],
            table[c, min(max(row_hi + 1 - row0, 0), last)])


@kernel
def _nearest(cells, ref, qx, qy, gate, first=False):  # pragma: no cover - compiled
    """Row of the reference point nearest to (qx, qy) closer than ``gate``, or -1; with
    ``first``, of any closer than ``gate``: the first found ends the search, where any
    answer will do (a scan placed well has one in the first cell or two looked at, in a map's
    wall bands of dozens)."""
    best = -1
    best_d2 = gate * gate
    # Only the cells the square of side 2 gate about the query touches: a point closer than
    # the gate lies in one of them, and they are visited in the order of the full 3 x 3 block
    # (the same nearest, ties too), but once the gate has shrunk to a few centimetres that is
    # one cell, seldom two, not nine (in a map's thick walls, a hundred points or more each).
    reach = gate + _SLACK
    row_lo, row_hi = _cell(qy - reach), _cell(qy + reach)
    for col in range(_cell(qx - reach), _cell(qx + reach) + 1):
        lo, hi = _column_rows(cells, col, row_lo, row_hi)
        for k in range(lo, hi):
            dx = ref[k, 0] - qx
            dy = ref[k, 1] - qy
            d2 = dx * dx + dy * dy
            if d2 < best_d2:
                if first:
                    return k
                best_d2 = d2
                best = k
    return best


@kernel
def count_near(cells, ref, points, x, y, c, s, distance):  # pragma: no cover - compiled
    """How many of ``points`` placed at (x, y), turned by the angle of cosine ``c`` and sine
    ``s``, lie closer than ``distance`` to a point of the reference ``ref`` (its cells:
    :func:`cell_index`)."""
    count = 0
    for i in range(points.shape[0]):
        qx = x + c * points[i, 0] - s * points[i, 1]
        qy = y + s * points[i, 0] + c * points[i, 1]
        if _nearest(cells, ref, qx, qy, distance, True) >= 0:
            count += 1
    return count


@kernel
def likelihood_sum(cells, ref, points, x, y, c, s, sigma, flat,
                   reach):  # pragma: no cover - compiled
    """The sum over ``points`` placed at (x, y), turned by the angle of cosine ``c`` and sine
    ``s``, of ``exp(-e^2 / 2 sigma^2)``, ``e`` how much farther than ``flat`` the nearest
    point of the reference ``ref`` (its cells: :func:`cell_index`) lies; a point with none
    within ``reach`` adds nothing."""
    total = 0.0
    scale = -0.5 / (sigma * sigma)
    for i in range(points.shape[0]):
        # As vmp.types.transform_points places them, to the bit.
        qx = x + c * points[i, 0] - s * points[i, 1]
        qy = y + s * points[i, 0] + c * points[i, 1]
        # A point with a partner within ``flat`` scores 1 whichever is nearest (most of a
        # scan placed well); else the nearest within flat + sigma, which touches fewer cells
        # than ``reach`` (the same nearest: one within it is the nearest within reach).
        if _nearest(cells, ref, qx, qy, min(flat, reach), True) >= 0:
            total += 1.0
            continue
        k = _nearest(cells, ref, qx, qy, min(flat + sigma, reach))
        if k < 0:
            k = _nearest(cells, ref, qx, qy, reach)
        if k >= 0:
            dx = ref[k, 0] - qx
            dy = ref[k, 1] - qy
            e = max(math.sqrt(dx * dx + dy * dy) - flat, 0.0)
            total += math.exp(e * e * scale)
    return total


@kernel
def run_icp(cells, ref, normals, line, corner, pts, x, y, th, corners, start_gate, min_gate,
            huber, corner_weight, tolerance, max_iterations,
            revisit=0.0, settle=0.0):  # pragma: no cover - compiled
    """ICP of ``pts`` from (x, y, th): returns x, y, th, the last normal matrix H (3 x 3), the
    weighted residual RMS, the matched count, the summed weights, iterations and whether the
    last step was below ``tolerance``; with ``revisit`` above 0, it stops where a step comes
    back to within ``revisit`` of where one of the last :data:`CYCLE` steps started; with
    ``settle`` above 0, it stops, converged, where a step changes the matched points'
    residuals by less than ``settle`` (their weighted RMS change, to first order), however
    far it moves the pose. (The same steps as the NumPy spec in ``tests/test_icp_kernel.py``;
    called by :func:`vmp.registration._icp`.)"""
    n = pts.shape[0]
    gate = start_gate
    converged = False
    # Where the last CYCLE steps started (a ring): a step back to within ``revisit`` of one
    # of them means the iterations cycle (below).
    seen = np.empty((CYCLE, 3))
    it = 0
    H = np.zeros((3, 3))
    rms = np.inf
    matched_share = 0.0
    wsum = 0.0
    for it in range(1, max_iterations + 1):
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
            k = _nearest(cells, ref, qx, qy, gate)
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
        seen[(it - 1) % CYCLE, 0] = x
        seen[(it - 1) % CYCLE, 1] = y
        seen[(it - 1) % CYCLE, 2] = th
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
        # The step's change of the matched points' residuals, to first order (its size as
        # the fit sees it): a step along what the fit leaves nearly free (a corridor's
        # axis, a wall band's slope) changes them little however long it is. Against a
        # saved map's wall bands, 82 % of ACES's tracking registrations leave a direction
        # free, and their steps slide on a few millimetres at a time: stopping here takes
        # them 11.5 iterations on average rather than 13.4, and scan odometry's 5.1 rather
        # than 6.2.
        change = (h00 * dx * dx + h11 * dy * dy + h22 * dth * dth
                  + 2.0 * (h01 * dx * dy + h02 * dx * dth + h12 * dy * dth))
        if change < settle * settle * w_total:
            converged = True
            break
        if revisit > 0.0 and _revisits(seen, min(it, CYCLE), x, y, th, revisit):
            break
    return x, y, th, H, rms, matched_share, wsum, it, converged


@kernel
def _revisits(seen, count, x, y, th, within):  # pragma: no cover - compiled
    """Whether (x, y, th) lies within ``within`` of one of the first ``count`` poses of the
    ring ``seen``."""
    for j in range(count):
        turn = abs((th - seen[j, 2] + math.pi) % (2 * math.pi) - math.pi)
        if max(abs(x - seen[j, 0]), abs(y - seen[j, 1]), turn) < within:
            return True
    return False


@kernel
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


@kernel
def fit_covariance(H, rms, wsum, min_constraint, degenerate_share, scale, min_sigma_xy,
                   min_sigma_theta, max_sigma):  # pragma: no cover - compiled
    """The covariance of a fit with normal matrix ``H``, and how many directions of
    translation it leaves free: ``s^2 H^-1`` with ``s^2 = scale * max(rms, min_sigma_xy)^2``,
    directions ``H`` barely constrains opened to ``max_sigma``, each direction of translation
    that few matched normals face (``H``'s xy eigenvalue under ``min_constraint`` or under
    ``degenerate_share`` of the summed weights) opened up too, plus a floor. (See
    :func:`vmp.registration._covariance`; two NumPy ``eigh`` calls cost about 30
    microseconds a registration.)"""
    big = max_sigma * max_sigma
    tv, tvec = np.linalg.eigh(H[:2, :2].copy())
    s = max(rms, min_sigma_xy)
    sigma2 = s * s * scale
    vals, vecs = np.linalg.eigh(H.copy())
    cov = np.zeros((3, 3))
    for k in range(3):
        inv = 1.0 / max(vals[k], 1e-300) if vals[k] > sigma2 / big else big / sigma2
        for r in range(3):
            for c in range(3):
                cov[r, c] += vecs[r, k] * inv * vecs[c, k]
    for r in range(3):
        for c in range(3):
            cov[r, c] *= sigma2
    free = 0
    for k in range(2):
        if tv[k] < min_constraint or tv[k] < degenerate_share * wsum:
            free += 1
            for r in range(2):
                for c in range(2):
                    cov[r, c] += big * tvec[r, k] * tvec[c, k]
    cov[0, 0] += min_sigma_xy * min_sigma_xy
    cov[1, 1] += min_sigma_xy * min_sigma_xy
    cov[2, 2] += min_sigma_theta * min_sigma_theta
    return cov, free


@kernel
def point_normals(cells, points, k, max_spread):  # pragma: no cover - compiled
    """Per point of a reference sorted by :func:`cell_keys`: the normal of the line through
    its ``k`` nearest points (itself included) that lie within ``max_spread``, whether they
    lie on a line (``line``: at least three, the minor axis of their scatter under a tenth of
    the major) and whether they do not (``corner``: at least three, no line). (SciPy's k-d
    tree built for this alone cost a third of a reference's building, which scan odometry
    and every new milestone do.)"""
    n = points.shape[0]
    normals = np.empty((n, 2))
    line = np.zeros(n, dtype=np.bool_)
    corner = np.zeros(n, dtype=np.bool_)
    best_d = np.empty(k)
    best_i = np.empty(k, dtype=np.int64)
    limit = max_spread * max_spread
    reach = max_spread + _SLACK  # the cells within this either way can hold a neighbour
    for p in range(n):
        px = points[p, 0]
        py = points[p, 1]
        found = 0
        row_lo, row_hi = _cell(py - reach), _cell(py + reach)
        for col in range(_cell(px - reach), _cell(px + reach) + 1):
            lo, hi = _column_rows(cells, col, row_lo, row_hi)
            for q in range(lo, hi):
                dx = points[q, 0] - px
                dy = points[q, 1] - py
                d2 = dx * dx + dy * dy
                if d2 > limit or (found == k and d2 >= best_d[k - 1]):
                    continue
                # Insert in distance order (ties: the lower row first).
                if found < k:
                    at = found
                    found += 1
                else:
                    at = k - 1  # the farthest kept gives way
                while at > 0 and (best_d[at - 1] > d2 or (best_d[at - 1] == d2
                                                          and best_i[at - 1] > q)):
                    best_d[at] = best_d[at - 1]
                    best_i[at] = best_i[at - 1]
                    at -= 1
                best_d[at] = d2
                best_i[at] = q
        mx = 0.0
        my = 0.0
        for t in range(found):
            mx += points[best_i[t], 0]
            my += points[best_i[t], 1]
        mx /= found
        my /= found
        sxx = 0.0
        syy = 0.0
        sxy = 0.0
        for t in range(found):
            dx = points[best_i[t], 0] - mx
            dy = points[best_i[t], 1] - my
            sxx += dx * dx
            syy += dy * dy
            sxy += dx * dy
        # Direction of the line through the neighbours: the major axis of their scatter.
        angle = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
        normals[p, 0] = -math.sin(angle)
        normals[p, 1] = math.cos(angle)
        tr = sxx + syy
        det = sxx * syy - sxy * sxy
        disc = math.sqrt(max(tr * tr / 4 - det, 0.0))
        minor = tr / 2 - disc
        major = tr / 2 + disc
        if found >= 3:
            if minor <= 0.1 * max(major, 1e-12):
                line[p] = True
            else:
                corner[p] = True
    return normals, line, corner
