"""The Hokuyo SCIP 2.0 protocol: sums, 2/3/4-character values, requests, replies, checks.

See ``../shared/protocols.md`` section 3. Everything is ASCII lines ending with LF. A reply is
the echo of the command line, a status line (two characters and a sum), data lines (at most 64
data characters and a sum each) and an empty line. The sum is the low 6 bits of the byte sum
plus ``0x30``; it misses flips of bits 6 and 7 and some drops, so a scan is only decoded when,
besides every sum, every data character lies in ``0x30..0x6F`` and every line has exactly the
length the request implies (:func:`check_scan`). Pure functions and one parser; no I/O.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "BLOCK",
    "ChecksumError",
    "FramingError",
    "Reply",
    "ReplyParser",
    "ScipError",
    "StatusError",
    "check_data_lines",
    "check_scan",
    "check_status",
    "data_lines",
    "decode",
    "decode_values",
    "encode",
    "encode_values",
    "gd_request",
    "info_line",
    "md_request",
    "parse_info",
    "parse_info_line",
    "reply",
    "scan_reply",
    "scip_sum",
    "status_line",
]

BLOCK = 64  # data characters per line
LOW, HIGH = 0x30, 0x6F  # the characters a value or a sum can use
_WEIGHTS = {w: (64 ** np.arange(w - 1, -1, -1)).astype(np.int64) for w in (1, 2, 3, 4)}


class ScipError(ValueError):
    """A reply that does not check; the subclass says which kind of check failed."""


class ChecksumError(ScipError):
    """A line whose sum character does not match its content."""


class FramingError(ScipError):
    """Broken structure: wrong echo, line count or length, characters outside 0x30..0x6F."""


class StatusError(ScipError):
    """A well-formed reply whose status is not the expected one (the device refused)."""

    def __init__(self, status: bytes, message: str) -> None:
        super().__init__(message)
        self.status = status


# -- sums and values --------------------------------------------------------------------------
def scip_sum(text: bytes) -> bytes:
    """The sum character of a line's content: low 6 bits of the byte sum, plus 0x30."""
    return bytes([(sum(text) & 0x3F) + LOW])


def encode(value: int, width: int) -> bytes:
    """``value`` in ``width`` (2, 3 or 4) characters, most significant 6 bits first."""
    return encode_values(np.array([value]), width)


