"""Save a whole map to one file and load it back exactly: segments, milestones, graph, config.

The file is an ``.npz`` (loaded with ``allow_pickle=False``) whose ``header`` entry is UTF-8
JSON: format name and version, beam geometry, the configuration used, the segments' anchors
and handovers, and (from version 2) a SHA-256 checksum of every other entry, which are numeric
arrays. A file is checked on load (checksum, shapes, finite poses, segment and milestone ids in
range) and a damaged one refused with one line; version 1 files (no checksum) still load.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tokenize
import zipfile
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from milestones.manager import MilestoneManager
from vmp.config import MappingConfig, config_from_dict
from vmp.errors import InputError
from vmp.fileio import atomic_write, not_regular
from vmp.pose_graph import PoseGraph
from vmp.types import ScanFrame, check_beams
from vmp.vector_map import BeamGeometry, VectorMap

__all__ = ["FORMAT", "VERSION", "MapData", "load_map", "save_map"]

FORMAT = "vmp-slam map"
VERSION = 3  # 2: the header holds a checksum of the arrays; 3: of the header too
READS = (1, 2, 3)  # the versions this program reads
MAX_EXTENT = 1e6  # m: a pose farther out than this is damage, not a building
_MS = "milestones/"


@dataclass
class MapData:
    """Everything a map file holds."""

    map: VectorMap
    milestones: MilestoneManager
    graph: PoseGraph
    config: dict
    trajectory_stamps: np.ndarray
    trajectory: np.ndarray  # assembled scan poses when saved (S, 3)

    def frames(self) -> list[ScanFrame]:
        """The map's scans as frames: ranges from the stored end points (``inf`` where a beam
        had no return), the assembled poses as their odometry, the stored stamps."""
        vmap = self.map
        g = vmap.geometry
        pts = vmap.end_points.astype(np.float64)
        reach = np.hypot(pts[..., 0], pts[..., 1])
        hits = vmap.scan_hits(range(len(vmap)))
        ranges = np.where(hits, np.minimum(reach, g.max_range), np.inf)
        # A scan whose beams without a return were kept as a 2 cm fan proved no free space.
        fan = (~hits & (reach < 0.03)).any(axis=1)
        stamps = vmap.stamps
        return [ScanFrame(float(stamps[k]), ranges[k], g.angle_min, g.angle_increment,
                          g.max_range, odom=self.trajectory[k], index=k,
                          no_return_free=0.0 if fan[k] else None)
                for k in range(len(vmap))]  # one frame object per stored scan

    def check_beams(self, geometry: BeamGeometry, label: str) -> None:
        """Refuse scans of another scanner than the map's (other beams) with a clear error."""
        if not geometry.same_beams(self.map.geometry):
            raise InputError(f"{label}: {geometry.describe()}, the map's scanner "
                             f"{self.map.geometry.describe()}: use the scanner the map was "
                             "made with")

    def check_as_loaded(self, label: str) -> None:
        """Refuse a map another run has mapped on since it was loaded, with a clear error
        (:class:`vmp.run.MappingRun` maps on in the map it is given: its scans then outnumber
        the poses loaded with it)."""
        if len(self.map) != len(self.trajectory):
            raise InputError(f"{label}: the saved map holds {len(self.map)} scans but "
                             f"{len(self.trajectory)} poses: a run has mapped on in it since "
                             "it was loaded; load it again for another run")


def save_map(path: str | os.PathLike[str], vmap: VectorMap, milestones: MilestoneManager,
             graph: PoseGraph, config: dict, trajectory: np.ndarray) -> None:
    """Write the map atomically."""
    ms = milestones.state()
    header = {
        "format": FORMAT, "version": VERSION,
        "geometry": asdict(vmap.geometry),
        "free_range": vmap.free_range,
        "config": config,
        "segment_anchor": vmap.segment_anchor,
        "segment_end": [None if e is None else [e[0], [float(v) for v in e[1]]]
                        for e in vmap.segment_end],
        "milestones": {"config": ms.pop("config"), "geometry": ms.pop("geometry"),
                       "next_id": ms.pop("next_id")},
        "edge_kinds": [e.kind for e in graph.edges],
    }
    arrays = {
        "points": vmap.end_points, "hits": vmap.packed_hits, "rel": vmap.rel_poses,
        "segment": vmap.segments, "stamps": vmap.stamps, "trajectory": trajectory,
        "edge_ij": np.array([[e.i, e.j] for e in graph.edges], dtype=np.int64).reshape(-1, 2),
        "edge_z": np.array([e.z for e in graph.edges]).reshape(-1, 3),
        "edge_info": np.array([e.information for e in graph.edges]).reshape(-1, 3, 3),
    }
    arrays.update({_MS + k: v for k, v in ms.items()})
    header["checksum"] = checksum(arrays, header)
    with atomic_write(path, "wb") as f:
        np.savez_compressed(f, header=np.frombuffer(json.dumps(header).encode(),
                                                    dtype=np.uint8), **arrays)


