"""The SICK LMS 2xx telegram protocol: CRC, telegrams, and a resynchronising receiver.

See ``../shared/protocols.md`` section 1. A telegram is ``STX ADDR LEN(u16 LE) CMD DATA
[STATUS] CRC(u16 LE)``; replies come from address ``0x80`` with code ``command + 0x80`` and end
with a status byte. The CRC is SICK's own (generator 0x8005, one bit per byte step), not a
textbook CRC-16. A telegram whose CRC fails is never decoded.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

__all__ = ["HOST", "LMS", "MAX_PAYLOAD", "Telegram", "TelegramReceiver", "decode_scan",
           "encode_scan", "reply", "request", "sick_crc"]

STX = 0x02
HOST, LMS = 0x00, 0x80
ACK, NAK = 0x06, 0x15
MAX_PAYLOAD = 812
UNITS_M = {0: 0.01, 1: 0.001, 2: 0.1}  # count-word bits 14-15: cm, mm, 10 cm


def sick_crc(data: bytes) -> int:
    """SICK's CRC-16 of a telegram from STX to its last data or status byte."""
    crc = 0
    prev = 0
    for byte in data:  # a few hundred bytes a telegram; the bit loop is the algorithm
        crc = ((crc << 1) & 0xFFFF) ^ 0x8005 if crc & 0x8000 else (crc << 1) & 0xFFFF
        crc ^= (prev << 8) | byte
        prev = byte
    return crc


def request(payload: bytes, address: int = HOST) -> bytes:
    """A complete telegram for ``payload`` (command byte and its data), CRC appended."""
    if not payload or len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload must hold 1 to {MAX_PAYLOAD} bytes, got {len(payload)}")
    head = bytes([STX, address]) + struct.pack("<H", len(payload)) + payload
    return head + struct.pack("<H", sick_crc(head))


def reply(payload: bytes, status: int = 0x10, ack: bool = True) -> bytes:
    """What the LMS sends for ``payload`` (reply code and data): ACK, telegram with status, CRC."""
    body = request(payload + bytes([status]), address=LMS)
    return (bytes([ACK]) if ack else b"") + body


@dataclass(frozen=True)
class Telegram:
    """A received telegram whose CRC checked."""

    address: int
    command: int
    data: bytes  # between the command and the status byte
    status: int  # -1 in a request (requests carry none)


class TelegramReceiver:
    """Feed bytes as they arrive; take out the telegrams that check.

    It skips bytes until ``02 80``, reads LEN, LEN bytes and the CRC, and on a bad CRC or an
    impossible LEN drops the frame and starts again one byte after the ``02``. Counters say
    what was dropped. With ``address=HOST`` it reads the host's requests instead (``02 00``,
    no status byte), as a device does.
    """

    def __init__(self, address: int = LMS) -> None:
        self.address = address
        self._sync = bytes([STX, address])
        self._buf = bytearray()
        self.crc_errors = 0
        self.bad_lengths = 0
        self.skipped_bytes = 0
        self.acks = 0
        self.naks = 0

    def feed(self, data: bytes) -> list[Telegram]:
        self._buf += data
        out = []
        while True:
            start = self._buf.find(self._sync)
            if start < 0:
                keep = 1 if self._buf[-1:] == bytes([STX]) else 0
                self._count_skipped(self._buf[:len(self._buf) - keep])
                del self._buf[:len(self._buf) - keep]
                return out
            self._count_skipped(self._buf[:start])
            del self._buf[:start]
            if len(self._buf) < 4:
                return out
            (length,) = struct.unpack_from("<H", self._buf, 2)
            if length < (2 if self.address == LMS else 1) or length > MAX_PAYLOAD:
                self.bad_lengths += 1
                del self._buf[:1]
                continue
            total = 4 + length + 2
            if len(self._buf) < total:
                return out
            frame = bytes(self._buf[:total])
            (crc,) = struct.unpack_from("<H", frame, 4 + length)
            if crc != sick_crc(frame[:4 + length]):
                self.crc_errors += 1
                del self._buf[:1]
                continue
            del self._buf[:total]
            if self.address == LMS:
                out.append(Telegram(frame[1], frame[4], frame[5:3 + length], frame[3 + length]))
            else:
                out.append(Telegram(frame[1], frame[4], frame[5:4 + length], -1))

    def _count_skipped(self, junk: bytes | bytearray) -> None:
        self.acks += junk.count(ACK)
        self.naks += junk.count(NAK)
        self.skipped_bytes += len(junk)


def decode_scan(telegram: Telegram) -> tuple[np.ndarray, float]:
    """Ranges in metres (``inf`` where the LMS saw nothing) of a ``B0`` telegram, and its unit.

    The 13-bit range is masked from the flag bits; 8191 units is the no-return reading.
    """
    if telegram.command != 0xB0:
        raise ValueError(f"not a scan telegram: command 0x{telegram.command:02X}")
    if len(telegram.data) < 2:
        raise ValueError("scan telegram without a count word")
    (count,) = struct.unpack_from("<H", telegram.data, 0)
    n = count & 0x3FF
    unit = UNITS_M.get(count >> 14)
    if unit is None:
        raise ValueError(f"unknown units code {count >> 14}")
    if len(telegram.data) < 2 + 2 * n:
        raise ValueError(f"scan telegram declares {n} values but holds "
                         f"{(len(telegram.data) - 2) // 2}")
    raw = np.frombuffer(telegram.data, dtype="<u2", count=n, offset=2) & 0x1FFF
    ranges = raw.astype(np.float64) * unit
    ranges[(raw == 0) | (raw >= 0x1FFF)] = np.inf
    return ranges, unit


def encode_scan(values: np.ndarray, units_code: int) -> bytes:
    """The payload of a ``B0`` telegram (reply code, count word, values) for raw ``values``."""
    v = np.asarray(values)
    if v.ndim != 1 or not 0 < v.size <= 0x3FF:
        raise ValueError(f"a scan holds 1 to 1023 values, got shape {v.shape}")
    count = v.size | (units_code << 14)
    return bytes([0xB0]) + struct.pack("<H", count) + v.astype("<u2").tobytes()
