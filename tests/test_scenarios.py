"""Built-in scenarios load; bad scenario files get errors naming the file, the key and the fix."""

import math

import numpy as np
import pytest

from drivers.scenario import ScenarioError, builtin_scenarios, load_scenario

BUILTIN = ["office", "corridor", "lab", "warehouse"]


def test_builtin_scenarios_are_listed():
    assert set(BUILTIN) <= set(builtin_scenarios())


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_scenario_loads(name):
    sc = load_scenario(name)
    assert sc.name == name
    assert sc.walls.ndim == 2 and sc.walls.shape[1] == 4 and len(sc.walls) > 4
    assert np.isfinite(sc.walls).all()
    assert sc.sensor.geometry.num_beams == 181
    assert math.isclose(math.degrees(sc.sensor.geometry.angle_increment), 1.0)
    assert sc.sensor.geometry.max_range == 8.0 and sc.sensor.rate_hz == 10.0


def test_scenarios_hold_what_the_issue_asks_for():
    office = load_scenario("office")
    assert office.trajectory.closed and office.trajectory.laps == 2
    assert office.obstacles
    lab = load_scenario("lab")
    assert lab.stations is not None and len(lab.stations.nearby) == 4
    wh = load_scenario("warehouse")
    loop = np.vstack([wh.trajectory.waypoints, wh.trajectory.waypoints[:1]])
    assert np.hypot(*np.diff(loop, axis=0).T).sum() >= 60.0


def test_repeat_lays_out_copies():
    wh = load_scenario("warehouse")
    # 5 rows x 13 shelving units x 4 sides, plus the shell and the rest.
    assert len(wh.walls) >= 5 * 13 * 4


def write(tmp_path, text, name="bad.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


GOOD_TRAJ = "trajectory: {waypoints: [[1, 1], [2, 1]]}\n"
GOOD_WALLS = "walls: [{polygon: [[0, 0], [3, 0], [3, 3]]}]\n"


@pytest.mark.parametrize(
    "text, expected",
    [
        (GOOD_TRAJ, r"bad\.yaml: walls: missing"),
        (GOOD_WALLS, r"bad\.yaml: trajectory: missing"),
        (GOOD_WALLS + GOOD_TRAJ + "sensor: {beams: -3}\n",
         r"bad\.yaml: sensor\.beams: expected an integer >= 2, got -3"),
        (GOOD_WALLS + GOOD_TRAJ + "sensor: {max_range: fast}\n",
         r"bad\.yaml: sensor\.max_range: expected a finite number, got 'fast'"),
        (GOOD_WALLS + GOOD_TRAJ + "sensor: {max_rnage: 8}\n",
         r"bad\.yaml: sensor\.max_rnage: unknown key; expected one of .*max_range"),
        ("walls: [{polygon: [[0, 0], [1], [2, 2]]}]\n" + GOOD_TRAJ,
         r"bad\.yaml: walls\[0\]\.polygon\[1\]: expected a list of 2 numbers"),
        ("walls: [{box: {center: [0, 0], size: [0, 1]}}]\n" + GOOD_TRAJ,
         r"walls\[0\]\.box\.size: expected a positive width and height"),
        ("walls: [{polygon: [[0, 0], [1, 0], [1, 1]], box: {center: [0, 0], size: [1, 1]}}]\n"
         + GOOD_TRAJ, r"walls\[0\]: expected exactly one of polygon, polyline or box"),
        (GOOD_WALLS + "trajectory: {waypoints: [[1, 1]]}\n",
         r"trajectory\.waypoints: expected a list of at least 2 points"),
        (GOOD_WALLS + "trajectory: {waypoints: [[1, 1], [2, 1]], laps: 2}\n",
         r"trajectory\.laps: expected laps only on a closed trajectory"),
        (GOOD_WALLS + "trajectory: {waypoints: [[1, 1], [2, 1]], speed: 0}\n",
         r"trajectory\.speed: expected a positive number, got 0"),
        (GOOD_WALLS + GOOD_TRAJ + "odometry: {trans_noise: -1}\n",
         r"odometry\.trans_noise: expected a number >= 0"),
        (GOOD_WALLS + GOOD_TRAJ + "stations: {home: [0, 0], nearby: []}\n",
         r"stations\.home: expected a list of 3 numbers"),
        (GOOD_WALLS + GOOD_TRAJ + "seed: 1.5\n", r"seed: expected an integer >= 0"),
        ("- just\n- a list\n", r"bad\.yaml: top level: expected a mapping of keys"),
        ("walls: [\n", r"bad\.yaml:\d+: not valid YAML"),
    ],
)
def test_bad_scenario_names_file_key_and_expectation(tmp_path, text, expected):
    with pytest.raises(ScenarioError, match=expected):
        load_scenario(write(tmp_path, text))


def test_unknown_scenario_lists_the_builtin_ones():
    with pytest.raises(ScenarioError, match=r"not a built-in scenario.*office"):
        load_scenario("nowhere")


def test_a_user_file_loads(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD_WALLS + GOOD_TRAJ, "mine.yaml"))
    assert sc.name == "mine" and len(sc.walls) == 3
