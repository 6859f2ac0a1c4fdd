"""The Kuemmerle benchmark: every log in ../shared/data with a relations file, default settings.

Run: python bench/kummerle.py [--only intel] [--repeat 1] [--no-kiss]

For each log it runs, in turn, KISS-ICP (odometry only, voxel 0.25 m, 2 threads; kiss-icp is in
the bench extra) and ``vmp map LOG`` as whole processes, timing each from outside, then scores
vmp-slam's trajectory on the log's relations (Kuemmerle et al. 2009: the error of every
relative motion between two stamped poses). It prints, per log, the translational and
rotational error (mean +- std), the loop edges in the graph and how many the robust adjustment
down-weighted, the wall time, the real-time factor and the ratio to KISS-ICP's time (the
median of the ratios of each pair run in turn, wall and CPU: user plus system time of the
process and its threads, which another load on the machine moves less); writes the
table beside the published figures into docs/benchmarks.md and each map to
docs/maps/kummerle_NAME.png. Each ``vmp map`` goes to a temporary results folder.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from report import machine, run_timed, write_section

from vmp.evaluate import read_relations, relation_error
from vmp.tum import read_tum

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "data"
MAPS = HERE.parent / "docs" / "maps"
# Published on the full data sets (Hess et al. 2016, tables II and V; GM from Kuemmerle et
# al. 2009), by the folder of the log: (Cartographer m, deg; graph mapping m, deg). On the
# Intel folder's first part (intel-first5505) they are the whole run's, for comparison only.
PUBLISHED = {"intel": (0.0229, 0.453, 0.031, 1.3), "aces": (0.0375, 0.373, 0.044, 0.4),
             "fr079": (0.0452, 0.538, 0.056, 0.6)}


def logs(only: str | None = None) -> list[tuple[str, Path, Path]]:
    """(name, log, relations) for every log in a folder of the data that holds a relations
    file (the Intel folder: its whole run and its first part), named by the log's file; only
    the one named ``only``, when given. The bench ends with a message when there is none."""
    out = []
    for rel in sorted(DATA.glob("*/*.relations")):
        for log in sorted(rel.parent.iterdir()):
            if not (log.suffixes[-2:] == [".clf", ".gz"] or log.suffix == ".clf"):
                continue
            name = log.name.split(".")[0]
            if only in (None, name):
                out.append((name, log, rel))
    if not out:
        raise SystemExit(f"no log with a relations file under {DATA}"
                         + (f" named {only}" if only else ""))
    return out


def vmp_map(log: Path, out: Path) -> tuple[float, float]:
    return run_timed([sys.executable, "-m", "vmp", "map", str(log), "--out", str(out), "-q"])


def kiss_icp(log: Path) -> tuple[float, float]:
    return run_timed([sys.executable, str(HERE / "kiss_icp_odometry.py"), str(log),
                  "--voxel", "0.25", "--threads", "2"])


def measure(name: str, log: Path, relations: Path, repeat: int, kiss: bool, work: Path) -> dict:
    runs, kiss_runs = [], []  # (wall, cpu) of each
    for k in range(repeat):
        if kiss:
            kiss_runs.append(kiss_icp(log))
        runs.append(vmp_map(log, work / f"{name}-{k}"))
    folder = work / f"{name}-{repeat - 1}" / "latest"
    stamps, poses = read_tum(folder / "trajectory.tum")
    err = relation_error(stamps, poses, read_relations(relations))
    metrics = json.loads((folder / "metrics.json").read_text())
    MAPS.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(folder / "grid.png", MAPS / f"kummerle_{name}.png")
    duration = float(stamps.max() - stamps.min())
    wall = statistics.median(w for w, _ in runs)
    row = {"name": name, "scans": len(stamps), "trans": err.trans_mean, "trans_std": err.trans_std,
           "rot": math.degrees(err.rot_mean), "rot_std": math.degrees(err.rot_std),
           "relations": err.used, "loops": metrics.get("loop edges in the graph", 0),
           "down": metrics.get("loop edges down-weighted", 0), "wall": wall,
           "cpu": statistics.median(c for _, c in runs),
           "delay": metrics.get("odometry delay learned (s)", 0.0),
           "refused": metrics.get("scan odometry: fell back to the wheels", 0) / len(stamps),
           "folder": relations.stem, "rt": duration / wall, "kiss": None}
    kiss_text = ""
    if kiss_runs:
        # ratios of the runs made in turn, then their median: each pair met the same load
        row.update(kiss=statistics.median(w for w, _ in kiss_runs),
                   kiss_cpu=statistics.median(c for _, c in kiss_runs),
                   ratio=statistics.median(a[0] / b[0]
                                           for a, b in zip(runs, kiss_runs, strict=True)),
                   cpu_ratio=statistics.median(a[1] / b[1]
                                               for a, b in zip(runs, kiss_runs, strict=True)))
        kiss_text = (f", KISS-ICP {row['kiss']:.1f} s (x{row['ratio']:.1f} in turn; CPU "
                     f"{row['cpu']:.1f} s against {row['kiss_cpu']:.1f} s, "
                     f"x{row['cpu_ratio']:.1f})")
    print(f"{name}: {row['trans']:.4f} +- {row['trans_std']:.4f} m, {row['rot']:.2f} +- "
          f"{row['rot_std']:.2f} deg on {row['relations']} relations; {row['loops']} loop edges "
          f"({row['down']} down-weighted); odometry delay {row['delay']:.3f} s; scan odometry "
          f"refused {100 * row['refused']:.1f} % of the scans; "
          f"{wall:.1f} s for {duration:.0f} s of data "
          f"({row['rt']:.0f}x real time){kiss_text}", flush=True)
    return row


def table(rows: list[dict], repeat: int) -> str:
    lines = ["## Kuemmerle benchmark", "",
             f"`python bench/kummerle.py --repeat {repeat}` on {machine()}: every log in "
             "`../shared/data` with a relations file, mapped by `vmp map LOG` with the default "
             "configuration; times are whole processes (median of the repeats), KISS-ICP "
             "(odometry only, voxel 0.25 m, 2 threads) run in turn on the same log; the "
             "ratios are medians of the ratios of the pairs run in turn, of wall time and of "
             "CPU time (user + system, all threads). Published figures are on the full data "
             "sets: beside the Intel log's first part (its first 1,089 s, intel-first5505) "
             "they are the whole run's. \"Scan odometry refused\": the share of scans whose "
             "registration scan odometry did not trust, the wheels predicting alone.", "",
             "| log | vmp-slam trans (m) | vmp-slam rot (deg) | loop edges (down-weighted) | "
             "odometry delay learned | scan odometry refused | wall | real time | / KISS-ICP | "
             "CPU / KISS-ICP CPU | Cartographer | graph mapping |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        pub = PUBLISHED.get(r["folder"])
        whole = "" if r["name"] == r["folder"] else " (whole run)"
        cart = f"{pub[0]} m, {pub[1]} deg{whole}" if pub else "-"
        gm = f"{pub[2]} m, {pub[3]} deg{whole}" if pub else "-"
        ratio = f"{r['ratio']:.1f} ({r['kiss']:.1f} s)" if r["kiss"] else "-"
        cpu = (f"{r['cpu_ratio']:.1f} ({r['cpu']:.1f} s / {r['kiss_cpu']:.1f} s)"
               if r["kiss"] else "-")
        lines.append(f"| {r['name']} ({r['relations']} relations) | {r['trans']:.4f} +- "
                     f"{r['trans_std']:.4f} | {r['rot']:.2f} +- {r['rot_std']:.2f} | "
                     f"{r['loops']} ({r['down']}) | {r['delay']:.3f} s | "
                     f"{100 * r['refused']:.1f} % | {r['wall']:.1f} s | "
                     f"{r['rt']:.1f}x | "
                     f"{ratio} | {cpu} | {cart} | {gm} |")
    lines += ["", "Maps: " + ", ".join(f"[{r['name']}](maps/kummerle_{r['name']}.png)"
                                        for r in rows) + ".", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="only this log (its file's name before the suffixes: intel, "
                    "intel-first5505, aces, fr079)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per log, median time kept")
    ap.add_argument("--no-kiss", action="store_true", help="do not time KISS-ICP")
    args = ap.parse_args()
    found = logs(args.only)
    with tempfile.TemporaryDirectory() as tmp:
        rows = [measure(name, log, rel, args.repeat, not args.no_kiss, Path(tmp))
                for name, log, rel in found]
    if args.only is None:
        write_section("kummerle", table(rows, args.repeat))


if __name__ == "__main__":
    main()
