"""The semantic backbone interface: one frame in, deep features and class probabilities out.

A backbone maps an RGB uint8 frame (H x W x 3) to a :class:`SemanticFrame`:
the deep feature tensor X (D x h x w, the paper's "conv5") and per-class
probabilities m_is on the same h x w grid (the class scores resized to the
feature grid, then L1-normalised over classes). Backbones register by name, so
``--backbone NAME`` and ``load_backbone(BackboneConfig(name=...))`` find them.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import os
import sys
from dataclasses import dataclass
from pathlib import Path
import typing
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from .config import BackboneConfig
from .errors import ModelError
from .paths import models_dir


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


@dataclass
class SemanticFrame:
    """One frame as the backbone sees it."""

    features: np.ndarray
    """X: (D, h, w) float32 deep features."""
    probs: np.ndarray
    """m: (C, h, w) float32 class probabilities over the model's C classes, summing to 1."""

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


BackboneFactory = Callable[[BackboneConfig, Path], Backbone]

# Built-in backbones: name -> (default model file, "module:factory"), imported only when loaded.
_BUILTIN: dict[str, tuple[str, str]] = {
    "mosaic-ade20k": ("mosaic-r4-ade20k31-uint8.tflite", "lostx.core.mosaic:MosaicBackbone"),
    "espnetv2-cityscapes": ("espnetv2-s2.0-cityscapes-1024x512.pth", "lostx.core.espnet:ESPNetv2Backbone"),
}
_REGISTERED: dict[str, tuple[str, BackboneFactory]] = {}


def register_backbone(name: str, default_file: str) -> Callable[[BackboneFactory], BackboneFactory]:
    """Decorator for a backbone class or factory ``(config, model_path) -> Backbone`` of your own;
    ``default_file`` is looked up in the models folder when no model path is given."""

    def wrap(factory: BackboneFactory) -> BackboneFactory:
        _REGISTERED[name] = (default_file, factory)
        return factory

    return wrap


def _entry(name: str) -> tuple[str, BackboneFactory]:
    if name in _REGISTERED:
        return _REGISTERED[name]
    if name in _BUILTIN:
        default_file, target = _BUILTIN[name]
        module, attr = target.split(":")
        return default_file, getattr(importlib.import_module(module), attr)
    raise ModelError(f"unknown backbone '{name}'; available: {', '.join(backbone_names())}")


def backbone_names() -> list[str]:
    return sorted(set(_BUILTIN) | set(_REGISTERED))


def default_model_paths() -> dict[str, Path]:
    """Each backbone's default model file in the models folder."""
    files = {name: entry[0] for name, entry in {**_BUILTIN, **_REGISTERED}.items()}
    return {name: models_dir() / files[name] for name in backbone_names()}


def resolve_model_path(config: BackboneConfig) -> Path:
    default_file, _ = _entry(config.name)
    path = Path(config.model_path) if config.model_path else models_dir() / default_file
    if not path.is_file():
        raise ModelError(
            f"model file for backbone '{config.name}' not found: {path} "
            f"(pass another with --model PATH, or set LOSTX_MODELS to the folder holding {default_file})"
        )
    return path


def load_backbone(config: BackboneConfig | None = None) -> Backbone:
    """Load the backbone ``config.name`` from ``config.model_path`` (or the models folder)."""
    config = config or BackboneConfig()
    path = resolve_model_path(config)
    return _entry(config.name)[1](config, path)


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
