"""The Slamtec RPLIDAR A1/A2 legacy protocol: requests, descriptors, replies, scan nodes, turns.

See ``../shared/protocols.md`` section 2. A request is ``A5 cmd`` or, for a command with bit 7
set, ``A5 cmd size payload xor``. Every reply starts with a 7-byte descriptor ``A5 5A``
``u32 LE (30-bit length, 2-bit mode)`` ``type``. A SCAN streams 5-byte nodes that carry **no
checksum**: only the check bit and the start flag with its inverse guard them, so
:class:`NodeDecoder` accepts the windows that pass those checks (sliding one byte at a time to
resynchronise) and :class:`TurnAssembler` refuses turns whose angle sequence is implausible.
A corrupted distance inside a plausible turn cannot be detected at all.

Angles on the wire are degrees clockwise seen from above; :func:`beam_layout` and
:func:`bin_index` map them to counter-clockwise beams (theta = -angle).
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from dataclasses import dataclass

import numpy as np

__all__ = [
    "ANGLE_FULL_Q6",
    "HEALTH_ERROR",
    "HEALTH_GOOD",
    "HEALTH_WARNING",
    "SCAN_DESCRIPTOR",
    "Descriptor",
    "DeviceInfo",
    "Health",
    "NodeDecoder",
    "Nodes",
    "Turn",
    "TurnAssembler",
    "beam_layout",
    "bin_index",
    "decode_nodes",
    "encode_nodes",
    "parse_descriptor",
    "parse_health",
    "parse_info",
    "request",
    "xor_checksum",
]

SYNC = 0xA5
SYNC2 = 0x5A
# commands (section 2.4)
STOP = 0x25
RESET = 0x40
SCAN = 0x20
FORCE_SCAN = 0x21
GET_INFO = 0x50
GET_HEALTH = 0x52
GET_SAMPLERATE = 0x59
SET_MOTOR_PWM = 0xF0
EXPRESS_SCAN = 0x82
# answer types
ANS_INFO = 0x04
ANS_HEALTH = 0x06
ANS_SAMPLERATE = 0x15
ANS_SCAN = 0x81

SCAN_DESCRIPTOR = bytes.fromhex("A55A0500004081")
INFO_DESCRIPTOR = bytes.fromhex("A55A1400000004")
HEALTH_DESCRIPTOR = bytes.fromhex("A55A0300000006")
SAMPLERATE_DESCRIPTOR = bytes.fromhex("A55A0400000015")
DESCRIPTOR_SIZE = 7
NODE_SIZE = 5
ANGLE_FULL_Q6 = 360 * 64  # a full turn in angle_q6 units
HEALTH_GOOD, HEALTH_WARNING, HEALTH_ERROR = 0, 1, 2


def xor_checksum(data: bytes) -> int:
    """XOR of all bytes (the request checksum, start flag included)."""
    return int(np.bitwise_xor.reduce(np.frombuffer(data, dtype=np.uint8))) if data else 0


def request(cmd: int, payload: bytes | None = None) -> bytes:
    """A request packet: ``A5 cmd``, plus ``size payload xor`` for commands with bit 7 set."""
    if not 0 <= cmd <= 0xFF:
        raise ValueError(f"command must be a byte, got {cmd}")
    if payload is None:
        if cmd & 0x80:
            raise ValueError(f"command 0x{cmd:02X} takes a payload (bit 7 set)")
        return bytes([SYNC, cmd])
    if not cmd & 0x80:
        raise ValueError(f"command 0x{cmd:02X} takes no payload (bit 7 clear)")
    if len(payload) > 0xFF:
        raise ValueError(f"payload holds at most 255 bytes, got {len(payload)}")
    head = bytes([SYNC, cmd, len(payload)]) + bytes(payload)
    return head + bytes([xor_checksum(head)])


@dataclass(frozen=True)
class Descriptor:
    """A response descriptor: size of each data packet, send mode (0 single, 1 multiple), type."""

    length: int
    mode: int
    type: int


def parse_descriptor(data: bytes) -> Descriptor:
    """The descriptor in the first 7 bytes of ``data`` (which must start with ``A5 5A``)."""
    if len(data) < DESCRIPTOR_SIZE:
        raise ValueError(f"a descriptor has 7 bytes, got {len(data)}")
    if data[0] != SYNC or data[1] != SYNC2:
        raise ValueError(f"a descriptor starts with A5 5A, got {data[:2].hex(' ').upper()}")
    (word,) = struct.unpack_from("<I", data, 2)
    return Descriptor(word & 0x3FFFFFFF, word >> 30, data[6])


@dataclass(frozen=True)
class Health:
    """GET_HEALTH data: status 0 good, 1 warning, 2 error; error code (u16 little-endian)."""

    status: int
    error_code: int

    @property
    def ok(self) -> bool:
        return self.status != HEALTH_ERROR


def parse_health(data: bytes) -> Health:
    """The 3 data bytes of a GET_HEALTH reply (little-endian error code, as in the manual)."""
    if len(data) < 3:
        raise ValueError(f"health data has 3 bytes, got {len(data)}")
    status, code = struct.unpack_from("<BH", data, 0)
    return Health(status, code)


@dataclass(frozen=True)
class DeviceInfo:
    """GET_INFO data: model, firmware (major, minor), hardware revision, 16-byte serial number."""

    model: int
    firmware: tuple[int, int]
    hardware: int
    serial: bytes

    @property
    def firmware_text(self) -> str:
        return f"{self.firmware[0]}.{self.firmware[1]:02d}"


def parse_info(data: bytes) -> DeviceInfo:
    """The 20 data bytes of a GET_INFO reply."""
    if len(data) < 20:
        raise ValueError(f"info data has 20 bytes, got {len(data)}")
    model, minor, major, hardware = data[:4]
    return DeviceInfo(model, (major, minor), hardware, bytes(data[4:20]))


# -- beam geometry ---------------------------------------------------------------------------
def beam_layout(beams: int) -> tuple[float, float]:
    """``(angle_min, angle_increment)`` in radians of ``beams`` equal bins over 360 degrees.

    Beams are counter-clockwise (theta = -device angle); beam ``beams // 2`` looks straight
    ahead (theta 0, device angle 0), so for an even count the first beam is at -pi.
    """
    if beams < 1:
        raise ValueError(f"beams must be positive, got {beams}")
    inc = 2.0 * math.pi / beams
    return -(beams // 2) * inc, inc


def bin_index(angle_q6: np.ndarray, beams: int) -> np.ndarray:
    """Beam index (see :func:`beam_layout`) of each device angle (degrees clockwise x 64)."""
    k = np.rint(np.asarray(angle_q6, dtype=np.float64) * (beams / ANGLE_FULL_Q6)).astype(np.int64)
    return (beams // 2 - k) % beams


# -- scan nodes -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Nodes:
    """Decoded scan nodes as parallel arrays."""

    start: np.ndarray  # bool: first node of a revolution
    quality: np.ndarray  # uint8, 0..63
    angle_q6: np.ndarray  # uint16: degrees clockwise x 64
    dist_q2: np.ndarray  # uint16: millimetres x 4; 0 = no measurement

    def __len__(self) -> int:
        return int(self.start.size)

    @property
    def angle_deg(self) -> np.ndarray:
        return self.angle_q6 / 64.0

    @property
    def dist_mm(self) -> np.ndarray:
        return self.dist_q2 / 4.0

    @staticmethod
    def empty() -> Nodes:
        return Nodes(np.zeros(0, bool), np.zeros(0, np.uint8), np.zeros(0, np.uint16),
                     np.zeros(0, np.uint16))

    @staticmethod
    def concat(parts: list[Nodes]) -> Nodes:
        parts = [p for p in parts if len(p)]
        if not parts:
            return Nodes.empty()
        if len(parts) == 1:
            return parts[0]
        return Nodes(*(np.concatenate([getattr(p, f) for p in parts])
                       for f in ("start", "quality", "angle_q6", "dist_q2")))

    def __getitem__(self, sl: slice) -> Nodes:
        return Nodes(self.start[sl], self.quality[sl], self.angle_q6[sl], self.dist_q2[sl])


def _window_ok(a: np.ndarray) -> np.ndarray:
    """For every offset i with 5 bytes available: does ``a[i:i+5]`` pass the node checks?"""
    b0 = a[:-4]
    b1 = a[1:-3]
    return (((b0 ^ (b0 >> 1)) & 1) & (b1 & 1)).astype(bool)


def decode_nodes(raw: bytes | np.ndarray) -> Nodes:
    """Decode whole 5-byte nodes (no checks; see :class:`NodeDecoder` for a checked stream)."""
    a = np.frombuffer(raw, dtype=np.uint8) if isinstance(raw, bytes | bytearray) else raw
    w = np.asarray(a, dtype=np.uint8).reshape(-1, NODE_SIZE).astype(np.uint16)
    return Nodes(start=(w[:, 0] & 1).astype(bool), quality=(w[:, 0] >> 2).astype(np.uint8),
                 angle_q6=((w[:, 1] | (w[:, 2] << 8)) >> 1).astype(np.uint16),
                 dist_q2=(w[:, 3] | (w[:, 4] << 8)).astype(np.uint16))


def encode_nodes(start: np.ndarray, quality: np.ndarray, angle_q6: np.ndarray,
                 dist_q2: np.ndarray) -> bytes:
    """The wire bytes of nodes (for simulators and tests)."""
    s = np.asarray(start, dtype=bool)
    q = np.asarray(quality, dtype=np.uint16)
    ang = np.asarray(angle_q6, dtype=np.uint16)
    d = np.asarray(dist_q2, dtype=np.uint16)
    if ang.size and int(ang.max()) > 0x7FFF:
        raise ValueError("angle_q6 holds 15 bits")
    out = np.empty((s.size, NODE_SIZE), dtype=np.uint8)
    out[:, 0] = ((q & 0x3F) << 2) | np.where(s, 0b01, 0b10)
    a2 = (ang << 1) | 1
    out[:, 1] = a2 & 0xFF
    out[:, 2] = a2 >> 8
    out[:, 3] = d & 0xFF
    out[:, 4] = d >> 8
    return out.tobytes()


class NodeDecoder:
    """Feed the bytes after a SCAN descriptor; get the nodes that pass the checks.

    A window is a node when ``S != not-S`` and the check bit is 1. While locked, nodes follow
    each other every 5 bytes; the first window that fails breaks the lock (a framing error)
    and the decoder slides one byte at a time until ``lock`` consecutive windows pass, 5 bytes
    apart. Bytes that belong to no accepted node are counted in ``skipped_bytes``. The work per
    chunk is vectorised; the Python loop runs once per lock break, not per node.
    """

    def __init__(self, lock: int = 3) -> None:
        if lock < 1:
            raise ValueError(f"lock must be at least 1, got {lock}")
        self.lock = lock
        self.framing_errors = 0
        self.skipped_bytes = 0
        self.nodes = 0
        self._buf = b""
        self._locked = False

    def reset(self) -> None:
        """Forget the partial node and the alignment (counters stay)."""
        self._buf = b""
        self._locked = False

    def feed(self, data: bytes) -> Nodes:
        buf = self._buf + bytes(data)
        a = np.frombuffer(buf, dtype=np.uint8)
        n = a.size
        if n < NODE_SIZE:
            self._buf = buf
            return Nodes.empty()
        ok = _window_ok(a)  # ok[i]: window at i passes; len n - 4
        starts: list[np.ndarray] = []
        pos = 0
        span = NODE_SIZE * (self.lock - 1)
        while True:
            if self._locked:
                idx = np.arange(pos, n - NODE_SIZE + 1, NODE_SIZE)
                if idx.size == 0:
                    break
                bad = np.flatnonzero(~ok[idx])
                if bad.size == 0:
                    starts.append(idx)
                    pos = int(idx[-1]) + NODE_SIZE
                    break
                j = int(bad[0])
                starts.append(idx[:j])
                pos = int(idx[j])
                self.framing_errors += 1
                self._locked = False
            else:
                end = n - NODE_SIZE + 1 - span  # candidates whose lock windows are all here
                if pos >= end:
                    break
                cand = ok[pos:end].copy()
                for k in range(1, self.lock):
                    cand &= ok[pos + k * NODE_SIZE:end + k * NODE_SIZE]
                hits = np.flatnonzero(cand)
                if hits.size == 0:
                    self.skipped_bytes += end - pos
                    pos = end
                    break
                self.skipped_bytes += int(hits[0])
                pos += int(hits[0])
                self._locked = True
        self._buf = buf[pos:]
        if not starts:
            return Nodes.empty()
        s = np.concatenate(starts)
        self.nodes += int(s.size)
        return decode_nodes(a[s[:, None] + np.arange(NODE_SIZE)])


# -- turns ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Turn:
    """One complete, plausible revolution: its nodes in the order received."""

    nodes: Nodes

    @property
    def angle_q6(self) -> np.ndarray:
        return self.nodes.angle_q6

    @property
    def dist_q2(self) -> np.ndarray:
        return self.nodes.dist_q2


class TurnAssembler:
    """Feed the bytes of a SCAN stream; get the complete turns that look like a revolution.

    A turn runs from a node with S = 1 to the next such node, or to an angle that drops by more
    than 180 degrees (a wrap whose start node was lost). The turn is complete only when the
    next one begins, as in the Slamtec SDK. Nodes before the first start flag are a partial
    turn and are dropped (``partial_nodes``). A turn is rejected (``rejected``, by reason in
    ``reasons``) unless:

    * it begins with a start flag;
    * it holds ``min_nodes`` to ``max_nodes`` nodes;
    * no angle reaches 360 degrees;
    * every step between successive angles, including the step from the last node back round
      to the first, lies within ``min_step`` to ``max_step`` times the median step: the
      angles rise monotonically, nothing is missing, and the turn covers the full circle.
    """

    def __init__(self, *, min_nodes: int = 32, max_nodes: int = 8192, min_step: float = 0.4,
                 max_step: float = 1.6, lock: int = 3) -> None:
        if not 0 < min_step < 1 < max_step:
            raise ValueError(f"need 0 < min_step < 1 < max_step, got {min_step}, {max_step}")
        self.decoder = NodeDecoder(lock=lock)
        self.min_nodes = min_nodes
        self.max_nodes = max_nodes
        self.min_step = min_step
        self.max_step = max_step
        self.turns = 0
        self.rejected = 0
        self.partial_nodes = 0
        self.reasons: Counter[str] = Counter()
        self._parts: list[Nodes] = []
        self._started = False
        self._last_angle: int | None = None

    @property
    def framing_errors(self) -> int:
        return self.decoder.framing_errors

    @property
    def skipped_bytes(self) -> int:
        """Bytes dropped: outside any node, or in the partial turn before the first start."""
        return self.decoder.skipped_bytes + NODE_SIZE * self.partial_nodes

    def reset(self) -> None:
        """Forget the partial turn and node (after a reconnect); counters stay."""
        self.decoder.reset()
        self._parts = []
        self._started = False
        self._last_angle = None

    def feed(self, data: bytes) -> list[Turn]:
        nodes = self.decoder.feed(data)
        if not len(nodes):
            return []
        ang = nodes.angle_q6.astype(np.int64)
        prev = np.empty_like(ang)
        prev[1:] = ang[:-1]
        prev[0] = ang[0] if self._last_angle is None else self._last_angle
        bound = np.flatnonzero(nodes.start | (prev - ang > ANGLE_FULL_Q6 // 2))
        self._last_angle = int(ang[-1])
        out: list[Turn] = []
        cut = 0
        for b in bound.tolist():  # one iteration per turn
            self._append(nodes[cut:b])
            self._close(out)
            self._started = True
            cut = b
        self._append(nodes[cut:])
        return out

    def _append(self, part: Nodes) -> None:
        if not len(part):
            return
        if self._started:
            self._parts.append(part)
        else:
            self.partial_nodes += len(part)

    def _close(self, out: list[Turn]) -> None:
        if not self._started:
            return
        nodes = Nodes.concat(self._parts)
        self._parts = []
        if not len(nodes):
            return
        reason = self.check(nodes)
        if reason is None:
            self.turns += 1
            out.append(Turn(nodes))
        else:
            self.rejected += 1
            self.reasons[reason] += 1

    def check(self, nodes: Nodes) -> str | None:
        """Why the nodes of one turn are not a plausible revolution, or None if they are."""
        n = len(nodes)
        if not nodes.start[0]:
            return "no start flag"
        if not self.min_nodes <= n <= self.max_nodes:
            return "node count"
        ang = nodes.angle_q6.astype(np.int64)
        if int(ang.max()) >= ANGLE_FULL_Q6:
            return "angle beyond 360"
        steps = np.diff(ang, append=ang[0] + ANGLE_FULL_Q6)
        med = float(np.median(steps))
        if med <= 0:
            return "angle sequence"
        if steps.min() < self.min_step * med or steps.max() > self.max_step * med:
            return "angle sequence"
        return None
