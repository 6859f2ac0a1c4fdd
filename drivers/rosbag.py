"""ROS bags (ROS 1, ROS 2, MCAP) through the ``rosbags`` library: LaserScan plus Odometry.

Scans come from a ``sensor_msgs/LaserScan`` topic, odometry from a ``nav_msgs/Odometry``
topic when there is one (the pose nearest in time to each scan); without odometry the
frames carry none and the mapper registers scans alone. Readings outside
``[range_min, range_max]`` are beams without a return.

Some early ROS 1 bags (the CCNY ``demo.bag`` of 2010) cannot be opened by ``rosbags``: their
IndexData records declare a data length of ``count * 20`` bytes while holding ``count``
entries of 12 bytes (a bug of the rosbag writer of the time), and the reader asserts
``size == count * 12``. For ROS 1 bags this module therefore walks the file's records itself
(bag header, chunks, connection and message-data records, which are sound) and only uses
``rosbags`` to decode the messages.
"""

from __future__ import annotations

import bz2
import math
import os
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from drivers.textlog import LineLog
from vmp.errors import InputError
from vmp.types import ScanFrame

__all__ = ["RosBagLog", "bag_topics"]

SCAN_TYPES = ("sensor_msgs/msg/LaserScan", "sensor_msgs/LaserScan")
ODOM_TYPES = ("nav_msgs/msg/Odometry", "nav_msgs/Odometry")


def _header_fields(buf: bytes) -> dict[bytes, bytes]:
    fields = {}
    i = 0
    while i < len(buf):
        (n,) = struct.unpack_from("<I", buf, i)
        i += 4
        key, _, value = buf[i:i + n].partition(b"=")
        fields[key] = value
        i += n
    return fields


def _records(buf: bytes, start: int, end: int) -> Iterator[tuple[dict[bytes, bytes], bytes]]:
    """ROS 1 bag records ``(header fields, data)`` in ``buf[start:end]``."""
    pos = start
    while pos + 8 <= end:
        (hlen,) = struct.unpack_from("<I", buf, pos)
        header = buf[pos + 4:pos + 4 + hlen]
        (dlen,) = struct.unpack_from("<I", buf, pos + 4 + hlen)
        data_start = pos + 8 + hlen
        if data_start + dlen > end:
            raise InputError("a record runs past the end of the file (truncated bag?)")
        yield _header_fields(header), buf[data_start:data_start + dlen]
        pos = data_start + dlen


def _ros1_messages(path: Path) -> Iterator[tuple[str, str, str, int, bytes]]:
    """``(topic, type, definition, time_ns, raw)`` of every message, in file order.

    Chunks are found through the chunk-info records after ``index_pos`` (sound in every bag
    seen), not by walking the records in between, whose IndexData lengths may be wrong.
    """
    buf = path.read_bytes()
    if not buf.startswith(b"#ROSBAG V2.0\n"):
        raise InputError(f"{path}: not a ROS 1 bag version 2.0")
    try:
        pos = len(b"#ROSBAG V2.0\n")
        (hlen,) = struct.unpack_from("<I", buf, pos)
        bag = _header_fields(buf[pos + 4:pos + 4 + hlen])
        (index_pos,) = struct.unpack("<Q", bag[b"index_pos"])
        if not 0 < index_pos < len(buf):
            raise InputError(f"{path}: the bag has no index (not closed properly?)")
        chunk_pos = []
        for fields, _ in _records(buf, index_pos, len(buf)):
            if fields.get(b"op", b"\x00")[0] == 6:  # chunk info
                chunk_pos.append(struct.unpack("<Q", fields[b"chunk_pos"])[0])
        conns: dict[int, tuple[str, str, str]] = {}
        for cpos in sorted(chunk_pos):
            fields, data = next(_records(buf, cpos, len(buf)))
            comp = fields.get(b"compression", b"none")
            if comp == b"bz2":
                data = bz2.decompress(data)
            elif comp == b"lz4":
                import lz4.frame  # optional: only bags compressed with lz4 need it

                data = lz4.frame.decompress(data)
            elif comp != b"none":
                raise InputError(f"{path}: chunk compression {comp.decode()!r} is not supported")
            for f, d in _records(data, 0, len(data)):
                op = f.get(b"op", b"\x00")[0]
                if op == 7:
                    inner = _header_fields(d)
                    conns[struct.unpack("<I", f[b"conn"])[0]] = (
                        f[b"topic"].decode(), inner[b"type"].decode(),
                        inner.get(b"message_definition", b"").decode())
                elif op == 2:
                    (conn,) = struct.unpack("<I", f[b"conn"])
                    sec, nsec = struct.unpack("<II", f[b"time"])
                    topic, msgtype, definition = conns[conn]
                    yield topic, msgtype, definition, sec * 10**9 + nsec, d
    except (struct.error, KeyError, StopIteration) as exc:
        raise InputError(f"{path}: corrupt ROS 1 bag ({exc!r})") from exc


