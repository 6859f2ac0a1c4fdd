"""Submaps: the scans stored around a milestone, in its frame, as one point set.

The vector map keeps every scan in the frame of its segment's anchor milestone. A milestone's
submap is the hit points of the segments anchored at it and at its neighbours along the path
(a few either way), placed in its frame through the milestones' current poses, voxel-thinned.
The vector map stays the stored truth; a submap is a view of it, built on demand. The loop
search (:mod:`vmp.loops`) caches what it builds from one and rebuilds it when the segments in
it change.
"""

from __future__ import annotations

import numpy as np

from vmp.types import FloatArray, relative, transform_points
from vmp.vector_map import VectorMap

__all__ = ["Submaps", "voxel_thin"]

VOXEL = 0.05  # one point kept per cell of this size (m)


def voxel_thin(points: FloatArray, size: float) -> FloatArray:
    """One point per ``size`` cell (the first seen), in their order."""
    if len(points) == 0:
        return points
    cells = np.floor(points / size).astype(np.int64)
    keys = (cells[:, 0] << 32) + (cells[:, 1] & 0xFFFFFFFF)  # one int per cell
    _, first = np.unique(keys, return_index=True)
    return points[np.sort(first)]


class Submaps:
    """Point sets of the vector map around its milestones."""

    def __init__(self, vmap: VectorMap) -> None:
        self.map = vmap

    def segments_around(self, anchor: int, around: int) -> tuple[int, ...]:
        """The segments of milestones ``anchor - around .. anchor + around`` (what
        :meth:`neighbourhood` is made of: where they are unchanged, so is it, unless the
        graph has moved its milestones)."""
        vmap = self.map
        ids = range(max(anchor - around, 0), anchor + around + 1)
        return tuple(k for mid in ids for k in vmap.segments_of(mid))

    def neighbourhood(self, anchor: int, around: int, anchor_poses: FloatArray
                      ) -> tuple[tuple[int, ...], FloatArray] | None:
        """The segments of milestones ``anchor - around .. anchor + around`` and their hit
        points in ``anchor``'s frame, placed through the milestones' poses (``anchor_poses``,
        by id); None when none of them holds a segment."""
        vmap = self.map
        ids = range(max(anchor - around, 0), min(anchor + around, len(anchor_poses) - 1) + 1)
        parts = []
        for mid in ids:  # a handful of milestones, each a block of scans
            mine = vmap.segments_of(mid)
            if not mine:
                continue
            scans = np.concatenate([np.arange(r.start, r.stop)
                                    for r in map(vmap.segment_scans, mine)])
            pts = self._points(scans)
            if mid != anchor and len(pts):
                pts = transform_points(relative(anchor_poses[anchor], anchor_poses[mid]), pts)
            parts.append(pts)
        if not parts:
            return None
        return self.segments_around(anchor, around), voxel_thin(np.concatenate(parts), VOXEL)

    def _points(self, scans: np.ndarray) -> FloatArray:
        """Hit points of ``scans`` in their segments' anchor frame."""
        if len(scans) == 0:
            return np.zeros((0, 2))
        vmap = self.map
        pts = transform_points(vmap.rel_poses[scans],
                               vmap.end_points[scans].astype(np.float64))
        return pts[vmap.scan_hits(scans)]
