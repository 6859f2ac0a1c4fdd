"""Branch-and-bound correlative scan matching over precomputed multi-resolution grids.

After Olson ("Real-time correlative scan matching", ICRA 2009) and Hess et al. ("Real-time
loop closure in 2D LIDAR SLAM", ICRA 2016). The reference (a submap's points) becomes a
likelihood grid; level ``d`` of the precomputed stack holds, at each cell, the largest
likelihood in the ``2^d x 2^d`` block that starts there, so the score of a pose on level ``d``
bounds the score of every pose in its block on level 0. The search scores the whole window
coarsely, then descends only into blocks whose bound can still beat the best exact score found
so far: the answer is the exhaustive search's, at a fraction of its cost, which grows with the
log of the window's area rather than with the area.

The descent goes level by level rather than depth first as in the papers: all surviving
candidates of a level are scored together, after a greedy dive from the best of them has set
the bound (an order that suits NumPy's arrays: the compiled search keeps it, so that its
answers, ties included, are those of the NumPy search kept in the tests; a search costs 0.9 ms
on the test room's windows, the NumPy one 1.4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vmp.jit import kernel
from vmp.types import FloatArray

__all__ = ["Match", "SearchGrid", "first_match", "likelihood_grid", "mean_likelihood",
           "search", "search_points"]


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
    grid, then ``exp`` of every cell, would take 7.1 of a 2,400-point submap's 10.6 ms.)
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
        # (see :attr:`bounds`) reads zeros under every offset of the window on every level.
        self.pad = 2 * self.max_steps + (1 << depth) + 1
        # One byte a cell: the block maxima are gathered by the thousand per search level.
        self.origin, level0 = likelihood_grid(pts, self.resolution, self.sigma, self.pad)
        self.stack = np.zeros((depth + 1, *level0.shape), dtype=np.uint8)  # level by level
        self.stack[0] = level0
        self.levels = list(self.stack)
        # Where the level below is not zero: the likelihood inside the padding, widened
        # towards the origin by each level's blocks.
        rows = [self.pad, level0.shape[0] - self.pad]
        cols = [self.pad, level0.shape[1] - self.pad]
        for k in range(1, depth + 1):
            step = 1 << (k - 1)
            _block_max(self.levels[k - 1], step, tuple(rows), tuple(cols), self.levels[k])
            rows[0], cols[0] = max(rows[0] - step, 0), max(cols[0] - step, 0)

    @property
    def shape(self) -> tuple[int, int]:
        return self.levels[0].shape  # type: ignore[return-value]

    @property
    def bounds(self) -> tuple[int, int, int]:
        """The least cell index a point's cell is clamped to (either axis) and the greatest
        in x and in y: a point beyond them is moved into the padding, where under any offset
        of a window up to ``max_window`` it indexes the grid and reads zeros (the likelihood
        is zero there too), so the search needs no bounds checks."""
        hi = np.array(self.shape) - 1 - self.max_steps - (1 << self.depth)
        return self.max_steps, int(hi[0]), int(hi[1])

    def score(self, points: FloatArray, pose: FloatArray) -> float:
        """Mean likelihood of ``points`` at ``pose`` (level 0), cells clamped to
        :attr:`bounds`."""
        lo, hi_x, hi_y = self.bounds
        return mean_likelihood(self.levels[0], self.origin, self.resolution, points, pose,
                               (lo, lo), (hi_x, hi_y))


def mean_likelihood(field: np.ndarray, origin: FloatArray, resolution: float,
                    points: FloatArray, pose: FloatArray, lo: tuple[int, int],
                    hi: tuple[int, int]) -> float:
    """Mean likelihood (0 to 1) of ``points`` ``(M, 2)`` (their frame) placed at ``pose`` in a
    byte grid ``field`` whose cell (0, 0) is centred at ``origin``, each cell index clamped
    to ``lo``..``hi``; 0 for no points. Once per scan and place followed: in NumPy, a dozen
    array operations of a few microseconds each on 180 points (29 microseconds a call;
    compiled, 5.5)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if len(pts) == 0:
        return 0.0
    x, y, theta = (float(v) for v in pose)
    total = _likelihood_sum(field, float(origin[0]), float(origin[1]), float(resolution),
                            pts, x, y, math.cos(theta), math.sin(theta), lo[0], lo[1], hi[0],
                            hi[1])
    return total / len(pts) / 255.0


