"""The compiled ICP (vmp.icp_kernel) against SciPy's k-d tree and a plain NumPy transcription of
the same iterations."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from drivers.scenario import load_scenario
from drivers.simulator import Simulator
from vmp.icp_kernel import CYCLE, REVISIT, _column_rows, _nearest, fit_covariance, run_icp
from vmp.registration import (
    CORNER_WEIGHT,
    COVARIANCE_SCALE,
    DEGENERATE_SHARE,
    HUBER,
    MAX_ITERATIONS,
    MAX_SIGMA,
    MIN_CONSTRAINT,
    MIN_DISTANCE,
    MIN_SIGMA_THETA,
    MIN_SIGMA_XY,
    START_DISTANCE,
    TOLERANCE,
    Reference,
    last_gate,
)
from vmp.submaps import voxel_thin
from vmp.types import relative, transform_points


@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("gate", [0.08, 0.3, 0.5, 1.3])
def test_nearest_is_the_k_d_trees_nearest_within_the_gate(gate, dense):
    rng = np.random.default_rng(7)
    # Clusters along lines and, in the sparse reference, a few points far out, on both sides
    # of the origin (its cells found in a hash table; the dense one's in a table).
    t = rng.uniform(-20, 20, 400)
    pts = np.concatenate([np.stack([t, 0.3 * t + rng.normal(0, 0.02, 400)], 1),
                          rng.uniform(-3, 3, (100, 2))])
    pts = (np.concatenate([pts, rng.uniform(-20, 20, (6000, 2))]) if dense
           else np.concatenate([pts, [[1e4, -1e4], [-7e5, 3.0]]]))
    ref = Reference(pts)
    assert (ref.cells[2] >= 0) == dense  # a hashed reference's column is -1
    queries = np.concatenate([ref.points[:300] + rng.normal(0, 0.7 * gate, (300, 2)),
                              rng.uniform(-25, 25, (300, 2)), [[1e4, -1e4 + 0.01]],
                              # exactly on cell borders
                              [[0.0, 0.0], [0.5, -0.5], [-1.0, 2.5]]])
    dist, _ = cKDTree(ref.points).query(queries, distance_upper_bound=gate)
    found = np.array([_nearest(ref.cells, ref.points, q[0], q[1], gate) for q in queries])
    hit = np.isfinite(dist)
    assert hit.sum() > 100 and (~hit).sum() > 100  # both kinds are tested
    assert np.all(found[~hit] == -1)
    # The same point, or one exactly as near (ties).
    near = np.hypot(*(ref.points[found[hit]] - queries[hit]).T)
    assert np.allclose(near, dist[hit], rtol=0, atol=1e-12)
    # Asked for any within the gate: one exactly where the nearest is.
    first = np.array([_nearest(ref.cells, ref.points, q[0], q[1], gate, True) for q in queries])
    assert np.all((first >= 0) == hit)
    assert np.all(np.hypot(*(ref.points[first[hit]] - queries[hit]).T) < gate)


def test_a_dense_references_table_gives_the_rows_the_binary_search_does():
    rng = np.random.default_rng(4)
    ref = Reference(np.concatenate([rng.uniform(-10, 10, (3000, 2)),
                                    rng.normal(0, 0.3, (2000, 2)) + [3.0, -2.0]]))
    keys, table, col0, row0 = ref.cells
    assert table.shape == (40, 41)  # 20 m in 0.5 m cells, and the columns' ends
    searched = (keys, np.zeros((0, 0), dtype=np.int64), 0, 0)
    # Columns and rows inside the box, at its edges and beyond it on every side.
    for col in range(col0 - 3, col0 + table.shape[0] + 3):
        for row_lo, row_hi in [(row0 - 5, row0 - 1), (row0 - 2, row0 + 1), (row0 + 7, row0 + 7),
                               (row0 + 10, row0 + 30), (row0 + 38, row0 + 45),
                               (row0 + 41, row0 + 44), (row0 - 9, row0 + 60)]:
            # The same rows (empty ranges alike, wherever they start).
            assert (range(*_column_rows(ref.cells, col, row_lo, row_hi))
                    == range(*_column_rows(searched, col, row_lo, row_hi)))


def test_a_sparse_references_hash_table_gives_the_rows_the_binary_search_does():
    """A scan's cells (a few hundred spread over 80 m and more, some far out) found in the
    hash table, cell by cell, give the rows two binary searches do, for every span of rows a
    gate asks for and beyond (where the searches are used)."""
    rng = np.random.default_rng(5)
    angles = rng.uniform(-math.pi, math.pi, 180)
    ranges = rng.uniform(0.5, 40.0, 180)
    pts = np.concatenate([np.stack([ranges * np.cos(angles), ranges * np.sin(angles)], 1),
                          [[1e4, -1e4], [-7e5, 3.0]], rng.normal(0, 0.2, (40, 2))])
    ref = Reference(pts)
    keys, table, col0, row0 = ref.cells
    assert col0 == row0 == -1 and table.shape[1] == 3
    assert (table[:, 0] >= 0).sum() == len(np.unique(keys))  # every cell, once
    searched = (keys, np.zeros((0, 0), dtype=np.int64), 0, 0)
    cols, rows = keys // (1 << 32), keys % (1 << 32)
    for col in np.unique(np.concatenate([cols, cols - 1, cols + 2])):
        for row in np.unique(rows[np.abs(cols - col) <= 1])[:30]:
            for row_lo, row_hi in [(row, row), (row - 1, row + 1), (row - 2, row + 1),
                                   (row + 1, row + 2), (row - 3, row + 3), (row - 9, row + 9)]:
                # The same rows (empty ranges alike, wherever they start).
                assert (range(*_column_rows(ref.cells, col, row_lo, row_hi))
                        == range(*_column_rows(searched, col, row_lo, row_hi)))


def _numpy_icp(reference, pts, initial, corners, cycles=False, settle=0.0):
    """The ICP loop in NumPy, the spec the compiled one must match; with
    ``cycles``, stopped where a step returns to within the tolerance of where one of the
    last :data:`CYCLE` steps started; with ``settle``, where a step changes the matched
    points' residuals by less than ``settle`` (weighted RMS, to first order)."""
    tree = cKDTree(reference.points)
    line_of = np.append(reference.valid, False)
    corner_of = np.append(reference.corner, False)
    x, y, th = initial
    gate, H, rms, wsum, inliers = START_DISTANCE, np.zeros((3, 3)), np.inf, 0.0, 0.0
    converged = False
    starts = []
    for it in range(1, MAX_ITERATIONS + 1):  # noqa: B007 - returned
        starts = [*starts[-(CYCLE - 1):], (x, y, th)]
        c, s = math.cos(th), math.sin(th)
        q = pts @ np.array([[c, s], [-s, c]]) + (x, y)
        _, idx = tree.query(q, distance_upper_bound=gate)
        line = line_of[idx]
        corner = corner_of[idx] if corners else np.zeros(len(q), bool)
        if line.sum() + corner.sum() < 6:
            break
        n = reference.normals[idx[line]]
        qm = q[line]
        e = ((qm - reference.points[idx[line]]) * n).sum(1)
        w = np.minimum(1.0, HUBER / np.maximum(np.abs(e), 1e-12))
        J = np.column_stack([n, n[:, 1] * qm[:, 0] - n[:, 0] * qm[:, 1]])
        qc = q[corner]
        dc = qc - reference.points[idx[corner]]
        ac = np.hypot(dc[:, 0], dc[:, 1])
        wc = CORNER_WEIGHT * np.where(ac <= HUBER, 1.0, HUBER / np.maximum(ac, 1e-12))
        Jc = np.zeros((2 * len(qc), 3))
        Jc[0::2, 0], Jc[0::2, 2], Jc[1::2, 1], Jc[1::2, 2] = 1.0, -qc[:, 1], 1.0, qc[:, 0]
        J, e, w = np.concatenate([J, Jc]), np.concatenate([e, dc.ravel()]), np.concatenate(
            [w, np.repeat(wc, 2)])
        H = (J * w[:, None]).T @ J
        wsum = w.sum()
        dx, dy, dth = step = -np.linalg.solve(H + 1e-9 * np.eye(3), (J * w[:, None]).T @ e)
        x, y = dx + math.cos(dth) * x - math.sin(dth) * y, dy + math.sin(dth) * x + math.cos(
            dth) * y
        th = (th + dth + math.pi) % (2 * math.pi) - math.pi
        rms = math.sqrt(w @ (e * e) / wsum)
        inliers = (line.sum() + corner.sum()) / len(pts)
        gate = min(gate, last_gate(rms))
        if max(abs(dx), abs(dy), abs(dth)) < TOLERANCE or step @ H @ step < settle**2 * wsum:
            converged = True
            break
        if cycles and any(max(abs(x - a), abs(y - b), abs(
                (th - t + math.pi) % (2 * math.pi) - math.pi)) < REVISIT
                for a, b, t in starts):
            break
    return x, y, th, H, rms, inliers, wsum, it, converged


