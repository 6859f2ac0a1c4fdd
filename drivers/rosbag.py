"""ROS bags (ROS 1, ROS 2 with sqlite3 or MCAP storage, bare MCAP files): LaserScan + odometry.

Scans come from a ``sensor_msgs/LaserScan`` topic; odometry from a ``nav_msgs/Odometry``
topic or from ``tf`` (the transforms from an odometry frame to the robot's base frame),
interpolated to each scan's stamp. Without either the frames carry no odometry and the
mapper registers scans alone. Topics are chosen with ``scan_topic`` / ``odom_topic`` or
detected (the first LaserScan topic; an Odometry topic, else ``/tf``). Readings outside
``[range_min, range_max]`` are beams without a return.

The bag is read twice, lazily: once for the odometry poses (three numbers a message), once
for the scans, which are yielded as they are read, so memory does not grow with the bag.

Some early ROS 1 bags (the CCNY ``demo.bag`` of 2010) cannot be opened by ``rosbags``: their
IndexData records declare a data length of ``count * 20`` bytes while holding ``count``
entries of 12 bytes (a bug of the rosbag writer of the time), and the reader asserts
``size == count * 12``. For ROS 1 bags this module therefore walks the file's records itself
(bag header, chunks, connection and message-data records, which are sound) through a memory
map and only uses ``rosbags`` to decode the messages. ROS 2 bags and MCAP files are read
with ``rosbags.highlevel.AnyReader``.
"""

from __future__ import annotations

import bz2
import math
import mmap
import os
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from drivers.textlog import Jumps, LineLog
from vmp.errors import InputError
from vmp.types import FloatArray, ScanFrame, interpolate_pose

__all__ = ["RosBagLog", "bag_topics", "is_ros2_bag"]

SCAN_TYPES = ("sensor_msgs/msg/LaserScan", "sensor_msgs/LaserScan")
ODOM_TYPES = ("nav_msgs/msg/Odometry", "nav_msgs/Odometry")
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf2_msgs/TFMessage", "tf/tfMessage", "tf/msg/tfMessage")
BASE_FRAMES = ("base_link", "base_footprint", "base")


def is_ros2_bag(path: Path) -> bool:
    """A rosbag2 directory, or a storage file rosbags reads on its own (.mcap, .db3)."""
    return (path.is_dir() and (path / "metadata.yaml").is_file()) or path.suffix in (
        ".mcap", ".db3")


# -- ROS 1: the file's own records ------------------------------------------------------------
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


def _records(buf, start: int, end: int) -> Iterator[tuple[dict[bytes, bytes], bytes]]:
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


def _ros1_messages(path: Path, topics: set[str] | None = None
                   ) -> Iterator[tuple[str, str, str, int, bytes]]:
    """``(topic, type, definition, time_ns, raw)`` of the messages (of ``topics``), file order.

    Chunks are found through the chunk-info records after ``index_pos`` (sound in every bag
    seen), not by walking the records in between, whose IndexData lengths may be wrong. The
    file is memory-mapped and one chunk at a time is decompressed.
    """
    with open(path, "rb") as f:
        if f.read(13) != b"#ROSBAG V2.0\n":
            raise InputError(f"{path}: not a ROS 1 bag version 2.0")
        try:
            buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError as exc:  # an empty file
            raise InputError(f"{path}: empty file") from exc
    with buf:
        try:
            pos = 13
            (hlen,) = struct.unpack_from("<I", buf, pos)
            bag = _header_fields(buf[pos + 4:pos + 4 + hlen])
            (index_pos,) = struct.unpack("<Q", bag[b"index_pos"])
            if not 0 < index_pos < len(buf):
                raise InputError(f"{path}: the bag has no index (not closed properly?)")
            chunk_pos = [struct.unpack("<Q", fields[b"chunk_pos"])[0]
                         for fields, _ in _records(buf, index_pos, len(buf))
                         if fields.get(b"op", b"\x00")[0] == 6]  # chunk info
            conns: dict[int, tuple[str, str, str]] = {}
            for cpos in sorted(chunk_pos):
                fields, data = next(_records(buf, cpos, len(buf)))
                data = _decompress(fields.get(b"compression", b"none"), data, path)
                for f_, d in _records(data, 0, len(data)):
                    op = f_.get(b"op", b"\x00")[0]
                    if op == 7:
                        inner = _header_fields(d)
                        conns[struct.unpack("<I", f_[b"conn"])[0]] = (
                            f_[b"topic"].decode(), inner[b"type"].decode(),
                            inner.get(b"message_definition", b"").decode())
                    elif op == 2:
                        topic, msgtype, definition = conns[struct.unpack("<I", f_[b"conn"])[0]]
                        if topics is None or topic in topics:
                            sec, nsec = struct.unpack("<II", f_[b"time"])
                            yield topic, msgtype, definition, sec * 10**9 + nsec, d
        except (struct.error, KeyError, StopIteration, UnicodeDecodeError) as exc:
            raise InputError(f"{path}: corrupt ROS 1 bag ({exc!r})") from exc


