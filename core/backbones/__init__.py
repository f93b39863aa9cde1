"""Semantic segmentation backbones: the interface, the registry, the generic runtimes and the built-in networks.

- :mod:`.base`: what a backbone is (:class:`Backbone`) and what it returns (:class:`SemanticFrame`);
- :mod:`.registry`: backbones by name (built in, registered, plugins, ``module:factory``);
- :mod:`.description`: a model file described by a small TOML file (tensors, input, classes);
- :mod:`.runtime`, :mod:`.tflite`, :mod:`.onnxrt`: any described TFLite (LiteRT) or ONNX (onnxruntime) model;
- :mod:`.graph`: a model file's tensors, and which ones look like features and class scores;
- :mod:`.presets`: named descriptor classes (street, indoor);
- :mod:`.mosaic`: MOSAIC, ADE20K, quantised TFLite (the default);
- :mod:`.espnet`: ESPNetv2, Cityscapes, PyTorch; :mod:`.espnet_onnx`: its ONNX export.
"""

from .base import Backbone, BackboneInfo, Quantisation, SemanticFrame
from .description import ModelDescription, read_description
from .presets import PRESETS, preset_classes
from .registry import backbone_names, default_model_paths, load_backbone, register_backbone, resolve_model_path

__all__ = [
    "PRESETS", "Backbone", "BackboneInfo", "ModelDescription", "Quantisation", "SemanticFrame", "backbone_names",
    "default_model_paths", "load_backbone", "preset_classes", "read_description", "register_backbone",
    "resolve_model_path",
]
