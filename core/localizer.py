"""The online localizer: one frame in, one place estimate out.

``Localizer(map, config).step(frame) -> Estimate`` runs, per frame:

1. the single-frame match (:class:`PlaceMatcher`: describe, search, verify);
2. the sequence filter (:class:`SequenceFilter`) over the last L frames, fed
   with the frame's candidates, the nearest map frames of its search and its
   scores, from which it has contrast-normalised costs computed for every
   map frame, or, on a large map (``sequence.costs``), only where it looks
   (:mod:`lostx.core.match.costs`); its best trajectory gives the position and speed;
3. the route tracker (:class:`RouteTracker`, a Kalman filter), which gates
   implausible jumps, narrows the speeds searched next, and restarts after a
   genuine jump.

The cues of a frame (LoST-X, the layout, appearance) are combined with the weights they earned on the stream: how
often each one's answer lands where its own trajectory predicted (:mod:`lostx.core.route.agreement`). The heading
(the query viewing the route the same way as the map or the opposite way) is found from the evidence by a
:class:`HeadingFilter`, whose voters are LoST-X's mirrored verification and which heading's combined answers keep to
their trajectory; both headings' answers fill a sequence window of their own, so that wherever the evidence turns the
heading the answers follow a window of the new heading's matches. A declared camera ties the direction of travel to
the heading; undeclared, trajectories of both signs are searched, and the direction of travel is found from them
(:class:`DirectionFilter`): once it is sure, the answer keeps to it. While the window fills, the answer is the best
trajectory so far (``sequence.warm_up``), flagged ``warming_up``. Where the recent frames' own answers do not keep to
the answering trajectory (the motion and the matches disagree, :class:`Disagreement`), the answer says so
(``disagrees``).

The margin, what the confidence is calibrated from:

- with the sequence filter: the best trajectory's mean cost under that of the
  best trajectory ending more than ``sequence.exclusion`` reference frames away,
  in units of the frames' contrast-normalised costs (standard deviations);
- single frame (``sequence.enabled = False``): the verified uniqueness
  1 - s_best / s_alt of :func:`lostx.core.match.matcher.uniqueness`.

Confidence, in [0, 1]: 1 - the probability that a wrong answer leads by as much,
from the tail of the wrong answers' leads measured on the map itself
(:mod:`lostx.core.decide.calibration`); 0 while warming up and when the tracker
replaces the answer by its prediction.

State: ``localized`` when the confidence reaches ``decision.min_confidence``,
the heading is at least ``heading.min_confidence`` probable and, with the
sequence filter, the window is full and (with the tracker) the answer agrees
with the track's prediction; ``not_localized`` otherwise.

Bad input (a frame that is not an H x W x 3 uint8 image, non-finite network
output, a timestamp earlier than the previous frame's) raises a
:class:`LostxError` and leaves the localizer's state as it was, ready for the
next good frame.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Callable

import numpy as np

from .backbones import Backbone
from .config import Config, HeadingConfig, TrackerConfig, looks_up_costs
from .decide.calibration import PLACES, UNCALIBRATED, Calibration, load, settings_key, store
from .decide.estimate import Candidate, DeferredCorrespondences, DeferredLayout, Estimate, Evidence, LayoutView
from .decide.tail import leads
from .describe.inputcheck import InputCheck
from .describe.keypoints import KeypointEvidence
from .errors import InputError, StateError
from .frame import HEADINGS, Frame, Heading
from .images import check_frame
from .maps.refmap import ReferenceMap
from .motion.odometer import mounting
from .match.costs import EveryFrameCosts, LookedUpCosts
from .match.combined import EVERY_FRAME_MAX, CombinedScores
from .match.matcher import FrameMatch, MatchResult, PlaceMatcher, combined_result, without
from .match.verify import Correspondences, verify
from .route.agreement import CueAgreement, Disagreement, agrees
from .route.direction import DirectionFilter
from .route.heading import HeadingFilter
from .route.sequence import SequenceFilter, SequenceResult, signed
from .route.tracker import RouteTracker

WINDOW_PICTURE_WIDTH = 15


def contrast_references(route: np.ndarray, metres: float) -> int:
    """The contrast neighbourhood, in references, that spans ``metres`` of a map's route (``route``: metres along
    it at each frame) at its median frame spacing; at least 2, at most the whole map."""
    steps = np.diff(np.asarray(route, dtype=np.float64))
    spacing = float(np.median(steps)) if len(steps) else 0.0
    if spacing <= 0.0:
        return max(2, len(route))
    return int(min(max(2, round(metres / spacing)), max(2, len(route))))


class Localizer:
    """Stateful place recognition over a stream of frames from one camera."""

    def __init__(self, refmap: ReferenceMap, config: Config | None = None, backbone: Backbone | None = None,
                 calibration: Calibration | None = None) -> None:
        """``calibration``: the map's wrong-answer margins for these settings; by default the map's
        stored one, or measured now (and stored beside the map) when it has none for them."""
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
        if calibration is None:
            calibration = load(refmap.path, self.config)
            if calibration is None:
                calibration = calibrate(refmap, self.config, self.matcher.backbone)
                store(refmap.path, calibration)
        self.calibration = calibration
        self.tracker = RouteTracker(self.config.tracker)
        self.heading = HeadingFilter(self.config.heading)
        seq = self.config.sequence
        self.direction = DirectionFilter(seq.direction_reliability, self.config.heading.switch, seq.direction_scale)
        self.reset()

    @property
    def sequence(self) -> SequenceFilter:
        """The sequence filter over the frames' combined matches under the heading answered with."""
        return self.filters[self._answering or "same"]

    def _sequence_filter(self, route: np.ndarray | None, cue: bool = False) -> SequenceFilter:
        """A sequence filter over the combined matches, or (``cue``) over one cue's own scores. Where costs are looked
        up, a cue's filter anchors at its candidates and as many of its lowest costs (``verify.top_k``): it only
        predicts where the cue's next answer lies (lostx.core.route.agreement), and more anchors changed no answer
        on either nuScenes scene while each reads a window's past."""
        seq = self.config.sequence
        looked_up = looks_up_costs(seq, self.map.n_frames)
        costs = LookedUpCosts if looked_up else EveryFrameCosts
        anchors = (self.config.verify.top_k if cue else seq.nearest) if looked_up else seq.anchors
        speeds = signed(seq.distance_ratios, stopped=False) if route is not None else signed(seq.speeds, stopped=True)
        window = seq.contrast_window if route is None else contrast_references(route, seq.contrast_distance)
        return SequenceFilter(seq.length, tuple(speeds), seq.radius, seq.penalty,
                              costs(self.map.n_frames, seq.length, window, seq.reference_prior),
                              anchors, window // 2, route, seq.distance_window, seq.distance_window / seq.length,
                              seq.switch_cost, seq.hypotheses if looked_up else 0)

    def _route(self) -> np.ndarray | None:
        return self.map.progress if self.following_distance else None

    def _fresh(self) -> None:
        """Every heading's sequence filter, the cues' agreements and what they predicted, started afresh (at the
        first frame, and where the trajectories start following the distance travelled)."""
        route = self._route()
        self.filters: dict[Heading, SequenceFilter] = {h: self._sequence_filter(route) for h in HEADINGS}
        """Each heading's sequence filter over its frames' combined matches."""
        self._last: dict[Heading, SequenceResult | None] = {h: None for h in HEADINGS}
        """Each heading's best trajectory after the latest frame: where it predicts the next answer."""
        self._disagreement = {h: Disagreement() for h in HEADINGS}
        memory = 2.0 * self.config.sequence.length
        within = self.config.cues.agree_within
        self.cues: dict[str, CueAgreement] = {
            key: CueAgreement(lambda: self._sequence_filter(route, cue=True), memory, within) for key in _CUE_KEYS}
        """Each cue's own sequence filter and agreement, by cue and heading (appearance sees both alike)."""

    def _follow(self, progress: float | None) -> None:
        """Choose what the sequence filters' trajectories are straight in: the distance travelled wherever the map
        and the frames have motion (turns, stops and changes of speed do not bend them), else the frames. Chosen at a
        traverse's first frame, and again at the first frame whose distance travelled is known where the first ones'
        was not (the filters then start afresh, following the distance). Trajectories straight in frames where there
        is motion won one query of 132 on scene-0523 and cost scene-0916 its heading (1 of 41 frames right against
        39) and 13 queries: not a choice that carries from one road to another, so it is not offered."""
        distance = progress is not None and self.map.progress is not None
        if self.following_distance is None or distance:
            self.following_distance = distance
            self._fresh()

    def reset(self) -> None:
        """Forget everything seen so far (start of a new traverse)."""
        self.matcher.reset()
        self.following_distance: bool | None = None
        """Whether the sequence filters follow the distance travelled (where the map and the frames have motion);
        None before any frame."""
        self._fresh()
        self._answering: Heading | None = None
        self._last_progress: float | None = None
        self.tracker.reset()
        self.heading.reset()
        self.direction.reset()
        self._last_timestamp: float | None = None

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
        matches = self.matcher.match(frame)
        self.input_check(frame.id, frame.image, matches.same.query_labels)
        if frame.timestamp is not None:
            self._last_timestamp = frame.timestamp
        estimate = self.update(frame, matches)
        estimate.latency_ms["total"] = 1e3 * (time.perf_counter() - start)
        return estimate

    def update(self, frame: Frame, matches: FrameMatch) -> Estimate:
        """Advance the cues' weights, the heading, the sequence filters and the tracker with the single-frame matches
        of ``frame``.

        :meth:`step` computes the matches with its own matcher; evaluation feeds matches of
        other single-frame methods (or cached ones) through the same stages here.
        """
        declared = self._declared_heading(frame)
        fixed = declared if declared is not None and self.config.heading.declared_prior >= 1.0 else None
        followed: tuple[Heading, ...] = (fixed,) if fixed is not None else HEADINGS  # type: ignore[assignment]
        if not self.following_distance:
            self._follow(matches.progress)
        progress = matches.progress if self.following_distance else None
        if self.following_distance and progress is None:
            progress = self._last_progress  # the distance moved is not known: as if it stood still
        self._last_progress = progress
        t0 = time.perf_counter()
        advanced: set[str] = set()
        combined = {h: self._combined(matches[h], h, progress, advanced) for h in followed}
        agreed = {h: agrees(combined[h].best, self._last[h], self.config.cues.agree_within) for h in followed}
        cue_seconds = time.perf_counter() - t0
        votes = {"mirror": matches.heading_evidence, "motion": _motion_vote(agreed)}
        heading, sure = self.heading.update(votes, declared)
        if heading not in combined:
            heading = followed[0]
        if self._answering is not None and heading != self._answering:
            self.tracker.reset()  # the track is of the other heading's answers
        self._answering = heading
        for h in followed:
            self._disagreement[h].add(agreed[h])
        result = combined[heading]
        latency = {k: 1e3 * v for k, v in result.timings.items()}
        if advanced:
            latency["cues"] = 1e3 * cue_seconds  # each cue's agreement and the combination
        t1 = time.perf_counter()
        if self.config.sequence.enabled:
            direction = self._travel_direction(frame, heading, sure)
            estimate = self._sequence_estimate(frame, result, sure, latency, direction, progress)
            t1 = time.perf_counter()
        else:
            estimate = self._single_estimate(frame, result, sure)
        for h in followed:
            if h != heading:
                self._last[h] = self.filters[h].update(combined[h].map_scores, combined[h].candidates,
                                                       combined[h].nearest, self._plausible_speeds(0), progress)
        if len(followed) > 1 or not self.config.sequence.enabled:
            # Single frame, every heading's trajectories are the heading's evidence (which one's answers keep to them).
            latency["other heading" if self.config.sequence.enabled else "heading"] = 1e3 * (time.perf_counter() - t1)
        estimate.heading_confidence = sure
        estimate.cue_weights = dict(result.weights) if result.weights is not None else {}
        estimate.latency_ms = latency
        return estimate

    def _combined(self, result: MatchResult, heading: Heading, progress: float | None,
                  advanced: set[str]) -> MatchResult:
        """``result`` (LoST-X's answer under ``heading``, its cues attached) ranked by its cues combined with the
        weights they earned (fixed ``cues.weights`` where given); each cue's agreement advanced with this frame (once
        a frame: ``advanced`` holds those already advanced, appearance being the same under both headings)."""
        cues = result.cues
        if cues is None or len(cues.present()) < 2:
            return result
        fixed = self.config.cues.weights
        weights: dict[str, float] = {}
        for name in cues.present():
            key = _cue_key(name, heading)
            agreement = self.cues[key]
            if key not in advanced:
                advanced.add(key)
                if name == "lostx":
                    agreement.update(cues.lostx, result.best, result.candidates, result.nearest, progress)
                else:
                    alone = without(CombinedScores(cues, {name: 1.0}), cues.lostx.removed)
                    candidates = _best_of(alone, result, self.config.verify.top_k)
                    agreement.update(alone, int(candidates[0]), candidates, result.nearest, progress)
            weights[name] = fixed.get(name, 0.0) if fixed else agreement.weight(self.map.n_frames)
        return combined_result(result, weights, self.config.verify.top_k, self.config.verify.uniqueness_exclusion)

    def _declared_heading(self, frame: Frame) -> Heading | None:
        if frame.camera is None:
            return None
        return "opposite" if frame.camera != self.map.camera else "same"

    def _single_estimate(self, frame: Frame, result: MatchResult, heading_sure: float) -> Estimate:
        self._last[result.heading] = self.filters[result.heading].update(
            result.map_scores, result.candidates, result.nearest, self._plausible_speeds(0), self._last_progress)
        confidence = self.calibration.single_confidence(result.confidence)
        localized = self._confident(confidence, heading_sure)
        estimate = self._estimate(frame, result, result.best, "localized" if localized else "not_localized",
                                  confidence, result.score)
        estimate.margin = result.confidence
        return estimate

    def _confident(self, confidence: float, heading_sure: float) -> bool:
        return confidence >= self.config.decision.min_confidence and heading_sure >= self.config.heading.min_confidence

    def _sequence_estimate(self, frame: Frame, result: MatchResult, heading_sure: float, latency: dict,
                           direction: int, progress: float | None) -> Estimate:
        cfg = self.config.sequence
        sequence = self.filters[result.heading]
        t0 = time.perf_counter()
        costs_before = sequence.costs.seconds
        speeds = self._plausible_speeds(direction)
        if direction:
            sequence.keep_direction(direction)
        seq = sequence.update(result.map_scores, result.candidates, result.nearest, speeds, progress)
        along, along_sure = self.direction.update(*sequence.best_by_sign())
        if not direction and along_sure >= self.config.heading.min_confidence:
            seq = sequence.choose(along)
        self._last[result.heading] = seq
        runner_up = sequence.runner_up(seq.position, cfg.exclusion)
        margin = max(0.0, runner_up - seq.mean) if np.isfinite(runner_up) else np.inf
        t1 = time.perf_counter()
        t_costs = t0 + (sequence.costs.seconds - costs_before)  # the costs' share of the update
        warming = not sequence.full
        disagrees = not warming and self._disagreement[result.heading].disagree
        confidence = 0.0 if warming else self.calibration.sequence_confidence(margin)
        confident = self._confident(confidence, heading_sure)
        position, speed, trusted = seq.position, seq.speed, confident
        if not warming and self.config.tracker.enabled:
            # Acquisition tests a constant speed in reference frames per frame: the trajectories' own model when
            # they follow the frames; when they follow the distance, stops and changes of speed break it.
            track = self.tracker.step(seq.position, seq.speed, confident, acquire=not self.following_distance)
            trusted = confident and track.accepted and abs(track.innovation) <= self.config.tracker.agree_within
            if not track.accepted and track.position != seq.position:
                position, speed, confidence = track.position, track.speed, 0.0  # the track's prediction
        state = "localized" if trusted and not warming else "not_localized"
        t2 = time.perf_counter()
        latency["costs"] = 1e3 * (t_costs - t0)
        latency["sequence"] = 1e3 * (t1 - t_costs)
        latency["tracker"] = 1e3 * (t2 - t1)
        if warming and cfg.warm_up == "single":
            position = float(result.best)
        index = int(np.clip(np.rint(position), 0, self.map.n_frames - 1)) if np.isfinite(position) else result.best
        estimate = self._estimate(frame, result, index, state, confidence, seq.score)
        estimate.margin = float(margin)
        estimate.sequence_score = seq.score
        estimate.speed = float(speed)
        estimate.window = seq.frames
        estimate.warming_up = warming
        estimate.disagrees = disagrees
        if estimate.evidence is not None:
            window, refs = sequence.window(WINDOW_PICTURE_WIDTH)
            estimate.evidence.sequence_window = window
            estimate.evidence.sequence_candidates = refs
        return estimate

    def _travel_direction(self, frame: Frame, heading: Heading, sure: float) -> int:
        """+1 (reference index rising), -1 (falling), or 0 (unknown: search both).

        A declared camera ties the heading to the direction of travel: a front camera that views the
        route the same way as a front-camera map drives it the same way; viewing it the opposite way,
        it drives it the other way (and a rear camera the reverse). Undeclared, both directions are searched:
        the best trajectory's own sign is no independent evidence (restricting the search to it would
        only ever confirm it).
        """
        if sure < self.config.heading.min_confidence:
            return 0
        if self.following_distance:
            # Metres along the map's route per metre the vehicle drives: the vehicles progress together when they
            # drive the road the same way, which the heading tells through how the two cameras are mounted.
            mounted = self._mounting(frame)
            return self.map.progress_sign * (1 if heading == "same" else -1) * mounted
        if frame.camera is None:
            return 0
        return 1 if (heading == "same") == (frame.camera == self.map.camera) else -1

    def _mounting(self, frame: Frame) -> int:
        """:func:`mounting` of the frame's camera and the map's (+1 where either is unknown: both ahead)."""
        map_camera = self.map.camera_geometry
        query_yaw = frame.geometry.yaw if frame.geometry is not None else 0.0
        return mounting(query_yaw, map_camera.yaw if map_camera is not None else 0.0)

    def _plausible_speeds(self, direction: int) -> np.ndarray:
        """Speeds of the trajectories the new frame spawns: the tracker's band, or the acquisition range;
        of one sign when the direction of travel is known."""
        cfg = self.config.sequence
        band = self.tracker.speed_range() if self.config.tracker.enabled else None
        if self.following_distance:
            speeds = signed(cfg.distance_ratios, stopped=False)
        elif band is None:
            speeds = signed(cfg.acquire_speeds, stopped=False)
        else:
            speeds = signed(cfg.speeds, stopped=True)
            inside = speeds[(speeds >= band[0]) & (speeds <= band[1])]
            speeds = inside if len(inside) else speeds[[int(np.argmin(np.abs(speeds - sum(band) / 2)))]]
        if direction:
            along = speeds[speeds * direction >= 0]
            speeds = along if len(along) else speeds
        return speeds

    def _estimate(self, frame: Frame, result: MatchResult, index: int, state: str, confidence: float,
                  score: float) -> Estimate:
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
            heading=result.heading,
            evidence=self._evidence(result, index),
        )

    def _evidence(self, result: MatchResult, index: int) -> Evidence:
        """What it takes to draw the answer (and the single-frame best): their correspondences (computed when a
        drawing asks for them)."""
        correspondences = {}
        if result.verification is not None:
            query = self.matcher.last_evidence
            for reference in dict.fromkeys((index, result.best)):
                correspondences[reference] = functools.partial(self._correspondences, result, reference, query)
        layout = None
        if result.layout is not None:
            layout = DeferredLayout(functools.partial(self._layout_view, result, index))
        return Evidence(query_labels=result.query_labels, correspondences=DeferredCorrespondences(correspondences),
                        grid=getattr(self.map, "grid", None), layout=layout)

    def _layout_view(self, result: MatchResult, index: int) -> LayoutView:
        """The frame's grid turned and shifted as it best fits map frame ``index``'s, both drawn in the query camera's
        view: turned 180 degrees back where it views the route the opposite way (a shift then changes side)."""
        answer = self.map.layout_grid(index, result.heading)
        fit = result.layout.aligned(answer)  # type: ignore[union-attr]
        metres = fit.shift * self.matcher.layout_config.cell
        if result.heading == "opposite":
            return LayoutView(fit.grid.turned(), answer.turned(), fit.turn, -metres)
        return LayoutView(fit.grid, answer, fit.turn, metres)

    def _correspondences(self, result: MatchResult, reference: int,
                         query: KeypointEvidence | None) -> Correspondences | None:
        """The surviving correspondences of the frame (its keypoint evidence ``query``) with map frame ``reference``."""
        corr = result.correspondences_for(reference)
        if corr is None and query is not None:
            # The answer was not among the verified candidates: verify it too, to draw it.
            distance = float(result.distances[0]) if len(result.distances) else 1.0
            extra = verify(query, self.map.evidence([reference]), np.array([distance]),
                           opposite=result.heading == "opposite", scoring=self.config.verify.scoring,
                           density=self.config.verify.density_filter)
            corr = extra.correspondences(0)
        return corr

    def _position(self, index: int) -> tuple[float, float] | None:
        if self.map.positions is None:
            return None
        x, y = self.map.positions[index]
        return float(x), float(y)

    def state(self) -> dict:
        """Everything that carries from one frame to the next (the matcher's query statistics, each heading's
        sequence window and prediction, the cues' agreements, the tracker, the heading's votes, what the trajectories
        follow), as plain values and numpy arrays: a localizer over the same map and settings given it by
        :meth:`restore` answers the next frames exactly as this one would. :class:`StateError` where a part cannot
        be carried (costs looked up on a very large map)."""
        return {"map_frames": self.map.n_frames, "matcher": self.matcher.state(),
                "filters": {h: f.state() for h, f in self.filters.items()},
                "last": {h: None if r is None else _result_state(r) for h, r in self._last.items()},
                "disagreement": {h: d.state() for h, d in self._disagreement.items()},
                "cues": {key: c.state() for key, c in self.cues.items()},
                "answering": self._answering, "following_distance": self.following_distance,
                "last_progress": self._last_progress,
                "tracker": self.tracker.state(), "heading": self.heading.state(), "direction": self.direction.belief,
                "last_timestamp": self._last_timestamp}

    def restore(self, state: dict) -> None:
        """Continue from :meth:`state` (of a localizer over a map of the same size and the same settings)."""
        if state["map_frames"] != self.map.n_frames:
            raise StateError(f"a saved state over a map of {state['map_frames']} frames, this map has "
                             f"{self.map.n_frames}")
        if "filters" not in state:
            raise StateError("a saved state of an earlier lostx (one sequence window, not one per heading)")
        self.reset()
        self.matcher.restore(state["matcher"])
        self.following_distance = state["following_distance"]
        self._fresh()
        for h, saved in state["filters"].items():
            self.filters[h].restore(saved)
        for h, saved in state["last"].items():
            self._last[h] = None if saved is None else _result_from_state(saved)
        for h, saved in state["disagreement"].items():
            self._disagreement[h].restore(saved)
        for key, saved in state["cues"].items():
            self.cues[key].restore(saved)
        self._answering = state["answering"]
        self._last_progress = state["last_progress"]
        self.tracker.restore(state["tracker"])
        self.heading.restore(state["heading"])
        self.direction.restore(state["direction"])
        self._last_timestamp = state["last_timestamp"]


