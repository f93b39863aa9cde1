"""The sequence filter's window as the view draws it: pure numpy, no Rerun.

A cell per candidate the filter holds: a row per frame of the window (oldest at
the top, the current frame at the bottom), a column per reference frame around
the answer (the answer in the middle column), the colour its cost (brighter is
lower). The cells are an image (one pixel each, stretched), with a dot on each
filled cell that names its reference, age and exact cost on hover. The frame is
fixed whatever the window's length, so the blueprint can frame it once and the
labels below it never move: reference indices under the band, then a two-dot key
of the colour scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CELL_WIDTH = 10.0
"""Scene units per reference column."""
BAND_HEIGHT = 200.0
"""Scene units the window's rows share, however many there are."""
INDEX_GAP = 6.0
"""Reference indices hang below the band from this far under it."""
KEY_GAP = 95.0
"""The colour key's dots sit this far below the band."""
KEY_ROOM = 40.0
KEY_DOT = 10.0
"""Radius of the colour key's dots (scene units)."""


@dataclass
class SequenceBand:
    """The window's costs around the answer: rows are its frames (oldest first), columns the
    reference frames ``first .. first + width - 1`` (NaN where a frame had no candidate there,
    or the column lies off the map)."""

    costs: np.ndarray
    first: int

    @property
    def width(self) -> int:
        return int(self.costs.shape[1])

    @property
    def rows(self) -> int:
        return int(self.costs.shape[0])


def sequence_band(window: np.ndarray, candidates: np.ndarray, n_refs: int, centre: int, half_width: int) -> SequenceBand:
    """Scatter the (L, k) window of candidate costs into an (L, 2 * half_width + 1) band centred on ``centre``.

    Candidates outside the band (other places on the route) and off the map are left out.
    """
    window = np.asarray(window, dtype=np.float64)
    candidates = np.asarray(candidates, dtype=np.int64)
    first = centre - half_width
    band = np.full((window.shape[0], 2 * half_width + 1), np.nan)
    inside = (candidates >= max(first, 0)) & (candidates <= min(centre + half_width, n_refs - 1))
    row, col = np.nonzero(inside & np.isfinite(window))
    # Where a frame lists one reference twice, keep its lower cost.
    order = np.argsort(-window[row, col], kind="stable")
    row, col = row[order], col[order]
    band[row, candidates[row, col] - first] = window[row, col]
    return SequenceBand(band, first)


def row_height(rows: int) -> float:
    return BAND_HEIGHT / max(rows, 1)


@dataclass
class WindowDots:
    """The band's filled cells: where each dot goes, and what it stands for."""

    xy: np.ndarray
    """(M, 2) scene positions."""
    cost: np.ndarray
    reference: np.ndarray
    """(M,) reference index of each dot."""
    age: np.ndarray
    """(M,) frames before the current one (0: the current frame)."""
    radius: float


EMPTY = (128, 128, 128)
"""Cells without a candidate: a grey that viridis never takes, and that reads on both themes."""


def on_map_columns(band: SequenceBand, n_refs: int) -> tuple[int, int]:
    """The band's columns [start, stop) whose references lie on the map."""
    return max(0, -band.first), min(band.width, n_refs - band.first)


def band_rgb(band: SequenceBand, lut: np.ndarray, columns: tuple[int, int]) -> np.ndarray:
    """(L, stop - start, 3) uint8 colours of the band's ``columns``, the lowest cost brightest, empty cells grey."""
    costs = band.costs[:, columns[0]:columns[1]]
    out = np.empty(costs.shape + (3,), np.uint8)
    out[:] = EMPTY
    filled = np.isfinite(costs)
    if filled.any():
        out[filled] = dot_colours(costs[filled], lut, float(costs[filled].min()), float(costs[filled].max()))
    return out


def window_dots(band: SequenceBand) -> WindowDots:
    row, col = np.nonzero(np.isfinite(band.costs))
    height = row_height(band.rows)
    xy = np.stack([(col + 0.5) * CELL_WIDTH, (row + 0.5) * height], axis=1)
    return WindowDots(xy, band.costs[row, col], band.first + col, band.rows - 1 - row,
                      0.5 * min(CELL_WIDTH, height))


def dot_colours(costs: np.ndarray, lut: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(M,) costs -> (M, 3) uint8: ``lo`` (the best) takes the last colour of ``lut``, ``hi`` the first."""
    costs = np.asarray(costs, dtype=np.float64)
    t = np.ones(len(costs)) if hi <= lo else (hi - costs) / (hi - lo)
    return lut[np.clip(np.rint(t * (len(lut) - 1)), 0, len(lut) - 1).astype(np.int64)]


def trajectory(rows: int, match_index: int, speed: float, first: int) -> np.ndarray:
    """(rows, 2) scene points of the straight trajectory that ends at ``match_index`` in the newest row.

    Row r of the window (0 oldest) sits ``speed * (rows - 1 - r)`` reference frames before the match.
    """
    r = np.arange(rows, dtype=np.float64)
    refs = match_index - speed * (rows - 1 - r)
    return np.stack([(refs - first + 0.5) * CELL_WIDTH, (r + 0.5) * row_height(rows)], axis=1)


def index_anchors(band: SequenceBand, n_refs: int) -> tuple[np.ndarray, list[int]]:
    """Where the reference indices under the band hang from, and which: the first and last
    columns on the map, and the middle one (the answer)."""
    centre = band.first + band.width // 2
    shown = sorted({max(band.first, 0), centre, min(band.first + band.width - 1, n_refs - 1)})
    x = (np.asarray(shown, dtype=np.float64) - band.first + 0.5) * CELL_WIDTH
    return np.stack([x, np.full(len(shown), BAND_HEIGHT + INDEX_GAP)], axis=1), shown


def key_anchors(band_width: int) -> np.ndarray:
    """(2, 2) the colour key's dots: the best cost under the band's left end, the worst under its right end."""
    y = BAND_HEIGHT + KEY_GAP
    return np.array([[0.1 * band_width * CELL_WIDTH, y], [0.9 * band_width * CELL_WIDTH, y]])


def window_bounds(band_width: int, margin: float = 12.0) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x range, y range) that shows the band, its indices (half a label's width beyond its edges) and its key."""
    side = margin + 4 * CELL_WIDTH
    return (-side, band_width * CELL_WIDTH + side), (-margin, BAND_HEIGHT + KEY_GAP + KEY_ROOM + margin)
