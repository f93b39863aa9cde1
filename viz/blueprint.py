"""The viewer's layout, so that it opens readable without arranging panels.

    +---------------------------------------------+----------------+
    | match: query | reference, correspondence    | status         |
    | lines coloured by semantic class            | top-10 table   |
    |                                             | top-10 scores  |
    +--------------+--------------+---------------+----------------+
    | confidence & | route        | sequence      | map (where the |
    | seq. score   | position     | window        | map has        |
    | speed        |              |               | positions)     |
    +--------------+--------------+---------------+----------------+

The plots show a sliding window of recent frames so a long stream stays legible.
"""

from __future__ import annotations

import rerun.blueprint as rrb

from . import entities as e
from .geometry import match_bounds

PLOT_WINDOW = 200
"""Frames of history the time series show (the cursor is at the right edge)."""


def _recent(frames: int) -> rrb.VisibleTimeRange:
    return rrb.VisibleTimeRange(
        e.FRAME_TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seq=-frames),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )


def build_blueprint(with_map: bool, image_size: tuple[int, int] | None = None,
                    plot_window: int = PLOT_WINDOW) -> rrb.Blueprint:
    """The layout; ``image_size`` (width, height of the shown images, where known) frames the match view on them."""
    recent = _recent(plot_window)
    bounds = None
    if image_size is not None:
        x_range, y_range = match_bounds(image_size, image_size)
        bounds = rrb.VisualBounds2D(x_range=x_range, y_range=y_range)
    match = rrb.Spatial2DView(name="Query | matched reference", origin=e.MATCH, visual_bounds=bounds)
    side = rrb.Vertical(
        rrb.TextDocumentView(name="Status", origin=e.STATUS),
        rrb.Tabs(
            rrb.TextDocumentView(name="Top-10 candidates", origin=e.CANDIDATE_TABLE),
            rrb.BarChartView(name="Top-10 scores (lower is better)", origin=e.CANDIDATE_SCORES),
        ),
        row_shares=[2, 3],
    )
    plots = [
        rrb.Vertical(
            rrb.TimeSeriesView(
                name="Confidence and sequence score",
                origin="/",
                contents=[e.CONFIDENCE, e.SEQUENCE_SCORE],
                time_ranges=recent,
            ),
            rrb.TimeSeriesView(name="Speed (reference frames per frame)", origin=e.SPEED, time_ranges=recent),
            row_shares=[3, 2],
        ),
        rrb.TimeSeriesView(
            name="Route position (reference index)",
            origin="/",
            contents=[e.MATCH_INDEX, e.SINGLE_MATCH_INDEX],
            time_ranges=recent,
        ),
        rrb.Spatial2DView(name="Sequence window (rows: frames, columns: references)", origin=e.SEQUENCE),
    ]
    if with_map:
        plots.append(rrb.Spatial2DView(name="Map", origin=e.MAP))
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(match, side, column_shares=[3, 1]),
            rrb.Horizontal(*plots),
            row_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=e.FRAME_TIMELINE),
        collapse_panels=False,
    )