@kernel
def _likelihood_sum(field, ox, oy, res, pts, x, y, c, s, lo_x, lo_y, hi_x, hi_y
                    ):  # pragma: no cover - compiled
    """The sum of ``field`` over the clamped cells of ``pts`` placed at (x, y), turned by
    the angle of cosine ``c`` and sine ``s``."""
    total = 0
    for k in range(pts.shape[0]):
        total += field[_cell(x + c * pts[k, 0] - s * pts[k, 1], ox, res, lo_x, hi_x),
                       _cell(y + s * pts[k, 0] + c * pts[k, 1], oy, res, lo_y, hi_y)]
    return float(total)


@kernel
def _cell(v, origin, res, lo, hi):  # pragma: no cover - compiled
    """The index of the cell holding coordinate ``v`` (cell 0 centred at ``origin``),
    clamped to ``lo``..``hi``."""
    return min(max(int(np.rint((v - origin) / res)), lo), hi)


@kernel
def _block_max(grid: np.ndarray, step: int, rows: tuple[int, int], cols: tuple[int, int],
               out: np.ndarray) -> None:
    """Into ``out`` (zeros, ``grid``'s shape): the maximum of the four cells ``step`` apart,
    a block of ``2 step`` from blocks of ``step`` (cells beyond the edge count as zero).
    ``grid`` is zero outside the rows ``rows[0]:rows[1]`` and columns ``cols[0]:cols[1]``:
    only the blocks reaching into them are worked out (a submap's padding is most of its
    grid)."""
    n_rows, n_cols = grid.shape
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

    ``exclude`` (a pose or several, a distance and a turn) leaves out the poses that near
    any of them: the best pose elsewhere, to tell a clear peak from one of several alike.
    """
    found = first_match(grid, points, np.reshape(center, (1, 3)), window_xy, window_theta,
                        min_score, exclude)
    return None if found is None else found[1]


def first_match(grid: SearchGrid, points: FloatArray, centers: FloatArray, window_xy: float,
                window_theta: float, min_score: float = 0.0,
                exclude: tuple[FloatArray, float, float] | None = None
                ) -> tuple[int, Match] | None:
    """The first of ``centers`` ``(K, 3)``, in their order, whose window (as :func:`search`
    has it) holds a pose scoring ``min_score``, and the best pose there; None when none does.
    The answer of :func:`search` called on each in turn until one answers, in one compiled
    loop: a search along a saved path is a few hundred small ones, and called one by one
    their setting up would cost more than their searching."""
    pts = np.asarray(points, dtype=np.float64)
    centers = np.ascontiguousarray(np.reshape(centers, (-1, 3)), dtype=np.float64)
    res, depth = grid.resolution, grid.depth
    turns = _angles(pts, res, window_theta)
    steps = min(math.ceil(window_xy / res - 1e-9), grid.max_steps)
    ex_pose, ex_xy, ex_theta = (np.zeros(3), -1.0, -1.0) if exclude is None else exclude
    ex_pose = np.ascontiguousarray(np.reshape(ex_pose, (-1, 3)), dtype=np.float64)
    reach = float(np.hypot(pts[:, 0], pts[:, 1]).max()) / res if len(pts) else 0.0
    k, score, r, x, y, evaluated = _first_found(
        grid.stack.reshape(depth + 1, -1), np.ascontiguousarray(pts), centers, turns,
        float(grid.origin[0]), float(grid.origin[1]), res, *grid.bounds, grid.shape[1],
        255.0 * len(pts), steps, depth, min_score, ex_pose, float(ex_xy), float(ex_theta),
        reach)
    if k < 0:
        return None
    center = centers[k]
    theta = (center[2] + turns)[r]
    pose = np.array([center[0] + x * res, center[1] + y * res,
                     (theta + math.pi) % (2 * math.pi) - math.pi])
    return int(k), Match(pose, float(score), int(evaluated))


@kernel
def _first_found(levels, pts, centers, turns, ox, oy, res, lo, hi_x, hi_y, stride, scale,
                 steps, depth, min_score, ex_pose, ex_xy, ex_theta, reach
                 ):  # pragma: no cover - compiled
    """The search about each of ``centers`` in turn until one finds a pose: (its index,
    score, rotation, x and y offset in cells, candidates scored in all), index -1 when none
    does. ``levels`` (depth + 1, cells) are the grid's levels flattened, ``turns`` the
    rotations searched about a centre's heading, ``reach`` the farthest point's range in
    cells."""
    evaluated = 0
    n_rot = turns.shape[0]
    group_level, top_level, corners = _start(steps, depth)
    # Each rotation's points, placed at the window's centre: flat cell indices (R, M). Only
    # the groups' middle rotations at first: where no group can score ``min_score`` (most
    # windows of a search along the saved path), the others are never needed.
    flat = np.empty((n_rot, pts.shape[0]), dtype=np.int64)
    placed = np.zeros(n_rot, dtype=np.bool_)
    for k in range(centers.shape[0]):
        thetas = centers[k, 2] + turns
        # Grouped per centre: the turn between rotations is taken from this centre's
        # headings, as :func:`search` takes it (rounded so, a group may differ by one).
        group, middle, h = _groups(thetas, reach, steps, group_level, lo, 1 << top_level)
        placed[:] = False
        for g in range(middle.shape[0]):
            placed[middle[g]] = True
        _place(pts, centers[k, 0], centers[k, 1], thetas, ox, oy, res, lo, hi_x, hi_y, stride,
               flat, placed)
        alive, bounded = _groups_alive(levels, flat, scale, group_level, min_score, stride,
                                       corners, middle, h)
        evaluated += bounded
        if not alive.any():
            continue
        # The other rotations of the groups that may score it; the rest are never scored.
        for r in range(n_rot):
            placed[r] = not placed[r] and alive[group[r]].any()
        _place(pts, centers[k, 0], centers[k, 1], thetas, ox, oy, res, lo, hi_x, hi_y, stride,
               flat, placed)
        score, r, x, y, n = _branch_and_bound(levels, flat, scale, steps, depth, min_score,
                                              stride, centers[k], thetas, res, ex_pose,
                                              ex_xy, ex_theta, top_level, corners, alive,
                                              group)
        evaluated += n
        if r >= 0:
            return k, score, r, x, y, evaluated
    return -1, 0.0, -1, 0, 0, evaluated


@kernel
def _place(pts, x, y, thetas, ox, oy, res, lo, hi_x, hi_y, stride, out, rows
           ):  # pragma: no cover - compiled
    """Into ``out`` (R, M), for each rotation ``r`` flagged in ``rows``: the flat cell indices
    of ``pts`` placed at (x, y) and turned by ``thetas[r]``, clamped to
    :attr:`SearchGrid.bounds`. (Only the rotations flagged are turned: most windows of a
    search along the saved path need a few of their 43.)"""
    for r in range(thetas.shape[0]):
        if not rows[r]:
            continue
        c, s = math.cos(thetas[r]), math.sin(thetas[r])
        for k in range(pts.shape[0]):
            out[r, k] = (_cell(x + c * pts[k, 0] - s * pts[k, 1], ox, res, lo, hi_x) * stride
                         + _cell(y + s * pts[k, 0] + c * pts[k, 1], oy, res, lo, hi_y))


@kernel
def _scores(levels, level, flat, rot, ox, oy, n, scale, stride, center, thetas, res, ex_pose,
            ex_xy, ex_theta):  # pragma: no cover - compiled
    """The scores of the first ``n`` candidates (rotation, cell offset) on ``level``; on level
    0, -1 for those within ``ex_xy`` and ``ex_theta`` of a row of ``ex_pose`` (none when
    negative): bounds above stay bounds."""
    off = np.empty(n, dtype=np.int64)
    for k in range(n):
        off[k] = ox[k] * stride + oy[k]
    out = block_sums(levels[level], flat, rot[:n], off) / scale
    if level == 0 and ex_xy >= 0.0:
        for k in range(n):
            near = False
            for e in range(ex_pose.shape[0]):  # the places already known: a few at most
                near = near or (
                    math.hypot(center[0] + ox[k] * res - ex_pose[e, 0],
                               center[1] + oy[k] * res - ex_pose[e, 1]) < ex_xy
                    and abs((thetas[rot[k]] - ex_pose[e, 2] + math.pi) % (2 * math.pi)
                            - math.pi) < ex_theta)
            if near:
                out[k] = -1.0
    return out


@kernel
def _branch_and_bound(levels, flat, scale, steps, depth, min_score, stride, center, thetas,
                      res, ex_pose, ex_xy, ex_theta, top_level, corners, alive,
                      group):  # pragma: no cover - compiled
    """The search level by level: (score, rotation, x and y offset in cells, candidates
    scored), rotation -1 when nothing scores ``min_score``. ``levels`` (depth + 1, cells) are
    the grid's levels flattened, ``flat`` (rotations, points) the points' cells at the
    window's centre, clamped no lower than the grid's bounds. The search starts on
    ``top_level``, at the ``corners`` (x, y; both from :func:`_start`) whose
    rotations' group (``group``, :func:`_groups`) ``alive`` says may score ``min_score``
    (:func:`_groups_alive`). Every level keeps the candidates that may still beat the best
    exact score, dives greedily from the best of them to set that score, and scores their
    children (the first of equal scores wins throughout)."""
    nc = corners.shape[0]
    evaluated = 0
    n = 0
    for r in range(thetas.shape[0]):
        for c in range(nc):
            n += alive[group[r], c]
    rot = np.empty(n, dtype=np.int64)
    ox = np.empty(n, dtype=np.int64)
    oy = np.empty(n, dtype=np.int64)
    k = 0
    for r in range(thetas.shape[0]):
        for c in range(nc):
            if alive[group[r], c]:
                rot[k], ox[k], oy[k] = r, corners[c, 0], corners[c, 1]
                k += 1
    values = _scores(levels, top_level, flat, rot, ox, oy, n, scale, stride, center, thetas,
                     res, ex_pose, ex_xy, ex_theta)
    evaluated += n
    best, br, bx, by = min_score, -1, 0, 0
    for level in range(top_level, 0, -1):
        m = 0
        for k in range(n):  # the candidates whose bound may still beat the best
            if values[k] >= best:
                rot[m], ox[m], oy[m], values[m] = rot[k], ox[k], oy[k], values[k]
                m += 1
        if m == 0:
            break
        n = m
        best, br, bx, by = _dive(levels, level, flat, rot, ox, oy, values, n, steps, scale,
                                 stride, center, thetas, res, ex_pose, ex_xy, ex_theta,
                                 best, br, bx, by)
        half = 1 << (level - 1)
        c_rot = np.empty(4 * n, dtype=np.int64)
        c_ox = np.empty(4 * n, dtype=np.int64)
        c_oy = np.empty(4 * n, dtype=np.int64)
        m = 0
        for k in range(n):
            for dx, dy in ((0, 0), (half, 0), (0, half), (half, half)):
                if ox[k] + dx <= steps and oy[k] + dy <= steps:
                    c_rot[m], c_ox[m], c_oy[m] = rot[k], ox[k] + dx, oy[k] + dy
                    m += 1
        rot, ox, oy, n = c_rot, c_ox, c_oy, m
        values = _scores(levels, level - 1, flat, rot, ox, oy, n, scale, stride, center,
                         thetas, res, ex_pose, ex_xy, ex_theta)
        evaluated += n
        if level == 1 and n > 0:  # exact scores: the leaves
            i = np.argmax(values)
            if values[i] >= best:
                best, br, bx, by = values[i], rot[i], ox[i], oy[i]
    return best, br, bx, by, evaluated


@kernel
def _covering_level(steps, depth):  # pragma: no cover - compiled
    """The first level whose blocks cover a window of ``steps`` cells either way (the levels
    above it bound nothing tighter); the stack's top, ``depth``, where none does."""
    level = 0
    while level < depth and (1 << level) < 2 * steps + 1:
        level += 1
    return level


