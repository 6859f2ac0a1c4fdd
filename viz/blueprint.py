"""The default Rerun layout: the map view, the time series and the event log."""

from __future__ import annotations

import rerun.blueprint as rrb

__all__ = ["default_blueprint"]


def default_blueprint(bounds: tuple[float, float, float, float] | None = None) -> rrb.Blueprint:
    """Map on the left (everything logged so far stays visible), metrics and log on the right.

    ``bounds`` (x_min, y_min, x_max, y_max in map metres) frames the map view.
    """
    visual = None
    if bounds is not None:
        x0, y0, x1, y1 = bounds  # the map is drawn with y flipped so that y points up
        visual = rrb.VisualBounds2D(x_range=[x0, x1], y_range=[-y1, -y0])
    so_far = [rrb.VisibleTimeRange("scan", start=rrb.TimeRangeBoundary.infinite(),
                                   end=rrb.TimeRangeBoundary.cursor_relative())]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="/", contents=["/world/**"], name="map",
                              time_ranges=so_far, visual_bounds=visual),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/metrics", name="metrics"),
                rrb.TextLogView(origin="/log", name="events"),
            ),
            column_shares=[3, 1],
        ),
        rrb.TimePanel(timeline="scan", play_state="following"),
        collapse_panels=True,
    )
