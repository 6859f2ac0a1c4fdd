"""The vector map in the forms others read: occupancy grids (ROS map_server, PNG, .npy), the
contours of free space (GeoJSON) and the milestone graph (JSON).

The grid: inside any scan polygon is free, a cell with hits (seen often enough against how
often it was seen free) is occupied, the rest unknown. Polygons are filled by a vectorised
even-odd scan-line fill: every polygon edge crossing every pixel row becomes one entry of one
array, and the runs between crossings are summed into the grid with a cumulative sum.
"""

from __future__ import annotations

import json
import math
import os
import struct
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
import yaml
from numpy.typing import NDArray

from vmp.errors import InputError
from vmp.fileio import atomic_write, not_regular, read_yaml
from vmp.raster_kernel import add_spans
from vmp.types import FloatArray

__all__ = ["FREE", "OCCUPIED", "UNKNOWN", "Grid", "coverage", "free_space_contours",
           "occupancy_grid", "read_ros_map", "write_graph_json", "write_png",
           "write_ros_map"]

UNION_RUNS = 8  # the free space is united in this many runs of consecutive scans ...
UNION_MIN_CHUNK = 200  # ... of at least this many (fewer scans: fewer runs)
UNION_PIECE = 1000  # polygons made and united at once within a thread (bounds memory)

OCCUPIED, FREE, UNKNOWN = 0, 254, 205


@dataclass(frozen=True)
class Grid:
    """An occupancy grid; row 0 is the bottom (lowest y), as the map frame has it."""

    cells: NDArray[np.uint8]  # (H, W) of OCCUPIED, FREE, UNKNOWN
    resolution: float  # metres per cell
    origin: tuple[float, float]  # map coordinates of the lower-left corner of cell (0, 0)

    @property
    def shape(self) -> tuple[int, int]:
        return self.cells.shape


def coverage(polygons: FloatArray, origin: tuple[float, float], resolution: float,
             shape: tuple[int, int]) -> NDArray[np.int32]:
    """How many polygons cover each cell centre (even-odd rule per polygon).

    ``polygons`` is ``(P, V, 2)``, each an implicitly closed ring (rasterised by
    :func:`vmp.raster_kernel.add_spans`).
    """
    H, W = shape
    acc = np.zeros((H, W + 1), dtype=np.int32)
    add_spans(acc, np.ascontiguousarray(polygons, dtype=np.float64), float(origin[0]),
              float(origin[1]), float(resolution))
    return np.cumsum(acc, axis=1)[:, :W]


def occupancy_grid(polygons: FloatArray, hits: FloatArray, resolution: float,
                   margin: float = 0.5, min_hit_share: float = 0.25) -> Grid:
    """Rasterise scan polygons ``(P, V, 2)`` and hit points ``(K, 2)`` into a grid.

    A cell is occupied when its hits make at least ``min_hit_share`` of all the times it was
    seen (hits plus polygons covering it): a person walking through leaves few hits where
    many scans saw free space.
    """
    if resolution <= 0 or not math.isfinite(resolution):
        raise InputError(f"resolution must be a positive number of metres, got {resolution}")
    pts = polygons.reshape(-1, 2)
    lo = np.minimum(pts.min(axis=0), hits.min(axis=0) if len(hits) else pts.min(axis=0))
    hi = np.maximum(pts.max(axis=0), hits.max(axis=0) if len(hits) else pts.max(axis=0))
    origin = (float(np.floor((lo[0] - margin) / resolution) * resolution),
              float(np.floor((lo[1] - margin) / resolution) * resolution))
    W = int(np.ceil((hi[0] + margin - origin[0]) / resolution))
    H = int(np.ceil((hi[1] + margin - origin[1]) / resolution))
    if H * W > 200_000_000:
        raise InputError(f"a {W} x {H} grid is too large; use a coarser --resolution")
    cover = coverage(polygons, origin, resolution, (H, W))
    hit_count = np.zeros((H, W), dtype=np.int32)
    if len(hits):
        ix = np.floor((hits[:, 0] - origin[0]) / resolution).astype(np.int64)
        iy = np.floor((hits[:, 1] - origin[1]) / resolution).astype(np.int64)
        ok = (ix >= 0) & (ix < W) & (iy >= 0) & (iy < H)
        hit_count = np.bincount(iy[ok] * W + ix[ok], minlength=H * W).reshape(H, W)
    cells = np.full((H, W), UNKNOWN, dtype=np.uint8)
    cells[cover > 0] = FREE
    occupied = (hit_count > 0) & (hit_count >= min_hit_share * (hit_count + cover))
    cells[occupied] = OCCUPIED
    return Grid(cells, float(resolution), origin)


