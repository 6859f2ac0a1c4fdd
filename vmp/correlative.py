"""Correlative scan matching: an exhaustive search of a pose window on a likelihood grid.

ICP converges only from a guess near the answer. When the robot comes back to a place after a
long way round, its predicted pose may be metres and tens of degrees off, and ICP from the
prediction fails. A signature match still says which place it is and roughly how the robot is
turned, so the answer lies in a small window around the milestone's node. This module searches
that window exhaustively (after Olson, "Real-time correlative scan matching", ICRA 2009; the
same search closes loops in Cartographer):

* the reference scan (a milestone's stored scan, in its own frame) becomes a likelihood grid:
  ``exp(-d^2 / 2 sigma^2)`` of the distance ``d`` from each cell to the nearest reference point
  (:class:`LikelihoodGrid`, built once per reference);
* every pose of the window (rotations at ``step_theta``, translations at the grid resolution)
  scores the mean likelihood of the live points it places (:func:`correlative_search`, one
  vectorised gather per rotation);
* the answer is the best pose, and the search also reports the best score of any pose well
  separated from it (``runner_up``). A clear peak (``runner_up / score`` well below 1) means the
  place fixes the pose; a flat ridge (a corridor) or a second peak (a repeated structure) does
  not, and the caller should not trust the match.

The search is coarse by design (a cell of 0.1 m, steps of 2 degrees): a point-to-line ICP
refinement from its answer gives the final pose and fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt

from vmp.types import FloatArray

__all__ = ["CorrelativeConfig", "CorrelativeMatch", "LikelihoodGrid", "correlative_search",
           "likelihood_field"]


@dataclass(frozen=True)
class CorrelativeConfig:
    """The search window and its resolution; lengths in metres, angles in radians."""

    resolution: float = 0.1  # grid cell, and the translation step of the search
    sigma: float = 0.1  # likelihood fall-off with the distance to the nearest reference point
    window_xy: float = 1.0  # translations searched, either way, in x and in y
    window_theta: float = math.radians(16.0)  # rotations searched, either way
    step_theta: float = math.radians(2.0)
    separation_xy: float = 0.3  # a runner-up is at least this far from the peak ...
    separation_theta: float = math.radians(6.0)  # ... or turned at least this much from it
    max_points: int = 120  # live points scored (evenly thinned beyond this)

    def __post_init__(self) -> None:
        if not (self.resolution > 0 and self.sigma > 0 and self.step_theta > 0):
            raise ValueError("resolution, sigma and step_theta must be positive")
        if self.window_xy < 0 or self.window_theta < 0:
            raise ValueError("the search window must not be negative")
        if self.max_points < 3:
            raise ValueError(f"max_points must be at least 3, got {self.max_points}")


@dataclass(frozen=True)
class CorrelativeMatch:
    """The best pose of a window search, its score and the best well-separated rival's."""

    pose: FloatArray  # (3,) live scanner pose in the reference frame
    score: float  # mean likelihood of the live points at that pose, in [0, 1]
    runner_up: float  # best score at least a separation away from the peak (0: none)
    poses_searched: int

    @property
    def ratio(self) -> float:
        """``runner_up / score``: near 1 for an ambiguous window, small for a clear peak."""
        return self.runner_up / self.score if self.score > 0 else math.inf


def likelihood_field(points: FloatArray, resolution: float, sigma: float,
                     pad: int) -> tuple[FloatArray, FloatArray]:
    """The likelihood ``exp(-d^2 / 2 sigma^2)`` of the distance ``d`` to the nearest of the
    finite ``points`` ``(N, 2)``, per cell: the world position of cell (0, 0)'s centre and the
    field, covering the points plus a few ``sigma`` and ``pad`` cells of zeros on every side."""
    margin = math.ceil(3.0 * sigma / resolution) + 1
    lo = points.min(axis=0) - (margin + pad) * resolution
    hi = points.max(axis=0) + (margin + pad) * resolution
    shape = np.ceil((hi - lo) / resolution).astype(np.int64) + 1
    cells = np.rint((points - lo) / resolution).astype(np.int64)
    free = np.ones(tuple(shape), dtype=bool)
    free[cells[:, 0], cells[:, 1]] = False
    field = np.exp(-0.5 * (distance_transform_edt(free) * resolution / sigma) ** 2)
    if pad:  # cells within ``pad`` of the border stay zero
        field[:pad], field[-pad:] = 0.0, 0.0
        field[:, :pad], field[:, -pad:] = 0.0, 0.0
    return lo, field


class LikelihoodGrid:
    """The likelihood of a point falling at each cell, given reference points ``(N, 2)``.

    The grid covers the reference points plus a margin of a few ``sigma`` (beyond it the
    likelihood is zero), and is padded with ``pad`` cells of zeros on every side so a search
    never indexes outside it.
    """

    def __init__(self, points: FloatArray, resolution: float = 0.1, sigma: float = 0.1,
                 pad: int = 0) -> None:
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
            raise ValueError(f"a likelihood grid needs points (N, 2), got {pts.shape}")
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts) == 0:
            raise ValueError("a likelihood grid needs at least one finite point")
        self.resolution = float(resolution)
        self.sigma = float(sigma)
        self.pad = int(pad)
        # origin: the world position of cell (0, 0)'s centre
        self.origin, field = likelihood_field(pts, self.resolution, self.sigma, self.pad)
        self.grid = field.astype(np.float32)

    @property
    def shape(self) -> tuple[int, int]:
        return self.grid.shape  # type: ignore[return-value]

    def score(self, points: FloatArray, pose: FloatArray) -> float:
        """Mean likelihood of ``points`` (scanner frame) placed at ``pose``."""
        pts = np.asarray(points, dtype=np.float64)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        q = np.stack([pose[0] + c * pts[:, 0] - s * pts[:, 1],
                      pose[1] + s * pts[:, 0] + c * pts[:, 1]], axis=-1)
        cells = np.rint((q - self.origin) / self.resolution).astype(np.int64)
        inside = ((cells >= 0) & (cells < np.array(self.shape))).all(axis=1)
        vals = np.zeros(len(pts), dtype=np.float64)
        vals[inside] = self.grid[cells[inside, 0], cells[inside, 1]]
        return float(vals.mean()) if len(vals) else 0.0


