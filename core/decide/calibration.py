"""Confidence calibrated on the map itself: how far ahead wrong answers get, measured without any query.

A threshold on a raw margin does not transfer between data sets: its scale depends on the scene,
the descriptor and the sequence settings. What does transfer is how likely a wrong answer is to lead by as
much. Every map frame is matched against its own map with the frames within ``sequence.exclusion`` of it
removed (:meth:`PlaceMatcher.match_reference`, run by :func:`lostx.core.localizer.calibrate`), in route
order through the same sequence filter, so that every place it is compared with is wrong.

Sequence mode, where ``localized`` is decided: of each such frame the ``PLACES`` best places are kept (the
best trajectories ending at distinct places, away from the frame's own), and their normalised spacings
(:func:`lostx.core.decide.tail.leads`) are ``PLACES - 1`` draws of the lead a wrong answer has over its
runner-up, the margin a live answer is judged by. Single frame: one draw per frame, its answer's margin
(the uniqueness, or with the layout the combined score's lead).

An answer's confidence is 1 - P(a wrong answer leads by at least its margin), that probability from the
generalised Pareto law fitted to the draws (:func:`lostx.core.decide.tail.fit_tail`), on the safe side of
the fit's uncertainty and never above what the number of draws supports (:attr:`Tail.ceiling`);
``localized`` means confidence >= ``decision.min_confidence``. A map whose draws cannot support that
confidence is too short to be sure (:meth:`Calibration.too_short`).

The map's own frames are matched as they are stored: no network runs, and the result is saved
beside the map (``calibration.json``) for the settings it was measured with.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config
from .tail import Tail, fit_tail

CALIBRATION_FILE = "calibration.json"


MODEL = "sequence: leads of the best 5 places; single: margins; generalised Pareto tails"
"""What is stored and how it is read: part of the settings key, so that a calibration stored by another model
is measured again rather than misread."""

PLACES = 5
"""Best places kept of each frame matched against the map in sequence mode: PLACES - 1 draws of a wrong answer's
lead."""


@dataclass(frozen=True)
class Calibration:
    """Draws of wrong answers' leads on one map, for one set of settings, and their fitted tails."""

    sequence: np.ndarray
    """Leads of wrong sequence answers: normalised spacings of the best trajectories' scores at distinct places."""
    single: np.ndarray
    """Margins of wrong single-frame answers, one per frame."""
    settings: dict[str, Any]
    """The settings the draws depend on (:func:`settings_key`)."""
    frames: int = 0
    """Map frames matched against the map to measure them."""

    @cached_property
    def sequence_tail(self) -> Tail:
        return fit_tail(self.sequence)

    @cached_property
    def single_tail(self) -> Tail:
        return fit_tail(self.single)

    def sequence_confidence(self, margin: float) -> float:
        return self.sequence_tail.confidence(margin)

    def single_confidence(self, margin: float) -> float:
        return self.single_tail.confidence(margin)

    def too_short(self, sequence: bool, min_confidence: float) -> str | None:
        """Why no answer can reach ``min_confidence`` on this map, or None when one can."""
        tail = self.sequence_tail if sequence else self.single_tail
        if tail.ceiling >= min_confidence:
            return None
        return (f"the map is too short to be sure: matched against itself, its {self.frames} frames gave "
                f"{tail.draws} samples of how far wrong answers lead, and a confidence of {min_confidence:g} needs "
                f"{tail.draws_for(min_confidence)}")

    def to_dict(self) -> dict[str, Any]:
        return {"settings": self.settings, "frames": self.frames, "sequence": self.sequence.tolist(),
                "single": self.single.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Calibration":
        return cls(np.asarray(data["sequence"], dtype=np.float64), np.asarray(data["single"], dtype=np.float64),
                   dict(data["settings"]), int(data["frames"]))


def settings_key(config: Config) -> dict[str, Any]:
    """What the draws depend on: how they are made and read (:data:`MODEL`), the sequence, verification and layout
    settings (not the tracker's)."""
    sequence = dataclasses.asdict(config.sequence)
    sequence.pop("enabled")
    verify = dataclasses.asdict(config.verify)
    layout = dataclasses.asdict(config.layout)
    return json.loads(json.dumps({"model": MODEL, "sequence": sequence, "verify": verify, "layout": layout}))


KEPT = 8
"""Calibrations kept beside a map (one per set of settings, the most recent first)."""


def load(path: Path, config: Config) -> Calibration | None:
    """The calibration stored beside the map at ``path`` for these settings (:func:`settings_key`), or None."""
    settings = settings_key(config)
    for entry in _stored(path):
        if entry.get("settings") == settings:
            try:
                return Calibration.from_dict(entry)
            except (KeyError, TypeError, ValueError):
                return None  # a damaged calibration is measured again
    return None


def store(path: Path, calibration: Calibration) -> None:
    """Keep ``calibration`` beside the map at ``path`` (``calibration.json``, written atomically; the map itself
    is not touched), with up to ``KEPT`` calibrations for other settings. A map on a read-only disk simply goes
    without: the calibration is measured again next time."""
    others = [e for e in _stored(path) if e.get("settings") != calibration.settings]
    file = Path(path) / CALIBRATION_FILE
    tmp = file.with_name(f".{file.name}.{os.getpid()}")
    try:
        tmp.write_text(json.dumps([calibration.to_dict(), *others][:KEPT]))
        os.replace(tmp, file)
    except OSError:
        tmp.unlink(missing_ok=True)


def _stored(path: Path) -> list[dict[str, Any]]:
    file = Path(path) / CALIBRATION_FILE
    try:
        entries = json.loads(file.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        return []
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


UNCALIBRATED = Calibration(np.zeros(0), np.zeros(0), {})
"""For the runs that measure a calibration: confidence is not needed there, only the scores."""
