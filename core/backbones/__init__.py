"""Semantic segmentation backbones: the interface, the registry, the generic runtimes and the built-in networks.

- :mod:`.base`: what a backbone is (:class:`Backbone`) and what it returns (:class:`SemanticFrame`);
- :mod:`.registry`: backbones by name (built in, registered, plugins, ``module:factory``);
- :mod:`.description`: a model file described by a small TOML file (tensors, input, classes);
- :mod:`.runtime`, :mod:`.tflite`, :mod:`.onnxrt`: any described TFLite (LiteRT) or ONNX (onnxruntime) model;
- :mod:`.graph`: a model file's tensors, and which ones look like features and class scores;
- :mod:`.presets`: named descriptor classes (street, indoor);
- :mod:`.mosaic`: MOSAIC, ADE20K, quantised TFLite (the default);
- :mod:`.espnet`: ESPNetv2, Cityscapes, PyTorch; :mod:`.espnet_onnx`: its ONNX export.

Names are imported on first use, so importing a submodule (``.presets`` for the command line's choices)
does not load numpy or a runtime.
"""

from ..lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(("Backbone", "BackboneInfo", "Quantisation", "SemanticFrame"), ".base"),
    **dict.fromkeys(("ModelDescription", "read_description"), ".description"),
    **dict.fromkeys(("PRESETS", "preset_classes"), ".presets"),
    **dict.fromkeys(("backbone_names", "default_model_paths", "load_backbone", "register_backbone",
                     "resolve_model_path"), ".registry"),
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
