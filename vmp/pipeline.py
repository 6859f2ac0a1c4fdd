"""The SLAM pipeline: predict, match, correct, insert, show, for every scan.

* predict: the filter moves by the odometry increment since the last scan, refined by scan
  registration (:mod:`vmp.frontend`);
* match: the live scan is registered against its segment's anchor milestone and the stored
  milestones whose signatures match it, each match judged (:mod:`vmp.matcher`), unless the
  robot has stood still since the last matched scan;
* correct: the filter is updated with the accepted anchor match; a return to a stored milestone
  nearer than the anchor re-localises on it and hands the segment over, adding an edge to the
  milestone graph; a loop edge that disagrees with the graph has it adjusted, and the robot
  moves with its anchor (:mod:`vmp.backend`). Nothing else changes the filter;
* insert: the scan goes into the open segment as a polygon in the anchor's frame, and the
  correction is spread over the scans since the previous one; where a milestone is due and the
  place distinctive, one is recorded and the next segment is anchored there;
* show: the view (a null view when nobody watches) gets what happened.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable

import numpy as np

from milestones.manager import MilestoneManager
from vmp.backend import BackEnd
from vmp.config import MappingConfig
from vmp.frontend import FrontEnd, new_view
from vmp.loops import NEIGHBOURS, LoopSearch
from vmp.mapfile import MapData
from vmp.matcher import Doubt, Kind, Match, Matcher, Seed
from vmp.session_ties import tie_sessions
from vmp.submaps import Submaps
from vmp.types import (
    BeamGeometry,
    FloatArray,
    ScanFrame,
    compose,
    inverse,
    relative,
    widest_variance,
)
from vmp.vector_map import VectorMap
from vmp.view import NullView, View

__all__ = ["Pipeline"]


# A loop edge the robust adjustment left less than this share of its information counts as
# down-weighted in the summary.
DOWN_WEIGHTED = 0.5


class Pipeline:
    """Build a vector map and a corrected trajectory from scan frames."""

    # The id of this session's first milestone when it maps on in a saved map (a class
    # default for checkpoints that do not hold it).
    _first_new: int | None = None

    def __init__(self, geometry: BeamGeometry, config: MappingConfig | None = None,
                 view: View | None = None, saved: MapData | None = None) -> None:
        """``saved`` is a map to go on mapping in (:meth:`join` puts the robot in it)."""
        self.config = config or MappingConfig()
        self.view: View = view or NullView()
        self.geometry = geometry
        self.stats: Counter[str] = Counter()
        self.map = (saved.map if saved is not None
                    else VectorMap(geometry, self.config.map.no_return_free_range))
        self.milestones = (saved.milestones if saved is not None
                           else MilestoneManager(self.config.milestones))
        self.front = FrontEnd(self.config)
        self.submaps = Submaps(self.map)
        self.matcher = Matcher(self.config, geometry, self.milestones, self.stats)
        self.back = BackEnd(self.config, self.milestones, self.matcher.reference, self.view,
                            self.stats)
        self.loops = LoopSearch(self.config, self.milestones, self._submap_segments,
                                self._submap_points, self.stats)
        if saved is not None:
            self.back.restore(saved.graph)
            self._first_new = int(saved.milestones.ids.max()) + 1 if len(saved.milestones) else 0
        self._join: int | None = None  # the saved milestone the robot was localized at
        # Every correction of the robot's pose: (scan index, kind, pose before, pose after).
        self.corrections: list[tuple[int, str, FloatArray, FloatArray]] = []
        self._stamp = 0.0
        self._last_corrected = -1  # index of the scan the last correction was spread to
        self._uncorrected: FloatArray | None = None  # this scan's pose before its correction
        self._handover: tuple[int, FloatArray] | None = None  # this scan's new anchor, handover
        # The pose of the last scan matched against the milestones (None: the next one is).
        self.matched_at: FloatArray | None = None

    def join(self, front: FrontEnd, place: int) -> None:
        """Go on mapping a saved map from where a localizer found the robot: ``front`` is
        its front end (its filter at the robot's pose in the map's frame, with its
        covariance), ``place`` the saved milestone it was registered against. The next scan
        records a milestone there, joined to ``place`` by a loop edge. From here on its scan
        odometry judges fits as the mapper's does."""
        front.scan_odometry.by_all_points = True
        self.front = front
        self._join = place

    # ---- one scan ----------------------------------------------------------------------------

    def step(self, frame: ScanFrame) -> None:
        self.predict(frame)
        matches = self.match(frame)
        self.correct(matches)
        self.insert(frame)
        self.show(frame, matches)

    def predict(self, frame: ScanFrame) -> None:
        self._stamp = frame.stamp
        self.front.predict(frame)
        self._uncorrected = None
        self._handover = None
        self.back.anchor_registration = None

    def match(self, frame: ScanFrame) -> list[Match]:
        if not self.config.matching.enabled or self.back.anchor is None:
            return []
        x, P = self.front.pose, self.front.covariance
        doubt = Doubt(self.front.motion_since_fix, self.back.cov_via_anchor(x),
                      self.back.milestone_cov)
        scan = len(self.map)
        matches = []
        if new_view(self.matched_at, x):  # standing still, a scan is not matched again
            self.matched_at = x.copy()
            matches = self.matcher.match(frame, x, P, self.back.anchor, doubt,
                                         self.back.closed_from_anchor())
        else:
            self.stats["scans not matched (standing still)"] += 1
        if self.loops.due(self.back.anchor):
            # A search's find stands beside the matcher's own match of its milestone only
            # where that one was accepted: registered from a prediction metres off, the
            # matcher's may fail where the search, over its window, finds the place (on ACES
            # with the wheels' heading drifting, the right place's find was dropped so, and
            # a stretch of corridor 7.5 m along closed the loop).
            seen = {m.milestone for m in matches if m.accepted}
            finds = self.loops.search(frame, x, self.back.anchor, self.back.linked(), scan,
                                      self._drift(x, P, doubt))
            for find in finds:
                if find.milestone not in seen:
                    # The search judged its own rivals (vmp.loops): a rival pose's score is
                    # not a signature's, so the matcher's signature ratio test gets none.
                    matches.append(self.matcher.judge(find.milestone, find.registration,
                                                      0.0, find.signature, x, P, doubt,
                                                      Seed.SEARCH))
        return matches

    def _drift(self, x: FloatArray, P: FloatArray, doubt: Doubt
               ) -> Callable[[int], FloatArray]:
        """How far the robot at ``x`` may have drifted from a stored milestone: the drift
        compounded along the path between them where the milestone lies on the path back from
        the anchor and that is the narrower, else the sum of both map-frame covariances
        (which hold all the drift since the start: a milestone ten seconds back would be
        searched metres around, in the warehouse as far as the next aisle)."""
        along: dict[int, FloatArray] = {}
        followed_to = math.inf  # the oldest milestone the path has been followed back to

        def drift(mid: int) -> FloatArray:
            nonlocal followed_to
            if mid < followed_to:
                along.update(self.back.drift_along_path(x, mid))
                followed_to = mid
            summed = P + doubt.via_anchor + doubt.milestone(mid)
            chain = along.get(mid)
            if chain is None or widest_variance(chain) >= widest_variance(summed):
                return summed
            return chain

        return drift

    def correct(self, matches: list[Match]) -> None:
        """Update the filter from the anchor match; re-localise on a stored milestone the robot
        has come back to (handing the segment over) or close a loop in place, and move the
        robot with its anchor when the graph is adjusted."""
        for m in matches:
            verdict = "accepted" if m.accepted else f"rejected ({m.reason.value})"
            self.stats[f"{m.kind.value} matches {verdict}"] += 1
        anchor = [m for m in matches if m.accepted and m.kind is Kind.ANCHOR]
        if anchor:
            self._uncorrected = self.front.pose.copy()
            self._update(anchor[0].z, anchor[0].R, "anchor")
            self.back.anchor_registration = anchor[0].registration
            self.front.motion_since_fix = np.zeros((3, 3))
        if self.back.anchor is None:
            return
        target = self.back.handover_target(matches, self.front.pose)
        if target is None:
            edge = self.back.close_in_place(matches, self.front.pose)
            if edge is not None:
                self.view.event(f"scan {len(self.map)}: loop edge from milestone {edge.i} to "
                                f"{edge.j} (no handover)")
        else:
            placed = relative(self.milestones.pose(self.back.anchor), self.front.pose)
            z, cov = self.back.handover_edge(target, self.front.pose)
            # Re-localise on the milestone we hand over to (degenerate directions of its
            # registration carry a huge covariance, so the filter keeps its own estimate there).
            self._update(target.z, target.R, "handover")
            self._uncorrected = None  # the scan goes into the new segment where the filter is
            now = relative(self.milestones.pose(target.milestone), self.front.pose)
            self._handover = (target.milestone, compose(placed, inverse(now)))
            edge = self.back.hand_over(target.milestone, z, cov)
            self.view.event(f"scan {len(self.map)}: handed over from milestone {edge.i} to "
                            f"{edge.j} (path edge)")
        if edge is not None and edge.kind == "loop" and self.back.disagrees(edge):
            self._adjust()

    def _submap_segments(self, anchor: int) -> tuple[int, ...]:
        return self.submaps.segments_around(anchor, NEIGHBOURS)

    def _submap_points(self, anchor: int):
        return self.submaps.neighbourhood(anchor, NEIGHBOURS, self.back.poses_by_id())

    def _update(self, z: FloatArray, R: FloatArray, kind: str) -> None:
        before = self.front.pose.copy()
        self.front.filter.update(z, R)
        self.corrections.append((len(self.map), kind, before, self.front.pose.copy()))

    def _adjust(self) -> None:
        """Adjust the milestone graph; the robot moves with its anchor."""
        anchor = self.back.anchor
        anchor_before = self.milestones.pose(anchor).copy()
        robot_in_anchor = relative(anchor_before, self.front.pose)
        poses = self.back.adjust()
        before = self.front.pose.copy()
        self.front.filter.set_pose(compose(poses[anchor], robot_in_anchor))
        if self._uncorrected is not None:
            # This scan's pose before the filter's correction moves with the anchor too: what
            # is spread over the scans since the last correction is that correction alone.
            self._uncorrected = compose(poses[anchor], relative(anchor_before,
                                                                self._uncorrected))
        self.corrections.append((len(self.map), "graph", before, self.front.pose.copy()))

    def insert(self, frame: ScanFrame) -> None:
        if self.back.anchor is None:
            first = self.back.begin(self.front.pose, self.front.covariance, frame)
            self._start_segment(first, None)
            if self._join is not None:
                self.back.join(self._join, first, self.front.covariance)
                self._join = None
        elif self._handover is not None:
            self._start_segment(*self._handover)
        anchor_pose = self.milestones.pose(self.back.anchor)
        before = self._uncorrected if self._uncorrected is not None else self.front.pose
        k = self.map.insert(frame.ranges, relative(anchor_pose, before), frame.stamp,
                            frame.no_return_free)
        if self._uncorrected is not None:
            correction = compose(relative(anchor_pose, self.front.pose),
                                 inverse(relative(anchor_pose, before)))
            self.map.spread(self._last_corrected + 1, correction)
            self._last_corrected = k
        if self.config.matching.enabled:
            placed = relative(anchor_pose, self.front.pose)
            new = self.back.record(self.front.pose, frame)
            if new is not None:
                self._start_segment(new, placed)

    def _start_segment(self, anchor: int, handover: FloatArray | None) -> None:
        segment = self.map.new_segment(anchor, handover)
        self._last_corrected = len(self.map) - 1
        self.view.segment(len(self.map), self._stamp, segment, anchor,
                          self.milestones.pose(anchor))

    def show(self, frame: ScanFrame, matches: list[Match]) -> None:
        k = len(self.map) - 1
        anchor = [m for m in matches if m.kind is Kind.ANCHOR and m.accepted]
        scores = [m.score for m in matches if m.kind is Kind.SIGNATURE]
        metrics = {
            "innovation": anchor[0].mahalanobis2 if anchor else math.nan,
            "score": min(scores) if scores else math.nan,
            "covariance_trace": float(np.trace(self.front.covariance[:2, :2])),
        }
        hits = np.unpackbits(self.map.packed_hits[k], count=self.geometry.num_beams).astype(bool)
        self.view.scan(k, frame.stamp, self.front.pose, self.front.odom_pose, frame.true_pose,
                       int(self.map.segments[k]), self.map.rel_poses[k], self.map.end_points[k],
                       hits, metrics)
        for m in matches:
            reason = "" if m.reason is None else m.reason.value
            self.view.match(m.milestone, self.milestones.pose(m.milestone), self.front.pose,
                            m.accepted, reason)
            if m.kind is Kind.SIGNATURE:
                verdict = "accepted" if m.accepted else f"rejected ({reason})"
                self.view.event(f"scan {k}: milestone {m.milestone} {verdict}, score "
                                f"{m.score:.3f}, ratio {m.ratio:.2f}, "
                                f"fit {m.registration.rms:.3f} m",
                                "INFO" if m.accepted else "DEBUG")

    # ---- results -----------------------------------------------------------------------------

    @property
    def pose(self) -> FloatArray:
        """The filter's pose after the last scan."""
        return self.front.pose

    def finish(self) -> None:
        """Search the loops between the sessions once more (mapping on in a saved map:
        :mod:`vmp.session_ties`), and adjust the graph a last time (when loops were closed)."""
        if self._first_new is not None:
            tied = tie_sessions(self._first_new, self.geometry, self.milestones, self.loops,
                                self.back, self.stats)
            self.view.event(f"{tied} loop edges between the sessions found at the end")
        self.back.finish()

    def trajectory(self) -> FloatArray:
        """Poses ``(S, 3)`` of every scan in the assembled map."""
        return self.map.world_poses(self.back.poses_by_id())

    def summary(self) -> dict[str, float | int]:
        s = dict(self.stats)
        s["scans"] = len(self.map)
        s["milestones"] = len(self.milestones)
        s["segments"] = len(self.map.segment_anchor)
        s["bytes per scan"] = self.map.bytes_per_scan
        odo = self.front.scan_odometry
        s["scan odometry: refined increments"] = odo.refined
        s["scan odometry: fell back to the wheels"] = odo.fallbacks
        s["scan odometry: wheels overruled"] = odo.overruled
        s["odometry delay learned (s)"] = self.front.latency.latency
        graph = self.back.graph
        loops = np.array([e.kind == "loop" for e in graph.edges], dtype=bool)
        s["loop edges in the graph"] = int(loops.sum())
        if len(graph.weights) == len(loops):  # after an adjustment
            s["loop edges down-weighted"] = int((graph.weights[loops] < DOWN_WEIGHTED).sum())
        return s

