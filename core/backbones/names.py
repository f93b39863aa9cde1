"""How a model's class names are read: each training set's published list spells a class its own way."""

from __future__ import annotations

import re


def class_terms(name: str) -> tuple[str, ...]:
    """What a model's class is called, to be looked up in this order: lowercased, with "_" and "-" read as
    spaces. Of a list of synonyms (ADE20K's published names: "road;route", "car;auto;automobile;machine;motorcar")
    only the first, the class's own: later ones can be broader ("streetlight;street;lamp"). Of a path (Mapillary
    Vistas': "construction--flat--road") every step, the last first ("marking--discrete--arrow--left": a marking)."""
    own = re.split(r"[;,|]", str(name).strip().lower())[0]
    steps = [" ".join(step.replace("_", " ").replace("-", " ").split()) for step in own.split("--")]
    return tuple(step for step in reversed(steps) if step) or ("",)
