"""``vmp simulate``: drive a simulated robot through a scenario and record what it sees."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

import numpy as np

from vmp.cli.args import nonneg_int, positive_int
from vmp.errors import InputError

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
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
    sim.add_argument("--seed", type=nonneg_int, help="random seed (default: the scenario's)")
    sim.add_argument("--laps", type=positive_int, help="laps of a closed trajectory "
                     "(default: the scenario's)")
    sim.add_argument("--scans", type=positive_int, help="stop after this many scans")
    sim.add_argument("-q", "--quiet", action="store_true", help="no progress, no summary")
    sim.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from drivers.carmen_writer import write_carmen
    from drivers.scenario import load_scenario
    from drivers.simulator import Simulator
    from vmp.progress import Progress
    from vmp.run import stop_on_signals
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
    progress = Progress(len(sim), f"simulating {scenario.name}",
                        enabled=not args.quiet)
    ended: list[str] = []  # the signal that ended the run early: the scans so far are written

    def stop(name: str) -> None:
        ended.append(name)
        sim.close()

    with stop_on_signals(stop):
        n = write_carmen(out, progress.wrap(sim),
                         comment=f"scenario {scenario.name}, seed {sim.seed}")
        write_tum(gt, sim.stamps[:n], sim.true_poses[:n])
    if ended:
        print(f"vmp simulate: interrupted by {ended[0]} after {n} scans; the log and the "
              f"ground truth hold them ({out}, {gt})", file=sys.stderr)
        return 128 + signal.Signals[ended[0]].value
    if not args.quiet:
        steps = np.diff(sim.true_poses[:, :2], axis=0)
        length = float(np.hypot(steps[:, 0], steps[:, 1]).sum())
        drift = float(np.hypot(*(sim.odom_poses[-1, :2] - sim.true_poses[-1, :2])))
        print(f"{scenario.name}: {n} scans, {sim.stamps[-1]:.1f} s, {length:.1f} m driven, "
              f"odometry off by {drift:.2f} m at the end ({progress.rate:,.0f} scans/s)")
        print(f"  log:          {out}")
        print(f"  ground truth: {gt}")
    return 0
