"""Single-frame place matching: describe, search the top k, verify, rank; with the layout where the map and
the frames have it (the two cues combined, :mod:`lostx.core.match.combined`)."""

from __future__ import annotations

import dataclasses
import math
import os
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..backbones import Backbone, load_backbone
from ..config import Config, LostConfig, looks_up_costs
from ..describe.camera import Geometry
from ..geometry import CameraGeometry
from ..describe.describer import LostDescriber, TrailingMeans
from ..describe.keypoints import KeypointEvidence
from ..describe.lost import RunningStandardiser
from ..describe.thumbnail import ThumbnailDescriber
from ..errors import InputError, MapError, StateError
from ..frame import HEADINGS, Camera, Frame, Heading
from ..images import check_frame
from ..layout import compare as grid_compare
from ..layout.classes import CHANNELS, LayoutClasses
from ..layout.describer import FramePlacer, LiveLayout
from ..layout.grid import Gathering, LayoutGrid
from ..maps.refmap import ReferenceMap
from . import comparers
from .combined import EVERY_FRAME_MAX, CombinedScores, Comparer, Cues, LayoutComparison, LayoutScores
from .comparers import ComparisonProcess, ComparisonWarning, ThreadComparer
from .scores import MapScores
from .search import CandidateSearch, QueryDistances, cosine_distances
from .verify import Correspondences, Verification, verify


@dataclass
class QueryDescription:
    """What the matcher needs of a LoST query frame, before any query statistics are applied.

    Computing it is the expensive part (the network); it depends only on the frame
    (and, with ``query_window > 1``, on the previous frames), so it can be cached.
    """

    descriptor: np.ndarray
    """Raw LoST descriptor L (Eq. 1-3), before normalisation."""
    appearance: np.ndarray | None
    """GeM-pooled network features (the appearance baseline), when asked for."""
    evidence: KeypointEvidence
    labels: np.ndarray
    """(h, w) grouped semantic labels."""
    timings: dict[str, float] = field(default_factory=dict)
    """Seconds: network, descriptor, layout, motion."""
    layout: LayoutGrid | Gathering | None = None
    """The frame's layout grid (gathered over the distance just travelled; :meth:`Gathering.grid`), where the layout
    is on; a grid as such where it was stored (an evaluation's cache)."""
    progress: float | None = None
    """Metres the stream has advanced along its camera's axis (lostx.core.motion), where its motion is known."""
    gathered: float | None = None
    """Metres the frame's layout grid gathered over (:attr:`Gathering.reach`), where it has a layout."""


@dataclass
class MatchResult:
    """One query frame's single-frame answer. Candidates are ranked best first by ``scores``."""

    candidates: np.ndarray
    """(k,) reference indices, best first."""
    distances: np.ndarray
    """(k,) descriptor distances: LoST cosine distance, or thumbnail SAD."""
    scores: np.ndarray
    """(k,) the method's score, lower is better: the verification score for LoST-X,
    the descriptor distance where nothing is verified."""
    confidence: float
    """Uniqueness in [0, 1]: 1 - best score / best score of a candidate more than
    ``uniqueness_exclusion`` reference frames away from the match (1 when there is none)."""
    n_matches: np.ndarray | None = None
    """(k,) keypoint correspondences that survived verification."""
    verification: Verification | None = None
    """The verification of the shortlist (rows in ``shortlist`` order)."""
    shortlist: np.ndarray | None = None
    """Reference index of each verification row."""
    query_labels: np.ndarray | None = None
    """(h, w) grouped semantic labels of the query."""
    timings: dict[str, float] = field(default_factory=dict)
    """Seconds per stage: network, descriptor, search, verify."""
    map_scores: MapScores | None = None
    """The single-frame score of any reference frame, computed when the sequence filter asks: the
    descriptor distance for thumbnails; for LoST-X the verification score of the verified candidates
    and, elsewhere, the descriptor distance times the candidates' median ratio of score to distance."""
    nearest: np.ndarray | None = None
    """The search's nearest reference frames, nearest first (``sequence.nearest`` of them where the sequence
    filter looks its costs up, else the ``verify.top_k`` candidates): where it looks for its anchors."""
    heading: Heading = "same"
    """The heading hypothesis these scores were computed under (the query's x mirrored for ``opposite``)."""
    layout: LayoutScores | None = None
    """The layout's similarity with any map frame under this heading (its query grid turned for ``opposite``),
    where the layout took part."""
    cues: Cues | None = None
    """Each cue's scores of any map frame under this heading (LoST-X's, the layout's, appearance's), before they are
    combined (:func:`combined_result`); None for a method with one score."""
    weights: dict[str, float] | None = None
    """Where this is the cues' combined answer: the weight each cue had (unit length)."""

    @property
    def best(self) -> int:
        return int(self.candidates[0])

    def correspondences_for(self, reference: int) -> Correspondences | None:
        """The surviving keypoint correspondences with a verified candidate (None if it was not verified)."""
        if self.verification is None or self.shortlist is None:
            return None
        rows = np.flatnonzero(self.shortlist == reference)
        return self.verification.correspondences(int(rows[0])) if len(rows) else None

    @property
    def score(self) -> float:
        return float(self.scores[0])