def checksum(arrays: dict[str, np.ndarray], header: dict | None = None) -> str:
    """SHA-256 over the arrays' names, types, shapes and bytes, in name order, and over the
    ``header`` but its checksum (its JSON with sorted keys; None: the arrays alone, as
    version 2 files hold it)."""
    h = hashlib.sha256()
    if header is not None:
        fields = {k: v for k, v in header.items() if k != "checksum"}
        h.update(json.dumps(fields, sort_keys=True).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _shape(a: dict[str, np.ndarray], key: str, shape: tuple, kind: str,
           finite: bool = False) -> np.ndarray:
    """``a[key]`` checked for its shape (``-1``: any length) and kind of number."""
    arr = a[key]
    if arr.dtype.kind not in kind or arr.ndim != len(shape) or any(
            want not in (-1, got) for want, got in zip(shape, arr.shape, strict=True)):
        want = "x".join("N" if n == -1 else str(n) for n in shape)
        raise ValueError(f"entry {key!r} is {arr.dtype} {arr.shape}, expected {want}")
    if finite and not np.isfinite(arr).all():
        raise ValueError(f"entry {key!r} holds a value that is not finite")
    return arr


def _check(header: dict, a: dict[str, np.ndarray]) -> None:
    """Raise ValueError naming what in a loaded map file's contents is out of shape or range."""
    g = header["geometry"]
    if not isinstance(g, dict) or not isinstance(g.get("num_beams"), int) or not all(
            isinstance(g.get(k), int | float) for k in ("angle_min", "angle_increment",
                                                        "max_range")):
        raise ValueError("its beam geometry is not a scanner's")
    try:
        check_beams(g["num_beams"], g["angle_min"], g["angle_increment"], g["max_range"])
    except ValueError as exc:
        raise ValueError(f"its beam geometry is not a scanner's: {exc}") from None
    free = header.get("free_range")
    if free is not None and not (isinstance(free, int | float) and 0 <= free <= MAX_EXTENT):
        raise ValueError(f"free_range {free!r}, expected metres >= 0 or none")
    _check_config(header)
    n = g["num_beams"]
    scans = len(a["stamps"])
    points = _shape(a, "points", (scans, n, 2), "f", finite=True)
    if scans and float(np.abs(points).max()) > g["max_range"] * 1.01:
        raise ValueError("a scan's end point lies beyond the scanner's range")
    _shape(a, "hits", (scans, (n + 7) // 8), "u")
    _shape(a, "stamps", (scans,), "f", finite=True)
    for key in ("rel", "trajectory", _MS + "poses"):
        if float(np.abs(_shape(a, key, (-1, 3), "f", finite=True)[:, :2]).max(
                initial=0.0)) > MAX_EXTENT:
            raise ValueError(f"entry {key!r} holds a pose farther than {MAX_EXTENT:g} m out")
    _shape(a, "rel", (scans, 3), "f")
    _shape(a, "trajectory", (scans, 3), "f")
    segment = _shape(a, "segment", (scans,), "iu")
    anchors, ends = header["segment_anchor"], header["segment_end"]
    if not isinstance(anchors, list) or not isinstance(ends, list) or len(ends) != len(anchors):
        raise ValueError("its segment anchors and ends do not pair up")
    if scans and (segment[0] != 0 or np.any(np.diff(segment) < 0) or np.any(
            np.diff(segment) > 1) or segment[-1] >= len(anchors)):
        raise ValueError("its scans' segment numbers do not run 0, 1, ... over its segments")
    ids = _shape(a, _MS + "ids", (-1,), "iu")
    m = len(ids)
    _shape(a, _MS + "signatures", (m, -1), "f", finite=True)
    _shape(a, _MS + "features", (m, -1), "f", finite=True)
    _shape(a, _MS + "scans", (-1,), "f")
    _shape(a, _MS + "poses", (m, 3), "f", finite=True)
    _shape(a, _MS + "stamps", (m,), "f", finite=True)
    lengths = _shape(a, _MS + "scan_lengths", (m,), "iu")
    if (lengths < 0).any() or int(lengths.sum()) != len(a[_MS + "scans"]):
        raise ValueError("its milestones' scan lengths do not add up")
    if m and (np.any(np.diff(ids) <= 0) or ids[0] < 0):
        raise ValueError("its milestone ids are not increasing")
    known = set(ids.tolist())
    if any(not isinstance(x, int) or x not in known for x in anchors):
        raise ValueError("a segment is anchored at a milestone the map does not hold")
    if not all(e is None or (isinstance(e, list) and len(e) == 2 and e[0] in known)
               for e in ends):
        raise ValueError("a segment hands over to a milestone the map does not hold")
    ij = _shape(a, "edge_ij", (-1, 2), "iu")
    e = len(ij)
    _shape(a, "edge_z", (e, 3), "f", finite=True)
    info = _shape(a, "edge_info", (e, 3, 3), "f", finite=True)
    if e and (np.abs(info - info.transpose(0, 2, 1)).max() > 1e-6 * max(
            1.0, float(np.abs(info).max())) or (np.diagonal(info, axis1=1, axis2=2) < 0).any()):
        raise ValueError("a graph edge's information matrix is not symmetric positive")
    if not np.isin(ij, ids).all():
        raise ValueError("a graph edge joins a milestone the map does not hold")
    if not isinstance(header["edge_kinds"], list) or len(header["edge_kinds"]) != e:
        raise ValueError("its graph edges and their kinds do not pair up")


def _check_config(header: dict) -> None:
    """Raise ValueError unless the header's configurations are mappings whose settings this
    program knows lie in their ranges (settings it does not know are left alone: a file from
    another version may name them)."""
    config, ms = header["config"], header["milestones"]
    if not isinstance(config, dict) or not isinstance(ms, dict) or not isinstance(
            ms.get("config"), dict):
        raise ValueError("its configuration is not a mapping of settings")
    defaults = MappingConfig()
    sections = {f.name: {g.name for g in dataclasses.fields(getattr(defaults, f.name))}
                for f in dataclasses.fields(defaults)}
    known = {name: {k: v for k, v in values.items() if k in sections[name]}
             for name, values in config.items() if name in sections and isinstance(values, dict)}
    known["milestones"] = {k: v for k, v in ms["config"].items() if k in sections["milestones"]}
    try:
        config_from_dict(known, "configuration")
    except InputError as exc:
        raise ValueError(str(exc)) from None


def load_map(path: str | os.PathLike[str]) -> MapData:
    """Read a map file; a missing, corrupt, damaged or foreign file raises :class:`InputError`
    with one line."""
    path = Path(path)
    if path.exists() and not path.is_file():  # a FIFO would block the read, a device not end
        raise InputError(f"{path}: {not_regular(path)}, not a map file")
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise InputError(f"{path}: not a vmp-slam map (a plain .npy array)")
        with data:
            a = {k: data[k] for k in data.files}
        header = json.loads(a.pop("header").tobytes().decode())
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except InputError:
        raise
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError, zlib.error,
            UnicodeDecodeError, NotImplementedError, RuntimeError, SyntaxError,
            tokenize.TokenError) as exc:  # the last two: a member's damaged .npy header
        raise InputError(f"{path}: not a readable vmp-slam map ({exc})") from exc
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise InputError(f"{path}: not a vmp-slam map file")
    if header.get("version") not in READS:
        raise InputError(f"{path}: map file version {header.get('version')}, this program "
                         f"reads versions {', '.join(map(str, READS))}")
    if header["version"] >= 2 and header.get("checksum") != checksum(
            a, header if header["version"] >= 3 else None):
        raise InputError(f"{path}: a damaged vmp-slam map (its checksum does not match)")
    try:
        _check(header, a)
    except (KeyError, TypeError, ValueError) as exc:
        what = f"no entry {exc}" if isinstance(exc, KeyError) else str(exc)
        raise InputError(f"{path}: a damaged vmp-slam map ({what})") from exc
    try:
        vmap = VectorMap(BeamGeometry(**header["geometry"]), header.get("free_range"))
        vmap.restore(header["segment_anchor"], header["segment_end"], a["points"], a["hits"],
                     a["rel"], a["segment"], a["stamps"])
        ms_state = {k[len(_MS):]: v for k, v in a.items() if k.startswith(_MS)}
        ms_state.update(header["milestones"])
        milestones = MilestoneManager.from_state(ms_state)
        graph = PoseGraph()
        for (i, j), z, info, kind in zip(a["edge_ij"], a["edge_z"], a["edge_info"],
                                         header["edge_kinds"], strict=True):
            graph.add_information(int(i), int(j), z, info, kind)
        return MapData(vmap, milestones, graph, header["config"], a["stamps"], a["trajectory"])
    except (KeyError, TypeError, ValueError) as exc:
        what = f"no entry {exc}" if isinstance(exc, KeyError) else str(exc)
        raise InputError(f"{path}: corrupt vmp-slam map ({what})") from exc
