"""From a frame's semantic labels to evidence on the road plane, through the calibrated camera.

Every label pixel's ray is fixed for a camera, so where it meets the road plane is computed once
(:class:`GroundProjector`), as a point in the camera's *ground frame*: metres along the camera's level
optical axis and to its left, from the point on the road under the camera. A frame then costs a few
table look-ups:

- **rays**: each label pixel below the horizon and nearer than ``max_range`` lands on the road plane;
  what it shows (road, other ground, or something standing there, whose ray passes on behind it) is
  counted where it lands. Rays landing in the same small square are merged (one ``bincount``).
- **contacts**: in each sampled column, the first pixel above the column's lowest run of ground that is
  neither ground nor sky is where that thing touches the ground (a building's foot, a tree's trunk, a
  car's wheels); its point counts the metres of ground front it covers at that range. Whatever lies
  below that run (the vehicle's own body where the camera file does not cut it away, a thing right beside
  the vehicle) touches no ground the camera sees.

Rows showing the vehicle itself (``geometry.body``) are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import CameraGeometry
from .classes import LayoutClasses

SPLAT = 0.25
"""Metres: rays landing in the same square of this side are merged."""
CONTACT_COLUMNS = 256
"""About this many columns are scanned for contacts, whatever the label map's width."""


@dataclass(frozen=True)
class FramePoints:
    """One frame's evidence on the road plane, in its camera's ground frame (x along, y left; metres)."""

    rays: np.ndarray
    """(n, 2) float32: where the rays land (merged per square)."""
    ray_kind: np.ndarray
    """(n,) int8: ROAD, GROUND or OBJECT (:mod:`.classes`)."""
    ray_weight: np.ndarray
    """(n,) float32: rays merged into each point."""
    contacts: np.ndarray
    """(m, 2) float32: where things touch the ground."""
    contact_kind: np.ndarray
    """(m,) int8: index into :data:`.classes.CONTACTS`."""
    contact_weight: np.ndarray
    """(m,) float32: metres of ground front each contact covers."""

    @classmethod
    def empty(cls) -> "FramePoints":
        z2, z1 = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
        return cls(z2, np.zeros(0, np.int8), z1, z2, np.zeros(0, np.int8), z1)


def ground_frame(geometry: CameraGeometry, points: np.ndarray) -> np.ndarray:
    """Vehicle-frame (x, y) points (..., 2) in the camera's ground frame (along its level axis, to its left)."""
    yaw = np.radians(geometry.yaw)
    along = np.array([np.cos(yaw), np.sin(yaw)])
    left = np.array([-np.sin(yaw), np.cos(yaw)])
    d = np.asarray(points, dtype=np.float64) - np.array([geometry.x, geometry.y])
    return np.stack([d @ along, d @ left], axis=-1)


