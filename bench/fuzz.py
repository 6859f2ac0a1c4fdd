"""Fuzz every parser a user can hand the program, as a hostile user would.

Run: python bench/fuzz.py [--cases 100000] [--only carmen mapfile ...] [--jobs 2]

Each parser gets a real excerpt (the test recordings, a saved map of a short simulated run, a
configuration, a scenario, relations and TUM files) and ``--cases`` mutations of it: a
truncation, flipped, inserted or deleted bytes, a span repeated, lines deleted, repeated or
swapped, a number replaced by an extreme one (nan, inf, 1e308, -1, 0, huge integers, words),
bytes that are not UTF-8, and for compressed containers the same done to the packed bytes or
to the text inside. A third of the text cases are aimed at a class of hostile input: a line of
9 MB, numbers replaced by physically impossible finite ones (a stamp 300 million years on, a
position of 500 km), scans cut to 0, 1 or 2 beams or without a return, YAML nested thousands
deep or with a number of thousands of digits; one case in fifty hands the parser a FIFO or a
symlink to a device instead of a file; half the map file's header edits keep the JSON sound
and its checksum valid. A recording read without complaint into odometry jumping faster than
a robot drives, or stamps a year apart, counts as silent nonsense. Every mutated file is read
the way the command line reads it (a recording through to its last frame, a map through its
checks, a configuration into a mapping run's settings, a scenario into its first scans).
Each case ends one of five ways: read (the
mutation left something valid), refused (:class:`InputError` or an OS error, which the
command line prints as one line and exit 2), a traceback (any other exception: a bug), a
hang (longer than ``--timeout``), or silent nonsense. An error message with a line break, and
a RuntimeWarning (which a user would see printed), count as tracebacks.

It prints per parser the counts and the first few tracebacks by place, and writes the table to
docs/benchmarks.md (section ``fuzz``). The exit code is 1 when any parser had a traceback or a
hang.
"""

from __future__ import annotations

import argparse
import functools
import gzip
import io
import json
import math
import os
import signal
import sys
import tempfile
import time
import traceback
import warnings
import zipfile
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import machine, write_section

from vmp.errors import InputError

DATA = Path(__file__).resolve().parent.parent / "tests" / "data"
EXTREMES = [b"nan", b"inf", b"-inf", b"1e308", b"-1e308", b"1e-320", b"0", b"-0", b"-1",
            b"99999999999999999999999", b"-99999999999999999999", b"abc", b"", b"1e6", b"0x10",
            b"1_000", b"\xff\xfe", b"null", b"[]", b"{}", b"~", b"2147483648", b"1e9"]


class Hang(Exception):
    """A case took longer than the time limit."""


@dataclass
class Tally:
    """What the cases of one parser ended as."""

    cases: int = 0
    read: int = 0
    refused: int = 0
    tracebacks: int = 0
    hangs: int = 0
    nonsense: int = 0  # read without complaint into values no file holds
    places: Counter = field(default_factory=Counter)  # "Type at file:line" -> count
    example: dict = field(default_factory=dict)  # place -> the case's seed

    def add(self, other: Tally) -> None:
        self.cases += other.cases
        self.read += other.read
        self.refused += other.refused
        self.tracebacks += other.tracebacks
        self.hangs += other.hangs
        self.nonsense += other.nonsense
        self.places.update(other.places)
        for k, v in other.example.items():
            self.example.setdefault(k, v)


# -- the excerpts ---------------------------------------------------------------------------
def _text_excerpt(name: str, lines: int) -> bytes:
    with gzip.open(DATA / name, "rb") as f:
        return b"".join(f.readline() for _ in range(lines))


def _zip(member: str, data: bytes) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr(member, data)
    return out.getvalue()


@functools.cache
def _lab_run():
    """A short mapping run of the lab scenario: the source of the saved-file excerpts."""
    from drivers import open_source
    from vmp.run import MappingRun

    return MappingRun(open_source("lab", scans=60)).run()


def _saved_map(workdir: Path) -> bytes:
    from vmp.config import config_to_dict
    from vmp.mapfile import save_map

    result = _lab_run()
    p = result.pipeline
    path = workdir / "seed.vmpmap"
    save_map(path, p.map, p.milestones, p.back.graph, config_to_dict(result.config),
             result.trajectory)
    return path.read_bytes()


