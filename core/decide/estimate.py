"""What the localizer answers for each frame: an :class:`Estimate`.

Everything in an Estimate is derived from the frames seen so far and the map;
nothing depends on ground truth. ``evidence`` holds the heavy arrays needed to
draw the match (label maps, keypoint correspondences, the sequence window);
everything else is small and is what the result messages carry.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Literal

import numpy as np

from ..frame import Heading
from ..layout.grid import LayoutGrid
from ..match.verify import Correspondences

State = Literal["localized", "not_localized"]
STATES: tuple[str, ...] = ("localized", "not_localized")


@dataclass
class Candidate:
    """One of the top-k reference frames of the single-frame search."""

    index: int
    """Reference frame index (0-based, map order)."""
    distance: float
    """Descriptor distance: LoST cosine distance, or thumbnail mean absolute difference."""
    score: float
    """Single-frame score, lower is better: the verification score for LoST-X (Eq. 4 family),
    the descriptor distance where nothing is verified. ``inf`` where verification found no correspondence."""
    correspondences: int = 0
    """Keypoint correspondences that survived verification (0 for thumbnails)."""


class DeferredCorrespondences(Mapping[int, "Correspondences | None"]):
    """Correspondences by reference index, each computed when first asked for: only drawing a match needs them
    (a reference off the shortlist is verified for it), and a localizer that draws nothing never asks."""

    def __init__(self, compute: dict[int, Callable[[], Correspondences | None]]) -> None:
        self._compute = compute
        self._computed: dict[int, Correspondences | None] = {}

    def __getitem__(self, reference: int) -> Correspondences | None:
        if reference not in self._computed:
            self._computed[reference] = self._compute[reference]()
        return self._computed[reference]

    def __iter__(self) -> Iterator[int]:
        return iter(self._compute)

    def __len__(self) -> int:
        return len(self._compute)


@dataclass(frozen=True)
class LayoutView:
    """The query's layout grid and the answer's as they were compared, both in the query camera's view (the
    answer's turned 180 degrees where the query views the route the opposite way)."""

    query: LayoutGrid
    """The query's grid, turned and shifted as it best fits the answer's."""
    answer: LayoutGrid
    turn: float
    """Degrees the query's grid is turned (anticlockwise seen from above)."""
    shift: float
    """Metres it is shifted, positive to the camera's right."""


class DeferredLayout:
    """A :class:`LayoutView`, made when first asked for: only drawing needs it."""

    def __init__(self, make: Callable[[], LayoutView]) -> None:
        self._make = make
        self._view: LayoutView | None = None

    def get(self) -> LayoutView:
        if self._view is None:
            self._view = self._make()
        return self._view


@dataclass
class Evidence:
    """Heavy per-frame arrays for visualisation; never sent in result messages."""

    query_labels: np.ndarray | None = None
    """(h, w) uint8 grouped semantic labels of the query (not mirrored)."""
    correspondences: Mapping[int, Correspondences | None] = field(default_factory=dict)
    """Surviving keypoint correspondences with the answer and with the single-frame best,
    by reference index (a localizer's, :class:`DeferredCorrespondences`, computed when asked for)."""
    grid: tuple[int, int] | None = None
    """(h, w) feature grid the keypoint coordinates refer to."""
    sequence_window: np.ndarray | None = None
    """(L, k) per-frame candidate costs in the sequence window, oldest row first (inf = no candidate)."""
    sequence_candidates: np.ndarray | None = None
    """(L, k) the reference indices behind ``sequence_window``; -1 where empty."""
    layout: DeferredLayout | None = None
    """The query's layout grid and the answer's as they were compared, where the layout took part."""


