"""Frame images on the wire: JPEG, PNG or raw pixels, with their size checked before decoding.

A compressed image is a decompression bomb waiting to happen: a 100-byte PNG can
declare 100000 x 100000 pixels. So the width and height are read from the
header (PNG IHDR, JPEG SOF) and checked against the pixel limit *before* the
decoder allocates anything.

Pillow decodes what arrives: OpenCV's libpng and libjpeg print a line to the
process's stderr for every corrupt image, which would let any peer flood the
service's log; Pillow reports the same failures as exceptions and prints nothing.
OpenCV still encodes (the producer's side, where the images are its own).
"""

from __future__ import annotations

import io
import struct

import cv2
import numpy as np
from PIL import Image

from .errors import ProtocolError

ENCODINGS: tuple[str, ...] = ("jpeg", "png", "raw")

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers (C4 = DHT, C8 = JPG extension, CC = DAC are not frames).
_SOF_MARKERS = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})
# Markers that stand alone, without a length field.
_STANDALONE = frozenset({0x01, *range(0xD0, 0xD9)})


def encode_image(image: np.ndarray, encoding: str, quality: int = 90) -> bytes | memoryview:
    """``image`` (RGB uint8, H x W x 3) as the bytes of one wire encoding (raw: a view of the
    pixels, which msgpack copies once into the message)."""
    if encoding == "raw":
        return memoryview(np.ascontiguousarray(image))
    bgr = np.ascontiguousarray(image[:, :, ::-1])
    if encoding == "jpeg":
        ok, data = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    elif encoding == "png":
        # Level 1: the wire is usually loopback, where encoding time matters more than bytes.
        ok, data = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    else:
        raise ValueError(f"unknown image encoding {encoding!r}; use one of {', '.join(ENCODINGS)}")
    if not ok:
        raise ValueError(f"OpenCV could not encode a {image.shape} image as {encoding}")
    return data.tobytes()


def header_size(data: bytes, encoding: str) -> tuple[int, int]:
    """(height, width) declared by a PNG or JPEG header, without decoding the pixels."""
    if encoding == "png":
        return _png_size(data)
    if encoding == "jpeg":
        return _jpeg_size(data)
    raise ValueError(f"no header to read for encoding {encoding!r}")


def _png_size(data: bytes) -> tuple[int, int]:
    if len(data) < 24 or not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
        raise ProtocolError("bad_image", "image: not a PNG (no PNG signature and IHDR chunk)")
    width, height = struct.unpack(">II", data[16:24])
    return height, width


def _jpeg_size(data: bytes) -> tuple[int, int]:
    if len(data) < 4 or data[0] != 0xFF or data[1] != 0xD8:
        raise ProtocolError("bad_image", "image: not a JPEG (no start-of-image marker)")
    pos = 2
    n = len(data)
    while pos < n:
        if data[pos] != 0xFF:
            raise ProtocolError("bad_image", f"image: corrupt JPEG (no marker at byte {pos})")
        while pos < n and data[pos] == 0xFF:  # fill bytes
            pos += 1
        if pos >= n:
            break
        marker = data[pos]
        pos += 1
        if marker in _STANDALONE:
            continue
        if marker in (0xD9, 0xDA):  # end of image, or start of scan before any frame header
            break
        if pos + 2 > n:
            break
        (length,) = struct.unpack(">H", data[pos:pos + 2])
        if length < 2:
            raise ProtocolError("bad_image", f"image: corrupt JPEG (segment length {length} at byte {pos})")
        if marker in _SOF_MARKERS:
            if pos + 7 > n:
                break
            height, width = struct.unpack(">HH", data[pos + 3:pos + 7])
            return height, width
        pos += length
    raise ProtocolError("bad_image", "image: corrupt JPEG (no frame header before the image data)")


def check_pixels(height: int, width: int, max_pixels: int) -> None:
    if height <= 0 or width <= 0:
        raise ProtocolError("bad_image", f"image: declares {width}x{height} pixels")
    if height * width > max_pixels:
        raise ProtocolError(
            "image_too_large", f"image: {width}x{height} pixels is over the limit of {max_pixels} pixels"
        )


def decode_image(data: bytes, encoding: str, shape: tuple[int, ...] | None) -> np.ndarray:
    """RGB uint8 H x W x 3 pixels of an image whose size has already been checked.

    ``shape`` is required for raw pixels; for JPEG and PNG, where given, the decoded
    image must have it.
    """
    if encoding == "raw":
        if shape is None:
            raise ProtocolError("missing_field", "raw image without a shape")
        image = np.frombuffer(data, dtype=np.uint8).reshape(shape)
        if image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        # A copy: frombuffer gives a read-only view of the message, and the localizer owns its frame.
        return image.copy()
    image = _decode_compressed(data, encoding)
    if shape is not None and tuple(image.shape[:2]) != tuple(shape[:2]):
        raise ProtocolError(
            "bad_image", f"image: decodes to {image.shape[1]}x{image.shape[0]}, the message says {shape[1]}x{shape[0]}"
        )
    return image


_FORMATS = {"png": "PNG", "jpeg": "JPEG"}


def _decode_compressed(data: bytes, encoding: str) -> np.ndarray:
    try:
        with Image.open(io.BytesIO(data), formats=(_FORMATS[encoding],)) as decoded:
            decoded.load()
            if decoded.mode.startswith("I"):
                # 16-bit grey: keep the high byte, as 8-bit viewers do.
                grey = (np.asarray(decoded, dtype=np.uint32) >> 8).astype(np.uint8)
                return np.repeat(grey[:, :, None], 3, axis=2)
            return np.array(decoded.convert("RGB"))
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise ProtocolError("bad_image", f"image: the {encoding} data does not decode ({len(data)} bytes: "
                            f"{_reason(exc)})") from None


def _reason(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) < 100 else text[:97] + "..."
