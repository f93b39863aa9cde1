"""MOSAIC (MobileNetV3 + MOSAIC head), ADE20K classes, quantised uint8 TFLite, run with LiteRT.

The built-in description of the generic TFLite backbone: the deep features are
the last encoder convolution (``MobilenetV3/Conv_1``, 32 x 32 x 448 uint8 at
a 512 x 512 input: the "conv5" of this net); the class scores are the
decoder's logits (``decoder/add``, 128 x 128 x 32). The same model described
by a TOML file and run with ``--backbone tflite`` gives the same answers.
"""

from __future__ import annotations

from pathlib import Path

from ..config import BackboneConfig
from .description import ModelDescription
from .tflite import TFLiteBackbone

ADE20K_CLASSES = (
    "other", "wall", "building", "sky", "floor", "tree", "ceiling", "road", "bed", "windowpane",
    "grass", "cabinet", "sidewalk", "person", "earth", "door", "table", "mountain", "plant",
    "curtain", "chair", "car", "water", "painting", "sofa", "shelf", "house", "sea", "mirror",
    "rug", "field", "armchair",
)
NAME = "mosaic-ade20k"


def mosaic_description(path: Path) -> ModelDescription:
    """MOSAIC's tensors and classes; the 512 x 512 uint8 input takes raw pixels, area-resized (also where a frame
    is smaller: MOSAIC's maps and measurements were made so)."""
    return ModelDescription(
        model=path,
        features="MobilenetV3/Conv_1/Relu",
        scores="decoder/add",
        classes=ADE20K_CLASSES,
        default_classes="street",
        resize="area",
    )


def load_mosaic(config: BackboneConfig, path: Path) -> TFLiteBackbone:
    """The default backbone: about 40 ms per frame on two CPU cores."""
    return TFLiteBackbone(mosaic_description(path), config, name=NAME)
