"""Trajectory metrics: ATE and RPE as evo computes them, Kümmerle relations, wrong corrections."""

import math

import numpy as np
import pytest

from vmp.errors import InputError
from vmp.evaluate import align_se2, ate, read_relations, relation_error, rpe, wrong_corrections
from vmp.types import compose, relative


def literal_ate(est, ref):
    """ATE by brute force: the best rotation on a fine grid, translation by the centroids."""
    best = np.inf
    for th in np.linspace(-np.pi, np.pi, 20001):
        c, s = np.cos(th), np.sin(th)
        p = est[:, :2] @ np.array([[c, s], [-s, c]])
        t = ref[:, :2].mean(axis=0) - p.mean(axis=0)
        err = np.sqrt(np.mean(np.sum((p + t - ref[:, :2]) ** 2, axis=1)))
        best = min(best, err)
    return best


def test_ate_equals_the_literal_alignment():
    rng = np.random.default_rng(1)
    ref = np.cumsum(rng.normal(0, 0.3, (200, 3)), axis=0)
    est = compose([2.0, -1.0, 0.7], ref) + rng.normal(0, 0.05, (200, 3))
    stamps = np.arange(200) * 0.1
    a = ate(stamps, est, stamps, ref)
    assert math.isclose(a.rmse, literal_ate(est, ref), rel_tol=1e-4)
    T = align_se2(est, ref)
    assert math.isclose(math.atan2(math.sin(T[2] + 0.7), math.cos(T[2] + 0.7)), 0.0,
                        abs_tol=0.02)
    assert ate(stamps, ref, stamps, ref).rmse < 1e-9


def test_rpe_by_hand():
    stamps = np.arange(5.0)
    ref = np.array([[i, 0.0, 0.0] for i in range(5)])
    est = np.array([[1.1 * i, 0.0, 0.0] for i in range(5)])  # 10 % too long
    r = rpe(stamps, est, stamps, ref, delta=1)
    assert math.isclose(r.trans_rmse, 0.1, rel_tol=1e-9) and r.rot_rmse == 0.0


def test_relation_metric(tmp_path):
    stamps = np.arange(10.0) + 1000.0
    truth = np.array([[i * 0.5, 0.1 * i, 0.05 * i] for i in range(10)])
    lines = []
    for a, b in ((0, 3), (2, 9), (5, 6)):
        rel = relative(truth[a], truth[b])
        lines.append(f"{stamps[a]} {stamps[b]} {rel[0]} {rel[1]} 0 0 0 {rel[2]}")
    lines.append("999.0 1001.0 0 0 0 0 0 0")  # a stamp with no scan: not used
    path = tmp_path / "r.relations"
    path.write_text("\n".join(lines) + "\n")
    rels = read_relations(path)
    exact = relation_error(stamps, truth, rels)
    assert exact.used == 3 and exact.total == 4 and exact.trans_mean < 1e-12
    shifted = truth.copy()
    shifted[9] += [0.2, 0.0, 0.0]
    e = relation_error(stamps, shifted, rels)
    assert math.isclose(e.trans_mean, 0.2 / 3, rel_tol=1e-6)
    bad = tmp_path / "bad.relations"
    bad.write_text("1 2 3\n")
    with pytest.raises(InputError, match=r"bad\.relations:1"):
        read_relations(bad)


def test_ate_and_rpe_equal_what_evo_computes(tmp_path):
    """Users check our numbers with evo: same files, same figures."""
    from evo.core import metrics as evo_metrics
    from evo.core import sync
    from evo.main_ape import ape
    from evo.main_rpe import rpe as evo_rpe
    from evo.tools import file_interface

    from vmp.tum import read_tum, write_tum

    rng = np.random.default_rng(3)
    ref = np.cumsum(rng.normal(0, [0.05, 0.05, 0.02], (500, 3)), axis=0)
    est = compose([1.5, -2.0, 0.4], ref) + rng.normal(0, [0.02, 0.02, 0.005], (500, 3))
    stamps = 1000.0 + np.arange(500) * 0.1
    write_tum(tmp_path / "ref.tum", stamps, ref)
    write_tum(tmp_path / "est.tum", stamps, est)
    s, e = read_tum(tmp_path / "est.tum")
    gs, g = read_tum(tmp_path / "ref.tum")
    ours_ate = ate(s, e, gs, g)
    ours_rpe = rpe(s, e, gs, g, delta=5)

    traj_ref = file_interface.read_tum_trajectory_file(str(tmp_path / "ref.tum"))
    traj_est = file_interface.read_tum_trajectory_file(str(tmp_path / "est.tum"))
    traj_ref, traj_est = sync.associate_trajectories(traj_ref, traj_est, max_diff=0.01)
    theirs_ate = ape(traj_ref, traj_est, pose_relation=evo_metrics.PoseRelation.translation_part,
                     align=True, correct_scale=False).stats["rmse"]
    theirs_rpe = evo_rpe(traj_ref, traj_est,
                         pose_relation=evo_metrics.PoseRelation.translation_part, delta=5,
                         delta_unit=evo_metrics.Unit.frames, all_pairs=True).stats["rmse"]
    assert math.isclose(ours_ate.rmse, theirs_ate, rel_tol=1e-6)
    assert math.isclose(ours_rpe.trans_rmse, theirs_rpe, rel_tol=1e-6)


def test_wrong_corrections_are_those_that_move_away_from_the_truth_by_more_than_the_limit():
    truth = np.zeros((3, 3))
    corrections = [
        (0, "anchor", np.array([0.3, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])),  # towards
        (1, "handover", np.array([0.0, 0.0, 0.0]), np.array([0.05, 0.0, 0.0])),  # 5 cm away
        (2, "graph", np.array([0.0, 0.1, 0.0]), np.array([0.0, 0.25, 0.0])),  # 15 cm away
        (9, "anchor", np.array([0.0, 0.0, 0.0]), np.array([0.0, -0.2, 0.0])),  # past the end
    ]
    assert wrong_corrections(corrections, truth) == [(2, "graph"), (9, "anchor")]
    assert wrong_corrections(corrections, truth, limit=0.01) == [
        (1, "handover"), (2, "graph"), (9, "anchor")]
    assert wrong_corrections([], truth) == []


def test_relations_between_keeps_those_whose_two_stamps_are_matched():
    from vmp.evaluate import relation_error, relations_between

    stamps = np.array([0.0, 1.0, 2.0, 3.0])
    rel = np.array([[0.0, 1.0, 1, 0, 0], [1.0, 2.5, 1, 0, 0], [2.0, 3.00001, 1, 0, 0]])
    kept = relations_between(stamps, rel)
    assert np.array_equal(kept, rel[[0, 2]])
    poses = np.c_[stamps, np.zeros(4), np.zeros(4)]
    assert relation_error(stamps, poses, rel).used == len(kept)
