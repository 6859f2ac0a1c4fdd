"""Scan frames from a simulated world: true poses, ray-cast ranges, noisy odometry.

The same scenario and seed give the same frames, bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator

import numpy as np

from drivers.raycast import cast_discs, cast_segments
from drivers.scenario import (
    MAX_SCANS,
    MovingObstacle,
    OdometryModel,
    Scenario,
    Trajectory,
    expected_scans,
)
from vmp.source import Reference, SourceReport
from vmp.types import BeamGeometry, FloatArray, ScanFrame, relative, wrap_angle

__all__ = ["Simulator", "drive", "noisy_odometry", "obstacle_positions"]


def _legs(traj: Trajectory) -> tuple[FloatArray, FloatArray]:
    """Start and end points ``(L, 2)`` and speeds ``(L,)`` of every leg, all laps included."""
    wp, sp = traj.waypoints, traj.speeds
    if traj.closed:
        starts, ends, speeds = wp, np.roll(wp, -1, axis=0), sp
        starts = np.tile(starts, (traj.laps, 1))
        ends = np.tile(ends, (traj.laps, 1))
        speeds = np.tile(speeds, traj.laps)
    else:
        starts, ends, speeds = wp[:-1], wp[1:], sp[:-1]
    return np.hstack([starts, ends]), speeds


def drive(traj: Trajectory, rate_hz: float) -> tuple[FloatArray, FloatArray]:
    """Sample the true motion at ``rate_hz``: stamps ``(N,)`` and poses ``(N, 3)``.

    The robot turns on the spot at ``turn_rate`` to face each leg, then drives it straight at the
    leg's speed.
    """
    legs, speeds = _legs(traj)
    headings = np.arctan2(legs[:, 3] - legs[:, 1], legs[:, 2] - legs[:, 0])
    h0 = traj.start_heading if traj.start_heading is not None else headings[0]
    # Unwrapped heading: each turn takes the short way round.
    turns = wrap_angle(np.diff(np.concatenate([[h0], headings])))
    unwrapped = h0 + np.cumsum(turns)
    before = np.concatenate([[h0], unwrapped[:-1]])
    lengths = np.hypot(legs[:, 2] - legs[:, 0], legs[:, 3] - legs[:, 1])

    # Primitives alternate: turn i, drive i. Each has start pose, end pose, duration.
    n = len(legs)
    start = np.empty((2 * n, 3))
    end = np.empty((2 * n, 3))
    start[0::2] = np.column_stack([legs[:, :2], before])
    end[0::2] = np.column_stack([legs[:, :2], unwrapped])
    start[1::2] = np.column_stack([legs[:, :2], unwrapped])
    end[1::2] = np.column_stack([legs[:, 2:], unwrapped])
    duration = np.empty(2 * n)
    duration[0::2] = np.abs(turns) / traj.turn_rate
    duration[1::2] = lengths / speeds
    keep = duration > 1e-12
    start, end, duration = start[keep], end[keep], duration[keep]

    t_end = np.cumsum(duration)
    t_start = t_end - duration
    total = float(t_end[-1])
    stamps = np.arange(math.floor(total * rate_hz + 1e-9) + 1) / rate_hz
    k = np.clip(np.searchsorted(t_end, stamps, side="right"), 0, len(duration) - 1)
    frac = np.clip((stamps - t_start[k]) / duration[k], 0.0, 1.0)[:, None]
    poses = start[k] + frac * (end[k] - start[k])
    poses[:, 2] = wrap_angle(poses[:, 2])
    return stamps, poses


def noisy_odometry(true_poses: FloatArray, model: OdometryModel,
                   rng: np.random.Generator) -> FloatArray:
    """Odometry poses ``(N, 3)`` that integrate the true increments with the model's errors.

    The odometry frame coincides with the world frame at the first pose.
    """
    inc = relative(true_poses[:-1], true_poses[1:])
    dist = np.hypot(inc[:, 0], inc[:, 1])
    dth = inc[:, 2]
    n = len(inc)
    scale = 1.0 + model.trans_scale_bias + rng.standard_normal(n) * model.trans_noise * np.sqrt(
        dist) / np.maximum(dist, 1e-12)
    rot_sigma = np.sqrt(model.rot_noise_per_m**2 * dist + model.rot_noise_per_rad**2 * np.abs(dth))
    dth_odo = (dth * (1.0 + model.rot_scale_bias) + model.drift_per_m * dist
               + rng.standard_normal(n) * rot_sigma)
    dxy = inc[:, :2] * scale[:, None]
    # Integrate: heading is a running sum; each step's translation turns with the heading before it.
    theta = true_poses[0, 2] + np.concatenate([[0.0], np.cumsum(dth_odo)])
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    step_x = c * dxy[:, 0] - s * dxy[:, 1]
    step_y = s * dxy[:, 0] + c * dxy[:, 1]
    out = np.empty_like(true_poses)
    out[:, 0] = true_poses[0, 0] + np.concatenate([[0.0], np.cumsum(step_x)])
    out[:, 1] = true_poses[0, 1] + np.concatenate([[0.0], np.cumsum(step_y)])
    out[:, 2] = wrap_angle(theta)
    return out


def obstacle_positions(obstacles: tuple[MovingObstacle, ...], stamps: FloatArray) -> FloatArray:
    """Centres ``(N, K, 2)`` of the moving obstacles at the given times."""
    out = np.empty((len(stamps), len(obstacles), 2))
    for j, ob in enumerate(obstacles):  # a handful of people, not a hot loop
        path = np.vstack([ob.path, ob.path[:1]]) if ob.closed else ob.path
        seg = np.hypot(*np.diff(path, axis=0).T) if len(path) > 1 else np.zeros(0)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        total = arc[-1]
        if total <= 0 or ob.speed == 0:
            out[:, j] = ob.path[0]
            continue
        s = ob.speed * stamps
        s = np.mod(s, total) if ob.closed else total - np.abs(np.mod(s, 2 * total) - total)
        out[:, j, 0] = np.interp(s, arc, path[:, 0])
        out[:, j, 1] = np.interp(s, arc, path[:, 1])
    return out


class Simulator:
    """Iterate the scan frames of a scenario: ray-cast ranges, noisy odometry, true poses.

    ``laps`` overrides the scenario's number of laps, ``max_scans`` cuts the run short,
    ``seed`` overrides the scenario's seed. A :class:`~vmp.source.Source` whose reference is
    the true trajectory.
    """

    def __init__(self, scenario: Scenario, *, seed: int | None = None, laps: int | None = None,
                 max_scans: int | None = None, batch: int = 16) -> None:
        traj = scenario.trajectory
        if laps is not None:
            if laps < 1:
                raise ValueError(f"laps must be >= 1, got {laps}")
            if laps != traj.laps and not traj.closed:
                raise ValueError(f"{scenario.name}: laps need a closed trajectory")
            traj = dataclasses.replace(traj, laps=laps)
            scans = expected_scans(traj, scenario.sensor.rate_hz)
            if scans > MAX_SCANS:
                raise ValueError(f"{scenario.name}: {laps:,} laps make {scans:,.0f} scans, "
                                 f"more than the {MAX_SCANS:,} a simulated run may make")
        self.scenario = scenario
        self.name = scenario.name
        self.sensor = scenario.sensor
        self._closed = False
        self.seed = scenario.seed if seed is None else seed
        self.batch = batch
        odo_seq, sensor_seq = np.random.SeedSequence(self.seed).spawn(2)
        self._sensor_seq = sensor_seq
        stamps, poses = drive(traj, self.sensor.rate_hz)
        # The odometry of the whole drive, then cut: a run of the first N scans sees the same
        # scans as the whole run does (a resumed run checks that it reads the same frames).
        odom = noisy_odometry(poses, scenario.odometry, np.random.default_rng(odo_seq))
        if max_scans is not None:
            stamps, poses, odom = stamps[:max_scans], poses[:max_scans], odom[:max_scans]
        self.stamps: FloatArray = stamps
        self.true_poses: FloatArray = poses
        self.odom_poses: FloatArray = odom

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def geometry(self) -> BeamGeometry:
        return self.sensor.geometry

    @property
    def length(self) -> int:
        return len(self.stamps)

    def reference(self) -> Reference:
        """The true trajectory."""
        return Reference(self.true_poses, "ground truth", truth=True, stamps=self.stamps)

    def report(self) -> SourceReport:
        return SourceReport(item="scan")

    def close(self) -> None:
        """End an iteration under way after the frame it is at."""
        self._closed = True

    def ranges_at(self, poses: FloatArray, stamps: FloatArray | None = None,
                  rng: np.random.Generator | None = None) -> FloatArray:
        """Ranges ``(P, B)`` seen from scanner poses ``(P, 3)``; ``inf`` where nothing is in range.

        Without ``rng`` the ranges are exact (no noise, no dropout). Moving obstacles stand
        where they are at ``stamps`` (default: time 0).
        """
        poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
        sensor = self.sensor
        angles = poses[:, 2, None] + sensor.angles[None, :]
        origins = poses[:, :2]
        walls = self._walls_near(origins)
        r = cast_segments(origins, angles, walls)
        if self.scenario.obstacles:
            t = np.zeros(len(poses)) if stamps is None else np.asarray(stamps)
            centres = obstacle_positions(self.scenario.obstacles, t)
            radii = np.array([o.radius for o in self.scenario.obstacles])
            r = np.minimum(r, cast_discs(origins, angles, centres, radii))
        if rng is not None:
            hit = np.isfinite(r)
            r = r + rng.standard_normal(r.shape) * sensor.range_noise
            # A return never comes from behind the scanner; keep noisy ranges positive.
            r = np.where(hit, np.maximum(r, 1e-3), np.inf)
            if sensor.dropout > 0:
                r[rng.random(r.shape) < sensor.dropout] = np.inf
        r[r > sensor.geometry.max_range] = np.inf
        return r

    def _walls_near(self, origins: FloatArray) -> FloatArray:
        """Walls that may lie within range of any of the origins (box test, conservative)."""
        walls = self.scenario.walls
        reach = self.sensor.geometry.max_range
        lo = origins.min(axis=0) - reach
        hi = origins.max(axis=0) + reach
        seg_lo = np.minimum(walls[:, :2], walls[:, 2:])
        seg_hi = np.maximum(walls[:, :2], walls[:, 2:])
        near = ((seg_hi >= lo) & (seg_lo <= hi)).all(axis=1)
        return walls[near]

    def __iter__(self) -> Iterator[ScanFrame]:
        rng = np.random.default_rng(self._sensor_seq)
        g = self.sensor.geometry
        self._closed = False
        for b0 in range(0, len(self), self.batch):
            sl = slice(b0, b0 + self.batch)
            ranges = self.ranges_at(self.true_poses[sl], self.stamps[sl], rng)
            for i, r in enumerate(ranges):
                k = b0 + i
                yield ScanFrame(
                    stamp=float(self.stamps[k]),
                    ranges=r,
                    angle_min=g.angle_min,
                    angle_increment=g.angle_increment,
                    max_range=g.max_range,
                    odom=self.odom_poses[k],
                    true_pose=self.true_poses[k],
                    index=k,
                )
                if self._closed:
                    return

    def station_ranges(
        self, rng: np.random.Generator | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Ranges seen from the home pose ``(B,)`` and the nearby stations ``(K, B)``."""
        st = self.scenario.stations
        if st is None:
            raise ValueError(f"scenario {self.scenario.name} defines no stations")
        r = self.ranges_at(np.vstack([st.home, st.nearby]), rng=rng)
        return r[0], r[1:]

