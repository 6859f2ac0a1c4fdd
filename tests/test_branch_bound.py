"""Branch-and-bound scan matching: the exhaustive search's answer at a fraction of its cost."""

import itertools
import math

import numpy as np
import pytest

from vmp.branch_bound import Match, SearchGrid, _angles, block_sums, first_match, search
from vmp.types import compose, inverse, transform_points


def _room() -> np.ndarray:
    """Walls of a 12 x 8 m room with a pillar and a niche, sampled every 2 cm."""
    corners = [(0, 0), (12, 0), (12, 8), (7, 8), (7, 6.5), (6, 6.5), (6, 8), (0, 8), (0, 0)]
    walls = [np.linspace(a, b, int(np.hypot(*np.subtract(b, a)) / 0.02))
             for a, b in itertools.pairwise(corners)]
    pillar = [np.linspace(a, b, 25) for a, b in (((4, 3), (4.5, 3)), ((4.5, 3), (4.5, 3.5)))]
    return np.vstack(walls + pillar)


def _seen_from(world: np.ndarray, pose: np.ndarray, keep: int = 150) -> np.ndarray:
    """World points within 10 m of ``pose``, in its frame, thinned to about ``keep``."""
    local = transform_points(inverse(pose), world)
    local = local[np.hypot(local[:, 0], local[:, 1]) < 10.0]
    return local[np.linspace(0, len(local) - 1, keep).round().astype(int)]


def test_recovers_a_known_pose_from_a_poor_guess():
    world = _room()
    grid = SearchGrid(world, 0.05, 0.05, depth=5, max_window=3.0)
    truth = np.array([5.3, 2.2, 0.4])
    live = _seen_from(world, truth)
    found = search(grid, live, truth + [1.2, -0.9, math.radians(12)], 2.0, math.radians(20))
    assert found is not None and found.score > 0.9
    assert np.hypot(*(found.pose[:2] - truth[:2])) <= 0.05
    assert abs(found.pose[2] - truth[2]) <= math.radians(0.5)


def test_equals_the_exhaustive_search():
    world = _room()
    grid = SearchGrid(world, 0.1, 0.1, depth=3, max_window=1.0)
    truth = np.array([8.0, 4.0, -0.3])
    live = _seen_from(world, truth, keep=60)
    center = truth + [0.35, -0.25, 0.04]
    found = search(grid, live, center, 0.6, math.radians(5))
    best = max(grid.score(live, np.array([center[0] + i * 0.1, center[1] + j * 0.1, th]))
               for th in center[2] + _angles(live, 0.1, math.radians(5))
               for i in range(-6, 7) for j in range(-6, 7))
    assert found.score == pytest.approx(best, abs=1e-12)
    assert found.evaluated < 13 * 13 * len(_angles(live, 0.1, math.radians(5)))


def test_nothing_above_the_minimum_score_is_none():
    world = _room()
    grid = SearchGrid(world, 0.1, 0.1, depth=4, max_window=2.0)
    elsewhere = np.random.default_rng(1).uniform(-5, 5, (100, 2))  # no such place
    assert search(grid, elsewhere, np.array([6.0, 4.0, 0.0]), 1.0, 0.2, min_score=0.8) is None


def test_excluding_the_best_gives_the_best_elsewhere():
    """Two identical rooms side by side: the second best pose is the other room's."""
    room = _room()
    world = np.vstack([room, room + [20.0, 0.0]])
    grid = SearchGrid(world, 0.1, 0.1, depth=6, max_window=12.0)
    truth = np.array([5.0, 4.0, 0.0])
    live = _seen_from(room, truth)  # sees only its own room's walls
    center = truth + [10.0, 0.0, 0.0]  # halfway: both rooms in the window
    best = search(grid, live, center, 11.0, math.radians(3))
    rival = search(grid, live, center, 11.0, math.radians(3),
                   exclude=(best.pose, 0.5, math.radians(5)))
    poses = sorted([best.pose[0], rival.pose[0]])
    assert poses[0] == pytest.approx(5.0, abs=0.1) and poses[1] == pytest.approx(25.0, abs=0.1)
    assert rival.score > 0.9 * best.score


