"""Serial-link integrity of the three simulated laser scanners under byte corruption.

Run: python bench/serial_integrity.py [--scans 1400] [--quick]

For each scanner (SICK LMS 2xx, RPLIDAR A1, Hokuyo URG-04LX) and each corruption rate, the
driver runs against its simulated device on a pty (scenario "office", device clock sped up)
and every delivered frame is matched by value to the scans the device sent, as the driver
tests do. A cell reports the scans sent, those that left the device intact, the intact ones
delivered exactly, the frames that match no sent scan (accepted with wrong values, and how
many beams differ from the nearest sent scan), the driver's error counters and the wall time.
A cell is split into sessions of at most --session scans, session i with corruption seed i.
In every session the device is power-cycled once (--off seconds of device time without power,
then a reboot) when --cycle-at of its scans have been sent; --off 0 leaves the power on.
The devices run as the real ones do: the LMS on a line paced at its baud rate, which comes
back at 9600 baud after its boot; the RPLIDAR streaming its nodes continuously with parallax-
corrected angles and a varying node count; the URG-04LX coming back in SCIP 1.1.
--quick runs a few hundred scans per cell and only prints (add --write to keep its figures).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from report import machine, write_section

from drivers.devices.pty_device import Corruption, PtyDevice, SentScan
from drivers.scanners import open_scanner, simulated_scanner
from drivers.scenario import load_scenario
from vmp.types import ScanFrame

SCANNERS = ("sick", "rplidar", "hokuyo")
TITLES = {"sick": "SICK LMS 2xx", "rplidar": "RPLIDAR A1", "hokuyo": "Hokuyo URG-04LX"}
CHECKS = {"sick": "CRC-16 per telegram", "rplidar": "check bit, inverted start flag, turn checks",
          "hokuyo": "6-bit sum per line, character range, line length"}
# the driver options: a silence of 0.2 s of wall time is 2 s of the sped-up device clock
DRIVER_OPTIONS = {"sick": {"baudrate": 38400, "units": "mm", "silence": 0.2},
                  "rplidar": {"silence": 0.2}, "hokuyo": {"silence": 0.2}}
RATES = (0.0, 1e-4, 1e-3, 3e-3)
# a hit byte: one bit flipped, dropped, an 8-byte burst of noise, or a byte added before it
MIX = {"flip": 0.5, "drop": 0.15, "burst": 0.2, "insert": 0.15}
# the devices as the real ones behave (see the module notes)
DEVICE_OPTIONS = {"sick": {"paced": True}, "rplidar": {}, "hokuyo": {"scip1_on_boot": True}}


# -- matching frames to sent scans, in the units each driver test compares -------------------
def frame_key(name: str, frame: ScanFrame) -> np.ndarray:
    """A delivered frame in the units its device recorded (Hokuyo: the expected ranges)."""
    r = frame.ranges
    if name == "sick":  # tests/test_sick_lms2xx.py: mm, no return = 0x1FFF
        return np.where(np.isfinite(r), np.round(r * 1000), 0x1FFF).astype(np.uint16)
    if name == "rplidar":  # tests/test_rplidar.py: distance_q2, no return = 0
        return np.where(np.isfinite(r), np.rint(r * 4000), 0).astype(np.uint16)
    return np.asarray(r, dtype=np.float64)  # tests/test_hokuyo.py compares ranges


def sent_key(name: str, scan: SentScan) -> np.ndarray:
    """A sent scan as :func:`frame_key` gives a frame delivered exactly."""
    v = scan.values
    if name == "hokuyo":  # tests/test_hokuyo.py: DMIN 20 .. DMAX 5600 mm, else no return
        return np.where((v >= 20) & (v <= 5600), v / 1000.0, np.inf)
    return np.asarray(v, dtype=np.uint16)


@dataclass
class Cell:
    """The figures of one scanner at one corruption rate, summed over its sessions."""

    name: str
    rate: float
    sessions: int = 0
    sent: int = 0
    intact: int = 0  # left the device intact
    intact_exact: int = 0  # of those, delivered exactly
    frames: int = 0
    corrupted_exact: int = 0  # corrupted in transit, yet delivered with the sent values
    wrong: int = 0  # delivered frames that match no sent scan
    wrong_beams: list[int] = field(default_factory=list)  # per wrong frame, vs nearest sent
    wrong_near_intact: int = 0  # wrong frames whose nearest sent scan left intact
    lost: list[tuple[int, int]] = field(default_factory=list)  # (session, place) intact, lost
    checksum: int = 0
    framing: int = 0
    rejected: int = 0
    timeouts: int = 0
    stalls: int = 0
    reconnects: int = 0
    power_cycles: int = 0
    bytes_dropped: int = 0  # the driver did not keep up
    wall: float = 0.0
    reasons: dict[str, int] = field(default_factory=dict)

    @property
    def share(self) -> float:
        return self.intact_exact / self.intact if self.intact else float("nan")


def tally(cell: Cell, dev: PtyDevice, frames: list[ScanFrame]) -> None:
    """Match ``frames`` to ``dev.sent`` by value and add the counts to ``cell``."""
    name = cell.name
    sent = dev.sent
    by_value = {sent_key(name, s).tobytes(): s for s in sent}
    counted = sent
    intact = {s.seq for s in counted if s.intact}
    corrupted = {s.seq for s in sent if not s.intact}
    exact: set[int] = set()
    wrong = []
    for f in frames:
        key = frame_key(name, f)
        s = by_value.get(key.tobytes())
        if s is None:
            wrong.append(key)
        else:
            exact.add(s.seq)
    if wrong and sent:
        table = np.stack([sent_key(name, s) for s in sent])
        for key in wrong:
            if key.shape != table.shape[1:]:
                cell.wrong_beams.append(int(key.size))
                continue
            diff = (table != key).sum(axis=1)
            nearest = int(np.argmin(diff))
            cell.wrong_beams.append(int(diff[nearest]))
            cell.wrong_near_intact += sent[nearest].intact
    cell.lost += [(cell.sessions + 1, i) for i, s in enumerate(counted)
                  if s.intact and s.seq not in exact]
    cell.sessions += 1
    cell.sent += len(sent)
    cell.intact += len(intact)
    cell.intact_exact += len(intact & exact)
    cell.corrupted_exact += len(corrupted & exact)
    cell.frames += len(frames)
    cell.wrong += len(wrong)


def session(cell: Cell, scans: int, speed: float, seed: int, scenario, off: float = 3.0,
            cycle_at: float = 0.5) -> None:
    """One driver session against a fresh simulated device until its run is sent, with the
    device's power off for ``off`` device seconds once ``cycle_at`` of the run is sent."""
    dev = simulated_scanner(cell.name, scenario, speed=speed,
                            corruption=Corruption(rate=cell.rate, **MIX), seed=seed,
                            max_scans=scans, **DEVICE_OPTIONS[cell.name])
    frames: list[ScanFrame] = []
    crash: list[BaseException] = []
    t0 = time.perf_counter()
    with dev:
        drv = open_scanner(cell.name, dev.port, **DRIVER_OPTIONS[cell.name])

        def collect() -> None:
            try:
                frames.extend(drv.frames())
            except BaseException as exc:  # reported below
                crash.append(exc)

        reader = threading.Thread(target=collect, name=f"{cell.name}-bench", daemon=True)
        reader.start()
        assert dev.source is not None
        limit = len(dev.source) * dev.source.period / speed * 2 + 20.0 + off / speed
        deadline = time.monotonic() + limit
        if off > 0:
            while (len(dev.sent) < cycle_at * len(dev.source) and not dev.finished.is_set()
                   and time.monotonic() < deadline and reader.is_alive()):
                time.sleep(0.01)
            dev.go_silent()
            time.sleep(off / speed)
            dev.power_on()
            cell.power_cycles += 1
        dev.finished.wait(max(0.0, deadline - time.monotonic()))
        time.sleep(0.3)  # the last scans in flight
        drv.close()
        reader.join(timeout=5.0)
    cell.wall += time.perf_counter() - t0
    if crash:
        raise RuntimeError(f"{cell.name} driver crashed at rate {cell.rate:g}") from crash[0]
    if reader.is_alive():
        raise RuntimeError(f"{cell.name} driver did not stop at rate {cell.rate:g}")
    if not dev.finished.is_set():
        print(f"  warning: {cell.name} device did not finish its run within {limit:.0f} s")
    st = drv.stats
    cell.checksum += st.checksum_errors
    cell.framing += st.framing_errors
    cell.rejected += st.rejected
    cell.timeouts += st.timeouts
    cell.stalls += st.stalls
    cell.reconnects += st.reconnects
    cell.bytes_dropped += dev.bytes_dropped
    for k, v in getattr(drv, "reject_reasons", {}).items():
        cell.reasons[k] = cell.reasons.get(k, 0) + v
    tally(cell, dev, frames)


