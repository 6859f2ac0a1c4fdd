"""``vmp live``: map as scans arrive from a serial laser scanner (or a simulated one)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vmp.cli.args import positive_float, positive_int
from vmp.cli.common import add_run_options, map_and_write, mapping_config
from vmp.errors import InputError
from vmp.folders import new_results_dir, remove_if_empty

__all__ = ["add_live_options", "add_parser", "open_live_source", "run"]

EPILOG = """\
examples:
  vmp live --driver sick --simulate office            # a simulated LMS on a pty, no hardware
  vmp live --driver hokuyo --simulate lab --speed 4   # simulated device clock 4x real time
  vmp live --driver rplidar --port /dev/ttyUSB0       # a real RPLIDAR A1/A2
  vmp live --driver sick --port /dev/ttyUSB0 --baud 38400 --odometry /dev/ttyACM1

Odometry: --odometry names a JSON-lines pose feed (serial port, named pipe or file) with one
{"x": .., "y": .., "theta": ..} per line in metres and radians; without it the run maps by
scan registration alone (with --simulate a simulated feed is used unless --no-odometry).
Every scan is recorded to live.clf in the results folder: 'vmp map' on that log reproduces
the run bit for bit. Ctrl-C or SIGTERM end the run and write everything.
"""


def add_parser(sub: argparse._SubParsersAction) -> None:
    lv = sub.add_parser(
        "live", help="map live from a serial laser scanner (SICK LMS 2xx, RPLIDAR, Hokuyo)",
        description="Map as scans arrive from a serial laser scanner, or from a simulated one "
        "served on a pseudo-terminal. Shows scans, rate and link errors while it runs and "
        "writes the same results folder as 'vmp map', plus the raw recording.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_live_options(lv, required=True)
    add_run_options(lv)
    lv.set_defaults(run=run)


def add_live_options(p: argparse.ArgumentParser, required: bool) -> None:
    """The options that choose a serial scanner (or a simulated one) and its link."""
    p.add_argument("--driver", required=required, choices=["sick", "rplidar", "hokuyo"],
                   help="scanner protocol")
    where = p.add_mutually_exclusive_group(required=required)
    where.add_argument("--port", help="serial device (e.g. /dev/ttyUSB0) or pyserial URL")
    where.add_argument("--simulate", metavar="SCENARIO",
                       help="serve a simulated device streaming this scenario on a pty")
    p.add_argument("--baud", type=positive_int, help="working baud rate (SICK: 9600, 19200, "
                   "38400 or 500000; default 38400)")
    p.add_argument("--odometry", metavar="FEED", help="JSON-lines pose feed to read odometry "
                   "from (serial port, named pipe or file)")
    p.add_argument("--no-odometry", action="store_true",
                   help="with --simulate: no simulated pose feed (registration only)")
    p.add_argument("--scans", type=positive_int, help="stop after this many mapped scans")
    p.add_argument("--duration", type=positive_float, help="stop after this many seconds")
    p.add_argument("--speed", type=positive_float, default=1.0,
                   help="with --simulate: device clock speed-up (default 1 = real time)")
    p.add_argument("--corruption", type=float, default=0.0,
                   help="with --simulate: share of bytes corrupted on the wire (e.g. 0.001)")
    p.add_argument("--silence", type=positive_float, default=1.0,
                   help="seconds without a byte from the scanner before reconnecting "
                   "(default 1)")


def open_live_source(args: argparse.Namespace, out: Path):
    """The live source the options name, recording to ``out/live.clf``; removes the empty
    folder ``out`` when it cannot be opened."""
    from drivers.scanners import open_live

    try:
        if not (args.port or args.simulate):
            raise InputError("--driver needs --port or --simulate")
        if not 0.0 <= args.corruption < 1.0:
            raise InputError(f"--corruption must lie in [0, 1), got {args.corruption}")
        if args.port and (args.no_odometry or args.corruption or args.speed != 1.0):
            raise InputError("--no-odometry, --corruption and --speed apply to --simulate "
                             "only")
        return open_live(args.driver, args.simulate or args.port, out / "live.clf",
                         simulate=bool(args.simulate), odometry=args.odometry,
                         no_odometry=args.no_odometry, scans=args.scans,
                         duration=args.duration, speed=args.speed,
                         corruption=args.corruption, silence=args.silence, baud=args.baud)
    except BaseException:
        remove_if_empty(out)
        raise


def run(args: argparse.Namespace) -> int:
    config = mapping_config(args.config)
    label = f"live-{args.driver}" + (f"-{args.simulate}" if args.simulate else "")
    out = new_results_dir(args.out, label)
    record = out / "live.clf"
    source = open_live_source(args, out)
    try:
        if not args.quiet:
            odometry = source.report().counts["odometry"]
            what = (f"simulated {args.driver} streaming {args.simulate}" if args.simulate
                    else f"{args.driver} on {args.port}")
            print(f"live: {what}; odometry: {odometry}; Ctrl-C ends the run")
        _, code = map_and_write(source, config, args, out, f"live {args.driver} "
                                f"{args.simulate or args.port}", args.scans)
    finally:
        source.shutdown()
    if not args.quiet:
        print(f"  recording   {record}  (vmp map {record} reproduces this run)")
    return code