_CUE_KEYS = ("lostx|same", "lostx|opposite", "layout|same", "layout|opposite", "appearance")


def _cue_key(name: str, heading: Heading) -> str:
    """A cue's agreement key: per heading, but for appearance, which sees both headings alike."""
    return name if name == "appearance" else f"{name}|{heading}"


def _best_of(scores, result: MatchResult, k: int) -> np.ndarray:  # noqa: ANN001
    """The ``k`` map frames a cue scores best (lower is better), among every map frame where the map is small enough,
    else among the search's nearest and LoST-X's candidates."""
    n = scores.n_frames
    if n <= EVERY_FRAME_MAX:
        values = scores.every()
        pool = np.arange(n)
    else:
        pool = np.union1d(result.nearest, result.candidates)  # type: ignore[arg-type]
        values = scores.at(pool)
    order = np.lexsort((pool, values))[:k]
    return pool[order]


def _motion_vote(agreed: dict[Heading, bool | None]) -> float | None:
    """+1 where only the opposite heading's answer kept to its trajectory, -1 only the same's, 0 both or neither;
    None where either had no prediction (or only one heading is followed)."""
    same, opposite = agreed.get("same"), agreed.get("opposite")
    if same is None or opposite is None:
        return None
    return float(opposite) - float(same)