def test_excluding_several_poses_leaves_each_out():
    """Three identical rooms in a row: with two of them excluded the search finds the third,
    with all three nothing scores as well."""
    room = _room()
    world = np.vstack([room, room + [20.0, 0.0], room + [40.0, 0.0]])
    grid = SearchGrid(world, 0.1, 0.1, depth=6, max_window=22.0)
    truth = np.array([5.0, 4.0, 0.0])
    live = _seen_from(room, truth)
    center = truth + [20.0, 0.0, 0.0]  # the middle room: all three in the window
    known = np.array([truth, truth + [40.0, 0.0, 0.0]])
    third = search(grid, live, center, 21.0, math.radians(3),
                   exclude=(known, 0.5, math.radians(5)))
    assert third.pose[0] == pytest.approx(25.0, abs=0.1)
    every = np.vstack([known, third.pose])
    assert search(grid, live, center, 21.0, math.radians(3), min_score=0.9 * third.score,
                  exclude=(every, 0.5, math.radians(5))) is None


def test_the_first_match_is_the_searches_in_turn():
    """Windows along a row of three identical rooms, searched in one call: the first window
    that holds a pose above the floor, and the very pose and score its own search finds."""
    room = _room()
    world = np.vstack([room, room + [20.0, 0.0], room + [40.0, 0.0]])
    grid = SearchGrid(world, 0.1, 0.1, depth=4, max_window=1.0)
    live = _seen_from(room, np.array([5.0, 4.0, 0.2]))
    rng = np.random.default_rng(5)
    centers = np.column_stack([rng.uniform(0.0, 48.0, 60), rng.uniform(1.0, 7.0, 60),
                               rng.uniform(-math.pi, math.pi, 60)])
    centers[41] = [45.2, 3.9, 0.25]  # near the third room's match: the first to answer
    known = (np.array([[5.0, 4.0, 0.2]]), 0.5, math.radians(5))
    floor = 0.8
    each = [search(grid, live, c, 0.6, math.radians(10), floor, exclude=known)
            for c in centers]
    first = next(k for k, m in enumerate(each) if m is not None)
    k, found = first_match(grid, live, centers, 0.6, math.radians(10), floor, exclude=known)
    assert k == first and k <= 41
    assert np.array_equal(found.pose, each[k].pose) and found.score == each[k].score
    assert first_match(grid, live, centers[:first], 0.6, math.radians(10), floor,
                       exclude=known) is None


def test_a_grid_needs_points():
    with pytest.raises(ValueError, match="at least one"):
        SearchGrid(np.zeros((0, 2)))


def test_the_search_is_independent_of_where_the_points_lie():
    """Points far off the grid score nothing and break nothing (no bounds checks needed)."""
    world = _room()
    grid = SearchGrid(world, 0.1, 0.1, depth=4, max_window=1.0)
    truth = np.array([3.0, 2.0, 0.2])
    live = np.vstack([_seen_from(world, truth), [[500.0, -300.0], [-1e4, 1e4]]])
    found = search(grid, live, compose(truth, [0.2, 0.1, 0.0]), 0.5, 0.1)
    assert np.hypot(*(found.pose[:2] - truth[:2])) <= 0.1


def _likelihood_by_distance_transform(points, resolution, sigma, pad):
    """The likelihood grid as a Euclidean distance transform of the whole grid gives it
    (the spec the stamped cells must match)."""
    from scipy.ndimage import distance_transform_edt

    margin = math.ceil(3.0 * sigma / resolution) + 1
    lo = points.min(axis=0) - margin * resolution
    hi = points.max(axis=0) + margin * resolution
    shape = np.ceil((hi - lo) / resolution).astype(np.int64) + 1
    cells = np.rint((points - lo) / resolution).astype(np.int64)
    free = np.ones(tuple(shape), dtype=bool)
    free[cells[:, 0], cells[:, 1]] = False
    field = np.exp(-0.5 * (distance_transform_edt(free) * resolution / sigma) ** 2)
    return lo - pad * resolution, np.pad(np.round(255.0 * field).astype(np.uint8), pad)


@pytest.mark.parametrize(("resolution", "sigma", "pad"),
                         [(0.1, 0.1, 0), (0.1, 0.1, 7), (0.05, 0.1, 3), (0.1, 0.25, 1),
                          (0.1, 0.05, 2)])
