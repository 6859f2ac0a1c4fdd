"""Line-by-line recording readers: constant memory, bad lines skipped and reported or strict."""

from __future__ import annotations

import dataclasses
import gzip
import io
import lzma
import math
import os
import struct
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from vmp.errors import InputError
from vmp.source import Reference, SourceReport
from vmp.types import BeamGeometry, ScanFrame

__all__ = [
    "DAMAGE",
    "MAX_LINE",
    "Jumps",
    "LineLog",
    "LineTooLong",
    "lines_of",
    "open_text",
]

# What reading a damaged gzip or zip container raises (a bad CRC or header, a cut-off stream,
# a corrupt deflate block); gzip.BadGzipFile is an OSError.
DAMAGE = (OSError, EOFError, zlib.error, zipfile.BadZipFile, lzma.LZMAError)
# The longest line read (characters): a scan of the most beams any 2D scanner measures a sweep
# (vmp.types.MAX_BEAMS) written with remissions takes a few hundred kB; a longer line is not
# a record, and reading it whole would hold all of it in memory.
MAX_LINE = 4 << 20


# Values no recording holds: a stamp past the year 2100 (Unix seconds), a robot faster than
# any ground vehicle that maps with a 2D laser (m/s; over at least a second, as stamps written
# on arrival come in bursts), a heading of more turns than a robot makes in its life (rad).
MAX_STAMP = 4.1e9
MAX_SAID = 200  # characters of a bad line's problem kept
MAX_SPEED = 50.0
MAX_GAP = 86400.0  # s: more than one recording pauses between two scans
MAX_HEADING = 1e6


class LineTooLong(ValueError):
    """A line longer than :data:`MAX_LINE`: not a record of any recording."""


def lines_of(f: IO[str]) -> Iterator[str]:
    """The lines of ``f``, each read to :data:`MAX_LINE` characters at most;
    :class:`LineTooLong` at the first longer one (memory stays bounded whatever the file)."""
    read = f.readline
    while line := read(MAX_LINE + 1):
        if len(line) > MAX_LINE:
            raise LineTooLong(f"a line longer than {MAX_LINE >> 20} MB (not a record)")
        yield line


class _FirstMember(io.RawIOBase):
    """The first member of a zip archive whose central directory is lost (a download cut
    off): inflated from its local header on, up to where the data ends."""

    def __init__(self, path: Path) -> None:
        self._file = open(path, "rb")
        head = self._file.read(30)
        if len(head) < 30 or head[:4] != b"PK\x03\x04":
            self._file.close()
            raise InputError(f"{path}: a damaged zip archive (no member header)")
        method, = struct.unpack_from("<H", head, 8)
        name_len, extra_len = struct.unpack_from("<HH", head, 26)
        if method not in (0, 8):
            self._file.close()
            raise InputError(f"{path}: a damaged zip archive (compression {method} of its "
                             "first member is not deflate)")
        self._file.seek(30 + name_len + extra_len)
        self._inflate = zlib.decompressobj(-zlib.MAX_WBITS) if method == 8 else None
        self._pending = b""

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:  # type: ignore[override]
        while not self._pending:
            raw = self._file.read(65536)
            if self._inflate is None:
                self._pending = raw
                break
            if not raw:
                if not self._inflate.eof:
                    raise EOFError("the archive ends inside its first member")
                break
            self._pending = self._inflate.decompress(raw)
            if self._inflate.eof:
                self._file.seek(0, io.SEEK_END)  # what follows the member is not text
        n = min(len(buffer), len(self._pending))
        buffer[:n] = self._pending[:n]
        self._pending = self._pending[n:]
        return n

    def close(self) -> None:
        self._file.close()
        super().close()


def open_text(path: Path) -> IO[str]:
    """A text file, unpacked on the fly when it is gzip or a zip archive (by magic bytes).

    From a zip archive the largest member that is not macOS metadata is read; from one whose
    directory at the end is lost (cut off), the first member as far as it goes.
    """
    return io.TextIOWrapper(open_bytes(path), encoding="ascii", errors="replace")


