"""``vmp export``: a saved map as an occupancy grid, PNG, .npy, contours or graph."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from vmp.cli.args import cell_size
from vmp.cli.common import warn_if_incomplete
from vmp.errors import InputError

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    ex = sub.add_parser(
        "export", help="write a map as an occupancy grid, PNG, .npy, contours or graph",
        description="Export a result (a results folder or a .vmpmap file): an occupancy grid "
        "in the ROS map_server form (PGM + YAML), a PNG, a NumPy array, the contours of free "
        "space as GeoJSON and the milestone graph as JSON.",
        epilog="examples:\n  vmp export results/latest --grid map.yaml --resolution 0.05\n"
        "  vmp export results/latest/map.vmpmap --png map.png --contours free.geojson\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ex.add_argument("result", type=Path, help="results folder or .vmpmap file")
    ex.add_argument("--grid", type=Path, metavar="YAML", help="map_server YAML (+ PGM beside)")
    ex.add_argument("--resolution", type=cell_size, default=0.05,
                    help="metres per cell (default 0.05)")
    ex.add_argument("--png", type=Path, help="greyscale PNG of the grid")
    ex.add_argument("--npy", type=Path, help="the grid as a NumPy array (0, 205, 254)")
    ex.add_argument("--contours", type=Path, metavar="GEOJSON", help="boundary of free space")
    ex.add_argument("--graph", type=Path, metavar="JSON", help="milestone graph")
    ex.set_defaults(run=run)


def _map_file(result: Path) -> Path:
    path = result / "map.vmpmap" if result.is_dir() else result
    if not path.is_file():
        raise InputError(f"{result}: neither a results folder with map.vmpmap nor a map file")
    return path


def run(args: argparse.Namespace) -> int:
    from vmp.export import (
        free_space_contours,
        occupancy_grid,
        write_geojson,
        write_graph_json,
        write_png,
        write_ros_map,
    )
    from vmp.fileio import atomic_write
    from vmp.mapfile import load_map

    if not any((args.grid, args.png, args.npy, args.contours, args.graph)):
        raise InputError("nothing to export: give --grid, --png, --npy, --contours or --graph")
    warn_if_incomplete(args.result)
    data = load_map(_map_file(args.result))
    poses = data.trajectory
    polys = data.map.polygons(poses)
    if args.grid or args.png or args.npy:
        grid = occupancy_grid(polys, data.map.world_points(poses), args.resolution)
        if args.grid:
            pgm = write_ros_map(args.grid, grid)
            print(f"grid: {args.grid} + {pgm} ({grid.shape[1]} x {grid.shape[0]} cells of "
                  f"{grid.resolution} m)")
        if args.png:
            write_png(args.png, grid)
            print(f"png: {args.png}")
        if args.npy:
            with atomic_write(args.npy, "wb") as f:
                np.save(f, grid.cells, allow_pickle=False)
            print(f"npy: {args.npy}")
    if args.contours:
        geom = free_space_contours(polys)
        write_geojson(args.contours, geom, {"what": "boundary of free space"})
        print(f"contours: {args.contours} ({geom.area:.1f} m2 of free space)")
    if args.graph:
        ms = data.milestones
        write_graph_json(args.graph, ms.ids, ms.poses, ms.stamps, data.graph.edges)
        print(f"graph: {args.graph} ({len(ms)} milestones, {len(data.graph.edges)} edges)")
    return 0
