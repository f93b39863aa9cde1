"""Confidence calibrated on the map itself: how sure wrong answers look, measured without any query.

A threshold on a raw margin does not transfer between data sets: its scale depends on the scene,
the descriptor and the sequence settings. What does transfer is a rank among wrong answers. Every
map frame is matched against its own map with the frames within ``sequence.exclusion`` of it
removed (:meth:`PlaceMatcher.match_reference`), in route order through the same sequence filter,
so that each answer is necessarily wrong: an *impostor*. Their margins (sequence mode: the best
trajectory's lead over the best trajectory elsewhere; single frame: the uniqueness of the best
candidate) make the empirical distribution F of wrong answers on this map, with these settings.

An answer's confidence is F(its margin): the share of wrong answers this map produces that would
have looked less sure. It is an estimate, on the conservative side, of the probability that the
answer is right: queries from another traverse (another season, the opposite view) are further
from the map than its own frames, which pushes their wrong answers' margins down, not up
(docs/metrics.md shows the measured reliability). ``localized`` means confidence >=
``decision.min_confidence``.

The map's own frames are matched as they are stored: no network runs, and the result is saved
beside the map (``calibration.json``) for the settings it was measured with.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from .config import Config, HeadingConfig, TrackerConfig
from .frame import Frame

if TYPE_CHECKING:
    from .backbones import Backbone
    from .refmap import ReferenceMap

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
    """Share of the impostors below ``value`` (ties count half); 1 above them all, inf included."""
    n = len(sorted_margins)
    if n == 0:
        return 1.0 if value > 0 else 0.0
    below = np.searchsorted(sorted_margins, value, side="left")
    ties = np.searchsorted(sorted_margins, value, side="right") - below
    return float((below + 0.5 * ties) / n)


def settings_key(config: Config) -> dict[str, Any]:
    """What impostor margins depend on: the sequence, verification and tracker-free settings."""
    sequence = dataclasses.asdict(config.sequence)
    sequence.pop("enabled")
    verify = dataclasses.asdict(config.verify)
    return json.loads(json.dumps({"sequence": sequence, "verify": verify}))


def calibrate(refmap: "ReferenceMap", config: Config, backbone: "Backbone | None" = None,
              progress: Callable[[int], None] | None = None) -> Calibration:
    """Match up to ``decision.calibration_frames`` map frames against the map, neighbourhood excluded.

    Longer maps are sampled in stretches spread over the route (each stretch long enough to fill the
    sequence window several times), so that the sequence filter sees a traverse as it would live.
    """
    from .localizer import Localizer  # the localizer uses calibrations

    seq = config.sequence
    # The map views the route the way it was built; the raw margins are wanted, not the tracker's gate.
    quiet = dataclasses.replace(config, heading=HeadingConfig(declared_prior=1.0),
                                tracker=TrackerConfig(enabled=False),
                                sequence=dataclasses.replace(seq, enabled=True))
    sequence_margins: list[float] = []
    single: list[float] = []
    for stretch in _stretches(refmap.n_frames, config.decision.calibration_frames, 4 * seq.length):
        localizer = Localizer(refmap, quiet, backbone, calibration=UNCALIBRATED)
        for index in stretch:
            matches = localizer.matcher.match_reference(int(index), seq.exclusion)
            if matches is None:
                continue
            frame = Frame(id=int(index), image=_NO_PIXELS, camera=refmap.camera)  # type: ignore[arg-type]
            estimate = localizer.update(frame, matches)
            single.append(matches.same.confidence)
            if not estimate.warming_up and estimate.margin is not None and np.isfinite(estimate.margin):
                sequence_margins.append(estimate.margin)
            if progress is not None:
                progress(1)
    return Calibration(np.sort(np.asarray(sequence_margins)), np.sort(np.asarray(single)), settings_key(config))


def _stretches(n_frames: int, budget: int, length: int) -> list[np.ndarray]:
    if n_frames <= budget:
        return [np.arange(n_frames)]
    length = min(length, budget)
    count = max(1, budget // length)
    starts = np.linspace(0, n_frames - length, count).astype(np.int64)
    return [np.arange(start, start + length) for start in starts]


def load(path: Path) -> Calibration | None:
    """The calibration stored beside a map, or None."""
    file = Path(path) / CALIBRATION_FILE
    if not file.is_file():
        return None
    try:
        return Calibration.from_dict(json.loads(file.read_text()))
    except (json.JSONDecodeError, KeyError, TypeError, ValueError):
        return None  # a damaged calibration is measured again


def store(path: Path, calibration: Calibration) -> None:
    """Write ``calibration.json`` beside the map atomically (the map itself is not touched)."""
    file = Path(path) / CALIBRATION_FILE
    tmp = file.with_name(f".{file.name}.{os.getpid()}")
    tmp.write_text(json.dumps(calibration.to_dict()))
    os.replace(tmp, file)


UNCALIBRATED = Calibration(np.zeros(0), np.zeros(0), {})
"""For the runs that measure a calibration: confidence is not needed there, only the margins."""

_NO_PIXELS = np.zeros((1, 1, 3), np.uint8)