def open_bytes(path: Path) -> IO[bytes]:
    """The bytes of a file, unpacked on the fly as :func:`open_text` reads them."""
    with open(path, "rb") as probe:
        magic = probe.read(4)
    if magic[:2] == b"\x1f\x8b":
        return gzip.open(path, "rb")
    if magic == b"PK\x03\x04":
        try:
            archive = zipfile.ZipFile(path)
        except zipfile.BadZipFile:
            return io.BufferedReader(_FirstMember(path))
        except (NotImplementedError, ValueError, EOFError, zlib.error) as exc:
            raise InputError(f"{path}: a damaged zip archive ({exc})") from exc
        try:
            members = [m for m in archive.infolist()
                       if not m.is_dir() and not m.filename.startswith("__MACOSX")]
            if not members:
                raise InputError(f"{path}: an empty zip archive")
            member = max(members, key=lambda m: m.file_size)
            return archive.open(member)
        except RuntimeError as exc:  # zipfile's word for an encrypted member
            raise InputError(f"{path}: an encrypted zip archive (unpack it first)") from exc
        except (zipfile.BadZipFile, zlib.error, EOFError, ValueError,
                NotImplementedError) as exc:
            raise InputError(f"{path}: a damaged zip archive ({exc})") from exc
    return open(path, "rb")


def count_lines_starting(path: Path, words: tuple[bytes, ...], chunk: int = 1 << 20) -> int:
    """How many lines of the (unpacked) file start with one of ``words``, read in chunks (the
    memory does not grow with the file or its lines); up to where a container is damaged."""
    n, tail = 0, b"\n"
    keep = max(len(w) for w in words)
    with open_bytes(path) as f:
        try:
            while block := f.read1(chunk):  # what is there: up to a damage, not past it
                text = tail + block
                n += sum(text.count(b"\n" + w) for w in words)
                tail = text[-keep:]  # a line head cut by the chunk's end is counted next time
                n -= sum(tail.count(b"\n" + w) for w in words)
        except DAMAGE:
            pass
    return n + sum(tail.count(b"\n" + w) for w in words)


class LineLog:
    """A recording with one message per line, read lazily; a :class:`~vmp.source.Source`.

    Subclasses turn lines into frames in :meth:`_frames`, calling :meth:`_bad` for a line
    that cannot be used: it is skipped and recorded in :attr:`problems` with its line number,
    or, with ``strict``, raises :class:`InputError` naming the file and line.
    """

    format_name = "text log"
    item = "line"  # what a problem's number counts (a bag counts messages)
    topics: dict[str, tuple[str, int]] | None = None  # topic -> (type, messages), for bags
    scan_words: tuple[bytes, ...] = ()  # what the lines of scans start with (counted: length)

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
        self.damaged = ""  # where and how the file was found damaged (what came before is read)
        self._length: int | None = None

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
        """How many scans the file holds, bad ones included: its lines that start as a scan's
        do, counted once (about 0.07 s for 13,631 scans of a CARMEN .gz); None where nothing
        tells a scan's line or the path is not a regular file."""
        if self._length is None and self.scan_words and self.path.is_file():
            try:
                self._length = count_lines_starting(self.path, self.scan_words)
            except (OSError, InputError):
                return None  # reading the file says what is wrong with it
        return self._length

    def reference(self) -> Reference | None:
        """Poses to compare against: none in a plain log."""
        return None

    def report(self) -> SourceReport:
        counts: dict[str, int | float | str] = {f"bad {self.item}s skipped": self.skipped,
                                                "stamps running backwards": self.backwards}
        if self.damaged:
            counts["damaged"] = self.damaged
        return SourceReport(self.item, self.skipped, self.backwards, list(self.problems),
                            counts, damaged=self.damaged)

    def notes(self) -> list[tuple[str, str]]:
        """What else there is to say about the recording, as (heading, text) lines."""
        return []

    def close(self) -> None:
        """End an iteration under way after the frame it is at."""
        self._closed = True

    def _bad(self, no: int, what: str, skip: bool = True) -> None:
        """Item ``no`` could not be used (``skip``) or is odd but kept (a stamp running
        backwards, a property of some recordings): recorded; with ``strict`` an unusable
        item raises :class:`InputError`."""
        if len(what) > MAX_SAID:  # a decoder's message may quote a whole definition
            what = what[:MAX_SAID] + " ..."
        if self.strict and skip:
            where = f"{self.path}:{no}" if self.item == "line" else f"{self.path}: {self.item} {no}"
            raise InputError(f"{where}: {what}")
        if skip:
            self.skipped += 1
        else:
            self.backwards += 1
        if len(self.problems) < 1000:
            self.problems.append((no, what))

    def _damage(self, where: str, exc: BaseException) -> None:
        """The file is damaged at ``where``: stop there (what came before is kept and the
        damage reported), or with ``strict`` raise :class:`InputError`."""
        what = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        if self.strict:
            raise InputError(f"{self.path}: damaged {where} ({what})") from exc
        self.damaged = f"damaged {where} ({what}); the rest of the file is not read"

    def _lines(self, f: IO[str]) -> Iterator[tuple[int, str]]:
        """Numbered lines of ``f`` up to the end or to where its container is damaged."""
        no = 0
        try:
            for no, line in enumerate(lines_of(f), start=1):
                yield no, line
        except LineTooLong as exc:
            self._damage(f"at line {no + 1}", exc)
        except DAMAGE as exc:
            self._damage(f"after line {no}", exc)

    def __iter__(self) -> Iterator[ScanFrame]:
        self.problems, self.skipped, self.backwards, self.scans = [], 0, 0, 0
        self._closed = False
        self.damaged = ""
        try:
            f = open_text(self.path)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read: {exc.strerror or exc}") from exc
        with f:
            last_stamp = -float("inf")
            jumps = Jumps()
            for frame in self._frames(self._lines(f)):
                frame, problem = jumps.admit(frame)
                if frame is None:
                    self._bad(self._line, f"{problem}; scan skipped")
                    continue
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


