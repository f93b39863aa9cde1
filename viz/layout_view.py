"""The layout beside the match: the query's bird's-eye grid and the matched reference's, as they were compared
(the reference's turned 180 degrees when the query views the route the other way, the query's turned a few
degrees and shifted sideways as it fits best), so a person sees why a place matched.

Each cell takes the colour of what dominates it: road, other ground, or the thing standing on the ground there
(building, vegetation, vehicle, other), brighter where more of it; unobserved cells stay dark. The camera is at
the bottom of each picture, looking up the page.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from lostx.core.decide.estimate import Estimate, LayoutView
from lostx.core.layout.classes import CHANNELS
from lostx.core.layout.grid import CONTACT_RANGE, LayoutGrid

from . import entities as e

CELL_PIXELS = 8
"""Each grid cell is drawn this many pixels wide."""
GAP = 2
"""Cells between the two pictures."""
CHANNEL_COLOURS = np.array([
    (150, 150, 160),  # road
    (190, 160, 100),  # other ground
    (255, 150, 0),  # building
    (40, 200, 60),  # vegetation
    (0, 200, 230),  # vehicle
    (200, 120, 255),  # other
], dtype=np.float32)
UNSEEN = np.array([25, 25, 30], dtype=np.float32)


def layout_picture(grid: LayoutGrid) -> np.ndarray:
    """(A * CELL_PIXELS, X * CELL_PIXELS, 3) uint8: the grid drawn with the camera at the bottom."""
    values = grid.values.copy()
    values[2:] /= CONTACT_RANGE / 2.0  # a few metres of contact weigh as much as a cell of road
    strength = values.max(axis=0)
    winner = values.argmax(axis=0)
    shade = 0.35 + 0.65 * np.clip(strength, 0.0, 1.0)[..., None]
    picture = np.where(grid.mask[..., None], CHANNEL_COLOURS[winner] * shade, UNSEEN)
    picture = picture[::-1]  # row 0 is nearest the camera: draw it at the bottom
    return np.repeat(np.repeat(picture.astype(np.uint8), CELL_PIXELS, axis=0), CELL_PIXELS, axis=1)


def log_layout(rec: rr.RecordingStream, est: Estimate) -> None:
    """Log the query's and the answer's grids side by side (nothing where the layout took no part)."""
    deferred = est.evidence.layout if est.evidence is not None else None
    if deferred is None:
        rec.log(e.LAYOUT, rr.Clear(recursive=True))
        return
    view = deferred.get()
    width = view.query.mask.shape[1] * CELL_PIXELS
    rec.log(e.LAYOUT_QUERY, rr.Image(layout_picture(view.query)))
    rec.log(e.LAYOUT_ANSWER, rr.Image(layout_picture(view.answer)))
    rec.log(e.LAYOUT_ANSWER_PLACE, rr.Transform3D(translation=[width + GAP * CELL_PIXELS, 0.0, 0.0]))
    turned = " (turned)" if est.opposite else ""
    rec.log(e.LAYOUT_CAPTIONS, rr.Points2D(
        [[width / 2, -6.0], [width * 1.5 + GAP * CELL_PIXELS, -6.0]],
        labels=[query_caption(view), f"reference {est.match_index}{turned}"], radii=rr.Radius.ui_points(0.1),
        show_labels=True))


def query_caption(view: LayoutView) -> str:
    """"query", with how its grid was turned and shifted to fit the reference's."""
    moves = []
    if view.turn:
        moves.append(f"turned {abs(view.turn):g} deg {'left' if view.turn > 0 else 'right'}")
    if view.shift:
        moves.append(f"{abs(view.shift):g} m {'right' if view.shift > 0 else 'left'}")
    return "query" + (f" ({', '.join(moves)})" if moves else "")


LEGEND = tuple(zip(CHANNELS, (tuple(int(v) for v in c) for c in CHANNEL_COLOURS)))
"""(channel, colour) of the layout pictures, for the view's legend."""