def _result_state(result: SequenceResult) -> list:
    return [result.position, result.speed, result.score, result.frames, result.trajectory, result.mean]


def _result_from_state(saved: list) -> SequenceResult:
    return SequenceResult(float(saved[0]), float(saved[1]), float(saved[2]), int(saved[3]), np.asarray(saved[4]),
                          float(saved[5]))


def _candidates(result: MatchResult) -> list[Candidate]:
    n = result.n_matches
    return [
        Candidate(int(c), float(d), float(s), int(n[i]) if n is not None else 0)
        for i, (c, d, s) in enumerate(zip(result.candidates, result.distances, result.scores))
    ]


def calibrate(refmap: ReferenceMap, config: Config, backbone: Backbone | None = None,
              progress: Callable[[int], None] | None = None) -> Calibration:
    """The map's calibration for these settings (:mod:`lostx.core.decide.calibration`): up to
    ``decision.calibration_frames`` map frames matched against the map, neighbourhood excluded, through a
    localizer of their own: of each, its single-frame margin and, once the sequence window is full, the leads among
    its ``PLACES`` best (all wrong) places.

    Longer maps are sampled in stretches spread over the route (each stretch long enough to fill the
    sequence window several times), so that the sequence filter sees a traverse as it would live.
    """
    seq = config.sequence
    # The map views the route the way it was built; the raw margins are wanted, not the tracker's gate.
    quiet = dataclasses.replace(config, heading=HeadingConfig(declared_prior=1.0),
                                tracker=TrackerConfig(enabled=False),
                                sequence=dataclasses.replace(seq, enabled=True))
    sequence_leads: list[np.ndarray] = []
    single: list[float] = []
    frames = 0
    route = refmap.progress
    for stretch in _stretches(refmap.n_frames, config.decision.calibration_frames, 4 * seq.length):
        localizer = Localizer(refmap, quiet, backbone, calibration=UNCALIBRATED)
        for index in stretch:
            frames += 1
            matches = localizer.matcher.match_reference(int(index), seq.exclusion)
            if matches is None:
                continue
            if route is not None:
                matches.progress = refmap.progress_sign * float(route[index])
            frame = Frame(id=int(index), image=_NO_PIXELS, camera=refmap.camera,  # type: ignore[arg-type]
                          geometry=refmap.camera_geometry)
            estimate = localizer.update(frame, matches)
            single.append(matches.same.confidence)
            if not estimate.warming_up:
                # Trajectories just outside the excluded neighbourhood run alongside the frame's own place and look
                # alike: near misses of the true place, not wrong places, so they are left out.
                ends = localizer.sequence.positions()
                with np.errstate(invalid="ignore"):
                    ends = np.where(np.abs(ends - index) > 2 * seq.exclusion, ends, np.nan)
                sequence_leads.append(leads(localizer.sequence.means(), ends, seq.exclusion, PLACES))
            if progress is not None:
                progress(1)
    return Calibration(_joined(sequence_leads), np.asarray(single, dtype=np.float64), settings_key(config), frames)


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0)


def _stretches(n_frames: int, budget: int, length: int) -> list[np.ndarray]:
    if n_frames <= budget:
        return [np.arange(n_frames)]
    length = min(length, budget)
    count = max(1, budget // length)
    starts = np.linspace(0, n_frames - length, count).astype(np.int64)
    return [np.arange(start, start + length) for start in starts]


_NO_PIXELS = np.zeros((1, 1, 3), np.uint8)