@pytest.mark.parametrize("corners", [False, True])
def test_the_compiled_icp_takes_the_numpy_loops_steps(corners):
    sim = Simulator(load_scenario("warehouse"))
    rng = np.random.default_rng(3)
    angles = sim.sensor.angles
    compared = 0
    for i in range(0, 2000, 100):
        a = sim.true_poses[i]
        b = a + [rng.normal(0, 0.2), rng.normal(0, 0.2), rng.normal(0, 0.05)]
        r = sim.ranges_at(np.vstack([a, b]), rng=rng)
        scans = [np.stack([rr * np.cos(angles), rr * np.sin(angles)], 1)[np.isfinite(rr)]
                 for rr in np.where(np.isfinite(r), r, np.nan)]
        ref = Reference(scans[0])
        guess = relative(a, b) + [0.1, -0.1, 0.03]
        got = run_icp(ref.cells, ref.points, ref.normals, ref.valid, ref.corner,
                      np.ascontiguousarray(scans[1]), *guess, corners, START_DISTANCE,
                      MIN_DISTANCE, HUBER, CORNER_WEIGHT, TOLERANCE, MAX_ITERATIONS)
        want = _numpy_icp(ref, scans[1], guess, corners)
        assert got[7] == want[7] and got[8] == want[8]  # iterations, converged
        assert np.allclose(got[:3], want[:3], rtol=0, atol=1e-9)
        assert np.allclose(got[3], want[3], rtol=1e-9, atol=1e-9)
        assert np.allclose(got[4:7], want[4:7], rtol=1e-9, atol=1e-12)
        compared += 1
    assert compared == 20


