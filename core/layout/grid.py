"""The layout grid: a window of frames' road-plane evidence, brought into one camera's ground frame with the
motion between them, on a grid around the stretch of road the camera looks at.

The grid lies in the camera's ground frame: ``length`` metres along its level axis centred ``centre`` metres
ahead, ``width`` metres across, cells of ``cell`` metres; row 0 nearest the camera, column 0 on its left.
Turned 180 degrees about its centre it is the same stretch seen from its other end.

Channels (:data:`.classes.CHANNELS`): the share of the rays landing in a cell that show road, and that
show other ground (a share, not a count: the number of rays per cell follows each camera's field of view
and pixel density, not the place); then, per kind of thing standing on the ground, log(1 + metres of it
touching the ground in the cell). A cell no ray reached is unobserved (the mask), and comparisons use only
the cells both grids observed. Values are smoothed with a Gaussian normalised by the mask.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import cv2
import numpy as np

from ..config import LayoutConfig
from ..motion.pose import relative
from .classes import CHANNELS, CONTACTS, GROUND, ROAD
from .projection import FramePoints

CONTACT_RANGE = 4.0
"""log(1 + metres) of contact stored up to this (55 m of ground front in one cell)."""


@dataclass(frozen=True)
class LayoutGrid:
    """One place's layout: (C, A, X) channel values and the (A, X) cells observed."""

    values: np.ndarray
    mask: np.ndarray

    @property
    def observed(self) -> int:
        return int(self.mask.sum())

    def rotated(self, degrees: float) -> "LayoutGrid":
        """The grid turned by ``degrees`` (anticlockwise seen from above) about its centre; cells brought in from
        outside are unobserved."""
        if degrees == 0:
            return self
        rows, cols = self.mask.shape
        # Row index grows along the camera's axis, column index to its right: anticlockwise from above is
        # clockwise in these (row, column) coordinates.
        matrix = cv2.getRotationMatrix2D(((cols - 1) / 2.0, (rows - 1) / 2.0), -degrees, 1.0)
        # The mask and the channels warped four at a time (channels last; OpenCV resamples 4-channel images as it does
        # 1-channel ones, not so 2-channel ones), padded with empty channels to a multiple of four.
        cells = np.concatenate([self.mask[None].astype(np.float32), self.values.astype(np.float32)])
        cells = np.concatenate([cells, np.zeros((-len(cells) % 4, rows, cols), np.float32)])
        warped = np.concatenate([cv2.warpAffine(np.ascontiguousarray(four.transpose(1, 2, 0)), matrix, (cols, rows),
                                                flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                                borderValue=0.0).transpose(2, 0, 1)
                                 for four in cells.reshape(-1, 4, rows, cols)])
        mask, values = warped[0] > 0.99, warped[1: 1 + len(self.values)]
        return LayoutGrid(np.where(mask, values, 0.0).astype(np.float32), mask)

    def turned(self) -> "LayoutGrid":
        """The grid seen from the other end of the stretch: rotated 180 degrees about its centre."""
        return LayoutGrid(np.ascontiguousarray(self.values[:, ::-1, ::-1]), np.ascontiguousarray(self.mask[::-1, ::-1]))


def grid_shape(config: LayoutConfig) -> tuple[int, int]:
    """(A, X): cells along and across."""
    return int(round(config.length / config.cell)), int(round(config.width / config.cell))


