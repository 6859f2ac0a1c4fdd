"""``vmp scenarios``: the built-in simulated worlds."""

from __future__ import annotations

import argparse

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    sc = sub.add_parser("scenarios", help="list the built-in scenarios",
                        description="List the built-in scenarios with their descriptions.")
    sc.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from drivers.scenario import builtin_scenarios

    names = builtin_scenarios()
    width = max(map(len, names))
    for name, desc in names.items():
        print(f"{name:<{width}}  {desc}")
    return 0