@dataclass
class FrameMatch:
    """One query frame matched under both heading hypotheses: the query views the route the same way
    as the map, or the opposite way (its x mirrored in verification, its thumbnail flipped)."""

    same: MatchResult
    opposite: MatchResult
    heading_evidence: float = 0.0
    """This frame's vote on the heading, in [-1, 1]: the mean over the candidates verified under both
    hypotheses of sign(score same - score opposite) (a flipped thumbnail's, for thumbnails). Positive favours
    ``opposite``; 0 is no evidence (nothing verified, or a method that cannot tell)."""
    progress: float | None = None
    """Metres the stream has advanced along its camera's axis at this frame, where its motion is known."""

    def __getitem__(self, heading: Heading) -> MatchResult:
        return self.opposite if heading == "opposite" else self.same

    @classmethod
    def either(cls, result: MatchResult) -> "FrameMatch":
        """A method that cannot tell the headings apart (a pooled descriptor): one answer for both."""
        return cls(same=result, opposite=dataclasses.replace(result, heading="opposite"))


def heading_vote(same: np.ndarray, opposite: np.ndarray) -> float:
    """Mean of sign(same - opposite) over the candidates scored (finitely) under both hypotheses.

    A sign per candidate, not a ratio: the vote does not depend on the scale of the scores, which
    differs between scorings and data sets.
    """
    both = np.isfinite(same) & np.isfinite(opposite)
    return float(np.mean(np.sign(same[both] - opposite[both]))) if both.any() else 0.0


def margin(candidates: np.ndarray, scores: np.ndarray, exclusion: int) -> float:
    """s_alt - s_best of signed scores (the combined score, in standard deviations), s_alt the best more than
    ``exclusion`` frames from the best candidate; the ranks of these margins are what the map calibrates."""
    if len(scores) == 0 or not np.isfinite(scores[0]):
        return 0.0
    far = np.abs(candidates - candidates[0]) > exclusion
    alt = scores[far][np.isfinite(scores[far])]
    return float(max(alt.min() - scores[0], 0.0)) if len(alt) else float("inf")


SIDEWAYS_DEG = 45.0
"""A camera mounted further than this from its vehicle's axis (ahead or behind) looks sideways: the layout steps
aside for it."""


def looks_sideways(geometry: CameraGeometry) -> bool:
    """Whether a camera is mounted more than :data:`SIDEWAYS_DEG` from its vehicle's axis, ahead or behind. Its
    view of a place from the road's other end is from the road's other side, which a grid turned 180 degrees about
    its centre does not give."""
    return abs(math.sin(math.radians(geometry.yaw))) > math.sin(math.radians(SIDEWAYS_DEG))


class LayoutWarning(UserWarning):
    """The layout could not take part (said once per stream, with the reason)."""


