"""A saved map as places to localize in: its milestones and, around each, a submap to search.

Localization reads a saved map and never changes it, so its frame is settled: every hit point
of the assembled map is placed once (voxel-thinned). Scans are tracked against the whole map at
once, in its frame: registered against one reference of its points and scored by their
distances to them (:meth:`Places.score`), built on first use, and searched for look-alikes in
one branch-and-bound grid. (A reference and scoring grid for each milestone's submap, built
when first asked for, would cover the same points many times over: the submaps, 40 m across
and a few metres apart, overlap, and building the references of those the robot passes would
be 16 % of tracking the Intel part's second half and 17 % of fr079's.) Around each milestone
the points within :data:`GRID_RADIUS` form its submap, in the milestone's frame, whichever part
of the path saw them, with a branch-and-bound search grid for the global search (turned as the
milestone faces). The mapper's submaps (:mod:`vmp.submaps`) take only the milestone's segments
and its neighbours', as the map may still move; a place seen again from elsewhere along the
path would then look half empty.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from milestones.manager import MilestoneManager
from vmp.branch_bound import Match, SearchGrid, search
from vmp.config import RegistrationConfig
from vmp.registration import Reference, Registration, fits_explained, likelihood
from vmp.submaps import voxel_thin
from vmp.types import FloatArray, inverse, transform_points
from vmp.vector_map import VectorMap
from vmp.views import SavedViews

__all__ = ["Place", "Places", "fits_map", "samples_along"]

GRID_RADIUS = 20.0  # submap points farther than this from the milestone are left out (m)
RESOLUTION = 0.1  # search grid cell (m)
SIGMA = 0.1  # likelihood fall-off of the search grid (m)
DEPTH = 5  # levels of block maxima
VOXEL = 0.05  # one map point kept per cell of this size (m); 0.1 does worse on Intel
MAX_WINDOW = 6.0  # the widest search window either way (m): the localizer's alias check
CACHED = 32  # submaps kept (a search grid of one is a few MB)
PATH_STEP = 1.0  # the saved path is sampled every this far (m) for look-alikes of a place
TURN_COST = 1.0  # choosing the nearest milestone, a radian of heading counts as this (m)


class Place:
    """One milestone's submap: its points and a branch-and-bound search grid."""

    def __init__(self, milestone: int, pose: FloatArray, points: FloatArray) -> None:
        self.milestone = milestone
        self.pose = pose  # the milestone in the map frame
        self.points = points  # the submap in the milestone's frame
        self._grid: SearchGrid | None = None

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
        self._grid: SearchGrid | None = None
        self._reference: Reference | None = None
        self._trajectory = trajectory
        self._views: SavedViews | None = None

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
            place = Place(milestone, pose, transform_points(inverse(pose), self.points[near]))
        self._cache[milestone] = place
        if len(self._cache) > CACHED:
            self._cache.popitem(last=False)
        return place

    @property
    def grid(self) -> SearchGrid:
        """One search grid of the whole map, in the map frame (built on first use): scans are
        searched in it for look-alikes near a place and anywhere along the path, where no
        milestone may be (a corridor's look-alike stretches are refused as milestones when
        mapped)."""
        if self._grid is None:
            self._grid = SearchGrid(self.points, RESOLUTION, SIGMA, DEPTH, MAX_WINDOW)
        return self._grid

    @property
    def reference(self) -> Reference:
        """The registration reference of the whole map, in the map frame (built on first
        use)."""
        if self._reference is None:
            self._reference = Reference(self.points)
        return self._reference

    @property
    def views(self) -> SavedViews:
        """The map's stored scans as views of the places along its path (built on first
        use)."""
        if self._views is None:
            self._views = SavedViews(self.map, self._trajectory)
        return self._views

    def score(self, points: FloatArray, pose: FloatArray) -> float:
        """Mean likelihood of ``points`` (their frame) placed at ``pose`` (map frame): a point
        within :data:`VOXEL` of a map point (the map's walls are bands of such points) scores
        1, one farther falls off as the search grid's does with the distance beyond
        (:func:`vmp.registration.likelihood`). The branch-and-bound search's score without
        the rounding to its grid's cells (in a grid of 0.1 m cells, the simulated warehouse's
        right place scored 1.000 in the frame of one milestone and 0.88 in the map's: a wall
        3 cm from a cell border)."""
        return likelihood(self.reference, points, pose, SIGMA, VOXEL)

    def fits(self, reg: Registration, points: FloatArray, config: RegistrationConfig) -> bool:
        """Whether a registration of ``points`` against the map (:attr:`reference`) fits
        (:func:`fits_map`)."""
        return fits_map(self.reference, reg, points, config)

    def everywhere(self, points: FloatArray, min_score: float,
                   exclude: tuple[FloatArray, float, float] | None = None) -> Match | None:
        """The best pose of ``points`` (their frame, as :func:`vmp.branch_bound.search`
        takes them) anywhere in the map, facing any way, scoring ``min_score`` or more in
        its search grid; None when there is none. ``exclude`` leaves out poses as the
        search does. The map's box is searched in windows of :data:`MAX_WINDOW` either way,
        each pruned below the best found so far (about 0.15 s for ACES's first half, 80 m
        by 60)."""
        if len(points) == 0 or len(self.points) == 0:
            return None
        grid = self.grid
        best = None
        for center in self._tiles():
            found = search(grid, points, center, MAX_WINDOW, math.pi, min_score, exclude)
            if found is not None and (best is None or found.score > best.score):
                best, min_score = found, found.score
        return best

    def _tiles(self) -> FloatArray:
        """The centres of the windows :meth:`everywhere` searches: :data:`MAX_WINDOW` either
        way of each covers the map's box."""
        lo, hi = self.points.min(axis=0), self.points.max(axis=0)
        xs, ys = np.meshgrid(np.arange(lo[0] + MAX_WINDOW, hi[0] + MAX_WINDOW, 2 * MAX_WINDOW),
                             np.arange(lo[1] + MAX_WINDOW, hi[1] + MAX_WINDOW, 2 * MAX_WINDOW),
                             indexing="ij")
        return np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])

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


def fits_map(reference: Reference, reg: Registration, points: FloatArray,
             config: RegistrationConfig) -> bool:
    """Whether a registration of ``points`` against a map's ``reference`` fits: closely, and
    with most of the points near a map point, on a clear line or not. (ICP matches only the
    points whose partner lies on a clear line, and a map assembled from many scans has thick
    walls: in the Intel part's half map a quarter of the points lie on one, and scans placed
    to a centimetre found partners for a fifth of their points, so that tracking never
    corrected the pose.)"""
    return fits_explained(reference, reg, points, config)


def samples_along(trajectory: FloatArray, step: float) -> FloatArray:
    """Poses of ``trajectory`` about ``step`` apart along its path: the first, each first
    one ``step`` farther along than the one before, and the last."""
    if len(trajectory) == 0:
        return np.zeros((0, 3))
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(trajectory[:, :2],
                                                                    axis=0).T))])
    marks = np.searchsorted(travelled, np.arange(0.0, travelled[-1], step))
    return trajectory[np.unique(np.append(marks, len(trajectory) - 1))]