@dataclass
class Estimate:
    """The localizer's answer for one frame."""

    frame_id: int
    timestamp: float | None
    state: State
    """``localized``: the answer is trusted; ``not_localized``: the evidence does not agree
    (warming up, off the map, or after a jump until the filter has re-acquired)."""
    match_index: int
    """Reference index of the answer (the best guess, also when not localized)."""
    match_name: str
    position: tuple[float, float] | None
    """Map position of ``match_index`` where the map has positions."""
    confidence: float
    """In [0, 1]: 1 - the probability that a wrong answer leads its runner-up by as much, from the tail of the
    leads of the wrong answers the map produces against itself (a conservative estimate of the probability
    that the answer is at the right place). Thresholding it trades precision against recall; see
    :mod:`lostx.core.decide.calibration`."""
    score: float
    """The method's own score of the answer, lower is better (sequence cost, or the
    single-frame score without the sequence filter)."""
    single_match_index: int
    """The single-frame answer (best verified candidate)."""
    candidates: list[Candidate]
    """Top-k of the single-frame search, best single-frame score first."""
    sequence_score: float | None = None
    """The best trajectory's sequence score over the window (its mean cost, or entering the map within the window,
    :func:`lostx.core.route.sequence.window_scores`; None without the sequence filter)."""
    speed: float | None = None
    """Estimated speed in reference frames per query frame (None before it is known)."""
    window: int = 0
    """Frames in the sequence window; below the configured length while warming up."""
    warming_up: bool = False
    margin: float | None = None
    """What the confidence is calibrated from: the sequence answer's lead over the best trajectory
    elsewhere (standard deviations of the frame costs; inf with no rival), or the single-frame
    uniqueness."""
    heading: Heading = "same"
    """The query views the route the same way as the map, or the opposite way (its x mirrored in
    verification, its route index running against the map's when it drives the other way)."""
    heading_confidence: float = 1.0
    """Probability, in [0.5, 1], that ``heading`` is right."""
    cue_weights: dict[str, float] = field(default_factory=dict)
    """The weight each single-frame cue had in the answer (``lostx``, ``layout``, ``appearance``; unit length), what it
    earned on this stream by agreeing with the motion; a cue missing took no part (the layout off, a map without
    appearance descriptors) or has not earned any. Empty where the method has one score."""
    disagrees: bool = False
    """The motion and the matches disagree: too few of the recent frames' own answers kept to the sequence filter's
    line (a bend the line cuts, a map that does not hold the road, a misled cue; or single frames that are noise the
    line rightly ignores: on the two nuScenes scenes answering the frame's own match instead changed no figure by more
    than a query, and on Nordland it lost 10 of 100)."""
    latency_ms: dict[str, float] = field(default_factory=dict)
    """Milliseconds per stage: network, descriptor, search, verify; with the sequence filter also
    costs (the frame's normalised cost for every reference: O(map size), like the search),
    sequence (the trajectory update: independent of the map size) and tracker; and total."""
    evidence: Evidence | None = None

    @property
    def opposite(self) -> bool:
        """The query views the route the opposite way to the map."""
        return self.heading == "opposite"

    def summary(self) -> dict[str, Any]:
        """Every field except the evidence, as plain Python types (JSON- and msgpack-ready)."""
        return {
            "frame_id": int(self.frame_id),
            "timestamp": None if self.timestamp is None else float(self.timestamp),
            "state": self.state,
            "match_index": int(self.match_index),
            "match_name": self.match_name,
            "position": None if self.position is None else [float(v) for v in self.position],
            "confidence": float(self.confidence),
            "score": _num(self.score),
            "single_match_index": int(self.single_match_index),
            "candidates": [
                {"index": int(c.index), "distance": _num(c.distance), "score": _num(c.score),
                 "correspondences": int(c.correspondences)}
                for c in self.candidates
            ],
            "sequence_score": None if self.sequence_score is None else _num(self.sequence_score),
            "speed": None if self.speed is None else float(self.speed),
            "window": int(self.window),
            "warming_up": bool(self.warming_up),
            "margin": None if self.margin is None else _num(self.margin),
            "heading": self.heading,
            "heading_confidence": float(self.heading_confidence),
            "cue_weights": {k: float(v) for k, v in self.cue_weights.items()},
            "disagrees": bool(self.disagrees),
            "latency_ms": {k: float(v) for k, v in self.latency_ms.items()},
        }


def _num(value: float) -> float | None:
    """A finite float, or None for inf/nan (which JSON cannot carry)."""
    value = float(value)
    return value if np.isfinite(value) else None