def _band_map_cases(seed, per_map):
    """Registrations against maps whose walls are bands (scans placed with 2 cm of error,
    thinned to 5 cm, as a saved map is): along the simulated warehouse, ``per_map`` per
    stretch, each (the reference, a live scan, a guess 5 cm and 0.6 deg off, the truth)."""
    sim = Simulator(load_scenario("warehouse"))
    rng = np.random.default_rng(seed)
    angles = sim.sensor.angles

    def scan(i):
        r = sim.ranges_at(sim.true_poses[i][None], rng=rng)[0]
        ok = np.isfinite(r)
        return np.stack([r[ok] * np.cos(angles[ok]), r[ok] * np.sin(angles[ok])], 1)

    for base in range(50, 1950, 100):
        world = [transform_points(sim.true_poses[j] + rng.normal(0, [0.02, 0.02, 0.005]),
                                  scan(j)) for j in range(base, base + 40, 2)]
        ref = Reference(voxel_thin(np.concatenate(world), 0.05))
        truth = sim.true_poses[base + 20]
        for _ in range(per_map):
            live = scan(base + 20)
            yield ref, live, truth + rng.normal(0, [0.05, 0.05, 0.01]), truth


def test_icp_that_cycles_stops_where_the_cycle_closes():
    """Against a map whose walls are bands, ICP's correspondences can alternate for ever
    between neighbouring points of a band: the compiled loop stops where a step comes back
    to where one began, as the spec does, where without that stop the spec runs on to the
    cap (asked to: the localizer's registrations against a saved map are)."""
    cycled = 0
    for ref, live, guess, _ in _band_map_cases(3, 10):
        got = run_icp(ref.cells, ref.points, ref.normals, ref.valid, ref.corner,
                      np.ascontiguousarray(live), *guess, False, START_DISTANCE,
                      MIN_DISTANCE, HUBER, CORNER_WEIGHT, TOLERANCE, MAX_ITERATIONS, REVISIT)
        want = _numpy_icp(ref, live, guess, False, cycles=True)
        assert got[7] == want[7] and got[8] == want[8]
        assert np.allclose(got[:3], want[:3], rtol=0, atol=1e-9)
        plain = _numpy_icp(ref, live, guess, False)
        if plain[7] != want[7]:  # stopped on a cycle: without the stop, on to the cap
            cycled += 1
            assert want[7] < plain[7] == MAX_ITERATIONS and not plain[8]
    assert cycled >= 5


