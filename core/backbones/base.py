"""The semantic backbone interface: one frame in, deep features and class probabilities out.

A backbone maps an RGB uint8 frame (H x W x 3) to a :class:`SemanticFrame`:
the deep feature tensor X (D x h x w, the paper's "conv5") and per-class
probabilities m_is on the same h x w grid (the class scores resized to the
feature grid, then L1-normalised over classes).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class Quantisation:
    """Affine uint8 quantisation of a tensor: real = scale * (q - zero_point)."""

    scale: float
    zero_point: int


@dataclass(frozen=True)
class BackboneInfo:
    """What identifies a backbone and the tensors it produces; recorded in every map."""

    name: str
    model_file: str
    model_md5: str
    feature_dim: int
    grid: tuple[int, int]
    """(h, w) of the feature grid."""
    class_names: tuple[str, ...]
    default_classes: dict[str, tuple[str, ...]]
    feature_quantisation: Quantisation | None = None
    """Set when the features are exactly representable as uint8 (a quantised model)."""
    feature_tensor: str = ""
    """The network tensor the features are read from."""
    input_size: tuple[int, int] | None = None
    """(width, height) the network takes frames at (None: any)."""


@dataclass
class SemanticFrame:
    """One frame as the backbone sees it."""

    features: np.ndarray
    """X: (D, h, w) float32 deep features."""
    probs: np.ndarray
    """m: (C, h, w) float32 class probabilities over the model's C classes, summing to 1."""
    label_map: np.ndarray | None = None
    """(H', W') uint8: the model's own class of each pixel at its score tensor's resolution, over the whole
    frame it was given (what the layout projects onto the road); None where the backbone gives none."""

    @property
    def grid(self) -> tuple[int, int]:
        return int(self.features.shape[1]), int(self.features.shape[2])

    def labels(self) -> np.ndarray:
        """Eq. 3 over the model's own classes: (h, w) arg-max class ids."""
        return self.probs.argmax(axis=0)


@runtime_checkable
class Backbone(Protocol):
    info: BackboneInfo

    def __call__(self, image: np.ndarray) -> SemanticFrame: ...


def file_md5(path: Path) -> str:
    digest = hashlib.md5()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@contextlib.contextmanager
def quiet_stderr() -> "typing.Iterator[None]":
    """Silence what native runtimes print straight to file descriptor 2 while loading."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def softmax(logits: np.ndarray, axis: int) -> np.ndarray:
    shifted = logits - logits.max(axis=axis, keepdims=True)
    np.exp(shifted, out=shifted)
    shifted /= shifted.sum(axis=axis, keepdims=True)
    return shifted
