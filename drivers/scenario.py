"""Simulated worlds: read ``scenarios/*.yaml`` into walls, a trajectory, sensor and odometry models.

A scenario file is data. Its keys (all lengths in metres, angles in degrees, converted to radians
here, once):

``name``, ``description``, ``seed``
``walls``: a list of shapes, each one of ``polygon: [[x, y], ...]`` (closed ring),
    ``polyline: [[x, y], ...]`` (open chain) or ``box: {center: [x, y], size: [w, h],
    angle_deg: 0}``, optionally with ``repeat: {count: n, step: [dx, dy]}`` to lay out
    copies (rows of shelves, desks).
``trajectory``: ``waypoints: [[x, y] or [x, y, speed], ...]`` driven in order, turning on the
    spot at each corner; ``closed`` (drive back to the first waypoint), ``laps``, ``speed``
    (m/s, default for legs without their own), ``turn_rate_deg`` (deg/s),
    ``start_heading_deg`` (default: towards the second waypoint).
``sensor`` (default: SICK LMS 200): ``beams`` 181, ``angle_min_deg`` -90,
    ``angle_increment_deg`` 1, ``max_range`` 8, ``range_noise`` 0.01 (sigma, m),
    ``rate_hz`` 10, ``dropout`` 0 (probability that a beam returns nothing).
``odometry``: random errors as the standard deviation accumulated over one metre driven or one
    radian turned (they grow with the square root of the distance): ``trans_noise`` (m),
    ``rot_noise_per_m_deg`` (deg), ``rot_noise_per_rad`` (rad); and systematic errors:
    ``trans_scale_bias`` (0.01 = distances read 1 % long), ``rot_scale_bias`` (same for
    turns), ``drift_deg_per_m`` (heading creep per metre, as from unequal wheels).
``obstacles`` (optional): people walking, ``- {path: [[x, y], ...], speed: 0.8, radius: 0.2,
    closed: false}``; an open path is walked back and forth.
``stations`` (optional): ``home: [x, y, theta_deg]`` and ``nearby: [[x, y, theta_deg], ...]``,
    the poses of the paper's experiment (section V).

Any mistake raises :class:`ScenarioError` naming the file, the key and what was expected.
"""

from __future__ import annotations

import importlib.resources
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vmp.errors import InputError
from vmp.fileio import parse_yaml
from vmp.types import MAX_BEAMS, BeamGeometry, FloatArray

__all__ = [
    "MovingObstacle",
    "OdometryModel",
    "Scenario",
    "ScenarioError",
    "SensorModel",
    "Stations",
    "Trajectory",
    "builtin_scenarios",
    "load_scenario",
]


class ScenarioError(InputError):
    """A scenario file that cannot be used; the message names the file and the key."""


# What one scenario may ask of a run (more is refused up front with the figure rather than
# exhausting memory or running for days): scans, beams per scan, stored beams, wall segments.
MAX_SCANS = 1_000_000
MAX_STORED_BEAMS = 200_000_000  # end points the map would hold: 1.6 GB of float32 pairs
MAX_WALL_SEGMENTS = 100_000


SICK_LMS200 = BeamGeometry(181, -math.pi / 2, math.radians(1.0), 8.0)  # 1 degree, 8 m mode


@dataclass(frozen=True)
class SensorModel:
    """A 2D laser range finder: its beams (a SICK LMS 200 by default), range noise, scan rate."""

    geometry: BeamGeometry = field(default_factory=lambda: SICK_LMS200)
    range_noise: float = 0.01
    rate_hz: float = 10.0
    dropout: float = 0.0

    @property
    def angles(self) -> FloatArray:
        return self.geometry.angles


@dataclass(frozen=True)
class OdometryModel:
    """Odometry errors: random (sqrt-distance growth) and systematic (bias)."""

    trans_noise: float = 0.02
    rot_noise_per_m: float = math.radians(0.5)
    rot_noise_per_rad: float = 0.02
    trans_scale_bias: float = 0.0
    rot_scale_bias: float = 0.0
    drift_per_m: float = 0.0


