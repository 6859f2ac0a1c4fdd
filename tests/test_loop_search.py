"""The loop search in one submap: pillars seen from a corridor place the scan along its axis,
which the walls' lines leave free; a bare corridor leaves it free."""

import math
from collections import Counter

import numpy as np

from vmp.branch_bound import SearchGrid
from vmp.config import MappingConfig
from vmp.loops import RESOLUTION, LoopSearch, _placed_by_search
from vmp.matcher import pins
from vmp.types import relative, transform_points


def wall(x0, y0, x1, y1, step=0.02):
    n = max(int(math.hypot(x1 - x0, y1 - y0) / step), 1)
    t = np.linspace(0.0, 1.0, n + 1)
    return np.stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)], axis=-1)


def corridor(posts=()):
    """A corridor 2 m wide along x, open to a room on its upper side between x = 1 and 7 m,
    where thin round posts (5 cm radius, 8 returns each) stand: nothing there a line fit can
    hold on to."""
    parts = [wall(-15, -1, 15, -1, 0.05), wall(-15, 1, 1, 1, 0.05), wall(7, 1, 15, 1, 0.05)]
    a = np.linspace(0.0, 2 * math.pi, 9)[:-1]
    parts += [np.stack([x + 0.05 * np.cos(a), y + 0.05 * np.sin(a)], axis=-1) for x, y in posts]
    return np.concatenate(parts)


POSTS = np.random.default_rng(7).uniform([1.3, 1.5], [6.7, 5.0], (24, 2))


def seen_from(points, pose, rng):
    """The points within 12 m of ``pose``, in its frame, with 1 cm noise."""
    local = transform_points(relative(pose, np.zeros(3)), points)
    local = local[np.hypot(local[:, 0], local[:, 1]) <= 12.0]
    return local + rng.normal(0.0, 0.01, local.shape)


def search_in(world, truth, guess, window):
    stats: Counter[str] = Counter()
    loops = LoopSearch(MappingConfig(), None, lambda mid: (0,), lambda mid: ((0,), world), stats)
    live = seen_from(world, truth, np.random.default_rng(4))
    thinned = live[np.linspace(0, len(live) - 1, 100).round().astype(int)]
    return loops.search_submap(0, thinned, live, guess, window, math.radians(10)), stats


def test_posts_place_the_scan_along_the_corridor():
    truth = np.array([0.4, 0.0, 0.05])
    find, stats = search_in(corridor(POSTS), truth, truth + [0.6, 0.1, 0.03], 2.0)
    assert find is not None
    assert pins(find.registration)
    assert np.hypot(*(find.registration.pose[:2] - truth[:2])) < 0.1
    assert stats["loop searches placed along a corridor"] == 1


def test_a_bare_corridor_leaves_the_axis_free():
    truth = np.array([-6.0, 0.0, 0.0])
    world = corridor()
    find, stats = search_in(world, truth, truth + [0.6, 0.1, 0.0], 3.0)
    assert find is None or not pins(find.registration)
    assert stats["loop searches placed along a corridor"] == 0


def test_a_ridge_along_the_free_axis_is_not_placed():
    """The rival search looks only beyond half a metre; the peak must fall within it too."""
    free_x = np.diag([1e4, 0.01**2, 0.002**2])
    pose = np.array([0.4, 0.0, 0.05])
    for world, placed in ((corridor(POSTS), True), (corridor(), False)):
        grid = SearchGrid(world, RESOLUTION, 0.1, 5, 7.0)
        live = seen_from(world, pose, np.random.default_rng(5))
        assert (_placed_by_search(free_x, grid, live, pose) is not None) is placed