def uniqueness(candidates: np.ndarray, scores: np.ndarray, exclusion: int) -> float:
    """1 - s_best / s_alt, s_alt the best score more than ``exclusion`` frames from the best candidate.

    Scores are ranked best first. 0 means an equally good answer elsewhere on the route.
    """
    if len(scores) == 0 or not np.isfinite(scores[0]):
        return 0.0
    far = np.abs(candidates - candidates[0]) > exclusion
    if not far.any():
        return 1.0
    alt = float(scores[far].min())
    if not np.isfinite(alt):
        return 1.0
    if alt <= 0.0:
        return 0.0
    return float(np.clip(1.0 - scores[0] / alt, 0.0, 1.0))


class PlaceMatcher:
    """Matches single frames against a reference map. Stateful only through the causal
    query normalisation and the trailing class-mean window; ``reset()`` clears both."""

    def __init__(self, refmap: ReferenceMap, config: Config | None = None, backbone: Backbone | None = None) -> None:
        self.map = refmap
        self.config = config or Config()
        self.describer: LostDescriber | ThumbnailDescriber
        if refmap.kind == "lost":
            if backbone is None:
                # The map's own backbone, with the model file, device and threads the configuration gives.
                name = (refmap.backbone or {}).get("name", self.config.backbone.name)
                backbone = load_backbone(dataclasses.replace(self.config.backbone, name=name))
            refmap.check_backbone(backbone.info)
            lost_cfg = self.config.lost
            classes = refmap.manifest.get("classes")
            self.describer = LostDescriber(backbone, lost_cfg if classes is None else _with_classes(lost_cfg, classes))
            recorded = refmap.manifest.get("geometry") or {}
            self.geometry = Geometry.for_backbone(self.config.camera, recorded.get("view_hfov_deg"),
                                                  recorded.get("fit", "squash"), backbone.info)
            if list(self.describer.groups.label_names) != refmap.manifest.get("label_names"):
                raise MapError(f"{refmap.path}: the map's semantic classes differ from the configured ones")
            self.normaliser = RunningStandardiser(
                refmap.stats, lost_cfg.prior_frames, running=lost_cfg.normalisation == "running"
            )
            self.means = TrailingMeans(lost_cfg.query_window)
        else:
            settings = refmap.manifest.get("thumbnail", {})
            self.describer = ThumbnailDescriber(tuple(settings.get("size", (64, 32))), settings.get("patch", 8))

        self.search = CandidateSearch(refmap, self.config.search)
        self.backbone: Backbone | None = self.describer.backbone if isinstance(self.describer, LostDescriber) else None
        self.last_evidence: KeypointEvidence | None = None
        """The latest LoST query's keypoint evidence (to verify further candidates against)."""
        self._worker: Comparer | None = None
        self._worker_pid = 0
        self._started: tuple[Gathering, LayoutComparison, int] | None = None
        """The grid (to be gathered) of the frame :meth:`match` describes, its comparison with the map (started while
        the frame's descriptor is computed) and the process that started it."""
        self.layout_off: str | None = None
        """Why the layout takes no part (None while it does, or before a frame showed it cannot)."""
        self._placer: FramePlacer | None = None
        self._live: LiveLayout | None = None
        self._setup_layout()

    def _setup_layout(self) -> None:
        cfg = self.config.layout
        if cfg.enabled == "off" or self.map.kind != "lost":
            self.layout_off = "the layout is switched off" if cfg.enabled == "off" else "a thumbnail map has no layout"
            return
        settings = self.map.layout_settings
        classes = LayoutClasses.of_model(self.backbone.info.class_names) if self.backbone is not None else None
        if settings is None:
            self.layout_off = (f"the map {self.map.path} has no layout: it was built from frames without a camera "
                               f"geometry (give its camera with a camera file and rebuild it)")
        elif classes is None:
            self.layout_off = f"the model {self.backbone.info.name} has no road class"  # type: ignore[union-attr]
        if self.layout_off is not None:
            if cfg.enabled == "on":
                raise InputError(f"[layout] enabled = on, but {self.layout_off}")
            return
        # The grid as the map drew it; how the frames are gathered and compared as configured.
        grid = {name: getattr(settings, name) for name in ("cell", "length", "width", "centre", "max_range", "blur")}
        self.layout_config = dataclasses.replace(cfg, **grid)
        self._placer = FramePlacer(classes, self.layout_config, self.config.motion)  # type: ignore[arg-type]
        self._live = LiveLayout(self.layout_config)
        weights = np.ones(len(CHANNELS))
        weights[CHANNELS.index("vehicle")] = cfg.vehicle_weight
        self._layout_weights = weights
        self._layout_shifts = int(round(cfg.across_shift / settings.cell))
        if not self.map.stores_other_ends:
            warnings.warn(f"the map {self.map.path} was built before lostx stored each frame's grid as the other end of "
                          f"its stretch sees it: views from the other end of a bend are compared unaligned (rebuild "
                          f"the map to align them)", LayoutWarning, stacklevel=3)

    def _layout_unavailable(self, reason: str) -> None:
        """A frame cannot have a layout: say why, once."""
        if self.layout_off is None:
            self.layout_off = reason
            if self.config.layout.enabled == "on":
                raise InputError(f"[layout] enabled = on, but {reason}")
            warnings.warn(f"the layout is off: {reason}; matching by LoST-X alone", LayoutWarning, stacklevel=3)

    def reset(self) -> None:
        self.last_evidence = None
        self._started = None
        if isinstance(self.describer, LostDescriber):
            self.normaliser.reset()
            self.means.reset()
        if self._placer is not None and self._live is not None:
            self._placer.reset()
            self._live.reset()

    def state(self) -> dict:
        """What carries from frame to frame, as plain values and arrays: the query statistics (LoST maps) and,
        where the layout takes part, the stream's motion and the frames its grids gather
        (:class:`StateError` where visual odometry places them)."""
        lost = isinstance(self.describer, LostDescriber)
        layout = self._placer is not None and self._live is not None and self.layout_off is None
        placing = self._placer is not None and self._live is not None
        return {"normaliser": self.normaliser.state() if lost else None, "means": self.means.state() if lost else None,
                "layout_off": self.layout_off,
                "placer": self._placer.state() if placing else None,  # type: ignore[union-attr]
                "live": self._live.state() if layout else None}  # type: ignore[union-attr]

    def restore(self, state: dict) -> None:
        self.reset()
        if isinstance(self.describer, LostDescriber) != (state["normaliser"] is not None):
            raise StateError("a saved state of another kind of map (LoST or thumbnail)")
        if state["normaliser"] is not None:
            self.normaliser.restore(state["normaliser"])
            self.means.restore(state["means"])
        self.layout_off = state["layout_off"]
        if state.get("placer") is not None and self._placer is not None and self._live is not None:
            self._placer.restore(state["placer"])
            if state.get("live") is not None:
                self._live.restore(state["live"])

    def match(self, frame: Frame | np.ndarray, camera: Camera | None = None) -> FrameMatch:
        """Match one frame (or a bare image from the ``camera`` it declares) under both heading hypotheses."""
        if not isinstance(frame, Frame):
            frame = Frame(id=0, image=frame, camera=camera)
        image = check_frame(frame.image)
        if isinstance(self.describer, ThumbnailDescriber):
            return self._match_thumbnail(image)
        return self.match_description(self.describe(frame, appearance=self.appearance_cue, compare=True))

    @property
    def appearance_cue(self) -> bool:
        """Whether appearance takes part as a cue: the map holds its descriptors and ``cues.appearance`` is on."""
        return (self.config.cues.appearance and self.config.verify.enabled and self.map.kind == "lost"
                and self.map.has_appearance)

    def describe(self, frame: Frame, appearance: bool = False, compare: bool = False) -> QueryDescription:
        """Run the network on a LoST query frame, and place it on the road with its layout where that is on
        (the expensive, cacheable half of :meth:`match`, in stream order); ``appearance`` also pools the GeM
        descriptor of the appearance cue. ``compare``: the frame is matched next; its layout's comparison with
        the map starts as soon as its grid is known, beside its descriptor."""
        describer = self.describer
        assert isinstance(describer, LostDescriber)
        image = check_frame(frame.image)
        t0 = time.perf_counter()
        semantic = describer.backbone(self.geometry.prepare(image, frame.camera))
        t1 = time.perf_counter()
        described = describer.from_semantic(semantic)
        t2 = time.perf_counter()
        timings = {"network": t1 - t0}
        layout, progress = self._place(frame, described.label_map, timings)
        comparison = None
        if compare and layout is not None and self.config.verify.enabled:
            comparison = self._layout_comparison(layout)
            self._started = None if comparison is None else (layout, comparison, os.getpid())
        if layout is not None and comparison is None:
            # Not handed to a comparison (described ahead): gathered now, so that the description holds its grid, not
            # its frames.
            t = time.perf_counter()
            layout.grid()
            timings["layout"] += time.perf_counter() - t
        t3 = time.perf_counter()
        raw = describer.descriptor(described, self.means(described))
        timings["descriptor"] = (t2 - t1) + (time.perf_counter() - t3)
        return QueryDescription(raw, described.appearance() if appearance else None, described.evidence,
                                described.labels, timings, layout, progress,
                                None if layout is None else layout.reach)

    def _place(self, frame: Frame, label_map: np.ndarray | None,
               timings: dict[str, float]) -> tuple[Gathering | None, float | None]:
        """The frame's layout grid (to be gathered) and progress, where the layout is on and the frame allows it."""
        if self._placer is None or self._live is None:
            return None, None
        if frame.geometry is None:
            self._layout_unavailable("the frames carry no camera geometry (a camera file beside them, "
                                     "--camera-file, or a dataset's calibration gives it)")
            return None, None
        if label_map is None:
            self._layout_unavailable(f"the backbone {self.backbone.info.name} gives no label map")  # type: ignore[union-attr]
            return None, None
        t0 = time.perf_counter()
        box = self.geometry.region((frame.image.shape[1], frame.image.shape[0]), frame.camera)
        placed = self._placer(frame, label_map, box)
        t1 = time.perf_counter()
        if placed is None:
            self._layout_unavailable("the frames' motion is unknown (no odometry, and visual odometry is off)")
            return None, None
        timings["motion"] = t1 - t0
        progress = placed.progress if placed.known else None
        if looks_sideways(frame.geometry):
            # The motion still lines the frames up with the map (progress is along the vehicle's travel).
            self._layout_unavailable(f"the camera looks sideways ({frame.geometry.yaw:g} degrees from the vehicle's "
                                     f"axis): the stretches its grids see are not the road's two ends")
            return None, progress
        gathering = self._live.add(placed)
        timings["layout"] = time.perf_counter() - t1
        return gathering, progress

    def _match_thumbnail(self, image: np.ndarray) -> FrameMatch:
        t0 = time.perf_counter()
        # The opposite hypothesis compares the flipped thumbnail: left and right swap between the views.
        return self._thumbnail_match({"same": self.describer(image), "opposite": self.describer(image[:, ::-1])}, t0)

    @property
    def _nearest_count(self) -> int:
        """Map frames the search returns: the candidates, and the seeds of a sequence filter that looks its
        costs up."""
        if self.config.sequence.enabled and looks_up_costs(self.config.sequence, self.map.n_frames):
            return max(self.config.verify.top_k, self.config.sequence.nearest)
        return self.config.verify.top_k

    def _thumbnail_match(self, queries: dict[str, np.ndarray], t0: float, removed: slice | None = None) -> FrameMatch:
        t1 = time.perf_counter()
        k = self.config.verify.top_k
        results = {}
        for heading, query in queries.items():
            distance_of = QueryDistances(self.search, query)
            nearest, distances = self.search.nearest(query, self._nearest_count, removed, distance_of)
            order, ranked = nearest[:k], distances[:k]
            results[heading] = MatchResult(
                candidates=order,
                distances=ranked,
                scores=ranked,
                confidence=uniqueness(order, ranked, self.config.verify.uniqueness_exclusion),
                map_scores=without(MapScores(distance_of, self.map.n_frames), removed),
                nearest=nearest,
                heading=heading,  # type: ignore[arg-type]
            )
        timings = {"network": 0.0, "descriptor": t1 - t0, "search": time.perf_counter() - t1, "verify": 0.0}
        for result in results.values():
            result.timings = timings
        # Paired over the candidates of both searches: every one of them scored both ways.
        shortlist = np.union1d(results["same"].candidates, results["opposite"].candidates)
        vote = heading_vote(results["same"].map_scores.at(shortlist),  # type: ignore[union-attr]
                            results["opposite"].map_scores.at(shortlist))  # type: ignore[union-attr]
        return FrameMatch(results["same"], results["opposite"], vote)

    def match_description(self, query: QueryDescription) -> FrameMatch:
        """Normalise (causally), search and verify a described LoST query frame under both headings."""
        t0 = time.perf_counter()
        evidence = self.last_evidence = self.map.query_evidence(query.evidence)
        vector = self.normaliser(query.descriptor)
        appearance = query.appearance if self.appearance_cue else None
        match = self._search_and_verify(vector, evidence, query.labels, {**query.timings}, t0,
                                        layout=query.layout, appearance=appearance)
        match.progress = query.progress
        return match

    def match_reference(self, index: int, exclude: int) -> FrameMatch | None:
        """Map frame ``index`` as a query, with the reference frames within ``exclude`` of it removed:
        its answer is necessarily wrong. What wrong answers look like, measured without any query
        (see :mod:`lostx.core.decide.calibration`), searched and scored as a query is. None when the exclusion
        leaves no reference frame."""
        removed = _around(self.map.n_frames, index, exclude)
        if self.map.n_frames <= removed.stop - removed.start:
            return None
        t0 = time.perf_counter()
        query = self.map.descriptor_rows(np.array([index]))[0]
        if isinstance(self.describer, ThumbnailDescriber):
            flipped = query.reshape(self.describer.size[1], -1)[:, ::-1].ravel()
            return self._thumbnail_match({"same": query, "opposite": flipped}, t0, removed)
        layout = self.map.layout_grid(index) if self._live is not None else None
        appearance = self.map.appearance_rows(np.array([index]))[0] if self.appearance_cue else None
        return self._search_and_verify(query, self.map.evidence([index]), self.map.labels(index), {}, t0, removed,
                                       layout, appearance)

    def _search_and_verify(self, vector: np.ndarray, evidence: KeypointEvidence, labels: np.ndarray,
                           timings: dict[str, float], t0: float, removed: slice | None = None,
                           layout: LayoutGrid | Gathering | None = None,
                           appearance: np.ndarray | None = None) -> FrameMatch:
        """LoST-X's answer under each heading, with the frame's cues attached (its layout's comparison and its
        appearance's distances, where they take part) for the localizer to combine with the weights they earned."""
        cfg = self.config.verify
        comparison = self._comparison(layout) if cfg.enabled else None
        distance_of = QueryDistances(self.search, vector)
        nearest, near = self.search.nearest(vector, self._nearest_count, removed, distance_of)
        shortlist, distances = nearest[: cfg.top_k], near[: cfg.top_k]
        t1 = time.perf_counter()
        timings.update({"search": t1 - t0, "verify": 0.0})
        if not cfg.enabled:
            return FrameMatch.either(MatchResult(
                shortlist, distances, distances, uniqueness(shortlist, distances, cfg.uniqueness_exclusion),
                query_labels=labels, timings=timings,
                map_scores=without(MapScores(distance_of, self.map.n_frames), removed), nearest=nearest))
        result = verify(
            evidence,
            self.map.evidence(shortlist),
            distances,
            scoring=cfg.scoring,
            density=cfg.density_filter,
        )
        timings["verify"] = time.perf_counter() - t1
        looks = None if appearance is None else without(MapScores(AppearanceDistances(self.map, appearance),
                                                                  self.map.n_frames), removed)
        by_heading = {"same": result.scores, "opposite": result.mirror_scores}
        answers = {}
        for row, (heading, scores) in enumerate(by_heading.items()):
            rank = np.lexsort((np.arange(len(shortlist)), scores))
            candidates, ranked = shortlist[rank], scores[rank]
            lost = map_scores(distance_of, self.map.n_frames, shortlist, distances, scores, cfg.scoring, removed)
            layout_scores = None if comparison is None else comparison.heading(row)
            answers[heading] = MatchResult(
                candidates=candidates,
                distances=distances[rank],
                scores=ranked,
                confidence=uniqueness(candidates, ranked, cfg.uniqueness_exclusion),
                n_matches=result.n_matches[rank],
                verification=result,
                shortlist=shortlist,
                query_labels=labels,
                timings=timings,
                map_scores=lost,
                nearest=nearest,
                heading=heading,  # type: ignore[arg-type]
                layout=layout_scores,
                cues=Cues(lost, layout_scores, looks),
            )
        if comparison is not None:
            timings["layout compare"] = comparison.seconds
        return FrameMatch(answers["same"], answers["opposite"], heading_vote(result.scores, result.mirror_scores))

    def _comparer(self, comparison: LayoutComparison) -> Comparer:
        """Where this process's layout comparisons run beside LoST-X (:mod:`.comparers`): for the matcher's life, a
        process of their own on a map from ``PROCESS_MIN_FRAMES`` frames (while it lives), else a thread; new ones
        in a forked child, which the parent's thread and socket do not serve."""
        fresh = self._worker is None or self._worker_pid != os.getpid()
        if fresh or not self._worker.alive:  # type: ignore[union-attr]
            # A process only for a fresh matcher (or fork): once one has ended, a thread.
            comparer: Comparer = ThreadComparer()
            if fresh and comparison.maps.n >= comparers.PROCESS_MIN_FRAMES and (os.cpu_count() or 1) > 1:
                try:
                    comparer = ComparisonProcess(comparison)
                except OSError as exc:
                    warnings.warn(f"the layout's comparison process could not start ({exc}); comparing on a thread",
                                  ComparisonWarning, stacklevel=4)
            self._worker, self._worker_pid = comparer, os.getpid()
        return self._worker  # type: ignore[return-value]

    def _layout_comparison(self, grid: LayoutGrid | Gathering | None) -> LayoutComparison | None:
        """The frame's layout comparison with the map, started beside LoST-X (:meth:`_comparer`) where it compares
        every map frame (None without a layout)."""
        if grid is None or self._live is None:
            return None
        cfg = self.config.layout
        n = self.map.n_frames
        every = n <= EVERY_FRAME_MAX
        # Where the sequence costs are looked up (a city map) the grids are compared only where the localizer looks,
        # read from the map as they are asked for; below that the costs, and so the layout, cover every map frame.
        stored = looks_up_costs(self.config.sequence, n) and not every
        grids = self.map.stored_grids if stored else self.map.layout_stack
        comparison = LayoutComparison(grid, grids(), self._layout_weights, self._layout_shifts, cfg.min_cells,
                                      grid_compare.TURNS, grids("opposite"))
        if every:
            comparison.start(self._comparer(comparison))
        return comparison

    def _comparison(self, grid: LayoutGrid | Gathering | None) -> LayoutComparison | None:
        """The comparison of ``grid`` with the map: the one started when its frame was described (in this process:
        a forked child has no thread or process comparing for it), or a new one."""
        started, self._started = self._started, None
        if started is not None and started[0] is grid and started[2] == os.getpid():
            return started[1]
        return self._layout_comparison(grid)


