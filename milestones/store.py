"""Save and load all milestones of a manager in one ``.npz`` file with a JSON header.

The header (array ``header``: UTF-8 JSON as bytes) holds the format name and version, the
manager's configuration and scan geometry. Every other entry is a plain numeric array, so the
file loads with ``allow_pickle=False``. The round trip is exact.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import tokenize
import zipfile
import zlib
from pathlib import Path

import numpy as np

from milestones.manager import MilestoneManager

__all__ = ["FORMAT", "VERSION", "StoreError", "load_milestones", "save_milestones"]

FORMAT = "vmp-slam milestones"
VERSION = 1

_ARRAYS = {
    # name: (dtype, number of dimensions)
    "ids": (np.int64, 1),
    "poses": (np.float64, 2),
    "stamps": (np.float64, 1),
    "signatures": (np.float32, 2),
    "features": (np.float32, 2),
    "scan_lengths": (np.int64, 1),
    "scans": (np.float32, 1),
}


class StoreError(ValueError):
    """A milestone file that cannot be read: missing, corrupt, foreign or of another version."""


def save_milestones(path: str | os.PathLike[str], manager: MilestoneManager) -> None:
    """Write the manager's milestones to ``path`` atomically (temporary file, then rename)."""
    state = manager.state()
    header = {
        "format": FORMAT,
        "version": VERSION,
        "count": len(manager),
        "config": state.pop("config"),
        "geometry": state.pop("geometry"),
        "next_id": state.pop("next_id"),
    }
    arrays = {k: np.ascontiguousarray(v, dtype=_ARRAYS[k][0]) for k, v in state.items()}
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8),
                     **arrays)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0o022)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it private; give the usual mode
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def load_milestones(path: str | os.PathLike[str]) -> MilestoneManager:
    """Read a file written by :func:`save_milestones`; any problem raises :class:`StoreError`."""
    path = Path(path)
    if path.exists() and not path.is_file():  # a FIFO would block the read, a device not end
        raise StoreError(f"{path}: not a regular file")
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise StoreError(f"{path}: not a milestone file (a plain .npy array, not .npz)")
        with data:
            contents = {k: data[k] for k in data.files}
    except FileNotFoundError:
        raise StoreError(f"{path}: no such file") from None
    except StoreError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, zlib.error,
            NotImplementedError, RuntimeError,  # RuntimeError: an encrypted member
            SyntaxError, tokenize.TokenError) as exc:  # a member's damaged .npy header
        raise StoreError(f"{path}: not a readable milestone file ({exc})") from exc
    if "header" not in contents:
        raise StoreError(f"{path}: not a milestone file (no header)")
    try:
        header = json.loads(contents.pop("header").tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StoreError(f"{path}: corrupt header ({exc})") from exc
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise StoreError(f"{path}: not a milestone file (format {header.get('format')!r}, "
                         f"expected {FORMAT!r})" if isinstance(header, dict)
                         else f"{path}: corrupt header")
    if header.get("version") != VERSION:
        raise StoreError(f"{path}: milestone file version {header.get('version')}, this "
                         f"program reads version {VERSION}")
    for name, (dtype, ndim) in _ARRAYS.items():
        a = contents.get(name)
        if a is None:
            raise StoreError(f"{path}: corrupt: array {name!r} is missing")
        if a.dtype != dtype or a.ndim != ndim:
            raise StoreError(f"{path}: corrupt: array {name!r} is {a.dtype} with {a.ndim} "
                             f"dimensions, expected {np.dtype(dtype)} with {ndim}")
    n = header.get("count")
    lengths = contents["scan_lengths"]
    if not all(len(contents[k]) == n for k in ("ids", "poses", "stamps", "signatures",
                                                "features", "scan_lengths")) \
            or lengths.sum() != len(contents["scans"]) or (lengths < 0).any():
        raise StoreError(f"{path}: corrupt: array sizes disagree with the header's count {n}")
    for name in ("poses", "stamps", "signatures", "features"):
        if not np.isfinite(contents[name]).all():
            raise StoreError(f"{path}: corrupt: array {name!r} holds a value that is not finite")
    ids = contents["ids"]
    if contents["poses"].shape[1:] != (3,) or (len(ids) and (ids[0] < 0 or np.any(
            np.diff(ids) <= 0))):
        raise StoreError(f"{path}: corrupt: poses are not (x, y, theta) rows or ids are not "
                         "increasing")
    if not isinstance(header.get("config"), dict) or not isinstance(header.get("geometry"),
                                                                     dict | None):
        raise StoreError(f"{path}: corrupt: its configuration or beam geometry is not a "
                         "mapping")
    try:
        state = dict(contents, config=header["config"], geometry=header["geometry"],
                     next_id=header["next_id"])
        return MilestoneManager.from_state(state)
    except (TypeError, ValueError, KeyError) as exc:
        raise StoreError(f"{path}: corrupt: {exc}") from exc
