"""Odometry refined by scan registration: where the scans see, they win; where not, the wheels."""

import math

import numpy as np

from vmp.config import MotionNoise, RegistrationConfig, ScanOdometryConfig
from vmp.scan_odometry import ScanOdometry, _percentile


def odometry() -> ScanOdometry:
    return ScanOdometry(ScanOdometryConfig(), RegistrationConfig(), MotionNoise())


def _room_scan(x: float) -> np.ndarray:
    """End points seen from (x, 0, 0) in a square room with walls 3 m from the origin."""
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    r = np.full(angles.size, np.inf)
    for normal in (0.0, math.pi / 2, math.pi, -math.pi / 2):
        dist = 3.0 - x * math.cos(normal)
        cos = np.cos(angles - normal)
        with np.errstate(divide="ignore"):
            r = np.minimum(r, np.where(cos > 1e-6, dist / cos, np.inf))
    return np.stack([r * np.cos(angles), r * np.sin(angles)], axis=-1)


def _corridor_scan(x: float) -> np.ndarray:
    """End points seen from (x, 0, 0) between two endless walls 1 m to either side (the same
    wherever the robot stands along them)."""
    angles = np.linspace(-math.pi / 2, math.pi / 2, 181)
    angles = angles[np.abs(np.sin(angles)) > 1.0 / 8.0]  # the walls within 8 m
    r = 1.0 / np.abs(np.sin(angles))
    return np.stack([r * np.cos(angles), r * np.sin(angles)], axis=-1)


def test_registration_corrects_wheels_that_err():
    odo = odometry()
    odo.increment(_room_scan(0.0), None)
    rng = np.random.default_rng(1)
    x = 0.0
    wheel_err, fused_err = [], []
    for _ in range(10):  # 0.1 m a step; the wheels err by about 1 cm and 0.6 degree
        x += 0.1
        wheel = np.array([0.1 + rng.normal(0, 0.01), rng.normal(0, 0.01), rng.normal(0, 0.01)])
        u, q = odo.increment(_room_scan(x), wheel)
        wheel_err.append(np.hypot(wheel[0] - 0.1, wheel[1]))
        fused_err.append(np.hypot(u[0] - 0.1, u[1]))
        assert np.sqrt(q[0, 0]) < 0.016  # surer than the wheels alone (1.6 cm per 0.1 m)
    assert odo.refined == 10 and odo.fallbacks == 0
    assert np.mean(fused_err) < 0.5 * np.mean(wheel_err), (fused_err, wheel_err)


def test_along_a_corridor_the_wheels_decide_the_axis():
    odo = odometry()
    odo.increment(_corridor_scan(0.0), None)
    u, q = odo.increment(_corridor_scan(0.1), np.array([0.13, 0.02, 0.0]))
    assert abs(u[0] - 0.13) < 1e-3  # along the walls: nothing to see, the wheels stand
    assert abs(u[1]) < 3e-3  # across them the scans put the robot back in the middle
    assert q[0, 0] > 10 * q[1, 1]


