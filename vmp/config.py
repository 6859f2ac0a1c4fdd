"""The mapping configuration: every setting a run can be given, grouped by the part it tunes.

Written with every result as ``config.yaml`` and read back with ``--config``. Units are SI,
angles in radians. Unknown keys and wrong types are errors that name the file and the key.

Settings a user may need for another robot, sensor or building are fields here; the values
inside one algorithm that nobody should have to touch are named constants in its module.
This module imports only leaves (``milestones``' configuration, the error type, file helpers),
so every part of the mapper can import its section from here.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from milestones.manager import ManagerConfig
from vmp.errors import InputError
from vmp.fileio import atomic_write, read_yaml

__all__ = ["LoopConfig", "MapConfig", "MappingConfig", "MatchingConfig", "MotionNoise",
           "RegistrationConfig", "ScanOdometryConfig", "config_from_dict", "config_to_dict",
           "load_config", "save_config"]


@dataclass(frozen=True)
class MotionNoise:
    """Wheel odometry noise: its variance grows linearly with distance and turn."""

    trans_per_m: float = 0.05  # sigma of translation error accumulated over 1 m (m)
    rot_per_m: float = math.radians(1.0)  # sigma of heading error per metre driven (rad)
    rot_per_rad: float = 0.05  # sigma of heading error per radian turned (rad)


@dataclass(frozen=True)
class RegistrationConfig:
    """Which scan registrations are trusted (by the scan odometry, the matcher, the graph)."""

    max_rms: float = 0.05  # residual RMS above which a fit is poor (m)
    min_inliers: float = 0.5  # share of the live points that must find a partner


@dataclass(frozen=True)
class ScanOdometryConfig:
    """Odometry refined by registering each scan against a recent keyframe."""

    enabled: bool = True  # False: the filter predicts from the wheels alone
    keyframe_distance: float = 0.3  # a new keyframe after this much travel (m) ...
    keyframe_turn: float = math.radians(10.0)  # ... or this much turn (rad)


@dataclass(frozen=True)
class MatchingConfig:
    """Matching live scans against stored milestones, and the verdicts on each match."""

    enabled: bool = True  # False: no milestones at all (odometry and scan matching only)
    candidates: int = 2  # signature candidates registered per scan, besides the anchor
    max_ratio: float = 0.9  # signature score / best rival's above which a match is ambiguous
    # A signature match registered from the milestone's node (the prediction having drifted
    # too far for ICP) needs a clearer place and a closer fit.
    retry_max_ratio: float = 0.7
    retry_min_inliers: float = 0.75


@dataclass(frozen=True)
class LoopConfig:
    """Returns to stored milestones: handovers, loop edges, the graph's adjustment."""

    switch_margin: float = 0.3  # hand over when another milestone is this much nearer (m)
    separation: int = 5  # milestones this many recordings apart may close a loop
    adjust_chi2: float = 1.0  # adjust the graph when a new loop edge disagrees this much


@dataclass(frozen=True)
class MapConfig:
    """What the vector map keeps of each scan."""

    no_return_free_range: float = 10.0  # how far a beam without a return marks free space (m)


