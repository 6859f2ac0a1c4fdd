"""The compiled ICP (vmp.icp_kernel) against SciPy's k-d tree and a plain NumPy transcription of
the same iterations."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from drivers.scenario import load_scenario
from drivers.simulator import Simulator
from vmp.icp_kernel import _nearest, run_icp
from vmp.registration import (
    CORNER_WEIGHT,
    HUBER,
    MAX_ITERATIONS,
    MIN_DISTANCE,
    START_DISTANCE,
    TOLERANCE,
    Reference,
    last_gate,
)
from vmp.types import relative


@pytest.mark.parametrize("gate", [0.08, 0.3, 0.5, 1.3])
def test_nearest_is_the_k_d_trees_nearest_within_the_gate(gate):
    rng = np.random.default_rng(7)
    # Clusters along lines and a few points far out, on both sides of the origin.
    t = rng.uniform(-20, 20, 400)
    pts = np.concatenate([np.stack([t, 0.3 * t + rng.normal(0, 0.02, 400)], 1),
                          rng.uniform(-3, 3, (100, 2)), [[1e4, -1e4], [-7e5, 3.0]]])
    ref = Reference(pts)
    queries = np.concatenate([ref.points[:300] + rng.normal(0, 0.7 * gate, (300, 2)),
                              rng.uniform(-25, 25, (300, 2)), [[1e4, -1e4 + 0.01]],
                              # exactly on cell borders
                              [[0.0, 0.0], [0.5, -0.5], [-1.0, 2.5]]])
    dist, _ = cKDTree(ref.points).query(queries, distance_upper_bound=gate)
    found = np.array([_nearest(ref.cell_keys, ref.points, q[0], q[1], gate) for q in queries])
    hit = np.isfinite(dist)
    assert hit.sum() > 100 and (~hit).sum() > 100  # both kinds are tested
    assert np.all(found[~hit] == -1)
    # The same point, or one exactly as near (ties).
    near = np.hypot(*(ref.points[found[hit]] - queries[hit]).T)
    assert np.allclose(near, dist[hit], rtol=0, atol=1e-12)


def _numpy_icp(reference, pts, initial, corners):
    """The ICP loop as it was written in NumPy before it was compiled (the spec)."""
    tree = cKDTree(reference.points)
    line_of = np.append(reference.valid, False)
    corner_of = np.append(reference.corner, False)
    x, y, th = initial
    gate, H, rms, wsum, inliers = START_DISTANCE, np.zeros((3, 3)), np.inf, 0.0, 0.0
    converged = False
    for it in range(1, MAX_ITERATIONS + 1):  # noqa: B007 - returned
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
        dx, dy, dth = -np.linalg.solve(H + 1e-9 * np.eye(3), (J * w[:, None]).T @ e)
        x, y = dx + math.cos(dth) * x - math.sin(dth) * y, dy + math.sin(dth) * x + math.cos(
            dth) * y
        th = (th + dth + math.pi) % (2 * math.pi) - math.pi
        rms = math.sqrt(w @ (e * e) / wsum)
        inliers = (line.sum() + corner.sum()) / len(pts)
        gate = min(gate, last_gate(rms))
        if max(abs(dx), abs(dy), abs(dth)) < TOLERANCE:
            converged = True
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
        got = run_icp(ref.cell_keys, ref.points, ref.normals, ref.valid, ref.corner,
                      np.ascontiguousarray(scans[1]), *guess, corners, START_DISTANCE,
                      MIN_DISTANCE, HUBER, CORNER_WEIGHT, TOLERANCE, MAX_ITERATIONS)
        want = _numpy_icp(ref, scans[1], guess, corners)
        assert got[7] == want[7] and got[8] == want[8]  # iterations, converged
        assert np.allclose(got[:3], want[:3], rtol=0, atol=1e-9)
        assert np.allclose(got[3], want[3], rtol=1e-9, atol=1e-9)
        assert np.allclose(got[4:7], want[4:7], rtol=1e-9, atol=1e-12)
        compared += 1
    assert compared == 20


def test_a_pose_gone_to_nan_matches_nothing():
    ref = Reference(np.stack([np.linspace(0, 5, 50), np.ones(50)], 1))
    pts = np.stack([np.linspace(0, 5, 50), np.ones(50)], 1)
    out = run_icp(ref.cell_keys, ref.points, ref.normals, ref.valid, ref.corner, pts,
                  math.nan, 0.0, 0.0, True, START_DISTANCE, MIN_DISTANCE, HUBER, CORNER_WEIGHT,
                  TOLERANCE, MAX_ITERATIONS)
    assert math.isinf(out[4]) and out[6] == 0.0 and out[7] == 1  # no fit, stopped at once
