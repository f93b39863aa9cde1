"""The viewer's layout, so that it opens readable without arranging panels, at 1280 x 720 and up.

    +------------------------------------------------------+-----------------+
    | match: query | reference, lines coloured by class,    | status          |
    | captions and the class legend under the images       |                 |
    |                                                      +-----------------+
    +-------------+-------------+-------------+------------+ top-10 table    |
    | confidence  | route       | sequence    | map (maps  | (tab: scores at |
    | seq. cost   | position    | window      | with       |  their reference|
    |             | speed       |             | positions) |  indices)       |
    +-------------+-------------+-------------+------------+-----------------+

Without the sequence filter, its panels (sequence cost, speed, window) are left out.
Every plot has its own axis and a short title that fits at 1280 x 720 (what it
shows; the speed's unit), so none needs a legend over its data; the status text
says which way the scores run. The time series show a sliding window of recent
frames so a long stream stays legible.
"""

from __future__ import annotations

import numpy as np
import rerun.blueprint as rrb

from . import entities as e
from .geometry import map_bounds, match_bounds
from .sequence_window import window_bounds

PLOT_WINDOW = 200
"""Frames of history the time series show (the cursor is at the right edge)."""


def _recent(frames: int) -> rrb.VisibleTimeRange:
    return rrb.VisibleTimeRange(
        e.FRAME_TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seq=-frames),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )


def _series(name: str, entity: str, recent: rrb.VisibleTimeRange, y_range: tuple[float, float] | None = None,
            contents: list[str] | None = None) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        name=name,
        origin="/",
        contents=contents or [entity],
        time_ranges=recent,
        axis_y=rrb.ScalarAxis(range=y_range) if y_range is not None else None,
        plot_legend=rrb.PlotLegend(visible=False),
    )


def _bounds(x_range: tuple[float, float], y_range: tuple[float, float]) -> rrb.VisualBounds2D:
    return rrb.VisualBounds2D(x_range=x_range, y_range=y_range)


def build_blueprint(n_refs: int = 0, image_size: tuple[int, int] | None = None, sequence: bool = True,
                    sequence_width: int = 51, route: np.ndarray | None = None,
                    plot_window: int = PLOT_WINDOW, layout: bool = False) -> rrb.Blueprint:
    """The layout. ``image_size`` (width, height of the shown images, where known) frames the match view
    on them, ``n_refs`` (the map's size) the route plot on the whole route, ``route`` (the map's
    positions, where it has them) adds the map view framed on it; ``sequence``: the localizer runs
    the sequence filter, whose window is ``sequence_width`` references wide; ``layout``: the map has a layout,
    whose grids are shown beside the plots."""
    recent = _recent(plot_window)
    bounds = _bounds(*match_bounds(image_size, image_size)) if image_size is not None else None
    hidden = rrb.EntityBehavior(visible=False)
    match = rrb.Spatial2DView(
        name="Query | matched reference (lines: verified correspondences, coloured by class)",
        origin=e.MATCH,
        visual_bounds=bounds,
        # The label maps are 32 x 32 blocks over the photographs: shown on request (blueprint panel).
        overrides={e.QUERY_LABELS: hidden, e.REFERENCE_LABELS: hidden},
    )
    side = rrb.Vertical(
        rrb.TextDocumentView(name="Status", origin=e.STATUS),
        rrb.Tabs(
            rrb.TextDocumentView(name="Top-10", origin=e.CANDIDATE_TABLE),
            rrb.BarChartView(name="Scores by reference", origin=e.CANDIDATE_BARS,
                             plot_legend=rrb.PlotLegend(visible=False)),
        ),
        row_shares=[2, 3],
    )
    route_range = (-0.5, n_refs - 0.5) if n_refs > 1 else None
    position = _series("Route position", e.MATCH_INDEX, recent, route_range,
                    contents=[e.MATCH_INDEX, e.SINGLE_MATCH_INDEX])
    confidence = _series("Confidence", e.CONFIDENCE, recent, (-0.04, 1.04))
    if sequence:
        plots: list[rrb.Container | rrb.View] = [
            rrb.Vertical(confidence, _series("Sequence cost", e.SEQUENCE_COST, recent)),
            rrb.Vertical(position, _series("Speed ref/frame", e.SPEED, recent), row_shares=[3, 2]),
            rrb.Spatial2DView(name="Sequence window", origin=e.SEQUENCE,
                              visual_bounds=_bounds(*window_bounds(sequence_width))),
        ]
    else:
        plots = [confidence, position]
    if route is not None:
        plots.append(rrb.Spatial2DView(name="Map", origin=e.MAP, visual_bounds=_bounds(*map_bounds(route))))
    if layout:
        plots.append(rrb.Spatial2DView(name="Layout: query | answer (road grey, ground tan, building orange, "
                                            "vegetation green, vehicle cyan, other violet)", origin=e.LAYOUT))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(match, rrb.Horizontal(*plots), row_shares=[5, 4]),
            side,
            column_shares=[3, 1],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=e.FRAME_TIMELINE),
        collapse_panels=False,
    )