def _saved_milestones(workdir: Path) -> bytes:
    from milestones.store import save_milestones

    path = workdir / "seed-milestones.npz"
    save_milestones(path, _lab_run().pipeline.milestones)
    return path.read_bytes()


def _saved_grid(workdir: Path) -> bytes:
    from vmp.export import write_ros_map

    write_ros_map(workdir / "seed-grid.yaml", _lab_run().grid(0.1))
    return (workdir / "seed-grid.pgm").read_bytes()


def _ros2_bag(workdir: Path, storage: str) -> bytes:
    """A ROS 2 storage file (sqlite3 or MCAP) of six simulated scans with odometry."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from drivers import open_source

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    bag = workdir / f"bag-{storage}"
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(bag, version=9, storage_plugin=plugin) as w:
        scan_c = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        odom_c = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        for k, f in enumerate(open_source("office", scans=6)):
            t = 100.0 + 0.1 * k
            ns = int(t * 1e9)
            stamp = T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=ns % 10**9)
            head = T["std_msgs/msg/Header"](stamp=stamp, frame_id="laser")
            g = f.geometry
            scan = T["sensor_msgs/msg/LaserScan"](
                header=head, angle_min=g.angle_min, angle_max=g.angle_min + g.angle_increment
                * (g.num_beams - 1), angle_increment=g.angle_increment, time_increment=0.0,
                scan_time=0.1, range_min=0.05, range_max=g.max_range,
                ranges=np.nan_to_num(f.ranges, posinf=0.0).astype(np.float32),
                intensities=np.zeros(0, np.float32))
            w.write(scan_c, ns, store.serialize_cdr(scan, scan_c.msgtype))
            q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(f.odom[2] / 2),
                                                   w=math.cos(f.odom[2] / 2))
            pos = T["geometry_msgs/msg/Point"](x=float(f.odom[0]), y=float(f.odom[1]), z=0.0)
            pose = T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](position=pos, orientation=q),
                covariance=np.zeros(36))
            vec = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            twist = T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=vec, angular=vec),
                covariance=np.zeros(36))
            odom = T["nav_msgs/msg/Odometry"](header=T["std_msgs/msg/Header"](
                stamp=stamp, frame_id="odom"), child_frame_id="base_link", pose=pose,
                twist=twist)
            w.write(odom_c, ns, store.serialize_cdr(odom, odom_c.msgtype))
    return next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")).read_bytes()


CONFIG = b"""# a configuration that sets a value in every section
motion: {trans_per_m: 0.05, rot_per_m: 0.0175, rot_per_rad: 0.05}
registration: {max_rms: 0.05, min_inliers: 0.5}
scan_odometry: {enabled: true, keyframe_distance: 0.3, keyframe_turn: 0.17}
milestones:
  length: 180
  clamp_range: 15.0
  method: cca
  compression: dct
  keep: 0.1
  record_distance: 1.0
  record_turn: 0.785
  max_heading: 1.05
  recognition_radius: 1.0
matching: {enabled: true, candidates: 2, max_ratio: 0.9, retry_max_ratio: 0.7,
           retry_min_inliers: 0.75}
loops: {switch_margin: 0.3, separation: 5, adjust_chi2: 1.0}
map: {no_return_free_range: 10.0}
"""

SCENARIO = b"""name: tiny
seed: 3
walls:
  - polygon: [[0, 0], [8, 0], [8, 6], [0, 6]]
  - box: {center: [4, 3], size: [1, 1]}
  - polyline: [[2, 0], [2, 2]]
    repeat: {count: 3, step: [1.5, 0]}
trajectory:
  waypoints: [[1, 1], [7, 1, 0.4], [7, 5], [1, 5]]
  closed: true
  laps: 2
  speed: 0.5
  turn_rate_deg: 45
  start_heading_deg: 0
sensor: {beams: 181, angle_min_deg: -90, angle_increment_deg: 1.0, max_range: 30,
         range_noise: 0.01, rate_hz: 10, dropout: 0.01}
odometry: {trans_noise: 0.02, rot_noise_per_m_deg: 1.0, rot_noise_per_rad: 0.02,
           trans_scale_bias: 0.01, rot_scale_bias: 0.0, drift_deg_per_m: 0.1}
obstacles:
  - {path: [[3, 4], [6, 4]], speed: 0.5, radius: 0.2, closed: false}
