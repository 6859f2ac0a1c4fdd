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
    "bin_nodes",
    "decode_nodes",
    "encode_nodes",
    "find_descriptor",
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


def find_descriptor(data: bytes, descriptor: bytes, max_wrong: int = 0) -> int:
    """Offset of the first 7 bytes of ``data`` that read as ``descriptor`` with at most
    ``max_wrong`` bytes changed on the wire, or -1."""
    if len(data) < DESCRIPTOR_SIZE:
        return -1
    windows = np.lib.stride_tricks.sliding_window_view(np.frombuffer(data, dtype=np.uint8),
                                                        DESCRIPTOR_SIZE)
    wrong = np.count_nonzero(windows != np.frombuffer(descriptor, dtype=np.uint8), axis=1)
    hits = np.flatnonzero(wrong <= max_wrong)
    return int(hits[0]) if hits.size else -1


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


def bin_nodes(angle_q6: np.ndarray, dist_q2: np.ndarray, beams: int) -> np.ndarray:
    """distance_q2 per beam of one turn's nodes (0: no return): the nearest node in a beam wins.

    Nodes reading 0 are no measurement and are left out.
    """
    none = 1 << 16  # above any distance_q2
    out = np.full(beams, none, dtype=np.int64)
    d = np.asarray(dist_q2, dtype=np.int64)
    hit = d > 0
    np.minimum.at(out, bin_index(np.asarray(angle_q6)[hit], beams), d[hit])
    out[out == none] = 0
    return out.astype(np.uint16)


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


def _window_angle(a: np.ndarray) -> np.ndarray:
    """For every offset i with 5 bytes available: angle_q6 of ``a[i:i+5]`` read as a node."""
    return (a[1:-3].astype(np.int64) | (a[2:-2].astype(np.int64) << 8)) >> 1


def _window_dist(a: np.ndarray) -> np.ndarray:
    """For every offset i with 5 bytes available: distance_q2 of ``a[i:i+5]`` read as a node."""
    return a[3:-1].astype(np.int64) | (a[4:].astype(np.int64) << 8)


def _falls_back(prev: np.ndarray | int, cur: np.ndarray | int) -> np.ndarray | bool:
    """Whether angle ``cur`` lies more than half a circle behind ``prev`` (angle_q6): where a
    new revolution begins."""
    return cur < prev - ANGLE_FULL_Q6 // 2


