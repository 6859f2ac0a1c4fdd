"""The ``vmp`` argument parser: the commands, their shared types, one-line errors."""

from __future__ import annotations

import argparse
from typing import NoReturn

from vmp import __version__

__all__ = ["Parser", "build_parser"]

EXAMPLES = """\
examples:
  vmp map office                          map the default scenario; results/latest holds it all
  vmp map run.clf --out results           map a CARMEN log
  vmp localize --map results/latest office --seed 3   where is the robot in that map?
  vmp map run2.clf --continue results/run1-20261201-101500   map on in a saved map
  vmp merge results/run1-... results/run2-... --out results   two maps joined into one
  vmp batch office:1..8 run.clf --set milestones.method=cca,dct   many runs, one table
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


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    from vmp.cli import (
        batch,
        evaluate,
        export,
        info,
        live,
        localize,
        mapping,
        merge,
        scenarios,
        simulate,
    )

    parser = Parser(
        prog="vmp",
        description="2D laser SLAM with the vector mapping paradigm and laser milestones.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"vmp-slam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for command in (simulate, mapping, localize, merge, batch, export, evaluate, info, live,
                    scenarios):
        command.add_parser(sub)
    return parser