def test_the_wheels_distance_scale_is_learned():
    odo = odometry()
    odo.increment(_room_scan(0.0), None)
    x = 0.0
    for k in range(60):  # the wheels read 5 % long; the robot drives to and fro in the room
        step = 0.05 if (k // 20) % 2 == 0 else -0.05
        x += step
        odo.increment(_room_scan(x), np.array([1.05 * step, 0.0, 0.0]))
    assert abs(odo.scale - 1 / 1.05) < 0.01


def test_wheels_that_miss_a_step_are_overruled_where_the_scans_see_everything():
    """The wheels miss a 25 cm step (beyond any slip), then the robot stands. In a room the
    registration pins every direction and the keyframe a metre back agrees with it, so it
    overrules the wheels (on fr079 the wheels said ahead where the robot backed up); the
    scans after it register against the right pose."""
    odo = odometry()
    x = -1.0
    odo.increment(_room_scan(x), None)
    for _ in range(10):
        x += 0.1
        odo.increment(_room_scan(x), np.array([0.1, 0.0, 0.0]))
    x += 0.25
    u, q = odo.increment(_room_scan(x), np.array([0.0, 0.0, 0.0]))  # the miss
    assert odo.fallbacks == 0 and odo.overruled == 1
    assert abs(u[0] - 0.25) < 0.01 and np.sqrt(q[0, 0]) < 0.02
    for _ in range(10):  # standing
        u, _ = odo.increment(_room_scan(x), np.zeros(3))
        assert np.hypot(u[0], u[1]) < 0.005
    assert odo.fallbacks == 0 and odo.overruled == 1 and odo.refined == 21


def test_a_registration_fooled_by_something_moving_along_does_not_overrule_the_wheels():
    """A box 0.8 m ahead moves with the robot (the office scenario's walker): against the
    last keyframe the scan fits standing still, every direction pinned, while the wheels
    say 0.1 m a step. A metre back the room's walls outweigh the box: the wheels stand."""
    def seen(x: float) -> np.ndarray:
        room = _room_scan(x)
        near = np.linalg.norm(room, axis=1) > 0  # every beam
        a = np.arctan2(room[:, 1], room[:, 0])
        box = np.abs(a) < 0.9  # the box fills the view ahead, 0.8 m away
        pts = room.copy()
        pts[box & near] = np.stack([np.full(box.sum(), 0.8), 0.8 * np.tan(a[box])], axis=-1)
        return pts

    odo = odometry()
    x = -1.5
    odo.increment(seen(x), None)
    for _ in range(12):
        x += 0.1
        u, _ = odo.increment(seen(x), np.array([0.1, 0.0, 0.0]))
    assert odo.overruled == 0
    assert abs(u[0] - 0.1) < 0.02


def test_along_a_corridor_a_registration_that_disagrees_falls_back_to_the_wheels():
    """Where the registration leaves a direction free it cannot overrule the wheels: a
    disagreement beyond the slip (something moving with the robot) falls back to them."""
    odo = odometry()
    odo.increment(_corridor_scan(0.0), None)
    walls = _corridor_scan(0.0)
    shifted = walls + np.array([0.0, 0.3])  # the walls seen 30 cm to one side: a wrong fit
    u, _ = odo.increment(shifted, np.array([0.1, 0.0, 0.0]))
    assert odo.fallbacks == 1 and odo.overruled == 0
    np.testing.assert_allclose(u, [0.1, 0.0, 0.0])


def test_a_slip_in_a_turn_goes_to_the_registration():
    """The wheels report no turn where the robot turned 8 degrees in place (fr079 slips like
    this): a registration that fits wins."""
    odo = odometry()
    odo.increment(_room_scan(0.0), None)
    turn = math.radians(8.0)
    c, s = math.cos(turn), math.sin(turn)
    turned = _room_scan(0.0) @ np.array([[c, -s], [s, c]])  # the room seen turned by +8 deg
    u, _ = odo.increment(turned, np.zeros(3))
    assert odo.fallbacks == 0
    assert abs(u[2] - turn) < math.radians(0.5), math.degrees(u[2])


def test_motion_noise_follows_wheels_noisier_than_configured():
    """Wheels that err about four times more than the configured noise (along travel only, so
    the 3-dof median sees less of it): the learned scale grows; wheels that err less than
    configured leave it at 1."""
    rng = np.random.default_rng(3)
    for sigma, expect_scale in ((0.005, (1.0, 1.0)), (0.05, (2.0, 100.0))):
        odo = odometry()
        odo.increment(_room_scan(0.0), None)
        x = 0.0
        for k in range(200):
            step = 0.05 if (k // 20) % 2 == 0 else -0.05
            x += step
            odo.increment(_room_scan(x), np.array([step + rng.normal(0, sigma), 0.0, 0.0]))
        assert expect_scale[0] <= odo.noise_scale <= expect_scale[1], (sigma, odo.noise_scale)


def test_the_scanner_mount_is_learned_from_turns():
    """A scanner 10 cm ahead of the axle swings sideways when the robot turns on the spot
    (the Intel and ACES robots do); the offset is learned from the turns' registrations."""
    from vmp.types import compose, inverse, transform_points

    walls = np.concatenate([np.column_stack([np.linspace(-3, 3, 300), np.full(300, y)])
                            for y in (-3.0, 3.0)]
                           + [np.column_stack([np.full(300, x), np.linspace(-3, 3, 300)])
                              for x in (-3.0, 2.0)])  # not square: every turn is distinct
    mount = np.array([0.1, 0.0, 0.0])

    def seen_from(base: np.ndarray) -> np.ndarray:
        return transform_points(inverse(compose(base, mount)), walls)

    odo = odometry()
    base = np.zeros(3)
    odo.increment(seen_from(base), None)
    step = np.array([0.0, 0.0, math.radians(10.0)])
    for _ in range(72):  # two turns on the spot
        base = compose(base, step)
        u, _ = odo.increment(seen_from(base), step)
    np.testing.assert_allclose(odo.mount, mount[:2], atol=0.01)
    # The scanner's increment, as the filter gets it, swings sideways by the mount.
    expected = compose(compose(inverse(mount), step), mount)
    np.testing.assert_allclose(u, expected, atol=0.005)


def test_the_noise_percentiles_are_numpys_to_the_last_bit():
    # The learned noise scale must not move when the percentile is computed by hand.
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 49, 50, 51, 199, 200):
        values = rng.exponential(size=n) * 10.0 ** rng.integers(-3, 4)
        median, tail = np.percentile(values, [50.0, 95.0])
        ordered = sorted(values.tolist())
        assert _percentile(ordered, 0.5) == median
        assert _percentile(ordered, 0.95) == tail


def test_the_learned_noise_follows_the_recent_disagreements_percentiles():
    """Kept sorted as values come and go, the window's median and 95th percentile are
    numpy's over its last NOISE_MEMORY values, scaled and bounded as documented."""
    from vmp.scan_odometry import CHI2_3DOF_95, CHI2_3DOF_MEDIAN, MAX_NOISE_SCALE, NOISE_MEMORY

    odo = odometry()
    rng = np.random.default_rng(5)
    seen: list[float] = []
    for k in range(3 * NOISE_MEMORY):
        d2 = float(rng.chisquare(3) * (8.0 if k > NOISE_MEMORY else 1.0))
        if k % 37 == 0:
            d2 = seen[-1] / odo.noise_scale if seen else d2  # repeated values come and go too
        seen.append(d2 * odo.noise_scale)
        odo._learn_noise(d2)
        window = seen[-NOISE_MEMORY:]
        if len(window) >= NOISE_MEMORY // 4:
            scale = min(max(np.percentile(window, 50) / CHI2_3DOF_MEDIAN, 1.0),
                        MAX_NOISE_SCALE)
            assert odo.noise_scale == scale
            assert odo.tail_scale == min(max(np.percentile(window, 95) / CHI2_3DOF_95, scale),
                                         MAX_NOISE_SCALE)
    assert odo.noise_scale > 2.0  # the noisier wheels were learned


def test_scan_odometry_stops_its_icp_where_the_steps_cycle_only_when_asked(monkeypatch):
    # A mapper's ICP runs on to its cap (its maps depend on the pose of a cycle it ends on);
    # a localizer's stops at a cycle (vmp.icp_kernel.CYCLE; its front end asks,
    # tests/test_tracking.py).
    import vmp.scan_odometry as so

    asked = []
    real = so.register

    def register(*args, **kwargs):
        asked.append(kwargs.get("stops_early", False))
        return real(*args, **kwargs)

    monkeypatch.setattr(so, "register", register)
    for early in (False, True):
        odo = ScanOdometry(ScanOdometryConfig(), RegistrationConfig(), MotionNoise(), early)
        asked.clear()
        odo.increment(_room_scan(0.0), None)
        odo.increment(_room_scan(0.1), np.array([0.1, 0.0, 0.0]))
        assert asked == [early]
