"""Peak memory of a whole mapping run (mapping, then writing every output) against its scans.

Run: python bench/memory.py [--scans 1000 5000 20000] [--scenario office]

Each size is one fresh process that maps the first N scans of the scenario driven for as many
laps as that takes (office: 1,110 scans a lap) and writes the whole results folder as
``vmp map`` does (map file, milestones, grid, PNG, contours, graph). It reports the process's
peak resident memory after mapping and after writing (``getrusage``'s high-water mark), the
wall time, and the memory per scan beyond the smallest run, and writes the table to
docs/benchmarks.md (section ``memory``).
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import machine, write_section


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


def child(scenario: str, scans: int) -> None:
    """Map and write in this process; print the figures as JSON."""
    from drivers.scenario import load_scenario
    from drivers.simulator import Simulator
    from vmp.run import MappingRun

    scn = load_scenario(scenario)
    lap = len(Simulator(scn, laps=1))
    source = Simulator(scn, laps=max(1, math.ceil(scans / lap)), max_scans=scans)
    started = time.perf_counter()
    result = MappingRun(source).run()
    mapped, mapping_peak = time.perf_counter(), _peak_mb()
    with tempfile.TemporaryDirectory() as out:
        result.write(Path(out))
    print(json.dumps({"scans": len(result.stamps), "mapping_mb": mapping_peak,
                      "total_mb": _peak_mb(), "mapping_s": mapped - started,
                      "writing_s": time.perf_counter() - mapped}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scans", type=int, nargs="+", default=[1000, 5000, 20000])
    ap.add_argument("--scenario", default="office")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-write", action="store_true", help="do not touch docs/benchmarks.md")
    args = ap.parse_args()
    if args.child:
        child(args.scenario, args.scans[0])
        return
    rows = []
    for n in args.scans:
        out = subprocess.run([sys.executable, __file__, "--child", "--scenario", args.scenario,
                              "--scans", str(n)], capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(r)
        print(f"{r['scans']:>6} scans: peak {r['mapping_mb']:.0f} MB mapping, "
              f"{r['total_mb']:.0f} MB with writing; {r['mapping_s']:.0f} s + "
              f"{r['writing_s']:.0f} s", flush=True)
    first = rows[0]
    lines = [f"`python bench/memory.py --scans {' '.join(map(str, args.scans))}` on "
             f"{machine()}: {args.scenario} driven for as many laps as the scans need, mapped "
             "and written (every output of `vmp map`) in one fresh process per size; peak "
             "resident memory (getrusage high-water mark) after mapping and after writing.", "",
             "| scans | peak after mapping | peak with writing | per scan beyond the "
             "smallest | mapping | writing |", "|---|---|---|---|---|---|"]
    for r in rows:
        extra = r["scans"] - first["scans"]
        per = (f"{1024 * (r['total_mb'] - first['total_mb']) / extra:.1f} kB" if extra > 0
               else "")
        lines.append(f"| {r['scans']} | {r['mapping_mb']:.0f} MB | {r['total_mb']:.0f} MB | "
                     f"{per} | {r['mapping_s']:.0f} s | {r['writing_s']:.0f} s |")
    if not args.no_write:
        write_section("memory", "## Peak memory against scans\n\n" + "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
