"""The ``vmp`` command: simulate scenarios (and, as they arrive, map, export, evaluate, live)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

import numpy as np

from vmp import __version__
from vmp.errors import InputError

EXAMPLES = """\
examples:
  vmp simulate office                     write office.clf (CARMEN log) and office.tum (truth)
  vmp simulate warehouse --out runs/w.clf --laps 3 --seed 11
  vmp simulate my_building.yaml --out b.clf
  vmp scenarios                           list the built-in scenarios

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