def _follows(prev: np.ndarray, cur: np.ndarray, ahead: np.ndarray | int,
             back: int) -> np.ndarray:
    """Whether angle ``cur`` can follow ``prev`` in a scan: at most ``ahead`` further round
    (the wrap to a new revolution included) or ``back`` behind (angle_q6 units)."""
    step = (cur - prev) % ANGLE_FULL_Q6
    return (step <= ahead) | (step >= ANGLE_FULL_Q6 - back)


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

    A window is a node when ``S != not-S``, the check bit is 1 and its angle is below 360
    degrees. While locked, nodes follow each other every 5 bytes, and the angle of each node
    with a return lies at most ``max_gap`` degrees ahead of, or ``max_back`` degrees behind,
    the last such node's (a revolution's angles rise in small steps and wrap past 360; the
    device's parallax correction can put a near point a little behind a far one). Nodes
    without a return are not held to their angle: the device does not correct it, and the
    Slamtec SDK replaces it. The first node that fails breaks the lock (a framing error) and
    is dropped; the decoder then slides one byte at a time until ``lock`` consecutive
    windows, 5 bytes apart, pass. A stream shifted by a lost or an extra byte still passes the
    window checks one time in four, so the angle check is what keeps the decoder from
    locking, or staying locked, on the wrong byte. Bytes that belong to no accepted node are
    counted in ``skipped_bytes``. The work per chunk is vectorised; the Python loop runs once
    per lock break, not per node.
    """

    def __init__(self, lock: int = 3, max_gap: float = 20.0, max_back: float = 10.0) -> None:
        if lock < 1:
            raise ValueError(f"lock must be at least 1, got {lock}")
        if not 0 < max_gap < 180 or not 0 <= max_back < 180:
            raise ValueError(f"max_gap must lie in (0, 180) and max_back in [0, 180) degrees, "
                             f"got {max_gap}, {max_back}")
        self.lock = lock
        self.max_gap = round(max_gap * 64)
        self.max_back = round(max_back * 64)
        self.framing_errors = 0
        self.skipped_bytes = 0
        self.nodes = 0
        self._buf = b""
        self._locked = False
        self._last: int | None = None  # angle_q6 of the last node with a return, while locked
        self._quiet = 0  # nodes without a return accepted since then
        self._resume = 0  # where in the buffer to go on
        self._suspect = False  # the buffer starts with a node held in doubt

    def reset(self) -> None:
        """Forget the partial node and the alignment (counters stay)."""
        self._buf = b""
        self._locked = False
        self._last = None
        self._quiet = 0
        self._resume = 0
        self._suspect = False

    def _fits(self, prev: np.ndarray, cur: np.ndarray, cur_dist: np.ndarray,
              nodes_on: np.ndarray | int = 1) -> np.ndarray:
        """Whether each node may follow the node with a return ``nodes_on`` nodes before it."""
        return (cur_dist == 0) | _follows(prev, cur, self.max_gap * nodes_on, self.max_back)

    @staticmethod
    def _false_start(ang: np.ndarray, start: np.ndarray, suspect: int, found: int) -> bool:
        """Whether the node a new lock found at ``found``, on the bytes of the node held in
        doubt at ``suspect``, begins a new revolution (its angle falls back by more than half
        a circle) without a start flag: not a node the device sent, but the held node's last
        byte read with the damaged start node after it, so the held node stands."""
        return bool(_falls_back(int(ang[suspect]), int(ang[found]))) and not start[found]

    def flush(self) -> Nodes:
        """The node held back for the window after it (the stream has paused)."""
        if not self._locked or self._suspect or self._resume or len(self._buf) < NODE_SIZE:
            return Nodes.empty()
        node = np.frombuffer(self._buf[:NODE_SIZE], dtype=np.uint8)
        self._buf = self._buf[NODE_SIZE:]
        self._locked = False  # what follows a pause starts a new lock
        self._last = None
        self._quiet = 0
        self.nodes += 1
        return decode_nodes(node)

    def feed(self, data: bytes) -> Nodes:
        """The nodes completed by ``data``.

        The last node accepted is held back until the window after it is seen: when that
        window breaks the lock, the held node may itself be misread (a byte before it was
        lost or added), and if the decoder locks again within it, on the node's own bytes,
        the held node is dropped; its last byte may have been the start of the next node.
        It stands when the node found there begins a revolution without a start flag (a
        byte lost at the head of the next turn); the lock then starts one node later.
        """
        buf = self._buf + bytes(data)
        a = np.frombuffer(buf, dtype=np.uint8)
        n = a.size
        pos = self._resume
        suspect = 0 if self._suspect else -1  # offset of a held node in doubt
        if n - pos < NODE_SIZE:
            self._buf = buf
            return Nodes.empty()
        ang = _window_angle(a)
        dist = _window_dist(a)
        ok = _window_ok(a) & (ang < ANGLE_FULL_Q6)  # ok[i]: window at i passes; len n - 4
        start = (a[:-4] & 1).astype(bool)  # start[i]: the window at i has S = 1
        starts: list[np.ndarray] = []
        span = NODE_SIZE * (self.lock - 1)
        while True:
            if self._locked:
                idx = np.arange(pos, n - NODE_SIZE + 1, NODE_SIZE)
                if idx.size == 0:
                    break
                hit = dist[idx] > 0
                at = np.arange(idx.size)
                # the last angle with a return before each node, and how many nodes back
                last = np.maximum.accumulate(np.where(hit, at, -1))
                ref = np.empty(idx.size, dtype=np.int64)
                ref[1:] = last[:-1]
                ref[0] = -1
                prev = np.where(ref >= 0, ang[idx[np.maximum(ref, 0)]], -1)
                back = np.where(ref >= 0, at - ref, at + 1 + self._quiet)
                if self._last is not None:
                    prev[ref < 0] = self._last
                fits = self._fits(prev, ang[idx], dist[idx], back) | (prev < 0)
                bad = np.flatnonzero(~(ok[idx] & fits))
                if bad.size == 0:  # all pass: the last one is held back
                    starts.append(idx[:-1])
                    if idx.size > 1 and last[-2] >= 0:
                        self._last = int(ang[idx[last[-2]]])
                        self._quiet = idx.size - 2 - int(last[-2])
                    else:
                        self._quiet += idx.size - 1
                    pos = int(idx[-1])
                    break
                j = int(bad[0])
                self.framing_errors += 1
                self._locked = False
                self._last = None
                self._quiet = 0
                if j >= 1:  # the node before the break is in doubt: slide from within it
                    starts.append(idx[:j - 1])
                    suspect = int(idx[j - 1])
                    pos = suspect + 1
                else:
                    pos = int(idx[0])
            else:
                end = n - NODE_SIZE + 1 - span  # candidates whose lock windows are all here
                if pos >= end:
                    break
                cand = ok[pos:end].copy()
                for k in range(1, self.lock):
                    here = slice(pos + k * NODE_SIZE, end + k * NODE_SIZE)
                    before = slice(pos + (k - 1) * NODE_SIZE, end + (k - 1) * NODE_SIZE)
                    cand &= ok[here]
                    cand &= self._fits(ang[before], ang[here], dist[here]) | (dist[before] == 0)
                    # a start node without a return right before another start node: no
                    # revolution is one node long (read on a no-return node's zero bytes)
                    cand &= ~(start[before] & start[here] & (dist[before] == 0))
                hits = np.flatnonzero(cand)
                found = pos + int(hits[0]) if hits.size else end
                if suspect >= 0 and (hits.size or end >= suspect + NODE_SIZE):
                    if hits.size and found < suspect + NODE_SIZE \
                            and self._false_start(ang, start, suspect, found):
                        starts.append(np.array([suspect]))  # it stands; the lock skips a node
                        self.skipped_bytes += found - suspect
                        found += NODE_SIZE
                    elif found < suspect + NODE_SIZE:  # locked again on its bytes: drop it
                        self.skipped_bytes += found - suspect
                    else:  # it stands
                        starts.append(np.array([suspect]))
                        self.skipped_bytes += found - suspect - NODE_SIZE
                    suspect = -1
                elif suspect < 0:
                    self.skipped_bytes += found - pos
                pos = found
                if not hits.size:
                    break
                self._locked = True
        keep = suspect if suspect >= 0 else pos
        self._buf = buf[keep:]
        self._resume = pos - keep
        self._suspect = suspect >= 0
        if not starts:
            return Nodes.empty()
        s = np.concatenate(starts).astype(np.int64)
        if not s.size:
            return Nodes.empty()
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

    A turn runs from a node with S = 1 to the next such node. The turn is complete when the
    next one begins, as in the Slamtec SDK, or, through :meth:`flush`, when the stream pauses
    after a turn that already passes every check (the last turn before a STOP or a power
    cut). Nodes before the first start flag are a partial
    turn and are dropped (``partial_nodes``). A turn is rejected (``rejected``, by reason in
    ``reasons``) unless:

    * it begins with a start flag;
    * it holds ``min_nodes`` to ``max_nodes`` nodes;
    * no angle reaches 360 degrees;
    * the nodes with a return advance round the circle at a steady step: between two of them
      ``k`` nodes apart, including the last and the first one round the wrap, the angle
      advances ``k`` median steps, give or take ``1 - min_step`` to ``max_step - 1`` of a step,
      so nothing is missing, out of order or extra, and the turn covers the full circle
      once. The device corrects each angle for the parallax between its laser and its
      camera, which moves a point at distance ``d`` by ``atan(parallax / d)``: where the
      distance changes between the two nodes, the advance may differ by that much more (and
      the last points of a turn may read a little past 0 degrees). A distance below
      ``min_range`` (mm; the A1 and A2 measure from 150 mm) counts as ``min_range`` here, so
      a corrupted distance cannot make room for missing nodes.

    Nodes without a return add nothing to a frame, and their angles (which the device does not
    correct) are not checked. A turn that fails only because nodes after its last one were
    taken in (the next turn's start node was lost, or reads as a node of this one) is cut
    back to one revolution, before the first bad step, and delivered if what is left
    passes every check (``trimmed`` counts the nodes cut off). ``lock``, ``max_gap`` and
    ``max_back`` go to :class:`NodeDecoder`.
    """

    def __init__(self, *, min_nodes: int = 32, max_nodes: int = 8192, min_step: float = 0.4,
                 max_step: float = 1.6, parallax: float = 25.0, min_range: float = 150.0,
                 lock: int = 3, max_gap: float = 20.0, max_back: float = 10.0) -> None:
        if not 0 < min_step < 1 < max_step:
            raise ValueError(f"need 0 < min_step < 1 < max_step, got {min_step}, {max_step}")
        if parallax < 0 or min_range <= 0:
            raise ValueError(f"need parallax >= 0 and min_range > 0 (mm), got {parallax}, "
                             f"{min_range}")
        self.min_range = min_range  # mm
        self.decoder = NodeDecoder(lock=lock, max_gap=max_gap, max_back=max_back)
        self.min_nodes = min_nodes
        self.max_nodes = max_nodes
        self.min_step = min_step
        self.max_step = max_step
        self.parallax = parallax  # mm
        self.turns = 0
        self.rejected = 0
        self.partial_nodes = 0
        self.trimmed = 0
        self.reasons: Counter[str] = Counter()
        self._parts: list[Nodes] = []
        self._pending = 0  # nodes in _parts
        self._started = False
        self._peeked = False  # the turn under way failed a flush and has not grown since

    @property
    def framing_errors(self) -> int:
        return self.decoder.framing_errors

    @property
    def skipped_bytes(self) -> int:
        """Bytes dropped: outside any node, in the partial turn before the first start, or
        cut off the end of a turn."""
        return self.decoder.skipped_bytes + NODE_SIZE * (self.partial_nodes + self.trimmed)

    def reset(self) -> None:
        """Forget the partial turn and node (after a reconnect); counters stay."""
        self.decoder.reset()
        self._parts = []
        self._pending = 0
        self._started = False
        self._peeked = False

    def feed(self, data: bytes) -> list[Turn]:
        return self._take(self.decoder.feed(data))

    def _take(self, nodes: Nodes) -> list[Turn]:
        out: list[Turn] = []
        if not len(nodes):
            return out
        cut = 0
        for b in np.flatnonzero(nodes.start).tolist():  # one iteration per turn
            self._append(nodes[cut:b], out)
            self._close(out)
            self._started = True
            cut = b
        self._append(nodes[cut:], out)
        return out

    def flush(self) -> list[Turn]:
        """The turn under way, if it already passes every check (the stream has paused).

        A turn still arriving does not yet cover the circle (the step round the wrap is too
        long) and is kept.
        """
        out = self._take(self.decoder.flush())
        if not self._started or not self._parts or self._peeked:
            return out
        nodes = Nodes.concat(self._parts)
        self._parts = [nodes]
        if self.check(nodes) is not None:
            self._peeked = True
            return out
        self._parts = []
        self._pending = 0
        self._started = False
        self.turns += 1
        return [*out, Turn(nodes)]

    def _append(self, part: Nodes, out: list[Turn]) -> None:
        if not len(part):
            return
        if not self._started:
            self.partial_nodes += len(part)
            return
        self._parts.append(part)
        self._pending += len(part)
        self._peeked = False
        if self._pending > 2 * self.max_nodes:  # start flags keep failing
            self._close(out)

    def _close(self, out: list[Turn]) -> None:
        if not self._started:
            return
        nodes = Nodes.concat(self._parts)
        self._parts = []
        self._pending = 0
        self._peeked = False
        if not len(nodes):
            return
        reason = self.check(nodes)
        if reason is not None and nodes.start[0]:
            keep = self._complete_prefix(nodes)
            if keep < len(nodes) and self.check(nodes[:keep]) is None:
                self.trimmed += len(nodes) - keep
                nodes, reason = nodes[:keep], None
        if reason is None:
            self.turns += 1
            out.append(Turn(nodes))
        else:
            self.rejected += 1
            self.reasons[reason] += 1

    def _steps(self, nodes: Nodes) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """The nodes with a return: their positions, how far round each lies from the first
        (angle_q6, unwrapped), whether the step from each to the next one (the last: round
        the wrap to the first) is one no revolution makes, and the median step per node."""
        n = len(nodes)
        pos = np.flatnonzero(nodes.dist_q2 > 0)
        if pos.size < 2:
            return pos, np.zeros(pos.size), np.zeros(pos.size, dtype=bool), 0.0
        a = nodes.angle_q6[pos].astype(np.int64)
        d = nodes.dist_q2[pos].astype(np.int64)
        half = ANGLE_FULL_Q6 // 2
        inner = (np.diff(a) + half) % ANGLE_FULL_Q6 - half  # a parallax-corrected angle may
        along = np.concatenate([[0], np.cumsum(inner)])  # cross 360 before the next start
        steps = np.append(inner, ANGLE_FULL_Q6 - along[-1])
        k = np.diff(pos, append=pos[0] + n)
        med = float(np.median(steps / k))
        if med <= 0:
            return pos, along, np.ones(pos.size, dtype=bool), med
        dev = steps - k * med
        mm = np.maximum(d / 4.0, self.min_range)  # nearer is no measurement the device makes
        shift = np.arctan(self.parallax / mm)  # radians each point was moved
        room = np.degrees(np.abs(shift - np.roll(shift, -1))) * 64.0
        bad = (dev < (self.min_step - 1) * med - room) | (dev > (self.max_step - 1) * med + room)
        return pos, along, bad, med

    def _complete_prefix(self, nodes: Nodes) -> int:
        """How many leading nodes come before the first step that no revolution makes, or
        before the revolution is complete (the next start flag was lost)."""
        pos, along, bad, med = self._steps(nodes)
        if pos.size < 2:
            return len(nodes)
        stop = np.flatnonzero(bad[:-1])
        over = np.flatnonzero(along > ANGLE_FULL_Q6 - 0.5 * max(med, 0.0))
        ends = [self._wrap_within(nodes, int(pos[stop[0]]), int(pos[stop[0] + 1]),
                                  int(pos[stop[0]]) + 1)] if stop.size else []
        ends += [self._wrap_within(nodes, int(pos[over[0] - 1]), int(pos[over[0]]),
                                   int(pos[over[0]]))] if over.size else []
        return min(ends, default=len(nodes))

    @staticmethod
    def _wrap_within(nodes: Nodes, first: int, last: int, default: int) -> int:
        """Where the next revolution begins among the nodes without a return between two
        with one (``first`` < index <= ``last``): at the first whose angle falls back by more
        than half a circle; ``default`` if none does. The nodes before it belong to this
        turn even when the next turn's start node was lost."""
        angle = nodes.angle_q6[first:last + 1].astype(np.int64)
        back = np.flatnonzero(_falls_back(angle[:-1], angle[1:]))
        return first + 1 + int(back[0]) if back.size else default

    def check(self, nodes: Nodes) -> str | None:
        """Why the nodes of one turn are not a plausible revolution, or None if they are."""
        n = len(nodes)
        if not nodes.start[0]:
            return "no start flag"
        if not self.min_nodes <= n <= self.max_nodes:
            return "node count"
        if int(nodes.angle_q6.max()) >= ANGLE_FULL_Q6:
            return "angle beyond 360"
        _, _, bad, _ = self._steps(nodes)
        if bad.any():
            return "angle sequence"
        return None