@kernel
def _start(steps, depth):  # pragma: no cover - compiled
    """Where a window of ``steps`` cells either way is searched from: the level rotations
    are grouped on (:func:`_groups_alive`), the level the search starts on and its
    corners, the offsets (x, y; cells) of its blocks over the window, in the order the
    search visits them.

    Where one block of a level covers the window (:func:`_covering_level`), the search starts a
    level lower, on that block's four quarters in the order the level's children are
    visited (the same answers, ties included), and rotations are grouped on the covering
    level: each of its blocks bounds a group over a quarter of the window, tighter than a
    block of the stack's top level over the whole window (where the window fills that
    block, there is no room to group rotations on it at all). (The localizer's search along
    the saved path, 13 cells a side: of the 4,420 windows searched while ACES's second half
    is tracked, 2,600 have groups that all fall short against 1,817 grouped on the top
    level, 342,375 candidates are scored against 437,025, and the searches take 66 ms
    against 80.) A wider
    window is searched from the stack's top level, whose blocks tile it, with rotations
    grouped there too where its blocks are wider than the window."""
    covering = _covering_level(steps, depth)
    if covering == 0 or (1 << covering) < 2 * steps + 1:
        tiles = np.arange(-steps, steps + 1, 1 << covering)
        corners = np.empty((tiles.shape[0] * tiles.shape[0], 2), dtype=np.int64)
        for a in range(tiles.shape[0]):
            for b in range(tiles.shape[0]):
                corners[a * tiles.shape[0] + b, 0] = tiles[a]
                corners[a * tiles.shape[0] + b, 1] = tiles[b]
        return depth, covering, corners
    side = 1 << (covering - 1)  # of a quarter
    corners = np.empty((4, 2), dtype=np.int64)
    for c, (dx, dy) in enumerate(((0, 0), (side, 0), (0, side), (side, side))):
        corners[c, 0] = -steps + dx
        corners[c, 1] = -steps + dy
    return covering, covering - 1, corners