def accumulate(frames: Sequence[FramePoints], poses: np.ndarray, current: np.ndarray,
               config: LayoutConfig) -> LayoutGrid:
    """The layout grid of the camera at pose ``current`` from ``frames`` taken at ``poses`` ((k, 3) camera
    ground poses in one odometry frame; ``current`` is one of them for a live frame)."""
    rows, cols = grid_shape(config)
    here = relative(current, np.asarray(poses, dtype=np.float64).reshape(-1, 3))  # each frame's pose in the current's
    # Rays and contacts moved and counted together, the contacts' kinds after the rays' three: a cell of one kind
    # receives the same points in the same order as counted apart.
    weights = cell_weights([(np.concatenate([f.rays, f.contacts]), np.concatenate([f.ray_kind, f.contact_kind + 3]),
                             np.concatenate([f.ray_weight, f.contact_weight])) for f in frames], here,
                           3 + len(CONTACTS), config).reshape(3 + len(CONTACTS), rows, cols)
    rays, contact = weights[:3], weights[3:]
    landed = rays.sum(axis=0)
    mask = landed > 0
    values = np.empty((len(CHANNELS), rows, cols), dtype=np.float32)
    values[0] = rays[ROAD] / np.maximum(landed, 1e-9)
    values[1] = rays[GROUND] / np.maximum(landed, 1e-9)
    values[2:] = np.minimum(np.log1p(contact), CONTACT_RANGE)
    values[:, ~mask] = 0.0
    return LayoutGrid(_smoothed(values, mask, config.blur / config.cell), mask)


@dataclass
class Gathering:
    """A live frame's layout grid before it is gathered: the frames chosen for it, where each stood, and where the
    camera stands now. Making one costs nothing; :meth:`grid` gathers it once, wherever it is first asked for (a
    comparison process gathers it beside LoST-X from the frames it was sent, by their numbers)."""

    frames: tuple[FramePoints, ...]
    keys: tuple[int, ...]
    """Each chosen frame's number in its stream (never given to another frame)."""
    window: tuple[int, ...]
    """The numbers of every frame the stream keeps now: those a later grid may gather."""
    poses: np.ndarray
    """(k, 3) where each chosen frame's camera stood, in the stream's odometry frame."""
    current: np.ndarray
    """(3,) where the camera stands now."""
    config: LayoutConfig
    _grid: LayoutGrid | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def reach(self) -> float:
        """Metres from where the camera stands now to the farthest frame gathered (0 for a frame alone)."""
        if not len(self.poses):
            return 0.0
        return float(np.hypot(*(np.asarray(self.poses)[:, :2] - np.asarray(self.current)[:2]).T).max())

    @property
    def gathered(self) -> bool:
        return self._grid is not None

    def grid(self) -> LayoutGrid:
        """The grid (gathered here the first time, unless it was gathered elsewhere and :meth:`received`)."""
        if self._grid is None:
            self.received(accumulate(self.frames, self.poses, self.current, self.config))
        return self._grid  # type: ignore[return-value]

    def received(self, grid: LayoutGrid) -> None:
        """The grid, gathered elsewhere from the same frames (the same bits); the frames are let go."""
        if self._grid is None:
            self._grid = grid
            self.frames = ()


def as_grid(source: LayoutGrid | Gathering) -> LayoutGrid:
    """The grid itself, or the one a gathering gives (gathered here unless it already was)."""
    return source.grid() if isinstance(source, Gathering) else source


def cell_weights(points: list[tuple[np.ndarray, np.ndarray, np.ndarray]], here: np.ndarray, kinds: int,
                 config: LayoutConfig) -> np.ndarray:
    """(kinds * A * X,) float64: the weights of each frame's points (xy, kind, weight) by kind and cell, the frames
    standing at poses ``here``, counted frame by frame and summed in that order."""
    rows, cols = grid_shape(config)
    size = kinds * rows * cols
    near = config.centre - config.length / 2.0
    total = np.zeros(size)
    # One frame at a time: its few thousand points' temporaries stay in cache (twice as fast as moving every
    # frame's points at once).
    for (xy, kind, weight), (x0, y0, angle) in zip(points, here):
        u, v = xy.T.astype(np.float64)
        cos, sin = np.cos(angle), np.sin(angle)
        a = np.floor((x0 + cos * u - sin * v - near) / config.cell)
        x = np.floor((config.width / 2.0 - (y0 + sin * u + cos * v)) / config.cell)
        inside = (a >= 0) & (a < rows) & (x >= 0) & (x < cols)
        index = ((kind.astype(np.float64) * rows + a) * cols + x)[inside].astype(np.int64)
        total += np.bincount(index, weight[inside], size)
    return total