stations: {home: [1, 1, 0], nearby: [[2, 1, 90]]}
"""

RELATIONS = b"""100.0 101.0 0.5 0.0 0 0 0 0.1
101.0 102.5 0.4 0.1 0 0 0 -0.05
102.5 104.0 0.3 -0.1 0 0 0 0.2
"""

TUM = b"""# t x y z qx qy qz qw
100.0 0 0 0 0 0 0 1
100.5 0.25 0 0 0 0 0.0499792 0.99875
101.0 0.5 0.02 0 0 0 0.0998334 0.995004
102.5 0.9 0.1 0 0 0 0.0499792 0.99875
104.0 1.2 0.0 0 0 0 0.0 1.0
"""


# -- reading a file the way the command line does -------------------------------------------
class Nonsense(Exception):
    """A file read without complaint into values no recording or map holds."""


def _read_recording(path: Path) -> None:
    from drivers.formats import open_recording
    from drivers.textlog import MAX_SPEED

    last = None
    scans = 0
    for frame in open_recording(path):
        scans += 1
        if last is not None and frame.odom is not None and last.odom is not None:
            dt = max(abs(frame.stamp - last.stamp), 1.0)
            if np.hypot(*(frame.odom[:2] - last.odom[:2])) > MAX_SPEED * dt:
                raise Nonsense(f"odometry jumps {np.hypot(*(frame.odom[:2] - last.odom[:2])):.3g}"
                               f" m in {dt:.3g} s")
        if last is not None and abs(frame.stamp - last.stamp) > 86400.0 * 365:
            raise Nonsense(f"stamps a year apart ({last.stamp:.6g}, {frame.stamp:.6g})")
        last = frame
    if not scans:
        raise InputError(f"{path}: no laser scans")


def _read_map(path: Path) -> None:
    from vmp.mapfile import load_map

    saved = load_map(path)
    saved.frames()


def _read_milestones(path: Path) -> None:
    from milestones.store import StoreError, load_milestones

    try:
        load_milestones(path)
    except StoreError as exc:  # the store's own one-line error (milestones imports no vmp)
        raise InputError(str(exc)) from exc


def _read_grid(path: Path) -> None:
    from vmp.export import read_ros_map

    meta = path.with_suffix(".yaml")
    meta.write_text(f"image: {path.name}\nresolution: 0.05\norigin: [-1.0, -2.0, 0.0]\n"
                    "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    read_ros_map(meta)


def _read_config(path: Path) -> None:
    from vmp.config import load_config

    load_config(path)


def _read_scenario(path: Path) -> None:
    from drivers.scenario import load_scenario
    from drivers.simulator import Simulator

    for _ in Simulator(load_scenario(path), max_scans=2):
        pass


def _read_relations(path: Path) -> None:
    from vmp.evaluate import read_relations

    read_relations(path)


def _read_tum(path: Path) -> None:
    from vmp.tum import read_tum

    read_tum(path)


@dataclass(frozen=True)
class Parser:
    """A parser under test: its excerpt, the file name it is given, how it is read, and
    whether the mutations go into the packed bytes or the text inside them."""

    name: str
    suffix: str
    read: Callable[[Path], None]
    pack: str = "none"  # none, gzip, zip: the excerpt's text is packed so


def parsers() -> list[Parser]:
    return [
        Parser("carmen", ".clf", _read_recording),
        Parser("carmen gzip", ".clf.gz", _read_recording, "gzip"),
        Parser("g2o zip", ".g2o.zip", _read_recording, "zip"),
        Parser("dpslam", ".log", _read_recording),
        Parser("breezyslam", ".dat", _read_recording),
        Parser("ros1 bag", ".bag", _read_recording),
        Parser("mcap", ".mcap", _read_recording),
        Parser("ros2 sqlite3", ".db3", _read_recording),
        Parser("map file", ".vmpmap", _read_map),
        Parser("milestones", ".npz", _read_milestones),
        Parser("grid (pgm)", ".pgm", _read_grid),
        Parser("configuration", ".yaml", _read_config),
        Parser("scenario", ".yaml", _read_scenario),
        Parser("relations", ".relations", _read_relations),
        Parser("tum", ".tum", _read_tum),
    ]


def excerpt(name: str, workdir: Path) -> bytes:
    """The unmutated text (or bytes) of a parser's input."""
    if name in ("carmen", "carmen gzip"):
        return _text_excerpt("intel-excerpt.clf.gz", 12)
    if name == "g2o zip":
        with zipfile.ZipFile(DATA / "killian-excerpt.g2o.zip") as z:
            member = max(z.infolist(), key=lambda m: m.file_size)
            return b"".join(z.open(member).readlines()[:12])
    if name == "dpslam":
        return _text_excerpt("loop5-excerpt.log.gz", 8)
    if name == "breezyslam":
        return _text_excerpt("exp1-excerpt.dat.gz", 6)
    if name == "ros1 bag":
        return (DATA / "demo-excerpt.bag").read_bytes()
    if name == "mcap":
        return _ros2_bag(workdir, "mcap")
    if name == "ros2 sqlite3":
        return _ros2_bag(workdir, "sqlite3")
    if name == "map file":
        return _saved_map(workdir)
    if name == "milestones":
        return _saved_milestones(workdir)
    if name == "grid (pgm)":
        return _saved_grid(workdir)
    return {"configuration": CONFIG, "scenario": SCENARIO, "relations": RELATIONS,
            "tum": TUM}[name]


