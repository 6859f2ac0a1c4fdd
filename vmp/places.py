"""A saved map as places to localize in: its milestones and, around each, a submap to match.

Localization reads a saved map and never changes it, so its frame is settled: every hit point
of the assembled map is placed once (voxel-thinned), and around each milestone the points
within :data:`GRID_RADIUS` form its submap, in the milestone's frame, whichever part of the
path saw them (the mapper's submaps, :mod:`vmp.submaps`, take only the milestone's segments
and its neighbours', as the map may still move; a place seen again from elsewhere along the
path would then look half empty). A submap is built when first asked for and kept (least
recently used dropped) as a registration reference for tracking and as a branch-and-bound
search grid for the global search.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import replace

import numpy as np

from milestones.manager import MilestoneManager
from vmp.branch_bound import SearchGrid, likelihood_grid, mean_likelihood
from vmp.config import RegistrationConfig
from vmp.registration import Reference, Registration, explained, fits, last_gate
from vmp.submaps import voxel_thin
from vmp.types import FloatArray, inverse, transform_points
from vmp.vector_map import VectorMap

__all__ = ["Place", "Places", "samples_along"]

GRID_RADIUS = 20.0  # submap points farther than this from the milestone are left out (m)
RESOLUTION = 0.1  # search grid cell (m)
SIGMA = 0.1  # likelihood fall-off of the search grid (m)
DEPTH = 5  # levels of block maxima
VOXEL = 0.05  # one map point kept per cell of this size (m); 0.1 did worse on Intel
MAX_WINDOW = 6.0  # the widest search window either way (m): the localizer's alias check
CACHED = 32  # submaps kept (a search grid of one is a few MB) ...
# ... and what tracking built of more (:attr:`Place.tracking`; a registration reference of
# 13,000 points is about 0.6 MB). Kept apart: the searches while the robot is lost or doubted
# look at dozens of submaps and pushed those tracked out of the cache, and rebuilding their
# references was 30 % of tracking fr079's second half (docs/benchmarks.md).
TRACKING_CACHED = 128

# A submap's registration reference and its likelihood field (origin, grid), once built.
Tracking = tuple[Reference | None, tuple[FloatArray, np.ndarray] | None]
PATH_STEP = 1.0  # the saved path is sampled every this far (m) for look-alikes of a place
TURN_COST = 1.0  # choosing the nearest milestone, a radian of heading counts as this (m)


class Place:
    """One milestone's submap: its points, a registration reference and a search grid."""

    def __init__(self, milestone: int, pose: FloatArray, points: FloatArray,
                 tracking: Tracking = (None, None)) -> None:
        """``tracking``: what :attr:`tracking` returned for these points, when built before."""
        self.milestone = milestone
        self.pose = pose  # the milestone in the map frame
        self.points = points  # the submap in the milestone's frame
        self._reference, self._field = tracking
        self._grid: SearchGrid | None = None

    def score(self, points: FloatArray, pose: FloatArray) -> float:
        """Mean likelihood of ``points`` (their frame) placed at ``pose`` in the submap: the
        branch-and-bound search's score, from a field of its own (the search's levels are
        built only for a search)."""
        if self._grid is not None:
            return self._grid.score(points, pose)
        if self._field is None:
            self._field = likelihood_grid(self.points, RESOLUTION, SIGMA, 1)
        origin, field = self._field
        # Clamped to the border cells, zeros.
        return mean_likelihood(field, origin, RESOLUTION, points, pose, (0, 0),
                               (field.shape[0] - 1, field.shape[1] - 1))

    def fits(self, reg: Registration, points: FloatArray, config: RegistrationConfig) -> bool:
        """Whether a registration of ``points`` against this submap fits: closely, and with
        most of the points near a map point, on a clear line or not. (ICP matches only the
        points whose partner lies on a clear line, and a map assembled from many scans has
        thick walls: in the Intel part's half map a quarter of the points lie on one, and
        scans placed to a centimetre found partners for a fifth of their points, so that
        tracking never corrected the pose.)"""
        if not np.isfinite(reg.rms):
            return False
        share = explained(self.reference, points, reg.pose, last_gate(reg.rms))
        return fits(replace(reg, inliers=share), config)

    @property
    def reference(self) -> Reference:
        """The registration reference (built on first use: most submaps a search looks at
        are rejected by the branch-and-bound search alone, and a reference of 13,000 points
        costs 17 ms, about what the search does)."""
        if self._reference is None:
            self._reference = Reference(self.points)
        return self._reference

    @property
    def tracking(self) -> Tracking:
        """What tracking against it has built so far: its registration reference and the
        field it is scored in without a search grid (None where not built)."""
        return self._reference, self._field

    @property
    def grid(self) -> SearchGrid:
        """The branch-and-bound search grid (built on first use)."""
        if self._grid is None:
            self._grid = SearchGrid(self.points, RESOLUTION, SIGMA, DEPTH, MAX_WINDOW)
        return self._grid


