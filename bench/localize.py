"""Localization in a saved map, from no initial pose: simulated worlds and real logs.

Run: python bench/localize.py [--sim office warehouse lab corridor] [--runs 20] [--no-real]
     python bench/localize.py --no-sim --only intel [--splits 0.4 0.6] [--offsets 4 8 12]

Simulated: each scenario is mapped with its own seed; then, in each of ``--runs`` runs with
another seed (100, 101, ...), the localizer starts with no pose at a random scan of that run,
follows it for 150 scans, is carried to another random place (3 m or more away; the odometry
does not see it) and follows 150 scans more. Per scenario: the runs localized within 30 scans of
the start and of the kidnap, the median scans it took, wrong fixes (declared localized more than
0.5 m from the truth), the scans still localized at the old place after the kidnap (before the
scans stop fitting there), the runs still localized there 30 scans after it, and the scans
ambiguous; and how many starts and kidnaps the world itself tells apart from every other place
on the path within 30 scans (:func:`look_alikes`), how many of those were localized, and
how many look the same as another place on every beam of those 30 scans.

Real (every log in ../shared/data with a relations file): the first half of the log is mapped,
the second half localized in that map from no pose, and scored on the relations whose two
stamps both lie in the second half, beside the whole log mapped in one go on the same
relations, and how many of its scans were localized where the first half passed (within
1 m, facing within 45 degrees: elsewhere its map may not hold what a scan sees). Also the
tracking speed against the mapping speed (scans per second of the localizer's steps that
began and ended localized, and of the whole log's mapping; ``--repeat`` runs of each in turn,
medians), and two second sessions scored on all the log's relations:
the second half mapped on in the first half's map (``vmp map --continue``), and both halves
mapped apart and merged (``vmp merge``). One run's share of scans localized is one draw, so
the log is also cut at each of ``--splits`` (default 0.35, 0.4, 0.45, 0.55, 0.6, 0.65 of its
scans): the part before mapped, the rest localized in that map, and scored the same way, with
the places declared farther than 0.5 m from where the whole log mapped in one go puts the robot
(its pose carried into the cut map's frame at the map's scan nearest the declared place): the
real logs' wrong fixes, as far as one go's poses tell. (Started a few scans late, ``--offsets``,
the runs fall back onto a few shared paths of decisions: ACES started 36, 40 and 44 scans late
is localized on 39.4 % of its scans each time.)

Writes the tables into docs/benchmarks.md (the simulated one when all four scenarios ran 20
runs, the real one when every log ran).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))

from kummerle import logs
from report import machine, whole, write_section

from drivers import open_source
from drivers.simulator import Simulator
from drivers.splice import carried
from vmp.evaluate import read_relations, relation_error, relations_between
from vmp.localization import WRONG_FIX, LocalizationResult, LocalizationRun
from vmp.localizer import MIN_SCORE, REACH, State
from vmp.mapfile import MapData, load_map, save_map
from vmp.places import Places
from vmp.registration import MIN_POINTS
from vmp.results import Result
from vmp.run import MappingRun
from vmp.source import FrameList, Reference
from vmp.types import FloatArray, compose, inverse, relative

STRETCH = 150  # scans before and after the kidnap
WITHIN = 30  # the goal: localized within this many scans of a start or a kidnap
PASSED_XY = 1.0  # a second-half scan this near (m) ...
PASSED_THETA = math.radians(45.0)  # ... and facing this close to a first-half scan: "passed"
CARRIED = 3.0  # the kidnap carries the robot at least this far (m)
# A place on the path looks like another when every scan from it matches the other's this
# closely (m) on this share of the beams (:func:`look_alikes`).
LOOK_ALIKE_RANGE = 0.1
LOOK_ALIKE_BEAMS = 0.95
SIM = ("office", "warehouse", "lab", "corridor")


def saved(result: Result) -> MapData:
    """A mapping run's map as a saved one: written to a map file and read back, so that
    mapping on in it leaves the run's own map alone."""
    p = result.pipeline
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "map.vmpmap"
        save_map(path, p.map, p.milestones, p.back.graph, {}, result.trajectory)
        return load_map(path)


def recovery(res: LocalizationResult, start: int, stop: int) -> int | None:
    """Scans from ``start`` to the first scan before ``stop`` localized near the truth."""
    err = res.errors()
    for k in range(start, stop):  # a few dozen at most
        if res.states[k] is State.LOCALIZED and err[k] <= WRONG_FIX:
            return k - start
    return None


