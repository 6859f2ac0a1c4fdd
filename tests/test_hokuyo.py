"""Hokuyo SCIP 2.0: the test vectors of ../shared/protocols.md section 3.6, the integrity checks,
the simulated URG-04LX, and driver sessions against it over a pty (clean, corrupted, power cycle).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import serial
from serial_support import Session

from drivers import scip2_protocol as scip
from drivers.devices.hokuyo_device import HokuyoDevice
from drivers.devices.pty_device import ScanSource
from drivers.hokuyo_scip2 import HokuyoScip2Driver
from drivers.scenario import load_scenario
from drivers.serial_scanner import DeviceError

H8 = b"GD0044004801\n00P\nm2@0?\n0CB1Dh00D0oo011F\n\n"
H9 = (b"0?X0@=0@b0AG0Al0BQ0C60C[0D@0De0EJ0Eo0FT0G90G^0HC0Hh0IM0J20JW0K<0I\n"
      b"Ka0LF0Lk0MPR\n")
H11 = b"MD0044004801002\n00P\n\n"
H12 = b"MD0044004801001\n99b\n00?Xg\n0CB1Dh00D0oo011F\n\n"
H13 = b"MD0044004801000\n99b\n00A<M\n0CH1DH00C0oo0160\n\n"
V12 = [1234, 5432, 20, 4095, 65]
V13 = [1240, 5400, 19, 4095, 70]
ECHOES = (b"MD0044004801002", b"MD0044004801001", b"MD0044004801000")


# -- test vectors ------------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "value", "text"), [
    ("H1", 1234, b"CB"), ("H2", 5432, b"1Dh"), ("H3", 16000000, b"m2@0"),
    ("H4", 4095, b"oo"), ("H4", 262143, b"ooo"),
])
def test_value_encoding_vectors(name, value, text):
    assert scip.encode(value, len(text)) == text
    assert scip.decode(text) == value


def test_encoding_is_vectorised_and_refuses_what_does_not_fit():
    v = np.array([0, 1, 63, 64, 4095, 5432, 262143])
    assert np.array_equal(scip.decode_values(scip.encode_values(v, 3), 3), v)
    with pytest.raises(ValueError):
        scip.encode(4096, 2)
    with pytest.raises(ValueError):
        scip.encode(-1, 3)


def test_h5_status_sums():
    assert scip.scip_sum(b"00") == b"P" and scip.scip_sum(b"99") == b"b"
    assert scip.status_line(b"00") == b"00P\n" and scip.status_line(b"99") == b"99b\n"
    assert scip.check_status(b"00P") == b"00"
    with pytest.raises(scip.ChecksumError):
        scip.check_status(b"00Q")


H6 = {"DMIN:20;4": ("DMIN", "20"), "DMAX:5600;_": ("DMAX", "5600"), "AMIN:44;7": ("AMIN", "44"),
      "AMAX:725;o": ("AMAX", "725"), "AFRT:384;6": ("AFRT", "384"), "SCAN:600;e": ("SCAN", "600"),
      "ARES:1024;\\": ("ARES", "1024")}


@pytest.mark.parametrize("line", sorted(H6))
def test_h6_info_lines(line):
    key, value = H6[line]
    assert scip.parse_info_line(line.encode()) == (key, value)
    assert scip.info_line(key, value) == line.encode() + b"\n"


def test_info_line_sum_with_semicolon_accepted_and_bad_sum_refused():
    body = b"DMIN:20"
    assert scip.parse_info_line(body + b";" + scip.scip_sum(body + b";")) == ("DMIN", "20")
    with pytest.raises(scip.ChecksumError):
        scip.parse_info_line(b"DMIN:21;4")
    with pytest.raises(scip.FramingError):
        scip.parse_info_line(b"DMIN20;4")


def test_h7_ms_data_line():
    assert scip.data_lines(scip.encode_values([1234, 4095], 2)) == b"CBooS\n"
    chars = scip.check_data_lines([b"CBooS"], 4)
    assert scip.decode_values(chars, 2).tolist() == [1234, 4095]


def test_h8_gd_reply():
    assert scip.scan_reply(b"GD0044004801", b"00", 16000000, V12, 3) == H8
    (rep,) = scip.ReplyParser((b"GD0044004801",)).feed(H8)
    stamp, values = scip.check_scan(rep, echo=b"GD0044004801", status=b"00", values=5, width=3)
    assert stamp == 16000000 and values.tolist() == V12


def test_h9_value_split_across_lines():
    values = list(range(1000, 1889, 37))
    assert len(values) == 25 and values[21] == 1777  # the 22nd value
    assert scip.data_lines(scip.encode_values(values, 3)) == H9
    lines = H9.split(b"\n")[:2]
    assert lines[0][-2:-1] == b"0" and lines[1].startswith(b"Ka")  # 1777 = "0Ka", split
    chars = scip.check_data_lines(lines, 75)
    assert scip.decode_values(chars, 3).tolist() == values


def test_h10_to_h13_md_request_acknowledgement_and_scans():
    assert scip.md_request(44, 48, 1, 0, 2) == b"MD0044004801002\n"
    assert scip.reply(b"MD0044004801002", b"00") == H11
    assert scip.scan_reply(b"MD0044004801001", b"99", 1000, V12, 3) == H12
    assert scip.scan_reply(b"MD0044004801000", b"99", 1100, V13, 3) == H13
    parser = scip.ReplyParser(ECHOES)
    ack, s1, s2 = parser.feed(H11 + H12 + H13)
    assert (ack.echo, ack.status, ack.lines, ack.complete) == (ECHOES[0], b"00P", (), True)
    assert scip.check_scan(s1, echo=ECHOES[1], status=b"99", values=5, width=3)[0] == 1000
    t2, v2 = scip.check_scan(s2, echo=ECHOES[2], status=b"99", values=5, width=3)
    assert t2 == 1100 and v2.tolist() == V13
    assert parser.skipped_bytes == 0


def test_h14_simple_requests():
    assert scip.gd_request(44, 725) == b"GD0044072501\n"
    assert scip.md_request(44, 725, 1, tag="ab") == b"MD0044072501000;ab\n"
    for bad in ((10, 5, 1), (0, 10000, 1), (0, 10, 100)):
        with pytest.raises(ValueError):
            scip.gd_request(*bad)


# -- integrity -----------------------------------------------------------------------------------
def _scan1(data: bytes) -> tuple[int, list[int]]:
    reps = [r for r in scip.ReplyParser(ECHOES).feed(data) if r.echo == ECHOES[1]]
    assert len(reps) == 1
    stamp, values = scip.check_scan(reps[0], echo=ECHOES[1], status=b"99", values=5, width=3)
    return stamp, values.tolist()


def _flip(data: bytes, pos: int, bit: int) -> bytes:
    b = bytearray(data)
    b[pos] ^= 1 << bit
    return bytes(b)


DATA_AT = H12.index(b"0CB1Dh")


def test_bad_sum_is_a_checksum_error():
    with pytest.raises(scip.ChecksumError):
        _scan1(_flip(H12, DATA_AT + 2, 0))
    with pytest.raises(scip.ChecksumError):
        _scan1(_flip(H12, H12.index(b"00?Xg") + 1, 1))  # time line


@pytest.mark.parametrize("bit", [6, 7])
def test_flips_the_sum_cannot_see_are_framing_errors(bit):
    bad = _flip(H12, DATA_AT + 1, bit)  # 'C' -> 0x03 or 0xC3
    line = bad[DATA_AT:bad.index(b"\n", DATA_AT)]
    assert scip.scip_sum(line[:-1]) == line[-1:]  # the 6-bit sum still matches
    with pytest.raises(scip.FramingError, match=r"0x30\.\.0x6F"):
        _scan1(bad)


@pytest.mark.parametrize(("what", "data"), [
    ("dropped character", H12[:DATA_AT + 3] + H12[DATA_AT + 4:]),
    ("inserted character", H12[:DATA_AT + 3] + b"0" + H12[DATA_AT + 3:]),
    ("short scan with good sums", scip.scan_reply(ECHOES[1], b"99", 1000, V12[:4], 3)),
    ("long scan with good sums", scip.scan_reply(ECHOES[1], b"99", 1000, V12 + [7], 3)),
    ("lost empty line", H12[:-1] + H13),
    ("lost time line", H12.replace(b"00?Xg\n", b"")),
])
def test_wrong_lengths_and_structure_are_framing_errors(what, data):
    with pytest.raises(scip.FramingError):
        _scan1(data)


def test_line_lengths_checked_even_when_the_total_is_right():
    chars = scip.encode_values(np.arange(1000, 1050), 3)  # 150 characters: 64 + 64 + 22
    lines = [chars[:63], chars[63:128], chars[128:]]  # 63 + 65 + 22: same total
    with pytest.raises(scip.FramingError):
        scip.check_data_lines([x + scip.scip_sum(x) for x in lines], 150)


def test_a_status_other_than_99_is_a_status_error():
    with pytest.raises(scip.StatusError):
        _scan1(H12.replace(b"99b", b"00P"))


def test_every_single_bit_flip_and_drop_of_a_scan_is_refused_and_the_next_one_survives():
    # continuous MD (count 00) as the driver streams it: every echo is the request itself, so a
    # changed echo (it carries no sum) is refused as well
    echo = b"MD0044004801000"
    s1 = scip.scan_reply(echo, b"99", 1000, V12, 3)
    s2 = scip.scan_reply(echo, b"99", 1100, V13, 3)
    for pos in range(len(s1)):
        variants = [_flip(s1, pos, bit) for bit in range(8)] + [s1[:pos] + s1[pos + 1:]]
        for bad in variants:
            decoded = []
            for rep in scip.ReplyParser((echo,)).feed(bad + s2):
                try:
                    decoded.append(scip.check_scan(rep, echo=echo, status=b"99", values=5,
                                                   width=3)[1].tolist())
                except scip.ScipError:
                    pass
            assert decoded == [V13], (pos, bad)


def test_parser_resynchronises_after_garbage_fed_one_byte_at_a_time():
    stream = (b"\x00junk\nmore junk 99b\n\n" + b"\xffxx" + H12 + b"MD00440048\n" + b"z" * 600
              + H13)
    parser = scip.ReplyParser(ECHOES)
    reps = []
    for i in range(len(stream)):
        reps += parser.feed(stream[i:i + 1])
    good = [r for r in reps if r.complete]
    assert [r.echo for r in good] == [ECHOES[1], ECHOES[2]]
    assert scip.check_scan(good[1], echo=ECHOES[2], status=b"99", values=5, width=3)[1].tolist() \
        == V13
    assert parser.skipped_bytes >= 600 + 25 and parser.garbage_runs >= 2


def test_parser_without_echoes_takes_any_reply_and_cuts_endless_lines():
    parser = scip.ReplyParser(max_line=100)
    reps = parser.feed(b"QT\n00P\n\n" + H8 + b"x" * 300)
    assert [(r.echo, r.status, len(r.lines)) for r in reps] == [(b"QT", b"00P", 0),
                                                                 (b"GD0044004801", b"00P", 2)]
    assert parser.skipped_bytes > 0 and len(parser._buf) <= 100


# -- the simulated device over its pty -----------------------------------------------------------
def _source(n: int, seed: int = 1) -> ScanSource:
    return ScanSource(load_scenario("office"), HokuyoDevice.sensor_model(), seed=seed, max_scans=n)


def _ask(ser: serial.Serial, line: bytes, replies: int = 1, timeout: float = 2.0) -> list[bytes]:
    """Send one command and read ``replies`` replies (each ends with an empty line)."""
    ser.write(line + b"\n")
    got = b""
    deadline = time.monotonic() + timeout
    while got.count(b"\n\n") < replies:
        assert time.monotonic() < deadline, f"no complete reply to {line!r}: {got!r}"
        got += ser.read(max(1, ser.in_waiting))
    parts = got.split(b"\n\n")
    return [p + b"\n\n" for p in parts[:replies]]


def _status(rep: bytes) -> bytes:
    return scip.check_status(rep.split(b"\n")[1])


def test_device_answers_its_commands():
    with HokuyoDevice(_source(20), speed=5.0) as dev, \
            serial.serial_for_url(dev.port, timeout=0.05) as ser:
        for line in (b"SCIP2.0", b"VV", b"PP", b"II", b"BM", b"QT", b"RS", b"XX", b"TM1"):
            (rep,) = _ask(ser, line)
            assert rep.startswith(line + b"\n")
        assert _status(_ask(ser, b"SCIP2.0")[0]) == b"0E"  # already SCIP 2.0
        assert _status(_ask(ser, b"XX")[0]) == b"0E"  # unknown command
        (pp,) = scip.ReplyParser((b"PP",)).feed(_ask(ser, b"PP")[0])
        info = scip.parse_info(pp, b"PP")
        assert {k: info[k] for k in ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN")} \
            == {"DMIN": "20", "DMAX": "5600", "ARES": "1024", "AMIN": "44", "AMAX": "725",
                "AFRT": "384", "SCAN": "600"}
        (vv,) = scip.ReplyParser((b"VV",)).feed(_ask(ser, b"VV")[0])
        assert scip.parse_info(vv, b"VV")["PROT"] == "SCIP 2.0"
        # GD needs the laser: status 10 while it is off, a scan after BM, 02 for a second BM
        assert _status(_ask(ser, b"GD0044072501")[0]) == b"10"
        assert _status(_ask(ser, b"BM")[0]) == b"00" and _status(_ask(ser, b"BM")[0]) == b"02"
        (gd,) = _ask(ser, b"GD0044072501")
        (rep,) = scip.ReplyParser((b"GD0044072501",)).feed(gd)
        _, values = scip.check_scan(rep, echo=b"GD0044072501", status=b"00", values=682, width=3)
        assert np.array_equal(values, dev.sent[-1].values)
        assert _status(_ask(ser, b"GD0044080001")[0]) == b"04"  # beyond AMAX
        for tm, status in ((b"TM0", b"00"), (b"TM1", b"00"), (b"TM2", b"00"), (b"TM2", b"03")):
            assert _status(_ask(ser, tm)[0]) == status
        assert _status(_ask(ser, b"QT")[0]) == b"00" and not dev.laser_on


def test_device_md_with_a_count_sends_ack_then_counted_scans_then_stops():
    with HokuyoDevice(_source(40), speed=10.0) as dev, \
            serial.serial_for_url(dev.port, timeout=0.05) as ser:
        ack, s1, s2 = _ask(ser, b"MD0044004801002", replies=3)
        assert ack == H11
        parser = scip.ReplyParser(ECHOES)
        (r1,) = parser.feed(s1)
        (r2,) = parser.feed(s2)
        t1, v1 = scip.check_scan(r1, echo=ECHOES[1], status=b"99", values=5, width=3)
        t2, v2 = scip.check_scan(r2, echo=ECHOES[2], status=b"99", values=5, width=3)
        assert [v1.tolist(), v2.tolist()] == [s.values.tolist() for s in dev.sent]
        assert 0 < t2 - t1 < 1000
        time.sleep(0.1)
        assert ser.read(4096) == b"" and dev.stream is None
        # skip 1: every other scan of the device clock
        ack, s1, s2 = _ask(ser, b"MD0044004801102", replies=3)
        assert ack == b"MD0044004801102\n00P\n\n" and s2.startswith(b"MD0044004801100\n")
        assert dev.sent[-1].seq - dev.sent[-2].seq == 2


def test_device_clusters_keep_the_nearest_valid_range():
    with HokuyoDevice(_source(20)) as dev:
        full = dev.values(3, 44, 725, 1, 3)
        grouped = dev.values(3, 44, 725, 4, 3)
    assert grouped.size == math.ceil(682 / 4)
    valid = np.where(full >= 20, full, 10**9)
    want = np.concatenate([valid, np.full(-682 % 4, 10**9)]).reshape(-1, 4).min(axis=1)
    assert np.array_equal(grouped, np.where(want == 10**9, 0, want))


# -- driver sessions ---------------------------------------------------------------------------
def _expected(values: np.ndarray) -> np.ndarray:
    return np.where((values >= 20) & (values <= 5600), values / 1000.0, np.inf)


def _match(dev: HokuyoDevice, frames: list) -> tuple[int, int, int]:
    """(intact scans sent, intact scans delivered, delivered scans that match no intact one)."""
    intact = {_expected(s.values).tobytes(): s.seq for s in dev.sent if s.intact}
    got = [f.ranges.tobytes() for f in frames]
    delivered = {intact[g] for g in got if g in intact}
    return len(intact), len(delivered), sum(g not in intact for g in got)


@pytest.mark.parametrize(("rate", "scans"), [(0.0, 120), (0.001, 300)])
def test_session_delivers_intact_scans_exactly_and_never_a_corrupted_one(rate, scans):
    with HokuyoDevice(_source(scans), corruption=rate, seed=3, speed=10.0) as dev:
        session = Session(HokuyoScip2Driver(dev.port, silence=1.0))
        session.wait(dev.finished.is_set, 15.0, "the end of the scenario run")
        time.sleep(0.2)
        session.stop()
    drv = session.driver
    lay = drv.geometry
    assert lay is not None and lay.num_beams == 682 and lay.max_range == 5.6
    assert lay.angle_min == pytest.approx((44 - 384) * 2 * math.pi / 1024)
    assert lay.angle_increment == pytest.approx(2 * math.pi / 1024)
    assert drv.params["DMAX"] == 5600
    intact, delivered, foreign = _match(dev, session.frames)
    assert dev.bytes_dropped == 0
    assert intact >= (0.8 * scans if rate == 0 else 20)
    assert delivered >= 0.99 * intact, drv.stats.summary()
    assert foreign == 0
    assert drv.stats.scans == len(session.frames)
    if rate == 0:
        assert drv.stats.errors() == 0 and drv.stats.skipped_bytes == 0
        assert drv.version["PROD"] == "URG-04LX"
    else:
        corrupted = len(dev.sent) - intact
        assert drv.stats.checksum_errors > 0 and drv.stats.framing_errors > 0
        assert drv.stats.errors() >= 0.9 * corrupted
    print(f"\nrate {rate}: {delivered}/{intact} intact scans delivered, {foreign} foreign; "
          f"{drv.stats.summary()}")


def test_session_with_a_step_range_and_clusters():
    with HokuyoDevice(_source(30), speed=10.0) as dev:
        session = Session(HokuyoScip2Driver(dev.port, first_step=100, last_step=400, cluster=3))
        session.wait(lambda: len(session.frames) >= 10, 5.0, "10 scans")
        session.stop()
    assert dev.commands[dev.commands.index(b"PP") + 1:].count(b"MD0100040003000") == 1
    lay = session.driver.geometry
    assert lay is not None and lay.num_beams == 101 and session.frames[0].ranges.size == 101
    assert lay.angle_min == pytest.approx((100 - 384) * 2 * math.pi / 1024)
    assert lay.angle_increment == pytest.approx(3 * 2 * math.pi / 1024)
    _, delivered, foreign = _match(dev, session.frames)
    assert delivered == len(session.frames) and foreign == 0


def test_reconnects_after_the_device_falls_silent_and_comes_back_power_cycled():
    # A long run (scans are ray-cast lazily) and generous deadlines: a loaded machine may
    # take seconds to notice the silence, and the device clock runs on meanwhile.
    with HokuyoDevice(_source(3000), speed=10.0) as dev:
        drv = HokuyoScip2Driver(dev.port, silence=0.3, backoff=0.05, backoff_max=0.2,
                                reply_timeout=0.15)
        session = Session(drv)
        session.wait(lambda: len(session.frames) >= 10, 20.0, "the first scans")
        dev.go_silent()
        session.wait(lambda: drv.stats.timeouts >= 1, 10.0, "the silence to be noticed")
        session.wait(lambda: drv.stats.failed_connects >= 1, 10.0, "an attempt while it is off")
        before, md_before = len(session.frames), dev.commands.count(b"MD0044072501000")
        dev.power_on()  # boots with the laser off and nothing streaming
        session.wait(lambda: len(session.frames) >= before + 10, 20.0, "scans after power-on")
        session.stop()
    assert drv.stats.timeouts >= 1 and drv.stats.reconnects >= 1
    assert drv.stats.failed_connects >= 1  # attempts while it was off
    assert dev.commands.count(b"MD0044072501000") > md_before  # streaming was restarted
    _, delivered, foreign = _match(dev, session.frames)
    assert foreign == 0 and delivered == len(session.frames)


def test_connects_to_a_device_left_streaming_by_an_earlier_session():
    with HokuyoDevice(_source(200), speed=10.0) as dev, \
            serial.serial_for_url(dev.port, timeout=0.05) as ser:
        _ask(ser, b"MD0044072501000", replies=2)  # streaming; nobody reads any more
        session = Session(HokuyoScip2Driver(dev.port))
        session.wait(lambda: len(session.frames) >= 5, 5.0, "scans")
        session.stop()
    assert session.driver.stats.errors() == 0
    assert _match(dev, session.frames)[2] == 0


def test_connect_to_a_silent_device_fails_with_a_clear_error():
    with HokuyoDevice(_source(10)) as dev:
        dev.go_silent()
        drv = HokuyoScip2Driver(dev.port, reply_timeout=0.1)
        drv.open_port()
        try:
            with pytest.raises(DeviceError, match="no answer to QT"):
                drv.connect()
        finally:
            assert drv.ser is not None
            drv.ser.close()
