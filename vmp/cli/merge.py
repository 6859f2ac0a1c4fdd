"""``vmp merge``: join two maps of one building, made separately, into one."""

from __future__ import annotations

import argparse
from pathlib import Path

from vmp.cli.common import add_run_options, map_and_write, mapping_config, warn_if_incomplete
from vmp.folders import new_results_dir

__all__ = ["add_parser", "run"]

EPILOG = """\
examples:
  vmp merge results/floor2-monday results/floor2-tuesday --out results
  vmp merge run1/latest run2/latest --out merged --resolution 0.1

The second map's scans are localized in the first (no start pose needed) and mapped on into
it as a second session would be ('vmp map --continue'), its poses serving as odometry: loops
between the two close where they overlap. Scans of the second map before it was first
localized are left out. Two maps that never overlap are refused.
"""


def add_parser(sub: argparse._SubParsersAction) -> None:
    mg = sub.add_parser(
        "merge", help="join two maps of the same building into one",
        description="Join two maps saved by 'vmp map' (results folders) into one map, by "
        "localizing the second map's scans in the first and closing the loops between them. "
        "Writes a dated results folder like 'vmp map'.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    mg.add_argument("first", type=Path, metavar="RESULT_A", help="the map to merge into")
    mg.add_argument("second", type=Path, metavar="RESULT_B", help="the map merged into it")
    add_run_options(mg)
    mg.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from vmp.localization import open_saved_map
    from vmp.source import FrameList

    warn_if_incomplete(args.first)
    warn_if_incomplete(args.second)
    first = open_saved_map(args.first)
    second = open_saved_map(args.second)
    first.check_beams(second.map.geometry, str(args.second))
    names = [p.resolve().name for p in (args.first, args.second)]
    source = FrameList(second.frames(), f"merge-{names[0]}-{names[1]}")
    out = new_results_dir(args.out, source.name)
    return map_and_write(source, mapping_config(args.config), args, out,
                         f"{args.second} merged into {args.first}", saved=first)[1]