def look_alikes(sim: Simulator, truth: FloatArray, start: int) -> tuple[bool, bool]:
    """Whether the world itself tells the place of scan ``start`` from every other place on
    the path within :data:`WITHIN` scans, and whether some other place looks the same on
    every beam. A look-alike is another scan pose of the run (0.5 m or more away) from which
    the same motion would have seen the same, every scan within :data:`LOOK_ALIKE_RANGE` on
    :data:`LOOK_ALIKE_BEAMS` of its beams (ranges cast in the world without noise, no return
    alike); where there is one, no localizer can say where the robot is that soon (the
    warehouse's middle aisle between two rows of identical bays: the bay 2.5 m on looks the
    same until an end of the rows comes within the 8 m of the scanner). Where one looks the
    same on every beam of every scan, nothing in the scans can tell the two apart, however
    well the localizer weighs them."""
    stop = min(start + WITHIN, len(truth))
    motion = np.array([relative(truth[start], p) for p in truth[start:stop]])
    seen = sim.ranges_at(truth[start:stop])
    others = truth[np.hypot(*(truth[:, :2] - truth[start, :2]).T) > WRONG_FIX]
    every = np.ones(len(others), dtype=bool)  # alike on every beam so far
    for k in range(len(motion)):  # the candidates thinned scan after scan: a few dozen left
        if len(others) == 0:
            return True, False
        c, s = np.cos(others[:, 2]), np.sin(others[:, 2])
        dx, dy, dth = motion[k]
        moved = np.column_stack([others[:, 0] + c * dx - s * dy, others[:, 1] + s * dx + c * dy,
                                 others[:, 2] + dth])
        cast = sim.ranges_at(moved)
        both_none = np.isinf(cast) & np.isinf(seen[k])
        with np.errstate(invalid="ignore"):  # inf - inf: no return from either
            close = np.abs(cast - seen[k]) <= LOOK_ALIKE_RANGE
        alike = (both_none | close).mean(axis=1)
        keep = alike >= LOOK_ALIKE_BEAMS
        others, every = others[keep], every[keep] & (alike[keep] == 1.0)
    return len(others) == 0, bool(every.any())


def sim_run(name: str, smap: MapData, seed: int) -> dict:
    sim = open_source(name, seed=seed)
    frames = list(sim)
    truth = sim.reference().poses
    n = len(frames)
    rng = np.random.default_rng(seed)
    a = int(rng.integers(0, n - STRETCH))
    end = truth[a + STRETCH - 1]
    far = np.flatnonzero(np.hypot(*(truth[: n - STRETCH, :2] - end[:2]).T) >= CARRIED)
    b = int(rng.choice(far))
    joined = carried([frames[a:a + STRETCH], frames[b:b + STRETCH]])
    ref = Reference(np.vstack([truth[a:a + STRETCH], truth[b:b + STRETCH]]), "ground truth",
                    True)
    res = whole(LocalizationRun(smap, FrameList(joined, name, ref)).run())
    err = res.errors()
    loc = res.localized
    starts = res.declarations
    after = np.arange(res.scans) >= STRETCH
    return {"seed": seed, "start": recovery(res, 0, STRETCH),
            "kidnap": recovery(res, STRETCH, 2 * STRETCH),
            "alike": (look_alikes(sim, truth, a), look_alikes(sim, truth, b)),
            "wrong": int((err[starts] > WRONG_FIX).sum()),
            "stale": int((loc & after & (err > WRONG_FIX)).sum()),
            "ambiguous": sum(s is State.AMBIGUOUS for s in res.states),
            "rate": res.scans / res.time,
            "tracking": res.metrics().get("tracking: scans per second", math.nan)}


