"""``vmp batch``: many logs, seeds and settings mapped at once on Dask, one table of figures.

:func:`plan` turns what a user types (logs, folders of logs, scenarios, ``scenario:1..8``
ranges, ``--set section.key=V1,V2`` sweeps) into :class:`Job` s; :func:`run_job` maps one
through the one runner (:class:`~vmp.run.MappingRun`), writes its results folder and
returns its row (it never raises: a failure is the row's status); :func:`run_batch` runs
the jobs as Dask tasks on a local cluster of worker processes or on a given scheduler (or
one after another in this process), and :func:`write_table` writes the rows as CSV and
Markdown. The benchmarks use the same functions.
"""

from __future__ import annotations

import argparse
import csv
import io
import itertools
import math
import os
import re
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vmp.cli.interrupt import handled_interrupt
from vmp.errors import InputError
from vmp.fileio import parse_yaml

__all__ = ["Job", "add_parser", "plan", "run", "run_batch", "run_job", "write_table"]

RANGE = re.compile(r"^(?P<name>[^:]+):(?P<first>\d+)\.\.(?P<last>\d+)$")
TIMING = ("mapping (s)", "real-time factor")  # the columns that differ from run to run
INSTALL = ("vmp batch needs Dask: pip install 'vmp-slam[batch]' "
           "(or: pip install 'dask[distributed]')")


@dataclass(frozen=True)
class Job:
    """One run of a batch: a source (a recording's path or a scenario), a seed, settings."""

    source: str
    seed: int | None = None
    settings: tuple[tuple[str, Any], ...] = ()  # (section.key, value) over the defaults
    out: str = "results"  # the folder that receives this run's results folder
    timeout: float | None = None  # seconds, then the run ends and is reported so
    scans: int | None = None  # map only the first this many scans
    config: str | None = None  # a configuration file the settings apply over (else defaults)

    @property
    def label(self) -> str:
        name = Path(self.source).name if os.sep in self.source else self.source
        return name if self.seed is None else f"{name}:{self.seed}"


def _recordings_in(folder: Path) -> list[Path]:
    from drivers.open import RECORDING_SUFFIXES

    found = [p for p in sorted(folder.iterdir())
             if p.is_file() and p.suffix in RECORDING_SUFFIXES and not p.name.startswith(".")]
    return found + [p for p in sorted(folder.iterdir()) if (p / "metadata.yaml").is_file()]


def _sources(texts: Sequence[str]) -> list[tuple[str, int | None]]:
    """(source, seed) for each log, each log in a folder, each scenario and seed range."""
    out: list[tuple[str, int | None]] = []
    for text in texts:
        m = RANGE.match(text)
        path = Path(text)
        if m:
            first, last = int(m["first"]), int(m["last"])
            if last < first:
                raise InputError(f"{text}: the range runs backwards ({first}..{last})")
            out += [(m["name"], seed) for seed in range(first, last + 1)]
        elif path.is_dir() and not (path / "metadata.yaml").is_file():
            logs = _recordings_in(path)
            if not logs:
                raise InputError(f"{text}: a folder without recordings")
            out += [(str(p), None) for p in logs]
        else:
            out.append((text, None))
    return out


def _value(text: str, where: str) -> Any:
    try:
        return parse_yaml(text, where)
    except InputError as exc:
        raise InputError(f"{where}: {text[:80]!r} is not a value") from exc


def _sweep(sets: Sequence[str]) -> list[tuple[tuple[str, Any], ...]]:
    """Every combination of the ``section.key=V1,V2,...`` settings (one empty one if none)."""
    axes = []
    for item in sets:
        key, eq, values = item.partition("=")
        key = key.strip()
        if not eq or key.count(".") != 1 or not values.strip():
            raise InputError(f"--set {item!r}: expected section.key=V1,V2,... "
                             "(e.g. milestones.method=cca,dct)")
        axes.append([(key, _value(v.strip(), f"--set {key}")) for v in values.split(",")])
    return [tuple(combo) for combo in itertools.product(*axes)]


def config_for(settings: tuple[tuple[str, Any], ...], base: str | None = None):
    """The configuration of file ``base`` (default: the built-in one) with ``settings``
    applied over it (checked as a file's would be)."""
    from vmp.config import MappingConfig, config_from_dict, config_to_dict, load_config

    doc = config_to_dict(load_config(base) if base else MappingConfig())
    for key, value in settings:
        section, name = key.split(".")
        if not isinstance(doc.get(section), dict):
            raise InputError(f"--set {key}: {section}: unknown section; expected one of "
                             f"{', '.join(sorted(doc))}")
        if name not in doc[section]:
            raise InputError(f"--set {key}: unknown key; expected one of "
                             f"{', '.join(sorted(doc[section]))}")
        doc[section][name] = value
    return config_from_dict(doc, "--set")