# -- mutations ------------------------------------------------------------------------------
def _bytes_mutation(data: bytes, rng: np.random.Generator) -> bytes:
    n = len(data)
    kind = rng.integers(6)
    if n == 0:
        return bytes(rng.integers(0, 256, 8, dtype=np.uint8))
    at = int(rng.integers(n))
    if kind == 0:  # truncation
        return data[:at]
    if kind == 1:  # flipped bytes
        b = bytearray(data)
        for i in rng.integers(0, n, int(rng.integers(1, 9))):
            b[i] ^= 1 << int(rng.integers(8))
        return bytes(b)
    if kind == 2:  # random bytes inserted
        return data[:at] + bytes(rng.integers(0, 256, int(rng.integers(1, 17)),
                                              dtype=np.uint8)) + data[at:]
    if kind == 3:  # a span deleted
        return data[:at] + data[at + int(rng.integers(1, 257)):]
    if kind == 4:  # a span repeated
        span = data[at:at + int(rng.integers(1, 257))]
        return data[:at] + span * int(rng.integers(2, 5)) + data[at:]
    b = bytearray(data)  # a block zeroed
    end = min(n, at + int(rng.integers(1, 513)))
    b[at:end] = bytes(end - at)
    return bytes(b)


def _text_mutation(data: bytes, rng: np.random.Generator) -> bytes:
    lines = data.split(b"\n")
    kind = rng.integers(5)
    i = int(rng.integers(len(lines)))
    if kind == 0:  # a number (or word) replaced by an extreme one
        words = lines[i].split(b" ")
        for _ in range(int(rng.integers(1, 4))):
            j = int(rng.integers(len(words)))
            words[j] = EXTREMES[int(rng.integers(len(EXTREMES)))]
        lines[i] = b" ".join(words)
    elif kind == 1:  # a line deleted
        del lines[i]
    elif kind == 2:  # a line repeated
        lines.insert(i, lines[i])
    elif kind == 3:  # two lines swapped
        j = int(rng.integers(len(lines)))
        lines[i], lines[j] = lines[j], lines[i]
    else:  # not UTF-8
        at = int(rng.integers(len(lines[i]) + 1))
        lines[i] = lines[i][:at] + b"\xc3\x28\xff" + lines[i][at:]
    return b"\n".join(lines)