def simulated(names: list[str], runs: int) -> list[dict]:
    rows = []
    for name in names:
        mapped = whole(MappingRun(open_source(name)).run())
        smap = saved(mapped)
        results = [sim_run(name, smap, 100 + i) for i in range(runs)]
        both = [r["start"] for r in results] + [r["kidnap"] for r in results]
        ok = [k for k in both if k is not None and k <= WITHIN]
        alike = [r["alike"][0] for r in results] + [r["alike"][1] for r in results]  # as both
        told = [a[0] for a in alike]
        told_ok = [k for k, t in zip(both, told, strict=True)
                   if t and k is not None and k <= WITHIN]
        took = [k for k in both if k is not None]
        row = {"name": name, "runs": runs, "within": len(ok), "of": len(both),
               "told": sum(told), "told_within": len(told_ok),
               "same": sum(a[1] for a in alike),
               "median": statistics.median(took) if took else math.nan,
               "never": sum(k is None for k in both),
               "wrong": sum(r["wrong"] for r in results),
               "stale": statistics.median(r["stale"] for r in results),
               "stuck": sum(r["stale"] > WITHIN for r in results),
               "ambiguous": sum(r["ambiguous"] for r in results),
               "rate": statistics.median(r["rate"] for r in results),
               "tracking": statistics.median(r["tracking"] for r in results),
               "map_rate": mapped.scans / mapped.mapping_time}
        print(f"{name}: {row['within']} of {row['of']} starts and kidnaps localized within "
              f"{WITHIN} scans (median {row['median']}, never {row['never']}); the world tells "
              f"{row['told']} of them from every other place on the path within {WITHIN} "
              f"scans, and {row['told_within']} of those were localized; {row['same']} look "
              f"the same as another place on every beam of {WITHIN} scans; wrong fixes "
              f"{row['wrong']}; scans at the old place after a kidnap (median) {row['stale']}, "
              f"runs still there after {WITHIN} scans {row['stuck']}; "
              f"ambiguous scans {row['ambiguous']}; localizing {row['rate']:.0f} scans/s, "
              f"tracking {row['tracking']:.0f}, mapping {row['map_rate']:.0f}", flush=True)
        rows.append(row)
    return rows


def passed(trajectory: FloatArray, half: int) -> np.ndarray:
    """For each scan of the second half: whether the first half passed there, within
    :data:`PASSED_XY` and facing within :data:`PASSED_THETA` (poses of one map of the whole
    log): where the first half's map can hold what the scan sees."""
    poses = np.asarray(trajectory, dtype=np.float64)
    first, second = poses[:half], poses[half:]
    dist, idx = cKDTree(first[:, :2]).query(second[:, :2])
    turn = np.abs((second[:, 2] - first[idx, 2] + math.pi) % math.tau - math.pi)
    return (dist <= PASSED_XY) & (turn <= PASSED_THETA)


def carried_at(pose: FloatArray, there: FloatArray, here: FloatArray) -> FloatArray:
    """``pose`` carried from one map's frame into another's at one scan, ``here`` its pose
    in the first and ``there`` in the second: two maps of one log bend apart over a
    building, but not at one place."""
    return compose(compose(there, inverse(here)), pose)


def explained(first_map: MapData, frames: list, half: int, one_go: FloatArray) -> np.ndarray:
    """For each scan of the second half: whether the first half's map explains it where it
    was taken: its points within the localizer's :data:`~vmp.localizer.REACH` score
    :data:`~vmp.localizer.MIN_SCORE` or more (:meth:`vmp.places.Places.score`) at one go's
    pose carried into the map's frame at the first-half scan nearest it
    (:func:`carried_at`). A wider test than :func:`passed`: a scan
    of a corridor the first half drove the other way is explained by its map. (The carried
    pose drifts with the distance to that scan, as the two maps bend apart: a scan taken
    far from the first half's path may be counted unexplained.)"""
    places = Places(first_map.map, first_map.milestones, first_map.trajectory)
    _, nearest = cKDTree(one_go[:half, :2]).query(one_go[half:, :2])
    out = np.zeros(len(frames) - half, dtype=bool)
    for s, k in enumerate(nearest):  # one score a scan, as the localizer's, not a hot path
        pose = carried_at(one_go[half + s], first_map.trajectory[k], one_go[k])
        points = frames[half + s].points()
        points = points[np.hypot(points[:, 0], points[:, 1]) <= REACH]
        out[s] = len(points) >= MIN_POINTS and places.score(points, pose) >= MIN_SCORE
    return out


def speed_rounds(name: str, frames: list, half: int, first_map: MapData,
                 rounds: int) -> list[tuple[float, float]]:
    """``rounds`` more (mapping, tracking) rates in scans per second, in turn: the whole log
    mapped, then its second half localized in its first half's saved map. (One run's ratio
    says little on a shared machine: its mapping of ACES may swing between 776 and 959
    scans a second from one run to the next.)"""
    out = []
    for _ in range(rounds):
        mapped = whole(MappingRun(FrameList(frames, name)).run())
        tracked = whole(LocalizationRun(first_map, FrameList(frames[half:], name)).run())
        out.append((mapped.scans / mapped.mapping_time,
                    tracked.metrics().get("tracking: scans per second", math.nan)))
    return out


