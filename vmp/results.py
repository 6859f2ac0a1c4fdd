"""The outcome of a mapping run, and what it writes into its results folder
(:mod:`vmp.folders` makes the folder and marks it complete).

::

    results/office-20261123-101500/
        trajectory.tum       the assembled map's scan poses (TUM: t x y z qx qy qz qw)
        online.tum           the filter's pose at each scan as it ran
        odometry.tum         the source's odometry
        ground_truth.tum     the true poses, when the source knows them (simulation)
        reference.tum        another system's poses, when the source carries them (GMapping)
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

import json
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from milestones.store import save_milestones
from vmp import __version__
from vmp.config import MappingConfig, config_to_dict, save_config
from vmp.evaluate import ate, ate_in_order
from vmp.export import (
    Grid,
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
from vmp.source import Reference, SourceReport
from vmp.tum import write_tum
from vmp.types import FloatArray

__all__ = ["Result", "export_all", "format_metrics"]


@dataclass
class Result:
    """A finished (or interrupted) run: the map, the trajectories, what the source reported."""

    label: str  # what was mapped, as the user named it
    config: MappingConfig
    pipeline: Pipeline
    stamps: FloatArray  # (S,) of the mapped scans
    trajectory: FloatArray  # (S, 3) poses in the assembled map
    online: FloatArray  # (S, 3) the filter's pose after each scan, as it ran
    odometry: FloatArray  # (S, 3) where odometry alone put the robot
    reference: Reference | None  # the source's reference poses, one per mapped scan
    report: SourceReport
    mapping_time: float  # seconds of the run loop and the final adjustment
    interrupted: str | None = None  # the signal that ended the run early, if one did
    compiling_time: float = 0.0  # seconds of mapping_time spent compiling kernels (first run)
    _grids: dict[float, Grid] = field(default_factory=dict, repr=False)
    _polygons: FloatArray | None = field(default=None, repr=False)

    @property
    def scans(self) -> int:
        return len(self.stamps)

    @property
    def corrections(self) -> list[tuple[int, str, FloatArray, FloatArray]]:
        """Every correction of the robot's pose: (scan index, kind, pose before, after)."""
        return self.pipeline.corrections

    def polygons(self) -> FloatArray:
        """The scan polygons of the assembled map (computed once)."""
        if self._polygons is None:
            self._polygons = self.pipeline.map.polygons(self.trajectory)
        return self._polygons

    def grid(self, resolution: float = 0.05) -> Grid:
        """The occupancy grid of the assembled map (computed once per resolution)."""
        if resolution not in self._grids:
            vmap = self.pipeline.map
            self._grids[resolution] = occupancy_grid(self.polygons(),
                                                     vmap.world_points(self.trajectory),
                                                     resolution)
        return self._grids[resolution]

    def metrics(self) -> dict:
        """The run's figures: the pipeline's counts, accuracy where a reference exists, speed."""
        out: dict = {"source": self.label, "version": __version__}
        out.update(self.report.counts)
        out.update(self.pipeline.summary())
        ref = self.reference
        if ref is not None and self.scans > 2:
            if ref.truth:
                out["ATE (m)"] = self._ate(self.trajectory)
                out["ATE odometry alone (m)"] = self._ate(self.odometry)
            else:
                out[f"ATE vs {ref.label} (m)"] = self._ate(self.trajectory)
                out[f"ATE of odometry vs {ref.label} (m)"] = self._ate(self.odometry)
        out["mapping time (s)"] = self.mapping_time
        if self.compiling_time:  # a first run after an install (later ones load them)
            out["compiling kernels (s)"] = self.compiling_time
        out["scans per second"] = self.scans / max(self.mapping_time - self.compiling_time,
                                                   1e-9)
        if self.scans > 1:
            out["data duration (s)"] = float(self.stamps.max() - self.stamps.min())
        if self.interrupted:
            out["interrupted by"] = self.interrupted
        return out

    def _ate(self, poses: FloatArray) -> float:
        ref = self.reference
        if ref.stamps is None:
            return ate_in_order(poses, ref.poses)
        return ate(self.stamps, poses, ref.stamps, ref.poses).rmse

    def write(self, out: Path, resolution: float = 0.05, threads: int | None = None) -> dict:
        """Write every output into the folder ``out``; returns the metrics. ``threads``: how
        many may unite the free space (default: one per core)."""
        # Uniting the free space is most of the writing (the Intel part: 2.7 s of 4.2 s; ACES
        # 5.0 of 7.9) and runs in GEOS, off the GIL: started first, it goes on while the rest
        # is rasterised and written.
        with ThreadPoolExecutor(1) as pool:
            free_space = pool.submit(free_space_contours, self.polygons(), threads=threads)
            self._write_all(out, resolution, free_space)
        metrics = self.metrics()
        with atomic_write(out / "metrics.json", "w") as f:
            json.dump(metrics, f, indent=1, default=float)
        return metrics

    def _write_all(self, out: Path, resolution: float, free_space: Future) -> None:
        write_tum(out / "trajectory.tum", self.stamps, self.trajectory)
        write_tum(out / "online.tum", self.stamps, self.online)
        write_tum(out / "odometry.tum", self.stamps, self.odometry)
        if self.reference is not None:
            name = "ground_truth.tum" if self.reference.truth else "reference.tum"
            write_tum(out / name, self.stamps, self.reference.poses)
        p = self.pipeline
        save_map(out / "map.vmpmap", p.map, p.milestones, p.back.graph,
                 config_to_dict(self.config), self.trajectory)
        save_milestones(out / "milestones.npz", p.milestones)
        save_config(out / "config.yaml", self.config)
        export_all(out, self, resolution, free_space)