# ---- files ----------------------------------------------------------------------------------

def write_ros_map(yaml_path: str | Path, grid: Grid) -> Path:
    """Write ``NAME.pgm`` (P5) and ``NAME.yaml`` in the form ROS map_server reads.

    Rows are flipped so that image row 0 is the top of the map; ``origin`` is the map
    position of the lower-left pixel.
    """
    yaml_path = Path(yaml_path)
    if yaml_path.suffix not in (".yaml", ".yml"):
        raise InputError(f"{yaml_path}: the grid's metadata file must end in .yaml")
    pgm = yaml_path.with_suffix(".pgm")
    H, W = grid.shape
    with atomic_write(pgm, "wb") as f:
        f.write(f"P5\n# vmp-slam occupancy grid, {grid.resolution} m/cell\n{W} {H}\n255\n"
                .encode("ascii"))
        f.write(np.ascontiguousarray(grid.cells[::-1]).tobytes())
    meta = {
        "image": pgm.name,
        "resolution": grid.resolution,
        # A whole number of cells in floating point (-217 * 0.05 = -10.850000000000001):
        # written to the nanometre, as a person would write it.
        "origin": [round(float(grid.origin[0]), 9), round(float(grid.origin[1]), 9), 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        "mode": "trinary",
    }
    with atomic_write(yaml_path, "w") as f:
        yaml.safe_dump(meta, f, sort_keys=False)
    return pgm


def read_ros_map(yaml_path: str | Path) -> Grid:
    """Read a map_server map (YAML + P5 PGM) back into a :class:`Grid`."""
    yaml_path = Path(yaml_path)
    try:
        meta = read_yaml(yaml_path)
        image = yaml_path.parent / str(meta["image"])
        if image.exists() and not image.is_file():
            raise InputError(f"{image}: {not_regular(image)}, not a PGM image")
        data = image.read_bytes()
        resolution = float(meta["resolution"])
        origin = (float(meta["origin"][0]), float(meta["origin"][1]))
    except (OSError, KeyError, TypeError, ValueError, IndexError, UnicodeDecodeError,
            yaml.YAMLError) as exc:
        raise InputError(f"{yaml_path}: not a readable map_server map: {exc}") from exc
    if not (math.isfinite(resolution) and resolution > 0 and all(map(math.isfinite, origin))):
        raise InputError(f"{yaml_path}: resolution must be a positive number and origin "
                         f"finite, got {resolution}, {origin}")
    fields = _pgm_header(data)
    if fields is None or fields[0] != b"P5" or not all(f.isdigit() for f in fields[1:]) \
            or int(fields[3]) != 255:
        raise InputError(f"{image}: not an 8-bit P5 PGM")
    W, H, pos = int(fields[1]), int(fields[2]), int(fields[4])
    body = data[pos + 1:pos + 1 + W * H]
    if len(body) != W * H:
        raise InputError(f"{image}: {len(body)} bytes of pixels, its header says {W} x {H}")
    pixels = np.frombuffer(body, dtype=np.uint8).reshape(H, W)
    return Grid(pixels[::-1].copy(), resolution, origin)


def _pgm_header(data: bytes) -> list[bytes] | None:
    """The magic, width, height and maximum of a PGM header, then the offset after them
    (as digits), or None when the header is cut off."""
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:
        while data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            pos = data.find(b"\n", pos) + 1
            if pos == 0:
                return None
            continue
        end = pos
        while end < len(data) and not data[end:end + 1].isspace():
            end += 1
        if end == pos:
            return None
        fields.append(data[pos:end])
        pos = end
    return [*fields, str(pos).encode()]


def write_png(path: str | Path, grid: Grid) -> None:
    """The grid as an 8-bit greyscale PNG, top row first (zlib, no imaging library needed)."""
    img = np.ascontiguousarray(grid.cells[::-1])
    H, W = img.shape
    raw = np.hstack([np.zeros((H, 1), dtype=np.uint8), img]).tobytes()  # filter byte 0

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, 0, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with atomic_write(path, "wb") as f:
        f.write(png)


def free_space_contours(polygons: FloatArray, grid_size: float = 0.01,
                        threads: int | None = None) -> shapely.Geometry:
    """The union of the scan polygons (free space) as one (multi)polygon, its vertices
    snapped to ``grid_size``; ``threads`` unite it (default: one per core).

    Consecutive runs of scans are united apart, in threads (GEOS releases the GIL), then the
    parts: on the Intel part's 5,505 scans 1.4 s on 2 cores against 2.4 s in one run. The
    runs are always the same (:data:`UNION_RUNS` of them), however many threads share them:
    the snapped result depends on how the scans are grouped (the Intel part's area moves by
    0.1 m^2 between 2, 4 and 8 runs), and a map's contours must not depend on the machine
    or on the runs beside it (a `vmp batch` worker unites with one thread: two runs side by
    side, each uniting with both cores, cost 9-13 % more CPU). 1, 2, 4 and 8 runs cost the
    same CPU to within noise (Intel part 2.4-2.6 s, office 1.3 s, one thread). Within a run
    the polygons are made and united :data:`UNION_PIECE` at a time, so that not every scan's
    geometry exists at once.
    """
    count = max(1, min(UNION_RUNS, len(polygons) // UNION_MIN_CHUNK))
    if count == 1:
        return _union_pieces(polygons, grid_size)
    runs = np.array_split(np.arange(len(polygons)), count)  # none empty: count <= len / 200
    with ThreadPoolExecutor(max(1, min(count, threads or os.cpu_count() or 1))) as pool:
        parts = list(pool.map(lambda run: _union_pieces(polygons[run[0]:run[-1] + 1],
                                                        grid_size), runs))
    return _snapped_union(parts, grid_size)


def _snapped_union(geometries: list, grid_size: float) -> shapely.Geometry:
    """The union of ``geometries`` snapped to ``grid_size``. GEOS's snap-rounding overlay can
    fail on edges that nearly coincide ("TopologyException: Ring edge missing", the Radish
    freiburg-079 log's last union, which ended `vmp map` without contours): then the union
    is made in floating point and snapped afterwards (valid, its area within 0.08 m^2 of
    470.9 m^2 there)."""
    try:
        return shapely.union_all(geometries, grid_size=grid_size)
    except shapely.errors.GEOSException:
        united = shapely.union_all(geometries)
        try:
            return shapely.set_precision(united, grid_size)
        except shapely.errors.GEOSException:  # never seen; the union unsnapped is still it
            return united


def _union_pieces(polygons: FloatArray, grid_size: float) -> shapely.Geometry:
    """The union of consecutive polygons, made and united a piece at a time, snapped to
    ``grid_size``.

    Beams along a wall end on one line: Douglas-Peucker within the snapping grid keeps a
    182-vertex Intel scan to 69 vertices on average and makes the union of the Intel part's
    scans about 1.6 times as fast on one core, its area within 0.04 m^2 of 646 m^2. The
    pieces are united in floating point and only their union snapped: snap-rounding every
    piece's union would take about twice the CPU for a boundary within 2.4 mm of it on
    average (their symmetric difference over the boundary's length). The simplification need
    not preserve topology (a quarter of its cost): a scan polygon is a star around its origin
    and came out invalid in none of 100,000 random ones, but a scan taken a centimetre from
    a wall with one beam through a gap can vanish, and such a one is simplified again the
    careful way.
    """
    pieces = []
    for k in range(0, len(polygons), UNION_PIECE):
        polys = shapely.polygons(polygons[k:k + UNION_PIECE])
        polys = polys[shapely.is_valid(polys)]
        simple = shapely.simplify(polys, grid_size, preserve_topology=False)
        bad = ~shapely.is_valid(simple) | shapely.is_empty(simple)
        if bad.any():
            simple[bad] = shapely.simplify(polys[bad], grid_size, preserve_topology=True)
        pieces.append(shapely.union_all(simple))
    return _snapped_union(pieces, grid_size)


def write_geojson(path: str | Path, geometry: shapely.Geometry, properties: dict) -> None:
    feature = {"type": "Feature", "properties": properties,
               "geometry": json.loads(shapely.to_geojson(geometry))}
    with atomic_write(path, "w") as f:
        json.dump({"type": "FeatureCollection", "features": [feature]}, f)


def write_graph_json(path: str | Path, ids: NDArray, poses: FloatArray, stamps: FloatArray,
                     edges: list) -> None:
    """Milestones (nodes) and path / loop edges (:class:`vmp.pose_graph.Edge`) as JSON."""
    edges = [{"from": e.i, "to": e.j, "kind": e.kind, "x": float(e.z[0]), "y": float(e.z[1]),
              "theta": float(e.z[2])} for e in edges]
    nodes = [{"id": int(i), "x": float(p[0]), "y": float(p[1]), "theta": float(p[2]),
              "stamp": float(s)} for i, p, s in zip(ids, poses, stamps, strict=True)]
    with atomic_write(path, "w") as f:
        json.dump({"frame": "map", "units": "m, rad", "nodes": nodes, "edges": edges}, f,
                  indent=1)
