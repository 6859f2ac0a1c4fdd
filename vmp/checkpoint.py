"""Checkpoints of a mapping run: where it was in its source and its whole state, in one file.

A checkpoint (``checkpoint.npz`` in the run's results folder, written atomically) holds the
pipeline (every object of it, through :mod:`vmp.state`), the trajectories recorded so far,
how many frames of the source were used, and a fingerprint of the last one. Resuming reads
the same source again, skips that many frames (checking the fingerprint: the same source),
and steps the pipeline on from there: the result is the one an uninterrupted run gives.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tokenize
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vmp.errors import InputError
from vmp.fileio import atomic_write, not_regular
from vmp.state import StateError, decode, encode
from vmp.types import ScanFrame

__all__ = ["CHECKPOINT", "Every", "fingerprint", "load_checkpoint", "remove_checkpoint",
           "save_checkpoint"]

CHECKPOINT = "checkpoint.npz"
FORMAT = "vmp-slam checkpoint"
# The state's layout: raised whenever the mapper's objects gain or lose attributes, so that a
# checkpoint of another layout is refused in one line (2: the odometry delay, the overruled
# count, the graph's marginals solved when asked; 3: a registration reference's line table;
# 4: the back end's record edges, looked up for the drift along the path; 5: the pose of the
# last matched scan, and the loop search's look-up of a submap's segments; 6: the graph's
# marginals keep the information's upper triangle; 7: a registration reference holds no k-d
# tree).
VERSION = 8


@dataclass(frozen=True)
class Every:
    """How often a run writes a checkpoint: every ``scans`` scans or ``seconds`` seconds."""

    scans: int | None = None
    seconds: float | None = None

    @classmethod
    def parse(cls, text: str) -> Every | None:
        """``'60s'`` (seconds), ``'500'`` (scans) or ``'off'`` (None)."""
        text = text.strip().lower()
        if text == "off":
            return None
        m = re.fullmatch(r"(\d+(?:\.\d*)?)\s*s", text)
        if m and float(m.group(1)) > 0:
            return cls(seconds=float(m.group(1)))
        if text.isdigit() and int(text) > 0:
            return cls(scans=int(text))
        raise InputError(f"--checkpoint-every: expected seconds ('60s'), a number of scans "
                         f"('500') or 'off', got {text!r}")

    def due(self, scans_since: int, seconds_since: float) -> bool:
        if self.scans is not None:
            return scans_since >= self.scans
        return self.seconds is not None and seconds_since >= self.seconds


def fingerprint(frame: ScanFrame) -> str:
    """A short hash of a frame's stamp, ranges and odometry: the same frame of the same
    source."""
    h = hashlib.sha1(np.float64(frame.stamp).tobytes(), usedforsecurity=False)
    h.update(np.ascontiguousarray(frame.ranges, dtype=np.float64).tobytes())
    if frame.odom is not None:
        h.update(np.ascontiguousarray(frame.odom, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def save_checkpoint(path: Path, state: dict[str, Any], frames: int, last: str,
                    label: str, keep: dict[str, object]) -> None:
    """Write ``state`` (the run's objects) after ``frames`` frames, the last with fingerprint
    ``last``; ``keep`` names objects written by name only (the view)."""
    tree, arrays = encode(state, keep)
    header = {"format": FORMAT, "version": VERSION, "frames": frames, "last": last,
              "label": label, "state": tree}
    with atomic_write(path, "wb") as f:
        np.savez(f, header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8),
                 **arrays)


def load_checkpoint(path: Path, keep: dict[str, object]) -> tuple[dict[str, Any], int, str,
                                                                  str]:
    """``(state, frames, last fingerprint, label)`` of a checkpoint; a damaged or foreign
    file raises :class:`InputError`."""
    if path.exists() and not path.is_file():  # a FIFO would block the read, a device not end
        raise InputError(f"{path}: {not_regular(path)}, not a checkpoint")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        header = json.loads(arrays.pop("header").tobytes().decode())
        if not isinstance(header, dict) or header.get("format") != FORMAT:
            raise InputError(f"{path}: not a vmp-slam checkpoint")
        if header.get("version") != VERSION:
            raise InputError(f"{path}: checkpoint version {header.get('version')}, this "
                             f"program reads version {VERSION}")
        state = decode(header["state"], arrays, keep)
        return state, int(header["frames"]), str(header["last"]), str(header["label"])
    except FileNotFoundError:
        raise InputError(f"{path}: no checkpoint (the run wrote none: it was shorter than "
                         "--checkpoint-every, or it finished)") from None
    except InputError:
        raise
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile,
            zlib.error, UnicodeDecodeError, StateError, SyntaxError,
            tokenize.TokenError) as exc:  # the last two: a member's damaged .npy header
        raise InputError(f"{path}: a damaged checkpoint ({exc})") from exc


def remove_checkpoint(folder: Path) -> None:
    """Remove a finished run's checkpoint."""
    try:
        os.unlink(folder / CHECKPOINT)
    except FileNotFoundError:
        pass
