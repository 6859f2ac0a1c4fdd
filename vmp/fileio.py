"""File helpers: atomic writes (a crash never leaves half a file) and numeric text tables."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np

from vmp.errors import InputError

# The process umask, read once at import (reading it means setting it, which is not thread-safe).
_UMASK = os.umask(0o022)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str], mode: str = "w", **kwargs) -> Iterator[IO]:
    """Open a temporary file beside ``path``; rename it onto ``path`` only if the block succeeds."""
    if mode not in ("w", "wb", "wt"):
        raise ValueError(f"atomic_write writes whole files, mode must be 'w' or 'wb', not {mode!r}")
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, mode, **kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
            # mkstemp makes the file private (0600); give it the mode a plain open() would.
            os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, target)
    except OSError as exc:  # say which file could not be written, not the temporary one
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if exc.filename in (tmp, None):
            raise OSError(exc.errno, exc.strerror or str(exc), str(target)) from exc
        raise
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def read_table(path: str | os.PathLike[str], columns: int, layout: str) -> np.ndarray:
    """Rows of ``columns`` finite numbers from a whitespace (or comma) separated text file.

    Blank lines and ``#`` comments are skipped; any other problem raises :class:`InputError`
    naming the file, the line and the expected ``layout`` (e.g. ``'t x y z qx qy qz qw'``).
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read: {exc}") from exc
    rows = []
    for no, line in enumerate(lines, start=1):
        parts = line.replace(",", " ").split()
        if not parts or parts[0].startswith("#"):
            continue
        if len(parts) != columns:
            raise InputError(f"{path}:{no}: expected {columns} values '{layout}', "
                             f"got {len(parts)}")
        try:
            values = [float(p) for p in parts]
        except ValueError as exc:
            raise InputError(f"{path}:{no}: not a number: {exc}") from exc
        if not all(np.isfinite(values)):
            raise InputError(f"{path}:{no}: values must be finite")
        rows.append(values)
    if not rows:
        raise InputError(f"{path}: no data (expected lines '{layout}')")
    return np.array(rows)