def late_starts(name: str, frames: list, half: int, first_map: MapData, full: Result,
                relations: FloatArray, offsets: list[int]) -> list[tuple[int, float, float]]:
    """The second half localized again, started each of ``offsets`` scans late: (offset,
    share of scans localized, relation error of the localized scans less one go's on the same
    relations). One run's share is one draw: started 4 scans late, the Intel part's second
    half is localized on 50.6 % of its scans against 75.4 % started on time."""
    out = []
    for k in offsets:
        res = whole(LocalizationRun(first_map, FrameList(frames[half + k:], name)).run())
        inside = relations[np.minimum(relations[:, 0], relations[:, 1]) >= frames[half + k].stamp]
        loc = res.localized
        e_loc = relation_error(res.stamps[loc], res.poses[loc], inside)
        e_same = relation_error(full.stamps, full.trajectory,
                                relations_between(res.stamps[loc], inside))
        out.append((k, float(loc.mean()), e_loc.trans_mean - e_same.trans_mean))
    return out


def declared_off(res: LocalizationResult, cut_map: FloatArray, one_go: FloatArray,
                 cut: int) -> int:
    """The places ``res`` declared (:attr:`LocalizationResult.declarations`) farther than
    :data:`WRONG_FIX` from one go's pose of the scan (``one_go``, the whole log mapped), the
    declared pose carried into one go's frame by the two trajectories' poses of the first
    ``cut`` scans (``cut_map``, the map localized in) at the one nearest it: the two maps
    bend apart over a building, but not at one place."""
    off = 0
    for s in res.declarations:
        pose = res.poses[s]
        k = int(np.argmin(np.hypot(*(cut_map[:, :2] - pose[:2]).T)))
        e = relative(one_go[cut + s], carried_at(pose, one_go[k], cut_map[k]))
        off += bool(math.hypot(e[0], e[1]) > WRONG_FIX)
    return off


def split_points(name: str, frames: list, full: Result, relations: FloatArray,
                 splits: list[float]) -> list[tuple[float, float, float, int]]:
    """The log cut at each of ``splits`` (shares of its scans): the part before mapped, the
    rest localized in that map; (split, share of scans localized, relation error of the
    localized scans less one go's on the same relations, places declared off one go's poses:
    :func:`declared_off`)."""
    out = []
    for f in splits:
        cut = int(len(frames) * f)
        first = whole(MappingRun(FrameList(frames[:cut], name)).run())
        res = whole(LocalizationRun(saved(first), FrameList(frames[cut:], name)).run())
        inside = relations[np.minimum(relations[:, 0], relations[:, 1]) >= frames[cut].stamp]
        loc = res.localized
        e_loc = relation_error(res.stamps[loc], res.poses[loc], inside)
        e_same = relation_error(full.stamps, full.trajectory,
                                relations_between(res.stamps[loc], inside))
        out.append((f, float(loc.mean()), e_loc.trans_mean - e_same.trans_mean,
                    declared_off(res, first.trajectory, full.trajectory, cut)))
    return out