def encode_values(values: Sequence[int] | np.ndarray, width: int) -> bytes:
    """All ``values`` in ``width`` characters each, concatenated (vectorised)."""
    if width not in (2, 3, 4):
        raise ValueError(f"SCIP values use 2, 3 or 4 characters, not {width}")
    v = np.asarray(values, dtype=np.int64).reshape(-1)
    if v.size and (v.min() < 0 or v.max() >= 64 ** width):
        raise ValueError(f"values must lie in 0..{64 ** width - 1} for {width} characters, "
                         f"got {v.min()}..{v.max()}")
    groups = (v[:, None] // _WEIGHTS[width][None, :]) & 0x3F
    return (groups + LOW).astype(np.uint8).tobytes()


def decode(text: bytes) -> int:
    """The value of one 2, 3 or 4 character group."""
    return int(decode_values(text, len(text))[0])


def decode_values(chars: bytes, width: int) -> np.ndarray:
    """The values of ``chars`` read in groups of ``width`` (vectorised, int64).

    Raises :class:`FramingError` when the length is not a multiple of ``width`` or a character
    lies outside ``0x30..0x6F``.
    """
    a = np.frombuffer(chars, dtype=np.uint8)
    if width not in _WEIGHTS or a.size % width:
        raise FramingError(f"{a.size} characters do not split into values of {width}")
    if a.size and (a.min() < LOW or a.max() > HIGH):
        raise FramingError("character outside 0x30..0x6F in a value")
    return (a.reshape(-1, width).astype(np.int64) - LOW) @ _WEIGHTS[width]


# -- what the device sends (also used by the tests) -----------------------------------------------
def status_line(status: bytes) -> bytes:
    """A status line with its sum and LF, e.g. ``b"00"`` -> ``b"00P\\n"``."""
    return status + scip_sum(status) + b"\n"


def data_lines(chars: bytes) -> bytes:
    """``chars`` cut into lines of 64 with a sum each, every line ending with LF."""
    out = bytearray()
    for i in range(0, len(chars), BLOCK):  # one iteration per line, not per value
        line = chars[i:i + BLOCK]
        out += line + scip_sum(line) + b"\n"
    return bytes(out)


def info_line(key: str, value: str) -> bytes:
    """An information line ``KEY:VALUE;S`` with the sum over ``KEY:VALUE``, and LF."""
    body = f"{key}:{value}".encode("ascii")
    return body + b";" + scip_sum(body) + b"\n"


def reply(echo: bytes, status: bytes, body: bytes = b"") -> bytes:
    """A complete reply: echo line, status line, ``body`` (lines with LF), empty line."""
    return echo + b"\n" + status_line(status) + body + b"\n"


def scan_reply(echo: bytes, status: bytes, time_ms: int, values: Sequence[int] | np.ndarray,
               width: int) -> bytes:
    """A GD/GS (status ``00``) or MD/MS (``99``) scan reply with time stamp and values."""
    stamp = encode(time_ms % (1 << 24), 4)
    return reply(echo, status, stamp + scip_sum(stamp) + b"\n"
                 + data_lines(encode_values(values, width)))


# -- requests ----------------------------------------------------------------------------------
def _tag(tag: str) -> bytes:
    if len(tag) > 16 or not tag.isascii() or any(c in tag for c in "\r\n;"):
        raise ValueError(f"a request tag holds up to 16 printable characters, got {tag!r}")
    return b";" + tag.encode("ascii") if tag else b""


def _check_range(first: int, last: int, cluster: int) -> None:
    if not 0 <= first <= last <= 9999:
        raise ValueError(f"steps must satisfy 0 <= first <= last <= 9999, got {first}..{last}")
    if not 0 <= cluster <= 99:
        raise ValueError(f"cluster count must lie in 0..99, got {cluster}")


def gd_request(first: int, last: int, cluster: int = 1, *, command: str = "GD",
               tag: str = "") -> bytes:
    """A one-scan request ``GDsssseeeecc`` (or ``GS``), with LF."""
    if command not in ("GD", "GS"):
        raise ValueError(f"single-scan command must be GD or GS, not {command!r}")
    _check_range(first, last, cluster)
    return f"{command}{first:04d}{last:04d}{cluster:02d}".encode("ascii") + _tag(tag) + b"\n"


def md_request(first: int, last: int, cluster: int = 1, skip: int = 0, scans: int = 0, *,
               command: str = "MD", tag: str = "") -> bytes:
    """A streaming request ``MDsssseeeeccinn`` (or ``MS``); ``scans`` 0 = until ``QT``."""
    if command not in ("MD", "MS"):
        raise ValueError(f"streaming command must be MD or MS, not {command!r}")
    _check_range(first, last, cluster)
    if not 0 <= skip <= 9 or not 0 <= scans <= 99:
        raise ValueError(f"skip must lie in 0..9 and scans in 0..99, got {skip}, {scans}")
    return (f"{command}{first:04d}{last:04d}{cluster:02d}{skip:01d}{scans:02d}".encode("ascii")
            + _tag(tag) + b"\n")


# -- receiving ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Reply:
    """One received reply, unchecked: lines as they arrived (sum characters included)."""

    echo: bytes
    status: bytes  # the status line with its sum, b"" if the reply ended before it
    lines: tuple[bytes, ...]  # the lines after the status line
    complete: bool  # it ended with the empty line (not cut off by the next echo)


class ReplyParser:
    """Feed bytes as they arrive; take out replies (echo, status, lines, empty line).

    With ``echoes`` (the exact echo lines expected), a reply starts only at one of them: lines
    in between are garbage (counted in ``skipped_bytes``, each run of them once in
    ``garbage_runs``), garbage glued before an echo on the same line is cut off, and an echo
    arriving inside a reply ends that reply as incomplete (the empty line was lost). Without
    ``echoes`` any non-empty line after an empty one starts a reply. Over-long lines and
    replies are cut so that garbage without line ends cannot grow the buffer.
    """

    def __init__(self, echoes: Iterable[bytes] | None = None, *, max_line: int = 256,
                 max_lines: int = 256) -> None:
        self.echoes = tuple(echoes) if echoes is not None else None
        if self.echoes is not None and any(not e or b"\n" in e for e in self.echoes):
            raise ValueError("echo lines must be non-empty and hold no LF")
        self._echo_re = (re.compile(b"(" + b"|".join(re.escape(e) for e in self.echoes)
                                    + rb")\Z") if self.echoes else None)
        self.max_line = max_line
        self.max_lines = max_lines
        self._buf = bytearray()
        self._cur: list[bytes] | None = None
        self._in_garbage = False
        self.skipped_bytes = 0
        self.garbage_runs = 0

    def feed(self, data: bytes) -> list[Reply]:
        self._buf += data
        out: list[Reply] = []
        start = 0
        while True:
            end = self._buf.find(b"\n", start)
            if end < 0:
                break
            self._line(bytes(self._buf[start:end]), out)
            start = end + 1
        del self._buf[:start]
        if len(self._buf) > self.max_line:  # no line end for too long: keep a possible echo
            if self._cur is not None:
                self._close(out, False)
            cut = len(self._buf) - BLOCK
            self._skip(cut)
            del self._buf[:cut]
        return out

    def _skip(self, n: int) -> None:
        self.skipped_bytes += n
        if not self._in_garbage:
            self._in_garbage = True
            self.garbage_runs += 1

    def _echo_in(self, line: bytes) -> int:
        """Where an expected echo ends the line (-1: none); 0 when the line is one."""
        if self.echoes is None:
            return -1
        if line in self.echoes:
            return 0
        m = self._echo_re.search(line) if self._echo_re is not None else None
        return m.start() if m else -1

    def _close(self, out: list[Reply], complete: bool) -> None:
        cur = self._cur
        assert cur is not None
        out.append(Reply(cur[0], cur[1] if len(cur) > 1 else b"", tuple(cur[2:]), complete))
        self._cur = None

    def _line(self, line: bytes, out: list[Reply]) -> None:
        at = self._echo_in(line) if line else -1
        if self._cur is not None:
            if not line:
                self._close(out, True)
                self._in_garbage = False
            elif at >= 0:
                self._close(out, False)
                self._start(line, at)
            elif len(self._cur) >= self.max_lines or len(line) > self.max_line:
                self._close(out, False)
                self._skip(len(line) + 1)
            else:
                self._cur.append(line)
            return
        if not line:
            if self._in_garbage:
                self.skipped_bytes += 1
            self._in_garbage = False
        elif at >= 0 or (self.echoes is None and not self._in_garbage
                         and len(line) <= self.max_line):
            self._start(line, max(at, 0))
        else:
            self._skip(len(line) + 1)

    def _start(self, line: bytes, at: int) -> None:
        if at:
            self._skip(at)
        self._in_garbage = False
        self._cur = [line[at:]]


def check_status(line: bytes) -> bytes:
    """The two status characters of a status line whose sum checks."""
    if len(line) != 3:
        raise FramingError(f"status line of {len(line)} characters: {line[:16]!r}")
    if scip_sum(line[:2]) != line[2:]:
        raise ChecksumError(f"bad sum on status line {line!r}")
    return line[:2]


def _line_lengths(n_chars: int) -> list[int]:
    full, rest = divmod(n_chars, BLOCK)
    return [BLOCK + 1] * full + ([rest + 1] if rest else [])


def check_data_lines(lines: Sequence[bytes], n_chars: int | None = None) -> bytes:
    """The data characters of ``lines`` (each with its sum), joined, once every check passes.

    Every line but the last must hold 64 data characters; with ``n_chars`` the line count and
    every length must match exactly. Characters out of ``0x30..0x6F`` or a wrong length raise
    :class:`FramingError`, a wrong sum :class:`ChecksumError` (sums checked vectorised).
    """
    lengths = np.fromiter((len(x) for x in lines), dtype=np.int64, count=len(lines))
    if n_chars is not None:
        want = _line_lengths(n_chars)
        if len(lines) != len(want) or not np.array_equal(lengths, want):
            raise FramingError(f"data lines of lengths {lengths.tolist()} where {n_chars} "
                               f"characters need {want}")
    elif lengths.size and ((lengths[:-1] != BLOCK + 1).any() or not 2 <= lengths[-1]
                           <= BLOCK + 1):
        raise FramingError(f"data lines of lengths {lengths.tolist()}")
    a = np.frombuffer(b"".join(lines), dtype=np.uint8)
    if a.size and (a.min() < LOW or a.max() > HIGH):
        raise FramingError("character outside 0x30..0x6F in a data line")
    ends = np.cumsum(lengths)  # one past each sum character
    starts = ends - lengths
    totals = np.add.reduceat(a.astype(np.int64), starts) if a.size else np.zeros(0, np.int64)
    sums = a[ends - 1].astype(np.int64)
    if ((totals - sums) & 0x3F != sums - LOW).any():
        raise ChecksumError("bad sum on a data line")
    keep = np.ones(a.size, dtype=bool)
    keep[ends - 1] = False
    return a[keep].tobytes()


def check_scan(rep: Reply, *, echo: bytes, status: bytes, values: int,
               width: int) -> tuple[int, np.ndarray]:
    """The time stamp (ms) and the ``values`` values of a scan reply that passes every check.

    ``echo`` is the exact echo line expected and ``status`` the expected status (``b"99"`` for
    MD/MS scans, ``b"00"`` for GD/GS). Raises :class:`FramingError`, :class:`ChecksumError` or
    :class:`StatusError`; a scan that fails any check is never decoded.
    """
    if not rep.complete:
        raise FramingError("reply cut off before its empty line")
    if rep.echo != echo:
        raise FramingError(f"echo {rep.echo[:32]!r} where {echo!r} was expected")
    got = check_status(rep.status)
    if got != status:
        raise StatusError(got, f"status {got.decode('ascii', 'replace')!r} in reply to "
                               f"{echo.decode('ascii', 'replace')}")
    if not rep.lines:
        raise FramingError("scan reply without a time stamp line")
    stamp = check_data_lines(rep.lines[:1], 4)
    chars = check_data_lines(rep.lines[1:], values * width)
    return int(decode_values(stamp, 4)[0]), decode_values(chars, width)


def parse_info_line(line: bytes) -> tuple[str, str]:
    """``(KEY, VALUE)`` of an information line ``KEY:VALUE;S``.

    The sum covers ``KEY:VALUE``; a sum over ``KEY:VALUE;`` is accepted as well, as urg_c does
    for firmware that computes it that way.
    """
    if len(line) < 4 or line[-2:-1] != b";" or b":" not in line[:-2]:
        raise FramingError(f"not an information line: {line[:40]!r}")
    body, s = line[:-2], line[-1:]
    if s not in (scip_sum(body), scip_sum(line[:-1])):
        raise ChecksumError(f"bad sum on information line {line!r}")
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError as exc:
        raise FramingError(f"non-ASCII information line {line!r}") from exc
    key, _, value = text.partition(":")
    return key, value


def parse_info(rep: Reply, echo: bytes) -> dict[str, str]:
    """The ``KEY: VALUE`` pairs of a VV/PP/II reply that checks (status ``00``)."""
    if not rep.complete or rep.echo != echo:
        raise FramingError(f"incomplete or foreign reply to {echo!r}")
    got = check_status(rep.status)
    if got != b"00":
        raise StatusError(got, f"status {got!r} in reply to {echo!r}")
    return dict(parse_info_line(x) for x in rep.lines)
