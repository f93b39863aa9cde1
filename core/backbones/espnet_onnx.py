"""ESPNetv2 as an ONNX model with its description beside it, for ``--backbone onnx`` (``lostx backbones export-onnx``).

The exported graph takes one 768 x 384 RGB frame normalised as the PyTorch
backbone does, and has two outputs: ``features`` (the last encoder level) and
``logits`` (the decoder's class scores at half the input size). The generic
ONNX backbone then does what the PyTorch one does after the network: softmax,
area resize onto the feature grid.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError, ModelError
from .base import quiet_stderr
from .description import description_path
from .espnet import CITYSCAPES_CLASSES, DEFAULT_CLASSES, IMAGENET_MEAN, IMAGENET_STD, INPUT_SIZE, load_network

OPSET = 18


@dataclass(frozen=True)
class Exported:
    model: Path
    description: Path
    bytes: int


def description_text(model_file: str, source: str) -> str:
    """The TOML describing the exported model (``model_file`` beside it)."""
    mean = [round(255.0 * v, 6) for v in IMAGENET_MEAN]
    std = [round(255.0 * v, 6) for v in IMAGENET_STD]
    return "\n".join([
        f"# ESPNetv2 (scale 2.0, Cityscapes), exported from {source} by `lostx backbones export-onnx`",
        f"model = {json.dumps(model_file)}",
        'features = "features"',
        'scores = "logits"',
        'scores_are = "logits"',
        f"input_size = {list(INPUT_SIZE)}",
        f"mean = {mean}",
        f"std = {std}",
        f"classes = {json.dumps(list(CITYSCAPES_CLASSES))}",
        # the PyTorch backbone's own groups, so that both give the same descriptors
        "default_classes = { " + ", ".join(f"{group} = {json.dumps(list(members))}"
                                           for group, members in DEFAULT_CLASSES.items()) + " }",
        "",
    ])


def export_onnx(weights: Path, out: Path, overwrite: bool = False) -> Exported:
    """Write the ESPNetv2 checkpoint ``weights`` as ONNX to ``out`` and its description beside it."""
    import torch

    out = Path(out)
    toml = description_path(out)
    if out.suffix != ".onnx":
        raise InputError(f"{out}: the exported model's file name must end in .onnx")
    for path in (out, toml):
        if path.exists() and not overwrite:
            raise InputError(f"{path} already exists; pass --overwrite to replace it")
    if not out.parent.is_dir():
        raise InputError(f"{out.parent} is not a folder")
    net = load_network(Path(weights))
    width, height = INPUT_SIZE
    partial = out.with_name(f".{out.name}.partial-{os.getpid()}")
    try:
        # The exporter reports its steps on stdout and stderr; lostx reports the outcome.
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()), quiet_stderr():
            warnings.simplefilter("ignore")
            torch.onnx.export(net, (torch.zeros(1, 3, height, width),), str(partial), input_names=["image"],
                              output_names=["features", "logits"], opset_version=OPSET, dynamo=True,
                              external_data=False)
        toml.write_text(description_text(out.name, Path(weights).name))
        os.replace(partial, out)
    except ImportError:
        partial.unlink(missing_ok=True)
        raise
    except Exception as exc:  # the exporter fails in many ways; the first line says which
        partial.unlink(missing_ok=True)
        reason = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise ModelError(f"exporting {weights} to ONNX failed: {reason}") from None
    return Exported(out, toml, out.stat().st_size)
