"""Colours of the view.

Two families. The semantic classes colour the correspondence lines and the label
maps, which lie over photographs, many of them at night: every class gets a
bright, saturated colour; the descriptor classes (road, building, vegetation) get
the three most distinct ones. Everything else (captions, outlines, plots, the
map) lies on the viewer's own background, white in the light theme and near black
in the dark one, and takes a colour of middling luminance that reads on both.
"""

from __future__ import annotations

import colorsys
from collections.abc import Sequence

Rgb = tuple[int, int, int]
Rgba = tuple[int, int, int, int]

KNOWN: dict[str, Rgb] = {
    "road": (255, 40, 200),
    "building": (255, 150, 0),
    "vegetation": (40, 230, 60),
    "sky": (80, 170, 255),
    "sidewalk": (240, 230, 60),
    "car": (0, 230, 230),
    "person": (255, 60, 60),
    "other": (170, 170, 170),
    "wall": (200, 120, 255),
    "tree": (40, 230, 60),
    "grass": (150, 255, 120),
    "plant": (100, 200, 80),
    "house": (255, 190, 90),
}
UNKNOWN_CLASS: Rgb = (170, 170, 170)
LINE_ALPHA = 190
"""Opacity of the correspondence lines (of 255): the photographs stay readable beneath 50-80 of them."""


def _fallback(index: int) -> Rgb:
    """A well spread, bright hue for classes without a fixed colour (golden-ratio hue steps)."""
    hue = (0.13 + index * 0.618034) % 1.0
    r, g, b = colorsys.hsv_to_rgb(hue, 0.75, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


def class_colours(names: Sequence[str]) -> list[Rgb]:
    """One colour per label id, in label order."""
    return [KNOWN.get(name, _fallback(i)) for i, name in enumerate(names)]


def annotation_entries(names: Sequence[str]) -> list[tuple[int, str, Rgb]]:
    """(class id, name, colour) per label: the content of a Rerun annotation context."""
    return [(i, name, colour) for i, (name, colour) in enumerate(zip(names, class_colours(names)))]


def line_colours(class_ids: Sequence[int], names: Sequence[str]) -> list[Rgba]:
    """The translucent colour of each correspondence line, from its class."""
    table = class_colours(names)
    return [(*(table[i] if 0 <= i < len(table) else UNKNOWN_CLASS), LINE_ALPHA) for i in class_ids]


# On the viewer's background: a relative luminance of about 0.15-0.3 keeps a contrast of
# about 3:1 or more against both themes (a label's text takes its point's colour).
CAPTION: Rgb = (40, 130, 220)
MIRRORED: Rgb = (225, 110, 0)
OUTLINE: Rgb = (128, 128, 128)
CONFIDENCE: Rgb = (40, 130, 220)
SEQUENCE_COST: Rgb = (225, 110, 0)
SPEED: Rgb = (150, 90, 215)
MATCH_INDEX: Rgb = (30, 160, 70)
SINGLE_MATCH_INDEX: Rgb = (128, 128, 128)
ROUTE: Rgb = (128, 128, 128)
CANDIDATE: Rgb = (215, 150, 0)
ANSWER: Rgb = (30, 160, 70)
LOCALIZED: Rgb = (30, 160, 70)
NOT_LOCALIZED: Rgb = (215, 50, 50)
TRUTH: Rgb = (40, 130, 220)
TRAJECTORY: Rgb = (230, 40, 170)