def _npz_mutation(data: bytes, rng: np.random.Generator) -> bytes:
    """A map file with one of its arrays (or its header) changed but packed soundly and its
    checksum made to match, as a faulty writer would leave it: this tries the structural
    checks behind the checksum."""
    from vmp.mapfile import checksum

    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    key = sorted(arrays)[int(rng.integers(len(arrays)))]
    a = arrays[key]
    if key == "header":
        header = json.loads(a.tobytes().decode())
        if rng.integers(2):  # a field's value replaced, the JSON still sound
            _edit_field(header, rng)
            edited = json.dumps(header).encode()
        else:
            edited = _text_mutation(json.dumps(header, indent=0).encode(), rng)
        arrays[key] = np.frombuffer(edited, dtype=np.uint8)
    elif a.size and rng.integers(3) and a.dtype.kind in "fiu":
        a = a.copy()
        flat = a.reshape(-1)
        j = int(rng.integers(flat.size))
        if a.dtype.kind == "f":
            flat[j] = [np.nan, np.inf, -1e30, 1e30, 0.0][int(rng.integers(5))]
        else:
            info = np.iinfo(a.dtype)
            was = int(flat[j])
            flat[j] = np.clip([info.max, info.min, 0, was + 1, was - 1][int(rng.integers(5))],
                              info.min, info.max)
        arrays[key] = a
    else:  # a shape changed
        arrays[key] = a.reshape(-1)[: max(0, a.size - int(rng.integers(1, 4)))]
    try:  # an edited header that is still JSON gets a valid checksum too
        header = json.loads(arrays["header"].tobytes().decode())
    except (ValueError, UnicodeDecodeError):
        header = {}
    if isinstance(header, dict) and "checksum" in header:
        version = header.get("version")
        with_header = header if isinstance(version, int) and version >= 3 else None
        header["checksum"] = checksum({k: v for k, v in arrays.items() if k != "header"},
                                      with_header)
        arrays["header"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    out = io.BytesIO()
    np.savez_compressed(out, **arrays)
    return out.getvalue()


# Values no recording holds, put where a number was: a stamp of 300 million years, a position
# of 500 km, a heading of a billion radians, a range limit or angle beyond any scanner's.
IMPOSSIBLE = [b"9760527911594970.0", b"507216.0", b"1.5e9", b"-3.0e7", b"1e200", b"5.7e31",
              b"1.8e19", b"100000", b"35156"]
HEADER_VALUES = [float("nan"), -5.0, 0.0, 1e300, "garbage", [], {}, None, -1, 10**30]


def _edit_field(node: object, rng: np.random.Generator) -> None:
    """Replace one value somewhere in a JSON document (in place) by a hostile one."""
    while True:
        keys = (list(node) if isinstance(node, dict) else range(len(node))
                if isinstance(node, list) else [])
        if not keys:
            return
        key = keys[int(rng.integers(len(keys)))]
        child = node[key]
        if isinstance(child, dict | list) and child and rng.integers(3):
            node = child
            continue
        node[key] = HEADER_VALUES[int(rng.integers(len(HEADER_VALUES)))]
        return


def _huge_line(data: bytes, rng: np.random.Generator) -> bytes:
    """A line longer than any record or configuration (9 MB: what one line of a damaged
    file may be)."""
    lines = data.split(b"\n")
    at = int(rng.integers(len(lines) + 1))
    junk = bytes([int(rng.integers(33, 127))]) * (9 << 20)
    return b"\n".join(lines[:at] + [junk] + lines[at:])


def _impossible_values(data: bytes, rng: np.random.Generator) -> bytes:
    """Numbers of a few lines replaced by physically impossible (finite) ones."""
    lines = data.split(b"\n")
    for _ in range(int(rng.integers(1, 4))):
        i = int(rng.integers(len(lines)))
        words = lines[i].split(b" ")
        j = int(rng.integers(len(words)))
        words[j] = IMPOSSIBLE[int(rng.integers(len(IMPOSSIBLE)))]
        lines[i] = b" ".join(words)
    return b"\n".join(lines)


def _degenerate_scans(data: bytes, rng: np.random.Generator) -> bytes:
    """Scan lines cut to 0, 1 or 2 beams, or with no return at all, the count matching
    (CARMEN FLASER and DP-SLAM Laser lines)."""
    lines = data.split(b"\n")
    keep = int(rng.integers(3))
    blind = bool(rng.integers(2))
    out = []
    for line in lines:
        words = line.split(b" ")
        if words[0] in (b"FLASER", b"Laser") and len(words) > 2 and words[1].isdigit():
            n = int(words[1])
            ranges, rest = words[2:2 + n], words[2 + n:]
            if blind:
                ranges = [b"0.0"] * n
            else:
                ranges, n = ranges[:keep], keep
            words = [words[0], str(n).encode(), *ranges, *rest]
        out.append(b" ".join(words))
    return b"\n".join(out)


def _deep_yaml(data: bytes, rng: np.random.Generator) -> bytes:
    """A document nested thousands deep, or a number of thousands of digits."""
    if rng.integers(2):
        depth = int(rng.integers(1000, 20000))
        return b"motion: " + b"[" * depth + b"]" * depth + b"\n"
    return data.replace(b": ", b": " + b"9" * int(rng.integers(4000, 20000)) + b"#", 1)


def _class_mutation(parser: Parser, original: bytes, rng: np.random.Generator
                    ) -> bytes | None:
    """One of the mutations aimed at a class of hostile input, for a parser it applies to
    (None: none does, or the draw fell to the others)."""
    textual = parser.name in ("carmen", "carmen gzip", "g2o zip", "dpslam", "breezyslam",
                              "configuration", "scenario", "relations", "tum")
    if not textual or rng.integers(3):
        return None
    kind = int(rng.integers(4))
    if kind == 0:
        inner = _huge_line(original, rng)
    elif kind == 1 or parser.name in ("relations", "tum"):
        inner = _impossible_values(original, rng)
    elif parser.name in ("configuration", "scenario"):
        inner = _deep_yaml(original, rng)
    else:
        inner = _degenerate_scans(original, rng)
    if parser.pack == "gzip":
        return gzip.compress(inner)
    return _zip("log.g2o", inner) if parser.pack == "zip" else inner


def mutate(parser: Parser, original: bytes, rng: np.random.Generator) -> bytes:
    """One mutation of ``original`` as the parser's file holds it."""
    aimed = _class_mutation(parser, original, rng)
    if aimed is not None:
        return aimed
    textual = parser.name not in ("ros1 bag", "mcap", "ros2 sqlite3", "map file",
                                  "milestones", "grid (pgm)")
    if parser.name in ("map file", "milestones") and rng.integers(2):
        return _npz_mutation(original, rng)
    inner = original
    if textual and (parser.pack == "none" or rng.integers(2)):
        inner = _text_mutation(original, rng)
        if rng.integers(4) == 0:
            inner = _bytes_mutation(inner, rng)
        if parser.pack == "none":
            return inner
        return gzip.compress(inner) if parser.pack == "gzip" else _zip("log.g2o", inner)
    packed = (gzip.compress(inner) if parser.pack == "gzip" else
              _zip("log.g2o", inner) if parser.pack == "zip" else inner)
    return _bytes_mutation(packed, rng)


# -- running cases --------------------------------------------------------------------------
def _not_a_file(target: Path, rng: np.random.Generator) -> None:
    """Make ``target`` a FIFO (nothing writes into it) or a symlink to an endless device."""
    devices = [d for d in ("/dev/zero", "/dev/urandom", "/dev/null") if os.path.exists(d)]
    if devices and rng.integers(2):
        target.symlink_to(devices[int(rng.integers(len(devices)))])
    else:
        os.mkfifo(target)


def _alarm(_signum: int, _frame: object) -> None:
    raise Hang


def _place(exc: BaseException) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if "/site-packages/" not in f.filename] or frames
    last = ours[-1] if ours else None
    where = f"{Path(last.filename).name}:{last.lineno}" if last else "?"
    return f"{type(exc).__name__} at {where}"