def _smoothed(values: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing normalised by the mask: unobserved cells neither count nor receive a value."""
    if sigma <= 0 or not mask.any():
        return values
    weight = cv2.GaussianBlur(mask.astype(np.float32), (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    out = np.empty_like(values)
    for c in range(len(values)):
        blurred = cv2.GaussianBlur(values[c] * mask, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
        out[c] = np.where(mask, blurred / np.maximum(weight, 1e-6), 0.0)
    return out


# Stored in a map: one byte per value (shares over 255 steps, contacts over CONTACT_RANGE), the mask as bits.
_SCALE = np.array([255.0, 255.0] + [255.0 / CONTACT_RANGE] * len(CONTACTS), dtype=np.float32)[:, None, None]


def pack(grid: LayoutGrid) -> tuple[np.ndarray, np.ndarray]:
    """(C*A*X,) uint8 values and (ceil(A*X / 8),) uint8 mask bits, as a map stores a grid."""
    values = np.clip(np.rint(grid.values * _SCALE), 0, 255).astype(np.uint8)
    return values.ravel(), np.packbits(grid.mask.ravel())


def pack_both(grid: LayoutGrid, other_end: LayoutGrid) -> tuple[np.ndarray, np.ndarray]:
    """A map frame's two grids (as its camera views the stretch, and as the stretch's other end views it) as a map
    stores them: one row of :func:`pack`'s values, then one of mask bits, each the first grid's then the other's."""
    (values, bits), (other_values, other_bits) = pack(grid), pack(other_end)
    return np.concatenate([values, other_values]), np.concatenate([bits, other_bits])


def holds_both(values: np.ndarray, shape: tuple[int, int]) -> bool:
    """Whether stored grids' value rows ((..., V)) hold :func:`pack_both`'s two grids, not :func:`pack`'s one."""
    rows, cols = shape
    return values.shape[-1] == 2 * len(CHANNELS) * rows * cols


def stored_half(values: np.ndarray, bits: np.ndarray, shape: tuple[int, int], other_end: bool) -> tuple[np.ndarray,
                                                                                                       np.ndarray]:
    """Stored grids' rows ((..., V) values, (..., B) bits) of one of :func:`pack_both`'s two grids (the other end's
    where ``other_end``); rows of one grid (a map built before the other end was stored) give that grid either way."""
    if not holds_both(values, shape):
        return values, bits
    rows, cols = shape
    size, nbits = len(CHANNELS) * rows * cols, -(-rows * cols // 8)
    start, bit_start = (size, nbits) if other_end else (0, 0)
    return values[..., start: start + size], bits[..., bit_start: bit_start + nbits]


def unpack(values: np.ndarray, bits: np.ndarray, shape: tuple[int, int]) -> LayoutGrid:
    rows, cols = shape
    grid = np.asarray(values, dtype=np.float32).reshape(len(CHANNELS), rows, cols) / _SCALE
    mask = np.unpackbits(np.asarray(bits, dtype=np.uint8))[: rows * cols].reshape(rows, cols).astype(bool)
    return LayoutGrid(grid, mask)


def unpack_levels(values: np.ndarray, bits: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray,
                                                                                       np.ndarray]:
    """Many stored grids (rows of :func:`pack`'s values and mask bits) as they are stored: (N, C, A, X) one-byte
    levels, (N, A, X) masks, and each channel's (C,) levels per unit (a value is its level / scale, as
    :func:`unpack` gives it)."""
    rows, cols = shape
    levels = np.asarray(values, dtype=np.uint8).reshape(len(values), len(CHANNELS), rows, cols)
    masks = np.unpackbits(np.asarray(bits, dtype=np.uint8), axis=1)[:, : rows * cols]
    return levels, masks.reshape(len(values), rows, cols).astype(bool), _SCALE.ravel().astype(np.float64)
