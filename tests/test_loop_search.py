"""The loop search in one submap: pillars seen from a corridor place the scan along its axis,
which the walls' lines leave free; a bare corridor leaves it free."""

import math
from collections import Counter

import numpy as np

from vmp.branch_bound import SearchGrid
from vmp.config import MappingConfig
from vmp.loops import RESOLUTION, LoopSearch, _placed_by_search
from vmp.matcher import pins
from vmp.types import ScanFrame, relative, transform_points


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
    return loops._search_one(0, thinned, live, guess, window, math.radians(10)), stats


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


def room():
    """A room 8 x 5 m with a door, a wall stub and a pillar: every direction pinned."""
    return [((-4, -2.5), (4, -2.5)), ((4, -2.5), (4, 2.5)), ((4, 2.5), (0.5, 2.5)),
            ((-0.5, 2.5), (-4, 2.5)), ((-4, 2.5), (-4, -2.5)), ((1.5, -2.5), (1.5, -1.0)),
            ((-2.2, 0.8), (-1.8, 0.8)), ((-1.8, 0.8), (-1.8, 1.2)), ((-1.8, 1.2), (-2.2, 1.2)),
            ((-2.2, 1.2), (-2.2, 0.8))]


def cast(segments, pose, beams=361):
    """A scan from ``pose`` against ``segments`` (the nearest crossing of every beam)."""
    angles = np.linspace(-math.pi, math.pi, beams, endpoint=False)
    a = np.array([s[0] for s in segments], float)
    b = np.array([s[1] for s in segments], float)
    d = np.stack([np.cos(angles + pose[2]), np.sin(angles + pose[2])], axis=-1)[:, None]
    e = (b - a)[None]
    w = (a - pose[:2])[None]
    den = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / den
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den
    t = np.where((t > 0) & (u >= 0) & (u <= 1), t, np.inf)
    return ScanFrame(0.0, t.min(axis=1), -math.pi, 2 * math.pi / beams, 30.0)


class TwoPlaces:
    """Two stored milestones, 8 m apart, each at the middle of a room like the other."""

    ids = np.array([0, 1, 40])
    poses = np.array([[0.0, 0.0, 0.0], [8.0, 0.0, 0.0], [4.0, 0.0, 0.0]])

    def pose(self, mid):
        return self.poses[list(self.ids).index(mid)]

    def rank(self, ranges, angle_min, angle_increment, max_range, ids):
        return [(int(mid), 0.9, 0.0) for mid in ids]


def search_two(rooms_alike):
    """The scan taken in the first room, searched in both rooms' submaps (the second one
    alike or turned into a bare box)."""
    first = np.concatenate([wall(*p, *q) for p, q in room()])
    other = first if rooms_alike else np.concatenate(
        [wall(*p, *q) for p, q in room()[:5]] + [wall(-3, -2.5, -3, 2.5)])
    stats: Counter[str] = Counter()
    loops = LoopSearch(MappingConfig(), TwoPlaces(), lambda mid: (mid,),
                       lambda mid: ((mid,), first if mid == 0 else other), stats)
    frame = cast(room(), np.array([0.3, -0.2, 0.1]))
    drift = np.diag([3.0**2, 3.0**2, 0.3**2])  # far travelled: a 7 m window either way
    finds = loops.search(frame, np.array([4.0, 0.0, 0.0]), 40, set(), 0, lambda mid: drift)
    return finds, stats


def test_a_view_two_submaps_explain_is_no_loop():
    finds, stats = search_two(rooms_alike=True)
    assert finds == []
    assert stats["loop searches ambiguous across submaps"] == 2


def test_a_view_one_submap_explains_is_a_loop():
    # The bare box fits part of the view too, less well: its find (if any) gives way to the
    # room's, and the room's stands.
    finds, _ = search_two(rooms_alike=False)
    assert [f.milestone for f in finds] == [0]
    assert np.hypot(*(finds[0].registration.pose[:2] - (0.3, -0.2))) < 0.05