class GroundProjector:
    """The road-plane look-up of one camera for label maps of one shape.

    ``box`` is the region of the original frame (x0, y0, width, height, in its pixels) that the label map
    covers, stretched: the whole frame by default; a crop or a cut where the frame was prepared so.
    """

    def __init__(self, geometry: CameraGeometry, label_shape: tuple[int, int], classes: LayoutClasses,
                 max_range: float, box: tuple[float, float, float, float] | None = None) -> None:
        self.geometry = geometry
        self.classes = classes
        h, w = int(label_shape[0]), int(label_shape[1])
        self.shape = (h, w)
        x0, y0, bw, bh = box if box is not None else (0.0, 0.0, float(geometry.width), float(geometry.height))
        rows = np.arange(h, dtype=np.float64)
        cols = np.arange(w, dtype=np.float64)
        u = x0 + (cols + 0.5) * bw / w - 0.5
        v_centre = y0 + (rows + 0.5) * bh / h - 0.5
        v_bottom = v_centre + 0.5 * bh / h
        # Rows showing the vehicle's own body are never looked at.
        self.rows = int(np.sum(v_bottom <= geometry.height * (1.0 - geometry.body) + 1e-6))
        self.column_step = max(1, w // CONTACT_COLUMNS)
        self.columns = np.arange(0, w, self.column_step)

        points, valid = self._points(u, v_centre, max_range)
        squares = np.floor(points[valid] / SPLAT).astype(np.int64)
        keys = (squares[:, 0] << 32) | (squares[:, 1] & 0xFFFFFFFF)
        _, square = np.unique(keys, return_inverse=True)
        self.square = np.full((h, w), -1, dtype=np.int64)
        """Each label pixel's square (-1: its ray does not land within range)."""
        self.square[valid] = square.ravel()
        self.n_squares = int(square.max()) + 1 if len(square) else 0
        self.landing = np.flatnonzero(valid)
        """The label pixels whose rays land within range (flat indices): the only ones a frame looks up."""
        self.landing_square = self.square.ravel()[self.landing]
        count = np.bincount(self.square[valid], minlength=self.n_squares)[:, None]
        self.square_centre = (np.stack([np.bincount(self.square[valid], points[valid][:, k], self.n_squares)
                                        for k in (0, 1)], axis=1) / np.maximum(count, 1)).astype(np.float32)

        # Contacts: the bottom edge of a pixel is where the thing it shows meets the ground.
        bottom, self.bottom_valid = self._points(u[self.columns], v_bottom, max_range)
        self.bottom = bottom.astype(np.float32)
        ranges = np.hypot(bottom[..., 0], bottom[..., 1])
        column_width = self.column_step * bw / w / geometry.fx
        self.contact_metres = np.where(self.bottom_valid, ranges * column_width, 0.0).astype(np.float32)

    def _points(self, u: np.ndarray, v: np.ndarray, max_range: float) -> tuple[np.ndarray, np.ndarray]:
        """Ground-frame points (rows, columns, 2) of the pixels (v x u), and which land within range."""
        uu, vv = np.meshgrid(u, v)
        vehicle, below = self.geometry.ground(uu, vv)
        points = ground_frame(self.geometry, np.where(below[..., None], vehicle, 0.0))
        valid = below & (np.hypot(points[..., 0], points[..., 1]) < max_range) & (points[..., 0] > 0)
        valid[self.rows:] = False
        return points, valid

    def __call__(self, labels: np.ndarray) -> FramePoints:
        """One frame's label map (the model's class ids, ``shape``) as evidence on the road plane."""
        if labels.shape != self.shape:
            raise ValueError(f"label map of shape {labels.shape}; this projector takes {self.shape}")
        c = self.classes
        ids = labels.astype(np.intp, copy=False)
        kind = c.ray[ids.ravel()[self.landing]]
        use = kind >= 0
        counts = np.bincount(self.landing_square[use] * 3 + kind[use], minlength=3 * self.n_squares)
        held = np.flatnonzero(counts)

        # The lowest ground run of each sampled column (from its lowest ground pixel up to the first that is not
        # ground), and the first thing above it.
        cols = self.columns
        ground = c.is_ground[ids[: self.rows, cols]][::-1]
        seen = ground.any(axis=0)
        ground |= np.arange(len(ground))[:, None] < np.argmax(ground, axis=0)
        run = np.where(ground.all(axis=0), len(ground), np.argmin(ground, axis=0))
        top = self.rows - 1 - run
        found = seen & (run > 0) & (top >= 0)
        col_index = np.flatnonzero(found)
        row = top[found]
        label = ids[row, cols[col_index]]
        keep = ~c.is_sky[label] & self.bottom_valid[row, col_index]
        col_index, row, label = col_index[keep], row[keep], label[keep]
        return FramePoints(
            rays=self.square_centre[held // 3],
            ray_kind=(held % 3).astype(np.int8),
            ray_weight=counts[held].astype(np.float32),
            contacts=self.bottom[row, col_index],
            contact_kind=c.contact[label],
            contact_weight=self.contact_metres[row, col_index],
        )
