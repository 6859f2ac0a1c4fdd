"""How much a log's score depends on luck: the same log started a few scans later.

Run: python bench/robustness.py [--only aces] [--starts 5]

A result that a change of nothing (the robot switched on a tenth of a second later) turns
into a failure proves little, and one run per log cannot tell a better method from a lucky
one. For every log in ../shared/data with a relations file, this maps the log from scan 0,
1, ..., ``--starts - 1`` on (default configuration, in this process), scores each on the
log's relations (those whose two stamps both lie in the scans mapped) and prints each
start's translational error, loop edges and how many the robust adjustment down-weighted,
then per log the median, the best and the worst. Writes the table into docs/benchmarks.md
when every log ran.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from kummerle import logs
from report import machine, whole, write_section

from drivers import open_source
from vmp.evaluate import read_relations, relation_error
from vmp.run import MappingRun
from vmp.source import FrameList


def starts_of(name: str, log: Path, relations: Path, starts: int) -> list[dict]:
    frames = list(open_source(str(log)))
    rel = read_relations(relations)
    rows = []
    for first in range(starts):
        result = whole(MappingRun(FrameList(frames[first:], name)).run())
        err = relation_error(result.stamps, result.trajectory, rel)
        metrics = result.metrics()
        row = {"start": first, "trans": err.trans_mean, "std": err.trans_std,
               "rot": math.degrees(err.rot_mean), "used": err.used,
               "loops": metrics.get("loop edges in the graph", 0),
               "down": metrics.get("loop edges down-weighted", 0)}
        print(f"{name} from scan {first}: {row['trans']:.4f} +- {row['std']:.4f} m, "
              f"{row['rot']:.2f} deg on {row['used']} relations; loop edges {row['loops']} "
              f"({row['down']} down-weighted)", flush=True)
        rows.append(row)
    return rows


def table(found: dict[str, list[dict]], starts: int) -> str:
    lines = ["## Robustness: each log started a few scans later", "",
             f"`python bench/robustness.py --starts {starts}` on {machine()}: each log mapped "
             f"from scan 0 to {starts - 1} on (the robot switched on a fraction of a second "
             "later), default configuration, scored on the log's relations. One run per log "
             "cannot tell a better method from a lucky one: compare changes on the median "
             "and the worst.", "",
             "| log | " + " | ".join(f"from {k}" for k in range(starts))
             + " | median | worst | loop edges (down-weighted) |",
             "|---|" + "---|" * (starts + 3)]
    for name, rows in found.items():
        median, _, worst = spread(rows)
        loops = ", ".join(f"{r['loops']} ({r['down']})" for r in rows)
        lines.append(f"| {name} | " + " | ".join(f"{r['trans']:.4f}" for r in rows)
                     + f" | {median:.4f} | {worst:.4f} | {loops} |")
    return "\n".join(lines)


def spread(rows: list[dict]) -> tuple[float, float, float]:
    """The median, best and worst translational error over the starts."""
    trans = [r["trans"] for r in rows]
    return statistics.median(trans), min(trans), max(trans)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="only this log (the relations file's name: intel, aces, ...)")
    ap.add_argument("--starts", type=int, default=5, help="starts per log: scans 0, 1, ...")
    args = ap.parse_args()
    if args.starts < 1:
        ap.error("--starts: at least 1")
    found = {name: starts_of(name, log, relations, args.starts)
             for name, log, relations in logs(args.only)}
    for name, rows in found.items():
        median, best, worst = spread(rows)
        print(f"{name}: median {median:.4f} m, best {best:.4f}, worst {worst:.4f} over "
              f"{len(rows)} starts")
    if args.only is None:
        write_section("robustness", table(found, args.starts))


if __name__ == "__main__":
    main()
