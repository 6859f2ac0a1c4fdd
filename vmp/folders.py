"""The results folder: a dated name under a root, marked incomplete until every file is
written, and the ``latest`` link beside it. (Light: the commands that only make or check a
folder need nothing of the mapper.)"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
import sys
from pathlib import Path

__all__ = ["INCOMPLETE", "is_incomplete", "link_latest", "mark_complete", "new_results_dir",
           "remove_if_empty"]


INCOMPLETE = "INCOMPLETE"  # in a results folder from its creation until every file is written


def new_results_dir(root: Path, name: str) -> Path:
    """Create ``root/NAME-YYYYmmdd-HHMMSS`` (unique), marked incomplete until
    :func:`mark_complete`; :func:`link_latest` points at it then."""
    root.mkdir(parents=True, exist_ok=True)
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = root / f"{name}-{stamp}"
    k = 1
    while path.exists():
        k += 1
        path = root / f"{name}-{stamp}-{k}"
    path.mkdir()
    (path / INCOMPLETE).write_text(
        f"This results folder is being written (process {os.getpid()}, since "
        f"{dt.datetime.now().isoformat(timespec='seconds')}). If it is still here, the run "
        "stopped before every file was written.\n")
    return path


def mark_complete(folder: Path) -> None:
    """Mark a results folder whose every file is written as complete."""
    (folder / INCOMPLETE).unlink(missing_ok=True)


def is_incomplete(folder: Path) -> bool:
    """Whether a results folder was left before all its files were written."""
    return (folder / INCOMPLETE).exists()


def remove_if_empty(folder: Path) -> None:
    """Remove a results folder that holds nothing but its incomplete mark."""
    if folder.is_dir() and all(p.name == INCOMPLETE for p in folder.iterdir()):
        mark_complete(folder)
        folder.rmdir()


def link_latest(folder: Path, name: str = "latest") -> None:
    """Point the link ``name`` beside ``folder`` at it (once everything in it is written)."""
    root = folder.parent
    link = root / name
    tmp = root / f".{name}.{os.getpid()}"
    if link.exists() and not link.is_symlink():
        # A folder or file of the user's under that name is not replaced by the link.
        print(f"vmp: {link} is not a link this program made; left as it is (the results are "
              f"in {folder})", file=sys.stderr)
        return
    try:
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(folder.name)
        os.replace(tmp, link)
    except OSError:  # a file system without links: the dated folder still holds everything
        with contextlib.suppress(OSError):
            tmp.unlink()