def _implausible(frame: ScanFrame) -> str:
    """What no recording holds in ``frame`` ("" when nothing): a stamp beyond
    :data:`MAX_STAMP`, an odometry pose beyond any building or a heading of
    :data:`MAX_HEADING` radians."""
    if not abs(frame.stamp) <= MAX_STAMP:
        return f"stamp {frame.stamp:.6g} s lies past the year 2100"
    odom = frame.odom
    if odom is not None and not (abs(odom[0]) <= MAX_SPEED * MAX_STAMP
                                 and abs(odom[1]) <= MAX_SPEED * MAX_STAMP
                                 and abs(odom[2]) <= MAX_HEADING):
        return f"odometry ({odom[0]:.6g}, {odom[1]:.6g}, {odom[2]:.6g}) is beyond any robot's"
    return ""


class Jumps:
    """Jumps between scans no robot makes: a scan whose stamp lies more than :data:`MAX_GAP`
    from the last scan kept's, or whose odometry lies farther from it than a robot drives at
    :data:`MAX_SPEED`, is a damaged record (skipped) unless it agrees with the scan read
    before it: then the recording paused, or the wheels' count started anew (kept, its
    increment unknown)."""

    def __init__(self) -> None:
        self._kept: ScanFrame | None = None
        self._read: ScanFrame | None = None
        self._anew = False

    def jump(self, frame: ScanFrame) -> str:
        """Why ``frame`` is skipped ("" when it is not)."""
        last, before = self._kept, self._read
        self._read = frame
        self._anew = False
        if last is None:
            return ""
        other = before if before is not None and before is not last else None
        if abs(frame.stamp - last.stamp) > MAX_GAP:
            if other is not None and abs(frame.stamp - other.stamp) <= MAX_GAP:
                self._anew = True  # a pause: the scans go on together from the one before
                return ""
            return (f"stamp {frame.stamp:.6g} s lies {abs(frame.stamp - last.stamp):.3g} s "
                    f"from the scan before (more than {MAX_GAP:g} s)")
        if frame.odom is None or last.odom is None or _reachable(last, frame):
            return ""
        if other is not None and other.odom is not None and _reachable(other, frame):
            self._anew = True  # the odometry started again where the scan before was
            return ""
        dist = math.hypot(*(frame.odom[:2] - last.odom[:2]))
        return (f"odometry jumps {dist:.6g} m in {abs(frame.stamp - last.stamp):.3g} s "
                f"(faster than {MAX_SPEED:g} m/s)")

    def admit(self, frame: ScanFrame) -> tuple[ScanFrame | None, str]:
        """``frame`` as kept (without odometry where the wheels' count started anew), or
        None and why it is skipped: a value no recording holds (:func:`_implausible`) or a
        jump (:meth:`jump`)."""
        problem = _implausible(frame) or self.jump(frame)
        return (None, problem) if problem else (self._checked(frame), "")

    def _checked(self, frame: ScanFrame) -> ScanFrame:
        self._kept = frame
        if self._anew:
            self._anew = False
            return dataclasses.replace(frame, odom=None)
        return frame


def _reachable(a: ScanFrame, b: ScanFrame) -> bool:
    """Whether a robot at :data:`MAX_SPEED` gets from ``a``'s odometry to ``b``'s between their
    stamps (over a second at least)."""
    dist = math.hypot(b.odom[0] - a.odom[0], b.odom[1] - a.odom[1])
    return dist <= MAX_SPEED * max(abs(b.stamp - a.stamp), 1.0)
