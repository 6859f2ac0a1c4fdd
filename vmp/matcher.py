"""Matching a live scan against stored milestones, and the verdict on each match.

Every scan is registered against the milestone its segment is anchored at, and against the
stored milestones whose signatures match it within the filter's gate, where a match could
change something (a milestone nearer than the anchor, or one far back along the path). A
match is rejected on a poor fit, an ambiguous signature (a rival place scores nearly as well)
or a failed Mahalanobis gate; a rejected match changes nothing. A loop candidate that ICP
cannot register from the prediction, whose drift after a long way round may be metres, is
registered from its node; where that fails too, the loop search (:mod:`vmp.loops`) looks for
the place by branch and bound.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Collection
from dataclasses import dataclass
from enum import Enum

import numpy as np

from milestones.manager import MilestoneManager
from vmp.config import MappingConfig
from vmp.fusion import CHI2_3DOF_99, pose_residual
from vmp.linalg import solve
from vmp.registration import MIN_POINTS, Reference, Registration, fits, register
from vmp.types import (
    BeamGeometry,
    FloatArray,
    ScanFrame,
    compose,
    relative,
    rotate_covariance,
    widest_variance,
)

__all__ = ["Doubt", "Kind", "Match", "Matcher", "Reason", "Seed", "pins"]

# A registration this certain in every direction pins the pose (m, rad).
PINNED_SIGMA_XY = 0.1
PINNED_SIGMA_THETA = 0.05
# A heading this uncertain (rad) is replaced by the signature's heading offset as ICP's start.
UNCERTAIN_HEADING = math.radians(10.0)
# The drift covariances compounded along hundreds of path edges are optimistic (the odometry's
# errors are not white); a match registered without the prediction (from the node or by the
# search) and pinned by its fit is gated on drift covariances inflated by this factor.
LOOP_DRIFT_INFLATION = 2.0


class Kind(Enum):
    """Why a milestone was matched: the segment's anchor, or a signature match."""

    ANCHOR = "anchor"
    SIGNATURE = "signature"


class Seed(Enum):
    """Where the registration started: the prediction, the milestone's node, the loop search."""

    PREDICTION = "prediction"
    NODE = "node"
    SEARCH = "search"


class Reason(Enum):
    """Why a match was rejected."""

    POOR_FIT = "poor fit"
    AMBIGUOUS = "ambiguous"
    GATE = "gate"


@dataclass(frozen=True)
class Match:
    """A milestone the live scan was registered against, and the verdict."""

    milestone: int
    kind: Kind
    registration: Registration
    z: FloatArray  # the pose measurement in the map frame
    R: FloatArray  # its covariance
    mahalanobis2: float
    ratio: float  # signature score / best rival's (0 for the anchor)
    score: float  # the signature score (nan for the anchor)
    reason: Reason | None  # why it was rejected; None: accepted
    seed: Seed = Seed.PREDICTION

    @property
    def accepted(self) -> bool:
        return self.reason is None


def pins(reg: Registration) -> bool:
    """Whether a registration fixes the pose in every direction (no corridor axis) by lines
    alone."""
    if reg.by_corners:
        return False
    return bool(math.sqrt(widest_variance(reg.covariance)) <= PINNED_SIGMA_XY
                and math.sqrt(reg.covariance[2, 2]) <= PINNED_SIGMA_THETA)


@dataclass(frozen=True)
class Doubt:
    """How far a match may disagree with the filter's prediction, besides the filter's own
    covariance and the registration's."""

    anchor_motion: FloatArray  # motion noise since the last anchor correction
    via_anchor: FloatArray  # the robot's map-frame covariance through its anchor's chain
    milestone: Callable[[int], FloatArray]  # a stored milestone's map-frame covariance


