"""Backbones by name: built in, registered in Python, installed as plugins, or named as ``module:factory``.

``--backbone NAME``, ``[backbone] name`` and ``load_backbone(BackboneConfig(name=...))`` look, in order:

1. backbones registered in this process with :func:`register_backbone`;
2. the built-in ones (their modules are imported only when loaded: the PyTorch one pulls in torch);
3. entry points in the group ``lostx.backbones`` of the installed packages (a plugin's ``pyproject.toml``
   declares ``[project.entry-points."lostx.backbones"] NAME = "package.module:factory"``);
4. ``package.module:factory`` itself, importable from the Python path or the current folder.

A factory is called as ``factory(config, model_path)`` and returns a :class:`Backbone`; ``model_path`` is
``--model`` (or the default file a built-in or registered backbone names), else None. A map records the
backbone by the name it was loaded with, so ``lostx match`` loads the same one again.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..config import BackboneConfig
from ..errors import ModelError
from ..paths import models_dir
from .base import Backbone, BackboneInfo

BackboneFactory = Callable[[BackboneConfig, "Path | None"], Backbone]
ENTRY_POINT_GROUP = "lostx.backbones"
EXTRAS = {"torch": "torch", "onnxruntime": "onnx", "onnx": "onnx", "onnxscript": "onnx"}
"""Optional packages and the extra of lostx that installs each."""
_TARGET = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_][\w.]*")


@dataclass(frozen=True)
class _Builtin:
    default_file: str | None
    target: str
    """``module:factory``, imported when the backbone is loaded."""


_BUILTIN: dict[str, _Builtin] = {
    "mosaic-ade20k": _Builtin("mosaic-r4-ade20k31-uint8.tflite", "lostx.core.backbones.mosaic:load_mosaic"),
    "espnetv2-cityscapes": _Builtin("espnetv2-s2.0-cityscapes-1024x512.pth",
                                    "lostx.core.backbones.espnet:ESPNetv2Backbone"),
    "tflite": _Builtin(None, "lostx.core.backbones.tflite:load_tflite"),
    "onnx": _Builtin(None, "lostx.core.backbones.onnxrt:load_onnx"),
}
_REGISTERED: dict[str, tuple[str | None, BackboneFactory]] = {}


def register_backbone(name: str, default_file: str | None = None) -> Callable[[BackboneFactory], BackboneFactory]:
    """Decorator for a backbone class or factory ``(config, model_path) -> Backbone`` of your own.

    ``default_file`` is looked up in the models folder when no model path is given; without one the
    factory gets ``model_path=None`` unless ``--model`` names a file.
    """

    def wrap(factory: BackboneFactory) -> BackboneFactory:
        _REGISTERED[name] = (default_file, factory)
        return factory

    return wrap


def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def backbone_names() -> list[str]:
    """Every name ``--backbone`` takes, except ``module:factory``."""
    return sorted(set(_BUILTIN) | set(_REGISTERED) | set(_entry_points()))


def _import_target(target: str, what: str) -> Any:
    module_name, _, attr = target.partition(":")
    if os.getcwd() not in sys.path:
        # After the installed packages: a module in the current folder must not shadow one of them.
        sys.path.append(os.getcwd())
    try:
        value: Any = importlib.import_module(module_name)
        for part in attr.split("."):
            value = getattr(value, part)
    except ImportError as exc:
        if exc.name and exc.name.split(".")[0] in EXTRAS:
            raise
        raise ModelError(f"{what}: cannot import {module_name} ({exc})") from None
    except AttributeError:
        raise ModelError(f"{what}: {module_name} has no {attr!r}") from None
    return value


def _entry(name: str) -> tuple[str | None, BackboneFactory]:
    """(default model file, factory) of a backbone name."""
    if name in _REGISTERED:
        return _REGISTERED[name]
    if name in _BUILTIN:
        builtin = _BUILTIN[name]
        return builtin.default_file, _import_target(builtin.target, f"backbone '{name}'")
    plugin = _entry_points().get(name)
    if plugin is not None:
        package = plugin.dist.name if plugin.dist else "an installed package"
        return None, _import_target(plugin.value, f"backbone '{name}' (plugin of {package})")
    if _TARGET.fullmatch(name):
        return None, _import_target(name, f"backbone '{name}'")
    raise ModelError(f"unknown backbone '{name}'; available: {', '.join(backbone_names())}, "
                     f"or package.module:factory")


def default_model_paths() -> dict[str, Path | None]:
    """Each named backbone's default model file in the models folder (None: it needs ``--model``)."""
    files: dict[str, str | None] = {name: b.default_file for name, b in _BUILTIN.items()}
    files.update({name: entry[0] for name, entry in _REGISTERED.items()})
    files.update({name: None for name in _entry_points()})
    return {name: (models_dir() / files[name]) if files[name] else None for name in backbone_names()}  # type: ignore[operator]


def resolve_model_path(config: BackboneConfig) -> Path | None:
    """The model file a backbone gets: ``config.model_path``, else its default file in the models folder."""
    default_file, _ = _entry(config.name)
    if config.model_path:
        path = Path(config.model_path)
        if not path.exists():
            raise ModelError(f"model file for backbone '{config.name}' not found: {path} (pass another with "
                             f"--model PATH)")
        return path
    if default_file is None:
        return None
    path = models_dir() / default_file
    if not path.is_file():
        raise ModelError(
            f"model file for backbone '{config.name}' not found: {path} "
            f"(pass another with --model PATH, or set LOSTX_MODELS to the folder holding {default_file})"
        )
    return path


def missing_package(exc: ImportError, what: str) -> ModelError:
    """The one-line error for a package ``what`` needs, naming the extra of lostx that installs it."""
    package = (exc.name or "").split(".")[0]
    if package not in EXTRAS:
        return ModelError(f"{what} needs a module that is not installed ({exc})")
    return ModelError(f"{what} needs {package}, which is not installed: pip install 'lostx[{EXTRAS[package]}]'")


def load_backbone(config: BackboneConfig | None = None) -> Backbone:
    """Load the backbone ``config.name`` with its model ``config.model_path`` (or its default file)."""
    config = config or BackboneConfig()
    try:
        path = resolve_model_path(config)
        backbone = _entry(config.name)[1](config, path)
    except ImportError as exc:
        raise missing_package(exc, f"backbone '{config.name}'") from None
    info = getattr(backbone, "info", None)
    if not isinstance(info, BackboneInfo) or not callable(backbone):
        raise ModelError(f"backbone '{config.name}' gave a {type(backbone).__name__}, not a backbone "
                         f"(a callable with an info attribute holding a BackboneInfo; see docs/backbones.md)")
    if info.name != config.name:
        # The map records this name; it must be the one that loads the backbone again.
        try:
            backbone.info = dataclasses.replace(info, name=config.name)
        except AttributeError:
            raise ModelError(f"backbone '{config.name}' calls itself '{info.name}' and its info cannot be set; "
                             f"make info a plain attribute, or name it '{config.name}'") from None
    return backbone