def plan(sources: Sequence[str], sets: Sequence[str] = (), out: str | Path = "results",
         timeout: float | None = None, scans: int | None = None,
         config: str | Path | None = None) -> list[Job]:
    """The jobs for every source, seed and combination of settings (settings checked now,
    so that a typo fails before any work)."""
    combos = _sweep(sets)
    base = None if config is None else str(config)
    for combo in combos:
        config_for(combo, base)
    return [Job(src, seed, combo, str(out), timeout, scans, base)
            for src, seed in _sources(sources) for combo in combos]


def _relations_beside(source: str) -> Path | None:
    """The Kümmerle relations file beside a log: the only one in its folder, or the one whose
    name begins the log's."""
    path = Path(source)
    if not path.is_file():
        return None
    found = sorted(path.parent.glob("*.relations"))
    if len(found) == 1:
        return found[0]
    named = [r for r in found if path.name.startswith(r.stem)]
    return named[0] if len(named) == 1 else None


def _row(job: Job) -> dict[str, Any]:
    row: dict[str, Any] = {"source": job.label, "seed": job.seed}
    row.update({key: value for key, value in job.settings})
    row.update({"scans": None, "mapping (s)": None, "real-time factor": None, "ATE (m)": None,
                "relation error (m)": None, "relation error (deg)": None,
                "loop edges": None, "wrong corrections": None, "status": "ok", "results": ""})
    return row


def run_job(job: Job) -> dict[str, Any]:
    """Map one job into a results folder under ``job.out``; its row of figures. Never raises:
    a bad source, a crash or the time limit is the row's status."""
    from drivers import open_source
    from vmp.evaluate import read_relations, relation_error, wrong_corrections
    from vmp.folders import mark_complete, new_results_dir
    from vmp.run import MappingRun

    row = _row(job)
    try:
        source = open_source(job.source, seed=job.seed, scans=job.scans)
        run = MappingRun(source, config_for(job.settings, job.config), label=job.label,
                         scans=job.scans)
        timer = None
        if job.timeout is not None:
            timer = threading.Timer(job.timeout, run.stop, args=("timeout",))
            timer.daemon = True
            timer.start()
        try:
            result = run.run()
        finally:
            if timer is not None:
                timer.cancel()
        name = source.name + ("" if job.seed is None else f"-seed{job.seed}") + "".join(
            f"-{k.split('.')[1]}={v}" for k, v in job.settings)
        folder = new_results_dir(Path(job.out), name)
        metrics = result.write(folder, threads=_worker_threads())
        mark_complete(folder)
        row["results"] = str(folder)
        _figures(row, result, metrics)
        relations = _relations_beside(job.source)
        if relations is not None:
            err = relation_error(result.stamps, result.trajectory, read_relations(relations))
            row["relation error (m)"] = err.trans_mean
            row["relation error (deg)"] = math.degrees(err.rot_mean)
        if result.reference is not None and result.reference.truth:
            row["wrong corrections"] = len(wrong_corrections(result.corrections,
                                                             result.reference.poses))
        if result.interrupted == "timeout":
            row["status"] = f"timeout after {job.timeout:g} s ({result.scans} scans mapped)"
        elif result.interrupted:
            row["status"] = f"interrupted by {result.interrupted}"
    except InputError as exc:
        row["status"] = f"error: {exc}"
    except Exception as exc:  # a crash is this row's, the others go on
        row["status"] = f"crash: {type(exc).__name__}: {exc}"
    return row


def _worker_threads() -> int | None:
    """The threads of the Dask worker running this task, or None outside one (one run at a
    time: every core): a run unites its free space with no more than its worker's share of
    the cores (why: :func:`vmp.export.free_space_contours`)."""
    try:
        from distributed import get_worker

        return get_worker().state.nthreads
    except (ImportError, ValueError):  # not in a worker
        return None


def _figures(row: dict[str, Any], result, metrics: dict) -> None:
    row["scans"] = result.scans
    row["mapping (s)"] = result.mapping_time
    duration = metrics.get("data duration (s)")
    row["real-time factor"] = duration / result.mapping_time if duration else None
    ate = [v for k, v in metrics.items() if k.startswith("ATE") and "odometry" not in k]
    row["ATE (m)"] = ate[0] if ate else None
    row["loop edges"] = metrics.get("loop edges in the graph", 0)


