"""What the layout needs to know of a segmentation model's classes: which are the road, other ground and
the sky, and what kind of thing each other class is where it stands on the ground.

Roles are found by the models' own class names (ADE20K's, Cityscapes' and Mapillary Vistas' vocabularies, and
the usual synonyms, however a model spells them: :func:`lostx.core.backbones.names.class_terms`), so any model
whose classes are named works; a model without a road class has no layout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backbones.names import class_terms

ROAD, GROUND, OBJECT = 0, 1, 2
"""What a ray that meets the road plane landed on (the rays of sky pixels do not count)."""
CONTACTS = ("building", "vegetation", "vehicle", "other")
"""The kinds of thing that stand on the ground, in the order of their grid channels."""
CHANNELS = ("road", "ground", *CONTACTS)
"""The grid's channels: the share of road and of other ground among the rays landing in a cell, then the
metres of each kind of thing touching the ground there (log(1 + metres))."""

_NAMES = {
    # Paint on the road is road: a marking's ray lands on the road plane, and it stands on nothing.
    "road": ("road", "street", "highway", "driveway", "lane", "crosswalk", "crosswalk plain", "crosswalk zebra",
             "marking", "marking only", "lane marking", "road marking", "bike lane", "service lane"),
    "ground": ("sidewalk", "earth", "grass", "field", "floor", "rug", "terrain", "parking", "sand", "dirt",
               "path", "runway", "gravel", "pavement", "ground", "curb", "curb cut", "land", "soil",
               "pedestrian area"),
    "sky": ("sky",),
    "building": ("building", "wall", "house", "fence", "door", "windowpane", "window", "ceiling", "cabinet",
                 "painting", "shelf", "mirror", "skyscraper", "bridge", "tower"),
    "vegetation": ("tree", "plant", "vegetation", "mountain", "palm", "flora", "hedge", "bush"),
    "vehicle": ("car", "truck", "bus", "train", "motorcycle", "bicycle", "van", "vehicle", "minibike", "boat"),
}
_MOVERS = ("person", "rider", "pedestrian", "animal") + _NAMES["vehicle"]
"""Classes of things that may move between two frames (visual odometry leaves them out)."""


@dataclass(frozen=True)
class LayoutClasses:
    """Lookup tables over a model's class ids (up to 256 classes)."""

    ray: np.ndarray
    """(256,) int8: ROAD, GROUND or OBJECT for a pixel's class; -1 for the sky."""
    contact: np.ndarray
    """(256,) int8: index into :data:`CONTACTS` of what a non-ground class is where it meets the ground."""
    is_ground: np.ndarray
    """(256,) bool: road or other ground."""
    is_sky: np.ndarray
    """(256,) bool."""
    is_mover: np.ndarray
    """(256,) bool: things that may move (vehicles, people)."""

    @classmethod
    def of_model(cls, class_names: tuple[str, ...] | list[str]) -> "LayoutClasses | None":
        """The roles of a model's classes, or None when it has no road class (no layout can be drawn)."""
        if len(class_names) > 256:
            return None
        role_of = {}
        for role, names in _NAMES.items():
            for name in names:
                role_of.setdefault(name, role)
        terms = [class_terms(name) for name in class_names]
        roles = [next((role_of[term] for term in called if term in role_of), "other") for called in terms]
        if "road" not in roles:
            return None
        ray = np.full(256, OBJECT, dtype=np.int8)
        contact = np.full(256, CONTACTS.index("other"), dtype=np.int8)
        for i, role in enumerate(roles):
            if role == "road":
                ray[i] = ROAD
            elif role == "ground":
                ray[i] = GROUND
            elif role == "sky":
                ray[i] = -1
            if role in CONTACTS:
                contact[i] = CONTACTS.index(role)
        movers = np.zeros(256, dtype=bool)
        movers[[i for i, called in enumerate(terms) if any(term in _MOVERS for term in called)]] = True
        return cls(ray=ray, contact=contact, is_ground=(ray == ROAD) | (ray == GROUND), is_sky=ray == -1,
                   is_mover=movers)
