"""MOSAIC (MobileNetV3 + MOSAIC head), ADE20K classes, quantised uint8 TFLite, run with LiteRT.

The deep features are the last encoder convolution (``MobilenetV3/Conv_1``,
32 x 32 x 448 uint8 at a 512 x 512 input: the "conv5" of this net); the class
scores are the decoder's logits (``decoder/add``, 128 x 128 x 32), turned
into probabilities by a softmax and area-resized to the feature grid.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np

from .base import BackboneInfo, Quantisation, SemanticFrame, file_md5, quiet_stderr, softmax
from ..config import BackboneConfig
from ..errors import ModelError
from ..images import check_frame

ADE20K_CLASSES = (
    "other", "wall", "building", "sky", "floor", "tree", "ceiling", "road", "bed", "windowpane",
    "grass", "cabinet", "sidewalk", "person", "earth", "door", "table", "mountain", "plant",
    "curtain", "chair", "car", "water", "painting", "sofa", "shelf", "house", "sea", "mirror",
    "rug", "field", "armchair",
)
DEFAULT_CLASSES = {
    "road": ("road",),
    "building": ("building", "house"),
    "vegetation": ("tree", "plant", "grass"),
}
FEATURE_TENSOR = "MobilenetV3/Conv_1/Relu"
SCORES_TENSOR = "decoder/add"


class MosaicBackbone:
    """The default backbone: about 30 ms per frame on two CPU cores."""

    def __init__(self, config: BackboneConfig, path: Path) -> None:
        from ai_edge_litert.interpreter import Interpreter

        try:
            with warnings.catch_warnings(), quiet_stderr():
                # Reading the intermediate feature tensor needs every tensor preserved.
                warnings.simplefilter("ignore", UserWarning)
                self._interp = Interpreter(
                    model_path=str(path), num_threads=config.threads, experimental_preserve_all_tensors=True
                )
                self._interp.allocate_tensors()
                self._interp.invoke()  # the runtime announces its delegate on the first run
        except (ValueError, RuntimeError) as exc:
            raise ModelError(
                f"{path} is not a loadable TFLite model ({exc}); pass the MOSAIC file with --model PATH"
            ) from None
        details = {d["name"]: d for d in self._interp.get_tensor_details()}
        features = [d for name, d in details.items() if name.startswith(FEATURE_TENSOR)]
        inputs = self._interp.get_input_details()
        if not features or SCORES_TENSOR not in details or len(inputs) != 1:
            raise ModelError(
                f"{path} is a TFLite model but not MOSAIC: it lacks the tensors {FEATURE_TENSOR!r} and "
                f"{SCORES_TENSOR!r}; pass the MOSAIC file with --model PATH"
            )
        self._input = inputs[0]
        self._features = features[0]
        self._scores = details[SCORES_TENSOR]
        _, in_h, in_w, _ = (int(v) for v in self._input["shape"])
        _, fh, fw, dim = (int(v) for v in self._features["shape"])
        n_classes = int(self._scores["shape"][-1])
        if n_classes != len(ADE20K_CLASSES) or self._input["dtype"] != np.uint8:
            raise ModelError(f"{path}: expected a uint8 model with {len(ADE20K_CLASSES)} classes, got {n_classes}")
        self._input_size = (in_w, in_h)
        scale, zero = self._features["quantization"]
        self._feature_q = Quantisation(float(scale), int(zero))
        scale, zero = self._scores["quantization"]
        self._scores_q = Quantisation(float(scale), int(zero))
        self.info = BackboneInfo(
            name="mosaic-ade20k",
            model_file=path.name,
            model_md5=file_md5(path),
            feature_dim=dim,
            grid=(fh, fw),
            class_names=ADE20K_CLASSES,
            default_classes=DEFAULT_CLASSES,
            feature_quantisation=self._feature_q,
            input_size=self._input_size,
        )

    def __call__(self, image: np.ndarray) -> SemanticFrame:
        image = check_frame(image)
        resized = cv2.resize(image, self._input_size, interpolation=cv2.INTER_AREA)
        self._interp.set_tensor(self._input["index"], resized[None])
        self._interp.invoke()
        q = self._interp.get_tensor(self._features["index"])[0]
        features = (q.astype(np.float32) - self._feature_q.zero_point) * self._feature_q.scale
        logits = self._interp.get_tensor(self._scores["index"])[0]
        logits = (logits.astype(np.float32) - self._scores_q.zero_point) * self._scores_q.scale
        probs = softmax(logits, axis=-1)
        fh, fw = self.info.grid
        # Paper footnote 2: the score tensor is resized to the feature grid; area keeps it a distribution.
        probs = cv2.resize(probs, (fw, fh), interpolation=cv2.INTER_AREA)
        probs /= probs.sum(axis=-1, keepdims=True)
        return SemanticFrame(
            features=np.ascontiguousarray(features.transpose(2, 0, 1)),
            probs=np.ascontiguousarray(probs.transpose(2, 0, 1)),
        )
