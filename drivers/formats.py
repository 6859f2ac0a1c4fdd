"""Open a recording by its content (and name): CARMEN, DP-SLAM, BreezySLAM logs, ROS bags."""

from __future__ import annotations

import os
from pathlib import Path

from drivers.breezyslam import BreezySlamLog
from drivers.carmen import CarmenLog
from drivers.dpslam import DpSlamLog
from drivers.rosbag import RosBagLog, is_ros2_bag
from drivers.textlog import DAMAGE, LineLog, LineTooLong, lines_of, open_text
from vmp.errors import InputError
from vmp.fileio import not_regular

__all__ = ["FORMATS", "detect_format", "open_recording"]

FORMATS: dict[str, type[LineLog]] = {
    "carmen": CarmenLog,
    "dpslam": DpSlamLog,
    "breezyslam": BreezySlamLog,
    "rosbag": RosBagLog,
}
# Words that open a CARMEN log line; a g2o file with ROBOTLASER1 lines (MIT Killian) reads
# the same way, its VERTEX and EDGE lines skipped.
_CARMEN_WORDS = {"FLASER", "ROBOTLASER1", "RAWLASER1", "PARAM", "ODOM", "SYNC", "NEFF",
                 "TRUEPOS", "VERTEX_SE2", "EDGE_SE2"}


def detect_format(path: Path) -> str:
    """The format of a recording, from its first meaningful line."""
    if is_ros2_bag(path):
        return "rosbag"
    if path.is_dir():
        raise InputError(f"{path}: a folder, and not a ROS 2 bag (no metadata.yaml)")
    with open(path, "rb") as probe:
        if probe.read(13) == b"#ROSBAG V2.0\n":
            return "rosbag"
    try:
        with open_text(path) as f:
            for _, line in zip(range(200), lines_of(f), strict=False):
                parts = line.split()
                if not parts or parts[0].startswith("#"):
                    continue
                if parts[0] in _CARMEN_WORDS:
                    return "carmen"
                if parts[0] in ("Odometry", "Laser"):
                    return "dpslam"
                if len(parts) > 700 and parts[0].replace(".", "", 1).isdigit():
                    return "breezyslam"
                break
    except (LineTooLong, *DAMAGE) as exc:
        raise InputError(f"{path}: cannot read: {exc}") from exc
    raise InputError(f"{path}: not a recording this program knows (formats: "
                     f"{', '.join(FORMATS)}; choose one with --format)")


def open_recording(path: str | os.PathLike[str], fmt: str | None = None,
                   strict: bool = False, *, scan_topic: str | None = None,
                   odom_topic: str | None = None) -> LineLog:
    """A lazily read recording; ``fmt`` overrides the detection; topics apply to bags."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if not (path.is_file() or path.is_dir()):
        # A FIFO would block until something writes into it, a device never ends.
        raise InputError(f"{path}: {not_regular(path)}; a recording is a regular file or a "
                         "ROS 2 bag folder")
    name = fmt or detect_format(path)
    if name not in FORMATS:
        raise InputError(f"unknown format {name!r}; expected one of {', '.join(FORMATS)}")
    if name == "rosbag":
        return RosBagLog(path, strict=strict, scan_topic=scan_topic, odom_topic=odom_topic)
    if scan_topic or odom_topic:
        raise InputError(f"{path}: --scan-topic and --odom-topic apply to ROS bags, "
                         f"not to a {FORMATS[name].format_name}")
    return FORMATS[name](path, strict=strict)