def run_cell(name: str, rate: float, scans: int, per_session: int, speed: float,
             scenario, off: float = 3.0, cycle_at: float = 0.5) -> Cell:
    cell = Cell(name, rate)
    left, seed = scans, 1
    while left > 0:
        n = min(left, per_session)
        session(cell, n, speed, seed, scenario, off, cycle_at)
        left -= n
        seed += 1
    return cell


# -- the report -------------------------------------------------------------------------------
def fmt_rate(rate: float) -> str:
    return "0" if rate == 0 else f"{rate:.0e}".replace("e-0", "e-")


def beams_text(c: Cell) -> str:
    if not c.wrong:
        return "-"
    b = c.wrong_beams
    return f"{sum(b)} ({min(b)}-{max(b)})"


def table(cells: list[Cell]) -> list[str]:
    lines = ["| scanner | rate | sent | left intact | intact delivered exactly "
             "| corrupted, delivered exactly | wrong scans delivered | wrong beams (per scan) "
             "| checksum / framing / rejected | power cycles / silences / stalls / reconnects "
             "| wall s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cells:
        lines.append(
            f"| {TITLES[c.name]} | {fmt_rate(c.rate)} | {c.sent} | {c.intact} "
            f"| {c.intact_exact} ({'-' if not c.intact else f'{c.share:.1%}'}) "
            f"| {c.corrupted_exact} | {c.wrong} "
            f"| {beams_text(c)} | {c.checksum} / {c.framing} / {c.rejected} "
            f"| {c.power_cycles} / {c.timeouts} / {c.stalls} / {c.reconnects} "
            f"| {c.wall:.1f} |")
    return lines


def findings(cells: list[Cell]) -> list[str]:
    """Sentences that state only what the cells measured (one per scanner, one on intact)."""
    out = []
    for name in SCANNERS:
        mine = [c for c in cells if c.name == name and c.rate > 0]
        if not mine:
            continue
        per_rate = ", ".join(f"{c.wrong} of {c.sent - c.intact} at {fmt_rate(c.rate)}"
                             for c in mine)
        text = (f"{TITLES[name]} ({CHECKS[name]}): frames delivered with wrong values, "
                f"against scans corrupted on the wire: {per_rate}")
        beams = [b for c in mine for b in c.wrong_beams]
        if beams:
            text += (f"; each wrong frame differed from the nearest sent scan in "
                     f"{min(beams)} to {max(beams)} beams")
        exact = sum(c.corrupted_exact for c in mine)
        if exact:
            text += f"; {exact} corrupted scans arrived with their values unchanged"
        out.append(text + ".")
    counted = [c for c in cells if c.intact]
    if counted:
        worst = min(counted, key=lambda c: c.share)
        if worst.share == 1.0:
            out.append("Every scan that left a device intact was delivered exactly.")
        else:
            out.append(f"Intact scans delivered exactly: lowest share {worst.share:.1%} "
                       f"({TITLES[worst.name]} at {fmt_rate(worst.rate)}).")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scans", type=int, default=None,
                    help="scans per cell, the power cuts included (default 1400; 200 with "
                         "--quick)")
    ap.add_argument("--quick", action="store_true",
                    help="smoke check: 200 scans per cell, printed, docs left alone")
    ap.add_argument("--write", action="store_true",
                    help="with --quick: write the figures to docs/benchmarks.md all the same")
    ap.add_argument("--session", type=int, default=700,
                    help="scans per session at most (default 700)")
    ap.add_argument("--speed", type=float, default=10.0,
                    help="device clock speed-up (default 10)")
    ap.add_argument("--rates", type=float, nargs="+", default=list(RATES),
                    help="byte corruption rates (default 0 1e-4 1e-3 3e-3)")
    ap.add_argument("--scanners", nargs="+", choices=SCANNERS, default=list(SCANNERS))
    ap.add_argument("--off", type=float, default=3.0,
                    help="device seconds without power in each session (default 3; 0: none)")
    ap.add_argument("--cycle-at", type=float, default=0.5,
                    help="share of a session's scans sent before its power cycle (default 0.5)")
    args = ap.parse_args()
    scans = args.scans if args.scans is not None else (200 if args.quick else 1400)
    if scans < 1 or args.session < 1:
        ap.error("--scans and --session must be positive")
    if args.off < 0 or not 0 <= args.cycle_at <= 1:
        ap.error("--off must be >= 0 and --cycle-at within 0..1")
    scenario = load_scenario("office")
    cells = []
    t0 = time.perf_counter()
    for name in args.scanners:
        for rate in args.rates:
            c = run_cell(name, rate, scans, args.session, args.speed, scenario, args.off,
                         args.cycle_at)
            cells.append(c)
            print(f"{name:8s} rate {fmt_rate(c.rate):5s}: {c.intact_exact}/{c.intact} intact "
                  f"delivered exactly, {c.wrong} wrong of {c.frames} frames "
                  f"(beams {c.wrong_beams}), {c.corrupted_exact} corrupted exact; "
                  f"errors {c.checksum}/{c.framing}/{c.rejected}, "
                  f"{c.power_cycles} power cycles, {c.timeouts} silences, {c.stalls} stalls, "
                  f"{c.reconnects} reconnects, "
                  f"{c.bytes_dropped} bytes dropped, {c.wall:.1f} s"
                  + (f"; rejected turns {c.reasons}" if c.reasons else "")
                  + (f"; {c.wrong_near_intact} wrong frames nearest an intact scan"
                     if c.wrong_near_intact else "")
                  + (f"; intact scans lost (session, place in it): {c.lost}"
                     if c.lost else ""), flush=True)
    total = time.perf_counter() - t0
    rows = table(cells)
    notes = findings(cells)
    print()
    print("\n".join(rows))
    print()
    print("\n".join(notes))
    print(f"\ntotal wall time {total:.0f} s")
    if any(c.bytes_dropped for c in cells):
        print("warning: a device dropped bytes (the driver did not keep up); lower --speed")
    if args.quick and not args.write:
        print("--quick: docs/benchmarks.md left alone")
        return
    cmd = "python bench/serial_integrity.py" + ("" if args.scans is None and not args.quick
                                                 else f" --scans {scans}")
    if args.speed != 10.0:
        cmd += f" --speed {args.speed:g}"
    if args.session != 700:
        cmd += f" --session {args.session}"
    if list(args.rates) != list(RATES):
        cmd += " --rates " + " ".join(fmt_rate(r) for r in args.rates)
    if list(args.scanners) != list(SCANNERS):
        cmd += " --scanners " + " ".join(args.scanners)
    if args.off != 3.0:
        cmd += f" --off {args.off:g}"
    if args.cycle_at != 0.5:
        cmd += f" --cycle-at {args.cycle_at:g}"
    sessions = -(-scans // args.session)
    lines = [
        "## Serial-link integrity of the scanner drivers",
        "",
        f"`{cmd}` on {machine()}; {total:.0f} s in all.",
        f"Each driver against its simulated device on a pty, scenario office, device clock "
        f"x{args.speed:g}, {scans} scans per cell in {sessions} session(s) (corruption seeds "
        f"1..{sessions}). Each byte the device sends is hit with the given probability "
        "(50 % one bit flipped, 15 % dropped, 15 % a random byte added before it, 20 % an "
        "8-byte random burst, which runs on into the next telegram). "
        + (f"In every session the device's power goes off for {args.off:g} s of device time "
           f"once {args.cycle_at:.0%} of its scans are sent; it comes back as after a reboot "
           "(the LMS at 9600 baud in request mode, the RPLIDAR idle after its banner, the "
           "URG-04LX in SCIP 1.1), and the driver has to find it silent and connect again. "
           if args.off > 0 else "")
        + "The devices behave as the real ones: the LMS line is paced at its baud rate, so the "
        "power cut truncates a telegram; the RPLIDAR streams its nodes continuously, starts "
        "mid-revolution, corrects its angles for parallax (near points can be reported behind "
        "far ones) and varies its node count by 1 %. Delivered frames "
        "are matched by value to the scans the device sent, as the driver tests do. "
        "*Left intact*: scans none of whose bytes was hit (a scan cut by the power cut or a "
        "STOP is not intact). *Wrong scans delivered*: frames equal to no sent "
        "scan; *wrong beams*: beams that differ from the nearest sent scan, in all (smallest - "
        "largest per scan). Error counters are the driver's `stats`; they count events, not "
        "scans. *Silences*: the device sent no byte for the driver's `silence`; *stalls*: "
        "bytes but no scan for its `stall`.",
        "",
        *rows,
        "",
        " ".join(notes),
    ]
    write_section("serial_integrity", "\n".join(lines))
    print("written to docs/benchmarks.md")


if __name__ == "__main__":
    main()
