"""Bringing frames of different cameras to a common geometry before the network.

Front and rear cameras rarely share a field of view (nuScenes: 65 against 90
degrees), and a rear camera often sees the vehicle's own body along its bottom
edge. Before the network, each frame is:

1. cut: ``ignore_top`` / ``ignore_bottom`` (fractions of the height) dropped;
2. narrowed to the common field of view ``view_hfov_deg`` when its camera's
   ``hfov_deg`` is wider: a centred crop of width W tan(view/2) / tan(hfov/2)
   (a pinhole camera; the height is cropped in proportion, so the scale of
   the scene matches between the cameras);
3. fitted to the network input's aspect ratio: ``squash`` (resize as is, the
   whole frame seen), ``crop`` (the centre that has the input's aspect) or
   ``pad`` (black borders).

Steps 1 and 2 take the settings of the camera the frame declares (``front``,
``rear``); all three are no-ops with the default settings. A map records the
settings its frames were prepared with; queries are prepared to its field of
view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..config import CameraConfig, Fit
from ..errors import InputError
from ..frame import Camera

if TYPE_CHECKING:
    from ..backbones import BackboneInfo


@dataclass(frozen=True)
class Geometry:
    """How the frames of each camera are prepared for one map."""

    cameras: CameraConfig
    view_hfov_deg: float | None
    """The map's common field of view (None: none)."""
    fit: Fit
    input_aspect: float | None
    """Width / height of the network input (None: unknown, no fitting)."""

    @classmethod
    def for_backbone(cls, cameras: CameraConfig, view_hfov_deg: float | None, fit: Fit,
                     info: "BackboneInfo") -> "Geometry":
        size = info.input_size
        return cls(cameras, view_hfov_deg, fit, None if size is None else size[0] / size[1])

    def prepare(self, image: np.ndarray, camera: Camera | None) -> np.ndarray:
        """The frame of ``camera`` (as the frame declares it) as the network should see it."""
        c = self.cameras
        out = image
        if camera is not None:
            out = cut_rows(out, c.ignore_top.get(camera, 0.0), c.ignore_bottom.get(camera, 0.0))
            hfov = c.hfov_deg.get(camera)
            if self.view_hfov_deg is not None and hfov is not None:
                out = narrow_to_fov(out, hfov, self.view_hfov_deg)
        if self.input_aspect is not None:
            out = fit_aspect(out, self.input_aspect, self.fit)
        return np.ascontiguousarray(out)

    def region(self, size: tuple[int, int], camera: Camera | None) -> tuple[float, float, float, float]:
        """The part of a ``size`` (width, height) frame that :meth:`prepare` hands the network, as
        (x0, y0, width, height) in the frame's pixels (beyond the frame where it is padded)."""
        c = self.cameras
        w, h = float(size[0]), float(size[1])
        x0 = y0 = 0.0
        if camera is not None:
            top, bottom = c.ignore_top.get(camera, 0.0), c.ignore_bottom.get(camera, 0.0)
            if top or bottom:
                first, last = int(round(top * h)), int(h) - int(round(bottom * h))
                y0, h = y0 + first, float(last - first)
            hfov = c.hfov_deg.get(camera)
            if self.view_hfov_deg is not None and hfov is not None and self.view_hfov_deg < hfov:
                scale = math.tan(math.radians(self.view_hfov_deg) / 2) / math.tan(math.radians(hfov) / 2)
                cw, ch = max(1, int(round(w * scale))), max(1, int(round(h * scale)))
                x0, y0 = x0 + (w - cw) // 2, y0 + (h - ch) // 2
                w, h = float(cw), float(ch)
        if self.input_aspect is not None and self.fit != "squash" and abs(w / h - self.input_aspect) >= 1e-6:
            if (self.fit == "crop") == (w / h > self.input_aspect):
                cw = float(int(round(h * self.input_aspect)))
                x0, w = x0 + (w - cw) // 2, cw
            else:
                ch = float(int(round(w / self.input_aspect)))
                y0, h = y0 + (h - ch) // 2, ch
        return x0, y0, w, h

    def record(self) -> dict[str, Any]:
        """What a map keeps of how its frames were prepared."""
        c = self.cameras
        return {"view_hfov_deg": self.view_hfov_deg, "fit": self.fit, "hfov_deg": dict(c.hfov_deg),
                "ignore_top": dict(c.ignore_top), "ignore_bottom": dict(c.ignore_bottom)}


def cut_rows(image: np.ndarray, top: float, bottom: float) -> np.ndarray:
    if top == 0 and bottom == 0:
        return image
    h = image.shape[0]
    y0, y1 = int(round(top * h)), h - int(round(bottom * h))
    if y1 - y0 < 16:
        raise InputError(f"ignoring {top:g} of the top and {bottom:g} of the bottom leaves {y1 - y0} rows of {h}")
    return image[y0:y1]


def narrow_to_fov(image: np.ndarray, hfov_deg: float, view_hfov_deg: float) -> np.ndarray:
    """The centred part of a pinhole image with ``hfov_deg`` that a ``view_hfov_deg`` camera would see."""
    if view_hfov_deg >= hfov_deg:
        return image
    scale = math.tan(math.radians(view_hfov_deg) / 2) / math.tan(math.radians(hfov_deg) / 2)
    h, w = image.shape[:2]
    cw, ch = max(1, int(round(w * scale))), max(1, int(round(h * scale)))
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    return image[y0 : y0 + ch, x0 : x0 + cw]


def fit_aspect(image: np.ndarray, aspect: float, fit: Fit) -> np.ndarray:
    """``squash``: unchanged (the network's resize squashes it); ``crop``: the centre with the given
    width / height; ``pad``: black borders up to it."""
    if fit == "squash":
        return image
    h, w = image.shape[:2]
    if abs(w / h - aspect) < 1e-6:
        return image
    if fit == "crop":
        if w / h > aspect:
            cw = int(round(h * aspect))
            x0 = (w - cw) // 2
            return image[:, x0 : x0 + cw]
        ch = int(round(w / aspect))
        y0 = (h - ch) // 2
        return image[y0 : y0 + ch]
    if w / h > aspect:
        size = (int(round(w / aspect)), w)
    else:
        size = (h, int(round(h * aspect)))
    out = np.zeros((*size, image.shape[2]), dtype=image.dtype)
    y0, x0 = (size[0] - h) // 2, (size[1] - w) // 2
    out[y0 : y0 + h, x0 : x0 + w] = image
    return out
