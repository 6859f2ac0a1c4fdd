"""A saved map as places to localize in: its milestones and, around each, a submap to match.

Localization reads a saved map and never changes it. Around every milestone the scans of its
segment and its neighbours' (:mod:`vmp.submaps`) form a submap in the milestone's frame; it is
built when first asked for and kept (least recently used dropped) as a registration reference
for tracking and as a branch-and-bound search grid for the global search.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from milestones.manager import MilestoneManager
from vmp.branch_bound import SearchGrid
from vmp.registration import Reference
from vmp.submaps import Submaps
from vmp.types import FloatArray
from vmp.vector_map import VectorMap

__all__ = ["Place", "Places"]

NEIGHBOURS = 3  # a submap takes in the segments of this many milestones either way
GRID_RADIUS = 20.0  # submap points farther than this from the milestone are left out (m)
RESOLUTION = 0.1  # search grid cell (m)
SIGMA = 0.1  # likelihood fall-off of the search grid (m)
DEPTH = 5  # levels of block maxima
MAX_WINDOW = 3.0  # the widest search window either way (m)
CACHED = 64  # submaps kept
TURN_COST = 1.0  # choosing the nearest milestone, a radian of heading counts as this (m)


class Place:
    """One milestone's submap: its points, a registration reference and a search grid."""

    def __init__(self, milestone: int, pose: FloatArray, points: FloatArray) -> None:
        self.milestone = milestone
        self.pose = pose  # the milestone in the map frame
        self.points = points  # the submap in the milestone's frame
        self.reference = Reference(points)
        self._grid: SearchGrid | None = None

    @property
    def grid(self) -> SearchGrid:
        """The branch-and-bound search grid (built on first use)."""
        if self._grid is None:
            self._grid = SearchGrid(self.points, RESOLUTION, SIGMA, DEPTH, MAX_WINDOW)
        return self._grid


class Places:
    """The milestones of a saved map and the submaps around them."""

    def __init__(self, vmap: VectorMap, milestones: MilestoneManager) -> None:
        self.map = vmap
        self.milestones = milestones
        ids = milestones.ids
        self._poses_by_id = np.zeros((int(ids.max()) + 1 if len(ids) else 0, 3))
        self._poses_by_id[ids] = milestones.poses
        self._submaps = Submaps(vmap)
        self._cache: OrderedDict[int, Place | None] = OrderedDict()

    def __len__(self) -> int:
        return len(self.milestones)

    def place(self, milestone: int) -> Place | None:
        """The submap around ``milestone``; None when it holds too few points."""
        if milestone in self._cache:
            self._cache.move_to_end(milestone)
            return self._cache[milestone]
        held = self._submaps.neighbourhood(milestone, NEIGHBOURS, self._poses_by_id)
        place = None
        if held is not None:
            pts = held[1]
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= GRID_RADIUS]
            if len(pts) >= 20:
                place = Place(milestone, self._poses_by_id[milestone].copy(), pts)
        self._cache[milestone] = place
        if len(self._cache) > CACHED:
            self._cache.popitem(last=False)
        return place

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