class AppearanceDistances:
    """The appearance cue's cosine distances of one query's GeM descriptor to the map frames asked for (None: every
    one), the whole map's computed at most once."""

    def __init__(self, refmap: ReferenceMap, query: np.ndarray) -> None:
        self.map, self.query = refmap, np.asarray(query, dtype=np.float32)
        self._every: np.ndarray | None = None

    def __call__(self, refs: np.ndarray | None = None) -> np.ndarray:
        if self._every is None and refs is None:
            self._every = cosine_distances(self.query, self.map.appearance)  # type: ignore[arg-type]
        if self._every is not None:
            return self._every if refs is None else self._every[refs]
        return cosine_distances(self.query, self.map.appearance_rows(refs))


def combined_result(result: MatchResult, weights: dict[str, float], top_k: int, exclusion: int) -> MatchResult:
    """``result`` (LoST-X's answer under one heading, its cues attached) ranked by its cues combined with ``weights``
    (:class:`CombinedScores`): the ``top_k`` best map frames of the combined score (every map frame where the map is
    small enough to score them all, else the search's nearest and LoST-X's candidates), its margin (the combined
    score's lead, in the cues' standard deviations) as the confidence. A result with one cue is returned as it is."""
    cues = result.cues
    if cues is None or len(cues.present()) < 2:
        return result
    lost = cues.lostx
    combined = without(CombinedScores(cues, weights), lost.removed)
    if set(combined.used) == {"lostx"}:
        return dataclasses.replace(result, weights=dict(combined.used))
    n = lost.n_frames
    pool = np.arange(n) if n <= EVERY_FRAME_MAX else np.union1d(result.nearest, result.candidates)  # type: ignore[arg-type]
    if lost.removed is not None:
        pool = pool[(pool < lost.removed.start) | (pool >= lost.removed.stop)]
    scores = combined.at(pool)
    order = np.lexsort((pool, scores))[:top_k]
    candidates, ranked = pool[order], scores[order]
    counts = {int(r): int(c) for r, c in zip(result.candidates, result.n_matches)} if result.n_matches is not None else {}
    return dataclasses.replace(
        result, candidates=candidates, distances=lost.distances(candidates), scores=ranked,
        confidence=margin(candidates, ranked, exclusion),
        n_matches=np.array([counts.get(int(c), 0) for c in candidates]), map_scores=combined,
        weights=dict(combined.used))


