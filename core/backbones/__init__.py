"""Semantic segmentation backbones: the interface, the registry and the built-in networks.

- :mod:`.base`: what a backbone is (:class:`Backbone`) and what it returns (:class:`SemanticFrame`);
- :mod:`.registry`: backbones by name (built-in and registered);
- :mod:`.mosaic`: MOSAIC, ADE20K, quantised TFLite (the default);
- :mod:`.espnet`: ESPNetv2, Cityscapes, PyTorch.
"""

from .base import Backbone, BackboneInfo, Quantisation, SemanticFrame
from .registry import backbone_names, default_model_paths, load_backbone, register_backbone, resolve_model_path

__all__ = [
    "Backbone", "BackboneInfo", "Quantisation", "SemanticFrame", "backbone_names", "default_model_paths",
    "load_backbone", "register_backbone", "resolve_model_path",
]