def _typename(msgtype: str) -> str:
    """ROS 1 names a type ``pkg/Name``; rosbags' type store knows ``pkg/msg/Name``."""
    pkg, _, name = msgtype.rpartition("/")
    return msgtype if "/msg/" in msgtype else f"{pkg}/msg/{name}"


def _typestore(messages: list[tuple[str, str, str]]):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    for _, msgtype, definition in messages:
        if definition and _typename(msgtype) not in store.fielddefs:
            store.register(get_types_from_msg(definition, _typename(msgtype)))
    return store


def bag_topics(path: str | os.PathLike[str]) -> dict[str, tuple[str, int]]:
    """Topic -> (message type, number of messages)."""
    return _count_topics(_ros1_messages(Path(path)))


def _count_topics(messages) -> dict[str, tuple[str, int]]:
    out: dict[str, tuple[str, int]] = {}
    for topic, msgtype, _, _, _ in messages:
        out[topic] = (msgtype, out.get(topic, (msgtype, 0))[1] + 1)
    return out


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y**2 + q.z**2))


class RosBagLog(LineLog):
    """Scan frames from a ROS 1 bag (``scan_topic`` and ``odom_topic`` chosen or detected)."""

    format_name = "ROS 1 bag"

    def __init__(self, path: str | os.PathLike[str], *, strict: bool = False,
                 scan_topic: str | None = None, odom_topic: str | None = None) -> None:
        super().__init__(path, strict=strict)
        self.scan_topic, self.odom_topic = scan_topic, odom_topic

    def __iter__(self) -> Iterator[ScanFrame]:
        self.problems, self.skipped, self.backwards, self.scans = [], 0, 0, 0
        msgs = list(_ros1_messages(self.path))  # a bag is read whole, once; they are small
        topics = _count_topics(msgs)
        scans = [t for t, (m, _) in topics.items() if m in SCAN_TYPES]
        odoms = [t for t, (m, _) in topics.items() if m in ODOM_TYPES]
        scan_topic = self.scan_topic or (scans[0] if scans else None)
        if scan_topic is None or scan_topic not in topics:
            raise InputError(f"{self.path}: no LaserScan topic"
                             f"{' ' + repr(scan_topic) if scan_topic else ''}; topics: "
                             f"{', '.join(sorted(topics)) or 'none'}")
        odom_topic = self.odom_topic or (odoms[0] if odoms else None)
        store = _typestore([(t, m, d) for t, m, d, _, _ in msgs])
        odom_t, odom_p = [], []
        if odom_topic is not None:
            for topic, msgtype, _, _, raw in msgs:
                if topic == odom_topic:
                    m = store.deserialize_ros1(raw, _typename(msgtype))
                    stamp = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
                    p = m.pose.pose
                    odom_t.append(stamp)
                    odom_p.append([p.position.x, p.position.y, _yaw(p.orientation)])
        odom_t_arr, odom_p_arr = np.array(odom_t), np.array(odom_p).reshape(-1, 3)
        last = -math.inf
        for k, (topic, msgtype, _, t_ns, raw) in enumerate(msgs):
            if topic != scan_topic:
                continue
            try:
                m = store.deserialize_ros1(raw, _typename(msgtype))
                r = np.asarray(m.ranges, dtype=np.float64)
                ok = np.isfinite(r) & (r >= m.range_min) & (r <= m.range_max) & (r > 0)
                ranges = np.where(ok, r, np.inf)
                stamp = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 or t_ns * 1e-9
                odom = None
                if len(odom_t_arr):
                    odom = odom_p_arr[int(np.argmin(np.abs(odom_t_arr - stamp)))]
                frame = ScanFrame(stamp=stamp, ranges=ranges, angle_min=float(m.angle_min),
                                  angle_increment=float(m.angle_increment),
                                  max_range=float(m.range_max), odom=odom, index=self.scans)
            except (ValueError, KeyError, struct.error) as exc:
                self._bad(k + 1, f"bad LaserScan message: {exc}")
                continue
            if frame.stamp < last:
                self._bad(k + 1, "stamp runs backwards; scan kept", skip=False)
            last = max(last, frame.stamp)
            self.scans += 1
            yield frame