def real(only: str | None, repeat: int = 3, offsets: tuple[int, ...] = (),
         splits: tuple[float, ...] = ()) -> list[dict]:
    rows = []
    for name, log, rel_path in logs(only):
        frames = list(open_source(str(log)))
        half = len(frames) // 2
        relations = read_relations(rel_path)
        t0 = frames[half].stamp
        inside = relations[(np.minimum(relations[:, 0], relations[:, 1]) >= t0)]
        full = whole(MappingRun(FrameList(frames, name)).run())
        first = whole(MappingRun(FrameList(frames[:half], name)).run())
        first_map = saved(first)
        res = whole(LocalizationRun(first_map, FrameList(frames[half:], name)).run())
        loc = res.localized
        e_full = relation_error(full.stamps, full.trajectory, inside)
        e_loc = relation_error(res.stamps[loc], res.poses[loc], inside)
        # The same relations as the localized scans', mapped: the like-for-like comparison
        # (a robot is localized where the first half mapped, and not everywhere the second
        # half drives, so its relations are not a random sample of the second half's).
        e_same = relation_error(full.stamps, full.trajectory,
                                relations_between(res.stamps[loc], inside))
        first_fix = int(np.argmax(loc)) if loc.any() else None
        if full.scans != len(frames):
            raise SystemExit(f"{name}: the whole-log map placed {full.scans} of "
                             f"{len(frames)} scans; cannot pair its poses with the halves")
        seen = passed(full.trajectory, half)
        known = explained(first_map, frames, half, full.trajectory)
        # The speeds: this run's pair and repeat - 1 more pairs in turn; medians, and the
        # median of the pairs' ratios.
        pairs = [(full.scans / full.mapping_time,
                  res.metrics().get("tracking: scans per second", math.nan))]
        pairs += speed_rounds(name, frames, half, first_map, repeat - 1)
        map_rate = statistics.median(m for m, _ in pairs)
        tracking = statistics.median(t for _, t in pairs)
        ratios = [t / m for m, t in pairs]
        starts = [(0, float(loc.mean()), e_loc.trans_mean - e_same.trans_mean)]
        starts += late_starts(name, frames, half, first_map, full, relations, list(offsets))
        cuts = sorted([(0.5, float(loc.mean()), e_loc.trans_mean - e_same.trans_mean,
                        declared_off(res, first.trajectory, full.trajectory, half))]
                      + split_points(name, frames, full, relations, list(splits)))
        # A second session: the second half mapped on in the first half's map, and the two
        # halves mapped apart and merged (what 'vmp map --continue' and 'vmp merge' do).
        cont = whole(MappingRun(FrameList(frames[half:], name), saved=saved(first)).run())
        second = whole(MappingRun(FrameList(frames[half:], name)).run())
        merged = whole(MappingRun(FrameList(saved(second).frames(), name),
                                  saved=saved(first)).run())
        e_all = relation_error(full.stamps, full.trajectory, relations)
        e_cont = relation_error(cont.stamps, cont.trajectory, relations)
        e_merged = relation_error(merged.stamps, merged.trajectory, relations)
        row = {"name": name, "scans": res.scans, "first": first_fix, "share": float(loc.mean()),
               "lost": sum(s is State.LOST for s in res.states), "relations": len(inside),
               "used": e_loc.used, "loc": e_loc, "full": e_full, "same": e_same,
               "rate": res.scans / res.time, "map_rate": map_rate, "all": e_all,
               "tracking": tracking, "ratio": statistics.median(ratios), "ratios": ratios,
               "cont": e_cont, "merged": e_merged, "passed": float(seen.mean()),
               "starts": starts, "cuts": cuts,
               "passed_localized": float(loc[seen].mean()) if seen.any() else math.nan,
               "explained": float(known.mean()),
               "explained_localized": float(loc[known].mean()) if known.any() else math.nan}
        print(f"{name}: second half ({res.scans} scans) localized after {first_fix} scans, "
              f"{row['share']:.1%} of scans localized, {row['lost']} lost; where the first "
              f"half passed ({row['passed']:.1%} of the scans) {row['passed_localized']:.1%} "
              f"localized; where its map explains the scan ({row['explained']:.1%}) "
              f"{row['explained_localized']:.1%} localized; relations in the "
              f"second half: localized {e_loc.trans_mean:.4f} m, "
              f"{math.degrees(e_loc.rot_mean):.2f} deg on {e_loc.used} of {len(inside)}; "
              f"whole log mapped {e_same.trans_mean:.4f} m, {math.degrees(e_same.rot_mean):.2f} "
              f"deg on the same, {e_full.trans_mean:.4f} m, "
              f"{math.degrees(e_full.rot_mean):.2f} deg on {e_full.used}; localizing "
              f"{row['rate']:.0f} scans/s, tracking "
              f"{row['tracking']:.0f}, mapping {map_rate:.0f} scans/s (medians of "
              f"{len(pairs)} pairs in turn; tracking x{row['ratio']:.2f} of mapping, the "
              f"median of " + " / ".join(f"x{r:.2f}" for r in ratios) + "); whole log: mapped "
              f"{e_all.trans_mean:.4f} m, continued {e_cont.trans_mean:.4f} m "
              f"({e_cont.used} relations), merged {e_merged.trans_mean:.4f} m "
              f"({e_merged.used}); started late: " + ", ".join(
                  f"{k}: {share:.1%} {d:+.4f} m" for k, share, d in starts)
              + "; cut at: " + ", ".join(f"{f:g}: {share:.1%} {d:+.4f} m, {off} declared off"
                                         for f, share, d, off in cuts), flush=True)
        rows.append(row)
    return rows


