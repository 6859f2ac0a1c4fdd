"""Pose algebra on SE(2) and the scan frame that every source yields.

A pose is ``(x, y, theta)`` in metres and radians with theta wrapped to [-pi, pi).
The pose functions take a single pose of shape ``(3,)`` or a stack of shape ``(..., 3)`` and
broadcast like NumPy; the covariance functions (first-order propagation through compose and
inverse) take single poses. This module imports nothing of the project.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = [
    "MAX_BEAMS",
    "BeamGeometry",
    "ScanFrame",
    "check_beams",
    "compose",
    "compose_covariance",
    "interpolate_pose",
    "inverse",
    "inverse_covariance",
    "relative",
    "rotate_covariance",
    "rotation_matrix",
    "transform_points",
    "widest_direction",
    "widest_variance",
    "wrap_angle",
]


def wrap_angle(theta: ArrayLike) -> FloatArray:
    """Wrap angles to [-pi, pi)."""
    t = np.asarray(theta, dtype=np.float64)
    return (t + np.pi) % (2.0 * np.pi) - np.pi


def _wrap1(theta: float) -> float:
    """:func:`wrap_angle` of one angle. The pose operations below take this path for single
    poses (about 90,000 calls mapping the Intel part), in Python floats: a call through 0-d
    arrays costs 8-10 microseconds, through NumPy scalars 2, and compose costs 1 this way
    against 3 through scalars (the same bits as the arrays' path: IEEE arithmetic, and
    NumPy's cosine, sine and remainder agree with Python's; tested). A heading that is not
    finite takes the arrays' path, where it gives NaNs rather than an error."""
    return (theta + math.pi) % (2.0 * math.pi) - math.pi


