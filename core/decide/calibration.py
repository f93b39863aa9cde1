"""Confidence calibrated on the map itself: how sure wrong answers look, measured without any query.

A threshold on a raw margin does not transfer between data sets: its scale depends on the scene,
the descriptor and the sequence settings. What does transfer is a rank among wrong answers. Every
map frame is matched against its own map with the frames within ``sequence.exclusion`` of it
removed (:meth:`PlaceMatcher.match_reference`, run by
:func:`lostx.core.localizer.calibrate`), in route order through the same sequence filter,
so that each answer is necessarily wrong: an *impostor*. Their margins (sequence mode: the best
trajectory's lead over the best trajectory elsewhere; single frame: the uniqueness of the best
candidate) make the empirical distribution F of wrong answers on this map, with these settings.

An answer's confidence is 1 - p, p = (k + 1) / (n + 1) for the k of the n impostors whose margin
is at least its own: the conservative share of the wrong answers this map produces that look as
sure. It estimates, on the safe side, the probability that the answer is right (docs/metrics.md
shows the measured reliability); ``localized`` means confidence >= ``decision.min_confidence``.
A map too short to produce 999 impostors can therefore never reach the default 0.999: what wrong
answers look like on it is not known well enough to trust an answer.

The map's own frames are matched as they are stored: no network runs, and the result is saved
beside the map (``calibration.json``) for the settings it was measured with.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config

CALIBRATION_FILE = "calibration.json"


@dataclass(frozen=True)
class Calibration:
    """Sorted impostor margins of one map, for one set of settings."""

    sequence: np.ndarray
    """Margins of wrong sequence answers (finite ones; an answer with no rival elsewhere has none)."""
    single: np.ndarray
    """Uniqueness of wrong single-frame answers."""
    settings: dict[str, Any]
    """The settings the margins depend on (:func:`settings_key`)."""

    def sequence_confidence(self, margin: float) -> float:
        return _rank(self.sequence, margin)

    def single_confidence(self, uniqueness: float) -> float:
        return _rank(self.single, uniqueness)

    def to_dict(self) -> dict[str, Any]:
        return {"settings": self.settings, "sequence": self.sequence.tolist(), "single": self.single.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Calibration":
        return cls(np.sort(np.asarray(data["sequence"], dtype=np.float64)),
                   np.sort(np.asarray(data["single"], dtype=np.float64)), dict(data["settings"]))


def _rank(sorted_margins: np.ndarray, value: float) -> float:
    """1 - p, p = (k + 1) / (n + 1) the conservative share of the n impostors that look at least as sure
    (k of them): a value above all n scores n / (n + 1), so 0.999 needs at least 999 impostors."""
    below = int(np.searchsorted(sorted_margins, value, side="left"))
    return below / (len(sorted_margins) + 1)


def settings_key(config: Config) -> dict[str, Any]:
    """What impostor margins depend on: the sequence, verification and layout settings (not the tracker's)."""
    sequence = dataclasses.asdict(config.sequence)
    sequence.pop("enabled")
    verify = dataclasses.asdict(config.verify)
    layout = dataclasses.asdict(config.layout)
    return json.loads(json.dumps({"sequence": sequence, "verify": verify, "layout": layout}))


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
"""For the runs that measure a calibration: confidence is not needed there, only the margins."""
