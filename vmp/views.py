"""A saved map's scans as views: how many of a live scan's ranges a place explains.

The localizer scores a place by where the live scan's end points fall in the map
(:meth:`vmp.places.Places.score`). Between two rows of identical rack bays that score cannot
tell the bays apart: every end point lands on some rack. What tells them apart is where the
beams pass: a beam that stops short at one bay passes a rack's end at the next, one that
returns here has no return there. The saved map keeps every scan it was made of, ranges and
pose, so the view from a place the mapper passed is known beam by beam: the stored scans taken
near it, seen from the place (each beam's end point, or the far end of its reach where it had
no return, put into the bearing it falls in from there, the nearest end point winning). A live
beam agrees with such a view when both read within :data:`AGREE` of each other, or neither has a
return.

In the simulated warehouse, along aisles whose bays all score 1.000 by their end points, the
right place's stored views contradict 0-1.2 % of the live beams (mean over a run's first 80
scans) and the closest look-alike's 2.3-28 % in seven of nine runs whose start or kidnap the
world tells apart, 0.4 and 0.9 % in the other two.
A place the mapper never passed, or passed facing another way, has no view: nothing is known
of it, and nothing is concluded from it.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from vmp.jit import kernel
from vmp.types import FloatArray
from vmp.vector_map import VectorMap

__all__ = ["AGREE", "SavedViews"]

AGREE = 0.1  # a live beam agrees with a view when the two ranges are this close (m) ...
# ... or when it reads what a beam this many either side of it would in the view: a wall seen
# at a grazing angle from a few centimetres aside moves its ranges by decimetres (the simulated
# corridor, seed 110's kidnap, scan 112: the right place's nearest stored scan, 6 cm aside,
# contradicts 30 beams by 0.1-0.3 m; with one beam either side the best stored scan nearby, 1).
# In the warehouse's runs this halves the right places' shares or more, the look-alikes' it
# cuts by a fifth to two thirds.
SPREAD = 1
# Stored scans taken this near a place (m) and facing this close to it make its view ...
NEAR_XY = 0.5
NEAR_THETA = math.radians(30.0)
CANDIDATES = 8  # ... the nearest this many of them, the one the live scan agrees with best
# A view must know at least this share of the live beams to be one (a stored scan turned away
# sees little of what the live one sees).
MIN_KNOWN = 0.5


class SavedViews:
    """The stored scans of a saved map, rendered at places near its path."""

    def __init__(self, vmap: VectorMap, trajectory: FloatArray) -> None:
        """``trajectory``: the map's assembled scan poses (as saved with it)."""
        g = vmap.geometry
        self.geometry = g
        self._poses = np.asarray(trajectory, dtype=np.float64)
        hits = vmap.scan_hits(range(len(vmap)))
        angles = g.angles
        reach = np.column_stack([np.cos(angles), np.sin(angles)]) * g.max_range
        # Where a beam had no return, the far end of its reach stands for it: the bearing
        # it falls in from the place is free as far as that.
        self._points = np.where(hits[..., None], vmap.end_points, reach[None]).astype(np.float64)
        self._hits = hits
        self._tree = cKDTree(self._poses[:, :2]) if len(self._poses) else None

    def disagreements(self, ranges: FloatArray, poses: FloatArray) -> np.ndarray:
        """For each live scan (``ranges`` ``(N, B)``, ``inf`` without a return) and place
        (``poses`` ``(N, 3)``, map frame): the beams the view from the place contradicts, and
        those it knows, for the stored scan nearby that agrees best; (0, 0) where the map holds
        no view of the place. ``(N, 2)`` integers. (Many places a call, the places followed or
        one place's past scans: a view at a time, the small arrays' overhead would cost the
        search half its speed in the simulated warehouse.)"""
        ranges = np.asarray(ranges, dtype=np.float64).reshape(-1, self.geometry.num_beams)
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if len(ranges) != len(poses):
            raise ValueError(f"{len(ranges)} scans of {self.geometry.num_beams} beams for "
                             f"{len(poses)} places")
        query, rows = self._near(poses)
        g = self.geometry
        return _disagreements(self._points, self._hits, self._poses, rows, query, poses, ranges,
                              g.angle_min, g.angle_increment, g.full_circle, MIN_KNOWN)

    def _near(self, poses: FloatArray) -> tuple[np.ndarray, np.ndarray]:
        """Pairs of a place (index into ``poses``) and a stored scan taken near it and facing
        about as it faces: :data:`CANDIDATES` at most per place, grouped by place, nearest
        first."""
        none = np.zeros(0, dtype=np.int64)
        if self._tree is None:
            return none, none
        found = self._tree.query_ball_point(poses[:, :2], NEAR_XY)
        counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
        if counts.sum() == 0:
            return none, none
        query = np.repeat(np.arange(len(poses)), counts)
        rows = np.concatenate([np.asarray(f, dtype=np.int64) for f in found])
        return _nearest_facing(query, rows, self._poses, poses, NEAR_THETA, CANDIDATES)


