"""Save a whole map to one file and load it back exactly: segments, milestones, graph, config.

The file is an ``.npz`` (loaded with ``allow_pickle=False``) whose ``header`` entry is UTF-8
JSON: format name and version, beam geometry, the configuration used, and the segments'
anchors and handovers. Every other entry is a numeric array.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from milestones.manager import MilestoneManager
from vmp.errors import InputError
from vmp.fileio import atomic_write
from vmp.pose_graph import PoseGraph
from vmp.types import ScanFrame
from vmp.vector_map import BeamGeometry, VectorMap

__all__ = ["FORMAT", "VERSION", "MapData", "load_map", "save_map"]

FORMAT = "vmp-slam map"
VERSION = 1
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
    with atomic_write(path, "wb") as f:
        np.savez_compressed(f, header=np.frombuffer(json.dumps(header).encode(),
                                                    dtype=np.uint8), **arrays)


def load_map(path: str | os.PathLike[str]) -> MapData:
    """Read a map file; a missing, corrupt or foreign file raises :class:`InputError`."""
    path = Path(path)
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
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError,
            UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable vmp-slam map ({exc})") from exc
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise InputError(f"{path}: not a vmp-slam map file")
    if header.get("version") != VERSION:
        raise InputError(f"{path}: map file version {header.get('version')}, this program "
                         f"reads version {VERSION}")
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
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: corrupt vmp-slam map ({exc})") from exc
    return MapData(vmap, milestones, graph, header["config"], a["stamps"], a["trajectory"])