def _decompress(comp: bytes, data: bytes, path: Path) -> bytes:
    if comp == b"none":
        return data
    try:
        if comp == b"bz2":
            return bz2.decompress(data)
        if comp == b"lz4":
            import lz4.frame  # optional: only bags compressed with lz4 need it

            return lz4.frame.decompress(data)
    except (OSError, ValueError, RuntimeError, EOFError) as exc:  # lz4 says RuntimeError
        raise InputError(f"{path}: a damaged {comp.decode()} chunk in the ROS 1 bag "
                         f"({exc})") from exc
    raise InputError(f"{path}: chunk compression {comp.decode(errors='replace')!r} is not "
                     "supported")


def _typename(msgtype: str) -> str:
    """ROS 1 names a type ``pkg/Name``; rosbags' type store knows ``pkg/msg/Name``."""
    pkg, _, name = msgtype.rpartition("/")
    return msgtype if "/msg/" in msgtype else f"{pkg}/msg/{name}"


class _Ros1Bag:
    """Topics and decoded messages of a ROS 1 bag."""

    def __init__(self, path: Path) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.path = path
        self.store = get_typestore(Stores.ROS1_NOETIC)
        self.topics: dict[str, tuple[str, int]] = {}
        for topic, msgtype, definition, _, _ in _ros1_messages(path):
            self.topics[topic] = (msgtype, self.topics.get(topic, (msgtype, 0))[1] + 1)
            self._register(msgtype, definition)

    def _register(self, msgtype: str, definition: str) -> None:
        from rosbags.typesys import get_types_from_msg

        name = _typename(msgtype)
        if definition and name not in self.store.fielddefs:
            try:
                self.store.register(get_types_from_msg(definition, name))
            except Exception:  # a damaged definition: its messages fail to decode, reported
                pass

    def messages(self, topics: set[str]) -> Iterator[tuple[int, str, int, object]]:
        """``(index, topic, time_ns, message or exception)`` of the chosen topics."""
        for k, (topic, msgtype, _, t_ns, raw) in enumerate(_ros1_messages(self.path, topics)):
            try:
                msg = self.store.deserialize_ros1(raw, _typename(msgtype))
            except Exception as exc:  # a broken message is reported, not fatal
                msg = exc
            yield k + 1, topic, t_ns, msg


