"""Loops between two sessions searched once more at the end of a run that mapped on in a
saved map (:mod:`vmp.session_ties`)."""

from __future__ import annotations

import numpy as np

import vmp.pipeline as pipeline_module
from drivers import open_source
from vmp.mapfile import MapData
from vmp.run import MappingRun
from vmp.source import FrameList


def test_a_second_session_no_search_tied_is_tied_to_the_saved_map_at_the_end(monkeypatch):
    first = MappingRun(FrameList(list(open_source("warehouse"))[:1500], "warehouse")).run()
    p = first.pipeline
    saved = MapData(p.map, p.milestones, p.back.graph, {}, first.stamps, first.trajectory)
    sim = open_source("warehouse", seed=4)
    frames, truth = list(sim)[:1500], sim.reference().poses
    # The second session drifts on scan odometry alone: no match, no loop search while it
    # runs; only the localizer's fix joins it to the saved map. (Without the search at the
    # end its poses are 0.47 m off the world's (median), 0.78 m at worst.)
    monkeypatch.setattr(pipeline_module.Pipeline, "match", lambda self, frame: [])
    second = MappingRun(FrameList(frames, "warehouse"), saved=saved).run()
    metrics = second.metrics()
    assert metrics["loop edges between the sessions found at the end"] >= 20
    before = metrics["scans before localized in the saved map"]
    err = np.hypot(*(second.trajectory[1500:, :2] - truth[before:1500, :2]).T)
    assert np.median(err) < 0.15 and err.max() < 0.3
