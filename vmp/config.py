"""The mapping configuration as a YAML file: written with every result, read with --config.

Units are SI throughout, angles in radians. Unknown keys and wrong types are errors that name
the file and the key.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import yaml

from vmp.errors import InputError
from vmp.fileio import atomic_write
from vmp.pipeline import PipelineConfig

__all__ = ["config_from_dict", "config_to_dict", "load_config", "save_config"]


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


def config_from_dict(doc: Any, source: str, cls: type = PipelineConfig,
                     path: str = "") -> Any:
    """Build ``cls`` from a mapping, starting from its defaults; errors name source and key."""
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise InputError(f"{source}: {path or 'top level'}: expected a mapping of keys")
    defaults = cls()
    fields = {f.name: f for f in dataclasses.fields(cls)}
    changes = {}
    for key, value in doc.items():
        where = f"{path}.{key}" if path else str(key)
        if key not in fields:
            raise InputError(f"{source}: {where}: unknown key; expected one of "
                             f"{', '.join(sorted(fields))}")
        current = getattr(defaults, key)
        if dataclasses.is_dataclass(current):
            changes[key] = config_from_dict(value, source, type(current), where)
        elif isinstance(current, bool):
            if not isinstance(value, bool):
                raise InputError(f"{source}: {where}: expected true or false, got {value!r}")
            changes[key] = value
        elif isinstance(current, int | float) and current is not None:
            if isinstance(value, bool) or not isinstance(value, int | float) \
                    or not math.isfinite(value):
                raise InputError(f"{source}: {where}: expected a number, got {value!r}")
            changes[key] = type(current)(value) if isinstance(current, int) and \
                float(value).is_integer() else float(value)
        elif isinstance(current, tuple):
            if not isinstance(value, list) or len(value) != len(current):
                raise InputError(f"{source}: {where}: expected a list of {len(current)} "
                                 f"numbers, got {value!r}")
            changes[key] = tuple(float(v) for v in value)
        else:
            changes[key] = value
    try:
        return dataclasses.replace(defaults, **changes)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{source}: {path or 'top level'}: {exc}") from exc


def load_config(path: str | Path) -> PipelineConfig:
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read: {exc}") from exc
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {exc}") from exc
    return config_from_dict(doc, str(path))


def save_config(path: str | Path, config: PipelineConfig) -> None:
    with atomic_write(path, "w") as f:
        f.write("# vmp-slam mapping configuration (SI units, angles in radians)\n")
        yaml.safe_dump(config_to_dict(config), f, sort_keys=False)