def test_the_stamped_likelihood_is_the_distance_transforms(resolution, sigma, pad):
    from vmp.branch_bound import likelihood_grid

    rng = np.random.default_rng(3)
    points = np.vstack([_room(), rng.uniform(-2, 14, (300, 2))])
    origin, grid = likelihood_grid(points, resolution, sigma, pad)
    want_origin, want = _likelihood_by_distance_transform(points, resolution, sigma, pad)
    np.testing.assert_array_equal(origin, want_origin)
    assert grid.dtype == np.uint8 and grid.shape == want.shape
    np.testing.assert_array_equal(grid, want)


def test_a_block_maximum_is_numpys():
    from vmp.branch_bound import _block_max

    def in_numpy(grid, step):  # the spec the compiled one must match
        out = grid.copy()
        out[:-step, :] = np.maximum(out[:-step, :], grid[step:, :])
        shifted = out.copy()
        out[:, :-step] = np.maximum(out[:, :-step], shifted[:, step:])
        return out

    grid = np.random.default_rng(5).integers(0, 256, (37, 23)).astype(np.uint8)
    for step in (1, 2, 4, 16, 30):
        out = np.zeros_like(grid)
        _block_max(grid, step, (0, 37), (0, 23), out)
        np.testing.assert_array_equal(out, in_numpy(grid, step))
    grid[:5], grid[30:], grid[:, :3], grid[:, 20:] = 0, 0, 0, 0  # zero but rows 5-29, cols 3-19
    for step in (1, 3, 8):
        out = np.zeros_like(grid)
        _block_max(grid, step, (5, 30), (3, 20), out)
        np.testing.assert_array_equal(out, in_numpy(grid, step))


# ---- the search in NumPy, the spec: the compiled one must agree ---------------------------

def _search_in_numpy(grid, points, center, window_xy, window_theta, min_score=0.0,
                     exclude=None):
    """The best pose of ``points`` within ``window_xy`` (either way, in x and y) and
    ``window_theta`` of ``center``, or None when no pose scores ``min_score``.

    ``exclude`` (a pose, a distance and a turn) leaves out the poses that near it: the best
    pose elsewhere, to tell a clear peak from one of several alike.
    """
    pts = np.asarray(points, dtype=np.float64)
    res, depth = grid.resolution, grid.depth
    thetas = center[2] + _angles(pts, res, window_theta)
    steps = min(math.ceil(window_xy / res - 1e-9), grid.max_steps)
    # Each rotation's points, placed at the window's centre: cell indices (R, M), clamped.
    c = np.array([math.cos(t) for t in thetas])[:, None]
    s = np.array([math.sin(t) for t in thetas])[:, None]
    cx = np.rint((center[0] + c * pts[:, 0] - s * pts[:, 1] - grid.origin[0]) / res)
    cy = np.rint((center[1] + s * pts[:, 0] + c * pts[:, 1] - grid.origin[1]) / res)
    lo, hi_x, hi_y = grid.bounds
    cx = np.clip(cx.astype(np.int64), lo, hi_x)
    cy = np.clip(cy.astype(np.int64), lo, hi_y)
    scale = 255.0 * len(pts)
    stride = grid.shape[1]
    flat = np.ascontiguousarray(cx * stride + cy)  # (R, M) flat cell indices
    levels = [g.ravel() for g in grid.levels]

    def scores(level: int, rot: np.ndarray, ox: np.ndarray, oy: np.ndarray) -> np.ndarray:
        out = block_sums(levels[level], flat, rot, ox * stride + oy) / scale
        if level == 0 and exclude is not None:  # bounds above stay bounds
            pose, dxy, dth = exclude
            near = (np.hypot(center[0] + ox * res - pose[0], center[1] + oy * res - pose[1])
                    < dxy) & (np.abs((thetas[rot] - pose[2] + math.pi) % (2 * math.pi)
                                     - math.pi) < dth)
            out[near] = -1.0
        return out

    # The coarsest candidates: blocks of 2^depth cells whose children cover the window.
    top = 1 << depth
    corners = np.arange(-steps, steps + 1, top)
    rot, ox, oy = (a.ravel() for a in np.meshgrid(np.arange(len(thetas)), corners, corners,
                                                  indexing="ij"))
    values = scores(depth, rot, ox, oy)
    evaluated = len(rot)
    best: tuple[float, tuple[int, int, int] | None] = (min_score, None)
    for level in range(depth, 0, -1):
        keep = values >= best[0]
        if not keep.any():
            break
        rot, ox, oy, values = rot[keep], ox[keep], oy[keep], values[keep]
        best = _dive_in_numpy(scores, level, rot, ox, oy, values, steps, best)
        half = 1 << (level - 1)
        n = len(rot)
        rot = np.repeat(rot, 4)
        ox = np.repeat(ox, 4) + np.tile([0, half, 0, half], n)
        oy = np.repeat(oy, 4) + np.tile([0, 0, half, half], n)
        inside = (ox <= steps) & (oy <= steps)
        rot, ox, oy = rot[inside], ox[inside], oy[inside]
        values = scores(level - 1, rot, ox, oy)
        evaluated += len(rot)
        if level == 1 and len(values):  # exact scores: the leaves
            i = int(np.argmax(values))
            if values[i] >= best[0]:
                best = (float(values[i]), (int(rot[i]), int(ox[i]), int(oy[i])))
    if best[1] is None:
        return None
    r, x, y = best[1]
    pose = np.array([center[0] + x * res, center[1] + y * res,
                     (thetas[r] + math.pi) % (2 * math.pi) - math.pi])
    return Match(pose, best[0], evaluated)


