"""``vmp live`` on simulated devices: a map, a recording that replays bit for bit, clean stops."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from drivers.carmen import CarmenLog
from drivers.live import LiveSource
from drivers.pose_feed import PoseFeed, parse_pose_line
from drivers.scenario import load_scenario
from drivers.serial_scanner import ScanDriver
from drivers.simulator import Simulator
from vmp.cli import main
from vmp.run import MappingRun


def _live(tmp_path: Path, *extra: str) -> Path:
    out = tmp_path / "live"
    code = main(["live", "--simulate", "office", "--speed", "8", "--scans", "120",
                 "--out", str(out), "-q", *extra])
    assert code == 0
    return (out / "latest").resolve()


def _replay_matches(tmp_path: Path, result: Path) -> None:
    out = tmp_path / "replay"
    assert main(["map", str(result / "live.clf"), "--out", str(out), "-q"]) == 0
    live = (result / "trajectory.tum").read_bytes()
    replay = (out / "latest" / "trajectory.tum").read_bytes()
    assert live == replay  # bit for bit, stamps included


@pytest.mark.parametrize("driver", ["sick", "rplidar", "hokuyo"])
def test_live_maps_and_the_recording_replays_bit_for_bit(tmp_path, driver) -> None:
    result = _live(tmp_path, "--driver", driver)
    for name in ("trajectory.tum", "grid.yaml", "grid.pgm", "map.vmpmap", "metrics.json",
                 "contours.geojson"):
        assert (result / name).stat().st_size > 0
    metrics = json.loads((result / "metrics.json").read_text())
    assert metrics["odometry"].startswith("pose feed")
    assert metrics["scans"] >= 90 and metrics["scans waiting for odometry"] <= 3
    assert metrics["link: checksum errors"] == metrics["link: framing errors"] == 0
    traj = np.loadtxt(result / "trajectory.tum")
    assert np.ptp(traj[:, 1]) > 1.0  # the robot moved and the map followed
    _replay_matches(tmp_path, result)


def test_live_without_odometry_records_rawlaser_and_says_so(tmp_path) -> None:
    result = _live(tmp_path, "--driver", "sick", "--no-odometry")
    metrics = json.loads((result / "metrics.json").read_text())
    assert "registration only" in metrics["odometry"]
    text = (result / "live.clf").read_text()
    assert "\nRAWLASER1 " in text and "\nFLASER " not in text and "\nODOM " not in text
    frames = list(CarmenLog(result / "live.clf"))
    assert frames and all(f.odom is None for f in frames)
    _replay_matches(tmp_path, result)


def test_cli_refuses_simulation_options_on_a_real_port(tmp_path, capsys) -> None:
    out = ["--out", str(tmp_path)]
    assert main(["live", "--driver", "sick", "--port", "/dev/null", "--speed", "3", *out]) == 2
    assert "--simulate only" in capsys.readouterr().err
    assert run_cli(["live", "--driver", "sick", "--simulate", "office", "--scans", "0"]) == 2
    assert main(["live", "--driver", "rplidar", "--port", "/dev/ttyUSB-none", *out]) == 2
    assert "no such serial port" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no results folder left behind


class _SignallingDriver(ScanDriver):
    """Frames of a scenario; after ``after`` of them the process gets SIGTERM, as when a
    service manager stops a run."""

    name = "test"

    def __init__(self, after: int) -> None:
        super().__init__("test://")
        self.after = after

    def frames(self):
        for k, frame in enumerate(Simulator(load_scenario("office"), max_scans=400)):
            if self._stop:
                return
            if k == self.after:
                os.kill(os.getpid(), signal.SIGTERM)
            self.stats.scans += 1
            yield frame
            time.sleep(0.002)


def test_sigterm_ends_a_live_run_with_everything_written(tmp_path) -> None:
    source = LiveSource(_SignallingDriver(40), tmp_path / "live.clf")
    try:
        result = MappingRun(source).run()
    finally:
        source.shutdown()
    assert result.interrupted == "SIGTERM"
    # Stopped soon after the signal with what it had mapped (frames still queued behind the
    # mapper are dropped); the recording holds exactly the mapped scans.
    assert 1 <= result.scans <= 41
    assert len(list(CarmenLog(tmp_path / "live.clf"))) == result.scans
    result.write(tmp_path)
    assert (tmp_path / "grid.pgm").stat().st_size > 0
    assert result.metrics()["link: scans received"] >= result.scans


def test_pose_feed_lines_and_interpolation(tmp_path) -> None:
    assert parse_pose_line('{"x": 1, "y": 2.5, "theta": -0.1, "t": 3}').tolist() == [1, 2.5, -0.1]
    for bad, why in (('{"x": 1, "y": 2}', "theta"), ('{"x": NaN, "y": 0, "theta": 0}', "finite"),
                     ("[1, 2, 3]", "object"), ("x=1", "JSON"),
                     ('{"x": true, "y": 0, "theta": 0}', "finite")):
        with pytest.raises(ValueError, match=why):
            parse_pose_line(bad)
    fifo = tmp_path / "feed"
    os.mkfifo(fifo)
    clock = iter(np.arange(0.0, 100.0, 1.0)).__next__
    feed = PoseFeed(str(fifo), clock=clock).start()
    with open(fifo, "w") as w:
        w.write('{"x": 0, "y": 0, "theta": 3.0}\nnot json\n{"x": 2, "y": 4, "theta": -3.0}\n')
    deadline = time.monotonic() + 5
    while feed.count < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    feed.close()
    assert feed.count == 2 and feed.bad == 1 and feed.problems[0][0] == 2
    # Stamped 0 s and 2 s on arrival (the bad line took 1 s); halfway is interpolated, the
    # heading the short way round through pi.
    mid = feed.pose_at(1.0)
    assert mid[:2].tolist() == [1.0, 2.0]
    assert abs(abs(mid[2]) - np.pi) < 1e-9
    assert feed.pose_at(-5.0)[0] == 0.0 and feed.pose_at(50.0)[0] == 2.0