@dataclass(frozen=True)
class Trajectory:
    """Waypoints driven in order at ``speeds[i]`` on the leg that starts at waypoint i."""

    waypoints: FloatArray
    speeds: FloatArray
    closed: bool = False
    laps: int = 1
    turn_rate: float = math.radians(45.0)
    start_heading: float | None = None


@dataclass(frozen=True)
class MovingObstacle:
    """A person (a disc) walking a path at constant speed; an open path is walked back and forth."""

    path: FloatArray
    speed: float
    radius: float
    closed: bool = False


@dataclass(frozen=True)
class Stations:
    """The home pose and the nearby poses of the paper's experiment (section V)."""

    home: FloatArray
    nearby: FloatArray


@dataclass(frozen=True)
class Scenario:
    name: str
    source: str
    walls: FloatArray  # (S, 4): x0 y0 x1 y1
    trajectory: Trajectory
    sensor: SensorModel = field(default_factory=SensorModel)
    odometry: OdometryModel = field(default_factory=OdometryModel)
    seed: int = 0
    description: str = ""
    obstacles: tuple[MovingObstacle, ...] = ()
    stations: Stations | None = None


# --------------------------------------------------------------------------------------------
# Reading with errors that say where and what


class _Node:
    """A value in the YAML document with its key path, for error messages."""

    def __init__(self, source: str, path: str, value: Any) -> None:
        self.source, self.path, self.value = source, path, value

    def fail(self, expected: str) -> ScenarioError:
        got = repr(self.value)
        if len(got) > 60:
            got = got[:57] + "..."
        return ScenarioError(
            f"{self.source}: {self.path or 'top level'}: expected {expected}, got {got}"
        )

    def child(self, key: str | int, value: Any) -> _Node:
        path = f"{self.path}[{key}]" if isinstance(key, int) else (
            f"{self.path}.{key}" if self.path else key
        )
        return _Node(self.source, path, value)

    def mapping(self, allowed: set[str], required: set[str] = frozenset()) -> dict[str, _Node]:
        if not isinstance(self.value, dict):
            raise self.fail("a mapping of keys")
        out = {}
        for k, v in self.value.items():
            if k not in allowed:
                where = f"{self.source}: {self.path + '.' if self.path else ''}{k}"
                raise ScenarioError(
                    f"{where}: unknown key; expected one of {', '.join(sorted(allowed))}"
                )
            out[k] = self.child(k, v)
        for k in sorted(required):
            if k not in out:
                where = f"{self.source}: {self.path + '.' if self.path else ''}{k}"
                raise ScenarioError(f"{where}: missing (required)")
        return out

    def seq(self, min_len: int = 0) -> list[_Node]:
        if not isinstance(self.value, list) or len(self.value) < min_len:
            raise self.fail(f"a list of at least {min_len} items" if min_len else "a list")
        return [self.child(i, v) for i, v in enumerate(self.value)]

    def number(self, *, positive: bool = False, nonneg: bool = False,
               at_most: float | None = None) -> float:
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise self.fail("a finite number")
        if positive and v <= 0:
            raise self.fail("a positive number")
        if nonneg and v < 0:
            raise self.fail("a number >= 0")
        if at_most is not None and v > at_most:
            raise self.fail(f"a number <= {at_most}")
        return float(v)

    def integer(self, *, minimum: int = 0) -> int:
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
            raise self.fail(f"an integer >= {minimum}")
        return int(v)

    def boolean(self) -> bool:
        if not isinstance(self.value, bool):
            raise self.fail("true or false")
        return self.value

    def text(self) -> str:
        if not isinstance(self.value, str):
            raise self.fail("a string")
        return self.value

    def vector(self, lengths: tuple[int, ...] = (2,)) -> list[float]:
        if not isinstance(self.value, list) or len(self.value) not in lengths:
            n = " or ".join(str(k) for k in lengths)
            raise self.fail(f"a list of {n} numbers")
        return [self.child(i, v).number() for i, v in enumerate(self.value)]

    def points(self, min_len: int, lengths: tuple[int, ...] = (2,)) -> list[list[float]]:
        items = self.seq()
        if len(items) < min_len:
            raise self.fail(f"a list of at least {min_len} points [x, y]")
        return [p.vector(lengths) for p in items]