@dataclass(frozen=True)
class MappingConfig:
    """Everything that tunes a mapping run (saved with every result)."""

    motion: MotionNoise = field(default_factory=MotionNoise)
    scan_odometry: ScanOdometryConfig = field(default_factory=ScanOdometryConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    milestones: ManagerConfig = field(default_factory=ManagerConfig)
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    loops: LoopConfig = field(default_factory=LoopConfig)
    map: MapConfig = field(default_factory=MapConfig)


# The physical range each number may take, both ends included, and its unit: noise no wheels
# are free of, lengths from a centimetre to a building, angles from a tenth of a degree to a
# turn, shares from a hundredth. A value outside is refused on load, naming the key, the range
# and the unit; every number field has one (tests/test_config.py checks).
LIMITS: dict[str, tuple[float, float, str]] = {
    "motion.trans_per_m": (1e-3, 10.0, "m per m driven"),
    "motion.rot_per_m": (1e-4, math.pi, "rad per m driven"),
    "motion.rot_per_rad": (1e-3, 10.0, "rad per rad turned"),
    "scan_odometry.keyframe_distance": (0.01, 100.0, "m"),
    "scan_odometry.keyframe_turn": (math.radians(0.1), math.pi, "rad"),
    "registration.max_rms": (1e-3, 10.0, "m"),
    "registration.min_inliers": (0.01, 1.0, "share of the points"),
    "milestones.length": (8, 4096, "signature values"),
    "milestones.clamp_range": (0.1, 1000.0, "m"),
    "milestones.keep": (0.01, 1.0, "share of the coefficients"),
    "milestones.record_distance": (0.01, 1000.0, "m"),
    "milestones.record_turn": (math.radians(0.1), 2 * math.pi, "rad"),
    "milestones.max_heading": (math.radians(0.1), math.pi, "rad"),
    "milestones.recognition_radius": (0.01, 1000.0, "m"),
    "matching.candidates": (0, 100, "milestones"),
    "matching.max_ratio": (0.01, 1.0, "score ratio"),
    "matching.retry_max_ratio": (0.01, 1.0, "score ratio"),
    "matching.retry_min_inliers": (0.01, 1.0, "share of the points"),
    "loops.switch_margin": (0.0, 100.0, "m"),
    "loops.separation": (1, 1_000_000, "milestones"),
    "loops.adjust_chi2": (0.0, 1e6, "chi-square"),
    "map.no_return_free_range": (0.0, 1000.0, "m"),
}


def config_to_dict(config: Any) -> dict:
    """Nested plain values of a (nested) configuration dataclass."""
    out = {}
    for f in dataclasses.fields(config):
        v = getattr(config, f.name)
        if dataclasses.is_dataclass(v):
            out[f.name] = config_to_dict(v)
        elif isinstance(v, tuple):
            out[f.name] = [float(x) for x in v]
        else:
            out[f.name] = v.item() if hasattr(v, "item") else v  # NumPy scalars to Python
    return out


def _finite_number(value: Any) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond any float
        return False


def _in_limits(value: float, key: str, where: str) -> None:
    low, high, unit = LIMITS[key]
    if not low <= value <= high:
        raise InputError(f"{where}: expected a number from {low:.4g} to {high:.4g} ({unit}), "
                         f"got {value!r}")


def _number(value: Any) -> Any:
    """``value``, or the number a string such as ``1e-09`` spells (YAML 1.1 reads an exponent
    without a decimal point as a string)."""
    if isinstance(value, str):
        try:
            return float(value) if len(value) <= 40 else value
        except ValueError:
            return value
    return value


def _value(current: Any, value: Any, where: str, key: str) -> Any:
    """``value`` checked against the type of the default ``current`` and the key's range in
    :data:`LIMITS`; raises InputError."""
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise InputError(f"{where}: expected true or false, got {value!r}")
        return value
    if isinstance(current, int | float):
        value = _number(value)
        if not _finite_number(value):
            raise InputError(f"{where}: expected a number, got {value!r}")
        if isinstance(current, int):
            if not float(value).is_integer():
                raise InputError(f"{where}: expected a whole number, got {value!r}")
            value = int(value)
        _in_limits(value, key, where)
        return value if isinstance(current, int) else float(value)
    if isinstance(current, str):
        if not isinstance(value, str):
            raise InputError(f"{where}: expected a word, got {value!r}")
        return value
    return value


def config_from_dict(doc: Any, source: str, cls: type = MappingConfig,
                     path: str = "") -> Any:
    """Build ``cls`` from a mapping, starting from its defaults; errors name source and key."""
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise InputError(f"{source}: {path or 'top level'}: expected a mapping of keys")
    defaults = cls()
    fields = {f.name for f in dataclasses.fields(cls)}
    changes = {}
    for key, value in doc.items():
        where = f"{path}.{key}" if path else str(key)
        if key not in fields:
            raise InputError(f"{source}: {where}: unknown key; expected one of "
                             f"{', '.join(sorted(fields))}")
        current = getattr(defaults, key)
        if dataclasses.is_dataclass(current):
            changes[key] = config_from_dict(value, source, type(current), where)
        else:
            changes[key] = _value(current, value, f"{source}: {where}", where)
    try:
        return dataclasses.replace(defaults, **changes)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{source}: {path or 'top level'}: {exc}") from exc


def load_config(path: str | Path) -> MappingConfig:
    """The configuration in a YAML file (keys left out keep their defaults)."""
    path = Path(path)
    return config_from_dict(read_yaml(path), str(path))


def save_config(path: str | Path, config: MappingConfig) -> None:
    with atomic_write(path, "w") as f:
        f.write("# vmp-slam mapping configuration (SI units, angles in radians)\n")
        yaml.safe_dump(config_to_dict(config), f, sort_keys=False)