def export_all(out: Path, result: Result, resolution: float, free_space: Future) -> None:
    """Grid (map_server, PNG, npy), graph and contours of a result; ``free_space`` is the
    union of its polygons under way (:func:`free_space_contours`), written last."""
    grid = result.grid(resolution)
    write_ros_map(out / "grid.yaml", grid)
    write_png(out / "grid.png", grid)
    with atomic_write(out / "grid.npy", "wb") as f:
        np.save(f, grid.cells, allow_pickle=False)
    ms = result.pipeline.milestones
    write_graph_json(out / "graph.json", ms.ids, ms.poses, ms.stamps,
                     result.pipeline.back.graph.edges)
    geom = free_space.result()
    write_geojson(out / "contours.geojson", geom,
                  {"what": "boundary of free space", "area_m2": round(geom.area, 3)})


# What a run's table leads with, in this order, where the run has it: accuracy, size, time,
# speed, loops. Everything else is grouped below it (with --verbose) and always in metrics.json.
HEADLINE = (
    "ATE (m)", "ATE odometry alone (m)", "error of localized poses, RMS (m)",
    "error of localized poses, max (m)", "share of scans localized", "scans until localized",
    "wrong fixes", "scans", "data duration (s)", "mapping time (s)", "localization time (s)",
    "compiling kernels (s)", "scans per second", "tracking: scans per second",
    "loop edges in the graph", "loop edges down-weighted", "milestones", "interrupted by",
    "damaged")
# The groups of the rest: a heading and the starts of its figures' names.
GROUPS = (
    ("source", ("bad ", "stamps running backwards", "map")),
    ("scan odometry", ("scan odometry", "odometry delay")),
    ("anchor matches", ("anchor matches", "milestone edges", "scans not matched")),
    ("signature matches", ("signature matches",)),
    ("loop search", ("loop ", "graph adjustment")),
    ("map", ("milestones recorded", "segments", "bytes per scan")),
    ("localization", ("times localized", "scans lost", "scans ambiguous", "scans standing",
                      "places searched", "localized scans")),
)


def _headline_key(key: str) -> bool:
    return key in HEADLINE or key.startswith(("ATE vs ", "ATE of odometry vs "))


def _group(key: str) -> str:
    for heading, starts in GROUPS:
        if key.startswith(starts):
            return heading
    return "other"


def format_metrics(metrics: dict, verbose: bool = False) -> str:
    """The metrics as an aligned two-column table: the headline figures first; with
    ``verbose`` the others after them under the headings of their groups, else a line saying
    how many more metrics.json holds."""
    rows = {k: v for k, v in metrics.items() if k not in ("source", "version")}
    head = [k for k in HEADLINE if k in rows] + [k for k in rows if _headline_key(k)
                                                 and k not in HEADLINE]
    rest = [k for k in rows if k not in head]
    width = max((len(k) for k in (rows if verbose else head)), default=6)
    lines = [f"{'metric':<{width}}  value", f"{'-' * width}  -----"]
    lines += [_row(k, rows[k], width) for k in head]
    if verbose:
        for heading in [g for g, _ in GROUPS] + ["other"]:
            keys = [k for k in rest if _group(k) == heading]
            if keys:
                lines += ["", f"{heading}:"] + [_row(k, rows[k], width) for k in keys]
    elif rest:
        lines.append(f"({len(rest)} more figures in metrics.json; --verbose prints them)")
    return "\n".join(lines)


def _row(key: str, value: object, width: int) -> str:
    text = f"{value:.4g}" if isinstance(value, float) else str(value)
    return f"{key:<{width}}  {text}"
