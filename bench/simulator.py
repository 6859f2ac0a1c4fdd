"""Scans per second of the scenario simulator (ray casting, noise, frames).

Run: python bench/simulator.py [--repeat 5]
Goal (issue 2): at least 2,000 scans/s on `office` (181 beams) on the 2-core machine.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from report import machine, median_time, write_section

from drivers.scenario import load_scenario
from drivers.simulator import Simulator


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rows = []
    for name in ("office", "corridor", "lab", "warehouse"):
        sc = load_scenario(name)
        n = len(Simulator(sc))
        med, times = median_time(lambda sc=sc: sum(1 for _ in Simulator(sc)), args.repeat)
        beams = sc.sensor.geometry.num_beams
        rows.append((name, len(sc.walls), beams, n, n / med, n / max(times), n / min(times)))
        print(f"{name:10s} {len(sc.walls):4d} walls {beams} beams {n:5d} scans: "
              f"median {n / med:,.0f} scans/s (range {n / max(times):,.0f}-{n / min(times):,.0f})")
    lines = [
        "## Simulator",
        "",
        f"`python bench/simulator.py --repeat {args.repeat}` on {machine()}.",
        "Whole runs of each scenario (true motion, noisy odometry, ray casting in batches of 16",
        "poses, ScanFrame construction); median of the runs. Goal: >= 2,000 scans/s on office.",
        "",
        "| scenario | walls | beams | scans | median scans/s | slowest - fastest run |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:,.0f} | {r[5]:,.0f} - {r[6]:,.0f} |"
              for r in rows]
    write_section("simulator", "\n".join(lines))


if __name__ == "__main__":
    main()
