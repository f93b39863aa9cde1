"""Where things are drawn: pure numpy, no Rerun.

The match space holds the query image on the left and the reference image on
its right; keypoints live on the feature grid (e.g. 32 x 32 cells) and are
drawn at the centre of their cell in each image's display pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lostx.core.verify import Correspondences

GAP = 16
"""Pixels between the query and the reference image in the match space."""


def display_size(height: int, width: int, target_width: int | None) -> tuple[int, int]:
    """(width, height) an image is shown at: about ``target_width`` wide, aspect kept, never enlarged.

    The width is the source width divided by a whole number (1024 -> 512 for a target of 640):
    a whole-number area reduction is several times faster than an arbitrary one and stays crisp.
    """
    if not target_width or target_width >= width:
        return width, height
    factor = max(1, round(width / target_width))
    return max(1, width // factor), max(1, height // factor)


@dataclass(frozen=True)
class Panel:
    """One image's place in the match space."""

    x0: float
    """Left edge in the match space."""
    width: int
    height: int
    mirrored: bool = False
    """The image is shown flipped left-right (a query whose camera faces opposite to the map's)."""

    def cell_centres(self, xy: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
        """(M, 2) grid cells (x, y), as taken by the verifier (never mirrored) -> (M, 2) match-space pixels."""
        h, w = grid
        x = np.asarray(xy[:, 0], dtype=np.float64)
        if self.mirrored:
            x = (w - 1) - x
        px = self.x0 + (x + 0.5) * self.width / w
        py = (np.asarray(xy[:, 1], dtype=np.float64) + 0.5) * self.height / h
        return np.stack([px, py], axis=1)

    def grid_scale(self, grid: tuple[int, int]) -> tuple[float, float]:
        """Scale from grid cells to this panel's pixels: how a label map is stretched over the image."""
        h, w = grid
        return self.width / w, self.height / h

    def outline(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """(min corner, size) of the panel in its own coordinates."""
        return (0.0, 0.0), (float(self.width), float(self.height))


def side_by_side(query: tuple[int, int], reference: tuple[int, int], mirrored: bool) -> tuple[Panel, Panel]:
    """Panels for a query of (width, height) ``query`` and a reference of ``reference``."""
    q = Panel(0.0, query[0], query[1], mirrored)
    r = Panel(float(query[0] + GAP), reference[0], reference[1], False)
    return q, r


def match_bounds(query: tuple[int, int], reference: tuple[int, int], margin: float = 24.0) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x range, y range) of the match space that shows both images and their captions above them."""
    q, r = side_by_side(query, reference, False)
    return (-margin, r.x0 + r.width + margin), (-CAPTION_HEIGHT - margin, max(q.height, r.height) + margin)


CAPTION_HEIGHT = 14.0
"""Captions sit this far above each image (match-space pixels)."""


def caption_anchors(query: Panel, reference: Panel) -> np.ndarray:
    """(2, 2) where the query's and the reference's captions are placed: centred above each image."""
    return np.array([[query.x0 + query.width / 2, -CAPTION_HEIGHT / 2],
                     [reference.x0 + reference.width / 2, -CAPTION_HEIGHT / 2]], dtype=np.float32)


def correspondence_strips(corr: Correspondences, grid: tuple[int, int], query: Panel, reference: Panel) -> tuple[np.ndarray, np.ndarray]:
    """One straight line per correspondence, query keypoint to reference keypoint.

    Returns (M, 2, 2) float32 strips in match-space pixels and (M,) uint16 class ids
    (the correspondences' semantic labels, which the annotation context colours).
    """
    if len(corr.label) == 0:
        return np.zeros((0, 2, 2), np.float32), np.zeros(0, np.uint16)
    a = query.cell_centres(corr.query_xy, grid)
    b = reference.cell_centres(corr.ref_xy, grid)
    return np.stack([a, b], axis=1).astype(np.float32), np.asarray(corr.label, dtype=np.uint16)


@dataclass
class SequenceBand:
    """The sequence window as an image: rows are the window's frames (oldest at the top),
    columns the reference frames ``first .. first + width - 1``, pixels the candidate cost
    (NaN where the frame had no candidate at that reference)."""

    costs: np.ndarray
    first: int

    @property
    def width(self) -> int:
        return int(self.costs.shape[1])


def sequence_band(window: np.ndarray, candidates: np.ndarray, n_refs: int, centre: int, half_width: int) -> SequenceBand:
    """Scatter the (L, k) window of candidate costs into an (L, B) band of reference indices around ``centre``.

    Candidates outside the band (other places on the route) are left out; the band
    is at most 2 * half_width + 1 wide and is clipped to the map.
    """
    window = np.asarray(window, dtype=np.float64)
    candidates = np.asarray(candidates, dtype=np.int64)
    first = max(0, centre - half_width)
    last = min(n_refs - 1, centre + half_width)
    band = np.full((window.shape[0], last - first + 1), np.nan)
    row, col = np.nonzero((candidates >= first) & (candidates <= last) & np.isfinite(window))
    # Where a frame lists one reference twice, keep its lower cost.
    order = np.argsort(-window[row, col], kind="stable")
    row, col = row[order], col[order]
    band[row, candidates[row, col] - first] = window[row, col]
    return SequenceBand(band, first)


def colourise(costs: np.ndarray, lut: np.ndarray, empty: tuple[int, int, int] = (25, 25, 25)) -> np.ndarray:
    """(H, W) costs -> (H, W, 3) uint8: the lowest cost takes the last colour of ``lut`` (brightest), NaN ``empty``."""
    out = np.empty(costs.shape + (3,), np.uint8)
    out[:] = empty
    finite = np.isfinite(costs)
    if finite.any():
        lo, hi = float(costs[finite].min()), float(costs[finite].max())
        t = np.ones(int(finite.sum())) if hi <= lo else (hi - costs[finite]) / (hi - lo)
        out[finite] = lut[np.clip(np.rint(t * (len(lut) - 1)), 0, len(lut) - 1).astype(np.int64)]
    return out


def trajectory(n_rows: int, match_index: int, speed: float, first: int) -> np.ndarray:
    """(n_rows, 2) band pixels of the straight trajectory ending at ``match_index`` in the newest row.

    Row r of the window (0 oldest) sits ``speed * (n_rows - 1 - r)`` reference frames before the match.
    """
    rows = np.arange(n_rows, dtype=np.float64)
    refs = match_index - speed * (n_rows - 1 - rows)
    return np.stack([refs - first + 0.5, rows + 0.5], axis=1)


def map_xy(positions: np.ndarray) -> np.ndarray:
    """(N, 2) east/north metres -> 2D view coordinates (the view's y axis points down, so north is flipped up)."""
    positions = np.asarray(positions, dtype=np.float64)
    return np.stack([positions[:, 0], -positions[:, 1]], axis=1)
