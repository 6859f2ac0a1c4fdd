"""Scans per second of the whole mapping pipeline, and bytes per stored scan.

Run: python bench/pipeline.py [--repeat 3] [--scenarios office warehouse ...]
Goals: at least 300 scans/s on `office` with views off (issue 4); logging to Rerun
(`--rerun FILE`) costs at most 20 % more time (issue 5).

Frames are simulated before the clock starts, so the figure is the pipeline's alone
(predict, match, correct, insert, show with the null view; final graph adjustment and map
assembly included; file writing excluded).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from report import machine, write_section

from drivers.scenario import load_scenario
from drivers.simulator import Simulator
from vmp.evaluate import ate
from vmp.results import Result
from vmp.run import MappingRun
from vmp.source import FrameList


def one_run(frames: list, rrd: Path | None = None) -> tuple[float, Result]:
    view = None
    if rrd is not None:
        from viz.rerun_view import open_rerun

        view, _ = open_rerun(str(rrd))
    t = time.perf_counter()
    result = MappingRun(FrameList(frames), view=view).run()
    if view is not None:
        view.close()
    return time.perf_counter() - t, result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scenarios", nargs="+", default=["office", "warehouse", "corridor", "lab"])
    args = ap.parse_args()
    rows = []
    for name in args.scenarios:
        sim = Simulator(load_scenario(name))
        frames = list(sim)
        times = []
        for _ in range(args.repeat):
            dt, r = one_run(frames)
            times.append(dt)
        med = statistics.median(times)
        p = r.pipeline
        err = ate(sim.stamps, r.trajectory, sim.stamps, sim.true_poses).rmse
        odo = ate(sim.stamps, sim.odom_poses, sim.stamps, sim.true_poses).rmse
        rows.append((name, len(frames), len(frames) / med, len(frames) / max(times),
                     len(frames) / min(times), p.map.bytes_per_scan, len(p.milestones),
                     err, odo))
        print(f"{name:10s} {len(frames)} scans: median {len(frames) / med:,.0f} scans/s "
              f"({min(times):.2f}-{max(times):.2f} s), {p.map.bytes_per_scan:.0f} B/scan, "
              f"ATE {100 * err:.1f} cm (odometry {100 * odo:.1f} cm)")
    lines = [
        "## Mapping pipeline",
        "",
        f"`python bench/pipeline.py --repeat {args.repeat}` on {machine()}.",
        "Whole runs, views off, frames simulated beforehand; median of the runs. "
        "Goal: >= 300 scans/s on office. ATE after SE(2) alignment, against the simulator's "
        "truth.",
        "",
        "| scenario | scans | median scans/s | slowest - fastest | bytes/scan | milestones "
        "| ATE | odometry ATE |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines += [f"| {r[0]} | {r[1]} | {r[2]:,.0f} | {r[3]:,.0f} - {r[4]:,.0f} | {r[5]:.0f} | "
              f"{r[6]} | {100 * r[7]:.1f} cm | {100 * r[8]:.1f} cm |" for r in rows]
    write_section("pipeline", "\n".join(lines))
    rerun_overhead(args.repeat)


def rerun_overhead(repeat: int) -> None:
    """Office with views off against office logging to a .rrd file, alternating runs."""
    import tempfile

    frames = list(Simulator(load_scenario("office")))
    off, on = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeat):
            off.append(one_run(frames)[0])
            rrd = Path(tmp) / f"office{k}.rrd"
            on.append(one_run(frames, rrd)[0])
            size = rrd.stat().st_size
    ratio = statistics.median(on) / statistics.median(off)
    print(f"office with --rerun FILE: median {statistics.median(on):.2f} s against "
          f"{statistics.median(off):.2f} s without: {100 * (ratio - 1):+.0f} % "
          f"({size / 1e6:.1f} MB recording)")
    write_section("rerun", "\n".join([
        "## Rerun logging cost",
        "",
        f"`python bench/pipeline.py --repeat {repeat}` (last part) on {machine()}.",
        "The office run with views off and with `--rerun FILE`, alternating; medians. "
        "Goal: at most 20 % more time.",
        "",
        "| views off | --rerun FILE | extra time | recording size |",
        "|---|---|---|---|",
        f"| {statistics.median(off):.2f} s | {statistics.median(on):.2f} s | "
        f"{100 * (ratio - 1):+.0f} % | {size / 1e6:.1f} MB |",
    ]))


if __name__ == "__main__":
    main()
