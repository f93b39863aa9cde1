"""What a map is on disk, shared by the reader and the writer: its format name, version, kinds and
how it records the backbone that built it."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any, Literal

from ..backbones import BackboneInfo

MAP_FORMAT = "lostx-map"
MAP_VERSION = 2
"""The newest format. 1: keypoint descriptors kept whole; 2: also maps whose keypoint descriptors are reduced
(a projection and each slot's coordinates on it). A map is written as the oldest version that holds it, so a
map with whole descriptors still opens in a lostx that reads only version 1."""
READABLE_VERSIONS = (1, 2)
WHOLE_VERSION = 1
"""The version of a map whose keypoint descriptors are kept whole."""
MapKind = Literal["lost", "thumbnail"]


BACKBONE_IDENTITY = {
    "name": "name", "model_md5": "model", "feature_tensor": "feature tensor", "feature_dim": "feature size",
    "grid": "grid",
}
"""What a map records of its backbone that a query backbone must match, and how errors call each."""


def backbone_identity(backbone: dict[str, Any]) -> str:
    h, w = backbone.get("grid", ("?", "?"))
    tensor = f" {backbone['feature_tensor']!r}" if backbone.get("feature_tensor") else ""
    return (f"{backbone.get('name')} (model {backbone.get('model_file')} md5 {backbone.get('model_md5')}, "
            f"features{tensor} {backbone.get('feature_dim')} x {h}x{w})")


def backbone_dict(info: BackboneInfo | None) -> dict[str, Any] | None:
    """A backbone's info as the manifest records it."""
    if info is None:
        return None
    data = asdict(info)
    data["grid"] = list(info.grid)
    data["class_names"] = list(info.class_names)
    data["default_classes"] = {k: list(v) for k, v in info.default_classes.items()}
    return data