def table(sim: list[dict], rows: list[dict], runs: int, repeat: int = 3) -> str:
    what = "simulated worlds" if sim else "real logs"
    cmd = "--no-real" if sim else "--no-sim"
    lines = [f"## Localization in a saved map: {what}", "",
             f"`python bench/localize.py {cmd}` on {machine()}, default configuration, no "
             "initial pose.", ""]
    if sim:
        lines += [f"Simulated: per scenario {runs} runs with seeds 100.., each started at a "
                  f"random scan and kidnapped after {STRETCH} scans to a random place "
                  f"{CARRIED:.0f} m or more away (the odometry does not see it). "
                  "\"Stale\" is the median number of scans still localized at the old place "
                  "after the kidnap, before the scans stop fitting there; \"stuck\" the runs "
                  f"still localized there after {WITHIN} scans (a kidnap to a place that looks "
                  "the same). \"Told apart\": the starts and kidnaps whose first "
                  f"{WITHIN} scans the world itself tells from those of every other place on "
                  "the path (no other scan pose 0.5 m or more away from which the same motion "
                  f"sees the same: every scan within {LOOK_ALIKE_RANGE:g} m on "
                  f"{LOOK_ALIKE_BEAMS:.0%} of its beams, cast without noise), and how many "
                  f"of those were localized within {WITHIN} scans: where the world does not "
                  "tell them apart, no localizer can say where the robot is that soon. "
                  "\"The same\": the starts and kidnaps with another place on the path from "
                  f"which every beam of those {WITHIN} scans reads within "
                  f"{LOOK_ALIKE_RANGE:g} m the same: a localizer that declared either would "
                  "be guessing.", "",
                  f"| scenario | localized within {WITHIN} scans (starts + kidnaps) | told "
                  "apart: of them, localized | the same on every beam | median "
                  "scans | never | wrong fixes | stale | stuck | ambiguous scans | scans/s: "
                  "localizing, tracking, mapping |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in sim:
            lines.append(f"| {r['name']} | {r['within']} of {r['of']} | "
                         f"{r['told']}: {r['told_within']} | {r['same']} | {r['median']} | "
                         f"{r['never']} | {r['wrong']} | {r['stale']} | {r['stuck']} | "
                         f"{r['ambiguous']} | "
                         f"{r['rate']:.0f}, {r['tracking']:.0f}, {r['map_rate']:.0f} |")
        lines.append("")
    if rows:
        lines += ["Real: the first half of each log mapped, the second half localized in it "
                  "from no pose; relations with both stamps in the second half. \"Where the "
                  "first half passed\": the second half's scans taken within "
                  f"{PASSED_XY:g} m of a first-half scan and facing within "
                  f"{math.degrees(PASSED_THETA):.0f} deg of it (poses of the whole log mapped "
                  "in one go), and how many of those were localized: elsewhere the first "
                  "half's map may not hold what the scan sees. \"Where its map explains the "
                  "scan\": the scans whose points score "
                  f"{MIN_SCORE:g} or more in the first half's map at one go's pose carried "
                  "into that map's frame at the nearest first-half scan (the localizer's "
                  "least score to declare a place), and how many of those were localized.",
                  "",
                  "| log | scans until localized | scans localized | where the first half "
                  "passed: scans, localized | where its map explains the scan: scans, "
                  "localized | lost | relations used | "
                  "localized: trans (m), rot (deg) | whole log mapped, the same relations | "
                  "whole log mapped, all relations of the second half | speed: "
                  "localizing, tracking, mapping (scans/s; tracking and mapping medians of "
                  f"{repeat} runs in turn) | tracking / mapping (median; each run's) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            a, b, c = r["loc"], r["same"], r["full"]
            lines.append(f"| {r['name']} | {r['first']} | {r['share']:.1%} | "
                         f"{r['passed']:.1%}, {r['passed_localized']:.1%} | "
                         f"{r['explained']:.1%}, {r['explained_localized']:.1%} | {r['lost']} | "
                         f"{a.used} of {r['relations']} | {a.trans_mean:.4f}, "
                         f"{math.degrees(a.rot_mean):.2f} | {b.trans_mean:.4f}, "
                         f"{math.degrees(b.rot_mean):.2f} | {c.trans_mean:.4f}, "
                         f"{math.degrees(c.rot_mean):.2f} | {r['rate']:.0f}, "
                         f"{r['tracking']:.0f}, {r['map_rate']:.0f} | "
                         f"x{r['ratio']:.2f} (" + ", ".join(f"{x:.2f}" for x in r["ratios"])
                         + ") |")
        lines.append("")
        if any(len(r["starts"]) > 1 for r in rows):
            lines += ["The second half localized again, started a few scans late (one run's "
                      "share is one draw): per start, the share of scans localized and the "
                      "relation error of the localized scans less one go's on the same "
                      "relations (m).", "",
                      "| log | " + " | ".join(f"started {k} late" for k, _, _ in
                                             rows[0]["starts"]) + " |",
                      "|---|" + "---|" * len(rows[0]["starts"])]
            for r in rows:
                lines.append(f"| {r['name']} | " + " | ".join(
                    f"{share:.1%}, {d:+.4f}" for _, share, d in r["starts"]) + " |")
            lines.append("")
        if any(len(r["cuts"]) > 1 for r in rows):
            lines += ["Each log cut elsewhere: the part before the cut mapped, the rest "
                      "localized in that map from no pose (each cut its own map, an "
                      "independent draw). Per cut, the share of scans localized, the relation "
                      "error of the localized scans less one go's on the same relations (m), "
                      f"and the places declared more than {WRONG_FIX:g} m from one go's pose "
                      "(carried into the cut map's frame at its scan nearest the place).", "",
                      "| log | " + " | ".join(f"cut at {f:g}" for f, *_ in rows[0]["cuts"])
                      + " |", "|---|" + "---|" * len(rows[0]["cuts"])]
            for r in rows:
                lines.append(f"| {r['name']} | " + " | ".join(
                    f"{share:.1%}, {d:+.4f}, {off} off" for _, share, d, off in r["cuts"])
                    + " |")
            lines.append("")
        lines += ["Second sessions on the same logs, scored on every relation of the log: the "
                  "second half mapped on in the first half's map (`vmp map --continue`), and "
                  "the two halves mapped apart then merged (`vmp merge`), beside the whole log "
                  "mapped in one go.", "",
                  "| log | one go: trans (m), rot (deg) | continued | merged |",
                  "|---|---|---|---|"]
        for r in rows:
            cells = [f"{e.trans_mean:.4f}, {math.degrees(e.rot_mean):.2f} ({e.used})"
                     for e in (r["all"], r["cont"], r["merged"])]
            lines.append(f"| {r['name']} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sim", nargs="*", default=list(SIM), help="scenarios (default: all four)")
    ap.add_argument("--runs", type=int, default=20, help="runs per scenario (default 20)")
    ap.add_argument("--no-sim", action="store_true", help="no simulated runs")
    ap.add_argument("--no-real", action="store_true", help="no real logs")
    ap.add_argument("--only", help="only this real log (intel, aces, fr079)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs of mapping and tracking in turn per real log for their speeds "
                         "(default 3; medians)")
    ap.add_argument("--offsets", type=int, nargs="*", default=[],
                    help="localize each real second half again started this many scans late "
                         "(default none)")
    ap.add_argument("--splits", type=float, nargs="*",
                    default=[0.35, 0.4, 0.45, 0.55, 0.6, 0.65],
                    help="also cut each real log at these shares of its scans, map the part "
                         "before and localize the rest in it (default 0.35 0.4 0.45 0.55 0.6 "
                         "0.65; none: no such runs)")
    args = ap.parse_args()
    if any(not 0.0 < f < 1.0 for f in args.splits):
        ap.error(f"--splits must lie between 0 and 1, got {args.splits}")
    if any(k < 0 for k in args.offsets):
        ap.error(f"--offsets must be 0 or more, got {args.offsets}")
    if args.repeat < 1:
        ap.error(f"--repeat must be 1 or more, got {args.repeat}")
    sim = [] if args.no_sim else simulated(args.sim, args.runs)
    rows = [] if args.no_real else real(args.only, args.repeat, tuple(args.offsets),
                                           tuple(args.splits))
    if sim and set(args.sim) == set(SIM) and args.runs == 20:
        write_section("localize-sim", table(sim, [], args.runs))
    if rows and args.only is None:
        write_section("localize-real", table([], rows, args.runs, args.repeat))


if __name__ == "__main__":
    main()
