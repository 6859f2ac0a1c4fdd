"""A Rerun view of the map being assembled: plain arrays in, a recording (or a viewer) out.

Entities (the 2D view shows everything logged up to the time cursor):

* ``/world``: the map frame, flipped so that y points up on screen;
* ``/world/segments/{k}``: one entity per map segment, its transform the pose of the segment's
  anchor milestone, so re-anchoring a segment is one transform update; under it ``scans``
  (polygon outlines, LineStrips2D) and ``hits`` (Points2D), in the anchor's frame;
* ``/world/path/{estimate,odometry,truth}``: the poses, one point per scan;
* ``/world/robot``: the robot now (static: only the latest is kept), ``/world/matches``: an
  arrow from the robot to each milestone matched this scan, green accepted, red rejected;
* ``/world/milestones``: labelled points; ``/world/grid``: the occupancy grid image;
* ``/world/hypotheses``: localizing in a saved map, the places followed after each scan;
* ``/metrics/*``: innovation, match score, covariance trace; ``/log``: events.

Timelines: ``scan`` (index) and ``sensor_time``.
"""

from __future__ import annotations

import time
import uuid
from pathlib import Path

import numpy as np
import rerun as rr

from viz.blueprint import default_blueprint

__all__ = ["RerunView", "open_rerun"]

ACCEPTED = (40, 190, 60)
REJECTED = (220, 50, 40)
COLORS = {"estimate": (30, 120, 230), "odometry": (150, 150, 150), "truth": (40, 170, 80)}


def _rotation(theta: float) -> rr.RotationAxisAngle:
    return rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0], radians=float(theta))


def _transform(pose: np.ndarray) -> rr.Transform3D:
    return rr.Transform3D(translation=[float(pose[0]), float(pose[1]), 0.0],
                          rotation=_rotation(pose[2]))


