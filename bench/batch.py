"""`vmp batch` against the same runs one after another: wall time, CPU and their ratio.

Run: python bench/batch.py [--pairs 6] [--source office:1..8] [--workers N]

Issue 16 asks that 8 seeds of office through `vmp batch` take at most 0.6 of the serial time on
this 2-core machine. The machine's speed drifts by a quarter within the hour, so one pair of
runs decides nothing: this runs the two whole commands in turn, `--pairs` times, the batch
first in every other pair (a drift then favours neither side), and reports each pair's ratio
and the median. It also says what bounds the ratio: the CPU of each side (the commands and
everything they start: Dask's workers are their children) and how many cores it kept busy. A
run alone keeps more than one core busy (its free-space union works beside the grid), so
the batch can at best take (serial cores x the batch's CPU over the serial's) / cores of the
serial time. Each pair's per-run figures (scans, ATE, loop edges, wrong corrections, status)
must be the same on both sides. Writes the table to docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from report import machine, run_timed, write_section

from vmp.cli.batch import TIMING

GOAL = 0.6  # issue 16: the batch takes at most this share of the serial time


@dataclass(frozen=True)
class Timed:
    """One whole command: wall time, CPU of it and its children (s), its table's rows."""

    wall: float
    cpu: float
    rows: list[dict]

    @property
    def cores(self) -> float:
        return self.cpu / self.wall


def run_command(source: str, out: Path, serial: bool, workers: int | None) -> Timed:
    """``vmp batch SOURCE`` (``--serial`` or on a local cluster) into ``out``, timed."""
    cmd = [sys.executable, "-m", "vmp", "batch", source, "-q", "--out", str(out)]
    cmd += ["--serial"] if serial else ([] if workers is None else ["--workers", str(workers)])
    wall, cpu = run_timed(cmd)
    with open(out / "batch.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return Timed(wall, cpu, rows)


def same_figures(a: list[dict], b: list[dict]) -> bool:
    """Whether two tables hold the same runs with the same figures (times aside)."""
    def strip(rows: list[dict]) -> list[dict]:
        return [{k: v for k, v in r.items() if k not in (*TIMING, "results")} for r in rows]
    return strip(a) == strip(b)


def pair(k: int, source: str, root: Path, workers: int | None) -> dict:
    """The k-th pair: both commands, the batch first when k is odd."""
    order = (False, True) if k % 2 == 0 else (True, False)
    timed = {}
    for serial in order:
        timed[serial] = run_command(source, root / f"{k}-{'serial' if serial else 'batch'}",
                                    serial, workers)
    s, b = timed[True], timed[False]
    return {"pair": k + 1, "first": "serial" if order[0] else "batch", "serial": s, "batch": b,
            "ratio": b.wall / s.wall, "cpu_ratio": b.cpu / s.cpu,
            "equal": same_figures(s.rows, b.rows)}


def report(rows: list[dict], source: str, cores: int) -> str:
    """The pairs as a Markdown table, the median ratio and what the cores allow."""
    ratios = [r["ratio"] for r in rows]
    floor = (statistics.median(r["serial"].cores for r in rows)
             * statistics.median(r["cpu_ratio"] for r in rows) / cores)
    lines = [f"`python bench/batch.py --pairs {len(rows)} --source {source}` on {machine()}: "
             "the whole commands `vmp batch SOURCE --serial` and `vmp batch SOURCE` (a local "
             "cluster, one worker per core) in turn; CPU is the command's and its children's "
             "(Dask's workers), cores = CPU / wall.", "",
             "| pair | first | serial: wall, CPU, cores | batch: wall, CPU, cores | batch / serial "
             "| CPU batch / serial | per-run figures |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        s, b = r["serial"], r["batch"]
        lines.append(f"| {r['pair']} | {r['first']} | {s.wall:.1f} s, {s.cpu:.1f} s, "
                     f"{s.cores:.2f} | {b.wall:.1f} s, {b.cpu:.1f} s, {b.cores:.2f} | "
                     f"{r['ratio']:.3f} | {r['cpu_ratio']:.3f} | "
                     f"{'equal' if r['equal'] else 'DIFFER'} |")
    lines += ["", f"Median ratio {statistics.median(ratios):.3f} (range {min(ratios):.3f}-"
              f"{max(ratios):.3f}; {sum(x <= GOAL for x in ratios)} of {len(ratios)} pairs at "
              f"or below the goal {GOAL}). What the cores allow: serial cores x CPU ratio / "
              f"{cores} cores = {floor:.3f} (medians), before any wait or fixed cost."]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=6, help="pairs of runs (default 6)")
    ap.add_argument("--source", default="office:1..8", help="what to map (default office:1..8)")
    ap.add_argument("--workers", type=int, help="the local cluster's workers (default: cores)")
    args = ap.parse_args()
    cores = args.workers or os.cpu_count() or 1
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.pairs):
            try:
                row = pair(k, args.source, Path(tmp), args.workers)
            except KeyboardInterrupt:
                raise SystemExit("bench: interrupted; no figures written") from None
            s, b = row["serial"], row["batch"]
            print(f"pair {k + 1} ({row['first']} first): serial {s.wall:.1f} s ({s.cores:.2f} "
                  f"cores), batch {b.wall:.1f} s ({b.cores:.2f} cores): {row['ratio']:.3f}; "
                  f"CPU {row['cpu_ratio']:.3f}; figures "
                  f"{'equal' if row['equal'] else 'DIFFER'}", flush=True)
            rows.append(row)
    text = report(rows, args.source, cores)
    print(text)
    write_section("batch-ratio", text)
    if not all(r["equal"] for r in rows):
        raise SystemExit("bench: the batch's per-run figures differ from the serial ones")


if __name__ == "__main__":
    main()