@kernel
def _groups(thetas, reach, steps, group_level, lo, top):  # pragma: no cover - compiled
    """Groups of neighbouring rotations of ``thetas`` bounded together on ``group_level``
    (:func:`_groups_alive`): each rotation's group, each group's middle rotation, and ``h``,
    the most cells a point of the group's rotations lies from where the middle one places
    it (``reach`` times the turn between them, plus one for the rounding); 0 where the
    level's block of ``2^group_level`` cells set ``h`` cells back cannot hold the block of
    ``top`` cells under a corner and ``2 h`` more, and each rotation is a group of its own."""
    n_rot = thetas.shape[0]
    span = min(top, 2 * steps + 1)  # cells of the window under one corner's block, at most
    room = min(((1 << group_level) - span) // 2, lo - steps)  # the widest h that fits
    half = 0  # rotations each side of a group's middle
    turn = 0.0
    if n_rot > 1 and room >= 1:
        turn = abs(thetas[1] - thetas[0])
        while half + 1 < n_rot and _shift(reach * (half + 1) * turn) <= room:
            half += 1
    size = 2 * half + 1
    n_groups = (n_rot + size - 1) // size
    group = np.empty(n_rot, dtype=np.int64)
    for r in range(n_rot):
        group[r] = r // size
    middle = np.empty(n_groups, dtype=np.int64)
    for g in range(n_groups):
        middle[g] = min(g * size + half, n_rot - 1)
    return group, middle, (_shift(reach * half * turn) if half > 0 else 0)


@kernel
def _groups_alive(levels, flat, scale, group_level, min_score, stride, corners, middle,
                  h):  # pragma: no cover - compiled
    """Which groups of rotations (:func:`_groups`; ``flat`` holds their middle rotations'
    cells) may score ``min_score`` at each corner's block: (alive[group, corner], bounds
    scored). The block of ``group_level`` set ``h`` cells back bounds every pose of the
    group in a corner's block; all alive, nothing scored, where ``h`` is 0. (In the
    localizer's search along the saved path, a window of 13 cells a side, the 43 rotations
    fall into 3 groups under the stack's top blocks of 32 cells; in ACES's second half
    1,980 of the 4,690 windows searched end there, and its path searches take 119 ms
    against 184 ungrouped. Under blocks of 16 over its quarters, 7 groups:
    :func:`_start`.)"""
    nc = corners.shape[0]
    alive = np.ones((middle.shape[0], nc), dtype=np.int64)
    if h == 0:
        return alive, 0
    level = levels[group_level]
    evaluated = 0
    for g in range(middle.shape[0]):
        row = flat[middle[g]]
        for c in range(nc):
            off = (corners[c, 0] - h) * stride + corners[c, 1] - h
            total = 0
            for i in range(row.shape[0]):
                total += level[row[i] + off]
            evaluated += 1
            if total / scale < min_score:
                alive[g, c] = 0
    return alive, evaluated


@kernel
def _shift(moved):  # pragma: no cover - compiled
    """The most cells a point's rounded cell moves when the point moves ``moved`` cells (a
    hair more, for the rounding of the turn itself)."""
    return math.floor(moved * (1.0 + 1e-9) + 1e-9) + 1


@kernel
def _dive(levels, level, flat, rot, ox, oy, values, n, steps, scale, stride, center, thetas,
          res, ex_pose, ex_xy, ex_theta, best, br, bx, by):  # pragma: no cover - compiled
    """Follow the best candidate's best child down to level 0; a better exact score found
    on the way raises the bound that prunes the others: the best (score, r, x, y)."""
    i = np.argmax(values[:n])
    r, x, y = rot[i], ox[i], oy[i]
    c_rot = np.full(4, r, dtype=np.int64)
    c_ox = np.empty(4, dtype=np.int64)
    c_oy = np.empty(4, dtype=np.int64)
    for lv in range(level, 0, -1):
        half = 1 << (lv - 1)
        m = 0
        for dx, dy in ((0, 0), (half, 0), (0, half), (half, half)):
            if x + dx <= steps and y + dy <= steps:
                c_ox[m], c_oy[m] = x + dx, y + dy
                m += 1
        s = _scores(levels, lv - 1, flat, c_rot, c_ox, c_oy, m, scale, stride, center, thetas,
                    res, ex_pose, ex_xy, ex_theta)
        j = np.argmax(s)
        x, y = c_ox[j], c_oy[j]
        if lv == 1 and s[j] >= best:
            return s[j], r, x, y
    return best, br, bx, by


@kernel
def block_sums(level, flat, rot, offset):  # pragma: no cover - compiled
    """For each candidate ``k``: the sum of ``level`` (a flattened grid of bytes) over the
    cells ``flat[rot[k]] + offset[k]`` (rotation ``rot[k]``'s points moved by ``offset[k]``
    cells). In NumPy the gather would make a (candidates, points) array of a few hundred
    thousand entries per level before summing it."""
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