def _box_corners(node: _Node) -> FloatArray:
    keys = node.mapping({"center", "size", "angle_deg"}, {"center", "size"})
    cx, cy = keys["center"].vector()
    size = keys["size"]
    w, h = size.vector()
    if w <= 0 or h <= 0:
        raise size.fail("a positive width and height")
    a = math.radians(keys["angle_deg"].number()) if "angle_deg" in keys else 0.0
    local = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2.0
    c, s = math.cos(a), math.sin(a)
    return local @ np.array([[c, s], [-s, c]]) + [cx, cy]


def _ring_segments(pts: FloatArray, closed: bool) -> FloatArray:
    ends = np.roll(pts, -1, axis=0) if closed else pts[1:]
    starts = pts if closed else pts[:-1]
    return np.hstack([starts, ends])


def _read_walls(node: _Node) -> FloatArray:
    segments = []
    total = 0
    for item in node.seq(min_len=1):
        keys = item.mapping({"polygon", "polyline", "box", "repeat"})
        shapes = [k for k in ("polygon", "polyline", "box") if k in keys]
        if len(shapes) != 1:
            raise item.fail("exactly one of polygon, polyline or box")
        kind = shapes[0]
        if kind == "box":
            segs = _ring_segments(_box_corners(keys["box"]), closed=True)
        else:
            pts = np.array(keys[kind].points(3 if kind == "polygon" else 2))
            segs = _ring_segments(pts, closed=(kind == "polygon"))
        lengths = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
        if (lengths <= 0).any():
            raise keys[kind].fail("consecutive points that differ")
        if "repeat" in keys:
            rep = keys["repeat"].mapping({"count", "step"}, {"count", "step"})
            count = rep["count"].integer(minimum=1)
            if count * len(segs) > MAX_WALL_SEGMENTS:
                raise rep["count"].fail(f"at most {MAX_WALL_SEGMENTS // len(segs):,} copies "
                                        f"(a scenario holds at most {MAX_WALL_SEGMENTS:,} "
                                        "wall segments)")
            dx, dy = rep["step"].vector()
            offsets = np.arange(count)[:, None] * np.array([dx, dy, dx, dy])
            segs = (segs[None, :, :] + offsets[:, None, :]).reshape(-1, 4)
        total += len(segs)
        if total > MAX_WALL_SEGMENTS:
            raise node.fail(f"at most {MAX_WALL_SEGMENTS:,} wall segments in all")
        segments.append(segs)
    return np.vstack(segments)


def _read_trajectory(node: _Node) -> Trajectory:
    keys = node.mapping(
        {"waypoints", "closed", "laps", "speed", "turn_rate_deg", "start_heading_deg"},
        {"waypoints"},
    )
    speed = keys["speed"].number(positive=True) if "speed" in keys else 0.5
    raw = keys["waypoints"].points(2, lengths=(2, 3))
    wp = np.array([p[:2] for p in raw])
    speeds = np.array([p[2] if len(p) == 3 else speed for p in raw])
    for i, p in enumerate(raw):
        if len(p) == 3 and p[2] <= 0:
            raise keys["waypoints"].child(i, p).fail("a positive speed as third value")
    closed = keys["closed"].boolean() if "closed" in keys else False
    legs = np.vstack([wp, wp[:1]]) if closed else wp
    if (np.hypot(*np.diff(legs, axis=0).T) <= 0).any():
        raise keys["waypoints"].fail("consecutive waypoints that differ")
    laps = keys["laps"].integer(minimum=1) if "laps" in keys else 1
    if laps > 1 and not closed:
        raise keys["laps"].fail("laps only on a closed trajectory (closed: true)")
    if laps * len(wp) > MAX_SCANS:
        raise keys["laps"].fail(f"at most {MAX_SCANS // len(wp):,} laps of these waypoints")
    turn = (math.radians(keys["turn_rate_deg"].number(positive=True))
            if "turn_rate_deg" in keys else math.radians(45.0))
    heading = (math.radians(keys["start_heading_deg"].number())
               if "start_heading_deg" in keys else None)
    return Trajectory(wp, speeds, closed, laps, turn, heading)


