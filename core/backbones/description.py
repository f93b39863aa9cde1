"""A segmentation model described as data: a small TOML file beside the model file.

It names what LoST-X reads from the network and how to feed it, so a TFLite or
ONNX model of one's own needs no code (docs/backbones.md has the keys)::

    model = "deeplab-ade20k.tflite"        # beside this file
    features = "MobilenetV2/Conv_1/Relu6"  # the deep features (D channels on an h x w grid)
    scores = "logits"                      # per-class scores, any resolution
    classes = ["other", "wall", "building", ...]
    default_classes = "street"             # or { road = ["road"], ... }
"""

from __future__ import annotations

import tomllib
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from ..config import _coerce as coerce_setting
from ..errors import ModelError
from .presets import PRESETS, preset_classes

Layout = Literal["nhwc", "nchw"]
ScoreKind = Literal["logits", "probabilities"]
Resize = Literal["auto", "area"]
GUIDE = "see docs/backbones.md; `lostx backbones inspect MODEL` lists a model's tensors"


@dataclass(frozen=True)
class ModelDescription:
    """A model file and what to read from it."""

    model: Path
    """The model file (in the TOML: relative to the TOML file)."""
    features: str
    """Tensor of the deep features: D channels on an h x w grid (the paper's "conv5")."""
    scores: str
    """Tensor of the per-class scores, one channel per entry of ``classes``, at any resolution."""
    classes: tuple[str, ...]
    """The model's class names, in the order of the score channels."""
    default_classes: dict[str, tuple[str, ...]] | str = "street"
    """Descriptor classes when the configuration names none: a preset name or groups of ``classes``."""
    scores_are: ScoreKind = "logits"
    """``logits`` get a softmax over the classes; ``probabilities`` are used as they are."""
    input_size: tuple[int, int] | None = None
    """(width, height) frames are resized to; by default the model's own fixed input size."""
    resize: Resize = "auto"
    """How frames are resized: ``auto`` averages areas where a frame shrinks both ways and interpolates
    bilinearly otherwise; ``area`` always averages areas (OpenCV's INTER_AREA, which enlarges a small frame
    much as nearest neighbour does), as the built-in MOSAIC has from the start."""
    mean: tuple[float, float, float] | None = None
    """Per-channel RGB mean subtracted from the 0-255 pixel values (with ``std``); none feeds raw pixels."""
    std: tuple[float, float, float] | None = None
    """Per-channel RGB divisor after the mean (0-255 scale)."""
    layout: Layout | None = None
    """Axis order of the input, feature and score tensors; by default the runtime's (TFLite nhwc, ONNX nchw)."""

    def class_groups(self) -> dict[str, tuple[str, ...]]:
        """The default descriptor classes as groups of the model's classes."""
        if isinstance(self.default_classes, str):
            return preset_classes(self.default_classes, self.classes)
        return dict(self.default_classes)


_REQUIRED = ("features", "scores", "classes")


def description_path(path: Path) -> Path:
    """The TOML describing ``path``: the file itself, or the ``.toml`` of the same name beside the model."""
    return path if path.suffix == ".toml" else path.with_suffix(".toml")


def read_description(path: str | Path) -> ModelDescription:
    """Read the description of a model: ``path`` is the TOML, or the model file with its TOML beside it."""
    path = Path(path)
    toml_path = description_path(path)
    if not toml_path.is_file():
        if not path.is_file():
            raise ModelError(f"model file not found: {path}; pass the model or its .toml with --model PATH")
        raise ModelError(f"{path} has no description beside it: write {toml_path} naming its feature and score "
                         f"tensors and its classes ({GUIDE})")
    try:
        data = tomllib.loads(toml_path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ModelError(f"{toml_path}: not valid TOML ({exc})") from None
    described = _model_file(data, toml_path, None if path == toml_path else path)
    return _parse(data, described, str(toml_path))


def _model_file(data: dict[str, Any], toml_path: Path, given: Path | None) -> Path:
    named = data.get("model")
    if named is not None and not isinstance(named, str):
        raise ModelError(f"{toml_path} model: expected the model file's path, got {named!r}")
    if named is None and given is None:
        raise ModelError(f"{toml_path} lacks the key 'model': the model file, relative to the TOML file")
    described = (toml_path.parent / named) if named is not None else given
    assert described is not None
    if given is not None and described.resolve() != given.resolve():
        raise ModelError(f"{toml_path} describes {described}, not {given}; pass the TOML itself with --model")
    if not described.is_file():
        raise ModelError(f"model file not found: {described} (named by {toml_path})")
    return described


def _parse(data: dict[str, Any], model: Path, where: str) -> ModelDescription:
    hints = typing.get_type_hints(ModelDescription)
    unknown = sorted(set(data) - set(hints))
    if unknown:
        raise ModelError(f"{where}: unknown key '{unknown[0]}'; known: {', '.join(hints)}")
    missing = [key for key in _REQUIRED if key not in data]
    if missing:
        raise ModelError(f"{where} lacks the key '{missing[0]}' ({GUIDE})")
    values: dict[str, Any] = {"model": model}
    for key, value in data.items():
        if key == "model":
            continue
        if key == "default_classes" and isinstance(value, str):
            values[key] = value
        else:
            values[key] = coerce_setting(value, hints[key], f"{where} {key}")
    description = ModelDescription(**values)
    _check(description, where)
    return description


def _check(d: ModelDescription, where: str) -> None:
    if not d.classes or len(set(d.classes)) != len(d.classes):
        raise ModelError(f"{where} classes: expected distinct class names, one per score channel")
    for key in ("mean", "std", "input_size"):
        value = getattr(d, key)
        expected = 2 if key == "input_size" else 3
        if value is not None and (len(value) != expected or min(value) <= 0 and key != "mean"):
            raise ModelError(f"{where} {key}: expected {expected} positive numbers, got {list(value)}")
    if (d.mean is None) != (d.std is None):
        raise ModelError(f"{where}: give mean and std together (or neither, to feed raw pixels)")
    if isinstance(d.default_classes, str):
        if d.default_classes not in PRESETS:
            raise ModelError(f"{where} default_classes: unknown preset '{d.default_classes}'; "
                             f"presets: {', '.join(PRESETS)}, or a table of groups")
        d.class_groups()
        return
    for group, members in d.default_classes.items():
        strangers = [m for m in members if m not in d.classes]
        if not members or strangers:
            raise ModelError(f"{where} default_classes: group '{group}' names "
                             f"{strangers[0] if strangers else 'no class'!r}, not one of the model's classes")
