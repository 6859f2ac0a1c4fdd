"""Ray casting and the scenario simulator."""

import math

import numpy as np

from drivers.raycast import cast_discs, cast_segments
from drivers.scenario import load_scenario, parse_scenario
from drivers.simulator import Simulator, drive
from vmp.types import relative

SQUARE = {
    "walls": [{"polygon": [[0, 0], [4, 0], [4, 4], [0, 4]]}],
    "trajectory": {"waypoints": [[1, 1], [3, 1], [3, 3], [1, 3]], "closed": True},
    "sensor": {"beams": 361, "angle_min_deg": -180, "angle_increment_deg": 1,
               "max_range": 10, "range_noise": 0},
}


def analytic_square(x, y, angles, side=4.0):
    """Distance from (x, y) inside [0, side]^2 to its boundary along each angle."""
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 1e-12, (side - x) / c, np.where(c < -1e-12, -x / c, np.inf))
        ty = np.where(s > 1e-12, (side - y) / s, np.where(s < -1e-12, -y / s, np.inf))
    return np.minimum(tx, ty)


def test_ranges_equal_analytic_distances_in_a_square_room():
    sim = Simulator(parse_scenario(SQUARE, "square"))
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(0.2, 3.8, 50), rng.uniform(0.2, 3.8, 50),
                             rng.uniform(-math.pi, math.pi, 50)])
    got = sim.ranges_at(poses)
    angles = poses[:, 2, None] + sim.sensor.angles[None, :]
    want = analytic_square(poses[:, 0, None], poses[:, 1, None], angles)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_beams_beyond_max_range_have_no_return():
    doc = dict(SQUARE, sensor={"max_range": 2.0, "range_noise": 0})
    sim = Simulator(parse_scenario(doc, "square"))
    r = sim.ranges_at(np.array([[1.0, 1.0, 0.0]]))[0]
    assert np.isinf(r).any() and np.isfinite(r).any()
    assert (r[np.isfinite(r)] <= 2.0).all()


def test_ray_segment_and_disc_by_hand():
    origins = np.zeros((1, 2))
    angles = np.array([[0.0, math.pi / 2, math.pi]])
    seg = np.array([[2.0, -1.0, 2.0, 1.0]])  # a wall at x = 2
    np.testing.assert_allclose(cast_segments(origins, angles, seg), [[2.0, np.inf, np.inf]])
    centres = np.array([[[0.0, 3.0]]])
    np.testing.assert_allclose(cast_discs(origins, angles, centres, np.array([0.5])),
                               [[np.inf, 2.5, np.inf]])


def test_casting_a_few_poses_at_a_time_changes_no_range(monkeypatch):
    """Poses cast in chunks (small here, so that many chunks and a short last one occur)
    give what one pose at a time gives, rays parallel to a wall included (no hit)."""
    import drivers.raycast as raycast

    rng = np.random.default_rng(4)
    segments = rng.uniform(-5, 5, (30, 4))
    segments[0] = [-5.0, 1.0, 5.0, 1.0]  # the first pose's beam at angle 0 runs along it
    origins = rng.uniform(-3, 3, (23, 2))
    origins[0] = [0.0, 1.0]
    angles = rng.uniform(-math.pi, math.pi, (23, 17))
    angles[0, 0] = 0.0
    one_by_one = np.vstack([cast_segments(origins[i:i + 1], angles[i:i + 1], segments)
                            for i in range(len(origins))])
    monkeypatch.setattr(raycast, "CHUNK_ELEMENTS", 3 * 17 * 30)
    np.testing.assert_array_equal(cast_segments(origins, angles, segments), one_by_one)
    assert np.isfinite(one_by_one).mean() > 0.5


def test_same_seed_same_frames_and_other_seed_differs():
    sc = load_scenario("office")
    a = list(Simulator(sc, max_scans=80))
    b = list(Simulator(sc, max_scans=80))
    c = list(Simulator(sc, seed=sc.seed + 1, max_scans=80))
    assert all(np.array_equal(x.ranges, y.ranges) and np.array_equal(x.odom, y.odom)
               for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x.ranges, y.ranges) for x, y in zip(a, c, strict=True))


def test_trajectory_follows_waypoints_at_speed():
    sc = load_scenario("office")
    stamps, poses = drive(sc.trajectory, sc.sensor.rate_hz)
    np.testing.assert_allclose(np.diff(stamps), 0.1)
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    assert steps.max() <= 0.5 * 0.1 + 1e-9  # never faster than 0.5 m/s
    turns = np.abs(relative(poses[:-1], poses[1:])[:, 2])
    assert turns.max() <= math.radians(45) * 0.1 + 1e-9
    # Two laps of the 52 m loop, starting and ending at the first waypoint.
    assert math.isclose(steps.sum(), 104.0, rel_tol=1e-6)
    np.testing.assert_allclose(poses[0, :2], [6, 6])
    np.testing.assert_allclose(poses[-1, :2], [6, 6], atol=1e-9)


def test_odometry_drifts_like_its_model():
    sc = load_scenario("office")
    sim = Simulator(sc)
    np.testing.assert_allclose(sim.odom_poses[0], sim.true_poses[0])
    err = np.hypot(*(sim.odom_poses[:, :2] - sim.true_poses[:, :2]).T)
    assert 0.3 < err[-1] < 10.0  # drifts, but stays a plausible odometry
    # Increments stay close to the truth: 1 % scale bias plus noise, per 5 cm step.
    d_true = relative(sim.true_poses[:-1], sim.true_poses[1:])
    d_odo = relative(sim.odom_poses[:-1], sim.odom_poses[1:])
    assert np.abs(d_odo[:, :2] - d_true[:, :2]).max() < 0.02


def test_noise_matches_the_sensor_model():
    sc = load_scenario("lab")
    sim = Simulator(sc)
    poses = np.repeat(sim.true_poses[:1], 200, axis=0)
    exact = sim.ranges_at(poses[:1])[0]
    noisy = sim.ranges_at(poses, rng=np.random.default_rng(1))
    both = np.isfinite(noisy) & np.isfinite(exact)[None, :]
    resid = noisy[both] - np.broadcast_to(exact, noisy.shape)[both]
    assert abs(resid.std() - 0.01) < 0.001
    assert abs(resid.mean()) < 0.001


def test_moving_obstacle_is_seen_where_it_walks():
    doc = dict(SQUARE, obstacles=[{"path": [[2, 2], [2, 3.5]], "speed": 1.0, "radius": 0.2}])
    sim = Simulator(parse_scenario(doc, "square"))
    pose = np.array([[1.0, 2.0, 0.0]])  # looking along +x at the person's start
    ahead = np.argmin(np.abs(sim.sensor.angles))
    at_start = sim.ranges_at(pose, np.array([0.0]))[0, ahead]
    later = sim.ranges_at(pose, np.array([1.0]))[0, ahead]  # walked 1 m away along +y
    assert math.isclose(at_start, 0.8, abs_tol=1e-9)
    assert math.isclose(later, 3.0, abs_tol=1e-9)  # the wall behind it
    back = sim.ranges_at(pose, np.array([3.0]))[0, ahead]  # 1.5 m out, 1.5 m back
    assert math.isclose(back, 0.8, abs_tol=1e-9)


def test_stations_of_the_lab():
    sim = Simulator(load_scenario("lab"))
    home, nearby = sim.station_ranges()
    assert home.shape == (181,) and nearby.shape == (4, 181)
    assert np.isfinite(home).mean() > 0.9