class _Ros2Bag:
    """Topics and decoded messages of a ROS 2 bag or MCAP file, through AnyReader."""

    def __init__(self, path: Path) -> None:
        from rosbags.highlevel import AnyReader

        self.path = path
        self._reader_cls = AnyReader
        try:
            with AnyReader([path]) as reader:
                self.topics = {t: (info.msgtype or "?", info.msgcount)
                               for t, info in reader.topics.items()}
        except Exception as exc:  # rosbags raises many kinds on a bad bag
            raise InputError(f"{path}: cannot open as a ROS 2 bag or MCAP file: {exc}") from exc

    def messages(self, topics: set[str]) -> Iterator[tuple[int, str, int, object]]:
        try:
            with self._reader_cls([self.path]) as reader:
                conns = [c for c in reader.connections if c.topic in topics]
                for k, (conn, t_ns, raw) in enumerate(reader.messages(connections=conns)):
                    try:
                        msg = reader.deserialize(raw, conn.msgtype)
                    except Exception as exc:  # reported, not fatal
                        msg = exc
                    yield k + 1, conn.topic, t_ns, msg
        except InputError:
            raise
        except Exception as exc:
            raise InputError(f"{self.path}: cannot read the bag: {exc}") from exc


def _open_bag(path: Path) -> _Ros1Bag | _Ros2Bag:
    return _Ros2Bag(path) if is_ros2_bag(path) else _Ros1Bag(path)


def bag_topics(path: str | os.PathLike[str]) -> dict[str, tuple[str, int]]:
    """Topic -> (message type, number of messages)."""
    return _open_bag(Path(path)).topics


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y**2 + q.z**2))


def _stamp(header, t_ns: int) -> float:
    s = header.stamp.sec + header.stamp.nanosec * 1e-9
    return s if s > 0 else t_ns * 1e-9


