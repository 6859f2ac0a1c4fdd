"""Odometry refined by scan registration: each scan against the latest keyframe scan.

Wheel odometry drifts (on the Intel recording it is off by metres after a loop). Before the
filter predicts, the increment since the last scan is refined by registering the scan against a
keyframe (the last scan that was at least ``keyframe_distance`` or ``keyframe_turn`` away), and
the two estimates are fused by their information: where the registration is well constrained it
wins, where it is not (along a featureless corridor) the wheels do. This goes beyond the paper.
"""

from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np

from vmp.config import MotionNoise, RegistrationConfig, ScanOdometryConfig
from vmp.fusion import CHI2_3DOF_99, motion_covariance
from vmp.linalg import inv, solve
from vmp.registration import MIN_POINTS, Reference, fits, fits_explained, register
from vmp.types import FloatArray, compose, inverse, relative, widest_variance

__all__ = ["ScanOdometry"]


# Wheel odometry is calibrated on the way: its distance scale is learned from increments where
# registration pins down the motion along the direction of travel, and its noise from how far
# the wheels disagree with registrations that fit: the median of the squared Mahalanobis
# distance over the last NOISE_MEMORY of them, against chi-square's median for 3 dof, scales
# the motion noise of the configuration up (never down) so the gate and the fusion follow the
# robot's real odometry (fr079's slips in turns several degrees per second; the Intel robot's
# does not).
CALIBRATION_SIGMA = 0.008  # registration sigma along travel needed to learn (m)
CALIBRATION_MEMORY = 50.0  # metres of travel the scale estimate averages over
# Wheels slip in turns: fr079's robot reported 3 degrees where it turned 14 (Kuemmerle's
# relations, scans 783-787) while every registration fit to 1 cm. Beside a registration the
# wheels' heading counts with a slip of this much per scan on top of their noise: in the gate
# on the two's disagreement and in their fusion (where registration sees, it wins). Their
# translation does not: a registration that disagrees with it is more likely fooled by
# something moving with the robot (the office scenario's walker, scans 599-630) than the
# wheels are by the floor. Alone, the wheels count with their noise.
SLIP = np.diag([0.0, 0.0, math.radians(5.0) ** 2])
SLIP.flags.writeable = False
NOISE_MEMORY = 200
CHI2_3DOF_MEDIAN = 2.366
CHI2_3DOF_95 = 7.815
MOUNT_MIN_TURN = math.radians(3.0)  # increments turning less say too little about the mount
MOUNT_FORGET = 0.999  # per turn learned from
MOUNT_SIGMA = 0.01  # the offset is used once known to this (m) ...
MAX_MOUNT = 0.5  # ... and at most this far from the axle (m)
MAX_NOISE_SCALE = 100.0
SEES_XY = 0.05  # a fitting registration this sure in every direction (m) ...
SEES_THETA = math.radians(1.0)  # ... and heading (rad) overrules wheels that disagree, ...
BASELINE_KEYFRAMES = 3  # ... when the keyframe this many back agrees with it
NO_ODOMETRY = np.diag([1.0, 1.0, 1.0])  # a source without odometry: "within a metre"
NO_ODOMETRY.flags.writeable = False


