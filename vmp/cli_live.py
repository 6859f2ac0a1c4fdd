"""The ``vmp live`` command: its options and how they become a live run."""

from __future__ import annotations

import argparse
from pathlib import Path

from vmp.errors import InputError

__all__ = ["add_live_parser", "cmd_live"]

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
the run bit for bit. Ctrl-C ends the run and writes everything.
"""


def add_live_parser(sub: argparse._SubParsersAction) -> None:
    lv = sub.add_parser(
        "live", help="map live from a serial laser scanner (SICK LMS 2xx, RPLIDAR, Hokuyo)",
        description="Map as scans arrive from a serial laser scanner, or from a simulated one "
        "served on a pseudo-terminal. Shows scans, rate and link errors while it runs and "
        "writes the same results folder as 'vmp map', plus the raw recording.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    lv.add_argument("--driver", required=True, choices=["sick", "rplidar", "hokuyo"],
                    help="scanner protocol")
    where = lv.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", help="serial device (e.g. /dev/ttyUSB0) or pyserial URL")
    where.add_argument("--simulate", metavar="SCENARIO",
                       help="serve a simulated device streaming this scenario on a pty")
    lv.add_argument("--baud", type=int, help="working baud rate (SICK: 9600, 19200, 38400 or "
                    "500000; default 38400)")
    lv.add_argument("--odometry", metavar="FEED", help="JSON-lines pose feed to read odometry "
                    "from (serial port, named pipe or file)")
    lv.add_argument("--no-odometry", action="store_true",
                    help="with --simulate: no simulated pose feed (registration only)")
    lv.add_argument("--scans", type=int, help="stop after this many mapped scans")
    lv.add_argument("--duration", type=float, help="stop after this many seconds")
    lv.add_argument("--speed", type=float, default=1.0,
                    help="with --simulate: device clock speed-up (default 1 = real time)")
    lv.add_argument("--corruption", type=float, default=0.0,
                    help="with --simulate: share of bytes corrupted on the wire (e.g. 0.001)")
    lv.add_argument("--silence", type=float, default=1.0,
                    help="seconds without a scan before reconnecting (default 1)")
    lv.add_argument("--out", type=Path, default=Path("results"),
                    help="folder that receives the dated results folder (default: results)")
    lv.add_argument("--config", type=Path, help="mapping configuration YAML")
    lv.add_argument("--resolution", type=float, default=0.05,
                    help="occupancy grid cell size in metres (default: 0.05)")
    lv.add_argument("--rerun", metavar="TARGET",
                    help="watch in Rerun: a .rrd file, 'spawn' or 'serve'")
    lv.add_argument("-q", "--quiet", action="store_true", help="no progress, no table")
    lv.set_defaults(func=cmd_live)


def cmd_live(args: argparse.Namespace) -> int:
    from drivers.devices.pose_feed_device import PoseFeedDevice
    from drivers.scanners import open_scanner, simulated_scanner
    from vmp.cli import open_view
    from vmp.config import load_config
    from vmp.live import LiveOptions, run_live
    from vmp.pipeline import PipelineConfig
    from vmp.results import format_metrics

    if args.scans is not None and args.scans < 1:
        raise InputError(f"--scans must be at least 1, got {args.scans}")
    for name in ("duration", "speed", "silence", "resolution"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            raise InputError(f"--{name} must be positive, got {value}")
    if not 0.0 <= args.corruption < 1.0:
        raise InputError(f"--corruption must lie in [0, 1), got {args.corruption}")
    if args.port and (args.no_odometry or args.corruption or args.speed != 1.0):
        raise InputError("--no-odometry, --corruption and --speed apply to --simulate only")
    config = load_config(args.config) if args.config else PipelineConfig()
    options = {"silence": args.silence}
    if args.baud is not None:
        options["baudrate"] = args.baud
    devices = []
    odometry = args.odometry
    try:
        if args.simulate:
            from drivers.scenario import load_scenario

            scenario = load_scenario(args.simulate)
            device = simulated_scanner(args.driver, scenario, speed=args.speed,
                                       corruption=args.corruption,
                                       max_scans=args.scans).start()
            devices.append(device)
            port = device.port
            if odometry is None and not args.no_odometry:
                feed = PoseFeedDevice(device).start()
                devices.append(feed)
                odometry = feed.port
        else:
            port = args.port
            if "://" not in port and not Path(port).exists():
                raise InputError(f"{port}: no such serial port (ls /dev/ttyUSB* /dev/ttyACM* "
                                 "lists the connected ones)")
        try:
            driver = open_scanner(args.driver, port, **options)
        except ValueError as exc:
            raise InputError(str(exc)) from exc
        view, _ = open_view(args.rerun, args.quiet)
        name = f"live-{args.driver}" + (f"-{args.simulate}" if args.simulate else "")
        if not args.quiet:
            src = f"simulated {args.driver} on {port}" if args.simulate else port
            print(f"live: {args.driver} on {src}; odometry: "
                  f"{odometry or 'none (scan registration only)'}; Ctrl-C ends the run")
        run = run_live(driver, config, LiveOptions(
            out=args.out, name=name, odometry=odometry, scans=args.scans,
            duration=args.duration, resolution=args.resolution, quiet=args.quiet),
            devices=tuple(devices), view=view)
        if view is not None:
            view.close()
    finally:
        for d in devices:
            d.close()
    if not args.quiet:
        print(format_metrics(run.metrics))
        state = "interrupted; " if run.interrupted else ""
        print(f"\n{state}results in {run.out} (also {args.out / 'latest'}):")
        print(f"  recording   {run.log}  (vmp map {run.log} reproduces this run)")
        print(f"  trajectory  {run.out / 'trajectory.tum'}")
        print(f"  grid        {run.out / 'grid.yaml'} (+ grid.pgm, grid.png, grid.npy)")
        print(f"  odometry    {run.odometry}")
    return 0
