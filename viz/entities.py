"""Entity paths and timeline names of the lostx recording, in one place.

The sink logs to these paths, the blueprint lays out views over them, and
anything reading a recording back (the tests, a user's notebook) finds the
data under them.
"""

from __future__ import annotations

FRAME_TIMELINE = "frame"
"""Sequence timeline: the frame's id in its stream."""
TIME_TIMELINE = "time"
"""The frame's own timestamp (absent for frames without a clock)."""

# The match space: query and reference side by side, correspondences between them.
MATCH = "match"
QUERY = "match/query"
QUERY_IMAGE = "match/query/image"
QUERY_LABELS = "match/query/labels"
QUERY_OUTLINE = "match/query/outline"
REFERENCE = "match/reference"
REFERENCE_IMAGE = "match/reference/image"
REFERENCE_LABELS = "match/reference/labels"
REFERENCE_OUTLINE = "match/reference/outline"
LINES = "match/lines"
CAPTIONS = "match/captions"
"""What each image is (a query shown mirrored says so), under the images."""
LEGEND_SWATCHES = "match/legend/swatches"
LEGEND_NAMES = "match/legend/names"
"""The classes of this frame's lines: a swatch of each colour, with the class name and count."""

# The layout: the query's bird's-eye grid beside the answer's.
LAYOUT = "layout"
LAYOUT_QUERY = "layout/query"
LAYOUT_ANSWER_PLACE = "layout/answer"
LAYOUT_ANSWER = "layout/answer/grid"
LAYOUT_CAPTIONS = "layout/captions"

# Time series.
CONFIDENCE = "plots/confidence"
SEQUENCE_COST = "plots/sequence_cost"
SPEED = "plots/speed"
MATCH_INDEX = "route/match_index"
SINGLE_MATCH_INDEX = "route/single_match_index"
CORRESPONDENCES = "plots/correspondences"

# Per-frame summaries.
STATUS = "status"
CANDIDATE_TABLE = "candidates/table"
CANDIDATE_BARS = "candidates/bars"
CANDIDATE_SCORES = "candidates/bars/candidates"
ANSWER_SCORE = "candidates/bars/answer"
"""The top-10's verification scores as bars at their reference indices; the answer's bar in its own colour."""

# The sequence filter's window: costs over reference index and time, and the chosen trajectory.
SEQUENCE = "sequence"
SEQUENCE_IMAGE = "sequence/image"
"""The window's cells, one pixel each, stretched over the band."""
SEQUENCE_WINDOW = "sequence/window"
"""One dot per filled cell of the window (hover: reference, age, cost)."""
SEQUENCE_TRAJECTORY = "sequence/trajectory"
SEQUENCE_INDICES = "sequence/indices"
SEQUENCE_KEY = "sequence/key/dots"
SEQUENCE_KEY_NAMES = "sequence/key/names"
"""Reference indices under the window, and the two-dot key of its colour scale with the two costs."""

# The map, where the reference map has positions.
MAP = "map"
MAP_ROUTE = "map/route"
MAP_CANDIDATES = "map/candidates"
MAP_ESTIMATE = "map/estimate"
MAP_TRUTH = "map/truth"
MAP_ERROR = "map/error"

HEAVY = (QUERY_IMAGE, QUERY_LABELS, QUERY_OUTLINE, REFERENCE_IMAGE, REFERENCE_LABELS, REFERENCE_OUTLINE, LINES, CAPTIONS,
         LEGEND_SWATCHES, LEGEND_NAMES, LAYOUT_QUERY, LAYOUT_ANSWER, LAYOUT_CAPTIONS)
"""Entities whose logging rate is limited (images, label maps, correspondence lines)."""