def _read_sensor(node: _Node) -> SensorModel:
    keys = node.mapping({"beams", "angle_min_deg", "angle_increment_deg", "max_range",
                         "range_noise", "rate_hz", "dropout"})
    d = SensorModel()
    g = d.geometry
    beams = keys["beams"].integer(minimum=2) if "beams" in keys else g.num_beams
    if beams > MAX_BEAMS:
        raise keys["beams"].fail(f"an integer <= {MAX_BEAMS:,}")
    amin = (math.radians(keys["angle_min_deg"].number()) if "angle_min_deg" in keys
            else g.angle_min)
    inc = (math.radians(keys["angle_increment_deg"].number(positive=True))
           if "angle_increment_deg" in keys else g.angle_increment)
    if inc * (beams - 1) > 2 * math.pi + 1e-9:
        raise node.fail("beams * angle_increment_deg covering at most 360 degrees")
    max_range = (keys["max_range"].number(positive=True) if "max_range" in keys
                 else g.max_range)
    return SensorModel(
        BeamGeometry(beams, amin, inc, max_range),
        range_noise=(keys["range_noise"].number(nonneg=True) if "range_noise" in keys
                     else d.range_noise),
        rate_hz=keys["rate_hz"].number(positive=True) if "rate_hz" in keys else d.rate_hz,
        dropout=(keys["dropout"].number(nonneg=True, at_most=1.0) if "dropout" in keys
                 else d.dropout),
    )


def _read_odometry(node: _Node) -> OdometryModel:
    keys = node.mapping({"trans_noise", "rot_noise_per_m_deg", "rot_noise_per_rad",
                         "trans_scale_bias", "rot_scale_bias", "drift_deg_per_m"})
    d = OdometryModel()

    def get(key: str, default: float, *, deg: bool = False, nonneg: bool = False) -> float:
        if key not in keys:
            return default
        v = keys[key].number(nonneg=nonneg)
        return math.radians(v) if deg else v

    return OdometryModel(
        trans_noise=get("trans_noise", d.trans_noise, nonneg=True),
        rot_noise_per_m=get("rot_noise_per_m_deg", d.rot_noise_per_m, deg=True, nonneg=True),
        rot_noise_per_rad=get("rot_noise_per_rad", d.rot_noise_per_rad, nonneg=True),
        trans_scale_bias=get("trans_scale_bias", d.trans_scale_bias),
        rot_scale_bias=get("rot_scale_bias", d.rot_scale_bias),
        drift_per_m=get("drift_deg_per_m", d.drift_per_m, deg=True),
    )


def _read_obstacles(node: _Node) -> tuple[MovingObstacle, ...]:
    out = []
    for item in node.seq():
        keys = item.mapping({"path", "speed", "radius", "closed"}, {"path"})
        out.append(MovingObstacle(
            path=np.array(keys["path"].points(1)),
            speed=keys["speed"].number(nonneg=True) if "speed" in keys else 0.8,
            radius=keys["radius"].number(positive=True) if "radius" in keys else 0.2,
            closed=keys["closed"].boolean() if "closed" in keys else False,
        ))
    return tuple(out)


def _read_stations(node: _Node) -> Stations:
    keys = node.mapping({"home", "nearby"}, {"home", "nearby"})

    def pose(v: list[float]) -> list[float]:
        return [v[0], v[1], math.radians(v[2])]

    home = np.array(pose(keys["home"].vector((3,))))
    nearby = np.array([pose(p.vector((3,))) for p in keys["nearby"].seq(min_len=1)])
    return Stations(home, nearby)


