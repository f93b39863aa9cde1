"""Where things are drawn: pure numpy, no Rerun.

The match space holds the query image on the left and the reference image on
its right, their captions and the legend of the line colours below them;
keypoints live on the feature grid (e.g. 32 x 32 cells) and are drawn at the
centre of their cell in each image's display pixels. The map view's coordinates
are here too; the sequence window's are in :mod:`.sequence_window`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lostx.core.match.verify import Correspondences

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


# Captions and legend names are drawn in UI points, the images in match-space pixels. The gaps
# below are in UI points and are turned into match-space pixels for the narrowest view the
# layout is made for (about 900 points for both images, a 1280 x 720 window): at any larger
# size they only grow apart.
DESIGN_WIDTH = 900.0
"""UI points across both images in a 1280-point-wide window."""
CAPTION_GAP = 6.0
"""Captions hang from this far under the images: never over a line or a picture."""
LEGEND_GAP = 62.0
"""The class legend's swatches sit this far under the images (room for two lines of caption)."""
LEGEND_ROOM = 34.0
"""Room under the swatches for their names."""
LEGEND_SWATCH = 28.0
LEGEND_MAX = 8
"""Most classes in the legend (the most frequent in the frame's correspondences)."""


def pixels_per_point(query: Panel, reference: Panel) -> float:
    """Match-space pixels per UI point when both images fill the design width (never below 1)."""
    return max(1.0, (reference.x0 + reference.width) / DESIGN_WIDTH)


def match_bounds(query: tuple[int, int], reference: tuple[int, int], margin: float = 24.0) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x range, y range) of the match space: both images, their captions and the class legend under them."""
    q, r = side_by_side(query, reference, False)
    bottom = max(q.height, r.height) + (LEGEND_GAP + LEGEND_ROOM) * pixels_per_point(q, r)
    return (-margin, r.x0 + r.width + margin), (-margin, bottom + margin)


def caption_anchors(query: Panel, reference: Panel) -> np.ndarray:
    """(2, 2) where the query's and the reference's captions hang from: centred under each image."""
    y = max(query.height, reference.height) + CAPTION_GAP * pixels_per_point(query, reference)
    return np.array([[query.x0 + query.width / 2, y], [reference.x0 + reference.width / 2, y]], dtype=np.float32)


def legend_entries(labels: np.ndarray, limit: int = LEGEND_MAX) -> list[tuple[int, int]]:
    """(class id, count) of the classes among ``labels``, most frequent first (ties: lower id first)."""
    ids, counts = np.unique(np.asarray(labels, dtype=np.int64), return_counts=True)
    order = np.lexsort((ids, -counts))[:limit]
    return [(int(ids[i]), int(counts[i])) for i in order]


def legend_layout(n: int, query: Panel, reference: Panel) -> tuple[np.ndarray, np.ndarray]:
    """Swatches (n, 2, 2) and name anchors (n, 2) of an n-entry legend in a row under the captions.

    The entries are spaced evenly over both images' width, as if there were at least six,
    so that a short legend keeps its names apart at any zoom."""
    if n == 0:
        return np.zeros((0, 2, 2), np.float32), np.zeros((0, 2), np.float32)
    scale = pixels_per_point(query, reference)
    step = (reference.x0 + reference.width) / max(n, 6)
    centres = (np.arange(n) + 0.5) * step
    y = np.full(n, max(query.height, reference.height) + LEGEND_GAP * scale)
    half = LEGEND_SWATCH / 2 * scale
    swatches = np.stack([np.stack([centres - half, y], 1), np.stack([centres + half, y], 1)], 1)
    return swatches.astype(np.float32), np.stack([centres, y + 2.0 * scale], 1).astype(np.float32)


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


def map_xy(positions: np.ndarray) -> np.ndarray:
    """(N, 2) east/north metres -> 2D view coordinates (the view's y axis points down, so north is flipped up)."""
    positions = np.asarray(positions, dtype=np.float64)
    return np.stack([positions[:, 0], -positions[:, 1]], axis=1)


def map_bounds(positions: np.ndarray, margin: float = 0.08) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x range, y range) of the map view that frames the whole route, with ``margin`` of its size around it."""
    xy = map_xy(positions)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = margin * max(float((hi - lo).max()), 1.0)
    return (float(lo[0] - pad), float(hi[0] + pad)), (float(lo[1] - pad), float(hi[1] + pad))
