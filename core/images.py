"""Reading frames from disk and checking that an array is a usable frame."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .errors import ImageError, InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp")


def list_images(folder: str | Path) -> list[Path]:
    """Image files directly inside ``folder``, in name order (the traverse order)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"not a folder: {folder}")
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputError(f"no images in {folder} (looked for {', '.join(IMAGE_SUFFIXES)}){_subfolders_hint(folder)}")
    return files


def _subfolders_hint(folder: Path, shown: int = 3) -> str:
    """What to point at instead where ``folder`` holds folders (a dataset's root, one folder per traverse)."""
    subfolders = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not subfolders:
        return ""
    names = ", ".join(p.name for p in subfolders[:shown])
    more = f" and {len(subfolders) - shown} more" if len(subfolders) > shown else ""
    # The example is a subfolder that holds images, where one does.
    example = next((p for p in subfolders if _holds_images(p)), subfolders[0])
    return f"; it holds folders ({names}{more}): give one of them as the source, e.g. {example}"


def _holds_images(folder: Path) -> bool:
    try:
        return any(f.suffix.lower() in IMAGE_SUFFIXES for f in folder.iterdir())
    except OSError:  # unreadable: not the one to suggest
        return False


MAX_PIXELS = 100_000_000
"""Image files declaring more pixels than this are refused before they are decoded (a few kilobytes of PNG
can declare gigabytes of pixels)."""


def declared_size(path: Path) -> tuple[int, int] | None:
    """(width, height) the file's header declares, read without decoding the pixels (None: a format whose
    header Pillow does not read)."""
    import warnings

    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # lostx judges the size itself
            with Image.open(path) as image:
                return image.size
    except Image.DecompressionBombError as exc:
        raise ImageError(f"cannot read image {path}: it declares too many pixels ({exc})") from None
    except (OSError, ValueError, SyntaxError):
        return None


def decode_file(path: str | Path, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """The image in a file, decoded by OpenCV with ``flags`` (BGR order), or an error naming the file."""
    path = Path(path)
    data = np.fromfile(path, dtype=np.uint8) if path.is_file() else None
    if data is None:
        raise ImageError(f"cannot read image {path}: no such file")
    size = declared_size(path) if data.size else None
    if size is not None and size[0] * size[1] > MAX_PIXELS:
        raise ImageError(f"cannot read image {path}: it declares {size[0]} x {size[1]} pixels, over the limit of "
                         f"{MAX_PIXELS // 1_000_000} megapixels")
    previous = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # lostx reports a corrupt file itself
    try:
        image = cv2.imdecode(data, flags) if data.size else None
    finally:
        cv2.utils.logging.setLogLevel(previous)
    if image is None:
        raise ImageError(f"cannot read image {path}: not a decodable image ({data.size} bytes)")
    return image


def read_image(path: str | Path) -> np.ndarray:
    """An RGB uint8 H x W x 3 frame; greyscale files are replicated to three channels."""
    return np.ascontiguousarray(decode_file(path)[:, :, ::-1])


def check_frame(image: object, where: str = "frame") -> np.ndarray:
    """Return ``image`` as an H x W x 3 uint8 array, or raise naming what is wrong."""
    if not isinstance(image, np.ndarray):
        raise ImageError(f"{where}: expected a numpy array, got {type(image).__name__}")
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ImageError(f"{where}: expected an H x W x 3 image, got shape {image.shape}")
    if image.dtype != np.uint8:
        raise ImageError(f"{where}: expected uint8 pixels, got {image.dtype}")
    if image.shape[0] < 16 or image.shape[1] < 16:
        raise ImageError(f"{where}: image of {image.shape[1]}x{image.shape[0]} pixels is too small")
    return image