def _place(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.column_stack([pose[0] + c * points[:, 0] - s * points[:, 1],
                            pose[1] + s * points[:, 0] + c * points[:, 1]])


class RerunView:
    """Implements the pipeline's view interface on a Rerun recording stream.

    Per-scan data is buffered and sent as columns every ``flush_every`` scans (and whenever
    something else happens): building one archetype per scan and entity would cost more than
    the mapping itself.
    """

    def __init__(self, recording: rr.RecordingStream, flush_every: int = 25) -> None:
        self.rec = recording
        self.flush_every = flush_every
        self._segment_anchor: list[int] = []
        self._milestones: dict[int, np.ndarray] = {}
        self._rows: dict[str, list[tuple[int, float, object]]] = {}
        self._pending = 0
        self._robot: np.ndarray | None = None
        self._matches: list[tuple[np.ndarray, np.ndarray, bool, str]] = []
        self._matches_at: np.ndarray | None = None
        self._now = (0, 0.0)
        self._state = ""  # the last localization state shown
        self.rec.log("/world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        for name, color in COLORS.items():
            self.rec.log(f"/world/path/{name}", rr.Points2D.from_fields(colors=[color],
                                                                         radii=[0.03]),
                         static=True)
        for name in ("innovation", "score", "covariance_trace"):
            self.rec.log(f"/metrics/{name}", rr.SeriesLines(names=[name]), static=True)

    # ---- time --------------------------------------------------------------------------------

    def _at(self, index: int, stamp: float) -> None:
        self.rec.set_time("scan", sequence=int(index))
        if stamp > 1e8:  # a Unix time from a real recording
            self.rec.set_time("sensor_time", timestamp=float(stamp))
        else:
            self.rec.set_time("sensor_time", duration=float(stamp))

    # ---- the view interface ------------------------------------------------------------------

    def _add(self, entity: str, index: int, stamp: float, payload: object) -> None:
        self._rows.setdefault(entity, []).append((index, stamp, payload))

    def flush(self) -> None:
        """Send the buffered scans as columns, one call per entity."""
        for entity, rows in self._rows.items():
            ks = [r[0] for r in rows]
            ts = np.array([r[1] for r in rows])
            time_col = (rr.TimeColumn("sensor_time", timestamp=ts) if ts.size and ts[0] > 1e8
                        else rr.TimeColumn("sensor_time", duration=ts))
            indexes = [rr.TimeColumn("scan", sequence=ks), time_col]
            payloads = [r[2] for r in rows]
            if entity.endswith("/scans"):
                cols = rr.LineStrips2D.columns(strips=payloads).partition([1] * len(rows))
            elif entity.startswith("/metrics/"):
                cols = rr.Scalars.columns(scalars=np.array(payloads, dtype=np.float64))
            elif entity == "/log":
                cols = rr.TextLog.columns(text=[p[0] for p in payloads],
                                          level=[p[1] for p in payloads])
            else:  # points: hits (many per scan) or path poses (one per scan)
                lengths = [len(p) for p in payloads]
                cols = rr.Points2D.columns(positions=np.vstack(payloads)).partition(lengths)
            self.rec.send_columns(entity, indexes=indexes, columns=cols)
        self._rows.clear()
        self._pending = 0
        if self._robot is not None:
            pose = self._robot
            heading = 0.5 * np.array([np.cos(pose[2]), np.sin(pose[2])])
            self.rec.log("/world/robot", rr.Arrows2D(origins=[pose[:2]], vectors=[heading],
                                                     colors=[COLORS["estimate"]], radii=[0.04]),
                         static=True)
        if self._matches:
            self.rec.log("/world/matches", rr.Arrows2D(
                origins=[m[0] for m in self._matches],
                vectors=[m[1] - m[0] for m in self._matches],
                colors=[ACCEPTED if m[2] else REJECTED for m in self._matches],
                labels=[m[3] for m in self._matches]), static=True)

    def segment(self, index: int, stamp: float, segment: int, anchor_id: int,
                anchor_pose: np.ndarray) -> None:
        # scans of each segment are an entity of their own: no need to flush here
        self._now = (index, stamp)
        self._at(index, stamp)
        while len(self._segment_anchor) <= segment:
            self._segment_anchor.append(-1)
        self._segment_anchor[segment] = int(anchor_id)
        self.rec.log(f"/world/segments/{segment}", _transform(anchor_pose))

    def scan(self, index: int, stamp: float, pose: np.ndarray, odom: np.ndarray,
             true_pose: np.ndarray | None, segment: int, rel_pose: np.ndarray,
             end_points: np.ndarray, hits: np.ndarray, metrics: dict[str, float]) -> None:
        pts = _place(rel_pose, end_points.astype(np.float64))
        outline = np.vstack([rel_pose[None, :2], pts, rel_pose[None, :2]])
        base = f"/world/segments/{segment}"
        self._add(f"{base}/scans", index, stamp, outline)
        self._add(f"{base}/hits", index, stamp, pts[hits])
        self._add("/world/path/estimate", index, stamp, pose[None, :2])
        self._add("/world/path/odometry", index, stamp, odom[None, :2])
        if true_pose is not None:
            self._add("/world/path/truth", index, stamp, true_pose[None, :2])
        for name, value in metrics.items():
            if np.isfinite(value):
                self._add(f"/metrics/{name}", index, stamp, float(value))
        self._robot = np.asarray(pose, dtype=np.float64).copy()
        self._now = (index, stamp)
        self._pending += 1
        if self._pending >= self.flush_every:
            self.flush()

    def milestone(self, milestone_id: int, pose: np.ndarray) -> None:
        self._at(*self._now)
        self._milestones[int(milestone_id)] = np.asarray(pose, dtype=np.float64).copy()
        self._log_milestones()
        self.event(f"milestone {milestone_id} recorded at ({pose[0]:.2f}, {pose[1]:.2f})")

    def match(self, milestone_id: int, milestone_pose: np.ndarray, robot_pose: np.ndarray,
              accepted: bool, reason: str) -> None:
        if self._matches_at is not self._robot:  # the first match of a new scan
            self._matches = []
            self._matches_at = self._robot
        self._matches.append((np.asarray(robot_pose[:2], dtype=np.float64),
                              np.asarray(milestone_pose[:2], dtype=np.float64), accepted,
                              str(milestone_id) if accepted else reason))

    def anchors_moved(self, ids: np.ndarray, poses: np.ndarray) -> None:
        """The graph moved the milestones: one transform update per affected segment."""
        self.flush()
        self._at(*self._now)
        by_id = {int(i): p for i, p in zip(ids, poses, strict=True)}
        for segment, anchor in enumerate(self._segment_anchor):
            if anchor in by_id:
                self.rec.log(f"/world/segments/{segment}", _transform(by_id[anchor]))
        self._milestones.update({i: np.asarray(p) for i, p in by_id.items()})
        self._log_milestones()
        self.event(f"milestone graph adjusted: {len(by_id)} milestones moved")

    def saved_milestones(self, ids: np.ndarray, poses: np.ndarray) -> None:
        self._milestones = {int(i): np.asarray(p, dtype=np.float64)
                            for i, p in zip(ids, poses, strict=True)}
        self._log_milestones()

    def localization(self, index: int, stamp: float, state: str, pose: np.ndarray | None,
                     hypotheses: np.ndarray, true_pose: np.ndarray | None) -> None:
        """A scan localized in a saved map: the pose when localized, every place followed
        (``/world/hypotheses``) and the state's changes in the log."""
        self._now = (index, stamp)
        if state != self._state:
            self._state = state
            self.event(f"scan {index}: {state}", "INFO" if state == "localized" else "WARN")
        if pose is not None:
            self._add("/world/path/estimate", index, stamp, pose[None, :2])
            self._robot = np.asarray(pose, dtype=np.float64).copy()
        if true_pose is not None:
            self._add("/world/path/truth", index, stamp, true_pose[None, :2])
        self._add("/world/hypotheses", index, stamp, np.asarray(hypotheses)[:, :2])
        self._pending += 1
        if self._pending >= self.flush_every:
            self.flush()

    def event(self, text: str, level: str = "INFO") -> None:
        index, stamp = self._now
        self._add("/log", index, stamp, (text, level))

    def grid(self, cells: np.ndarray, resolution: float, origin: tuple[float, float]) -> None:
        """The occupancy grid, row 0 at the bottom, placed by its resolution and origin."""
        self.flush()
        self._at(*self._now)
        self.rec.log("/world/grid", rr.Transform3D(translation=[origin[0], origin[1], 0.0],
                                                   scale=[resolution, resolution, 1.0]),
                     rr.Image(np.ascontiguousarray(cells), draw_order=-10.0))
        h, w = cells.shape
        self.rec.send_blueprint(default_blueprint(
            (origin[0], origin[1], origin[0] + w * resolution, origin[1] + h * resolution)))

    def hold(self) -> None:
        """Keep serving the recording (``serve``) until Ctrl-C."""
        self.flush()
        self.rec.flush()
        print("rerun: still serving; press Ctrl-C to stop", flush=True)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass

    def close(self) -> None:
        self.flush()
        self.rec.flush()
        self.rec.disconnect()

    def _log_milestones(self) -> None:
        ids = sorted(self._milestones)
        pos = np.array([self._milestones[i][:2] for i in ids]).reshape(-1, 2)
        self.rec.log("/world/milestones", rr.Points2D(pos, labels=[str(i) for i in ids],
                                                      radii=[0.08], colors=[(230, 140, 20)]))


def open_rerun(target: str, app_id: str = "vmp-slam") -> tuple[RerunView, str]:
    """A view writing to ``target``: a ``.rrd`` path, ``spawn`` or ``serve``.

    Returns the view and a line telling the user where to look.
    """
    rec = rr.RecordingStream(app_id, recording_id=str(uuid.uuid4()))
    bp = default_blueprint()
    if target == "spawn":
        rec.spawn(default_blueprint=bp)
        where = "opened the Rerun viewer"
    elif target == "serve":
        url = rec.serve_grpc(default_blueprint=bp)
        rr.serve_web_viewer(open_browser=False, connect_to=url)
        where = f"web viewer on http://localhost:9090/?url={url}"
    else:
        path = Path(target)
        if path.suffix != ".rrd":
            raise ValueError(f"--rerun expects a .rrd file, 'spawn' or 'serve', got {target!r}")
        made = not path.parent.exists()
        path.parent.mkdir(parents=True, exist_ok=True)
        rec.save(path, default_blueprint=bp)
        where = f"recording in {path}" + (f" (made the folder {path.parent})" if made else "")
    return RerunView(rec), where