class ScanOdometry:
    """Turn wheel increments into registration-refined increments with covariances."""

    def __init__(self, config: ScanOdometryConfig, registration: RegistrationConfig,
                 noise: MotionNoise, stops_early: bool = False,
                 by_all_points: bool = True) -> None:
        self.config, self.registration, self.noise = config, registration, noise
        # Whether its ICP stops early, where its steps cycle or no longer change the fit
        # (vmp.registration.register's ``stops_early``): a localizer's does; a mapper's runs
        # on, as its maps depend on it.
        self.stops_early = stops_early
        # Whether a registration fits by the share of the scan's points near a keyframe
        # point, on a line or not (the mapper's), or by the share that found a line partner
        # (the localizer's). The share on lines falls with the beams' spacing and the
        # ranges: judged by it, a mapper refused the registrations of a fifth of the scans
        # with every second beam dropped and fell back to the wheels (docs/benchmarks.md,
        # generalise). A localizer riding on the first declares a look-alike 44 m off, turned
        # 178 deg, on ACES cut at 0.35 and 0.4, after the robot drove where the map never
        # saw (all sixteen places it followed were look-alikes then); on the second, none.
        self.by_all_points = by_all_points
        self._key: Reference | None = None
        self._rel = np.zeros(3)  # the last scan's pose in the keyframe's frame
        # The keyframes before it, oldest first, each with its pose in the keyframe's frame:
        # a longer baseline to check a registration that overrules the wheels against.
        self._older: deque[tuple[Reference, FloatArray]] = deque(maxlen=BASELINE_KEYFRAMES)
        self.refined = 0
        self.fallbacks = 0
        self.overruled = 0  # refined increments whose wheels the registration overruled
        self._dist_wheel = 0.0  # travel behind the scale estimate, wheels and registration
        self._dist_reg = 0.0
        self._disagreement: deque[float] = deque(maxlen=NOISE_MEMORY)
        self._ordered: list[float] = []  # the same values, in ascending order
        self.noise_scale = 1.0  # the learned factor on the configured motion noise
        self.tail_scale = 1.0  # ... and on it beside a registration (at least noise_scale)
        # Where the scanner sits on the robot (m, in the robot's frame): odometry moves the
        # robot, registration the scanner; turning on the spot, a scanner ahead of the axle
        # swings sideways. Learned from turns (normal equations, forgetting).
        self.mount = np.zeros(2)
        self._mount_normal = np.zeros((2, 2))
        self._mount_rhs = np.zeros(2)
        # The last scan's increment as a fitting registration measured it (its frame), else
        # None: what the scan stamps' delay is learned from (vmp.latency).
        self.registered: FloatArray | None = None

    @property
    def scale(self) -> float:
        """The learned factor from wheel distance to true distance (1 until learned)."""
        if self._dist_wheel < 2.0:
            return 1.0
        return self._dist_reg / self._dist_wheel

    def increment(self, points: FloatArray,
                  wheel: FloatArray | None) -> tuple[FloatArray, FloatArray]:
        """The increment since the last scan (its frame) and its covariance.

        ``points`` are the scan's hit end points in its own frame; ``wheel`` is the wheel
        odometry increment, or None when the source has no odometry (then registration alone
        moves the robot, from a standstill guess that it is free to overrule).
        """
        c = self.config
        self.registered = None
        if wheel is None:
            wheel = np.zeros(3)
            q_wheel = NO_ODOMETRY
        else:
            base = np.array([wheel[0] * self.scale, wheel[1] * self.scale, wheel[2]])
            wheel = base.copy()
            wheel[:2] += _mount_matrix(base[2]) @ self.mount  # the scanner's increment
            q_wheel = motion_covariance(wheel, self.noise) * self.noise_scale
        if not c.enabled or len(points) < MIN_POINTS:
            return wheel, q_wheel
        if self._key is None:
            self._new_key(points)
            return wheel, q_wheel
        guess = compose(self._rel, wheel)
        # Without corner matching: between keyframes a few decimetres apart its sampling bias
        # (a corner is hit at a slightly different place by every scan) adds up along the path.
        reg = register(self._key, points, guess, corners=False, stops_early=self.stops_early)
        u_reg = relative(self._rel, reg.pose)
        d = u_reg - wheel
        d[2] = (d[2] + math.pi) % (2 * math.pi) - math.pi
        # A registration that disagrees with the wheels beyond a slip is not trusted unless
        # it sees every direction: something moved with the robot, or ICP fell into another
        # minimum; where it sees everything, the wheels are wrong (below).
        fit = (fits_explained(self._key, reg, points, self.registration) if self.by_all_points
               else fits(reg, self.registration))
        if fit:
            self.registered = u_reg
        d2 = float(d @ solve(q_wheel + reg.covariance, d))
        if fit and q_wheel[0, 0] < 1.0:
            self._learn_noise(d2)
            self._learn_mount(wheel, u_reg, q_wheel + reg.covariance)
        q_slip = q_wheel * (self.tail_scale / self.noise_scale) + SLIP
        disagree = float(d @ solve(q_slip + reg.covariance, d)) > CHI2_3DOF_99
        overrule = (fit and disagree and _sees_all(reg.covariance)
                    and self._confirmed(points, guess, reg.pose))
        if not fit or (disagree and not overrule):
            self.fallbacks += 1
            # The scan's pose in the keyframe is now the wheels' guess, not a registration:
            # measured against it, the next scans would disagree by the wheels' error again
            # and again (fr079: the robot stopping while the wheels lag; 564 of 2,000 scans
            # fell back, most of them this way). The scan becomes the keyframe.
            self._new_key(points, guess)
            return wheel, q_wheel
        self.refined += 1
        if overrule:
            # Wheels that disagree beyond a slip with a registration that sees every
            # direction, confirmed a metre back, are wrong: on fr079 the wheels reported
            # driving ahead where the robot backed up (scans 1400-1426, the Kuemmerle
            # relations agree with the scans), and
            # where scan odometry fell back to the wheels the registration was nearer the
            # truth in 28 of 31 relations (0.2 to 1.0 m against 1 to 7 cm).
            self.overruled += 1
            u, q = u_reg, reg.covariance
        else:
            if q_wheel[0, 0] < 1.0:
                self._learn_scale(wheel, u_reg, reg.covariance)
            # Fuse the two increments by information; registration constrains what it sees,
            # the wheels (as they may slip) the rest.
            info_w = inv(q_slip)
            info_r = inv(reg.covariance)
            q = inv(info_w + info_r)
            u = wheel + q @ (info_r @ d)
        self._rel = compose(self._rel, u)
        if (np.hypot(self._rel[0], self._rel[1]) >= c.keyframe_distance
                or abs(self._rel[2]) >= c.keyframe_turn):
            self._new_key(points, self._rel)
        return u, q

    def _learn_noise(self, d2: float) -> None:
        """Keep the disagreement of a fitting registration (with the noise as it was scaled
        then); rescale the motion noise to make the recent median chi-square's, and the
        noise the wheels count with beside a registration to make the 95th percentile
        chi-square's (the tail where they slip)."""
        # Kept sorted as they come and go: sorted anew each scan, and clipped by NumPy, they
        # would take 0.19 s of scan odometry's 0.53 s in the Intel part's tracked second half
        # (pyinstrument).
        if len(self._disagreement) == NOISE_MEMORY:
            del self._ordered[bisect.bisect_left(self._ordered, self._disagreement[0])]
        value = d2 * self.noise_scale  # as against the configured noise
        self._disagreement.append(value)
        bisect.insort(self._ordered, value)
        if len(self._ordered) >= NOISE_MEMORY // 4:
            median = _percentile(self._ordered, 0.5)
            tail = _percentile(self._ordered, 0.95)
            self.noise_scale = min(max(median / CHI2_3DOF_MEDIAN, 1.0), MAX_NOISE_SCALE)
            self.tail_scale = min(max(tail / CHI2_3DOF_95, self.noise_scale), MAX_NOISE_SCALE)

    def _learn_mount(self, wheel: FloatArray, u_reg: FloatArray, cov: FloatArray) -> None:
        """Refine the scanner's mounting offset from a turn's registered increment: the
        scanner's increment is ``inverse(T) (+) base (+) T`` for a mount ``T``, whose
        translation part is linear in the offset (:func:`_mount_matrix`)."""
        if abs(wheel[2]) < MOUNT_MIN_TURN:
            return
        M = _mount_matrix(wheel[2])
        base_xy = wheel[:2] - M @ self.mount  # the increment of the robot itself
        W = np.linalg.inv(cov[:2, :2])
        self._mount_normal = self._mount_normal * MOUNT_FORGET + M.T @ W @ M
        self._mount_rhs = self._mount_rhs * MOUNT_FORGET + M.T @ W @ (u_reg[:2] - base_xy)
        if np.linalg.eigvalsh(self._mount_normal)[0] * MOUNT_SIGMA**2 < 1.0:
            return  # not yet pinned to MOUNT_SIGMA
        offset = np.linalg.solve(self._mount_normal, self._mount_rhs)
        norm = float(np.hypot(*offset))
        self.mount = offset if norm <= MAX_MOUNT else offset * (MAX_MOUNT / norm)

    def _learn_scale(self, wheel: FloatArray, u_reg: FloatArray, cov: FloatArray) -> None:
        """Accumulate wheel and registered distance where registration sees along travel."""
        dist = float(np.hypot(wheel[0], wheel[1]))
        if dist < 0.01:
            return
        along = wheel[:2] / dist
        if float(along @ cov[:2, :2] @ along) > CALIBRATION_SIGMA**2:
            return
        raw = dist / self.scale  # what the wheels said before scaling
        forget = max(0.0, 1.0 - dist / CALIBRATION_MEMORY)
        self._dist_wheel = self._dist_wheel * forget + raw
        self._dist_reg = self._dist_reg * forget + float(along @ u_reg[:2])

    def _new_key(self, points: FloatArray, pose: FloatArray | None = None) -> None:
        """The scan becomes the keyframe; ``pose`` is its pose in the keyframe before (None:
        unknown, the history of keyframes starts again)."""
        try:
            key = Reference(points)
        except ValueError:
            return
        if self._key is not None and pose is not None:
            back = inverse(pose)
            self._older = deque(((ref, compose(back, p)) for ref, p in self._older),
                                maxlen=BASELINE_KEYFRAMES)
            self._older.append((self._key, back))
        else:
            self._older.clear()
        self._key = key
        self._rel = np.zeros(3)

    def _confirmed(self, points: FloatArray, wheels: FloatArray, scans: FloatArray) -> bool:
        """Whether the oldest keyframe kept, a longer way back, agrees with the registration
        (the scan at ``scans`` in the keyframe's frame) rather than with the wheels (at
        ``wheels``): registered from the wheels' pose it must fit and end nearer the
        registration's. Something moving along with the robot (the office scenario's walker)
        fools a registration against the last keyframe, 0.3 m back; a metre back, the walls
        it passed outweigh it."""
        if not self._older:
            return False
        ref, pose = self._older[0]
        back = inverse(pose)
        at_wheels, at_scans = compose(back, wheels), compose(back, scans)
        check = register(ref, points, at_wheels, corners=False, stops_early=self.stops_early)
        if not fits(check, self.registration):
            return False
        to_scans = relative(at_scans, check.pose)
        to_wheels = relative(at_wheels, check.pose)
        return bool(math.hypot(to_scans[0], to_scans[1]) + abs(to_scans[2])
                    < math.hypot(to_wheels[0], to_wheels[1]) + abs(to_wheels[2]))