def test_icp_asked_to_settle_stops_where_its_steps_no_longer_change_the_fit():
    """Against a map whose walls are bands, ICP slides on a millimetre a step where the fit
    barely sees it (along a wall band's slope, a corridor's axis): asked to settle, the
    compiled loop stops where a step changes the matched points' residuals by less than the
    tolerance, as the spec does, iterations sooner, and as near the truth."""
    sooner = saved = 0
    off_settled, off_plain = [], []
    for ref, live, guess, truth in _band_map_cases(5, 5):
        got = run_icp(ref.cells, ref.points, ref.normals, ref.valid, ref.corner,
                      np.ascontiguousarray(live), *guess, False, START_DISTANCE,
                      MIN_DISTANCE, HUBER, CORNER_WEIGHT, TOLERANCE, MAX_ITERATIONS, REVISIT,
                      TOLERANCE)
        want = _numpy_icp(ref, live, guess, False, cycles=True, settle=TOLERANCE)
        assert got[7] == want[7] and got[8] == want[8]
        assert np.allclose(got[:3], want[:3], rtol=0, atol=1e-9)
        plain = _numpy_icp(ref, live, guess, False, cycles=True)
        assert got[7] <= plain[7]
        sooner += got[7] < plain[7]
        saved += plain[7] - got[7]
        off_settled.append(math.dist(got[:2], truth[:2]))
        off_plain.append(math.dist(plain[:2], truth[:2]))
    # A third of them settle, two or more iterations sooner; as near the truth on the whole
    # (the slide they stop short of is the bands' own error, not the robot's pose).
    assert sooner >= 20 and saved >= 2 * sooner
    assert np.mean(off_settled) <= np.mean(off_plain) + 0.001


def test_a_pose_gone_to_nan_matches_nothing():
    ref = Reference(np.stack([np.linspace(0, 5, 50), np.ones(50)], 1))
    pts = np.stack([np.linspace(0, 5, 50), np.ones(50)], 1)
    out = run_icp(ref.cells, ref.points, ref.normals, ref.valid, ref.corner, pts,
                  math.nan, 0.0, 0.0, True, START_DISTANCE, MIN_DISTANCE, HUBER, CORNER_WEIGHT,
                  TOLERANCE, MAX_ITERATIONS)
    assert math.isinf(out[4]) and out[6] == 0.0 and out[7] == 1  # no fit, stopped at once


def _numpy_covariance(H, rms, wsum):
    """The fit's covariance and free directions as NumPy computed them."""
    tv, tvec = np.linalg.eigh(H[:2, :2])
    free = [v for amount, v in zip(tv, tvec.T, strict=True)
            if amount < MIN_CONSTRAINT or amount < DEGENERATE_SHARE * wsum]
    big = MAX_SIGMA**2
    sigma2 = max(rms, MIN_SIGMA_XY) ** 2 * COVARIANCE_SCALE
    vals, vecs = np.linalg.eigh(H)
    inv = np.where(vals > sigma2 / big, 1.0 / np.maximum(vals, 1e-300), big / sigma2)
    cov = sigma2 * (vecs * inv) @ vecs.T
    for v in free:
        cov[:2, :2] += big * np.outer(v, v)
    return cov + np.diag([MIN_SIGMA_XY**2, MIN_SIGMA_XY**2, MIN_SIGMA_THETA**2]), len(free)


