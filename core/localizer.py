"""The online localizer: one frame in, one place estimate out.

``Localizer(map, config).step(frame) -> Estimate`` runs, per frame:

1. the single-frame match (:class:`PlaceMatcher`: describe, search, verify);
2. the sequence filter (:class:`SequenceFilter`) over the last L frames, fed
   with the frame's candidates and its contrast-normalised cost for every
   reference; its best trajectory gives the position and speed;
3. the route tracker (:class:`RouteTracker`, a Kalman filter), which gates
   implausible jumps, narrows the speeds searched next, and restarts after a
   genuine jump.

Confidence, in [0, 1], higher is surer:

- with the sequence filter: 1 - exp(-m), where m is the margin of the best
  trajectory's mean cost under the best trajectory ending more than
  ``sequence.exclusion`` reference frames away, in units of the frames'
  contrast-normalised costs (standard deviations); 0 when there is no margin;
- single-frame (``sequence.enabled = False``): the verified uniqueness
  1 - s_best / s_alt of :func:`lostx.core.matcher.uniqueness`;
- always 0 when the state is ``not_localized``.

State, with the sequence filter: ``localized`` when the window is full and the
answer is confident (confidence >= ``sequence.min_confidence``) and, with the
tracker, plausible (it agrees with the track's prediction); ``not_localized``
while warming up (fewer than L frames seen), when the evidence is weak, and
when the tracker finds the answer implausible (then the answer is the track's
prediction).

Bad input (a frame that is not an H x W x 3 uint8 image, non-finite network
output, a timestamp earlier than the previous frame's) raises a
:class:`LostxError` and leaves the localizer's state as it was, ready for the
next good frame.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .backbones import Backbone
from .config import Config
from .errors import InputError
from .estimate import Candidate, Estimate, Evidence
from .frame import Frame
from .images import check_frame
from .inputcheck import InputCheck
from .matcher import MatchResult, PlaceMatcher
from .refmap import ReferenceMap
from .search import top_k
from .sequence import ReferenceNormaliser, SequenceFilter, contrast_normalise
from .tracker import RouteTracker
from .verify import verify

WINDOW_PICTURE_WIDTH = 15


class Localizer:
    """Stateful place recognition over a stream of frames from one camera."""

    def __init__(self, refmap: ReferenceMap, config: Config | None = None, backbone: Backbone | None = None) -> None:
        self.map = refmap
        self.config = config or Config()
        self.input_check = InputCheck.for_map(refmap.manifest)
        matcher_config = self.config
        if self.input_check.compares_labels:
            # The input check compares the query's labels with the map's own and warns once naming both; the
            # class-coverage check (whose advice is for choosing a map's classes) would report the same frames again.
            matcher_config = dataclasses.replace(matcher_config,
                                                 lost=dataclasses.replace(matcher_config.lost, coverage_frames=0))
        self.matcher = PlaceMatcher(refmap, matcher_config, backbone)
        seq = self.config.sequence
        self.sequence = SequenceFilter(seq.length, seq.speeds, seq.radius, seq.penalty)
        self.hubs = ReferenceNormaliser(seq.reference_prior)
        self.tracker = RouteTracker(self.config.tracker)
        self._last_timestamp: float | None = None

    def reset(self) -> None:
        """Forget everything seen so far (start of a new traverse)."""
        self.matcher.reset()
        self.sequence.reset()
        self.hubs.reset()
        self.tracker.reset()
        self._last_timestamp = None

    def step(self, frame: Frame) -> Estimate:
        start = time.perf_counter()
        check_frame(frame.image, f"frame {frame.id}")
        if frame.timestamp is not None:
            if not np.isfinite(frame.timestamp):
                raise InputError(f"frame {frame.id}: timestamp {frame.timestamp} is not a finite number")
            if self._last_timestamp is not None and frame.timestamp < self._last_timestamp:
                raise InputError(
                    f"frame {frame.id}: timestamp {frame.timestamp} is earlier than the previous frame's "
                    f"{self._last_timestamp}; frames must arrive in time order (reset the localizer for a new traverse)"
                )
        opposite = self._declared_opposite(frame)
        result = self.matcher.match(frame.image, opposite=opposite)
        self.input_check(frame.id, frame.image, result.query_labels)
        if frame.timestamp is not None:
            self._last_timestamp = frame.timestamp
        estimate = self.update(frame, result)
        estimate.latency_ms["total"] = 1e3 * (time.perf_counter() - start)
        return estimate

    def update(self, frame: Frame, result: MatchResult) -> Estimate:
        """Advance the sequence filter and tracker with a single-frame result for ``frame``.

        :meth:`step` computes the result with its own matcher; evaluation feeds results of
        other single-frame methods (or cached ones) through the same sequence stages here.
        """
        opposite = self._declared_opposite(frame)
        latency = {k: 1e3 * v for k, v in result.timings.items()}
        if self.config.sequence.enabled:
            estimate = self._sequence_estimate(frame, result, opposite, latency)
        else:
            estimate = self._single_estimate(frame, result, opposite)
        estimate.latency_ms = latency
        return estimate

    def _declared_opposite(self, frame: Frame) -> bool:
        return frame.camera is not None and frame.camera != self.map.camera

    def _single_estimate(self, frame: Frame, result: MatchResult, opposite: bool) -> Estimate:
        index = result.best
        return self._estimate(frame, result, opposite, index, "localized", result.confidence, result.score)

    def _sequence_estimate(self, frame: Frame, result: MatchResult, opposite: bool, latency: dict) -> Estimate:
        cfg = self.config.sequence
        t0 = time.perf_counter()
        costs = self.hubs(contrast_normalise(result.map_scores, cfg.contrast_window))
        anchors = np.union1d(result.candidates, top_k(costs, cfg.anchors))
        t_costs = time.perf_counter()
        speeds = self._plausible_speeds()
        seq = self.sequence.update(anchors, costs, speeds)
        runner_up = self.sequence.runner_up(seq.position, cfg.exclusion)
        margin = max(0.0, runner_up - seq.score) if np.isfinite(runner_up) else np.inf
        confidence = float(1.0 - np.exp(-margin))
        t1 = time.perf_counter()
        warming = seq.frames < cfg.length
        confident = confidence >= cfg.min_confidence
        position, speed, trusted = seq.position, seq.speed, confident
        if not warming and self.config.tracker.enabled:
            track = self.tracker.step(seq.position, seq.speed, confident)
            trusted = confident and track.accepted
            if not track.accepted:
                position, speed = track.position, track.speed
        state = "localized" if trusted and not warming else "not_localized"
        t2 = time.perf_counter()
        latency["costs"] = 1e3 * (t_costs - t0)
        latency["sequence"] = 1e3 * (t1 - t_costs)
        latency["tracker"] = 1e3 * (t2 - t1)
        index = int(np.clip(np.rint(position), 0, self.map.n_frames - 1))
        estimate = self._estimate(frame, result, opposite, index, state,
                                  confidence if state == "localized" else 0.0, seq.score)
        estimate.sequence_score = seq.score
        estimate.speed = float(speed)
        estimate.window = seq.frames
        estimate.warming_up = warming
        if estimate.evidence is not None:
            window, refs = self.sequence.window(WINDOW_PICTURE_WIDTH)
            estimate.evidence.sequence_window = window
            estimate.evidence.sequence_candidates = refs
        return estimate

    def _plausible_speeds(self) -> np.ndarray:
        """Speeds of the trajectories the new frame spawns: the tracker's band, or the acquisition range."""
        cfg = self.config.sequence
        band = self.tracker.speed_range() if self.config.tracker.enabled else None
        if band is None:
            return np.asarray(cfg.acquire_speeds, dtype=np.float64)
        speeds = np.asarray(cfg.speeds, dtype=np.float64)
        inside = speeds[(speeds >= band[0]) & (speeds <= band[1])]
        return inside if len(inside) else speeds[[int(np.argmin(np.abs(speeds - sum(band) / 2)))]]

    def _estimate(self, frame: Frame, result: MatchResult, opposite: bool, index: int, state: str,
                  confidence: float, score: float) -> Estimate:
        return Estimate(
            frame_id=frame.id,
            timestamp=frame.timestamp,
            state=state,  # type: ignore[arg-type]
            match_index=index,
            match_name=self.map.names[index],
            position=self._position(index),
            confidence=float(confidence),
            score=float(score),
            single_match_index=result.best,
            candidates=_candidates(result),
            heading="opposite" if opposite else "same",
            evidence=self._evidence(result, index, opposite),
        )

    def _evidence(self, result: MatchResult, index: int, opposite: bool) -> Evidence:
        """What it takes to draw the answer (and the single-frame best): their correspondences."""
        correspondences = {}
        if result.verification is not None:
            for reference in dict.fromkeys((index, result.best)):
                corr = result.correspondences_for(reference)
                if corr is None and self.matcher.last_evidence is not None:
                    # The sequence answer was not among the verified candidates: verify it too, to draw it.
                    distance = float(result.distances[0]) if len(result.distances) else 1.0
                    extra = verify(self.matcher.last_evidence, self.map.evidence([reference]), np.array([distance]),
                                   opposite=opposite, scoring=self.config.verify.scoring,
                                   density=self.config.verify.density_filter)
                    corr = extra.correspondences(0)
                correspondences[reference] = corr
        return Evidence(query_labels=result.query_labels, correspondences=correspondences,
                        grid=getattr(self.map, "grid", None))

    def _position(self, index: int) -> tuple[float, float] | None:
        if self.map.positions is None:
            return None
        x, y = self.map.positions[index]
        return float(x), float(y)


def _candidates(result: MatchResult) -> list[Candidate]:
    n = result.n_matches
    return [
        Candidate(int(c), float(d), float(s), int(n[i]) if n is not None else 0)
        for i, (c, d, s) in enumerate(zip(result.candidates, result.distances, result.scores))
    ]

