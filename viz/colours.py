"""Colours of the semantic classes, shared by the label maps and the correspondence lines.

The lines are drawn over photographs, many of them at night, so every class
gets a bright, saturated colour; the descriptor classes (road, building,
vegetation) get the three most distinct ones.
"""

from __future__ import annotations

import colorsys

Rgb = tuple[int, int, int]

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


def _fallback(index: int) -> Rgb:
    """A well spread, bright hue for classes without a fixed colour (golden-ratio hue steps)."""
    hue = (0.13 + index * 0.618034) % 1.0
    r, g, b = colorsys.hsv_to_rgb(hue, 0.75, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


def class_colours(names: list[str] | tuple[str, ...]) -> list[Rgb]:
    """One colour per label id, in label order."""
    return [KNOWN.get(name, _fallback(i)) for i, name in enumerate(names)]


def annotation_entries(names: list[str] | tuple[str, ...]) -> list[tuple[int, str, Rgb]]:
    """(class id, name, colour) per label: the content of a Rerun annotation context."""
    return [(i, name, colour) for i, (name, colour) in enumerate(zip(names, class_colours(names)))]


QUERY_OUTLINE: Rgb = (235, 235, 235)
MIRRORED_OUTLINE: Rgb = (255, 170, 0)
REFERENCE_OUTLINE: Rgb = (235, 235, 235)
CONFIDENCE: Rgb = (80, 200, 255)
SEQUENCE_SCORE: Rgb = (255, 170, 0)
SPEED: Rgb = (200, 120, 255)
MATCH_INDEX: Rgb = (40, 230, 60)
SINGLE_MATCH_INDEX: Rgb = (230, 230, 230)
CORRESPONDENCES: Rgb = (255, 40, 200)
ROUTE: Rgb = (150, 150, 150)
CANDIDATE: Rgb = (255, 220, 80)
LOCALIZED: Rgb = (40, 230, 60)
NOT_LOCALIZED: Rgb = (255, 60, 60)
TRUTH: Rgb = (80, 170, 255)
TRAJECTORY: Rgb = (255, 40, 200)
