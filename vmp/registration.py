"""Scan registration: point-to-line ICP of a live scan against a reference scan, with a fit measure.

The reference (a milestone's stored scan, a few recent scans, or a saved map) is prepared once:
its points sorted by grid cell (:mod:`vmp.icp_kernel`) and a normal per point. :func:`register`
then finds the pose of the live scan in the reference frame, starting from a guess, and says how
well it fits (residual RMS, share of points with a partner) and how well the fit constrains each
direction (covariance). In a corridor the fit leaves the direction along the walls free, and the
covariance says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vmp.config import RegistrationConfig
from vmp.icp_kernel import (
    REVISIT,
    cell_index,
    cell_keys,
    count_near,
    fit_covariance,
    likelihood_sum,
    point_normals,
    run_icp,
)
from vmp.types import FloatArray

__all__ = ["MIN_POINTS", "Reference", "Registration", "explained", "fits", "fits_explained",
           "last_gate", "likelihood", "register"]


MIN_POINTS = 20  # a scan with fewer returns is neither registered nor matched
# The ICP's own settings (lengths in metres, angles in radians).
MAX_ITERATIONS = 30
START_DISTANCE = 0.5  # correspondence gate of the first iteration (the kernel's CELL)
MIN_DISTANCE = 0.08  # the gate shrinks to this
HUBER = 0.03  # residuals beyond this get Huber-down-weighted
TOLERANCE = 5e-4  # stop when a step moves less than this
NEIGHBOURS = 5  # reference points per normal estimate
MAX_NORMAL_SPREAD = 0.3  # neighbours farther than this do not define a normal
COVARIANCE_SCALE = 4.0  # ICP covariances are optimistic: inflate
MIN_SIGMA_XY = 0.005  # covariance floor
MIN_SIGMA_THETA = 0.002
MAX_SIGMA = 100.0  # cap for unconstrained directions
# A direction of translation that few matched points' normals face (a corridor's axis) is
# degenerate, the fit says nothing there: fewer than this share of the points' summed
# squared cosines, or fewer than MIN_CONSTRAINT of them.
DEGENERATE_SHARE = 0.05
MIN_CONSTRAINT = 8.0
# Where point-to-line matching leaves a direction of translation free (a rack aisle, a
# corridor), the fit is run again with the reference points among close neighbours that do
# not lie on a line (a post, a corner, a pallet's end) matched point to point, with this weight
# relative to a line match. Isolated points (a wall sampled sparsely at a grazing angle) are
# never matched: their nearest partner slides with the robot. Only then, since a corner is hit
# at a slightly different place by every scan (docs/benchmarks.md, "Settings removed").
CORNER_WEIGHT = 0.5


@dataclass(frozen=True)
class Registration:
    """The pose of a live scan in a reference frame, and how much to trust it."""

    pose: FloatArray  # (3,) live scanner pose in the reference frame
    rms: float  # RMS of the point-to-line residuals of matched points (m)
    inliers: float  # share of live points matched within the final gate
    covariance: FloatArray  # (3, 3)
    iterations: int
    converged: bool
    # Whether corner points had to be matched to constrain every direction (less sure than
    # lines: a loop is not closed on such a fit alone).
    by_corners: bool = False


class Reference:
    """Reference points ``(N, 2)`` sorted by grid cell, with their cells' index
    (:func:`vmp.icp_kernel.cell_index`) and per-point normals, built once."""

    def __init__(self, points: FloatArray) -> None:
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
            raise ValueError(f"a reference needs at least 3 points (N, 2), got {pts.shape}")
        # Sorted by grid cell, as the compiled ICP looks its neighbours up (vmp.icp_kernel).
        keys = cell_keys(pts)
        order = np.argsort(keys, kind="stable")
        self.cells = cell_index(keys[order])
        pts = self.points = np.ascontiguousarray(pts[order])
        self.normals, self.valid, self.corner = point_normals(
            self.cells, pts, min(NEIGHBOURS, len(pts)), MAX_NORMAL_SPREAD)


def fits(reg: Registration, config: RegistrationConfig) -> bool:
    """Whether a registration fits well enough to be used: a close fit of most points."""
    return bool(np.isfinite(reg.rms) and reg.rms <= config.max_rms
                and reg.inliers >= config.min_inliers)


def fits_explained(reference: Reference, reg: Registration, points: FloatArray,
                   config: RegistrationConfig) -> bool:
    """Whether a registration of ``points`` against ``reference`` fits: closely, and with
    most of the points near a reference point, on a clear line or not."""
    if not np.isfinite(reg.rms):
        return False
    share = explained(reference, points, reg.pose, last_gate(reg.rms))
    return fits(replace(reg, inliers=share), config)


def last_gate(rms: float) -> float:
    """The correspondence gate (m) ICP has shrunk to at a fit of residual RMS ``rms``."""
    return max(MIN_DISTANCE, 4.0 * rms + 0.02)


def explained(reference: Reference, points: FloatArray, pose: FloatArray,
              distance: float) -> float:
    """The share of ``points`` (their frame) placed at ``pose`` that lie within ``distance``
    of a reference point, on a line or not (looked up in the reference's cells, as ICP does:
    a k-d tree built for this would take 2 ms on a localizer's 13,000-point submap)."""
    if len(points) == 0:
        return 0.0
    near = count_near(reference.cells, reference.points, _contiguous(points),
                      *_placing(pose), float(distance))
    return near / len(points)


def likelihood(reference: Reference, points: FloatArray, pose: FloatArray, sigma: float,
               flat: float = 0.0) -> float:
    """The mean over ``points`` (their frame) placed at ``pose`` of ``exp(-e^2 / 2
    sigma^2)``, ``e`` how much farther than ``flat`` the nearest reference point lies (none
    counts beyond ``flat`` plus 3 sigma, where it is 0.011); 0 for no points."""
    if len(points) == 0:
        return 0.0
    total = likelihood_sum(reference.cells, reference.points, _contiguous(points),
                           *_placing(pose), float(sigma), float(flat),
                           float(flat) + 3.0 * float(sigma))
    return total / len(points)


def _placing(pose: FloatArray) -> tuple[float, float, float, float]:
    """``pose``'s x, y and the cosine and sine of its heading, as
    :func:`vmp.types.transform_points` computes them, for a kernel to place points with (in
    NumPy, placing a scan's 180 points cost about as much as scoring them)."""
    x, y, theta = np.asarray(pose, dtype=np.float64)
    return float(x), float(y), float(np.cos(theta)), float(np.sin(theta))


def _contiguous(points: FloatArray) -> FloatArray:
    return np.ascontiguousarray(points, dtype=np.float64)


def register(reference: Reference, points: FloatArray, initial: FloatArray,
             corners: bool = True, stops_early: bool = False) -> Registration:
    """Point-to-line ICP of ``points`` ``(M, 2)`` (live scanner frame) onto the reference;
    where that leaves a direction free and ``corners`` allows, again with corner points
    matched point to point. With ``stops_early``, ICP stops where its steps cycle
    (:data:`vmp.icp_kernel.CYCLE`) rather than run on to its cap, and where a step changes
    the matched points' residuals by less than :data:`TOLERANCE` (:func:`run_icp`'s
    ``settle``) however far it moves the pose."""
    pts = np.asarray(points, dtype=np.float64)
    revisit = REVISIT if stops_early else 0.0
    settle = TOLERANCE if stops_early else 0.0
    reg, free = _icp(reference, pts, np.asarray(initial, dtype=np.float64), False, revisit,
                     settle)
    if corners and free and reference.corner.any():
        with_corners, _ = _icp(reference, pts, reg.pose, True, revisit, settle)
        if np.isfinite(with_corners.rms):
            return replace(with_corners, by_corners=True)
    return reg


def _icp(reference: Reference, pts: FloatArray, initial: FloatArray,
         corners: bool, revisit: float = 0.0, settle: float = 0.0
         ) -> tuple[Registration, int]:
    """One ICP run from ``initial`` (compiled: :mod:`vmp.icp_kernel`); the registration and
    how many directions of translation its fit leaves free (none when nothing was
    matched)."""
    x, y, th, H, rms, inliers, wsum, it, converged = run_icp(
        reference.cells, reference.points, reference.normals, reference.valid,
        reference.corner,
        np.ascontiguousarray(pts), float(initial[0]), float(initial[1]), float(initial[2]),
        corners, START_DISTANCE, MIN_DISTANCE, HUBER, CORNER_WEIGHT, TOLERANCE,
        MAX_ITERATIONS, revisit, settle)
    free = 0
    if math.isfinite(rms) and wsum > 0:
        cov, free = fit_covariance(H, rms, wsum, MIN_CONSTRAINT, DEGENERATE_SHARE,
                                   COVARIANCE_SCALE, MIN_SIGMA_XY, MIN_SIGMA_THETA, MAX_SIGMA)
    else:
        cov = _unfitted()
    reg = Registration(pose=np.array([x, y, th]), rms=rms, inliers=inliers, covariance=cov,
                       iterations=it, converged=converged)
    return reg, free


def _unfitted() -> FloatArray:
    """The covariance of a registration that matched nothing: unconstrained."""
    return np.diag([MAX_SIGMA**2] * 3)