def _client(workers: int | None, scheduler: str | None):
    """A Dask client on ``scheduler`` or on a new local cluster of worker processes."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:
        raise InputError(INSTALL) from exc
    if scheduler:
        try:
            return Client(scheduler, timeout="10s"), None
        except OSError as exc:
            raise InputError(f"--scheduler {scheduler}: cannot reach it ({exc})") from exc
    n = workers or max(1, os.cpu_count() or 1)
    import dask

    # Dask starts its worker processes with MALLOC_TRIM_THRESHOLD_=65536, which hands every
    # freed block above 64 KiB back to the system; the mapper allocates and frees such arrays
    # for every scan, and each comes back with fresh page faults (about a tenth of a run's
    # time: docs/benchmarks.md, "vmp batch"). Unset (None) for our workers; the other
    # settings (one BLAS thread per worker) stay. Without a dashboard nobody sees the
    # workers' sampling profiler, which wakes every 10 ms, nor needs the event loop's 20 ms
    # ticks: both take the GIL from the mapping thread, so both are off.
    quiet = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
             "distributed.worker.profile.enabled": False,
             "distributed.admin.tick.interval": "1s"}
    with dask.config.set(quiet):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None)
    return Client(cluster), cluster


def run_batch(jobs: Sequence[Job], *, workers: int | None = None, scheduler: str | None = None,
              serial: bool = False, on_row: Callable[[dict], None] | None = None,
              on_running: Callable[[list[Job]], None] | None = None
              ) -> tuple[list[dict | None], bool]:
    """Rows of every job, in the jobs' order (None for a job cancelled by Ctrl-C), and
    whether Ctrl-C cut the batch short. ``serial`` runs them here, one after another;
    otherwise each is a Dask task on ``scheduler`` or on a local cluster of ``workers``
    processes. ``on_row`` is told of each row as it arrives, ``on_running`` of the jobs
    running now whenever that changes (checked every second; on a cluster, the first of the
    jobs handed to the workers, as many as they have threads)."""
    rows: list[dict | None] = [None] * len(jobs)
    if serial:
        try:
            for i, job in enumerate(jobs):
                if on_running is not None:
                    on_running([job])
                rows[i] = row = run_job(job)
                if on_row is not None:
                    on_row(row)
                if row["status"].startswith("interrupted"):  # Ctrl-C ended this run
                    return rows, True
        except KeyboardInterrupt:
            handled_interrupt()
            return rows, True
        return rows, False
    from distributed import TimeoutError as DaskTimeout
    from distributed import wait

    client, cluster = _client(workers, scheduler)
    futures = client.map(run_job, list(jobs), pure=False)
    where = {f.key: i for i, f in enumerate(futures)}
    running: list[int] = []
    try:
        pending = set(futures)
        while pending:
            try:
                done, pending = wait(pending, timeout=1.0, return_when="FIRST_COMPLETED")
            except DaskTimeout:
                done = set()
            for future in sorted(done, key=lambda f: where[f.key]):
                i = where[future.key]
                try:
                    rows[i] = future.result()
                except Exception as exc:  # the worker died under the task
                    rows[i] = dict(_row(jobs[i]), status=f"lost: {type(exc).__name__}: {exc}")
                if on_row is not None:
                    on_row(rows[i])
            if on_running is not None and pending:
                # A worker is handed more tasks than it has threads; it runs them in the
                # order they were submitted, so the first of them, a thread each, run now.
                threads = sum(w.get("nthreads", 1)
                              for w in client.scheduler_info()["workers"].values())
                now = sorted(where[k] for keys in client.processing().values() for k in keys
                             if k in where and rows[where[k]] is None)[:threads]
                if now != running:
                    running = now
                    on_running([jobs[i] for i in now])
        return rows, False
    except KeyboardInterrupt:
        handled_interrupt()
        client.cancel(futures)
        return rows, True
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def write_table(rows: Sequence[dict], out: Path) -> str:
    """Write the rows to ``out``/batch.csv and batch.md; returns the Markdown table."""
    from vmp.fileio import atomic_write

    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    text = io.StringIO()
    w = csv.DictWriter(text, columns, lineterminator="\n")
    w.writeheader()
    w.writerows([{k: ("" if r.get(k) is None else r.get(k)) for k in columns} for r in rows])
    md = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    md += ["| " + " | ".join(_cell(r.get(k)).replace("|", "/") for k in columns) + " |"
           for r in rows]
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(out / "batch.csv", "w") as f:
        f.write(text.getvalue())
    with atomic_write(out / "batch.md", "w") as f:
        f.write("\n".join(md) + "\n")
    return "\n".join(md)


# -- the command ----------------------------------------------------------------------------
def add_parser(sub: argparse._SubParsersAction) -> None:
    from vmp.cli.args import positive_float, positive_int

    bp = sub.add_parser(
        "batch", help="map many logs, seeds and settings at once (Dask), one table of figures",
        description="Map every source as one Dask task through the same runner as 'vmp map', "
        "score it where a reference exists (a Kuemmerle relations file beside a log, a "
        "scenario's ground truth, GMapping's poses in a corrected log) and gather one table "
        "(printed, and written as batch.csv and batch.md in --out): source, seed, settings, "
        "scans, mapping time, real-time factor, ATE, relation errors, loop edges, wrong "
        "corrections, status. Each run also writes its usual results folder under --out. A "
        "source that fails (a bad log, a crash, --timeout) gets its error in its row and the "
        "others go on; Ctrl-C cancels the rest and writes the rows done. By default the tasks "
        "run on a local cluster of worker processes, one per core; --scheduler sends them to "
        "a running Dask cluster instead, whose workers must have vmp-slam installed and see "
        "the data at the same paths as this machine. Needs the batch extra: "
        "pip install 'vmp-slam[batch]'.",
        epilog="examples:\n"
        "  vmp batch office corridor:1..4 ../shared/data/intel/intel-first5505.clf.gz\n"
        "  vmp batch office:1..8 --set milestones.method=cca,dct --out sweep\n"
        "  vmp batch ../shared/data/radish_gmapping_corrected --timeout 1800\n"
        "  vmp batch office:1..8 --scheduler tcp://10.0.0.5:8786   # an existing cluster\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    bp.add_argument("sources", nargs="+", metavar="SOURCE",
                    help="a recording, a folder of recordings, a scenario, or SCENARIO:A..B "
                    "(seeds A to B)")
    bp.add_argument("--out", type=Path, default=Path("results/batch"),
                    help="folder for the table and every run's results folder "
                    "(default: results/batch)")
    bp.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=V1,V2",
                    help="run every value (repeatable: every combination) on every source; "
                    "the settings become columns of the table")
    bp.add_argument("--config", type=Path, help="mapping configuration YAML for every run "
                    "(--set applies over it; default: built-in)")
    bp.add_argument("--workers", type=positive_int,
                    help="worker processes of the local cluster (default: one per core)")
    bp.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                    help="a running Dask scheduler to send the tasks to (paths must be valid "
                    "on its workers)")
    bp.add_argument("--serial", action="store_true",
                    help="no Dask: one run after another in this process")
    bp.add_argument("--timeout", type=positive_float, metavar="S",
                    help="end a run after S seconds of mapping (its row says so)")
    bp.add_argument("--scans", type=positive_int, help="map only the first N scans of each")
    bp.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    bp.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from vmp.progress import Progress

    if args.serial and (args.scheduler or args.workers):
        raise InputError("--serial runs here: leave out --scheduler and --workers")
    jobs = plan(args.sources, args.set, args.out, args.timeout, args.scans, args.config)
    if not args.serial:
        try:
            import distributed  # noqa: F401 - only to say how to install it
        except ImportError as exc:
            raise InputError(INSTALL) from exc
    progress = Progress(len(jobs), "batch", unit="runs", enabled=not args.quiet,
                        tick=1.0)
    running: list[str] = []
    progress.activity = lambda: f"running {', '.join(running)}" if running else ""

    def arrived(row: dict) -> None:
        if row["source"] in running:
            running.remove(row["source"])
        if not row["status"].startswith("ok"):
            progress.status = f"last problem: {row['source']}"
        progress.update()

    def now_running(now: list[Job]) -> None:
        running[:] = [job.label for job in now]

    started = time.perf_counter()
    rows, cut = run_batch(jobs, workers=args.workers, scheduler=args.scheduler,
                          serial=args.serial, on_row=arrived, on_running=now_running)
    progress.close()
    done = [r for r in rows if r is not None]
    table = write_table(done, args.out)
    print(table)
    failed = sum(not r["status"].startswith("ok") for r in done)
    print(f"\n{len(done)} of {len(jobs)} runs in {time.perf_counter() - started:.0f} s"
          f"{f', {failed} failed' if failed else ''}; table in {args.out / 'batch.csv'} and "
          f"{args.out / 'batch.md'}", file=sys.stderr)
    if cut:
        print("vmp batch: interrupted; the rows of the runs done are written", file=sys.stderr)
        return 130
    return 1 if failed else 0