def test_the_fits_covariance_is_the_numpy_one():
    rng = np.random.default_rng(11)
    frees = set()
    for _ in range(300):
        # Normals of matched points: some fits all along one wall (a corridor), some not.
        spread = rng.choice([0.02, 1.0])
        angle = rng.normal(0, spread, int(rng.integers(10, 200)))
        n = np.column_stack([np.cos(angle), np.sin(angle)])
        q = rng.uniform(-5, 5, (len(n), 2))
        J = np.column_stack([n, n[:, 1] * q[:, 0] - n[:, 0] * q[:, 1]])
        w = rng.uniform(0.2, 1, len(n))
        H = (J * w[:, None]).T @ J
        rms = float(rng.uniform(0.001, 0.05))
        got, free = fit_covariance(H, rms, float(w.sum()), MIN_CONSTRAINT, DEGENERATE_SHARE,
                                   COVARIANCE_SCALE, MIN_SIGMA_XY, MIN_SIGMA_THETA, MAX_SIGMA)
        want, want_free = _numpy_covariance(H, rms, float(w.sum()))
        assert free == want_free
        np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-12)
        frees.add(free)
    assert frees >= {0, 1}  # both kinds of fit were compared


@pytest.mark.parametrize("spread", [0.3, 1.2])  # the default, and wider than a cell
def test_point_normals_are_the_k_d_trees(spread):
    """Normals and kinds of reference points as a k-d tree's five nearest neighbours give
    them."""
    from vmp.icp_kernel import point_normals
    from vmp.registration import NEIGHBOURS
    rng = np.random.default_rng(2)
    t = rng.uniform(0, 10, 300)
    pts = np.concatenate([np.column_stack([t, 2 + 0.5 * t + rng.normal(0, 0.003, 300)]),
                          rng.uniform(-2, 12, (200, 2)),  # sparse: some isolated, some not
                          rng.normal([5.0, -3.0], 0.05, (40, 2))])  # a post: no line
    ref = Reference(pts)
    p = ref.points
    dist, idx = cKDTree(p).query(p, k=NEIGHBOURS)
    nb = p[idx]
    w = (dist <= spread).astype(np.float64)
    cnt = w.sum(axis=1)
    mean = (nb * w[..., None]).sum(axis=1) / cnt[:, None]
    d = (nb - mean[:, None, :]) * w[..., None]
    sxx, syy = (d[..., 0] ** 2).sum(axis=1), (d[..., 1] ** 2).sum(axis=1)
    sxy = (d[..., 0] * d[..., 1]).sum(axis=1)
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    normals = np.stack([-np.sin(angle), np.cos(angle)], axis=-1)
    tr, det = sxx + syy, sxx * syy - sxy**2
    disc = np.sqrt(np.maximum(tr**2 / 4 - det, 0.0))
    valid = (cnt >= 3) & (tr / 2 - disc <= 0.1 * np.maximum(tr / 2 + disc, 1e-12))
    corner = (cnt >= 3) & ~valid
    assert valid.sum() > 250 and corner.sum() > 20 and (cnt < 3).sum() > 5
    got_normals, got_valid, got_corner = point_normals(ref.cells, p, NEIGHBOURS, spread)
    np.testing.assert_array_equal(got_valid, valid)
    np.testing.assert_array_equal(got_corner, corner)
    np.testing.assert_allclose(got_normals, normals, rtol=0, atol=1e-12)


def test_the_share_explained_is_the_k_d_trees():
    """Points near a reference point, counted in its cells, as a k-d tree counts them."""
    from vmp.registration import explained

    rng = np.random.default_rng(9)
    ref = Reference(np.concatenate([rng.uniform(-20, 20, (3000, 2)),
                                    np.column_stack([np.linspace(0, 5, 200), np.zeros(200)])]))
    pts = rng.uniform(-22, 22, (500, 2))
    pose = np.array([0.3, -0.2, 0.4])
    for distance in (0.05, 0.2, 0.6, 1.3):
        placed = transform_points(pose, pts)
        dist, _ = cKDTree(ref.points).query(placed, distance_upper_bound=distance)
        want = np.count_nonzero(np.isfinite(dist)) / len(pts)
        assert 0.0 < want < 1.0
        assert explained(ref, pts, pose, distance) == want
    assert explained(ref, np.zeros((0, 2)), pose, 0.2) == 0.0
