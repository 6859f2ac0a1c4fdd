"""The whole mapper on the built-in scenarios, its map file, and the commands around it."""

import math

import numpy as np
import pytest

from drivers.scenario import load_scenario
from drivers.simulator import Simulator
from vmp.cli import main
from vmp.evaluate import ate, wrong_corrections
from vmp.mapfile import load_map, save_map
from vmp.pipeline import Pipeline
from vmp.vector_map import BeamGeometry

RUNS = {}


def run(name, scans=None):
    key = (name, scans)
    if key not in RUNS:
        sim = Simulator(load_scenario(name), max_scans=scans)
        s = sim.sensor
        p = Pipeline(BeamGeometry(s.beams, s.angle_min, s.angle_increment, s.max_range))
        for f in sim:
            p.step(f)
        p.finish()
        RUNS[key] = (p, sim)
    return RUNS[key]


def ate_of(p, sim):
    traj = p.trajectory()
    return (ate(sim.stamps, traj, sim.stamps, sim.true_poses).rmse,
            ate(sim.stamps, sim.odom_poses, sim.stamps, sim.true_poses).rmse)


def test_office_ate_is_under_5_cm_and_5_times_below_odometry():
    p, sim = run("office")
    mapped, odom = ate_of(p, sim)
    assert mapped <= 0.05 and mapped * 5 <= odom, (mapped, odom)
    assert p.stats["loop edges"] >= 1 and len(p.milestones) > 20
    assert wrong_corrections(p.corrections, sim.true_poses) == []


def test_warehouse_ate_is_under_5_cm_and_5_times_below_odometry():
    p, sim = run("warehouse")
    mapped, odom = ate_of(p, sim)
    assert mapped <= 0.05 and mapped * 5 <= odom, (mapped, odom)


def test_corridor_never_corrects_wrongly():
    p, sim = run("corridor")
    assert len(p.corrections) > 50
    assert wrong_corrections(p.corrections, sim.true_poses) == []


def test_lab_is_mapped_to_a_centimetre():
    p, sim = run("lab")
    mapped, odom = ate_of(p, sim)
    assert mapped < 0.01 < odom


def test_a_rejected_match_changes_nothing():
    p, _ = run("lab", scans=200)
    frames = list(Simulator(load_scenario("office"), max_scans=3))
    pose, cov = p.filter.pose.copy(), p.filter.covariance.copy()
    matches = p.match(frames[-1])  # a scan from another building
    assert matches and not any(m.accepted for m in matches)
    p.correct(matches)
    np.testing.assert_array_equal(p.filter.pose, pose)
    np.testing.assert_array_equal(p.filter.covariance, cov)


def test_map_file_round_trip_is_exact(tmp_path):
    p, _ = run("lab", scans=200)
    traj = p.trajectory()
    save_map(tmp_path / "m.vmpmap", p.map, p.milestones, p.graph, {"note": "test"}, traj)
    back = load_map(tmp_path / "m.vmpmap")
    for name in ("end_points", "packed_hits", "rel_poses", "segments", "stamps"):
        a, b = getattr(p.map, name), getattr(back.map, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert back.map.segment_anchor == p.map.segment_anchor
    np.testing.assert_array_equal(back.milestones.poses, p.milestones.poses)
    np.testing.assert_array_equal(back.trajectory, traj)
    assert [(e.i, e.j, e.kind) for e in back.graph.edges] == \
        [(e.i, e.j, e.kind) for e in p.graph.edges]
    np.testing.assert_array_equal(back.map.world_poses(back.milestones.poses), traj)
    (tmp_path / "junk.vmpmap").write_bytes(b"not a map")
    from vmp.errors import InputError
    with pytest.raises(InputError, match=r"junk\.vmpmap"):
        load_map(tmp_path / "junk.vmpmap")


def test_map_export_evaluate_commands(tmp_path, capsys):
    out = tmp_path / "res"
    assert main(["map", "lab", "--scans", "300", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "ATE (m)" in said and "scans per second" in said
    latest = out / "latest"
    for name in ("trajectory.tum", "online.tum", "odometry.tum", "ground_truth.tum",
                 "map.vmpmap", "milestones.npz", "grid.yaml", "grid.pgm", "grid.png",
                 "grid.npy", "contours.geojson", "graph.json", "config.yaml", "metrics.json"):
        assert (latest / name).is_file(), name
    grid = tmp_path / "g" / "map.yaml"
    assert main(["export", str(latest), "--grid", str(grid), "--resolution", "0.1",
                 "--png", str(tmp_path / "g.png"), "--npy", str(tmp_path / "g.npy")]) == 0
    assert (tmp_path / "g" / "map.pgm").is_file()
    assert np.load(tmp_path / "g.npy", allow_pickle=False).dtype == np.uint8
    assert main(["evaluate", str(latest), "--ground-truth",
                 str(latest / "ground_truth.tum")]) == 0
    said = capsys.readouterr().out
    rmse = float(said.split("ATE  rmse ")[1].split()[0])
    assert rmse < 0.02
    # The configuration written with a result maps the same way when given back.
    assert main(["map", "lab", "--scans", "50", "--out", str(out), "-q", "--config",
                 str(latest / "config.yaml")]) == 0


@pytest.mark.parametrize("argv, message", [
    (["map", "nowhere.clf"], "nowhere.clf: no such file"),
    (["map", "lab", "--resolution", "-1"], "--resolution must be positive"),
    (["export", "."], "nothing to export"),
    (["evaluate", "."], "give --ground-truth"),
])
def test_mapping_mistakes_get_one_line(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_bad_config_names_file_and_key(tmp_path, capsys):
    bad = tmp_path / "c.yaml"
    bad.write_text("registration: {max_iteration: 3}\n")
    assert main(["map", "lab", "--scans", "5", "--config", str(bad), "--out",
                 str(tmp_path)]) == 2
    assert "c.yaml: registration.max_iteration: unknown key" in capsys.readouterr().err


def test_map_of_a_carmen_log(tmp_path, capsys):
    log = tmp_path / "lab.clf"
    assert main(["simulate", "lab", "--scans", "200", "--out", str(log), "-q"]) == 0
    assert main(["map", str(log), "--out", str(tmp_path / "r"), "-q"]) == 0
    assert main(["evaluate", str(tmp_path / "r" / "latest"), "--ground-truth",
                 str(log.with_suffix(".tum"))]) == 0
    rmse = float(capsys.readouterr().out.split("ATE  rmse ")[1].split()[0])
    assert rmse < 0.03
    assert math.isfinite(rmse)
