"""The correlative window search: finds a known offset, and says when a place is ambiguous."""

import math

import numpy as np
import pytest

from vmp.correlative import CorrelativeConfig, LikelihoodGrid, correlative_search, grid_for
from vmp.registration import Reference, register
from vmp.types import compose, inverse


def segment(a, b, step=0.05):
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(int(np.hypot(*(b - a)) / step), 1)
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    return a + t * (b - a)


def room():
    """An irregular room: walls, a recess and two boxes (no symmetry)."""
    walls = [((-3, -2), (4, -2)), ((4, -2), (4, 1)), ((4, 1), (5, 1)), ((5, 1), (5, 3)),
             ((5, 3), (-3, 3)), ((-3, 3), (-3, -2)),
             ((1, -1), (1.8, -1)), ((1.8, -1), (1.8, -0.4)), ((1.8, -0.4), (1, -0.4)),
             ((1, -0.4), (1, -1)), ((-2, 1.5), (-1.2, 2.2))]
    return np.vstack([segment(a, b) for a, b in walls])


def seen_from(points, pose, noise=0.0, seed=0):
    """World points in the frame of a scanner at ``pose`` (x, y, theta)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = points - pose[:2]
    local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=-1)
    if noise:
        local = local + np.random.default_rng(seed).normal(0.0, noise, local.shape)
    return local


def test_recovers_a_known_offset():
    world = room()
    ref_pose = np.array([0.2, 0.1, 0.3])
    live_pose = np.array([0.75, -0.35, 0.3 + math.radians(9.0)])
    ref = seen_from(world, ref_pose)
    live = seen_from(world, live_pose, noise=0.01)[::2]
    truth = compose(inverse(ref_pose), live_pose)  # live scanner in the reference frame
    cfg = CorrelativeConfig()
    found = correlative_search(grid_for(ref, cfg), live, np.zeros(3), cfg)
    assert np.hypot(*(found.pose[:2] - truth[:2])) <= 0.1
    assert abs(found.pose[2] - truth[2]) <= math.radians(2.0)
    assert found.score > 0.7
    assert found.ratio < 0.85  # a clear peak
    # ICP from the coarse answer lands on the truth.
    reg = register(Reference(ref), live, found.pose)
    assert np.hypot(*(reg.pose[:2] - truth[:2])) < 0.01
    assert abs(reg.pose[2] - truth[2]) < math.radians(0.3)


def test_searches_around_the_given_centre():
    world = room()
    live = seen_from(world, np.array([2.0, 1.0, 0.5]))
    cfg = CorrelativeConfig(window_xy=0.5, window_theta=math.radians(6.0))
    grid = grid_for(world, cfg)
    found = correlative_search(grid, live, np.array([1.8, 1.2, 0.45]), cfg)
    assert np.allclose(found.pose[:2], [2.0, 1.0], atol=0.1)
    assert abs(found.pose[2] - 0.5) <= math.radians(2.0)
    assert found.poses_searched == 11 * 11 * 7


def test_a_corridor_is_ambiguous():
    """Two long parallel walls: every shift along them scores the same."""
    walls = np.vstack([segment((-10, -1), (10, -1)), segment((-10, 1), (10, 1))])
    live = seen_from(walls, np.array([0.5, 0.0, 0.0]))
    live = live[np.abs(live[:, 0]) < 6.0]  # the scanner sees 6 m either way
    cfg = CorrelativeConfig()
    found = correlative_search(grid_for(walls, cfg), live, np.zeros(3), cfg)
    assert found.score > 0.9
    assert found.ratio > 0.95


def test_a_repeated_structure_is_ambiguous():
    """Identical pillars every 0.6 m along a wall: the window holds several equal peaks."""
    wall = segment((-8, 0), (8, 0))
    pillars = [segment((x, 0.5), (x + 0.2, 0.5)) for x in np.arange(-8, 8, 0.6)]
    world = np.vstack([wall, *pillars])
    live = seen_from(world, np.array([0.3, -1.0, 0.0]))
    live = live[np.abs(live[:, 0]) < 3.0]
    cfg = CorrelativeConfig()
    found = correlative_search(grid_for(world, cfg), live, np.array([0.0, -1.0, 0.0]), cfg)
    assert found.ratio > 0.9


def test_a_copy_beyond_the_window_is_not_seen():
    """Shelves every 2.4 m: within the +-1 m window the peak is unique, though the place is
    not (the filter's gate guards against the copies beyond the window)."""
    wall = segment((-12, 0), (12, 0))
    shelves = [segment((x, 0.0), (x, 0.8)) for x in np.arange(-12, 12.1, 2.4)]
    marks = [segment((x + 0.3, 0.0), (x + 0.5, 0.4)) for x in np.arange(-12, 12.1, 2.4)]
    world = np.vstack([wall, *shelves, *marks])
    live = seen_from(world, np.array([0.1, -1.5, 0.0]))
    live = live[np.abs(live[:, 0]) < 5.0]
    cfg = CorrelativeConfig()
    found = correlative_search(grid_for(world, cfg), live, np.array([0.0, -1.5, 0.0]), cfg)
    assert np.hypot(found.pose[0] - 0.1, found.pose[1] + 1.5) <= 0.1
    assert found.ratio < 0.85  # the window alone sees one clear peak


def test_likelihood_grid_scores_and_padding():
    pts = segment((0, 0), (2, 0))
    grid = LikelihoodGrid(pts, resolution=0.1, sigma=0.1, pad=3)
    assert grid.score(pts, np.zeros(3)) > 0.95
    assert grid.score(pts, np.array([0.0, 1.0, 0.0])) < 0.01  # 10 sigma away
    assert grid.score(pts, np.array([50.0, 0.0, 0.0])) == 0.0  # off the grid
    assert (grid.grid[:3] == 0).all() and (grid.grid[:, -3:] == 0).all()
    with pytest.raises(ValueError, match="padded"):
        correlative_search(grid, pts, np.zeros(3), CorrelativeConfig(window_xy=1.0))


def test_bad_inputs():
    with pytest.raises(ValueError):
        LikelihoodGrid(np.zeros((0, 2)))
    with pytest.raises(ValueError):
        CorrelativeConfig(resolution=0.0)
    grid = grid_for(room(), CorrelativeConfig())
    found = correlative_search(grid, np.full((4, 2), np.nan), np.array([1.0, 2.0, 0.1]))
    assert found.score == 0.0 and found.poses_searched == 0
    assert found.ratio == math.inf