@kernel
def _disagreements(points, hits, stored, rows, query, places, live, angle_min, increment,
                   full_circle, min_known):  # pragma: no cover - compiled
    """:meth:`SavedViews.disagreements` for the pairs of a place (``query``, into ``places``)
    and a stored scan (``rows``, into ``points``, ``hits`` and ``stored``), grouped by place,
    nearest first. Each stored scan is seen from the place: its beams' end points (or the far
    end of a beam with no return) put into the bearing they fall in from there, the nearest
    end point winning; a live beam agrees when it reads within :data:`AGREE` of the view's
    beam, or of one within :data:`SPREAD` beside it, or neither has a return. (In NumPy, a
    place's eight stored scans cost some thirty array operations of a few microseconds each:
    tracking a place watched by its views would run at half the speed in the simulated
    worlds.)"""
    beams = points.shape[1]
    out = np.zeros((places.shape[0], 2), dtype=np.int64)
    best = np.full(places.shape[0], -1.0)
    expected = np.empty(beams)
    known = np.empty(beams, dtype=np.bool_)
    turn = 1.0 if increment >= 0.0 else -1.0  # a scanner may sweep clockwise
    step = abs(increment)
    for m in range(rows.shape[0]):
        r, q = rows[m], query[m]
        if best[q] >= 1.0:  # every beam agrees: no later (farther) scan can agree better
            continue
        # The stored scanner seen from the place (vmp.types.relative).
        c0, s0 = math.cos(places[q, 2]), math.sin(places[q, 2])
        dx, dy = stored[r, 0] - places[q, 0], stored[r, 1] - places[q, 1]
        ax, ay = c0 * dx + s0 * dy, -s0 * dx + c0 * dy
        turned = stored[r, 2] - places[q, 2]
        c, s = math.cos(turned), math.sin(turned)
        expected[:] = np.inf
        known[:] = False
        for j in range(beams):
            px, py = points[r, j, 0], points[r, j, 1]
            x = ax + c * px - s * py
            y = ay + s * px + c * py
            offset = (turn * (math.atan2(y, x) - angle_min)) % (2.0 * math.pi)
            beam = int(np.rint(offset / step))
            if full_circle:
                beam %= beams
            if beam >= beams:
                continue
            known[beam] = True  # a return, or free to the scanner's reach
            if hits[r, j]:
                expected[beam] = min(expected[beam], math.sqrt(x * x + y * y))
        n_known = 0
        n_agree = 0
        for j in range(beams):
            if not known[j]:
                continue
            n_known += 1
            here = live[q, j]
            for d in range(-SPREAD, SPREAD + 1):
                k = j + d
                if k < 0 or k >= beams:
                    if not full_circle:
                        continue  # past the ends of the sweep: nothing known
                    k %= beams
                near = expected[k]
                if abs(near - here) <= AGREE or (math.isinf(near) and math.isinf(here)
                                                 and known[k]):
                    n_agree += 1
                    break
        if n_known >= min_known * beams:
            share = n_agree / n_known
            if share > best[q]:  # the first of equals: the nearest
                best[q] = share
                out[q, 0] = n_known - n_agree
                out[q, 1] = n_known
    return out


@kernel
def _nearest_facing(query, rows, stored, places, within, most):  # pragma: no cover - compiled
    """Of the pairs of a place (``query``, into ``places``, grouped) and a stored scan
    (``rows``, into ``stored``), those whose stored scan faces within ``within`` of the
    place's heading, the ``most`` nearest per place (equals in the order given), grouped by
    place, nearest first. (In NumPy, a dozen small array operations: a third of a single
    place's view.)"""
    n = rows.shape[0]
    keep_query = np.empty(n, dtype=np.int64)
    keep_rows = np.empty(n, dtype=np.int64)
    kept = 0
    start = 0
    while start < n:
        stop = start
        while stop < n and query[stop] == query[start]:
            stop += 1
        q = query[start]
        facing = np.empty(stop - start, dtype=np.int64)
        apart = np.empty(stop - start)
        m = 0
        for k in range(start, stop):
            r = rows[k]
            turn = abs((stored[r, 2] - places[q, 2] + math.pi) % (2.0 * math.pi) - math.pi)
            if turn <= within:
                facing[m] = r
                apart[m] = math.hypot(stored[r, 0] - places[q, 0], stored[r, 1] - places[q, 1])
                m += 1
        order = np.argsort(apart[:m], kind="mergesort")
        for k in range(min(m, most)):
            keep_query[kept] = q
            keep_rows[kept] = facing[order[k]]
            kept += 1
        start = stop
    return keep_query[:kept], keep_rows[:kept]
