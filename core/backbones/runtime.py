"""What the generic TFLite and ONNX backbones share: feeding a frame as the description says, and turning
the named feature and score tensors into a :class:`SemanticFrame`.

A runtime supplies three things (:class:`DescribedBackbone`'s abstract
methods): the input tensor, a run that returns the two named tensors, and
their quantisation. Everything else (resizing, normalising, dequantising, the
softmax, resizing the scores onto the feature grid) is here, once.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ModelError
from ..images import check_frame
from .base import BackboneInfo, Quantisation, SemanticFrame, file_md5, softmax
from .description import GUIDE, Layout, ModelDescription, Resize


@dataclass(frozen=True)
class TensorSpec:
    """A model tensor as a runtime reports it."""

    name: str
    shape: tuple[int | None, ...]
    """Unknown (dynamic) dimensions are None."""
    dtype: np.dtype
    quantisation: Quantisation | None = None


def resize_frame(image: np.ndarray, size: tuple[int, int], resize: Resize = "auto") -> np.ndarray:
    """The frame resized to (width, height): area averaging when it shrinks both ways (or always, with
    ``resize="area"``), else bilinear."""
    h, w = image.shape[:2]
    area = resize == "area" or (size[0] <= w and size[1] <= h)
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if area else cv2.INTER_LINEAR)


def dequantise(values: np.ndarray, quantisation: Quantisation | None) -> np.ndarray:
    if quantisation is None:
        return values.astype(np.float32, copy=False)
    return (values.astype(np.float32) - quantisation.zero_point) * quantisation.scale


def probabilities_on_grid(scores: np.ndarray, grid: tuple[int, int], logits: bool) -> np.ndarray:
    """(H, W, C) class scores -> (C, h, w) probabilities on the feature grid.

    The paper (footnote 2) resizes the score map to the feature grid; an area
    resize of the probabilities keeps each cell a distribution.
    """
    probs = softmax(scores, axis=-1) if logits else scores.astype(np.float32)
    h, w = grid
    probs = cv2.resize(probs, (w, h), interpolation=cv2.INTER_AREA)
    if probs.ndim == 2:  # OpenCV drops a single channel's axis
        probs = probs[..., None]
    probs /= np.maximum(probs.sum(axis=-1, keepdims=True), np.finfo(np.float32).tiny)
    return np.ascontiguousarray(probs.transpose(2, 0, 1))


class DescribedBackbone(ABC):
    """A backbone whose tensors, input and classes come from a :class:`ModelDescription`."""

    layout: Layout
    """The runtime's axis order when the description gives none."""

    def __init__(self, description: ModelDescription, name: str) -> None:
        self.description = description
        self.layout = description.layout or self.layout
        self._input = self._input_spec()
        _check_input_dtype(self._input, description)
        self._input_size = self._input_size_of(self._input)
        self._prepare(self._input_size)
        features, scores = self._run(np.zeros(self._input_shape(), dtype=self._input.dtype))
        self._features, self._scores = self._output_specs(features, scores)
        f = self._hwc(features, self._features, "features")
        s = self._hwc(scores, self._scores, "scores")
        if s.shape[-1] != len(description.classes):
            raise ModelError(
                f"{description.model}: score tensor {description.scores!r} has {s.shape[-1]} channels but the "
                f"description lists {len(description.classes)} classes (layout {self.layout}; {GUIDE})"
            )
        q = self._features.quantisation
        self.info = BackboneInfo(
            name=name,
            model_file=description.model.name,
            model_md5=file_md5(description.model),
            feature_dim=int(f.shape[2]),
            grid=(int(f.shape[0]), int(f.shape[1])),
            class_names=description.classes,
            default_classes=description.class_groups(),
            feature_quantisation=q if q is not None and self._features.dtype == np.uint8 else None,
            feature_tensor=description.features,
            input_size=self._input_size,
        )

    @abstractmethod
    def _input_spec(self) -> TensorSpec:
        """The model's one image input."""

    def _prepare(self, size: tuple[int, int]) -> None:
        """Make the model take frames of this (width, height) (a runtime with fixed shapes may resize)."""

    @abstractmethod
    def _run(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The raw feature and score tensors for one input batch."""

    @abstractmethod
    def _output_specs(self, features: np.ndarray, scores: np.ndarray) -> tuple[TensorSpec, TensorSpec]:
        """The feature and score tensors, given a first run's values (some runtimes know shapes only then)."""

    def _input_size_of(self, spec: TensorSpec) -> tuple[int, int]:
        shape = spec.shape
        where = f"{self.description.model}: input {spec.name!r} of shape {_shape(shape)}"
        channels_axis = 3 if self.layout == "nhwc" else 1
        if len(shape) != 4 or shape[channels_axis] != 3:
            raise ModelError(f"{where} is not one {self.layout} RGB image (set layout in the description?)")
        if self.description.input_size is not None:
            return self.description.input_size
        h, w = (shape[1], shape[2]) if self.layout == "nhwc" else (shape[2], shape[3])
        if h is None or w is None:
            raise ModelError(f"{where} has no fixed size: set input_size = [width, height] in the description")
        return int(w), int(h)

    def _input_shape(self) -> tuple[int, int, int, int]:
        w, h = self._input_size
        return (1, h, w, 3) if self.layout == "nhwc" else (1, 3, h, w)

    def _hwc(self, tensor: np.ndarray, spec: TensorSpec, role: str) -> np.ndarray:
        """One tensor of the batch as (h, w, channels)."""
        if tensor.ndim != 4 or tensor.shape[0] != 1:
            raise ModelError(
                f"{self.description.model}: {role} tensor {spec.name!r} has shape {_shape(tensor.shape)}, not a "
                f"batch of one {self.layout} map (a weight or a label tensor? {GUIDE})"
            )
        if not (np.issubdtype(tensor.dtype, np.floating) or spec.quantisation is not None):
            raise ModelError(f"{self.description.model}: {role} tensor {spec.name!r} holds {tensor.dtype} values "
                             f"without quantisation: not scores or features ({GUIDE})")
        return tensor[0] if self.layout == "nhwc" else tensor[0].transpose(1, 2, 0)

    def _feed(self, image: np.ndarray) -> np.ndarray:
        """The frame as the model's input batch: resized, normalised, quantised as the input tensor wants."""
        d, spec = self.description, self._input
        pixels = resize_frame(check_frame(image), self._input_size, d.resize)
        if d.mean is None or d.std is None:
            values = pixels if spec.dtype == np.uint8 else pixels.astype(np.float32)
        else:
            values = (pixels.astype(np.float32) - np.float32(d.mean)) / np.float32(d.std)
            if spec.quantisation is not None:
                info = np.iinfo(spec.dtype)
                q = spec.quantisation
                values = np.clip(np.rint(values / q.scale + q.zero_point), info.min, info.max)
        batch = values.astype(spec.dtype, copy=False)[None]
        return batch if self.layout == "nhwc" else np.ascontiguousarray(batch.transpose(0, 3, 1, 2))

    def __call__(self, image: np.ndarray) -> SemanticFrame:
        features, scores = self._run(self._feed(image))
        f = dequantise(self._hwc(features, self._features, "features"), self._features.quantisation)
        s = dequantise(self._hwc(scores, self._scores, "scores"), self._scores.quantisation)
        return SemanticFrame(
            features=np.ascontiguousarray(f.transpose(2, 0, 1)),
            probs=probabilities_on_grid(s, self.info.grid, self.description.scores_are == "logits"),
            label_map=label_map(s),
        )


def label_map(scores: np.ndarray) -> np.ndarray | None:
    """(H, W) uint8 arg-max class of (H, W, C) scores at their own resolution (None beyond 256 classes)."""
    return scores.argmax(axis=-1).astype(np.uint8) if scores.shape[-1] <= 256 else None


def _shape(shape: tuple[int | None, ...]) -> str:
    return " x ".join("?" if v is None else str(v) for v in shape) or "scalar"


def _check_input_dtype(spec: TensorSpec, description: ModelDescription) -> None:
    """Float inputs take normalised pixels, uint8 ones raw pixels; quantised integers need the normalisation."""
    if np.issubdtype(spec.dtype, np.floating):
        return
    if description.mean is None and spec.dtype == np.uint8:
        return
    if description.mean is not None and spec.quantisation is not None and np.issubdtype(spec.dtype, np.integer):
        return
    raise ModelError(f"{description.model}: input {spec.name!r} is {np.dtype(spec.dtype)}; lostx feeds float "
                     f"images, raw uint8 pixels, or quantised integers when the description gives mean and std")