class RosBagLog(LineLog):
    """Scan frames from a ROS 1 or ROS 2 bag or an MCAP file (topics chosen or detected)."""

    format_name = "ROS bag"
    item = "message"

    def __init__(self, path: str | os.PathLike[str], *, strict: bool = False,
                 scan_topic: str | None = None, odom_topic: str | None = None) -> None:
        super().__init__(path, strict=strict)
        self.scan_topic, self.odom_topic = scan_topic, odom_topic
        self.bag = _open_bag(self.path)
        self.format_name = "ROS 2 bag / MCAP" if isinstance(self.bag, _Ros2Bag) else "ROS 1 bag"
        self.topics = self.bag.topics
        self.chosen_scan, self.chosen_odom = self._choose()
        self._odom: tuple[FloatArray, FloatArray] | None = None
        self._odom_problems: tuple[list[tuple[int, str]], int] = ([], 0)

    @property
    def length(self) -> int | None:
        """The messages of the scan topic, as the bag's index counts them."""
        return self.topics[self.chosen_scan][1]

    def notes(self) -> list[tuple[str, str]]:
        """The bag's topics, and which were chosen for scans and odometry."""
        out = [("topics", "")]
        for topic, (msgtype, count) in sorted(self.topics.items()):
            used = (" <- scans" if topic == self.chosen_scan else
                    " <- odometry" if topic == self.chosen_odom else "")
            out.append(("", f"  {topic:<28} {msgtype:<32} {count:>7} messages{used}"))
        return out

    def _choose(self) -> tuple[str, str | None]:
        topics = self.topics
        listing = ", ".join(f"{t} ({m})" for t, (m, _) in sorted(topics.items())) or "none"
        scans = [t for t, (m, _) in topics.items() if m in SCAN_TYPES]
        scan = self.scan_topic or (scans[0] if scans else None)
        if scan is None or scan not in topics or topics[scan][0] not in SCAN_TYPES:
            what = f"{scan!r} is not a LaserScan topic" if scan else "no LaserScan topic"
            raise InputError(f"{self.path}: {what}; topics: {listing}")
        odom = self.odom_topic
        if odom is not None:
            if odom not in topics or topics[odom][0] not in ODOM_TYPES + TF_TYPES:
                raise InputError(f"{self.path}: {odom!r} is neither an Odometry nor a tf "
                                 f"topic; topics: {listing}")
        else:
            odoms = [t for t, (m, _) in topics.items() if m in ODOM_TYPES]
            tfs = [t for t, (m, _) in topics.items() if m in TF_TYPES and t != "/tf_static"]
            odom = odoms[0] if odoms else (tfs[0] if tfs else None)
        return scan, odom

    def _odometry(self) -> tuple[FloatArray, FloatArray]:
        """Stamps and poses of the odometry topic, sorted by stamp (read once; its bad
        messages count in every pass)."""
        if self._odom is None:
            self._odom = self._read_odometry()
            self._odom_problems = (list(self.problems), self.skipped)
        else:
            self.problems, self.skipped = list(self._odom_problems[0]), self._odom_problems[1]
        return self._odom

    def _read_odometry(self) -> tuple[FloatArray, FloatArray]:
        if self.chosen_odom is None:
            return np.zeros(0), np.zeros((0, 3))
        is_tf = self.topics[self.chosen_odom][0] in TF_TYPES
        t, p = [], []
        for k, _, t_ns, m in self.bag.messages({self.chosen_odom}):
            if isinstance(m, Exception):
                self._bad(k, f"bad odometry message: {m}")
                continue
            try:
                got = self._odometry_poses(m, t_ns, is_tf)
            except (AttributeError, TypeError, ValueError, OverflowError) as exc:  # damaged
                self._bad(k, f"bad odometry message: {type(exc).__name__}: {exc}")
                continue
            t.extend(s for s, _ in got)
            p.extend(q for _, q in got)
        stamps, poses = np.array(t), np.array(p).reshape(-1, 3)
        good = np.isfinite(stamps) & np.isfinite(poses).all(axis=1)
        order = np.argsort(stamps[good], kind="stable")
        return stamps[good][order], poses[good][order]

    @staticmethod
    def _odometry_poses(m, t_ns: int, is_tf: bool) -> list[tuple[float, list[float]]]:
        """(stamp, [x, y, yaw]) of the robot in an Odometry or tf message."""
        if not is_tf:
            pose = m.pose.pose
            return [(_stamp(m.header, t_ns),
                     [pose.position.x, pose.position.y, _yaw(pose.orientation)])]
        out = []
        for tr in m.transforms:
            child = tr.child_frame_id.lstrip("/")
            if child in BASE_FRAMES and "odom" in tr.header.frame_id:
                q, v = tr.transform.rotation, tr.transform.translation
                out.append((_stamp(tr.header, t_ns), [v.x, v.y, _yaw(q)]))
        return out

    def __iter__(self) -> Iterator[ScanFrame]:
        self.problems, self.skipped, self.backwards, self.scans = [], 0, 0, 0
        self._closed = False
        odom_t, odom_p = self._odometry()
        last = -math.inf
        jumps = Jumps()
        for k, _, t_ns, m in self.bag.messages({self.chosen_scan}):
            try:
                if isinstance(m, Exception):
                    raise ValueError(str(m))
                with np.errstate(invalid="ignore", over="ignore"):  # damage: not ranges
                    r = np.asarray(m.ranges, dtype=np.float64)
                ok = np.isfinite(r) & (r >= m.range_min) & (r <= m.range_max) & (r > 0)
                stamp = _stamp(m.header, t_ns)
                frame = ScanFrame(stamp=stamp, ranges=np.where(ok, r, np.inf),
                                  angle_min=float(m.angle_min),
                                  angle_increment=float(m.angle_increment),
                                  max_range=float(m.range_max),
                                  odom=interpolate_pose(odom_t, odom_p, stamp),
                                  index=self.scans)
            except (ValueError, AttributeError, TypeError, OverflowError) as exc:
                self._bad(k, f"bad LaserScan message: {exc}")
                continue
            frame, problem = jumps.admit(frame)
            if frame is None:
                self._bad(k, f"{problem}; scan skipped")
                continue
            if frame.stamp < last:
                self._bad(k, "stamp runs backwards; scan kept", skip=False)
            last = max(last, frame.stamp)
            self.scans += 1
            yield frame
            if self._closed:
                return
