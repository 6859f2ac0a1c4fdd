"""``vmp localize``: where is the robot in a saved map? No starting pose needed."""

from __future__ import annotations

import argparse
import math
import shutil
from pathlib import Path

import numpy as np

from vmp.cli.args import nonneg_int
from vmp.cli.common import (
    add_run_options,
    finish,
    mapping_config,
    open_view,
    warn_if_incomplete,
)
from vmp.cli.live import add_live_options, open_live_source
from vmp.errors import InputError
from vmp.folders import new_results_dir, remove_if_empty

__all__ = ["add_parser", "run"]

EPILOG = """\
examples:
  vmp map office && vmp localize --map results/latest office --seed 3
  vmp localize --map results/office-20261201-101500 run2.clf --method dct
  vmp localize --map results/latest --driver sick --simulate office   # live, simulated LMS
  vmp localize --map results/latest --driver rplidar --port /dev/ttyUSB0

States per scan (states.csv): searching (no place yet), ambiguous (several places fit about
as well: the robot must move on), localized (one place, and the scans fit there), lost (the
scans stopped fitting; the search runs again, so a robot carried elsewhere is found again).
The trajectory holds the localized scans, in the saved map's frame. A map made by
'vmp map' with one scanner localizes scans of that scanner (the same beams).
"""


LINK = "latest-localization"  # the newest localization's folder ('latest' is the newest map)


def add_parser(sub: argparse._SubParsersAction) -> None:
    lc = sub.add_parser(
        "localize", help="localize in a saved map from no initial pose, then track",
        description="Localize a recording, a scenario or a live scanner in a map saved by "
        "'vmp map', starting with no pose: the milestones' signatures propose places, a "
        "branch-and-bound search and ICP against the submaps there verify them, and the "
        "robot is localized only when one place is clearly better than every other. Then "
        "it is tracked against the map, and searched for again when the scans stop fitting. "
        "Writes a dated results folder (trajectory.tum, states.csv, metrics.json) and "
        f"points '{LINK}' beside it at it ('latest' stays the newest map).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    lc.add_argument("--map", required=True, type=Path, metavar="RESULT",
                    help="results folder of 'vmp map' (or its map.vmpmap)")
    lc.add_argument("source", nargs="?", help="scenario name, scenario YAML or a recording "
                    "(as for 'vmp map'); leave out with --driver")
    lc.add_argument("--method", choices=["ed", "cca", "dct", "hwt"],
                    help="signature comparison that proposes places (default: the map's)")
    lc.add_argument("--initial-pose", metavar="X,Y,THETA",
                    help="a start to try first (metres, metres, degrees); never needed")
    lc.add_argument("--seed", type=nonneg_int, help="simulation seed (scenarios only)")
    lc.add_argument("--format", choices=["carmen", "dpslam", "breezyslam", "rosbag"],
                    help="recording format (default: detected from the content)")
    add_live_options(lc, required=False)
    add_run_options(lc)
    lc.set_defaults(run=run)


FAR = 1e6  # metres: farther from a map's origin than any building reaches


def _initial_pose(text: str | None) -> np.ndarray | None:
    if text is None:
        return None
    try:
        x, y, th = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--initial-pose: expected X,Y,THETA (m, m, deg), got {text!r}") \
            from None
    if not (all(math.isfinite(v) for v in (x, y, th)) and max(abs(x), abs(y)) <= FAR
            and abs(th) <= 360.0):
        raise InputError(f"--initial-pose: expected metres within {FAR:g} of the map's "
                         f"origin and degrees within 360, got {text!r}")
    return np.array([x, y, math.radians(th)])


def run(args: argparse.Namespace) -> int:
    from drivers import open_source
    from vmp.localization import open_saved_map

    if (args.source is None) == (args.driver is None):
        raise InputError("give a SOURCE (scenario or recording) or --driver with --port or "
                         "--simulate, not both")
    if args.driver is None and (args.port or args.simulate):
        raise InputError("--port and --simulate need --driver")
    live_only = {"--baud": args.baud, "--odometry": args.odometry,
                 "--no-odometry": args.no_odometry, "--duration": args.duration,
                 "--speed": args.speed != 1.0, "--corruption": args.corruption}
    given = [k for k, v in live_only.items() if v]
    if args.driver is None and given:
        raise InputError(f"{', '.join(given)} apply to a live scanner (--driver) only")
    initial = _initial_pose(args.initial_pose)
    config = mapping_config(args.config)
    warn_if_incomplete(args.map)
    saved = open_saved_map(args.map, args.method)
    live = args.driver is not None
    if live:
        label = f"live-{args.driver}" + (f"-{args.simulate}" if args.simulate else "")
        out = new_results_dir(args.out, f"localize-{label}")
        source = open_live_source(args, out)
    else:
        source = open_source(args.source, seed=args.seed, scans=args.scans, fmt=args.format)
        label = args.source
        out = new_results_dir(args.out, f"localize-{source.name}")
    view = open_view(args.rerun, args.quiet)
    try:
        if view is not None:
            _show_saved_map(view, saved, args.resolution)
        result = _localize(saved, source, config, view, args, label, initial, out)
    finally:
        if live:
            source.shutdown()
    return finish(result, lambda: result.write(out), out, args, view, label, link=LINK)


def _localize(saved, source, config, view, args, label, initial, out):
    """Run the localizer with a progress line; no empty results folder left on failure."""
    from vmp.localization import LocalizationRun
    from vmp.progress import Progress

    total = source.length if args.scans is None or source.length is None else min(
        args.scans, source.length)
    progress = Progress(total or args.scans, f"localizing {source.name}",
                        enabled=not args.quiet, tick=1.0)
    try:
        run = LocalizationRun(saved, source, config, view, map_path=str(args.map),
                              scans=args.scans, initial_pose=initial, progress=progress,
                              label=label)
    except BaseException:
        progress.close()
        shutil.rmtree(out, ignore_errors=True)  # nothing ran: not even a recording to keep
        raise
    try:
        return run.run()
    except BaseException:
        remove_if_empty(out)  # nothing was localized (a live run keeps its recording)
        raise


def _show_saved_map(view, saved, resolution: float) -> None:
    """The saved map's occupancy grid in the view, under what the localizer shows."""
    from vmp.export import occupancy_grid

    vmap = saved.map
    grid = occupancy_grid(vmap.polygons(saved.trajectory), vmap.world_points(saved.trajectory),
                          resolution)
    view.grid(grid.cells, grid.resolution, grid.origin)
