"""``vmp map``: map a scenario or a recording into a results folder."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from vmp.cli.args import nonneg_int, positive_int
from vmp.cli.common import add_run_options, map_and_write, mapping_config, warn_if_incomplete
from vmp.errors import InputError
from vmp.folders import new_results_dir

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    mp = sub.add_parser(
        "map",
        help="build a map and a corrected trajectory from a scenario or a recording",
        description="Build a vector map with laser milestones from a built-in scenario, a "
        "scenario file or a recording. Writes a dated results folder (and a 'latest' link, "
        "moved once everything is written): trajectory (TUM), the map, milestones, occupancy "
        "grid, contours, milestone graph, the configuration used and a metrics summary, also "
        "printed at the end. Ctrl-C or SIGTERM end the run early: what was mapped so far is "
        "written, and the exit code (130 or 143) says it was interrupted.",
        epilog="examples:\n  vmp map office\n  vmp map warehouse --out /tmp/runs\n"
        "  vmp map ../shared/data/intel/intel-first5505.clf.gz\n"
        "  vmp map corridor --no-milestones          # odometry and scan matching only\n"
        "  vmp map office --config my.yaml           # see results/latest/config.yaml\n"
        "  vmp map run2.clf --continue results/run1-20261201-101500   # map on in a saved map\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    mp.add_argument("source", help="scenario name, scenario YAML, or a recording: CARMEN log "
                    "(.clf, .log, .gz, g2o .zip), DP-SLAM or BreezySLAM log, ROS 1 bag, ROS 2 "
                    "bag folder or MCAP file")
    add_run_options(mp)
    mp.add_argument("--method", choices=["ed", "cca", "dct", "hwt"],
                    help="signature comparison of the milestones (default: cca)")
    mp.add_argument("--no-milestones", action="store_true",
                    help="no milestones: odometry refined by scan matching only")
    mp.add_argument("--no-scan-odometry", action="store_true",
                    help="predict from wheel odometry alone, without scan registration")
    mp.add_argument("--scans", type=positive_int, help="stop after this many scans")
    mp.add_argument("--seed", type=nonneg_int, help="simulation seed (scenarios only)")
    mp.add_argument("--format", choices=["carmen", "dpslam", "breezyslam", "rosbag"],
                    help="recording format (default: detected from the content)")
    mp.add_argument("--scan-topic", help="ROS bags: the LaserScan topic (default: the first)")
    mp.add_argument("--odom-topic", help="ROS bags: an Odometry or tf topic (default: an "
                    "Odometry topic, else /tf; see 'vmp info')")
    mp.add_argument("--continue", dest="continue_from", metavar="RESULT", type=Path,
                    help="go on mapping in a saved map (a results folder of 'vmp map'): the "
                    "scans are localized in it first, no start pose needed; the result holds "
                    "both sessions")
    mp.add_argument("--checkpoint-every", metavar="EVERY", default="60s",
                    help="write the run's whole state into its results folder this often: "
                    "seconds ('60s', the default), scans ('500') or 'off'; a run killed "
                    "(even by SIGKILL or a power cut) goes on from there with --resume")
    mp.add_argument("--resume", metavar="RESULT", type=Path,
                    help="go on with a run that was killed: its (incomplete) results folder, "
                    "which holds checkpoint.npz; give the same SOURCE (and --scans, --seed); "
                    "the result is the one the uninterrupted run gives")
    mp.add_argument("--strict", action="store_true",
                    help="stop at the first bad line of a recording, or where its file is "
                    "damaged (default: skip, count, report; read up to the damage). Stamps "
                    "that run backwards are kept and reported either way")
    mp.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from drivers import open_source
    from vmp.checkpoint import Every

    config = mapping_config(args.config)
    if args.method:
        config = dataclasses.replace(
            config, milestones=dataclasses.replace(config.milestones, method=args.method))
    if args.no_milestones:
        config = dataclasses.replace(
            config, matching=dataclasses.replace(config.matching, enabled=False))
    if args.no_scan_odometry:
        config = dataclasses.replace(config, scan_odometry=dataclasses.replace(
            config.scan_odometry, enabled=False))
    saved = None
    if args.continue_from is not None:
        from vmp.localization import open_saved_map

        if args.no_milestones:
            raise InputError("--continue needs milestones: leave out --no-milestones")
        warn_if_incomplete(args.continue_from)
        saved = open_saved_map(args.continue_from)
    every = Every.parse(args.checkpoint_every)
    resume = _resume_file(args) if args.resume is not None else None
    source = open_source(args.source, seed=args.seed, scans=args.scans, strict=args.strict,
                         fmt=args.format, scan_topic=args.scan_topic,
                         odom_topic=args.odom_topic)
    out = args.resume if resume is not None else new_results_dir(args.out, source.name)
    return map_and_write(source, config, args, out, args.source, args.scans, saved,
                         every=every, resume=resume)[1]


def _resume_file(args: argparse.Namespace) -> Path:
    """The checkpoint of the results folder ``--resume`` names; other options that would
    change the run are refused (the checkpoint holds the run's configuration)."""
    changes = [name for name, given in (
        ("--config", args.config), ("--method", args.method),
        ("--no-milestones", args.no_milestones), ("--no-scan-odometry", args.no_scan_odometry),
        ("--continue", args.continue_from)) if given]
    if changes:
        raise InputError(f"--resume goes on with the run's own settings: leave out "
                         f"{', '.join(changes)}")
    from vmp.checkpoint import CHECKPOINT

    folder = args.resume
    if not folder.is_dir():
        raise InputError(f"{folder}: not a results folder (give the folder of the killed run)")
    if not (folder / CHECKPOINT).is_file():
        raise InputError(f"{folder}: no {CHECKPOINT} here: the run wrote none (shorter than "
                         "--checkpoint-every) or finished")
    return folder / CHECKPOINT
