"""ROS 2 bags (sqlite3 and MCAP storage) and bare MCAP files: LaserScan with Odometry or tf."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from drivers.formats import detect_format, open_recording
from drivers.rosbag import RosBagLog, bag_topics
from drivers.scenario import load_scenario
from drivers.simulator import Simulator
from vmp.cli import main
from vmp.errors import InputError


def _write_bag(path: Path, storage: str, *, odometry: str = "odom", n: int = 12,
               broken: int | None = None) -> list:
    """A ROS 2 bag of ``n`` simulated office scans plus odometry at twice the scan rate."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    frames = list(Simulator(load_scenario("office"), max_scans=n))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        scan_c = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        odom_c = (w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
                  if odometry == "odom" else
                  w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=store))

        def stamp(t: float):
            return T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round(
                (t - int(t)) * 1e9))

        def header(t: float, frame: str):
            return T["std_msgs/msg/Header"](stamp=stamp(t), frame_id=frame)

        def quat(th: float):
            return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(th / 2),
                                                      w=math.cos(th / 2))

        t0 = 100.0
        odo_t = np.arange(0, n * 0.1, 0.05)
        odo_x = np.interp(odo_t, [f.stamp for f in frames], [f.odom[0] for f in frames])
        odo_y = np.interp(odo_t, [f.stamp for f in frames], [f.odom[1] for f in frames])
        odo_th = np.interp(odo_t, [f.stamp for f in frames],
                           np.unwrap([f.odom[2] for f in frames]))
        for t, x, y, th in zip(odo_t, odo_x, odo_y, odo_th, strict=True):
            pos = T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0)
            if odometry == "odom":
                cov = np.zeros(36)
                pose = T["geometry_msgs/msg/PoseWithCovariance"](
                    pose=T["geometry_msgs/msg/Pose"](position=pos, orientation=quat(th)),
                    covariance=cov)
                twist = T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](
                        linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                    covariance=cov)
                msg = T["nav_msgs/msg/Odometry"](header=header(t0 + t, "odom"),
                                                 child_frame_id="base_link", pose=pose,
                                                 twist=twist)
                data = store.serialize_cdr(msg, "nav_msgs/msg/Odometry")
            else:
                tr = T["geometry_msgs/msg/TransformStamped"](
                    header=header(t0 + t, "odom"), child_frame_id="base_link",
                    transform=T["geometry_msgs/msg/Transform"](
                        translation=T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y),
                                                                  z=0.0),
                        rotation=quat(th)))
                msg = T["tf2_msgs/msg/TFMessage"](transforms=[tr])
                data = store.serialize_cdr(msg, "tf2_msgs/msg/TFMessage")
            w.write(odom_c, int((t0 + t) * 1e9), data)
        for k, f in enumerate(frames):
            r = np.where(np.isfinite(f.ranges), f.ranges, 0.0).astype(np.float32)
            msg = T["sensor_msgs/msg/LaserScan"](
                header=header(t0 + f.stamp, "laser"), angle_min=f.angle_min,
                angle_max=f.angle_min + f.angle_increment * (f.num_beams - 1),
                angle_increment=f.angle_increment, time_increment=0.0, scan_time=0.1,
                range_min=0.02, range_max=f.max_range, ranges=r,
                intensities=np.zeros(0, dtype=np.float32))
            data = store.serialize_cdr(msg, "sensor_msgs/msg/LaserScan")
            if k == broken:
                data = data[:40]  # a message cut short
            w.write(scan_c, int((t0 + f.stamp) * 1e9), data)
    return frames


@pytest.mark.parametrize("storage, odometry", [("sqlite3", "odom"), ("mcap", "tf")])
def test_ros2_bag_yields_scans_with_interpolated_odometry(tmp_path, storage, odometry):
    bag = tmp_path / "run"
    truth = _write_bag(bag, storage, odometry=odometry)
    assert detect_format(bag) == "rosbag"
    topics = bag_topics(bag)
    assert topics["/scan"] == ("sensor_msgs/msg/LaserScan", 12)
    log = RosBagLog(bag)
    assert log.chosen_odom == ("/odom" if odometry == "odom" else "/tf")
    frames = list(log)
    assert len(frames) == 12 and log.skipped == 0
    for got, want in zip(frames, truth, strict=True):
        assert got.num_beams == want.num_beams
        assert got.stamp == pytest.approx(100.0 + want.stamp)
        np.testing.assert_allclose(got.ranges, want.ranges.astype(np.float32), rtol=1e-6)
        np.testing.assert_allclose(got.odom[:2], want.odom[:2], atol=1e-6)
        assert abs(math.remainder(got.odom[2] - want.odom[2], math.tau)) < 1e-6


def test_bare_mcap_file_and_topic_selection(tmp_path):
    bag = tmp_path / "run"
    _write_bag(bag, "mcap")
    mcap = next(bag.glob("*.mcap"))
    assert detect_format(mcap) == "rosbag"
    log = open_recording(mcap, scan_topic="/scan", odom_topic="/odom")
    assert len(list(log)) == 12
    with pytest.raises(InputError, match="'/odom' is not a LaserScan topic; topics: /odom"):
        open_recording(mcap, scan_topic="/odom")
    with pytest.raises(InputError, match="neither an Odometry nor a tf topic"):
        open_recording(mcap, odom_topic="/scan")


def test_a_broken_message_is_skipped_and_reported_or_stops_with_strict(tmp_path):
    bag = tmp_path / "run"
    _write_bag(bag, "sqlite3", broken=5)
    log = RosBagLog(bag)
    assert len(list(log)) == 11 and log.skipped == 1
    summary = log.report().summary("run")
    assert "message" in summary and "bad LaserScan message" in summary
    with pytest.raises(InputError, match="message"):
        list(RosBagLog(bag, strict=True))


def test_info_lists_topics_and_map_runs_on_a_ros2_bag(tmp_path, capsys):
    bag = tmp_path / "run"
    _write_bag(bag, "sqlite3", n=30)
    assert main(["info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "/scan" in out and "<- scans" in out and "/odom" in out and "<- odometry" in out
    assert main(["map", str(bag), "--out", str(tmp_path / "res"), "-q"]) == 0
    traj = np.loadtxt(tmp_path / "res" / "latest" / "trajectory.tum")
    assert len(traj) == 30
    assert main(["map", str(bag), "--scan-topic", "/nope", "-q"]) == 2
    assert "not a LaserScan topic" in capsys.readouterr().err
