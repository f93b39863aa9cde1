"""Images as the viewer gets them: shrunk to the display width and JPEG-compressed.

A raw 1024 x 640 RGB frame is 2 MB; as a 640-pixel-wide JPEG it is about 40 kB,
which is what keeps a long stream inside the viewer's memory limit.
Reference images are read from disk once and kept, encoded, in a small cache:
consecutive frames usually match the same few references.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lostx.core.errors import ImageError
from lostx.core.images import read_image
from lostx.core.refmap import ReferenceMap

from .geometry import display_size


@dataclass(frozen=True)
class Jpeg:
    data: bytes
    width: int
    height: int


def encode(image: np.ndarray, width: int | None, quality: int, mirror: bool = False) -> Jpeg:
    """RGB uint8 H x W x 3 -> a JPEG ``width`` pixels wide (aspect kept, never enlarged), optionally mirrored."""
    h, w = image.shape[:2]
    size = display_size(h, w, width)
    if size != (w, h):
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    if mirror:
        image = image[:, ::-1]
    # OpenCV encodes BGR; reversing the channel axis is a view, imencode copies anyway.
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ImageError(f"could not JPEG-encode a {w}x{h} image")
    return Jpeg(data.tobytes(), size[0], size[1])


def file_size(path: Path | None) -> tuple[int, int] | None:
    """(width, height) of an image file from its header (no decoding); None if it cannot be read."""
    if path is None or not path.is_file():
        return None
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            return int(image.width), int(image.height)
    except (OSError, UnidentifiedImageError):
        return None


class ReferenceImages:
    """Encoded reference images by map index, least recently used dropped first."""

    def __init__(self, refmap: ReferenceMap, width: int | None, quality: int, capacity: int = 64) -> None:
        self.map = refmap
        self.width = width
        self.quality = quality
        self.capacity = max(1, capacity)
        self._cache: OrderedDict[int, Jpeg | None] = OrderedDict()

    def get(self, index: int) -> Jpeg | None:
        """The reference image ``index``, or None where the map has no image root or the file is gone."""
        if index in self._cache:
            self._cache.move_to_end(index)
            return self._cache[index]
        path = self.map.image_path(index)
        jpeg = None
        if path is not None and path.is_file():
            try:
                jpeg = encode(read_image(path), self.width, self.quality)
            except ImageError:
                jpeg = None
        self._cache[index] = jpeg
        if len(self._cache) > self.capacity:
            self._cache.popitem(last=False)
        return jpeg

    def display_size(self) -> tuple[int, int] | None:
        """(width, height) the map's images are shown at, from the first image's header; None without images."""
        size = file_size(self.map.image_path(0)) if self.map.n_frames else None
        return display_size(size[1], size[0], self.width) if size else None

    def __len__(self) -> int:
        return len(self._cache)