class Matcher:
    """Registers live scans against stored milestones and judges each match."""

    def __init__(self, config: MappingConfig, geometry: BeamGeometry,
                 milestones: MilestoneManager, stats: Counter[str]) -> None:
        self.config = config
        self.geometry = geometry
        self.milestones = milestones
        self.stats = stats
        self._refs: dict[int, Reference] = {}

    def reference(self, mid: int) -> Reference:
        """The registration reference of a milestone's stored scan (built once)."""
        ref = self._refs.get(mid)
        if ref is None:
            r = self.milestones.scan(mid).astype(np.float64)
            ok = np.isfinite(r)
            a = self.geometry.angles[ok]
            pts = np.stack([r[ok] * np.cos(a), r[ok] * np.sin(a)], axis=-1)
            ref = self._refs[mid] = Reference(pts)
        return ref

    def match(self, frame: ScanFrame, pose: FloatArray, cov: FloatArray, anchor: int,
              doubt: Doubt, settled: Collection[int] = ()) -> list[Match]:
        """The matches of one scan: its anchor's, then its signature candidates'.

        ``pose`` and ``cov`` are the filter's. A candidate in ``settled`` (the anchor's loop
        to it is closed already) is not registered: its match could change nothing. It
        still takes its place among the candidates, so the others are those of a run that
        registered it.
        """
        points = frame.points()
        if len(points) < MIN_POINTS:
            self.stats["scans too sparse to match"] += 1
            return []
        targets = [(anchor, Kind.ANCHOR, 0.0, None, math.nan)]
        for target in self._candidates(frame, pose, anchor, cov + doubt.via_anchor):
            if target[0] in settled:
                self.stats["signature matches of closed loops not registered"] += 1
            else:
                targets.append(target)
        return [self._register(mid, kind, ratio, offset, score, points, pose, cov, doubt)
                for mid, kind, ratio, offset, score in targets]

    def judge(self, mid: int, reg: Registration, ratio: float, score: float, x: FloatArray,
              P: FloatArray, doubt: Doubt, seed: Seed) -> Match:
        """A registration on a stored milestone found otherwise (by the loop search), judged
        as a signature match seeded there."""
        return self._verdict(mid, Kind.SIGNATURE, reg, seed, ratio, score, x, P, doubt)

    def _candidates(self, frame: ScanFrame, pose: FloatArray, anchor: int,
                    gate_cov: FloatArray) -> list[tuple[int, Kind, float, float, float]]:
        """Signature matches worth registering: where a match could change something, a
        milestone nearer than the anchor (a handover) or one far back along the path (a loop)."""
        c = self.config
        d_anchor = float(np.hypot(*(self.milestones.pose(anchor)[:2] - pose[:2])))
        out: list[tuple[int, Kind, float, float, float]] = []
        for cand in self.milestones.query(frame.ranges, frame.angle_min, frame.angle_increment,
                                          frame.max_range, predicted_pose=pose,
                                          covariance=gate_cov,
                                          max_candidates=c.matching.candidates + 1):
            if cand.id == anchor or len(out) >= c.matching.candidates:
                continue
            d_cand = float(np.hypot(*(cand.pose[:2] - pose[:2])))
            near_anchor = abs(cand.id - anchor) <= c.loops.separation
            if near_anchor and d_cand + c.loops.switch_margin >= d_anchor:
                continue
            out.append((cand.id, Kind.SIGNATURE, cand.ratio, cand.heading_offset, cand.score))
        return out

    def _register(self, mid: int, kind: Kind, ratio: float, offset: float | None,
                  score: float, points: FloatArray, x: FloatArray, P: FloatArray,
                  doubt: Doubt) -> Match:
        c = self.config
        ms_pose = self.milestones.pose(mid)
        guess = relative(ms_pose, x)
        if offset is not None and P[2, 2] > UNCERTAIN_HEADING**2:
            guess[2] = offset  # an uncertain heading: trust the signature's instead
        reg = register(self.reference(mid), points, guess)
        seed = Seed.PREDICTION
        if kind is Kind.SIGNATURE and offset is not None and not fits(reg, c.registration):
            reg, seed = self._from_node(mid, points, offset, ratio, reg)
        return self._verdict(mid, kind, reg, seed, ratio, score, x, P, doubt)

    def _verdict(self, mid: int, kind: Kind, reg: Registration, seed: Seed, ratio: float,
                 score: float, x: FloatArray, P: FloatArray, doubt: Doubt) -> Match:
        c = self.config
        ms_pose = self.milestones.pose(mid)
        z = compose(ms_pose, reg.pose)
        R = rotate_covariance(reg.covariance, ms_pose[2])
        if kind is Kind.ANCHOR:
            # Only the motion since the last anchor correction may separate prediction and
            # match, so a registration that drags the robot elsewhere (say, towards a person
            # walking along with it) fails the gate.
            spread = R + doubt.anchor_motion
        else:
            # A return to an old milestone disagrees by the drift of both chains since.
            loop_drift = P + doubt.via_anchor + doubt.milestone(mid)
            if seed is not Seed.PREDICTION and pins(reg):
                loop_drift = loop_drift * LOOP_DRIFT_INFLATION
            spread = R + loop_drift
        y = pose_residual(z, x)
        d2 = float(y @ solve(spread, y))
        reason = None
        if not fits(reg, c.registration):
            reason = Reason.POOR_FIT
        elif kind is Kind.SIGNATURE and ratio > c.matching.max_ratio:
            reason = Reason.AMBIGUOUS
        elif d2 > CHI2_3DOF_99:
            reason = Reason.GATE
        return Match(mid, kind, reg, z, R, d2, ratio, score, reason, seed)

    def _from_node(self, mid: int, points: FloatArray, offset: float, ratio: float,
                   reg: Registration) -> tuple[Registration, Seed]:
        """A signature match ICP could not register from the prediction, which may have
        drifted far (a loop after a long way round): a matching signature says the robot
        stands near the node, turned by the offset. Returns the registration to judge."""
        c = self.config
        # Only a clear place and a close fit: this guess ignores the prediction.
        if ratio > c.matching.retry_max_ratio:
            return reg, Seed.PREDICTION
        retry = register(self.reference(mid), points, np.array([0.0, 0.0, offset]))
        if fits(retry, c.registration) and retry.inliers >= c.matching.retry_min_inliers:
            return retry, Seed.NODE
        return reg, Seed.PREDICTION
