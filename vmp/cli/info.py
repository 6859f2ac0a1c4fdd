"""``vmp info``: what a recording holds."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    inf = sub.add_parser(
        "info", help="what a recording holds: format, scans, beams, field of view, duration",
        description="Read a recording through and print its format, number of scans, beams, "
        "field of view, maximum range, duration, whether it has odometry, and its bad lines.",
        epilog="examples:\n  vmp info ../shared/data/intel/intel-first5505.clf.gz\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    inf.add_argument("recording", type=Path, help="a recording: CARMEN log (.clf, .log, "
                     ".gz, g2o .zip), DP-SLAM or BreezySLAM log, ROS 1 bag, ROS 2 bag folder or "
                     "MCAP file")
    inf.add_argument("--format", choices=["carmen", "dpslam", "breezyslam", "rosbag"],
                     help="recording format (default: detected from the content)")
    inf.add_argument("--scan-topic", help="ROS bags: the LaserScan topic (default: the first)")
    inf.add_argument("--odom-topic", help="ROS bags: an Odometry or tf topic")
    inf.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from drivers.formats import open_recording
    from vmp.survey import survey

    path = args.recording
    log = open_recording(path, args.format, scan_topic=args.scan_topic,
                         odom_topic=args.odom_topic)
    s = survey(log)
    g = s.geometry
    print(f"file          {path}")
    print(f"format        {log.format_name}" + (" (gzip)" if path.suffix == ".gz" else ""))
    print(f"scans         {s.scans}")
    print(f"beams         {', '.join(str(b) for b in s.beam_counts)}")
    print(f"field of view {math.degrees(abs(g.angle_increment) * (g.num_beams - 1)):.1f} deg "
          f"from {math.degrees(g.angle_min):.1f} deg, step "
          f"{math.degrees(g.angle_increment):.4f} deg")
    print(f"max range     {g.max_range:g} m; {100 * s.returned:.0f} % of beams return")
    print(f"duration      {s.duration:.1f} s ({s.first_stamp:.3f} .. {s.last_stamp:.3f})")
    if s.last_odom is None:
        print("odometry      none: vmp map registers the scans alone")
    else:
        some = ("" if s.with_odom == s.scans else
                f" in {s.with_odom} of {s.scans} scans (the others are registered alone)")
        last = s.last_odom
        print(f"odometry      {'yes' if s.odom_moves else 'none (constant pose)'}{some}; last "
              f"({last[0]:.2f}, {last[1]:.2f}, {math.degrees(last[2]):.1f} deg)")
    for heading, text in log.notes():
        print(f"{heading:<14}{text}".rstrip() if heading else text)
    r = log.report()
    item = r.item
    print(f"bad {item}s{' ' * (9 - len(item))}{r.skipped} skipped, {r.backwards} stamps "
          f"running backwards"
          + (f" (first: {item} {r.problems[0][0]}: {r.problems[0][1]})" if r.problems else ""))
    if r.damaged:
        print(f"damaged       {r.damaged}")
    return 0