def run_cases(job: tuple[str, int, int, float]) -> Tally:
    """``count`` cases of one parser from ``seed`` on, in this process."""
    name, seed, count, timeout = job
    parser = next(p for p in parsers() if p.name == name)
    tally = Tally()
    signal.signal(signal.SIGALRM, _alarm)
    # A warning a user would see (overflow in a conversion, say) is a message that is not one
    # line: it counts as a traceback.
    warnings.simplefilter("error", RuntimeWarning)
    with tempfile.TemporaryDirectory(prefix="vmp-fuzz-") as tmp:
        workdir = Path(tmp)
        original = excerpt(name, workdir)
        target = workdir / f"case{parser.suffix}"
        for case in range(seed, seed + count):
            rng = np.random.default_rng(case)
            if target.is_symlink() or target.exists():
                target.unlink()
            if rng.integers(50) == 0 and hasattr(os, "mkfifo"):
                _not_a_file(target, rng)  # what a user may point at: a FIFO, a device
            else:
                target.write_bytes(mutate(parser, original, rng))
            tally.cases += 1
            signal.setitimer(signal.ITIMER_REAL, timeout)
            try:
                parser.read(target)
                tally.read += 1
            except Hang:
                tally.hangs += 1
                tally.places["hang"] += 1
                tally.example.setdefault("hang", case)
            except (InputError, OSError) as exc:
                if "\n" in str(exc).strip():
                    tally.tracebacks += 1
                    place = f"multi-line {type(exc).__name__}"
                    tally.places[place] += 1
                    tally.example.setdefault(place, case)
                else:
                    tally.refused += 1
            except Nonsense as exc:
                tally.nonsense += 1
                place = f"nonsense read: {exc}"[:80]
                tally.places[place] += 1
                tally.example.setdefault(place, case)
            except Exception as exc:
                tally.tracebacks += 1
                place = _place(exc)
                tally.places[place] += 1
                tally.example.setdefault(place, case)
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
    return tally


