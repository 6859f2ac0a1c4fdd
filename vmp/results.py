"""A mapping run's results folder: dated, with a ``latest`` link beside it.

::

    results/office-20261123-101500/
        trajectory.tum       the assembled map's scan poses (TUM: t x y z qx qy qz qw)
        online.tum           the filter's pose at each scan as it ran
        odometry.tum         the source's odometry
        ground_truth.tum     the true poses, when the source knows them (simulation)
        map.vmpmap           the whole map (segments, milestones, graph, configuration)
        milestones.npz       the milestones alone (milestones.store format)
        grid.yaml, grid.pgm  occupancy grid, ROS map_server form; grid.png; grid.npy
        contours.geojson     boundary of free space
        graph.json           milestone graph
        config.yaml          the configuration used
        metrics.json         the summary printed at the end of the run
    results/latest -> office-20261123-101500
"""

from __future__ import annotations

import datetime as dt
import json
import os
from pathlib import Path

import numpy as np

from milestones.store import save_milestones
from vmp import __version__
from vmp.config import save_config
from vmp.evaluate import ate
from vmp.export import (
    free_space_contours,
    occupancy_grid,
    write_geojson,
    write_graph_json,
    write_png,
    write_ros_map,
)
from vmp.fileio import atomic_write
from vmp.mapfile import save_map
from vmp.pipeline import Pipeline
from vmp.tum import write_tum

__all__ = ["export_all", "new_results_dir", "write_results"]


def new_results_dir(root: Path, name: str) -> Path:
    """Create ``root/NAME-YYYYmmdd-HHMMSS`` (unique) and point ``root/latest`` at it."""
    root.mkdir(parents=True, exist_ok=True)
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = root / f"{name}-{stamp}"
    k = 1
    while path.exists():
        k += 1
        path = root / f"{name}-{stamp}-{k}"
    path.mkdir()
    link = root / "latest"
    tmp = root / f".latest.{os.getpid()}"
    try:
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(path.name)
        os.replace(tmp, link)
    except OSError:  # a file system without links: the dated folder still holds everything
        pass
    return path


def export_all(out: Path, vmap, poses: np.ndarray, milestones, graph, resolution: float,
               contours: bool = True) -> dict[str, str]:
    """Grid (map_server, PNG, npy), contours and graph of a map with scan ``poses``."""
    polys = vmap.polygons(poses)
    hits = vmap.world_points(poses)
    grid = occupancy_grid(polys, hits, resolution)
    written = {}
    write_ros_map(out / "grid.yaml", grid)
    write_png(out / "grid.png", grid)
    with atomic_write(out / "grid.npy", "wb") as f:
        np.save(f, grid.cells, allow_pickle=False)
    written["grid"] = str(out / "grid.yaml")
    if contours:
        geom = free_space_contours(polys)
        write_geojson(out / "contours.geojson", geom,
                      {"what": "boundary of free space", "area_m2": round(geom.area, 3)})
        written["contours"] = str(out / "contours.geojson")
    write_graph_json(out / "graph.json", milestones.ids, milestones.poses, milestones.stamps,
                     graph.edges)
    written["graph"] = str(out / "graph.json")
    return written


def write_results(out: Path, pipeline: Pipeline, stamps: np.ndarray, source: str,
                  resolution: float = 0.05, extra: dict | None = None) -> dict:
    """Write every output of a finished run into ``out``; returns the metrics.

    ``extra`` entries (plain values) join the metrics after the source.
    """
    from vmp.config import config_to_dict

    mapping_time = pipeline.wall_time
    traj = pipeline.trajectory()
    online = np.array(pipeline.online)
    odom = np.array(pipeline.odometry)
    write_tum(out / "trajectory.tum", stamps, traj)
    write_tum(out / "online.tum", stamps, online)
    write_tum(out / "odometry.tum", stamps, odom)
    metrics: dict = {"source": source, "version": __version__}
    metrics.update(extra or {})
    metrics.update(pipeline.summary())
    truth = pipeline.truth
    if all(t is not None for t in truth) and len(truth) > 2:
        gt = np.array(truth)
        write_tum(out / "ground_truth.tum", stamps, gt)
        metrics["ATE (m)"] = ate(stamps, traj, stamps, gt).rmse
        metrics["ATE odometry alone (m)"] = ate(stamps, odom, stamps, gt).rmse
    save_map(out / "map.vmpmap", pipeline.map, pipeline.milestones, pipeline.graph,
             config_to_dict(pipeline.config), traj)
    save_milestones(out / "milestones.npz", pipeline.milestones)
    save_config(out / "config.yaml", pipeline.config)
    export_all(out, pipeline.map, traj, pipeline.milestones, pipeline.graph, resolution)
    metrics["mapping time (s)"] = mapping_time
    metrics["scans per second"] = len(traj) / max(mapping_time, 1e-9)
    if len(stamps) > 1:
        metrics["data duration (s)"] = float(stamps.max() - stamps.min())
    with atomic_write(out / "metrics.json", "w") as f:
        json.dump(metrics, f, indent=1, default=float)
    return metrics


def format_metrics(metrics: dict) -> str:
    """The metrics as an aligned two-column table."""
    rows = [(k, v) for k, v in metrics.items() if k not in ("source", "version")]
    width = max(len(k) for k, _ in rows)
    lines = [f"{'metric':<{width}}  value", f"{'-' * width}  -----"]
    for k, v in rows:
        text = f"{v:.4g}" if isinstance(v, float) else str(v)
        lines.append(f"{k:<{width}}  {text}")
    return "\n".join(lines)
