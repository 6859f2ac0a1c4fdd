"""The fusion filter: an extended Kalman filter on (x, y, theta), built on filterpy.

It predicts from odometry increments, with noise that grows with the distance driven and the
angle turned, and corrects from pose measurements (a milestone pose composed with a registered
relative pose). filterpy subtracts residuals plainly; here the heading residual is wrapped, and
theta is wrapped again after every update.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from vmp.config import MotionNoise
from vmp.linalg import solve
from vmp.types import FloatArray, compose, rotate_covariance, wrap_angle

__all__ = ["CHI2_3DOF_99", "PoseFilter", "motion_covariance", "pose_residual"]

CHI2_3DOF_99 = 11.34


# Per step, however short, the odometry is this uncertain (m, rad).
FLOOR_XY = 0.001
FLOOR_THETA = math.radians(0.05)


def motion_covariance(u: FloatArray, noise: MotionNoise) -> FloatArray:
    """Covariance of an odometry increment ``u`` in its own (start) frame."""
    dist = float(np.hypot(u[0], u[1]))
    turn = abs(float(u[2]))
    var_xy = noise.trans_per_m**2 * dist + FLOOR_XY**2
    var_th = noise.rot_per_m**2 * dist + noise.rot_per_rad**2 * turn + FLOOR_THETA**2
    return np.diag([var_xy, var_xy, var_th])


def pose_residual(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a - b`` with the heading difference wrapped to [-pi, pi)."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    d[2] = wrap_angle(d[2])
    return d


class _OdometryEKF(ExtendedKalmanFilter):
    """filterpy's EKF with the motion model ``x (+) u``."""

    def predict_x(self, u: FloatArray = 0) -> None:
        x = self.x
        c, s = np.cos(x[2]), np.sin(x[2])
        self.F = np.array([[1.0, 0.0, -s * u[0] - c * u[1]],
                           [0.0, 1.0, c * u[0] - s * u[1]],
                           [0.0, 0.0, 1.0]])
        self.x = compose(x, u)


class PoseFilter:
    """EKF of the scanner pose in the map frame."""

    def __init__(self, pose: FloatArray, covariance: FloatArray,
                 noise: MotionNoise | None = None) -> None:
        self.noise = noise or MotionNoise()
        self._ekf = _OdometryEKF(dim_x=3, dim_z=3)
        self._ekf.x = np.asarray(pose, dtype=np.float64).copy()
        self._ekf.P = np.asarray(covariance, dtype=np.float64).copy()

    @property
    def pose(self) -> FloatArray:
        return self._ekf.x

    @property
    def covariance(self) -> FloatArray:
        return self._ekf.P

    def set_pose(self, pose: FloatArray) -> None:
        """Move the estimate without changing its uncertainty (after the map moved under it)."""
        self._ekf.x = np.asarray(pose, dtype=np.float64).copy()

    def predict(self, u: FloatArray, covariance: FloatArray | None = None) -> None:
        """Move by the increment ``u`` (scanner frame) and grow the covariance.

        ``covariance`` is the increment's, in the scanner frame; without it the motion noise
        model gives one that grows with the distance driven and the angle turned.
        """
        u = np.asarray(u, dtype=np.float64)
        if covariance is None:
            covariance = motion_covariance(u, self.noise)
        self._ekf.Q = rotate_covariance(covariance, self._ekf.x[2])
        self._ekf.predict(u=u)
        self._ekf.x[2] = wrap_angle(self._ekf.x[2])

    def mahalanobis2(self, z: FloatArray, R: FloatArray) -> float:
        """Squared Mahalanobis distance of a pose measurement from the prediction."""
        y = pose_residual(z, self._ekf.x)
        S = self._ekf.P + R
        return float(y @ solve(S, y))

    def update(self, z: FloatArray, R: FloatArray) -> FloatArray:
        """Correct with a pose measurement ``z`` of covariance ``R``; returns the pose change."""
        before = self._ekf.x.copy()
        self._ekf.update(np.asarray(z, dtype=np.float64), HJacobian=lambda x: np.eye(3),
                         Hx=lambda x: x, R=np.asarray(R, dtype=np.float64),
                         residual=pose_residual)
        self._ekf.x[2] = wrap_angle(self._ekf.x[2])
        self._ekf.P = 0.5 * (self._ekf.P + self._ekf.P.T)
        return pose_residual(self._ekf.x, before)