def _write(rows: list[tuple[str, Tally, float]], names: list[str], cases: int) -> None:
    """Put the rows into docs/benchmarks.md's fuzz section, keeping other parsers' rows."""
    body = ["`python bench/fuzz.py" + (f" --cases {cases}" if cases != 100_000 else "")
            + f"` on {machine()} (rows of parsers run separately: `--only NAME`): every "
            "parser's real excerpt mutated (truncation, byte flips, insertions, deletions, "
            "repeats, zeroed blocks, line edits, extreme numbers, non-UTF-8; a third of the "
            "text cases aimed at a class of hostile input: 9 MB lines, impossible finite "
            "values, scans of 0-2 beams or no return, deep YAML and huge integers; one case "
            "in fifty a FIFO or a device; map header edits with a valid checksum), read as "
            "the command line reads it, RuntimeWarnings counted as tracebacks. Refused: "
            "one-line error, exit 2. Silent nonsense: a recording read without complaint "
            "into odometry faster than 50 m/s or stamps a year apart.", "",
            "| parser | cases | read | refused (one line) | tracebacks | hangs | silent nonsense "
            "| time |",
            "|---|---|---|---|---|---|---|---|"]
    table = _rows_written_before(names)
    for name, t, took in rows:
        table[name] = (f"| {name} | {t.cases} | {t.read} | {t.refused} | {t.tracebacks} | "
                       f"{t.hangs} | {t.nonsense} | {took:.0f} s |")
    body += [table[n] for n in names if n in table]
    write_section("fuzz", "## Fuzzing the parsers\n\n" + "\n".join(body) + "\n")


def _rows_written_before(names: list[str]) -> dict[str, str]:
    """The table rows of docs/benchmarks.md's fuzz section by parser (a run of some parsers
    keeps the others' rows)."""
    from report import DOC

    text = DOC.read_text() if DOC.exists() else ""
    section = text.partition("<!-- bench:fuzz -->")[2].partition("<!-- /bench:fuzz -->")[0]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells and cells[0] in names:
            rows[cells[0]] = line.strip()
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=100_000, help="cases per parser")
    ap.add_argument("--only", nargs="+", metavar="PARSER", help="these parsers only")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--timeout", type=float, default=10.0, help="seconds a case may take")
    ap.add_argument("--seed", type=int, default=0, help="the first case's seed")
    ap.add_argument("--no-write", action="store_true", help="do not touch docs/benchmarks.md")
    args = ap.parse_args()
    names = [p.name for p in parsers()]
    chosen = args.only or names
    unknown = set(chosen) - set(names)
    if unknown:
        ap.error(f"unknown parser(s) {', '.join(sorted(unknown))}; choose from {', '.join(names)}")
    chunk = max(1, min(2000, args.cases // (4 * args.jobs) or 1))
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for name in chosen:
            started = time.perf_counter()
            jobs = [(name, args.seed + s, min(chunk, args.cases - s), args.timeout)
                    for s in range(0, args.cases, chunk)]
            tally = Tally()
            for part in pool.map(run_cases, jobs):
                tally.add(part)
            took = time.perf_counter() - started
            rows.append((name, tally, took))
            print(f"{name:<14} {tally.cases:>7} cases: {tally.read:>7} read, {tally.refused:>7} "
                  f"refused (one line), {tally.tracebacks:>5} tracebacks, {tally.hangs:>3} "
                  f"hangs, {tally.nonsense:>3} silent nonsense ({took:.0f} s)", flush=True)
            for place, n in tally.places.most_common(8):
                print(f"    {n:>6} x {place} (first: case {tally.example[place]})", flush=True)
            if not args.no_write:  # after each parser: a long run cut short keeps its rows
                _write(rows, names, args.cases)
    return 1 if any(t.tracebacks or t.hangs or t.nonsense for _, t, _ in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