def _steps(c: CorrelativeConfig, res: float) -> int:
    """Translation steps of the window either way (cells)."""
    return math.ceil(c.window_xy / res - 1e-9)


def _padding(c: CorrelativeConfig, res: float) -> int:
    return 2 * _steps(c, res) + 1


def grid_for(points: FloatArray, config: CorrelativeConfig) -> LikelihoodGrid:
    """The likelihood grid of reference points, padded for searches with ``config``."""
    return LikelihoodGrid(points, config.resolution, config.sigma,
                          pad=_padding(config, config.resolution))


def _window_scores(grid: FloatArray, origin: FloatArray, res: float, qx: FloatArray,
                   qy: FloatArray, steps: int) -> FloatArray:
    """Mean grid value of the points ``(qx, qy)`` ``(R, M)`` under every offset
    ``(i, j)`` cells, ``|i|, |j| <= steps``: ``(R, T, T)``, ``T = 2 steps + 1``."""
    reach = steps
    cx = np.rint((qx - origin[0]) / res).astype(np.int64)
    cy = np.rint((qy - origin[1]) / res).astype(np.int64)
    # Points whose cell lies in the outer half of the padding score zero at every offset (the
    # likelihood starts ``pad`` cells in); they are left out.
    nx, ny = grid.shape
    ok = (cx >= reach) & (cx < nx - reach) & (cy >= reach) & (cy < ny - reach)
    # Window views of the grid: view[i, j] is the (T, T) block from cell (i, j) on.
    size = 2 * reach + 1
    windows = np.lib.stride_tricks.sliding_window_view(grid, (size, size))
    T = 2 * steps + 1
    scores = np.empty((qx.shape[0], T, T), dtype=np.float64)
    for r in range(qx.shape[0]):
        keep = ok[r]
        scores[r] = windows[cx[r, keep] - reach, cy[r, keep] - reach].sum(axis=0,
                                                                          dtype=np.float64)
    return scores / qx.shape[1]


def correlative_search(grid: LikelihoodGrid, points: FloatArray, center: FloatArray,
                       config: CorrelativeConfig | None = None) -> CorrelativeMatch:
    """Search the window around ``center`` (x, y, theta) for the pose of ``points``.

    ``grid`` must be padded for the search (see :func:`grid_for`). Every rotation
    ``center[2] + k * step_theta`` within ``window_theta`` and every translation
    ``center[:2] + (i, j) * resolution`` within ``window_xy`` is scored.
    """
    c = config or CorrelativeConfig()
    pts = np.asarray(points, dtype=np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        return CorrelativeMatch(np.asarray(center, dtype=np.float64).copy(), 0.0, 0.0, 0)
    if len(pts) > c.max_points:
        pts = pts[np.linspace(0, len(pts) - 1, c.max_points).round().astype(np.int64)]
    res = grid.resolution
    steps = _steps(c, res)
    need = _padding(c, res)
    if grid.pad < need:
        raise ValueError(f"the grid is padded by {grid.pad} cells, the search needs {need}")
    n_rot = math.floor(c.window_theta / c.step_theta + 1e-9)
    thetas = center[2] + c.step_theta * np.arange(-n_rot, n_rot + 1)
    offsets = np.arange(-steps, steps + 1)
    # Live points rotated by every searched angle, placed at the window's centre: (R, M).
    cos, sin = np.cos(thetas)[:, None], np.sin(thetas)[:, None]
    qx = center[0] + cos * pts[:, 0] - sin * pts[:, 1]
    qy = center[1] + sin * pts[:, 0] + cos * pts[:, 1]
    scores = _window_scores(grid.grid, grid.origin, res, qx, qy, steps)
    searched = scores.size
    best = np.unravel_index(int(np.argmax(scores)), scores.shape)
    score = float(scores[best])
    bx, by = offsets[best[1]] * res, offsets[best[2]] * res  # the peak's offset
    # The runner-up: the best pose at least a separation away from the peak.
    dth = np.abs(thetas - thetas[best[0]])
    dxy = np.hypot(*np.meshgrid(offsets * res - bx, offsets * res - by, indexing="ij"))
    near = (dth[:, None, None] < c.separation_theta) & (dxy[None] < c.separation_xy)
    runner_up = float(max(np.where(near, -np.inf, scores).max(), 0.0))
    pose = np.array([center[0] + bx, center[1] + by,
                     (thetas[best[0]] + math.pi) % (2 * math.pi) - math.pi])
    return CorrelativeMatch(pose, score, runner_up, int(searched))
