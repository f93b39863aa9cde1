"""Backbones by name: the built-in ones and those registered by the user.

``--backbone NAME`` and ``load_backbone(BackboneConfig(name=...))`` find a
backbone here; a built-in backbone's module is imported only when it is loaded
(the PyTorch one pulls in torch).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Callable

from ..config import BackboneConfig
from ..errors import ModelError
from ..paths import models_dir
from .base import Backbone

BackboneFactory = Callable[[BackboneConfig, Path], Backbone]

# Built-in backbones: name -> (default model file, "module:factory"), imported only when loaded.
_BUILTIN: dict[str, tuple[str, str]] = {
    "mosaic-ade20k": ("mosaic-r4-ade20k31-uint8.tflite", "lostx.core.backbones.mosaic:MosaicBackbone"),
    "espnetv2-cityscapes": ("espnetv2-s2.0-cityscapes-1024x512.pth", "lostx.core.backbones.espnet:ESPNetv2Backbone"),
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
