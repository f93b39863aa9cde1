"""Any TFLite segmentation model, run with LiteRT, its tensors named by a description (``--backbone tflite``).

The feature and score tensors may be intermediate: every tensor is kept after
a run so they can be read. A fused TFLite tensor carries the names of the
layers folded into it, separated by ``;``; a description may name it by any
one of them.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..config import BackboneConfig
from ..errors import InputError, ModelError
from .base import Quantisation, quiet_stderr
from .description import GUIDE, ModelDescription, read_description
from .runtime import DescribedBackbone, TensorSpec


def open_interpreter(path: Path, threads: int) -> Any:
    """A LiteRT interpreter of the model with every tensor kept after a run; a clear error for other files."""
    from ai_edge_litert.interpreter import Interpreter

    if threads < 1:
        raise InputError(f"threads must be at least 1, got {threads}")
    try:
        with warnings.catch_warnings(), quiet_stderr():
            # Reading an intermediate tensor needs every tensor preserved.
            warnings.simplefilter("ignore", UserWarning)
            interpreter = Interpreter(model_path=str(path), num_threads=threads, experimental_preserve_all_tensors=True)
            interpreter.allocate_tensors()
    except (ValueError, RuntimeError) as exc:
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ModelError(f"{path} is not a loadable TFLite model ({reason}); pass another with --model PATH") from None
    return interpreter


def names_of(tensor_name: str) -> list[str]:
    """The names a fused tensor answers to: its full name and each ``;``-separated part."""
    return [tensor_name, *tensor_name.split(";")] if ";" in tensor_name else [tensor_name]


def quantisation_of(detail: dict[str, Any]) -> Quantisation | None:
    scale, zero = detail["quantization"]
    return Quantisation(float(scale), int(zero)) if scale else None


def spec_of(detail: dict[str, Any]) -> TensorSpec:
    return TensorSpec(detail["name"], tuple(int(v) for v in detail["shape"]), np.dtype(detail["dtype"]),
                      quantisation_of(detail))


class TFLiteBackbone(DescribedBackbone):
    """A TFLite model described by a :class:`ModelDescription`."""

    layout = "nhwc"

    def __init__(self, description: ModelDescription, config: BackboneConfig, name: str = "tflite") -> None:
        self._interp = open_interpreter(description.model, config.threads)
        self._input_index = int(self._interp.get_input_details()[0]["index"])
        self._feature_index = self._find(description, description.features, "features")
        self._score_index = self._find(description, description.scores, "scores")
        with quiet_stderr():  # the runtime announces its delegate on the first run
            super().__init__(description, name)

    def _find(self, description: ModelDescription, wanted: str, key: str) -> int:
        details = self._interp.get_tensor_details()
        # A tensor's full name wins over the same name folded into another tensor's.
        found = [d for d in details if d["name"] == wanted] or [d for d in details if wanted in names_of(d["name"])]
        if len(found) != 1:
            problem = "no tensor" if not found else f"{len(found)} tensors"
            raise ModelError(f"{description.model} has {problem} named {wanted!r} (the description's {key}; {GUIDE})")
        return int(found[0]["index"])

    def _input_spec(self) -> TensorSpec:
        inputs = self._interp.get_input_details()
        if len(inputs) != 1:
            raise ModelError(f"{self.description.model} has {len(inputs)} inputs; lostx feeds models one image")
        return spec_of(inputs[0])

    def _prepare(self, size: tuple[int, int]) -> None:
        w, h = size
        if self._input.shape[1:3] == (h, w):
            return
        try:
            self._interp.resize_tensor_input(self._input_index, [1, h, w, 3])
            self._interp.allocate_tensors()
        except (ValueError, RuntimeError) as exc:
            raise ModelError(f"{self.description.model} cannot take {w} x {h} frames (input_size in the "
                             f"description): {str(exc).strip().splitlines()[0]}") from None

    def _run(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._interp.set_tensor(self._input_index, batch)
        try:
            self._interp.invoke()
        except RuntimeError as exc:
            raise ModelError(f"{self.description.model} failed to run: {str(exc).strip().splitlines()[0]}") from None
        return self._interp.get_tensor(self._feature_index), self._interp.get_tensor(self._score_index)

    def _output_specs(self, features: np.ndarray, scores: np.ndarray) -> tuple[TensorSpec, TensorSpec]:
        details = {d["index"]: d for d in self._interp.get_tensor_details()}
        return spec_of(details[self._feature_index]), spec_of(details[self._score_index])


def load_tflite(config: BackboneConfig, path: Path | None) -> TFLiteBackbone:
    """``--backbone tflite --model FILE``: FILE is the description, or the model with its ``.toml`` beside it."""
    if path is None:
        raise ModelError("backbone 'tflite' needs its model: pass --model PATH (the .tflite file with its .toml "
                         "description beside it, or the .toml)")
    return TFLiteBackbone(read_description(path), config)
