"""Odometry refined by scan registration: each scan against the latest keyframe scan.

Wheel odometry drifts (on the Intel recording it is off by metres after a loop). Before the
filter predicts, the increment since the last scan is refined by registering the scan against a
keyframe (the last scan that was at least ``keyframe_distance`` or ``keyframe_turn`` away), and
the two estimates are fused by their information: where the registration is well constrained it
wins, where it is not (along a featureless corridor) the wheels do. This goes beyond the paper.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from vmp.fusion import MotionNoise, motion_covariance
from vmp.registration import Reference, RegistrationConfig, register
from vmp.types import FloatArray, compose, relative, transform_points

__all__ = ["ScanOdometry", "ScanOdometryConfig", "motion_covariance"]


@dataclass(frozen=True)
class ScanOdometryConfig:
    enabled: bool = True
    keyframe_distance: float = 0.3  # m
    keyframe_turn: float = math.radians(10.0)
    max_rms: float = 0.05  # m; a worse fit falls back to wheel odometry
    min_inliers: float = 0.5
    min_points: int = 20
    # A registration whose increment disagrees with the wheels beyond this (squared
    # Mahalanobis, 3 dof 99 %) is not trusted: something moved with the robot.
    gate: float = 11.34
    # Wheel odometry is calibrated on the way: its distance scale is learned from increments
    # where registration pins down the motion along the direction of travel.
    calibrate: bool = True
    calibration_sigma: float = 0.008  # registration sigma along travel needed to learn (m)
    calibration_memory: float = 50.0  # metres of travel the scale estimate averages over
    # The reference a scan registers against: the latest keyframe and the ones before it, all
    # in the latest's frame. One sparse scan rarely samples a rack upright's side or a pallet's
    # end well enough to see motion along an aisle; a few keyframes together do.
    submap_keyframes: int = 1  # 6 halves the warehouse ATE but breaks the corridor (open)
    # Registration here is checked against the wheels (``gate``) and fused with them by
    # information, so it may keep a weaker constraint than a milestone match (the rack uprights
    # seen along a one-sided aisle): the registration's ``min_constraint`` for scan odometry.
    min_constraint: float | None = None  # 4.0 helps the warehouse, costs the office
    # Point-to-point matching of corner points (RegistrationConfig.corner_weight) for scan
    # odometry. Off: between keyframes a few decimetres apart its sampling bias (a corner is
    # hit at a slightly different place by every scan) adds up along the path. On (0.5), the
    # median ATE over the first 4 corridor seeds went from 10.8 to 20.1 cm, over 8 warehouse
    # seeds from 5.0 to 5.6 cm (python bench/seeds.py warehouse corridor --config FILE, FILE
    # holding this key). Milestone matches keep it: their errors do not add up.
    corner_weight: float = 0.0
    # The wheel noise model (MotionNoise) is a floor, not the truth: a log with one scan per
    # half metre and several degrees of wheel error per step (GMapping's keyframes) would see
    # most good registrations refused by ``gate`` and the wheels win. So the model's variance
    # is scaled up, translation and heading apart, by the factor that makes the median
    # normalised disagreement between wheels and fitting registrations what a chi-square
    # says it should be, over the last ``adapt_window`` registrations (refused ones too, or
    # the estimate would only see what it already allows). The median ignores the minority
    # of wrong registrations. Never below 1; applied once ``adapt_min_samples`` are in.
    adapt_noise: bool = False  # opt-in: on, it costs the dense Intel run (0.029 -> 0.15 m)
    adapt_window: int = 100
    adapt_min_samples: int = 20
    adapt_max_scale: float = 1e4


_CHI2_MEDIAN_1DOF = 0.4549
_CHI2_MEDIAN_2DOF = 1.3863


def _variance_scale(d: FloatArray, q: FloatArray, r: FloatArray, target: float) -> float:
    """The factor ``k`` with ``d' (k q + r)^-1 d = target`` (0 when ``r`` alone explains ``d``).

    ``q`` is positive definite; both are whitened by ``q`` and diagonalised together, so the
    left side is ``sum_j e_j^2 / (k + r_j)``, decreasing in ``k``: a bisection in log ``k``.
    """
    L = np.linalg.cholesky(q)
    w = np.linalg.solve(L, d)
    rw = np.linalg.solve(L, np.linalg.solve(L, r).T)  # L^-1 r L^-T
    vals, vecs = np.linalg.eigh(0.5 * (rw + rw.T))
    e2 = (vecs.T @ w) ** 2
    vals = np.maximum(vals, 0.0)

    def nis(k: float) -> float:
        return float(np.sum(e2 / np.maximum(k + vals, 1e-300)))

    if nis(0.0) <= target:
        return 0.0
    lo, hi = -6.0, 6.0  # log10 k
    if nis(10.0**hi) > target:
        return 10.0**hi
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if nis(10.0**mid) > target:
            lo = mid
        else:
            hi = mid
    return 10.0 ** (0.5 * (lo + hi))


class ScanOdometry:
    """Turn wheel increments into registration-refined increments with covariances."""

    def __init__(self, config: ScanOdometryConfig, registration: RegistrationConfig,
                 noise: MotionNoise) -> None:
        registration = replace(registration, corner_weight=config.corner_weight)
        if config.min_constraint is not None:
            registration = replace(registration, min_constraint=config.min_constraint)
        self.config, self.registration, self.noise = config, registration, noise
        self._key: Reference | None = None
        self._rel = np.zeros(3)  # the last scan's pose in the keyframe's frame
        self._pose = np.zeros(3)  # the last scan's pose, integrated from the increments
        self._keys: list[tuple[FloatArray, FloatArray]] = []  # recent keyframes: pose, points
        self.refined = 0
        self.fallbacks = 0
        self._dist_wheel = 0.0  # travel behind the scale estimate, wheels and registration
        self._dist_reg = 0.0
        # Per fitting registration: the wheel-noise scale it alone would call for, xy and theta.
        self._k_xy: deque[float] = deque(maxlen=config.adapt_window)
        self._k_th: deque[float] = deque(maxlen=config.adapt_window)
        self.noise_scale = np.ones(2)  # the current factors on the model's xy and theta variance

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
        if wheel is None:
            wheel = np.zeros(3)
            q_wheel = np.diag([1.0, 1.0, 1.0])  # no odometry: "somewhere within a metre"
        else:
            wheel = np.array([wheel[0] * self.scale, wheel[1] * self.scale, wheel[2]])
            q_wheel = motion_covariance(wheel, self.noise)
            q_wheel = q_wheel * np.array([self.noise_scale[0], self.noise_scale[0],
                                          self.noise_scale[1]])
        if not c.enabled or len(points) < c.min_points:
            return wheel, q_wheel
        if self._key is None:
            self._new_key(points)
            return wheel, q_wheel
        guess = compose(self._rel, wheel)
        reg = register(self._key, points, guess, self.registration)
        u_reg = relative(self._rel, reg.pose)
        d = u_reg - wheel
        d[2] = (d[2] + math.pi) % (2 * math.pi) - math.pi
        fits = np.isfinite(reg.rms) and reg.rms <= c.max_rms and reg.inliers >= c.min_inliers
        if fits and c.adapt_noise and q_wheel[0, 0] < 1.0:
            self._adapt(d, q_wheel, reg.covariance)
        if not fits or float(d @ np.linalg.solve(q_wheel + reg.covariance, d)) > c.gate:
            self.fallbacks += 1
            u, q = wheel, q_wheel
        else:
            self.refined += 1
            if q_wheel[0, 0] < 1.0:
                self._learn_scale(wheel, u_reg, reg.covariance)
            # Fuse the two increments by information; registration constrains what it sees.
            info_w = np.linalg.inv(q_wheel)
            info_r = np.linalg.inv(reg.covariance)
            q = np.linalg.inv(info_w + info_r)
            u = wheel + q @ (info_r @ d)
        self._rel = compose(self._rel, u)
        self._pose = compose(self._pose, u)
        if (np.hypot(self._rel[0], self._rel[1]) >= c.keyframe_distance
                or abs(self._rel[2]) >= c.keyframe_turn):
            self._new_key(points)
        return u, q

    def _adapt(self, d: FloatArray, q_wheel: FloatArray, r: FloatArray) -> None:
        """Record what scale of the wheel noise this disagreement calls for; update the scale."""
        c = self.config
        base = q_wheel / np.array([self.noise_scale[0], self.noise_scale[0],
                                   self.noise_scale[1]])
        self._k_xy.append(_variance_scale(d[:2], base[:2, :2], r[:2, :2], _CHI2_MEDIAN_2DOF))
        self._k_th.append(_variance_scale(d[2:], base[2:, 2:], r[2:, 2:], _CHI2_MEDIAN_1DOF))
        if len(self._k_xy) >= c.adapt_min_samples:
            self.noise_scale = np.clip([np.median(self._k_xy), np.median(self._k_th)],
                                       1.0, c.adapt_max_scale)

    def _learn_scale(self, wheel: FloatArray, u_reg: FloatArray, cov: FloatArray) -> None:
        """Accumulate wheel and registered distance where registration sees along travel."""
        dist = float(np.hypot(wheel[0], wheel[1]))
        if not self.config.calibrate or dist < 0.01:
            return
        along = wheel[:2] / dist
        if float(along @ cov[:2, :2] @ along) > self.config.calibration_sigma**2:
            return
        raw = dist / self.scale  # what the wheels said before scaling
        forget = max(0.0, 1.0 - dist / self.config.calibration_memory)
        self._dist_wheel = self._dist_wheel * forget + raw
        self._dist_reg = self._dist_reg * forget + float(along @ u_reg[:2])

    def _new_key(self, points: FloatArray) -> None:
        keys = [*self._keys[-(self.config.submap_keyframes - 1):], (self._pose.copy(), points)] \
            if self.config.submap_keyframes > 1 else [(self._pose.copy(), points)]
        parts = [transform_points(relative(self._pose, pose), pts) for pose, pts in keys]
        try:
            self._key = Reference(np.concatenate(parts), self.registration)
            self._rel = np.zeros(3)
            self._keys = keys
        except ValueError:
            pass