def _dive_in_numpy(scores, level: int, rot: np.ndarray, ox: np.ndarray, oy: np.ndarray,
          level_scores: np.ndarray, steps: int, best: tuple) -> tuple:
    """Follow the best candidate's best child down to level 0; a better exact score found
    on the way raises the bound that prunes the others."""
    i = int(np.argmax(level_scores))
    r, x, y = rot[i], ox[i], oy[i]
    for lv in range(level, 0, -1):
        half = 1 << (lv - 1)
        cx = np.array([x, x + half, x, x + half])
        cy = np.array([y, y, y + half, y + half])
        ok = (cx <= steps) & (cy <= steps)
        cx, cy = cx[ok], cy[ok]
        s = scores(lv - 1, np.full(len(cx), r), cx, cy)
        j = int(np.argmax(s))
        x, y = cx[j], cy[j]
        if lv == 1 and s[j] >= best[0]:
            return float(s[j]), (int(r), int(x), int(y))
    return best


def test_the_compiled_search_is_the_numpy_search():
    world = _room()
    rng = np.random.default_rng(11)
    grid = SearchGrid(world, 0.1, 0.1, depth=5, max_window=4.0)
    for trial in range(40):
        truth = np.array([rng.uniform(2, 10), rng.uniform(2, 6), rng.uniform(-3, 3)])
        pts = _seen_from(world, truth, keep=int(rng.integers(30, 150)))
        pts = pts + rng.normal(0, 0.02, pts.shape)
        center = truth + [rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-0.2, 0.2)]
        wxy, wth = rng.uniform(0.3, 4.0), rng.uniform(0.05, 0.5)
        floor = rng.uniform(0.0, 0.8)
        for exclude in (None, (truth, 0.5, 0.1)):
            got = search(grid, pts, center, wxy, wth, floor, exclude=exclude)
            want = _search_in_numpy(grid, pts, center, wxy, wth, floor, exclude=exclude)
            assert (got is None) == (want is None), trial
            if got is not None:
                np.testing.assert_array_equal(got.pose, want.pose)
                assert got.score == want.score


