"""The SICK LMS 2xx driver against the simulated LMS on a pseudo-terminal."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from drivers.devices.pty_device import ScanSource
from drivers.devices.sick_device import SickDevice
from drivers.scenario import load_scenario
from drivers.sick_lms2xx import SickLms2xx
from drivers.sick_protocol import HOST, TelegramReceiver, encode_scan, reply, request


def test_device_replies_match_the_test_vectors() -> None:
    assert reply(bytes([0xA0, 0x00])) == bytes.fromhex("06 02 80 03 00 A0 00 10 16 0A")
    b0 = reply(encode_scan(np.array([1000, 2500, 750]), 1), ack=False)
    assert b0 == bytes.fromhex("02 80 0A 00 B0 03 40 E8 03 C4 09 EE 02 10 58 17")
    power_on = reply(bytes([0x90]) + b"LMS200;301063;V02.10 ", ack=False)
    assert power_on == bytes.fromhex(
        "02 80 17 00 90 4C 4D 53 32 30 30 3B 33 30 31 30 36 33 3B 56 30 32 2E 31 30 20 10 63 5E")


def test_device_side_receiver_reads_host_requests_through_garbage() -> None:
    rx = TelegramReceiver(address=HOST)
    wire = b"\x00\xff" + request(b"\x20\x24") + b"\x02\x00\xff\x7f" + request(b"\x30\x01")
    got = rx.feed(wire)
    assert [(t.command, t.data) for t in got] == [(0x20, b"\x24"), (0x30, b"\x01")]
    assert rx.bad_lengths == 1
    # A false header with a plausible length holds the request back only until its CRC fails.
    got = rx.feed(b"\x02\x00\x02" + request(b"\x31"))
    assert got == []
    got = rx.feed(bytes(520))
    assert [(t.command, t.data) for t in got] == [(0x31, b"")] and rx.crc_errors == 1
    assert request(b"\x30\x01") == bytes.fromhex("02 00 02 00 30 01 31 18")


def test_driver_rejects_impossible_settings() -> None:
    with pytest.raises(ValueError, match="variant"):
        SickLms2xx("loop://", angle=180, resolution=0.25)
    with pytest.raises(ValueError, match="baud"):
        SickLms2xx("loop://", baudrate=57600)
    with pytest.raises(ValueError, match="units"):
        SickLms2xx("loop://", units="inch")


def _run(driver: SickLms2xx, device: SickDevice, *, seconds: float,
         during=None) -> list:
    """Frames until the device has sent its run (plus a little) or ``seconds`` pass."""
    frames = []

    def watch() -> None:
        deadline = time.monotonic() + seconds
        if during is not None:
            during()
        while time.monotonic() < deadline and not device.finished.is_set():
            time.sleep(0.05)
        time.sleep(0.3)
        driver.close()

    threading.Thread(target=watch, daemon=True).start()
    for frame in driver.frames():
        frames.append(frame)
    return frames


def _check(frames: list, device: SickDevice) -> tuple[int, int, int]:
    """(intact scans sent, intact delivered, delivered that match no intact scan)."""
    intact = {s.values.tobytes() for s in device.sent if s.intact}
    delivered = 0
    foreign = 0
    for f in frames:
        raw = np.where(np.isfinite(f.ranges), np.round(f.ranges * 1000), 0x1FFF)
        if raw.astype(np.uint16).tobytes() in intact:
            delivered += 1
        else:
            foreign += 1
    return len(intact), delivered, foreign


@pytest.fixture(scope="module")
def office() -> object:
    return load_scenario("office")


@pytest.mark.parametrize("rate", [0.0, 0.001])
def test_full_session_delivers_intact_scans_and_never_a_corrupted_one(office, rate) -> None:
    source = ScanSource(office, SickDevice.sensor_model(), max_scans=150)
    with SickDevice(source, corruption=rate, seed=7, speed=5.0, units=0) as device:
        driver = SickLms2xx(device.port, baudrate=38400, units="mm", silence=0.5)
        frames = _run(driver, device, seconds=20.0)
        assert device.config[6] == 1  # the driver switched the units from cm to mm
        assert device.baud == 38400
    sent, delivered, foreign = _check(frames, device)
    assert len(device.sent) >= 140
    assert delivered >= 0.99 * sent
    assert foreign == 0  # a scan with a corrupted byte is never accepted
    assert all(f.num_beams == 181 and f.max_range == pytest.approx(8.19) for f in frames)
    stamps = [f.stamp for f in frames]
    assert stamps == sorted(stamps)
    if rate == 0.0:
        assert driver.stats.checksum_errors == 0 and sent == len(device.sent)
    else:
        assert driver.stats.checksum_errors > 0  # the corruption was there and was caught
        assert sent < len(device.sent)


def test_reconnects_after_a_power_cycle(office) -> None:
    source = ScanSource(office, SickDevice.sensor_model(), max_scans=300)
    marks: dict[str, float] = {}
    with SickDevice(source, speed=5.0) as device:
        driver = SickLms2xx(device.port, baudrate=38400, silence=0.3, backoff=0.05)

        def cycle() -> None:
            time.sleep(1.0)
            device.go_silent()
            time.sleep(0.8)
            marks["sent"] = len(device.sent)
            marks["time"] = time.time()
            device.power_on()  # back at 9600, request mode, the 0.5 degree variant

        frames = _run(driver, device, seconds=30.0, during=cycle)
    assert device.boots == 2
    assert driver.stats.timeouts >= 1 and driver.stats.reconnects >= 1
    after = [f for f in frames if f.stamp > marks["time"]]
    sent_after = len(device.sent) - marks["sent"]
    assert sent_after >= 10  # the driver brought the rebooted LMS back to streaming
    assert len(after) >= sent_after - 1  # and took every scan it streamed since
    assert all(f.num_beams == 181 for f in frames)  # the 1 degree variant was set again
