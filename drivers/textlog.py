"""Line-by-line recording readers: constant memory, bad lines skipped and reported or strict."""

from __future__ import annotations

import gzip
import io
import os
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from vmp.errors import InputError
from vmp.source import Reference, SourceReport
from vmp.types import BeamGeometry, ScanFrame

__all__ = ["LineLog", "open_text"]


def open_text(path: Path) -> IO[str]:
    """A text file, unpacked on the fly when it is gzip or a zip archive (by magic bytes).

    From a zip archive the largest member that is not macOS metadata is read.
    """
    with open(path, "rb") as probe:
        magic = probe.read(4)
    if magic[:2] == b"\x1f\x8b":
        return gzip.open(path, "rt", encoding="ascii", errors="replace")
    if magic == b"PK\x03\x04":
        archive = zipfile.ZipFile(path)
        members = [m for m in archive.infolist()
                   if not m.is_dir() and not m.filename.startswith("__MACOSX")]
        if not members:
            raise InputError(f"{path}: an empty zip archive")
        member = max(members, key=lambda m: m.file_size)
        return io.TextIOWrapper(archive.open(member), encoding="ascii", errors="replace")
    return open(path, encoding="ascii", errors="replace")


class LineLog:
    """A recording with one message per line, read lazily; a :class:`~vmp.source.Source`.

    Subclasses turn lines into frames in :meth:`_frames`, calling :meth:`_bad` for a line
    that cannot be used: it is skipped and recorded in :attr:`problems` with its line number,
    or, with ``strict``, raises :class:`InputError` naming the file and line.
    """

    format_name = "text log"
    item = "line"  # what a problem's number counts (a bag counts messages)
    topics: dict[str, tuple[str, int]] | None = None  # topic -> (type, messages), for bags

    def __init__(self, path: str | os.PathLike[str], *, strict: bool = False) -> None:
        self.path = Path(path)
        self.name = self.path.name.split(".")[0]
        self.strict = strict
        self.problems: list[tuple[int, str]] = []  # (line, what), the first 1,000
        self.skipped = 0
        self.backwards = 0
        self.scans = 0
        self._geometry: BeamGeometry | None = None
        self._closed = False

    @property
    def geometry(self) -> BeamGeometry:
        """The beams of the first scan (read once, on first use)."""
        if self._geometry is None:
            frames = iter(self)
            first = next(frames, None)
            frames.close()
            if first is None:
                raise InputError(f"{self.path}: no laser scans in this {self.format_name}")
            self._geometry = first.geometry
        return self._geometry

    @property
    def length(self) -> int | None:
        return None  # known only by reading the whole file

    def reference(self) -> Reference | None:
        """Poses to compare against: none in a plain log."""
        return None

    def report(self) -> SourceReport:
        return SourceReport(self.item, self.skipped, self.backwards, list(self.problems),
                            {f"bad {self.item}s skipped": self.skipped,
                             "stamps running backwards": self.backwards})

    def notes(self) -> list[tuple[str, str]]:
        """What else there is to say about the recording, as (heading, text) lines."""
        return []

    def close(self) -> None:
        """End an iteration under way after the frame it is at."""
        self._closed = True

    def _bad(self, no: int, what: str, skip: bool = True) -> None:
        if self.strict:
            where = f"{self.path}:{no}" if self.item == "line" else f"{self.path}: {self.item} {no}"
            raise InputError(f"{where}: {what}")
        if skip:
            self.skipped += 1
        else:
            self.backwards += 1
        if len(self.problems) < 1000:
            self.problems.append((no, what))

    def __iter__(self) -> Iterator[ScanFrame]:
        self.problems, self.skipped, self.backwards, self.scans = [], 0, 0, 0
        self._closed = False
        try:
            f = open_text(self.path)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read: {exc.strerror or exc}") from exc
        with f:
            last_stamp = -float("inf")
            for frame in self._frames(enumerate(f, start=1)):
                if frame.stamp < last_stamp:
                    self._bad(self._line, f"stamp {frame.stamp:.6f} runs backwards (latest "
                                          f"before {last_stamp:.6f}); scan kept", skip=False)
                last_stamp = max(last_stamp, frame.stamp)
                self.scans += 1
                yield frame
                if self._closed:
                    return

    def _frames(self, lines: Iterator[tuple[int, str]]) -> Iterator[ScanFrame]:
        raise NotImplementedError