def test_rotations_bounded_in_groups_keep_every_answer():
    # The localizer's search along a saved path: a window of 0.6 m and 10 degrees about each
    # of many centres, a floor near the right place's score. Rotations bounded in groups
    # (and the search started at the level that covers the window) must find what the
    # search of every rotation finds, centre by centre, where it finds a pose and where not.
    world = _room()
    rng = np.random.default_rng(13)
    grid = SearchGrid(world, 0.1, 0.1, depth=5, max_window=4.0)
    truth = np.array([5.5, 3.0, 0.7])
    pts = _seen_from(world, truth, keep=100) + rng.normal(0, 0.02, (100, 2))
    floor = grid.score(pts, truth) - 0.02
    centers = np.column_stack([rng.uniform(1, 11, 300), rng.uniform(1, 7, 300),
                               rng.uniform(-3, 3, 300)])
    centers[150] = truth + [0.3, -0.2, 0.05]
    found_some = 0
    for center in centers:
        got = search(grid, pts, center, 0.6, math.radians(10), floor)
        want = _search_in_numpy(grid, pts, center, 0.6, math.radians(10), floor)
        assert (got is None) == (want is None)
        if got is not None:
            np.testing.assert_array_equal(got.pose, want.pose)
            assert got.score == want.score
            found_some += 1
    assert 0 < found_some < len(centers)
    found = first_match(grid, pts, centers, 0.6, math.radians(10), floor)
    assert found is not None and found[0] <= 150
    assert found[1].score >= floor


def test_a_window_under_one_block_is_searched_from_its_quarters_with_the_same_answers():
    # A window that one block of a level covers is searched from that block's four quarters
    # in the order its children are visited, rotations bounded on the covering level: the
    # same answers as the search from the top level, ties included. Two posts the scanner's
    # own point (the scan origin) fits equally well, one in the quarter of high x and low y,
    # one in that of low x and high y: the order decides which is returned.
    for steps in (3, 5, 6, 7, 9, 10, 11, 12, 13, 14, 15):
        k = (steps - 1) * 0.1
        center = np.array([10.0, 10.0, 0.3])
        posts = np.array([[10.0 + k, 10.0 - k], [10.0 - k, 10.0 + k], [0.0, 0.0], [20.0, 20.0]])
        grid = SearchGrid(posts, 0.1, 0.1, depth=5, max_window=2.0)
        origin = np.zeros((1, 2))
        got = search(grid, origin, center, steps * 0.1, math.radians(3))
        want = _search_in_numpy(grid, origin, center, steps * 0.1, math.radians(3))
        assert got.score == want.score == 1.0
        np.testing.assert_array_equal(got.pose, want.pose)
        np.testing.assert_allclose(got.pose[:2], posts[0], atol=1e-9)  # high x comes first
    # And where poses do not tie: windows of the test room, answers and scores as the
    # search from the top level has them.
    world = _room()
    grid = SearchGrid(world, 0.1, 0.1, depth=5, max_window=2.0)
    rng = np.random.default_rng(17)
    for steps in range(1, 17):
        truth = np.array([rng.uniform(2, 10), rng.uniform(2, 6), rng.uniform(-3, 3)])
        pts = _seen_from(world, truth, keep=int(rng.integers(30, 120)))
        center = truth + [rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 0.05]
        floor = rng.uniform(0.0, 0.7)
        got = search(grid, pts, center, steps * 0.1, math.radians(5), floor)
        want = _search_in_numpy(grid, pts, center, steps * 0.1, math.radians(5), floor)
        assert (got is None) == (want is None), steps
        if got is not None:
            np.testing.assert_array_equal(got.pose, want.pose)
            assert got.score == want.score


def test_the_compiled_score_is_the_mean_over_the_clamped_cells():
    grid = SearchGrid(_room(), 0.1, 0.1, depth=5, max_window=4.0)
    rng = np.random.default_rng(12)
    lo, hi = grid.max_steps, np.array(grid.shape) - 1 - grid.max_steps - (1 << grid.depth)
    for _ in range(50):
        pts = rng.uniform(-30, 30, (int(rng.integers(1, 200)), 2))  # some far off the grid
        pose = np.array([rng.uniform(-5, 15), rng.uniform(-5, 12), rng.uniform(-4, 4)])
        c, s = math.cos(pose[2]), math.sin(pose[2])
        cx = np.rint((pose[0] + c * pts[:, 0] - s * pts[:, 1] - grid.origin[0]) / 0.1)
        cy = np.rint((pose[1] + s * pts[:, 0] + c * pts[:, 1] - grid.origin[1]) / 0.1)
        cx = np.clip(cx.astype(np.int64), lo, hi[0])
        cy = np.clip(cy.astype(np.int64), lo, hi[1])
        assert grid.score(pts, pose) == grid.levels[0][cx, cy].mean() / 255.0
    assert grid.score(np.zeros((0, 2)), np.zeros(3)) == 0.0