def _as_poses(p: ArrayLike) -> FloatArray:
    a = np.asarray(p, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise ValueError(f"a pose has shape (..., 3), got {a.shape}")
    return a


def rotation_matrix(theta: ArrayLike) -> FloatArray:
    """Rotation matrices ``(..., 2, 2)`` for angles ``(...)``."""
    t = np.asarray(theta, dtype=np.float64)
    c, s = np.cos(t), np.sin(t)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def compose(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``a (+) b``: pose ``b``, given in the frame of ``a``, in the frame ``a`` is given in."""
    a, b = _as_poses(a), _as_poses(b)
    if a.ndim == 1 and b.ndim == 1 and math.isfinite(a[2]):
        (ax, ay, at), (bx, by, bt) = a.tolist(), b.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([ax + c * bx - s * by, ay + s * bx + c * by, _wrap1(at + bt)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap_angle(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: ArrayLike) -> FloatArray:
    """``(-) a``: the pose of the outer frame seen from ``a``, so ``a (+) inverse(a) = 0``."""
    a = _as_poses(a)
    if a.ndim == 1 and math.isfinite(a[2]):
        ax, ay, at = a.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([-c * ax - s * ay, s * ax - c * ay, _wrap1(-at)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap_angle(-a[..., 2])], axis=-1)


def rotate_covariance(cov: ArrayLike, theta: float) -> FloatArray:
    """A pose covariance ``(3, 3)`` given in a frame turned by ``theta``, in the outer frame
    (the heading's variance is unchanged)."""
    c, s = math.cos(theta), math.sin(theta)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot @ np.asarray(cov, dtype=np.float64) @ rot.T


def widest_variance(cov: ArrayLike) -> float:
    """The largest variance of a pose covariance's position (m^2): the larger eigenvalue of
    its 2x2 block, in closed form (LAPACK's call costs more than the arithmetic, and the
    mapper asks several times a scan)."""
    a, b, d = float(cov[0][0]), 0.5 * (float(cov[0][1]) + float(cov[1][0])), float(cov[1][1])
    return max(0.5 * (a + d) + math.hypot(0.5 * (a - d), b), 0.0)  # rounding: never below 0


def widest_direction(cov: ArrayLike) -> FloatArray:
    """The unit direction ``(2,)`` of the largest variance of a pose covariance's position
    (:func:`widest_variance`): the eigenvector of its 2x2 block, in closed form."""
    a, b, d = float(cov[0][0]), 0.5 * (float(cov[0][1]) + float(cov[1][0])), float(cov[1][1])
    angle = 0.5 * math.atan2(2.0 * b, a - d)
    return np.array([math.cos(angle), math.sin(angle)])


def compose_covariance(a: ArrayLike, cov_a: ArrayLike, b: ArrayLike, cov_b: ArrayLike
                       ) -> FloatArray:
    """Covariance ``(3, 3)`` of ``a (+) b`` for independent poses ``a`` and ``b`` (first order).

    ``cov_b`` is in ``a``'s frame; the result is in the frame ``a`` is given in, so ``b``'s
    spread turns with ``a``'s heading and ``a``'s heading doubt swings ``b`` about ``a``.
    """
    a, b = _as_poses(a), _as_poses(b)
    c, s = math.cos(a[2]), math.sin(a[2])
    ja = np.array([[1.0, 0.0, -s * b[0] - c * b[1]],
                   [0.0, 1.0, c * b[0] - s * b[1]],
                   [0.0, 0.0, 1.0]])
    out = ja @ np.asarray(cov_a, dtype=np.float64) @ ja.T + rotate_covariance(cov_b, a[2])
    return 0.5 * (out + out.T)


def inverse_covariance(a: ArrayLike, cov_a: ArrayLike) -> FloatArray:
    """Covariance ``(3, 3)`` of ``inverse(a)`` (in ``a``'s frame) given ``a``'s (first order)."""
    a = _as_poses(a)
    c, s = math.cos(a[2]), math.sin(a[2])
    inv = inverse(a)
    j = np.array([[-c, -s, inv[1]], [s, -c, -inv[0]], [0.0, 0.0, -1.0]])
    out = j @ np.asarray(cov_a, dtype=np.float64) @ j.T
    return 0.5 * (out + out.T)


def relative(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``(-) a (+) b``: pose ``b`` expressed in the frame of pose ``a``."""
    a, b = _as_poses(a), _as_poses(b)
    if a.ndim == 1 and b.ndim == 1 and math.isfinite(a[2]):
        (ax, ay, at), (bx, by, bt) = a.tolist(), b.tolist()
        c, s = math.cos(at), math.sin(at)
        dx, dy = bx - ax, by - ay
        return np.array([c * dx + s * dy, -s * dx + c * dy, _wrap1(bt - at)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return np.stack(
        [c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1
    )


def transform_points(pose: ArrayLike, points: ArrayLike) -> FloatArray:
    """Map points ``(..., N, 2)`` given in the frame of ``pose`` to the outer frame.

    ``pose`` has shape ``(..., 3)``; its leading dimensions broadcast against the points'.
    """
    p = _as_poses(pose)
    pts = np.asarray(points, dtype=np.float64)
    c = np.cos(p[..., 2])[..., None]
    s = np.sin(p[..., 2])[..., None]
    x = p[..., 0, None] + c * pts[..., 0] - s * pts[..., 1]
    y = p[..., 1, None] + s * pts[..., 0] + c * pts[..., 1]
    return np.stack([x, y], axis=-1)



def interpolate_pose(stamps: ArrayLike, poses: ArrayLike, t: float) -> FloatArray | None:
    """The pose at time ``t`` from poses ``(N, 3)`` at sorted ``stamps``: linear between the
    two around it (heading the short way round), the nearest outside them, None without any."""
    st = np.asarray(stamps, dtype=np.float64)
    ps = np.asarray(poses, dtype=np.float64)
    if st.size == 0:
        return None
    i = int(np.searchsorted(st, t))
    if i == 0:
        return ps[0].copy()
    if i == st.size:
        return ps[-1].copy()
    t0, t1 = st[i - 1], st[i]
    f = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
    a, b = ps[i - 1], ps[i]
    out = a + f * (b - a)
    out[2] = float(wrap_angle(a[2] + f * float(wrap_angle(b[2] - a[2]))))
    return out


@dataclass(frozen=True)
class BeamGeometry:
    """The beams of a laser scanner: count, first angle, increment (rad), range limit (m).

    Every scan of one source, and so of one map, shares them.
    """

    num_beams: int
    angle_min: float
    angle_increment: float
    max_range: float

    @property
    def angles(self) -> FloatArray:
        """Beam angles in the scanner frame (radians)."""
        return beam_angles(self.num_beams, self.angle_min, self.angle_increment)

    @property
    def field_of_view(self) -> float:
        """Angle covered by the beams: the span between first and last plus one step."""
        return float(abs(self.angle_increment) * self.num_beams)

    @property
    def full_circle(self) -> bool:
        return self.field_of_view >= 2 * np.pi - 1e-6

    def same_beams(self, other: BeamGeometry) -> bool:
        """Whether ``other`` has these beams (its range limit may differ)."""
        return (self.num_beams, self.angle_min, self.angle_increment) == (
            other.num_beams, other.angle_min, other.angle_increment)

    def describe(self) -> str:
        """The beams in words, angles in degrees."""
        return (f"{self.num_beams} beams from {math.degrees(self.angle_min):.2f} deg every "
                f"{math.degrees(self.angle_increment):.3f} deg")


def _readonly(a: ArrayLike, dtype: type = np.float64) -> FloatArray:
    out = np.array(a, dtype=dtype, copy=True)
    out.flags.writeable = False
    return out


# The most beams a sweep may hold: more than any 2D scanner measures (a few thousand).
MAX_BEAMS = 10_000


def check_beams(num_beams: int, angle_min: float, angle_increment: float,
                max_range: float) -> None:
    """:class:`ValueError`, saying what is wrong, unless these are a 2D scanner's beams: at
    most :data:`MAX_BEAMS`, finite angles, a non-zero step, at most a full turn from the first
    beam to the last, a positive finite range limit."""
    if not 1 <= num_beams <= MAX_BEAMS:
        raise ValueError(f"{num_beams} beams, expected 1 to {MAX_BEAMS:,}")
    if not (math.isfinite(angle_min) and abs(angle_min) <= 2 * math.pi):
        raise ValueError(f"first beam at {angle_min!r} rad, expected a finite angle within "
                         "+-2 pi")
    if not (math.isfinite(angle_increment) and angle_increment != 0):
        raise ValueError(f"angle step {angle_increment!r} rad, expected finite and non-zero")
    span = abs(angle_increment) * (num_beams - 1)
    if span > 2 * math.pi + 1e-6:
        raise ValueError(f"{num_beams} beams every {math.degrees(angle_increment):.4g} deg "
                         f"span {math.degrees(span):.4g} deg, more than a full turn")
    if not (math.isfinite(max_range) and max_range > 0):
        raise ValueError(f"range limit {max_range!r} m, expected positive and finite")


@dataclass(frozen=True, eq=False)
class ScanFrame:
    """One laser scan with the odometry (and, in simulation, the true pose) at its time.

    ``ranges`` holds one distance per beam in metres. A beam without a return (nothing within
    ``max_range``, or the sensor reported no echo) is marked explicitly: its range is
    ``+inf``. It bounds free space but is not an obstacle. Finite ranges are never NaN,
    negative or beyond ``max_range``; sources convert their own conventions (zero, max-range
    codes) when they build a frame.

    Poses are those of the scanner: ``odom`` in the odometry frame, ``true_pose`` in the
    world frame (only a simulator knows it).
    """

    stamp: float
    ranges: FloatArray
    angle_min: float
    angle_increment: float
    max_range: float
    odom: FloatArray | None = None
    true_pose: FloatArray | None = None
    index: int = field(default=-1)
    # How far a beam without a return proves free space: None as far as the mapper allows;
    # 0 not at all, for a sensor whose no-return reading also means "could not measure".
    no_return_free: float | None = None

    def __post_init__(self) -> None:
        r = _readonly(self.ranges)
        if r.ndim != 1 or r.size == 0:
            raise ValueError(f"ranges must be a non-empty 1-D array, got shape {r.shape}")
        check_beams(r.size, self.angle_min, self.angle_increment, self.max_range)
        if np.isnan(r).any():
            raise ValueError("ranges hold NaN: mark beams without a return as +inf")
        if (r <= 0).any():
            raise ValueError("ranges must be positive (mark beams without a return as +inf)")
        finite = np.isfinite(r)
        if (r[finite] > self.max_range).any():
            raise ValueError(f"finite ranges must not exceed max_range={self.max_range}")
        if self.no_return_free is not None and not self.no_return_free >= 0:
            raise ValueError(f"no_return_free must be >= 0, got {self.no_return_free}")
        object.__setattr__(self, "ranges", r)
        for name in ("odom", "true_pose"):
            v = getattr(self, name)
            if v is not None:
                p = _readonly(v)
                if p.shape != (3,) or not np.isfinite(p).all():
                    raise ValueError(f"{name} must be a finite (x, y, theta), got {v!r}")
                object.__setattr__(self, name, p)

    @property
    def num_beams(self) -> int:
        return int(self.ranges.size)

    @property
    def geometry(self) -> BeamGeometry:
        """The beams of this scan."""
        return BeamGeometry(self.num_beams, self.angle_min, self.angle_increment, self.max_range)

    @property
    def angles(self) -> FloatArray:
        """Beam angles in the scanner frame (radians)."""
        return beam_angles(self.ranges.size, self.angle_min, self.angle_increment)

    @property
    def angle_max(self) -> float:
        return float(self.angle_min + self.angle_increment * (self.ranges.size - 1))

    @property
    def field_of_view(self) -> float:
        """Angle covered by the beams: the span between first and last plus one step."""
        return self.geometry.field_of_view

    @property
    def returned(self) -> NDArray[np.bool_]:
        """True for beams that hit something within ``max_range``."""
        return np.isfinite(self.ranges)

    def free_ranges(self) -> FloatArray:
        """Extent of free space along each beam: the range, or without a return
        ``max_range`` (capped by ``no_return_free``)."""
        reach = self.max_range if self.no_return_free is None else min(self.max_range,
                                                                         self.no_return_free)
        return np.where(self.returned, self.ranges, reach)

    def points(self) -> FloatArray:
        """End points ``(K, 2)`` of the returned beams, in the scanner frame."""
        ok = self.returned
        r = self.ranges[ok]
        cos, sin = _directions(self.ranges.size, self.angle_min, self.angle_increment)
        out = np.empty((r.size, 2))
        # The cosines and sines of a scanner's beams are the same every scan: worked out
        # each time, and stacked, they would take 11 of a tracked scan's 440 microseconds on ACES.
        np.multiply(r, cos[ok], out=out[:, 0])
        np.multiply(r, sin[ok], out=out[:, 1])
        return out


def beam_angles(beams: int, angle_min: float, angle_increment: float) -> FloatArray:
    """The angles (rad, scanner frame) of ``beams`` beams from ``angle_min`` on, every
    ``angle_increment``."""
    return angle_min + angle_increment * np.arange(beams)


@lru_cache(maxsize=16)
def _directions(beams: int, angle_min: float, angle_increment: float
                ) -> tuple[FloatArray, FloatArray]:
    """The cosines and sines (read-only) of :func:`beam_angles`."""
    angles = beam_angles(beams, angle_min, angle_increment)
    cos, sin = np.cos(angles), np.sin(angles)
    cos.flags.writeable = sin.flags.writeable = False
    return cos, sin
