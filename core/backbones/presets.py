"""Named sets of descriptor classes for the common scenes, resolved against a model's own class names.

A preset lists, for each descriptor class, the class names different training
sets use for it (ADE20K says tree, plant and grass where Cityscapes says
vegetation); a model's groups keep the names it has, however it spells them
(``class_terms``: "road;route", "construction--flat--road").
"""

from __future__ import annotations

from collections.abc import Sequence

from ..errors import InputError
from .names import class_terms

PRESETS: dict[str, dict[str, tuple[str, ...]]] = {
    # Each of the paper's three classes takes in the classes that stand for the same thing in a street:
    # the ground beside the road, walls beside buildings, fields beside trees (measured: more of the frame
    # described, better opposite-view matches, RobotCar day/night unchanged; docs/opposite-view.md).
    "street": {
        "road": ("road", "sidewalk", "earth"),
        "building": ("building", "house", "wall"),
        "vegetation": ("vegetation", "tree", "plant", "grass", "field", "terrain"),
    },
    "indoor": {
        "wall": ("wall",),
        "floor": ("floor",),
        "ceiling": ("ceiling",),
    },
}


def preset_classes(preset: str, class_names: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """The preset's descriptor classes as groups of the model's classes; an error names a group the model lacks."""
    if preset not in PRESETS:
        raise InputError(f"unknown class preset '{preset}'; presets: {', '.join(PRESETS)}")
    # A model's class stands for a preset's name when it is what the class is called (``class_terms``' first).
    called = [(class_terms(name)[0], name) for name in class_names]
    groups = {group: tuple(own for name in names for term, own in called if term == name)
              for group, names in PRESETS[preset].items()}
    missing = [group for group, members in groups.items() if not members]
    if missing:
        wanted = "; ".join(f"{group}: {' or '.join(PRESETS[preset][group])}" for group in missing)
        raise InputError(
            f"class preset '{preset}' does not fit this model: it has no class for {wanted}; "
            f"set [lost] classes to groups of its classes ({', '.join(class_names)})"
        )
    return groups