def _around(n: int, index: int, radius: int) -> slice:
    return slice(max(0, index - radius), min(n, index + radius + 1))


WORST_SAMPLE = 4096
"""Map frames (evenly spaced, and the verified candidates) whose worst score stands in for the removed frames'
score (every frame of a map up to this size)."""


def without(scores: MapScores, removed: slice | None) -> MapScores:
    """``scores`` with the ``removed`` map frames given the worst score of the others."""
    if removed is None:
        return scores
    n = scores.n_frames
    sample = np.union1d(np.linspace(0, n - 1, min(n, WORST_SAMPLE)).astype(np.int64), scores.known)
    sample = sample[(sample < removed.start) | (sample >= removed.stop)]
    worst = float(np.max(scores.at(sample))) if len(sample) else 0.0
    return dataclasses.replace(scores, removed=removed, removed_score=worst)


def map_scores(distance_of: Callable[[np.ndarray | None], np.ndarray], n_frames: int, shortlist: np.ndarray,
               distances: np.ndarray, verified: np.ndarray, scoring: str, removed: slice | None = None) -> MapScores:
    """Extend the verified scores of the shortlist to every reference frame.

    Verification scores exist for the top k only. Elsewhere the score is imputed
    from the descriptor distance: the verified scores are the distance times a
    verification factor (Eq. 4 family), and an unverified frame gets the
    shortlist's median factor (for plain Eq. 4, whose score ignores the distance,
    the shortlist's median score). A candidate without usable correspondences
    gets the imputed score too.
    """
    finite = np.isfinite(verified)
    factor, constant = 1.0, None
    if scoring == "eq4":
        constant = float(np.median(verified[finite])) if finite.any() else 1.0
    else:
        d = np.maximum(distances, 1e-12)
        factor = float(np.median(verified[finite] / d[finite])) if finite.any() else 1.0
    order = np.argsort(shortlist[finite])
    return without(MapScores(distance_of, n_frames, factor=factor, constant=constant, known=shortlist[finite][order],
                             known_scores=np.asarray(verified[finite], dtype=np.float64)[order]), removed)


def _with_classes(config: LostConfig, classes: dict[str, list[str]]) -> LostConfig:
    """The LoST settings with the classes a map was built with."""
    return dataclasses.replace(config, classes={k: tuple(v) for k, v in classes.items()})
