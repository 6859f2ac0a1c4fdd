"""The ``vmp`` command: simulate scenarios (and, as they arrive, map, export, evaluate, live)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

import numpy as np

from vmp import __version__
from vmp.errors import InputError

EXAMPLES = """\
examples:
  vmp map office                          map the default scenario; results/latest holds it all
  vmp map run.clf --out results           map a CARMEN log
  vmp export results/latest --grid map.yaml --resolution 0.05
  vmp evaluate results/latest --ground-truth results/latest/ground_truth.tum
  vmp simulate office                     write office.clf (CARMEN log) and office.tum (truth)
  vmp simulate warehouse --out runs/w.clf --laps 3 --seed 11
  vmp simulate my_building.yaml --out b.clf
  vmp scenarios                           list the built-in scenarios
  vmp info demo.bag                       what a recording holds (topics of a ROS bag)
  vmp live --driver sick --simulate office   live mapping from a simulated LMS 200
  vmp live --driver rplidar --port /dev/ttyUSB0

Angles on the command line and in scenario files are in degrees, everything else in SI units.
"""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="vmp",
        description="2D laser SLAM with the vector mapping paradigm and laser milestones.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"vmp-slam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    sim = sub.add_parser(
        "simulate",
        help="drive a simulated robot through a scenario and record the scans",
        description="Drive a simulated robot through a scenario: ray-cast laser scans, noisy "
        "odometry. Writes a CARMEN log (FLASER and ODOM lines) and the true trajectory as a "
        "TUM file, the same formats real recordings come in.",
        epilog="examples:\n  vmp simulate office\n  vmp simulate lab --out lab.clf --seed 3\n"
        "  vmp simulate corridor --scans 500 --out short.clf\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sim.add_argument("scenario", help="a built-in scenario name (see 'vmp scenarios') or a "
                     "scenario YAML file")
    sim.add_argument("--out", type=Path, help="CARMEN log to write (default: SCENARIO.clf)")
    sim.add_argument("--ground-truth", type=Path, metavar="TUM",
                     help="true trajectory to write (default: the log's name with .tum)")
    sim.add_argument("--seed", type=_nonneg_int, help="random seed (default: the scenario's)")
    sim.add_argument("--laps", type=_positive_int, help="laps of a closed trajectory "
                     "(default: the scenario's)")
    sim.add_argument("--scans", type=_positive_int, help="stop after this many scans")
    sim.add_argument("-q", "--quiet", action="store_true", help="no progress, no summary")
    sim.set_defaults(func=cmd_simulate)

    mp = sub.add_parser(
        "map",
        help="build a map and a corrected trajectory from a scenario or a recording",
        description="Build a vector map with laser milestones from a built-in scenario, a "
        "scenario file or a CARMEN log. Writes a dated results folder (and a 'latest' link): "
        "trajectory (TUM), the map, milestones, occupancy grid, contours, milestone graph, "
        "the configuration used and a metrics summary, also printed at the end.",
        epilog="examples:\n  vmp map office\n  vmp map warehouse --out /tmp/runs\n"
        "  vmp map corridor --no-milestones          # odometry and scan matching only\n"
        "  vmp map office --config my.yaml           # see results/latest/config.yaml\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    mp.add_argument("source", help="scenario name, scenario YAML, or a recording: CARMEN log "
                    "(.clf, .log, .gz, g2o .zip), DP-SLAM or BreezySLAM log, ROS 1 bag, ROS 2 "
                    "bag folder or MCAP file")
    mp.add_argument("--out", type=Path, default=Path("results"),
                    help="folder that receives the dated results folder (default: results)")
    mp.add_argument("--config", type=Path, help="mapping configuration YAML (default: built-in)")
    mp.add_argument("--method", choices=["ed", "cca", "dct", "hwt"],
                    help="signature comparison of the milestones (default: cca)")
    mp.add_argument("--no-milestones", action="store_true",
                    help="no milestones: odometry refined by scan matching only")
    mp.add_argument("--no-scan-odometry", action="store_true",
                    help="predict from wheel odometry alone, without scan registration")
    mp.add_argument("--resolution", type=float, default=0.05,
                    help="occupancy grid cell size in metres (default: 0.05)")
    mp.add_argument("--scans", type=_positive_int, help="stop after this many scans")
    mp.add_argument("--seed", type=_nonneg_int, help="simulation seed (scenarios only)")
    mp.add_argument("--format", choices=["carmen", "dpslam", "breezyslam", "rosbag"],
                    help="recording format (default: detected from the content)")
    mp.add_argument("--scan-topic", help="ROS bags: the LaserScan topic (default: the first)")
    mp.add_argument("--odom-topic", help="ROS bags: an Odometry or tf topic (default: an "
                    "Odometry topic, else /tf; see 'vmp info')")
    mp.add_argument("--strict", action="store_true",
                    help="stop at the first bad line of a recording (default: skip, count, "
                    "report)")
    mp.add_argument("--rerun", metavar="TARGET",
                    help="watch in Rerun: a .rrd file to save, 'spawn' (native viewer) or "
                    "'serve' (web viewer on localhost)")
    mp.add_argument("-q", "--quiet", action="store_true", help="no progress, no table")
    mp.set_defaults(func=cmd_map)

    ex = sub.add_parser(
        "export", help="write a map as an occupancy grid, PNG, .npy, contours or graph",
        description="Export a result (a results folder or a .vmpmap file): an occupancy grid "
        "in the ROS map_server form (PGM + YAML), a PNG, a NumPy array, the contours of free "
        "space as GeoJSON and the milestone graph as JSON.",
        epilog="examples:\n  vmp export results/latest --grid map.yaml --resolution 0.05\n"
        "  vmp export results/latest/map.vmpmap --png map.png --contours free.geojson\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ex.add_argument("result", type=Path, help="results folder or .vmpmap file")
    ex.add_argument("--grid", type=Path, metavar="YAML", help="map_server YAML (+ PGM beside)")
    ex.add_argument("--resolution", type=float, default=0.05, help="metres per cell")
    ex.add_argument("--png", type=Path, help="greyscale PNG of the grid")
    ex.add_argument("--npy", type=Path, help="the grid as a NumPy array (0, 205, 254)")
    ex.add_argument("--contours", type=Path, metavar="GEOJSON", help="boundary of free space")
    ex.add_argument("--graph", type=Path, metavar="JSON", help="milestone graph")
    ex.set_defaults(func=cmd_export)

    ev = sub.add_parser(
        "evaluate", help="score a trajectory: ATE, RPE, Kuemmerle relations",
        description="Score a result's trajectory (or any TUM file) against ground truth (ATE "
        "after SE(2) alignment, and RPE, as evo computes them) or against a relations file "
        "(Kuemmerle et al. 2009: mean and std of translational and rotational error).",
        epilog="examples:\n  vmp evaluate results/latest --ground-truth office.tum\n"
        "  vmp evaluate results/latest --relations ../shared/data/intel/intel.relations\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ev.add_argument("result", type=Path, help="results folder or TUM trajectory")
    ev.add_argument("--ground-truth", type=Path, metavar="TUM")
    ev.add_argument("--relations", type=Path, metavar="FILE")
    ev.add_argument("--delta", type=_positive_int, default=1,
                    help="RPE frame distance (default 1)")
    ev.set_defaults(func=cmd_evaluate)

    inf = sub.add_parser(
        "info", help="what a recording holds: format, scans, beams, field of view, duration",
        description="Read a recording through and print its format, number of scans, beams, "
        "field of view, maximum range, duration, whether it has odometry, and its bad lines.",
        epilog="examples:\n  vmp info ../shared/data/intel/intel-first5505.clf.gz\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    inf.add_argument("recording", type=Path)
    inf.add_argument("--format", choices=["carmen", "dpslam", "breezyslam", "rosbag"],
                     help="recording format (default: detected from the content)")
    inf.add_argument("--scan-topic", help="ROS bags: the LaserScan topic (default: the first)")
    inf.add_argument("--odom-topic", help="ROS bags: an Odometry or tf topic")
    inf.set_defaults(func=cmd_info)

    from vmp.cli_live import add_live_parser

    add_live_parser(sub)

    sc = sub.add_parser("scenarios", help="list the built-in scenarios",
                        description="List the built-in scenarios with their descriptions.")
    sc.set_defaults(func=cmd_scenarios)
    return parser


def cmd_scenarios(args: argparse.Namespace) -> int:
    from drivers.scenario import builtin_scenarios

    names = builtin_scenarios()
    width = max(map(len, names))
    for name, desc in names.items():
        print(f"{name:<{width}}  {desc}")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from drivers.carmen import write_carmen
    from drivers.scenario import load_scenario
    from drivers.simulator import Simulator
    from vmp.progress import Progress
    from vmp.tum import write_tum

    scenario = load_scenario(args.scenario)
    try:
        sim = Simulator(scenario, seed=args.seed, laps=args.laps, max_scans=args.scans)
    except ValueError as exc:
        raise InputError(str(exc)) from exc
    out = args.out if args.out is not None else Path(f"{scenario.name}.clf")
    gt = args.ground_truth if args.ground_truth is not None else out.with_suffix(".tum")
    if out.resolve() == gt.resolve():
        raise InputError(f"--out and --ground-truth name the same file: {out}")
    progress = Progress(len(sim), f"simulating {scenario.name}", enabled=None if not args.quiet
                        else False)
    n = write_carmen(out, progress.wrap(sim),
                     comment=f"scenario {scenario.name}, seed {sim.seed}")
    write_tum(gt, sim.stamps, sim.true_poses)
    if not args.quiet:
        steps = np.diff(sim.true_poses[:, :2], axis=0)
        length = float(np.hypot(steps[:, 0], steps[:, 1]).sum())
        drift = float(np.hypot(*(sim.odom_poses[-1, :2] - sim.true_poses[-1, :2])))
        print(f"{scenario.name}: {n} scans, {sim.stamps[-1]:.1f} s, {length:.1f} m driven, "
              f"odometry off by {drift:.2f} m at the end ({progress.rate:,.0f} scans/s)")
        print(f"  log:          {out}")
        print(f"  ground truth: {gt}")
    return 0


def _open_source(text: str, seed: int | None, scans: int | None, strict: bool = False,
                 fmt: str | None = None, scan_topic: str | None = None,
                 odom_topic: str | None = None):
    """Frames, beam geometry, their count (or None), a name, and the log reader (or None)."""
    import itertools

    from drivers.formats import open_recording
    from drivers.scenario import builtin_scenarios, load_scenario
    from drivers.simulator import Simulator
    from vmp.vector_map import BeamGeometry

    path = Path(text)
    is_log = fmt is not None or path.suffix in (".clf", ".log", ".gz", ".txt", ".dat",
                                                ".bag", ".mcap", ".db3", ".zip") or (
        path.is_file() and path.suffix not in (".yaml", ".yml")) or path.is_dir()
    if not is_log or text in builtin_scenarios():
        scenario = load_scenario(text)
        try:
            sim = Simulator(scenario, seed=seed, max_scans=scans)
        except ValueError as exc:
            raise InputError(str(exc)) from exc
        s = sim.sensor
        geom = BeamGeometry(s.beams, s.angle_min, s.angle_increment, s.max_range)
        return iter(sim), geom, len(sim), scenario.name, None
    if seed is not None:
        raise InputError("--seed applies to scenarios, not to recordings")
    if not path.exists():
        raise InputError(f"{path}: no such file")
    log = open_recording(path, fmt, strict, scan_topic=scan_topic, odom_topic=odom_topic)
    frames = iter(log)
    first = next(frames, None)
    if first is None:
        raise InputError(f"{path}: no laser scans in this {log.format_name}")
    geom = BeamGeometry(first.num_beams, first.angle_min, first.angle_increment,
                        first.max_range)
    stream = itertools.chain([first], frames)
    if scans is not None:
        stream = itertools.islice(stream, scans)
    name = path.name.split(".")[0]
    return stream, geom, scans, name, log


def cmd_map(args: argparse.Namespace) -> int:
    import dataclasses

    from vmp.config import load_config
    from vmp.pipeline import Pipeline, PipelineConfig
    from vmp.progress import Progress
    from vmp.results import format_metrics, new_results_dir, write_results

    config = load_config(args.config) if args.config else PipelineConfig()
    if args.method:
        config = dataclasses.replace(
            config, milestones=dataclasses.replace(config.milestones, method=args.method))
    if args.no_milestones:
        config = dataclasses.replace(config, use_milestones=False)
    if args.no_scan_odometry:
        config = dataclasses.replace(config, scan_odometry=dataclasses.replace(
            config.scan_odometry, enabled=False))
    if not (args.resolution > 0):
        raise InputError(f"--resolution must be positive, got {args.resolution}")
    frames, geom, total, name, log = _open_source(args.source, args.seed, args.scans,
                                                  args.strict, args.format, args.scan_topic,
                                                  args.odom_topic)
    view, where = open_view(args.rerun, args.quiet)
    pipeline = Pipeline(geom, config, view)
    progress = Progress(total, f"mapping {name}", enabled=False if args.quiet else None)
    stamps = []
    for frame in progress.wrap(frames):
        if frame.num_beams != geom.num_beams:
            raise InputError(f"scan {frame.index}: {frame.num_beams} beams, the first scan "
                             f"had {geom.num_beams}")
        pipeline.step(frame)
        stamps.append(frame.stamp)
    if not stamps:
        raise InputError(f"{args.source}: no scans to map")
    pipeline.finish()
    if log is not None:
        pipeline.stats["bad lines skipped"] = log.skipped
        pipeline.stats["stamps running backwards"] = log.backwards
        if log.problems and not args.quiet:
            print(log.summary(), file=sys.stderr)
    out = new_results_dir(args.out, name)
    extra = _against_reference(log, pipeline, out, np.array(stamps))
    metrics = write_results(out, pipeline, np.array(stamps), args.source, args.resolution,
                            extra=extra)
    if view is not None:
        from vmp.export import read_ros_map

        grid = read_ros_map(out / "grid.yaml")
        view.grid(grid.cells, grid.resolution, grid.origin)
        if args.rerun == "serve":
            view.rec.flush()
            print(f"rerun: still serving ({where}); press Ctrl-C to stop", flush=True)
            try:
                while True:
                    time.sleep(1.0)
            except KeyboardInterrupt:
                pass
        view.close()
    if not args.quiet:
        print(format_metrics(metrics))
        print(f"\nresults in {out} (also {args.out / 'latest'}):")
        print(f"  trajectory  {out / 'trajectory.tum'}")
        print(f"  map         {out / 'map.vmpmap'}")
        print(f"  grid        {out / 'grid.yaml'} (+ grid.pgm, grid.png, grid.npy)")
        print(f"  contours    {out / 'contours.geojson'};  graph {out / 'graph.json'}")
    return 0


def open_view(target: str | None, quiet: bool):
    """The Rerun view asked for with ``--rerun`` (and where it goes), or (None, "")."""
    if not target:
        return None, ""
    from viz.rerun_view import open_rerun

    try:
        view, where = open_rerun(target)
    except ValueError as exc:
        raise InputError(str(exc)) from exc
    if not quiet:
        print(f"rerun: {where}")
    return view, where


def _against_reference(log, pipeline, out: Path, stamps: np.ndarray) -> dict:
    """ATE against the poses a recording carries as a reference (GMapping's, in Radish logs).

    Scans are paired by order (some of those logs have no usable stamps); the reference is
    written beside the trajectory as ``reference.tum``.
    """
    from vmp.evaluate import ate_in_order
    from vmp.tum import write_tum

    ref = getattr(log, "reference", None)
    if not ref or len(ref) != len(stamps):
        return {}
    poses = np.array([p for _, p in ref])
    write_tum(out / "reference.tum", stamps, poses)
    return {
        "unknown odometry increments": getattr(log, "unknown_increments", 0),
        "ATE vs GMapping's poses (m)": ate_in_order(pipeline.trajectory(), poses),
        "ATE of odometry vs GMapping's poses (m)": ate_in_order(np.array(pipeline.odometry),
                                                                poses),
    }


def _map_file(result: Path) -> Path:
    path = result / "map.vmpmap" if result.is_dir() else result
    if not path.is_file():
        raise InputError(f"{result}: neither a results folder with map.vmpmap nor a map file")
    return path


def cmd_export(args: argparse.Namespace) -> int:
    from vmp.export import (
        free_space_contours,
        occupancy_grid,
        write_geojson,
        write_graph_json,
        write_png,
        write_ros_map,
    )
    from vmp.fileio import atomic_write
    from vmp.mapfile import load_map

    if not any((args.grid, args.png, args.npy, args.contours, args.graph)):
        raise InputError("nothing to export: give --grid, --png, --npy, --contours or --graph")
    data = load_map(_map_file(args.result))
    poses = data.trajectory
    polys = data.map.polygons(poses)
    if args.grid or args.png or args.npy:
        grid = occupancy_grid(polys, data.map.world_points(poses), args.resolution)
        if args.grid:
            pgm = write_ros_map(args.grid, grid)
            print(f"grid: {args.grid} + {pgm} ({grid.shape[1]} x {grid.shape[0]} cells of "
                  f"{grid.resolution} m)")
        if args.png:
            write_png(args.png, grid)
            print(f"png: {args.png}")
        if args.npy:
            with atomic_write(args.npy, "wb") as f:
                np.save(f, grid.cells, allow_pickle=False)
            print(f"npy: {args.npy}")
    if args.contours:
        geom = free_space_contours(polys)
        write_geojson(args.contours, geom, {"what": "boundary of free space"})
        print(f"contours: {args.contours} ({geom.area:.1f} m2 of free space)")
    if args.graph:
        ms = data.milestones
        write_graph_json(args.graph, ms.ids, ms.poses, ms.stamps, data.graph.edges)
        print(f"graph: {args.graph} ({len(ms)} milestones, {len(data.graph.edges)} edges)")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    import math

    from drivers.formats import open_recording

    path = args.recording
    log = open_recording(path, args.format, scan_topic=args.scan_topic,
                         odom_topic=args.odom_topic)
    n = 0
    first = None
    beams = set()
    t0, t1 = math.inf, -math.inf
    odom_moves = False
    has_odom = True
    returned = 0.0
    with_odom = 0
    first_odom = last_odom = None
    for frame in log:  # one pass, constant memory
        if frame.odom is None:
            has_odom = False
        else:
            with_odom += 1
            if first_odom is None:
                first_odom = frame.odom
            elif not odom_moves and not np.array_equal(frame.odom, first_odom):
                odom_moves = True
            last_odom = frame.odom
        if first is None:
            first = frame
        n += 1
        beams.add(frame.num_beams)
        t0, t1 = min(t0, frame.stamp), max(t1, frame.stamp)
        returned += float(frame.returned.mean())
    if first is None:
        raise InputError(f"{path}: no laser scans in this {log.format_name}")
    fov = math.degrees(abs(first.angle_increment) * (first.num_beams - 1))
    print(f"file          {path}")
    print(f"format        {log.format_name}" + (" (gzip)" if path.suffix == ".gz" else ""))
    print(f"scans         {n}")
    print(f"beams         {', '.join(str(b) for b in sorted(beams))}")
    print(f"field of view {fov:.1f} deg from {math.degrees(first.angle_min):.1f} deg, step "
          f"{math.degrees(first.angle_increment):.4f} deg")
    print(f"max range     {first.max_range:g} m; {100 * returned / n:.0f} % of beams return")
    print(f"duration      {t1 - t0:.1f} s ({t0:.3f} .. {t1:.3f})")
    if last_odom is None:
        print("odometry      none: vmp map registers the scans alone")
    else:
        some = "" if has_odom else f" in {with_odom} of {n} scans (the others are registered alone)"
        print(f"odometry      {'yes' if odom_moves else 'none (constant pose)'}{some}; last "
              f"({last_odom[0]:.2f}, {last_odom[1]:.2f}, {math.degrees(last_odom[2]):.1f} deg)")
    if getattr(log, "gmapping", False):
        print(f"note          GMapping output log: odometry rebuilt from its ODOM lines "
              f"({log.unknown_increments} of {n - 1} increments unknown); its corrected poses "
              f"are the reference")
    if log.topics is not None:
        chosen = (getattr(log, "chosen_scan", None), getattr(log, "chosen_odom", None))
        print("topics")
        for topic, (msgtype, count) in sorted(log.topics.items()):
            used = (" <- scans" if topic == chosen[0] else
                    " <- odometry" if topic == chosen[1] else "")
            print(f"  {topic:<28} {msgtype:<32} {count:>7} messages{used}")
    item = log.item
    print(f"bad {item}s{' ' * (9 - len(item))}{log.skipped} skipped, {log.backwards} stamps "
          f"running backwards"
          + (f" (first: {item} {log.problems[0][0]}: {log.problems[0][1]})"
             if log.problems else ""))
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    import math

    from vmp.evaluate import ate, read_relations, relation_error, relation_errors, rpe
    from vmp.tum import read_tum

    if not args.ground_truth and not args.relations:
        raise InputError("give --ground-truth TUM and/or --relations FILE")
    traj = args.result / "trajectory.tum" if args.result.is_dir() else args.result
    if not traj.is_file():
        raise InputError(f"{args.result}: no trajectory (expected a TUM file or a results "
                         "folder with trajectory.tum)")
    stamps, poses = read_tum(traj)
    if args.ground_truth:
        gs, gp = read_tum(args.ground_truth)
        a = ate(stamps, poses, gs, gp)
        r = rpe(stamps, poses, gs, gp, delta=args.delta)
        print(f"ATE  rmse {a.rmse:.4f} m  mean {a.mean:.4f} m  max {a.max:.4f} m  "
              f"({a.pairs} poses, SE(2) aligned)")
        print(f"RPE  trans rmse {r.trans_rmse:.4f} m  rot rmse {math.degrees(r.rot_rmse):.4f} "
              f"deg  (delta {r.delta} frames, {r.pairs} pairs)")
    if args.relations:
        relations = read_relations(args.relations)
        rel = relation_error(stamps, poses, relations)
        print(f"relations  trans {rel.trans_mean:.4f} +- {rel.trans_std:.4f} m  rot "
              f"{math.degrees(rel.rot_mean):.3f} +- {math.degrees(rel.rot_std):.3f} deg  "
              f"({rel.used} of {rel.total} relations)")
        span, et, er = relation_errors(stamps, poses, relations)
        print("  by time between the two poses:")
        for lo, hi in ((0, 10), (10, 60), (60, 300), (300, math.inf)):
            m = (span >= lo) & (span < hi)
            if m.any():
                print(f"  {lo:>4}-{hi:<4g} s  {int(m.sum()):>5} relations  trans "
                      f"{et[m].mean():.4f} m  rot {math.degrees(er[m].mean()):.3f} deg  "
                      f"({et[m].sum() / et.sum():.0%} of the total error)")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return int(args.func(args))
    except InputError as exc:
        print(f"vmp {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        name = f": {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"vmp {args.command}: error: {exc.strerror or exc}{name}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vmp {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
