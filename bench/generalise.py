"""The generalisation suite: every log with relations, as logged and under perturbations that
make a new SLAM problem out of the same building, mapped with the default configuration.

Run: python bench/generalise.py [--only intel aces] [--jobs 2]

Logs: every log in ../shared/data (VMP_DATA) with a relations file beside it (the Intel
folder's whole run and its first part, ACES, fr079). Perturbations:

- ``as logged``;
- ``drift +1 deg/10 m``, ``drift -2 deg/10 m``: a heading bias that grows with the distance the
  odometry travelled, the positions integrated anew from the increments so bent;
- ``scale +5 %``, ``scale -5 %``: the odometry's distances (not its turns) scaled;
- ``every 2nd scan``: every second scan dropped (the relations whose stamps are left);
- ``from scan 500``: mapped from its 501st scan on;
- ``every 2nd beam``: every second beam dropped (half the angular resolution).

Each cell is Kuemmerle et al.'s mean translational relation error (m) over the relations whose
two stamps both have a mapped scan; per log the median and the worst over the perturbations,
and the unperturbed figure's ratio to that median. The table goes to docs/benchmarks.md
(section generalise). A change to the mapping algorithm is judged on this table and on the
simulated worlds (bench/seeds.py), never on one log.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import multiprocessing
import statistics
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from kummerle import logs
from report import machine, whole, write_section

from drivers import open_source
from vmp.evaluate import read_relations, relation_error
from vmp.run import MappingRun
from vmp.source import Reference, Source, SourceReport
from vmp.types import BeamGeometry, FloatArray, ScanFrame, compose, relative

# name -> (heading drift, rad per metre travelled; distance scale; keep every n-th scan;
#          scans skipped at the start; keep every n-th beam)
PERTURBATIONS: dict[str, tuple[float, float, int, int, int]] = {
    "as logged": (0.0, 1.0, 1, 0, 1),
    "drift +1 deg/10 m": (math.radians(1.0) / 10.0, 1.0, 1, 0, 1),
    "drift -2 deg/10 m": (-math.radians(2.0) / 10.0, 1.0, 1, 0, 1),
    "scale +5 %": (0.0, 1.05, 1, 0, 1),
    "scale -5 %": (0.0, 0.95, 1, 0, 1),
    "every 2nd scan": (0.0, 1.0, 2, 0, 1),
    "from scan 500": (0.0, 1.0, 1, 500, 1),
    "every 2nd beam": (0.0, 1.0, 1, 0, 2),
}


class Perturbed:
    """A source whose frames are changed as one of :data:`PERTURBATIONS` says."""

    def __init__(self, source: Source, name: str) -> None:
        self.source, self.perturbation = source, name
        self.drift, self.scale, self.every, self.skip, self.beams = PERTURBATIONS[name]
        self.name = source.name

    @property
    def geometry(self) -> BeamGeometry:
        g = self.source.geometry
        return BeamGeometry(len(range(0, g.num_beams, self.beams)), g.angle_min,
                            g.angle_increment * self.beams, g.max_range)

    @property
    def length(self) -> int | None:
        n = self.source.length
        return None if n is None else len(range(self.skip, n, self.every))

    def __iter__(self) -> Iterator[ScanFrame]:
        last_odom: FloatArray | None = None  # the source's odometry at the frame before
        bent: FloatArray | None = None  # the perturbed odometry there
        for k, frame in enumerate(self.source):
            odom = frame.odom
            if odom is not None and (self.drift or self.scale != 1.0):
                if last_odom is None:
                    bent = odom.copy()
                else:
                    step = relative(last_odom, odom)
                    travelled = math.hypot(step[0], step[1])
                    step = np.array([self.scale * step[0], self.scale * step[1],
                                     step[2] + self.drift * travelled])
                    bent = compose(bent, step)
                last_odom = odom
                frame = dataclasses.replace(frame, odom=bent.copy())
            if k < self.skip or (k - self.skip) % self.every:
                continue
            if self.beams > 1:
                frame = dataclasses.replace(frame, ranges=frame.ranges[::self.beams],
                                            angle_increment=frame.angle_increment * self.beams)
            yield frame

    def reference(self) -> Reference | None:
        return None

    def report(self) -> SourceReport:
        return self.source.report()

    def close(self) -> None:
        self.source.close()


def one_run(task: tuple[str, str, str, str]) -> dict:
    """Map one log under one perturbation; its relation error and time."""
    name, log, relations, perturbation = task
    started = time.perf_counter()
    result = whole(MappingRun(Perturbed(open_source(log), perturbation)).run())
    err = relation_error(result.stamps, result.trajectory, read_relations(relations))
    scans = result.scans
    refused = result.pipeline.front.scan_odometry.fallbacks
    return {"log": name, "perturbation": perturbation, "trans": err.trans_mean,
            "rot": math.degrees(err.rot_mean), "relations": err.used, "scans": scans,
            "refused": refused / max(scans, 1), "seconds": time.perf_counter() - started}


def table(rows: list[dict], names: list[str], jobs: int) -> str:
    perts = list(PERTURBATIONS)
    lines = [
        "## Generalisation: the logs under perturbations", "",
        f"`python bench/generalise.py --jobs {jobs}` on {machine()}: every log with relations, "
        "mapped with the default configuration as logged and under each perturbation (the "
        "script's docstring says what each does). A cell: the mean translational relation "
        "error (m) over the relations whose two stamps have a mapped scan. Per log the median "
        "and the worst over the perturbations, and the median's ratio to the figure as logged.",
        "",
        "| log | " + " | ".join(perts) + " | median | worst | median / as logged |",
        "|---|" + "---|" * (len(perts) + 3)]
    for name in names:
        mine = {r["perturbation"]: r for r in rows if r["log"] == name}
        errs = [mine[p]["trans"] for p in perts if p in mine]
        if not errs:
            continue
        med, worst = statistics.median(errs), max(errs)
        base = mine["as logged"]["trans"] if "as logged" in mine else math.nan
        cells = " | ".join(f"{mine[p]['trans']:.4f}" if p in mine else "-" for p in perts)
        lines.append(f"| {name} | {cells} | {med:.4f} | {worst:.4f} | {med / base:.2f} |")
    lines += ["", "Scan odometry refused (the share of scans whose registration it did not "
              "trust, the wheels predicting alone), per log and perturbation:", "",
              "| log | " + " | ".join(perts) + " |", "|---|" + "---|" * len(perts)]
    for name in names:
        mine = {r["perturbation"]: r for r in rows if r["log"] == name}
        if mine:
            lines.append(f"| {name} | " + " | ".join(
                f"{100 * mine[p]['refused']:.1f} %" if p in mine else "-" for p in perts) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", help="these logs (intel, intel-first5505, aces, fr079)")
    ap.add_argument("--perturbations", nargs="+", choices=list(PERTURBATIONS),
                    help="these perturbations (default: all)")
    ap.add_argument("--jobs", type=int, default=2, help="runs at once (default 2)")
    args = ap.parse_args()
    found = [(n, log, rel) for n, log, rel in logs() if not args.only or n in args.only]
    if not found:
        raise SystemExit(f"none of {args.only} among the logs with relations")
    perts = args.perturbations or list(PERTURBATIONS)
    tasks = [(n, str(log), str(rel), p) for n, log, rel in found for p in perts]
    # The longest first, so that two workers finish together.
    tasks.sort(key=lambda t: -Path(t[1]).stat().st_size / (2 if "2nd scan" in t[3] else 1))
    rows = []
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=context) as pool:
        for row in pool.map(one_run, tasks):
            rows.append(row)
            print(f"{row['log']:<16} {row['perturbation']:<18} {row['trans']:.4f} m "
                  f"{row['rot']:.2f} deg ({row['relations']} relations, {row['scans']} scans, "
                  f"scan odometry refused {100 * row['refused']:.1f} %, {row['seconds']:.0f} s)",
                  flush=True)
    text = table(rows, [n for n, _, _ in found], args.jobs)
    print(text)
    if not args.only and not args.perturbations:
        write_section("generalise", text)


if __name__ == "__main__":
    main()