def _percentile(ordered: list[float], q: float) -> float:
    """``numpy.percentile(values, 100 q)`` (linear interpolation, to the last bit) of values
    given in ascending order. Once per scan on 200 values numpy's takes 40 microseconds, most
    of it the call's own overhead: a sixth of scan odometry's time outside ICP."""
    n = len(ordered)
    at = (n - 1) * q
    below = math.floor(at)
    if below >= n - 1:
        return ordered[-1]
    a, b = ordered[below], ordered[below + 1]
    share = at - below
    # numpy's lerp: from the nearer end, so that share 1 gives b exactly.
    return b - (b - a) * (1.0 - share) if share >= 0.5 else a + (b - a) * share


def _sees_all(cov: FloatArray) -> bool:
    """Whether a registration's covariance pins every direction to :data:`SEES_XY` and
    :data:`SEES_THETA`."""
    return bool(math.sqrt(widest_variance(cov)) <= SEES_XY
                and math.sqrt(cov[2, 2]) <= SEES_THETA)


def _mount_matrix(turn: float) -> FloatArray:
    """``(2, 2)``: what a scanner mounted at offset ``o`` from the robot adds to the robot's
    translation over an increment turning by ``turn``: ``(R(turn) - I) o``."""
    c, s = math.cos(turn), math.sin(turn)
    return np.array([[c - 1.0, -s], [s, c - 1.0]])
