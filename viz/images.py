"""Images as the viewer gets them: shrunk to the display width and JPEG-compressed.

A raw 1024 x 640 RGB frame is 2 MB; shown 512 pixels wide as a JPEG it is
about 30 kB, which is what keeps a long stream inside the viewer's memory limit.
Reference images are read from disk once and kept, encoded, in a small cache:
consecutive frames often match the same few references. Reading one is the
single largest cost of the view (a 1024 x 640 PNG takes ~17 ms to decode here),
so they are decoded straight at the reduced size where the codec can.
"""

from __future__ import annotations

import hashlib
import io
import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lostx.core.errors import ImageError
from lostx.core.images import read_image
from lostx.core.maps.refmap import ReferenceMap

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


_REDUCED = {2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}


def read_for_display(path: Path, width: int | None) -> np.ndarray:
    """An RGB image file, decoded at (about) the size it will be shown at.

    Where the display size is the file's size over 2, 4 or 8, the decoder reduces as it
    decodes (several times faster for JPEG, a little for PNG); otherwise full size.
    """
    size = file_size(path)
    factor = size[0] // display_size(size[1], size[0], width)[0] if size else 1
    if factor not in _REDUCED:
        return read_image(path)
    data = np.fromfile(path, dtype=np.uint8)
    image = cv2.imdecode(data, _REDUCED[factor]) if data.size else None
    if image is None:
        raise ImageError(f"cannot read image {path}: not a decodable image ({data.size} bytes)")
    return np.ascontiguousarray(image[:, :, ::-1])


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a JPEG's header; None if it is not a readable JPEG."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as image:
            return (int(image.width), int(image.height)) if image.format == "JPEG" else None
    except (OSError, UnidentifiedImageError):
        return None


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
    """Encoded reference images by map index: in memory (least recently used dropped first),
    and optionally on disk, so that a later run against the same map reads each one as a
    ready JPEG instead of decoding the original again.

    The disk copies live in ``disk / <map id>-w<width>-q<quality>/<index>.jpg``; the map id is
    a digest of the map's manifest, so a rebuilt map never shows another build's images.
    A cache that cannot be written (read-only home, full disk) is given up silently.
    """

    def __init__(self, refmap: ReferenceMap, width: int | None, quality: int, capacity: int = 64,
                 disk: Path | None = None) -> None:
        self.map = refmap
        self.width = width
        self.quality = quality
        self.capacity = max(1, capacity)
        self._cache: OrderedDict[int, Jpeg | None] = OrderedDict()
        self.folder = self._folder(disk) if disk is not None else None
        self.decoded = 0
        """Reference images decoded from their original files (the expensive path)."""

    def _folder(self, disk: Path) -> Path | None:
        try:
            digest = hashlib.sha256((self.map.path / "manifest.json").read_bytes()).hexdigest()[:16]
        except OSError:
            return None
        return Path(disk) / f"{digest}-w{self.width or 0}-q{self.quality}"

    def get(self, index: int) -> Jpeg | None:
        """The reference image ``index``, or None where the map has no image root or the file is gone."""
        if index in self._cache:
            self._cache.move_to_end(index)
            return self._cache[index]
        jpeg = self._from_disk(index)
        if jpeg is None:
            jpeg = self._decode(index)
            if jpeg is not None:
                self._to_disk(index, jpeg)
        self._cache[index] = jpeg
        if len(self._cache) > self.capacity:
            self._cache.popitem(last=False)
        return jpeg

    def _decode(self, index: int) -> Jpeg | None:
        path = self.map.image_path(index)
        if path is None or not path.is_file():
            return None
        try:
            jpeg = encode(read_for_display(path, self.width), self.width, self.quality)
        except ImageError:
            return None
        self.decoded += 1
        return jpeg

    def _from_disk(self, index: int) -> Jpeg | None:
        if self.folder is None:
            return None
        try:
            data = (self.folder / f"{index}.jpg").read_bytes()
        except OSError:
            return None
        size = jpeg_size(data)
        return Jpeg(data, *size) if size else None

    def _to_disk(self, index: int, jpeg: Jpeg) -> None:
        if self.folder is None:
            return
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            tmp = self.folder / f".{index}.{os.getpid()}.tmp"
            tmp.write_bytes(jpeg.data)
            os.replace(tmp, self.folder / f"{index}.jpg")  # readers never see a partial file
        except OSError:
            self.folder = None

    def display_size(self) -> tuple[int, int] | None:
        """(width, height) the map's images are shown at, from the first image's header; None without images."""
        size = file_size(self.map.image_path(0)) if self.map.n_frames else None
        return display_size(size[1], size[0], self.width) if size else None

    def __len__(self) -> int:
        return len(self._cache)