class Places:
    """The milestones of a saved map and the submaps around them."""

    def __init__(self, vmap: VectorMap, milestones: MilestoneManager,
                 trajectory: FloatArray) -> None:
        """``trajectory``: the map's assembled scan poses (as saved with it)."""
        self.map = vmap
        self.milestones = milestones
        self.points = voxel_thin(vmap.world_points(trajectory), VOXEL)
        self.path = samples_along(np.asarray(trajectory, dtype=np.float64), PATH_STEP)
        self._cache: OrderedDict[int, Place | None] = OrderedDict()
        self._tracking: OrderedDict[int, Tracking] = OrderedDict()
        self._grid: SearchGrid | None = None

    def __len__(self) -> int:
        return len(self.milestones)

    def place(self, milestone: int) -> Place | None:
        """The submap around ``milestone``; None when it holds too few points."""
        if milestone in self._cache:
            self._cache.move_to_end(milestone)
            return self._cache[milestone]
        pose = self.milestones.pose(milestone).copy()
        near = np.hypot(self.points[:, 0] - pose[0], self.points[:, 1] - pose[1]) <= GRID_RADIUS
        place = None
        if near.sum() >= 20:
            place = Place(milestone, pose, transform_points(inverse(pose), self.points[near]),
                          self._tracking.pop(milestone, (None, None)))
        self._cache[milestone] = place
        if len(self._cache) > CACHED:
            _, dropped = self._cache.popitem(last=False)
            if dropped is not None and any(built is not None for built in dropped.tracking):
                self._tracking[dropped.milestone] = dropped.tracking
                if len(self._tracking) > TRACKING_CACHED:
                    self._tracking.popitem(last=False)
        return place

    @property
    def grid(self) -> SearchGrid:
        """One search grid of the whole map, in the map frame (built on first use): for
        look-alikes anywhere along the path, where no milestone may be (a corridor's
        look-alike stretches are refused as milestones when mapped)."""
        if self._grid is None:
            self._grid = SearchGrid(self.points, RESOLUTION, SIGMA, DEPTH, MAX_WINDOW)
        return self._grid

    def nearest(self, pose: FloatArray) -> Place | None:
        """The submap of the milestone nearest ``pose`` (a turn counts as
        :data:`TURN_COST` metres a radian) that holds enough points."""
        poses = self.milestones.poses
        if len(poses) == 0:
            return None
        turn = np.abs((poses[:, 2] - pose[2] + math.pi) % (2 * math.pi) - math.pi)
        cost = np.hypot(poses[:, 0] - pose[0], poses[:, 1] - pose[1]) + TURN_COST * turn
        for row in np.argsort(cost)[:4]:  # the nearest, or one of the next when it is empty
            place = self.place(int(self.milestones.ids[row]))
            if place is not None:
                return place
        return None


def samples_along(trajectory: FloatArray, step: float) -> FloatArray:
    """Poses of ``trajectory`` about ``step`` apart along its path: the first, each first
    one ``step`` farther along than the one before, and the last."""
    if len(trajectory) == 0:
        return np.zeros((0, 3))
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(trajectory[:, :2],
                                                                    axis=0).T))])
    marks = np.searchsorted(travelled, np.arange(0.0, travelled[-1], step))
    return trajectory[np.unique(np.append(marks, len(trajectory) - 1))]
