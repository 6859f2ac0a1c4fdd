"""SICK LMS 2xx telegrams against the test vectors of ../shared/protocols.md, section 1.6."""

import numpy as np
import pytest

from drivers.sick_protocol import TelegramReceiver, decode_scan, request, sick_crc

H = bytes.fromhex

REQUESTS = {
    "L1": ("20 40", "02 00 02 00 20 40 50 08"),
    "L2": ("20 42", "02 00 02 00 20 42 52 08"),
    "L3": ("20 41", "02 00 02 00 20 41 51 08"),
    "L4": ("20 48", "02 00 02 00 20 48 58 08"),
    "L5": ("20 24", "02 00 02 00 20 24 34 08"),
    "L6": ("20 25", "02 00 02 00 20 25 35 08"),
    "L7": ("30 01", "02 00 02 00 30 01 31 18"),
    "L8": ("20 00 53 49 43 4B 5F 4C 4D 53", "02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 BE C5"),
    "L9": ("3B B4 00 64 00", "02 00 05 00 3B B4 00 64 00 97 49"),
    "L10": ("3B B4 00 32 00", "02 00 05 00 3B B4 00 32 00 3B 1F"),
    "L11": ("3B 64 00 19 00", "02 00 05 00 3B 64 00 19 00 E7 72"),
    "L12": ("31", "02 00 01 00 31 15 12"),
    "L13": ("3A", "02 00 01 00 3A 1E 12"),
    "L14": ("10", "02 00 01 00 10 34 12"),
}
L15 = "06 02 80 03 00 A0 00 10 16 0A"
L16 = "02 80 0A 00 B0 03 40 E8 03 C4 09 EE 02 10 58 17"
L17 = ("02 80 17 00 90 4C 4D 53 32 30 30 3B 33 30 31 30 36 33 3B 56 30 32 2E 31 30 20 10 "
       "63 5E")


def test_crc_worked_example():
    assert sick_crc(H("02 00 02 00 30 01")) == 0x1831


@pytest.mark.parametrize("name", sorted(REQUESTS))
def test_request_vectors(name):
    payload, wire = REQUESTS[name]
    assert request(H(payload)) == H(wire)


def test_reply_vectors_decode():
    rx = TelegramReceiver()
    (ack,) = rx.feed(H(L15))
    assert (ack.address, ack.command, ack.data, ack.status) == (0x80, 0xA0, b"\x00", 0x10)
    assert rx.acks == 1
    (scan,) = rx.feed(H(L16))
    ranges, unit = decode_scan(scan)
    assert unit == 0.001
    np.testing.assert_allclose(ranges, [1.0, 2.5, 0.75])
    (power_on,) = rx.feed(H(L17))
    assert power_on.command == 0x90 and power_on.data == b"LMS200;301063;V02.10 "


def test_frames_split_anywhere_and_garbage_between_resynchronise():
    stream = b"\xff\x02\x13garbage" + H(L16) + b"\x02\x80\xff\xff" + H(L17) + H(L16)
    rx = TelegramReceiver()
    got = []
    for i in range(len(stream)):  # one byte at a time: every possible split
        got += rx.feed(stream[i:i + 1])
    assert [t.command for t in got] == [0xB0, 0x90, 0xB0]
    assert rx.bad_lengths >= 1 and rx.skipped_bytes > 0


def test_a_corrupted_scan_is_never_decoded():
    rng = np.random.default_rng(0)
    good = H(L16)
    decoded = 0
    for _ in range(500):
        bad = bytearray(good)
        k = int(rng.integers(0, len(bad)))
        bad[k] ^= 1 << int(rng.integers(0, 8))  # one flipped bit
        rx = TelegramReceiver()
        for t in rx.feed(bytes(bad)):
            if t.command == 0xB0:
                decoded += 1
                np.testing.assert_allclose(decode_scan(t)[0], [1.0, 2.5, 0.75])
    assert decoded == 0


def test_bad_scan_payloads_raise():
    from drivers.sick_protocol import Telegram

    with pytest.raises(ValueError, match="not a scan"):
        decode_scan(Telegram(0x80, 0xA0, b"\x00", 0x10))
    with pytest.raises(ValueError, match="declares 5 values but holds 1"):
        decode_scan(Telegram(0x80, 0xB0, b"\x05\x40\x01\x00", 0x10))
