"""Branch-and-bound correlative scan matching over precomputed multi-resolution grids.

After Olson ("Real-time correlative scan matching", ICRA 2009) and Hess et al. ("Real-time
loop closure in 2D LIDAR SLAM", ICRA 2016). The reference (a submap's points) becomes a
likelihood grid; level ``d`` of the precomputed stack holds, at each cell, the largest
likelihood in the ``2^d x 2^d`` block that starts there, so the score of a pose on level ``d``
bounds the score of every pose in its block on level 0. The search scores the whole window
coarsely, then descends only into blocks whose bound can still beat the best exact score found
so far: the answer is the exhaustive search's, at a fraction of its cost, which grows with the
log of the window's area rather than with the area.

NumPy suits a level-by-level descent better than the depth-first recursion of the papers: all
surviving candidates of a level are scored in one gather, after a greedy dive from the best of
them has set the bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vmp.jit import kernel
from vmp.types import FloatArray

__all__ = ["Match", "SearchGrid", "likelihood_grid", "search", "search_points"]


SEARCH_POINTS = 100  # live points searched with (evenly thinned) ...
SEARCH_RANGE = 12.0  # ... from those within this range (m)


def search_points(points: FloatArray) -> FloatArray:
    """The points of a scan ``(N, 2)`` a search uses: those within :data:`SEARCH_RANGE`,
    evenly thinned to :data:`SEARCH_POINTS` (the search's cost grows with their number)."""
    pts = points[np.hypot(points[:, 0], points[:, 1]) <= SEARCH_RANGE]
    if len(pts) > SEARCH_POINTS:
        pts = pts[np.linspace(0, len(pts) - 1, SEARCH_POINTS).round().astype(np.int64)]
    return pts


@dataclass(frozen=True)
class Match:
    """The best pose in a window, its score (mean likelihood of the points) and effort."""

    pose: FloatArray  # (3,) the points' frame in the grid's frame
    score: float  # in [0, 1]
    evaluated: int  # candidate poses scored, all levels together


def likelihood_grid(points: FloatArray, resolution: float, sigma: float,
                    pad: int) -> tuple[FloatArray, np.ndarray]:
    """The likelihood ``exp(-d^2 / 2 sigma^2)`` of the distance ``d`` from each cell's centre
    to the nearest cell holding one of the finite ``points`` ``(N, 2)``, in steps of 1/255 (one
    byte a cell): the world position of cell (0, 0)'s centre and the grid, covering the points
    plus a few ``sigma`` and ``pad`` cells of zeros on every side.

    Cell distances are whole numbers under a root, so the likelihood takes one value per
    squared distance; each point's cell stamps the few within reach of a non-zero value (a
    radius of 3.5 sigma), keeping the larger. (A Euclidean distance transform of the whole
    grid, then ``exp`` of every cell, took 7.1 of a 2,400-point submap's 10.6 ms.)
    """
    margin = math.ceil(3.0 * sigma / resolution) + 1
    lo = points.min(axis=0) - margin * resolution
    hi = points.max(axis=0) + margin * resolution
    shape = np.ceil((hi - lo) / resolution).astype(np.int64) + 1
    cells = np.rint((points - lo) / resolution).astype(np.int64) + pad
    return lo - pad * resolution, _stamp(cells, shape[0] + 2 * pad, shape[1] + 2 * pad,
                                          _likelihood_by_squared_distance(resolution, sigma))


def _likelihood_by_squared_distance(resolution: float, sigma: float) -> np.ndarray:
    """``round(255 exp(-d^2 / 2 sigma^2))`` for ``d`` = ``resolution`` times the root of 0, 1,
    2, ... cells squared, up to the last that is not zero."""
    reach = math.ceil(4.0 * sigma / resolution) + 1  # exp(-8) * 255 rounds to 0
    d = np.sqrt(np.arange(reach * reach + 1, dtype=np.float64))
    value = np.round(255.0 * np.exp(-0.5 * (d * resolution / sigma) ** 2)).astype(np.uint8)
    return value[:np.flatnonzero(value)[-1] + 1]


@kernel
def _stamp(cells: np.ndarray, rows: int, cols: int, value: np.ndarray) -> np.ndarray:
    """A ``rows x cols`` byte grid: per cell, the largest ``value[d2]`` over the ``cells``
    ``(N, 2)`` at squared distance ``d2`` from it."""
    out = np.zeros((rows, cols), dtype=np.uint8)
    far = len(value)
    radius = int(np.sqrt(far - 1))
    for k in range(cells.shape[0]):
        cx, cy = cells[k, 0], cells[k, 1]
        for dx in range(-radius, radius + 1):
            x = cx + dx
            if x < 0 or x >= rows:
                continue
            for dy in range(-radius, radius + 1):
                y = cy + dy
                d2 = dx * dx + dy * dy
                if y < 0 or y >= cols or d2 >= far:
                    continue
                if value[d2] > out[x, y]:
                    out[x, y] = value[d2]
    return out


class SearchGrid:
    """A likelihood grid of reference points and its stack of block maxima.

    ``resolution`` is the cell size; the likelihood falls off with the distance to the nearest
    reference point as ``exp(-d^2 / 2 sigma^2)``; ``depth`` levels are precomputed.
    """

    def __init__(self, points: FloatArray, resolution: float = 0.1, sigma: float = 0.1,
                 depth: int = 5, max_window: float = 4.0) -> None:
        pts = np.asarray(points, dtype=np.float64)
        pts = pts[np.isfinite(pts).all(axis=1)] if pts.size else pts.reshape(0, 2)
        if len(pts) == 0:
            raise ValueError("a search grid needs at least one reference point")
        self.resolution, self.sigma, self.depth = float(resolution), float(sigma), int(depth)
        self.max_steps = math.ceil(max_window / resolution - 1e-9)
        # Zeros around the likelihood, wide enough that a point clamped into the padding
        # (see :meth:`clamp`) reads zeros under every offset of the window on every level.
        self.pad = 2 * self.max_steps + (1 << depth) + 1
        # One byte a cell: the block maxima are gathered by the thousand per search level.
        self.origin, level0 = likelihood_grid(pts, self.resolution, self.sigma, self.pad)
        self.levels = [level0]
        # Where the level below is not zero: the likelihood inside the padding, widened
        # towards the origin by each level's blocks.
        rows = [self.pad, level0.shape[0] - self.pad]
        cols = [self.pad, level0.shape[1] - self.pad]
        for k in range(1, depth + 1):
            step = 1 << (k - 1)
            self.levels.append(_block_max(self.levels[-1], step, tuple(rows), tuple(cols)))
            rows[0], cols[0] = max(rows[0] - step, 0), max(cols[0] - step, 0)

    @property
    def shape(self) -> tuple[int, int]:
        return self.levels[0].shape  # type: ignore[return-value]

    def cells(self, points: FloatArray, pose: FloatArray) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices of ``points`` (their frame) placed at ``pose``."""
        cx, cy = self.turned_cells(points, pose[0], pose[1], (pose[2],))
        return cx[0], cy[0]

    def turned_cells(self, points: FloatArray, x: float, y: float, thetas
                     ) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices ``(R, M)`` of ``points`` ``(M, 2)`` placed at (x, y) turned by each of
        the ``R`` angles ``thetas`` (their cosines by ``math``, one at a time)."""
        c = np.array([math.cos(t) for t in thetas])[:, None]
        s = np.array([math.sin(t) for t in thetas])[:, None]
        px = x + c * points[:, 0] - s * points[:, 1]
        py = y + s * points[:, 0] + c * points[:, 1]
        return (np.rint((px - self.origin[0]) / self.resolution).astype(np.int64),
                np.rint((py - self.origin[1]) / self.resolution).astype(np.int64))

    def clamp(self, cx: np.ndarray, cy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cells moved into the padding where they lie beyond it: under any offset of a
        window up to ``max_window`` they then index the grid and read zeros (the likelihood is
        zero there too), so the search needs no bounds checks."""
        lo, hi = self.max_steps, np.array(self.shape) - 1 - self.max_steps - (1 << self.depth)
        return np.clip(cx, lo, hi[0]), np.clip(cy, lo, hi[1])

    def score(self, points: FloatArray, pose: FloatArray) -> float:
        """Mean likelihood of ``points`` at ``pose`` (level 0)."""
        cx, cy = self.clamp(*self.cells(np.asarray(points, dtype=np.float64), pose))
        return float(self.levels[0][cx, cy].mean()) / 255.0


@kernel
def _block_max(grid: np.ndarray, step: int, rows: tuple[int, int], cols: tuple[int, int]
               ) -> np.ndarray:
    """The maximum of the four cells ``step`` apart: a block of ``2 step`` from blocks of
    ``step`` (cells beyond the edge count as zero). ``grid`` is zero outside the rows
    ``rows[0]:rows[1]`` and columns ``cols[0]:cols[1]``: only the blocks reaching into them
    are worked out (a submap's padding is most of its grid)."""
    n_rows, n_cols = grid.shape
    out = np.zeros_like(grid)
    x0, y0 = max(rows[0] - step, 0), max(cols[0] - step, 0)
    x_in, y_in = min(rows[1], n_rows - step), min(cols[1], n_cols - step)
    for x in range(x0, x_in):  # blocks whole inside the grid: no bounds to check
        for y in range(y0, y_in):
            out[x, y] = max(max(grid[x, y], grid[x, y + step]),
                            max(grid[x + step, y], grid[x + step, y + step]))
    for x in range(x0, rows[1]):  # blocks that cross the last rows or columns
        for y in range(y_in if x < x_in else y0, cols[1]):
            m = grid[x, y]
            if y + step < n_cols:
                m = max(m, grid[x, y + step])
            if x + step < n_rows:
                m = max(m, grid[x + step, y])
                if y + step < n_cols:
                    m = max(m, grid[x + step, y + step])
            out[x, y] = m
    return out


def _angles(points: FloatArray, resolution: float, window: float) -> FloatArray:
    """Rotations searched: a step that moves the farthest point by about one cell."""
    r = float(np.hypot(points[:, 0], points[:, 1]).max()) if len(points) else 1.0
    step = math.acos(max(-1.0, 1.0 - resolution**2 / (2.0 * max(r, resolution) ** 2)))
    n = math.ceil(window / step)
    return np.arange(-n, n + 1) * step


def search(grid: SearchGrid, points: FloatArray, center: FloatArray, window_xy: float,
           window_theta: float, min_score: float = 0.0,
           exclude: tuple[FloatArray, float, float] | None = None) -> Match | None:
    """The best pose of ``points`` within ``window_xy`` (either way, in x and y) and
    ``window_theta`` of ``center``, or None when no pose scores ``min_score``.

    ``exclude`` (a pose, a distance and a turn) leaves out the poses that near it: the best
    pose elsewhere, to tell a clear peak from one of several alike.
    """
    pts = np.asarray(points, dtype=np.float64)
    res, depth = grid.resolution, grid.depth
    thetas = center[2] + _angles(pts, res, window_theta)
    steps = min(math.ceil(window_xy / res - 1e-9), grid.max_steps)
    # Each rotation's points, placed at the window's centre: cell indices (R, M).
    cx, cy = grid.clamp(*grid.turned_cells(pts, center[0], center[1], thetas))
    scale = 255.0 * len(pts)
    stride = grid.shape[1]
    flat = np.ascontiguousarray(cx * stride + cy)  # (R, M) flat cell indices
    levels = [g.ravel() for g in grid.levels]

    def scores(level: int, rot: np.ndarray, ox: np.ndarray, oy: np.ndarray) -> np.ndarray:
        out = block_sums(levels[level], flat, rot, ox * stride + oy) / scale
        if level == 0 and exclude is not None:  # bounds above stay bounds
            pose, dxy, dth = exclude
            near = (np.hypot(center[0] + ox * res - pose[0], center[1] + oy * res - pose[1])
                    < dxy) & (np.abs((thetas[rot] - pose[2] + math.pi) % (2 * math.pi)
                                     - math.pi) < dth)
            out[near] = -1.0
        return out

    # The coarsest candidates: blocks of 2^depth cells whose children cover the window.
    top = 1 << depth
    corners = np.arange(-steps, steps + 1, top)
    rot, ox, oy = (a.ravel() for a in np.meshgrid(np.arange(len(thetas)), corners, corners,
                                                  indexing="ij"))
    values = scores(depth, rot, ox, oy)
    evaluated = len(rot)
    best: tuple[float, tuple[int, int, int] | None] = (min_score, None)
    for level in range(depth, 0, -1):
        keep = values >= best[0]
        if not keep.any():
            break
        rot, ox, oy, values = rot[keep], ox[keep], oy[keep], values[keep]
        best = _dive(scores, level, rot, ox, oy, values, steps, best)
        half = 1 << (level - 1)
        n = len(rot)
        rot = np.repeat(rot, 4)
        ox = np.repeat(ox, 4) + np.tile([0, half, 0, half], n)
        oy = np.repeat(oy, 4) + np.tile([0, 0, half, half], n)
        inside = (ox <= steps) & (oy <= steps)
        rot, ox, oy = rot[inside], ox[inside], oy[inside]
        values = scores(level - 1, rot, ox, oy)
        evaluated += len(rot)
        if level == 1 and len(values):  # exact scores: the leaves
            i = int(np.argmax(values))
            if values[i] >= best[0]:
                best = (float(values[i]), (int(rot[i]), int(ox[i]), int(oy[i])))
    if best[1] is None:
        return None
    r, x, y = best[1]
    pose = np.array([center[0] + x * res, center[1] + y * res,
                     (thetas[r] + math.pi) % (2 * math.pi) - math.pi])
    return Match(pose, best[0], evaluated)


@kernel
def block_sums(level, flat, rot, offset):  # pragma: no cover - compiled
    """For each candidate ``k``: the sum of ``level`` (a flattened grid of bytes) over the
    cells ``flat[rot[k]] + offset[k]`` (rotation ``rot[k]``'s points moved by ``offset[k]``
    cells). In NumPy the gather made a (candidates, points) array of a few hundred thousand
    entries per level before summing it (docs/benchmarks.md, 2026-12-03)."""
    n = rot.shape[0]
    m = flat.shape[1]
    out = np.empty(n, dtype=np.int64)
    for k in range(n):
        row = flat[rot[k]]
        off = offset[k]
        total = 0
        for i in range(m):
            total += level[row[i] + off]
        out[k] = total
    return out


def _dive(scores, level: int, rot: np.ndarray, ox: np.ndarray, oy: np.ndarray,
          level_scores: np.ndarray, steps: int, best: tuple) -> tuple:
    """Follow the best candidate's best child down to level 0; a better exact score found
    on the way raises the bound that prunes the others."""
    i = int(np.argmax(level_scores))
    r, x, y = rot[i], ox[i], oy[i]
    for lv in range(level, 0, -1):
        half = 1 << (lv - 1)
        cx = np.array([x, x + half, x, x + half])
        cy = np.array([y, y, y + half, y + half])
        ok = (cx <= steps) & (cy <= steps)
        cx, cy = cx[ok], cy[ok]
        s = scores(lv - 1, np.full(len(cx), r), cx, cy)
        j = int(np.argmax(s))
        x, y = cx[j], cy[j]
        if lv == 1 and s[j] >= best[0]:
            return float(s[j]), (int(r), int(x), int(y))
    return best
