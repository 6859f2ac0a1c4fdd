"""The SLAM pipeline: predict, match, correct, insert, show, for every scan.

* predict: the filter moves by the odometry increment since the last scan;
* match: the live scan is registered against the milestone its segment is anchored at, and
  against the stored milestones whose signatures match it within the filter's gate; a match is
  rejected on a poor registration fit, an ambiguous signature (a rival place scores nearly as
  well), or a failed Mahalanobis gate, and a rejected match changes nothing; a loop candidate
  (a milestone far back along the path) that ICP cannot register from the prediction, whose
  drift after a long way round may be metres, is registered from its node, or found by an
  exhaustive correlative search around the node (:mod:`vmp.correlative`) and accepted only
  on a clear peak and a close ICP fit;
* correct: the filter is updated with the best accepted match (the milestone pose composed
  with the registered relative pose);
* insert: the scan goes into the open segment as a polygon in the anchor's frame, and the
  correction is spread over the scans since the previous one; when the robot reaches a place
  where it should record a milestone, or comes back to a stored one, the segment closes and the
  next is anchored there; a return adds a loop edge to the milestone graph, whose adjustment
  moves the milestones and with them their segments; a loop to a milestone no nearer than the
  anchor (the anchor stands at the same place, recorded there on this visit) adds its edge
  without a handover;
* show: the view (a null view when nobody watches) gets what happened.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from milestones.manager import ManagerConfig, MilestoneManager
from vmp.correlative import CorrelativeConfig, LikelihoodGrid, correlative_search, grid_for
from vmp.fusion import CHI2_3DOF_99, MotionNoise, PoseFilter, pose_residual
from vmp.pose_graph import PoseGraph
from vmp.registration import Reference, Registration, RegistrationConfig, register
from vmp.scan_odometry import ScanOdometry, ScanOdometryConfig, motion_covariance
from vmp.types import (
    FloatArray,
    ScanFrame,
    compose,
    compose_covariance,
    inverse,
    inverse_covariance,
    relative,
    rotate_covariance,
)
from vmp.vector_map import BeamGeometry, VectorMap
from vmp.view import NullView, View

__all__ = ["Match", "Pipeline", "PipelineConfig", "fuse"]


def fuse(a: FloatArray, cov_a: FloatArray, b: FloatArray, cov_b: FloatArray
         ) -> tuple[FloatArray, FloatArray]:
    """Two estimates of one relative pose combined by their information."""
    info_a, info_b = np.linalg.inv(cov_a), np.linalg.inv(cov_b)
    cov = np.linalg.inv(info_a + info_b)
    d = np.asarray(a, dtype=np.float64) - b
    d[2] = (d[2] + math.pi) % (2 * math.pi) - math.pi
    return b + cov @ (info_a @ d), 0.5 * (cov + cov.T)


@dataclass(frozen=True)
class PipelineConfig:
    """Everything that tunes a mapping run (saved with every result)."""

    motion: MotionNoise = field(default_factory=MotionNoise)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    scan_odometry: ScanOdometryConfig = field(default_factory=ScanOdometryConfig)
    milestones: ManagerConfig = field(default_factory=ManagerConfig)
    use_milestones: bool = True  # False: odometry only (the baseline)
    max_rms: float = 0.05  # registration residual above which a match is a poor fit (m)
    min_inliers: float = 0.5  # share of live points that must find a partner
    max_ratio: float = 0.9  # signature score / best rival's above which a match is ambiguous
    gate: float = CHI2_3DOF_99  # Mahalanobis gate of a pose measurement (3 dof, 99 %)
    candidates: int = 2  # signature candidates registered per query, besides the anchor
    retry_max_ratio: float = 0.7  # a signature match registered from the node itself needs a
    retry_min_inliers: float = 0.75  # clearer place and a closer fit
    # A loop candidate (a signature match to a milestone far back along the path) that ICP
    # cannot register from the prediction nor from the node: search a window around the node
    # exhaustively (vmp/correlative.py), refine with ICP, accept only a clear peak.
    loop_search: CorrelativeConfig = field(default_factory=CorrelativeConfig)
    use_loop_search: bool = True
    search_every: int = 5  # scans between two searches for the same milestone
    search_max_ratio: float = 0.85  # runner-up / peak score above which the place is ambiguous
    search_min_score: float = 0.4  # mean likelihood of the live points at the peak
    search_min_inliers: float = 0.5  # share of live points the ICP refinement must match
    search_max_shift: float = 0.2  # ICP may move this far from the peak (m) ...
    search_max_turn: float = math.radians(4.0)  # ... and turn this much
    # The drift covariances compounded along hundreds of path edges are optimistic (the
    # odometry's errors are not white); a match registered without the prediction (from the
    # node or by the search) and verified by its fit is gated on drift covariances inflated
    # by this factor.
    loop_drift_inflation: float = 2.0
    pinned_sigma_xy: float = 0.1  # a registration this certain in every direction pins the
    pinned_sigma_theta: float = 0.05  # pose (m, rad): the above apply only to such matches
    query_every: int = 1  # scans between signature queries (the anchor is matched every scan)
    switch_margin: float = 0.3  # switch anchor when another milestone is this much nearer (m)
    loop_separation: int = 5  # milestones this many recordings apart may close a loop
    loop_chi2: float = 1.0  # adjust the graph when a new loop edge disagrees this much
    min_points: int = 20  # fewer returns than this: the scan is not matched
    no_return_free_range: float = 10.0  # how far a beam without a return marks free space (m)
    initial_sigma: tuple[float, float, float] = (0.01, 0.01, math.radians(0.5))
    # After a handover the robot's pose in the new anchor's frame keeps the gate's spread where
    # the registration does not see (helps the warehouse with a submap; costs the office: open).
    handover_covariance: bool = False


@dataclass(frozen=True)
class Match:
    """A milestone the live scan was registered against, and the verdict."""

    milestone: int
    source: str  # "anchor" or "signature"
    registration: Registration
    z: FloatArray  # the pose measurement in the map frame
    R: FloatArray  # its covariance
    mahalanobis2: float
    ratio: float
    score: float  # the signature score (nan for the anchor)
    accepted: bool
    reason: str  # why it was rejected ("" when accepted)
    seed: str = "prediction"  # the registration's start: "prediction", "node" or "search"


class Pipeline:
    """Build a vector map and a corrected trajectory from scan frames."""

    def __init__(self, geometry: BeamGeometry, config: PipelineConfig | None = None,
                 view: View | None = None) -> None:
        self.config = config or PipelineConfig()
        self.view: View = view or NullView()
        self.geometry = geometry
        self.map = VectorMap(geometry, self.config.no_return_free_range)
        self.milestones = MilestoneManager(self.config.milestones)
        self.graph = PoseGraph()
        self.filter: PoseFilter | None = None
        self.anchor: int | None = None
        self.stats: Counter[str] = Counter()
        self.online: list[FloatArray] = []  # filter pose after each scan
        # Every correction of the robot's pose: (scan index, kind, pose before, pose after).
        self.corrections: list[tuple[int, str, FloatArray, FloatArray]] = []
        self.odometry: list[FloatArray] = []
        self.truth: list[FloatArray | None] = []
        self._refs: dict[int, Reference] = {}
        self._grids: dict[int, LikelihoodGrid] = {}  # loop-search grids of milestones
        self._searched: dict[int, int] = {}  # milestone -> scan index of its last search
        self._closed: set[tuple[int, int]] = set()  # loops closed without a handover
        self._last_odom: FloatArray | None = None  # the odometry of the scan before
        self._odom_pose = np.zeros(3)  # where odometry alone puts the robot
        self._odom_offset = np.zeros(3)  # odometry frame -> that pose, after any gaps
        self._last_corrected = -1  # index of the scan the last correction was spread to
        self._pending: FloatArray | None = None  # pose before this scan's correction
        self._anchor_reg: Registration | None = None  # this scan's accepted anchor match
        self._abs_cov: list[FloatArray] = []  # per milestone: covariance in the map frame
        self._q_since = np.zeros((3, 3))  # motion noise since the last anchor correction
        # How well the robot's pose in its anchor's frame was known when the segment began:
        # nothing to doubt at a milestone just recorded, but a handover to a stored one sees
        # only what its registration sees (not the position along a rack aisle).
        self._handover_cov = np.zeros((3, 3))
        self.scan_odometry = ScanOdometry(self.config.scan_odometry, self.config.registration,
                                          self.config.motion)
        self._started = time.perf_counter()
        self._stamp = 0.0

    # ---- one scan ----------------------------------------------------------------------------

    def step(self, frame: ScanFrame) -> None:
        self.predict(frame)
        matches = self.match(frame)
        self.correct(matches)
        self.insert(frame, matches)
        self.show(frame, matches)

    def predict(self, frame: ScanFrame) -> None:
        self._stamp = frame.stamp
        odom = frame.odom
        if self.filter is None:
            start = odom if odom is not None else np.zeros(3)
            self.filter = PoseFilter(start, np.diag(np.square(self.config.initial_sigma)),
                                     self.config.motion)
            self._odom_pose = start.copy()
        else:
            # The wheel increment is known when this scan and the one before carry odometry.
            wheel = (relative(self._last_odom, odom)
                     if odom is not None and self._last_odom is not None else None)
            if odom is None:
                pass  # odometry alone knows no motion here: its pose holds
            elif wheel is None:  # odometry resumes: continue from where it stopped
                self._odom_offset = compose(self._odom_pose, inverse(odom))
            if odom is not None:
                self._odom_pose = compose(self._odom_offset, odom)
            u, q = self.scan_odometry.increment(frame.points(), wheel)
            self.filter.predict(u, q)
            self._q_since = self._q_since + rotate_covariance(q, self.filter.pose[2])
        self._last_odom = odom
        self._pending = None
        self._anchor_reg = None

    def match(self, frame: ScanFrame) -> list[Match]:
        c = self.config
        if not c.use_milestones or self.anchor is None:
            return []
        points = frame.points()
        if len(points) < c.min_points:
            self.stats["scans too sparse to match"] += 1
            return []
        x, P = self.filter.pose, self.filter.covariance
        targets: list[tuple[int, str, float, float | None, float]] = [
            (self.anchor, "anchor", 0.0, None, math.nan)]
        d_anchor = float(np.hypot(*(self.milestones.pose(self.anchor)[:2] - x[:2])))
        if len(self.map) % c.query_every == 0:
            gate_cov = P + self._robot_cov_via_anchor()
            for cand in self.milestones.query(frame.ranges, frame.angle_min,
                                              frame.angle_increment, frame.max_range,
                                              predicted_pose=x, covariance=gate_cov,
                                              max_candidates=c.candidates + 1):
                if cand.id == self.anchor or len(targets) > c.candidates:
                    continue
                # Registering costs; do it only where a match could change something: a
                # milestone nearer than the anchor (a handover) or one far back along the
                # path (a loop).
                d_cand = float(np.hypot(*(cand.pose[:2] - x[:2])))
                near_anchor = abs(cand.id - self.anchor) <= c.loop_separation
                if near_anchor and d_cand + c.switch_margin >= d_anchor:
                    continue
                targets.append((cand.id, "signature", cand.ratio, cand.heading_offset,
                                cand.score))
        return [self._register(mid, source, ratio, offset, score, points, x, P)
                for mid, source, ratio, offset, score in targets]

    def _register(self, mid: int, source: str, ratio: float, offset: float | None,
                  score: float, points: FloatArray, x: FloatArray, P: FloatArray) -> Match:
        c = self.config
        ms_pose = self.milestones.pose(mid)
        guess = relative(ms_pose, x)
        if offset is not None and P[2, 2] > math.radians(10) ** 2:
            guess[2] = offset  # an uncertain heading: trust the signature's instead
        reg = register(self._reference(mid), points, guess, c.registration)
        seed = "prediction"
        if source == "signature" and offset is not None and not self._fits(reg):
            # The prediction may have drifted far (a loop after a long way round): a matching
            # signature says the robot stands near the node, turned by the offset.
            retry = register(self._reference(mid), points, np.array([0.0, 0.0, offset]),
                             c.registration)
            # Only a clear place and a close fit: this guess ignores the prediction.
            if (self._fits(retry) and ratio <= c.retry_max_ratio
                    and retry.inliers >= c.retry_min_inliers):
                reg, seed = retry, "node"
            elif self._search_due(mid):
                found = self._loop_search(mid, points, offset)
                if found is not None:
                    reg, seed = found, "search"
        z = compose(ms_pose, reg.pose)
        R = rotate_covariance(reg.covariance, ms_pose[2])
        if source == "anchor":
            # Only the motion since the last anchor correction may separate prediction and
            # match, so a registration that drags the robot elsewhere (say, towards a person
            # walking along with it) fails the gate.
            spread = R + self._q_since
        else:
            # A return to an old milestone disagrees by the drift of both chains since.
            drift = self.filter.covariance + self._robot_cov_via_anchor() + self._abs_cov[mid]
            if seed != "prediction" and self._pins(reg):
                drift = drift * c.loop_drift_inflation
            spread = R + drift
        y = pose_residual(z, x)
        d2 = float(y @ np.linalg.solve(spread, y))
        reason = ""
        if not self._fits(reg):
            reason = "poor fit"
        elif source == "signature" and ratio > c.max_ratio:
            reason = "ambiguous"
        elif d2 > c.gate:
            reason = "gate"
        return Match(mid, source, reg, z, R, d2, ratio, score, reason == "", reason, seed)

    def _search_due(self, mid: int) -> bool:
        """Whether a loop search against milestone ``mid`` may run for this scan."""
        c = self.config
        if not c.use_loop_search or abs(mid - self.anchor) <= c.loop_separation:
            return False
        last = self._searched.get(mid)
        return last is None or len(self.map) - last >= c.search_every

    def _loop_search(self, mid: int, points: FloatArray, offset: float) -> Registration | None:
        """Register ``points`` on milestone ``mid`` by a window search around its node.

        The window is centred on the node, turned by the signature's heading offset; the peak
        must stand clear of every pose a separation away, and its ICP refinement must fit
        well, match most points and stay near the peak. Returns the refinement, or None.
        """
        c = self.config
        self._searched[mid] = len(self.map)
        self.stats["loop searches"] += 1
        grid = self._grids.get(mid)
        if grid is None:
            grid = self._grids[mid] = grid_for(self._reference(mid).points, c.loop_search)
        found = correlative_search(grid, points, np.array([0.0, 0.0, offset]), c.loop_search)
        if found.score < c.search_min_score or found.ratio > c.search_max_ratio:
            self.stats["loop searches without a clear peak"] += 1
            return None
        reg = register(self._reference(mid), points, found.pose, c.registration)
        shift = reg.pose - found.pose
        turn = abs((shift[2] + math.pi) % (2 * math.pi) - math.pi)
        if (not self._fits(reg) or reg.inliers < c.search_min_inliers
                or math.hypot(shift[0], shift[1]) > c.search_max_shift
                or turn > c.search_max_turn):
            self.stats["loop searches with a poor refinement"] += 1
            return None
        self.stats["loop searches found"] += 1
        return reg

    def _pins(self, reg: Registration) -> bool:
        """Whether a registration fixes the pose in every direction (no corridor axis) by
        lines alone."""
        if reg.by_corners:
            return False
        sd = np.sqrt(np.linalg.eigvalsh(reg.covariance[:2, :2]))
        return bool(sd.max() <= self.config.pinned_sigma_xy
                    and math.sqrt(reg.covariance[2, 2]) <= self.config.pinned_sigma_theta)

    def _fits(self, reg: Registration) -> bool:
        c = self.config
        return bool(np.isfinite(reg.rms) and reg.rms <= c.max_rms and reg.inliers >= c.min_inliers)

    def correct(self, matches: list[Match]) -> None:
        """Update the filter from the anchor match; a return to an old milestone instead
        hands the segment over to it (see :meth:`insert`) and moves the graph."""
        for m in matches:
            self.stats[f"{m.source} matches accepted" if m.accepted
                       else f"{m.source} matches rejected ({m.reason})"] += 1
        anchor = [m for m in matches if m.accepted and m.source == "anchor"]
        if not anchor:
            return
        self._pending = self.filter.pose.copy()
        self.filter.update(anchor[0].z, anchor[0].R)
        self.corrections.append((len(self.map), "anchor", self._pending, self.filter.pose.copy()))
        self._anchor_reg = anchor[0].registration
        self._q_since = np.zeros((3, 3))

    def insert(self, frame: ScanFrame, matches: list[Match]) -> None:
        x = self.filter.pose
        if self.anchor is None:
            first = self.milestones.add(x, frame.ranges, frame.angle_min,
                                        frame.angle_increment, frame.max_range, frame.stamp)
            self._abs_cov.append(self.filter.covariance.copy())
            self._start_segment(first, handover=None)
        else:
            self._maybe_switch_anchor(matches)
        anchor_pose = self.milestones.pose(self.anchor)
        before = self._pending if self._pending is not None else self.filter.pose
        k = self.map.insert(frame.ranges, relative(anchor_pose, before), frame.stamp,
                            frame.no_return_free)
        if self._pending is not None:
            correction = compose(relative(anchor_pose, self.filter.pose),
                                 inverse(relative(anchor_pose, before)))
            self.map.spread(self._last_corrected + 1, correction)
            self._last_corrected = k
        self.online.append(self.filter.pose.copy())
        self.odometry.append(self._odom_pose.copy())
        self.truth.append(None if frame.true_pose is None else frame.true_pose.copy())
        if self.config.use_milestones:
            new = self.milestones.consider(self.filter.pose, frame.ranges, frame.angle_min,
                                           frame.angle_increment, frame.max_range, frame.stamp)
            if new is not None:
                self.stats["milestones recorded"] += 1
                placed = relative(self.milestones.pose(self.anchor), self.filter.pose)
                rel, cov = self._milestone_edge(self.anchor, new, self._robot_in_anchor())
                self.graph.add(self.anchor, new, rel, cov, "path")
                self._abs_cov.append(self._compound_cov(self.anchor, rel, cov))
                self.view.milestone(new, self.milestones.pose(new))
                self._start_segment(new, handover=placed)

    def show(self, frame: ScanFrame, matches: list[Match]) -> None:
        k = len(self.map) - 1
        anchor = [m for m in matches if m.source == "anchor" and m.accepted]
        scores = [m.score for m in matches if m.source == "signature"]
        metrics = {
            "innovation": anchor[0].mahalanobis2 if anchor else math.nan,
            "score": min(scores) if scores else math.nan,
            "covariance_trace": float(np.trace(self.filter.covariance[:2, :2])),
        }
        hits = np.unpackbits(self.map.packed_hits[k], count=self.geometry.num_beams).astype(bool)
        self.view.scan(k, frame.stamp, self.filter.pose, self._odom_pose, frame.true_pose,
                       int(self.map.segments[k]), self.map.rel_poses[k], self.map.end_points[k],
                       hits, metrics)
        for m in matches:
            self.view.match(m.milestone, self.milestones.pose(m.milestone), self.filter.pose,
                            m.accepted, m.reason)
            if m.source == "signature":
                verdict = "accepted" if m.accepted else f"rejected ({m.reason})"
                self.view.event(f"scan {k}: milestone {m.milestone} {verdict}, score "
                                f"{m.score:.3f}, ratio {m.ratio:.2f}, "
                                f"fit {m.registration.rms:.3f} m",
                                "INFO" if m.accepted else "DEBUG")

    def _reference(self, mid: int) -> Reference:
        """The registration reference of a milestone's stored scan (built once)."""
        ref = self._refs.get(mid)
        if ref is None:
            r = self.milestones.scan(mid).astype(np.float64)
            ok = np.isfinite(r)
            a = self.geometry.angles[ok]
            pts = np.stack([r[ok] * np.cos(a), r[ok] * np.sin(a)], axis=-1)
            ref = self._refs[mid] = Reference(pts, self.config.registration)
        return ref

    # ---- segments and the graph -----------------------------------------------------------------

    def _start_segment(self, anchor: int, handover: FloatArray | None) -> None:
        self.anchor = anchor
        self._handover_cov = np.zeros((3, 3))
        segment = self.map.new_segment(anchor, handover)
        self._last_corrected = len(self.map) - 1
        self.view.segment(len(self.map), self._stamp, segment, anchor,
                          self.milestones.pose(anchor))

    def _robot_in_anchor(self) -> tuple[FloatArray, FloatArray]:
        """The robot's pose in the anchor's frame and its covariance.

        The motion since the anchor bounds the uncertainty (odometry noise over that
        distance); this scan's registration against the anchor narrows it where it sees.
        """
        rel = relative(self.milestones.pose(self.anchor), self.filter.pose)
        cov = motion_covariance(rel, self.config.motion) + self._handover_cov
        if self._anchor_reg is not None:
            return rel, fuse(rel, self._anchor_reg.covariance, rel, cov)[1]
        return rel, cov

    def _milestone_edge(self, a: int, b: int, fallback: tuple[FloatArray, FloatArray]
                        ) -> tuple[FloatArray, FloatArray]:
        """Milestone ``b`` in ``a``'s frame by registering their stored scans.

        ``fallback`` (pose and covariance, also the starting guess) stands when the two scans
        do not register well.
        """
        guess, cov = fallback
        ref_b = self._reference(b)
        reg = register(self._reference(a), ref_b.points, guess, self.config.registration)
        if (np.isfinite(reg.rms) and reg.rms <= self.config.max_rms
                and reg.inliers >= self.config.min_inliers):
            self.stats["milestone edges registered"] += 1
            return fuse(reg.pose, reg.covariance, guess, cov)
        self.stats["milestone edges from the filter"] += 1
        return guess, cov

    def _compound_cov(self, anchor: int, rel: FloatArray, cov: FloatArray) -> FloatArray:
        """Map-frame covariance of ``anchor (+) rel``, given the edge covariance ``cov``."""
        return compose_covariance(self.milestones.pose(anchor), self._abs_cov[anchor], rel, cov)

    @staticmethod
    def _via(rel_a: FloatArray, cov_a: FloatArray, reg: Registration
             ) -> tuple[FloatArray, FloatArray]:
        """Milestone ``b`` in the anchor's frame through the robot: the robot in the anchor's
        frame (``rel_a``, ``cov_a``) and in ``b``'s (a registration, in ``b``'s frame)."""
        to_b = inverse(reg.pose)
        return compose(rel_a, to_b), compose_covariance(
            rel_a, cov_a, to_b, inverse_covariance(reg.pose, reg.covariance))

    def _robot_cov_via_anchor(self) -> FloatArray:
        """How uncertain the robot is in the map frame through its anchor's chain."""
        rel = relative(self.milestones.pose(self.anchor), self.filter.pose)
        return self._compound_cov(self.anchor, rel, np.zeros((3, 3)))

    def _maybe_switch_anchor(self, matches: list[Match]) -> None:
        """Hand over to a stored milestone the robot has come back to, adding a loop edge."""
        x = self.filter.pose
        d_anchor = float(np.hypot(*(self.milestones.pose(self.anchor)[:2] - x[:2])))
        best = None
        for m in matches:
            if not m.accepted or m.source != "signature":
                continue
            if m.seed != "prediction" and self._pins(m.registration):
                # Registered from the node, not from the prediction (which, after a long way
                # round, may be metres off): how far the match puts the robot decides.
                d = float(np.hypot(*m.registration.pose[:2]))
            else:
                d = float(np.hypot(*(self.milestones.pose(m.milestone)[:2] - x[:2])))
            if d + self.config.switch_margin < d_anchor and (best is None or d < best[1]):
                best = (m, d)
        if best is None:
            self._close_in_place(matches)
            return
        m = best[0]
        anchor_pose = self.milestones.pose(self.anchor).copy()
        placed = relative(anchor_pose, self.filter.pose)  # where this scan would have gone
        rel_a, cov_a = self._robot_in_anchor()
        z, cov = self._milestone_edge(self.anchor, m.milestone,
                                      self._via(rel_a, cov_a, m.registration))
        # Re-localise on the milestone we hand over to (degenerate directions of its
        # registration carry a huge covariance, so the filter keeps its own estimate there).
        before = self.filter.pose.copy()
        # The robot in the new anchor's frame: the registration where it sees, elsewhere what
        # the filter and both chains of milestones knew (the spread of the handover's gate).
        in_map = None
        if self.config.handover_covariance:
            prior = (self.filter.covariance + self._robot_cov_via_anchor()
                     + self._abs_cov[m.milestone])
            in_map = fuse(m.z, m.R, m.z, prior)[1]
        self.filter.update(m.z, m.R)
        self.corrections.append((len(self.map), "handover", before, self.filter.pose.copy()))
        self._pending = None  # the scan goes into the new segment where the filter now is
        target = self.milestones.pose(m.milestone)
        handover = compose(placed, inverse(relative(target, self.filter.pose)))
        sequential = abs(m.milestone - self.anchor) == 1
        edge = self.graph.add(self.anchor, m.milestone, z, cov, "path" if sequential else "loop")
        self.stats["anchor switches"] += 1
        self._start_segment(m.milestone, handover=handover)
        if in_map is not None:
            self._handover_cov = rotate_covariance(in_map,
                                                   -self.milestones.pose(m.milestone)[2])
        self.view.event(f"scan {len(self.map)}: handed over from milestone {edge.i} to "
                        f"{edge.j} ({edge.kind} edge)")
        if edge.kind == "loop":
            self.stats["loop edges"] += 1
            e = self.graph.error(self.milestones.poses, edge)
            if float(e @ edge.information @ e) > self.config.loop_chi2:
                self._adjust()

    def _close_in_place(self, matches: list[Match]) -> None:
        """A loop to a milestone no nearer than the anchor: an edge between the two, no
        handover.

        The anchor may itself stand at the place seen long ago (recorded there on this visit,
        or on an earlier one whose loop was never closed), so no handover comes; a match that
        pins the pose then still closes the loop, when the graph disagrees with it (once per
        pair of milestones). A match registered from the prediction needs a clear place
        (``retry_max_ratio``), as one registered from the node does: the Intel run passed such
        places, one after another, without closing a loop whenever the robot came back facing
        another way and recorded a milestone of its own there.
        """
        for m in matches:
            if (not m.accepted or m.source != "signature"
                    or (m.seed == "prediction" and m.ratio > self.config.retry_max_ratio)
                    or abs(m.milestone - self.anchor) <= self.config.loop_separation
                    or (self.anchor, m.milestone) in self._closed
                    or not self._pins(m.registration)):
                continue
            rel_a, cov_a = self._robot_in_anchor()
            z, cov = self._milestone_edge(self.anchor, m.milestone,
                                          self._via(rel_a, cov_a, m.registration))
            edge = self.graph.add(self.anchor, m.milestone, z, cov, "loop")
            self._closed.add((self.anchor, m.milestone))
            self.stats["loop edges"] += 1
            self.stats["loop edges in place"] += 1
            self.view.event(f"scan {len(self.map)}: loop edge from milestone {edge.i} to "
                            f"{edge.j} (no handover)")
            e = self.graph.error(self.milestones.poses, edge)
            if float(e @ edge.information @ e) > self.config.loop_chi2:
                self._adjust()
            return

    def _adjust(self) -> None:
        """Adjust the milestone graph; the robot moves with its anchor."""
        t = time.perf_counter()
        robot_in_anchor = relative(self.milestones.pose(self.anchor), self.filter.pose)
        poses = self.graph.optimize(self.milestones.poses)
        self.milestones.set_poses(poses)
        if self.graph.marginals is not None:  # the loop has shrunk every milestone's doubt
            self._abs_cov = [c + np.diag([1e-6, 1e-6, 1e-8]) for c in self.graph.marginals]
        before = self.filter.pose.copy()
        self.filter.set_pose(compose(poses[self.anchor], robot_in_anchor))
        self.corrections.append((len(self.map), "graph", before, self.filter.pose.copy()))
        self.stats["graph adjustments"] += 1
        self.stats["graph adjustment seconds"] += time.perf_counter() - t
        self.view.anchors_moved(self.milestones.ids, poses)

    # ---- results -----------------------------------------------------------------------------

    def finish(self) -> None:
        """Adjust the graph a last time (when loops were closed)."""
        if self.stats["loop edges"]:
            poses = self.graph.optimize(self.milestones.poses)
            self.milestones.set_poses(poses)
            self.view.anchors_moved(self.milestones.ids, poses)

    def trajectory(self) -> FloatArray:
        """Poses ``(S, 3)`` of every scan in the assembled map."""
        return self.map.world_poses(self._poses_by_id())

    def _poses_by_id(self) -> FloatArray:
        ids = self.milestones.ids
        out = np.zeros((int(ids.max()) + 1 if len(ids) else 0, 3))
        out[ids] = self.milestones.poses
        return out

    @property
    def wall_time(self) -> float:
        return time.perf_counter() - self._started

    def summary(self) -> dict[str, float | int]:
        s = dict(self.stats)
        s["scans"] = len(self.map)
        s["milestones"] = len(self.milestones)
        s["segments"] = len(self.map.segment_anchor)
        s["bytes per scan"] = self.map.bytes_per_scan
        return s