def expected_scans(traj: Trajectory, rate_hz: float) -> float:
    """How many scans driving ``traj`` takes at ``rate_hz`` (at most a few more than the
    simulator makes: each turn is counted as a half turn)."""
    wp = traj.waypoints
    legs = np.vstack([wp, wp[:1]]) if traj.closed else wp
    lengths = np.hypot(*np.diff(legs, axis=0).T)
    speeds = traj.speeds if traj.closed else traj.speeds[:-1]
    lap = float(np.sum(lengths / speeds)) + len(lengths) * math.pi / traj.turn_rate
    return lap * traj.laps * rate_hz + 1


def _check_budget(scn: Scenario, root: _Node) -> None:
    """Refuse a scenario whose run would be unbounded in scans or memory, with the figure."""
    scans = expected_scans(scn.trajectory, scn.sensor.rate_hz)
    beams = scn.sensor.geometry.num_beams
    if not scans <= MAX_SCANS:
        raise ScenarioError(
            f"{root.source}: trajectory: expected a drive of at most {MAX_SCANS:,} scans; its "
            f"waypoints, speeds and laps at {scn.sensor.rate_hz:g} Hz make {scans:,.0f}")
    if scans * beams > MAX_STORED_BEAMS:
        raise ScenarioError(
            f"{root.source}: sensor: expected at most {MAX_STORED_BEAMS:,} beams over the run; "
            f"{scans:,.0f} scans of {beams:,} beams make {scans * beams:,.0f}")


def parse_scenario(doc: Any, source: str) -> Scenario:
    """Build a :class:`Scenario` from a parsed YAML document; ``source`` names it in errors."""
    root = _Node(source, "", doc)
    keys = root.mapping(
        {"name", "description", "seed", "walls", "trajectory", "sensor", "odometry",
         "obstacles", "stations"},
        {"walls", "trajectory"},
    )
    scn = Scenario(
        name=keys["name"].text() if "name" in keys else Path(source).stem,
        source=source,
        walls=_read_walls(keys["walls"]),
        trajectory=_read_trajectory(keys["trajectory"]),
        sensor=_read_sensor(keys["sensor"]) if "sensor" in keys else SensorModel(),
        odometry=_read_odometry(keys["odometry"]) if "odometry" in keys else OdometryModel(),
        seed=keys["seed"].integer() if "seed" in keys else 0,
        description=keys["description"].text() if "description" in keys else "",
        obstacles=_read_obstacles(keys["obstacles"]) if "obstacles" in keys else (),
        stations=_read_stations(keys["stations"]) if "stations" in keys else None,
    )
    _check_budget(scn, root)
    return scn


def builtin_scenarios() -> dict[str, str]:
    """Names of the built-in scenarios with the first line of their description."""
    out = {}
    for entry in sorted(importlib.resources.files("scenarios").iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".yaml"):
            doc = yaml.safe_load(entry.read_text(encoding="utf-8")) or {}
            desc = str(doc.get("description", "")).strip().splitlines()
            out[entry.name[:-5]] = desc[0] if desc else ""
    return out


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a built-in scenario by name (``office``) or any scenario file by path."""
    text_path = str(name_or_path)
    builtin = importlib.resources.files("scenarios").joinpath(f"{text_path}.yaml")
    if "/" not in text_path and not text_path.endswith((".yaml", ".yml")) and builtin.is_file():
        source = f"scenarios/{text_path}.yaml"
        text = builtin.read_text(encoding="utf-8")
    else:
        path = Path(name_or_path)
        if not path.is_file():
            names = ", ".join(builtin_scenarios())
            raise ScenarioError(
                f"{text_path}: no such scenario file, and not a built-in scenario ({names})"
            )
        source = str(path)
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ScenarioError(f"{source}: cannot read: {exc}") from exc
    try:
        doc = parse_yaml(text, source)
    except InputError as exc:
        raise ScenarioError(str(exc)) from exc
    return parse_scenario(doc, source)
