"""File helpers: atomic writes (a crash never leaves half a file) and numeric text tables."""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np
import yaml

from vmp.errors import InputError

# The largest YAML document read (bytes): a configuration or scenario is a few kB, and one of
# the most wall segments a scenario may hold (100,000) about 4 MB.
MAX_YAML = 8 << 20

# The process umask, read once at import (reading it means setting it, which is not thread-safe).
_UMASK = os.umask(0o022)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str], mode: str = "w", **kwargs) -> Iterator[IO]:
    """Open a temporary file beside ``path``; rename it onto ``path`` only if the block succeeds.

    A symlink is written through to the file it names (the link stays); a ``path`` that is a
    device, a FIFO, a socket or a folder is refused with :class:`InputError` before anything
    is written, since the rename would put a regular file in its place."""
    if mode not in ("w", "wb", "wt"):
        raise ValueError(f"atomic_write writes whole files, mode must be 'w' or 'wb', not {mode!r}")
    target = writable_target(path)
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


def writable_target(path: str | os.PathLike[str]) -> Path:
    """The regular file that writing ``path`` replaces: ``path`` itself, or the file a
    symlink at ``path`` leads to (which need not exist yet). :class:`InputError` when that is
    a device, a FIFO, a socket or a folder."""
    given = Path(path)
    target = given.resolve() if given.is_symlink() else given
    try:
        mode = target.stat().st_mode
    except FileNotFoundError:
        return target
    except OSError as exc:
        raise InputError(f"{given}: cannot write: {exc.strerror or exc}") from exc
    if stat.S_ISREG(mode):
        return target
    raise InputError(f"{given}: {_kind(mode)}, not a regular file; refusing to replace it "
                     "(name a file to write)")


def not_regular(path: str | os.PathLike[str]) -> str:
    """What ``path`` (an existing file that is not a regular one) is, in words."""
    return _kind(Path(path).stat().st_mode)


def _kind(mode: int) -> str:
    """What a file of ``mode`` (``st_mode``) is, in words: "a FIFO", "a character device"."""
    kinds = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
             (stat.S_ISSOCK, "a socket"))
    return next((word for test, word in kinds if test(mode)), "not a regular file")


def read_table(path: str | os.PathLike[str], columns: int, layout: str) -> np.ndarray:
    """Rows of ``columns`` finite numbers from a whitespace (or comma) separated text file.

    Blank lines and ``#`` comments are skipped; any other problem raises :class:`InputError`
    naming the file, the line and the expected ``layout`` (e.g. ``'t x y z qx qy qz qw'``).
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        raise InputError(f"{path}: {not_regular(path)}, not a regular file (expected lines "
                         f"'{layout}')")
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


def parse_yaml(text: str, source: str) -> object:
    """The YAML document ``text`` (safe types only); :class:`InputError` naming ``source``
    and, where the parser knows it, the line, for what is not YAML or cannot be held: nesting
    deeper than the parser's stack, an integer of thousands of digits."""
    if len(text) > MAX_YAML:
        raise InputError(f"{source}: {len(text):,} characters; a YAML file this program reads "
                         f"is at most {MAX_YAML >> 20} MB")
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{source}:{mark.line + 1}" if mark is not None else source
        problem = getattr(exc, "problem", None) or str(exc)
        raise InputError(f"{where}: not valid YAML: {problem}") from exc
    except RecursionError as exc:
        raise InputError(f"{source}: not a YAML file this program reads: nested too deep"
                         ) from exc
    except ValueError as exc:  # an integer of more digits than Python converts
        raise InputError(f"{source}: not a YAML file this program reads: a number of "
                         "thousands of digits") from exc


def read_yaml(path: str | os.PathLike[str]) -> object:
    """The YAML document in the regular file ``path`` (:func:`parse_yaml`)."""
    path = Path(path)
    if path.exists() and not path.is_file():
        raise InputError(f"{path}: {not_regular(path)}, not a YAML file")
    try:
        if path.stat().st_size > MAX_YAML:
            raise InputError(f"{path}: {path.stat().st_size:,} bytes; a YAML file this "
                             f"program reads is at most {MAX_YAML >> 20} MB")
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read: {exc}") from exc
    return parse_yaml(text, str(path))
