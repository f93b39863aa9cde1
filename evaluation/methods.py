"""``lostx eval`` as a Python API: several methods on one reference/query pair, single-frame and sequence.

Methods (all on the same frames and the same ground truth):

- ``lostx``: LoST descriptor search + spatial layout verification (the paper's LoST-X), with the layout of the
  place on the road where the frames have a camera geometry (lostx.core.layout) and appearance, each cue weighted by
  what it earns on the stream (lostx.core.route.agreement);
- ``lostx-nolayout``: LoST-X alone; ``layout``: the layout alone (its weight beside LoST-X made overwhelming);
- ``lost``: the LoST descriptor alone (the paper's "LoST");
- ``appearance``: GeM pooling of the same network's features, cosine distance (an
  appearance baseline on the same network, as the paper compares against);
- ``thumbnail``: SeqSLAM's patch-normalised thumbnails, sum of absolute differences.

Each runs single-frame and through the same sequence filter and tracker
(:meth:`Localizer.update`). In sequence mode a query's candidate list for
Recall@N is the sequence answer followed by its single-frame candidates.

The network runs once per image: the reference side is kept as a LoST map
(it holds the appearance descriptors too) and the query side as a file of
per-frame descriptions, both in a cache folder keyed by the images, the model
and the settings, so re-running the metrics does not re-run the network.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from tqdm import tqdm

from lostx.core.backbones import Backbone, load_backbone
from lostx.core.build import build_map
from lostx.core.config import Config
from lostx.core.match.scores import MapScores
from lostx.core.describe.describer import LostDescriber
from lostx.core.errors import InputError, MapError
from lostx.core.frame import Frame
from lostx.core.describe.keypoints import KeypointEvidence
from lostx.core.describe.reduce import reduced_dims
from lostx.core.layout.grid import as_grid, pack, unpack
from lostx.core.localizer import Localizer
from lostx.core.match.matcher import FrameMatch, MatchResult, PlaceMatcher, QueryDescription, uniqueness
from lostx.core.maps.refmap import ReferenceMap
from lostx.core.match.search import cosine_distances, top_k
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.replay.folder import Traverse

from .catalogue import METHODS, MODES
from .datasets import DatasetPair
from .groundtruth import GroundTruth
from .metrics import (
    Evaluation, OperatingPoint, ReliabilityBin, evaluate_tolerances, operating_point, reliability,
)
from .significance import PairedComparison, paired_comparison

DEFAULT_TOLERANCES = {"frames": (0.0, 1.0, 2.0), "m": (5.0, 10.0, 20.0, 40.0, 80.0)}
NETWORK_METHODS = ("lostx", "lostx-nolayout", "layout", "lost", "appearance")
HEADING_METHODS = ("lostx", "lostx-nolayout", "layout", "thumbnail")
"""The methods that can tell the headings apart (a verification mirrored or not, a flipped thumbnail);
pooled descriptors (LoST alone, GeM) are the same both ways."""
LAYOUT_METHODS = ("lostx-nolayout", "layout")
"""The methods that differ from ``lostx`` only where the frames have a layout."""
LAYOUT_ALONE = {"lostx": 0.01, "layout": 1.0}
"""The fixed cue weights of the ``layout`` method: LoST-X only breaks the layout's ties."""


@dataclass
class Run:
    """One method in one mode: an answer, a confidence and a candidate list per query."""

    method: str
    mode: str
    predictions: np.ndarray
    confidences: np.ndarray
    candidates: np.ndarray
    headings: np.ndarray | None = None
    """Per query, the heading the localizer reported ('same' / 'opposite')."""
    localized: np.ndarray | None = None
    """Per query, whether the answer was ``localized``."""
    evaluations: list[Evaluation] = field(default_factory=list)
    """The oracle view: every threshold tried afterwards, per tolerance."""
    deployed: list[OperatingPoint] = field(default_factory=list)
    """The deployed view: the ``localized`` answers, per tolerance."""
    reliability: list[list[ReliabilityBin]] = field(default_factory=list)
    """Binned confidence against measured precision, per tolerance."""
    true_heading: str | None = None
    too_short: str | None = None
    """Why no answer could be ``localized`` on this map (:meth:`Calibration.too_short`), or None."""

    def extras(self, k: int) -> dict[str, float | int]:
        """The deployed numbers and the heading accuracy, for the report entry of tolerance ``k``."""
        out: dict[str, float | int] = dict(self.deployed[k].summary()) if self.deployed else {}
        if self.headings is not None and self.true_heading is not None:
            right = self.headings == self.true_heading
            out["heading_right"] = float(right.mean())
            localized = self.localized if self.localized is not None else np.zeros(len(right), bool)
            out["heading_right_localized"] = float(right[localized].mean()) if localized.any() else float("nan")
        return out

    @property
    def label(self) -> str:
        return f"{METHODS[self.method]}, {self.mode}"


def _fingerprint(traverse: Traverse, extra: dict) -> str:
    motion = {"geometry": traverse.geometry.to_dict() if traverse.geometry is not None else None,
              "odometry": None if traverse.odometry is None else hashlib.sha256(traverse.odometry.tobytes()).hexdigest()}
    payload = json.dumps({"frames": traverse.fingerprint(), **motion, **extra}, sort_keys=True, default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def _settings_key(config: Config, backbone: Backbone) -> dict:
    lost = dataclasses.asdict(config.lost)
    info = backbone.info
    # One model file described twice (another feature tensor or input size) gives other features.
    features = [info.feature_tensor, info.feature_dim, list(info.grid)]
    # The frames are prepared per camera before the network (field of view, rows ignored, fitting).
    geometry = {"camera": dataclasses.asdict(config.camera), "fit": config.backbone.fit}
    # The layout's grids and the motion they are gathered with.
    layout = {"layout": dataclasses.asdict(config.layout), "motion": dataclasses.asdict(config.motion)}
    return {"model": info.model_md5, "backbone": info.name, "features": features, "lost": lost, **geometry, **layout}


def reference_maps(pair: DatasetPair, config: Config, cache: Path, methods: Sequence[str],
                   backbone: Backbone | None, progress: bool) -> dict[str, ReferenceMap]:
    """The reference side as maps: a LoST map (network methods) and a thumbnail map, built once and cached."""
    maps: dict[str, ReferenceMap] = {}
    meta = {"camera": pair.reference.camera, "image_root": str(pair.reference.root.resolve())}
    if any(m in NETWORK_METHODS for m in methods):
        assert backbone is not None
        settings = {"kind": "lost", **_settings_key(config, backbone)}
        reduced = reduced_dims(config.verify, backbone.info.feature_dim)
        if reduced is not None:  # maps whose keypoint descriptors are kept whole keep their earlier key
            settings["reduced_keypoints"] = reduced
        key = _fingerprint(pair.reference, settings)
        maps["lost"] = _cached_map(cache / f"reference-lost-{key}", pair.reference, config,
                                   LostDescriber(backbone, config.lost), meta, progress, "describing references")
    if "thumbnail" in methods:
        key = _fingerprint(pair.reference, {"kind": "thumbnail"})
        maps["thumbnail"] = _cached_map(cache / f"reference-thumbnail-{key}", pair.reference, config,
                                        ThumbnailDescriber(), meta, progress, "reference thumbnails")
    return maps


def _cached_map(path: Path, traverse: Traverse, config: Config, describer, meta: dict, progress: bool,
                label: str) -> ReferenceMap:
    if (path / "manifest.json").is_file():
        try:
            return ReferenceMap.open(path)
        except MapError:
            pass  # a damaged cache entry is rebuilt
    build_map(traverse, path, config, describer, meta, overwrite=True, total=len(traverse), progress=progress,
              label=label)
    return ReferenceMap.open(path)


def query_descriptions(traverse: Traverse, matcher: PlaceMatcher, cache: Path, config: Config,
                       progress: bool) -> list[QueryDescription]:
    """Every query frame through the network once; cached as one .npz keyed by the images and settings."""
    backbone = matcher.describer.backbone  # type: ignore[union-attr]
    key = _fingerprint(traverse, {"kind": "queries", **_settings_key(config, backbone)})
    path = cache / f"queries-{key}.npz"
    if path.is_file():
        try:
            return _load_descriptions(path)
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache entry is recomputed
    out = []
    for frame in tqdm(traverse, total=len(traverse), desc="describing queries", unit="frame",
                      disable=not progress, leave=False):
        described = matcher.describe(frame, appearance=True)
        # Kept as the cache stores it (not the frame's whole features): the same on a first run and a cached one.
        out.append(dataclasses.replace(described, evidence=described.evidence.sparse()))
    _save_descriptions(path, out)
    return out


def _save_descriptions(path: Path, items: list[QueryDescription]) -> None:
    ev = KeypointEvidence.stack([d.evidence for d in items])
    slots = np.cumsum([0] + [len(d.evidence.slot_keys) for d in items])
    arrays = {
        "descriptor": np.stack([d.descriptor for d in items]),
        "appearance": np.stack([d.appearance for d in items]),
        "labels": np.stack([d.labels for d in items]),
        "network": np.array([d.timings.get("network", 0.0) for d in items]),
        "progress": np.array([np.nan if d.progress is None else d.progress for d in items]),
        "gathered": np.array([np.nan if d.gathered is None else d.gathered for d in items]),
        "keypoints": ev.keypoints, "evidence_labels": ev.labels, "slot_keys": ev.slot_keys,
        "slot_offsets": ev.slot_offsets, "channels": ev.channels, "values": ev.values, "slot_norms": ev.slot_norms,
        "frame_slots": slots, "grid": np.array(ev.grid), "feature_dim": np.array(ev.feature_dim),
    }
    if all(d.layout is not None for d in items):
        grids = [as_grid(d.layout) for d in items]  # type: ignore[arg-type]
        packed = [pack(grid) for grid in grids]
        arrays["layout_values"] = np.stack([v for v, _ in packed])
        arrays["layout_mask"] = np.stack([m for _, m in packed])
        arrays["layout_shape"] = np.array(grids[0].mask.shape)
    tmp = path.with_name(path.name + ".partial.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def _load_descriptions(path: Path) -> list[QueryDescription]:
    with np.load(path) as a:
        data = {k: a[k] for k in a.files}
    grid = tuple(int(v) for v in data["grid"])
    n_loc = grid[0] * grid[1]
    out = []
    for i in range(len(data["descriptor"])):
        lo, hi = int(data["frame_slots"][i]), int(data["frame_slots"][i + 1])
        e0, e1 = int(data["slot_offsets"][lo]), int(data["slot_offsets"][hi])
        evidence = KeypointEvidence(
            keypoints=data["keypoints"][i : i + 1], labels=data["evidence_labels"][i : i + 1],
            slot_keys=data["slot_keys"][lo:hi] - i * n_loc, slot_offsets=data["slot_offsets"][lo : hi + 1] - e0,
            channels=data["channels"][e0:e1], values=data["values"][e0:e1], slot_norms=data["slot_norms"][lo:hi],
            grid=grid, feature_dim=int(data["feature_dim"]),
        )
        layout = (unpack(data["layout_values"][i], data["layout_mask"][i], tuple(data["layout_shape"]))
                  if "layout_values" in data else None)
        progress = float(data["progress"][i]) if np.isfinite(data["progress"][i]) else None
        gathered = float(data["gathered"][i]) if np.isfinite(data["gathered"][i]) else None
        out.append(QueryDescription(data["descriptor"][i], data["appearance"][i], evidence, data["labels"][i],
                                    {"network": float(data["network"][i]), "descriptor": 0.0}, layout, progress,
                                    gathered))
    return out


def appearance_result(query: np.ndarray, refs: np.ndarray, config: Config) -> FrameMatch:
    """Single-frame answer of the appearance baseline: cosine distance of GeM descriptors (pooled, so
    it cannot tell the headings apart)."""
    distances = cosine_distances(query, refs)
    nearest = top_k(distances, max(config.verify.top_k, config.sequence.nearest))
    order = nearest[: config.verify.top_k]
    ranked = distances[order]
    return FrameMatch.either(MatchResult(order, ranked, ranked,
                                         uniqueness(order, ranked, config.verify.uniqueness_exclusion),
                                         map_scores=MapScores.of_array(distances), nearest=nearest, timings={}))


def single_results(method: str, pair: DatasetPair, maps: dict[str, ReferenceMap], config: Config,
                   descriptions: list[QueryDescription] | None, backbone: Backbone | None,
                   progress: bool) -> list[FrameMatch]:
    if method == "thumbnail":
        matcher = PlaceMatcher(maps["thumbnail"], config)
        frames = tqdm(pair.query, total=len(pair.query), desc="query thumbnails", unit="frame", disable=not progress,
                      leave=False)
        return [matcher.match(f.image) for f in frames]
    assert descriptions is not None
    if method == "appearance":
        refs = maps["lost"].appearance
        if refs is None:
            raise MapError(f"{maps['lost'].path} holds no appearance descriptors; rebuild it")
        return [appearance_result(d.appearance, refs, config) for d in descriptions]
    matcher = PlaceMatcher(maps["lost"], method_config(method, config), backbone)
    return [matcher.match_description(d) for d in descriptions]


def method_config(method: str, config: Config) -> Config:
    """The settings a method runs with: LoST alone does not verify; LoST-X without the layout is LoST-X alone (the
    layout and appearance off); the layout alone outweighs LoST-X, with appearance off."""
    verify = dataclasses.replace(config.verify, enabled=method != "lost")
    layout, cues = config.layout, config.cues
    if method == "lostx-nolayout":
        layout = dataclasses.replace(layout, enabled="off")
        cues = dataclasses.replace(cues, appearance=False)
    elif method == "layout":
        cues = dataclasses.replace(cues, appearance=False, weights=dict(LAYOUT_ALONE))
    return dataclasses.replace(config, verify=verify, layout=layout, cues=cues)


def runs_of(method: str, matches: list[FrameMatch], refmap: ReferenceMap, query: Traverse, config: Config,
            backbone: Backbone | None, modes: Sequence[str]) -> list[Run]:
    """Each mode through the localizer's own stages (heading, and the sequence filter and tracker)."""
    config = method_config(method, config)
    out = []
    for mode in modes:
        sequence = dataclasses.replace(config.sequence, enabled=mode == "sequence")
        localizer = Localizer(refmap, dataclasses.replace(config, sequence=sequence), backbone)
        too_short = localizer.calibration.too_short(sequence.enabled, config.decision.min_confidence)
        estimates = []
        for i, frame_matches in enumerate(matches):
            # These stages read the frame's id, clock, camera and its mounting, never its pixels.
            stamp = float(query.timestamps[i]) if query.timestamps is not None else None
            frame = Frame(id=i, image=np.zeros((1, 1, 3), np.uint8), timestamp=stamp, camera=query.camera,
                          geometry=query.geometry)
            estimates.append(localizer.update(frame, frame_matches))
        lists = [[e.match_index] + [c.index for c in e.candidates if c.index != e.match_index] for e in estimates]
        out.append(Run(method, mode, np.array([e.match_index for e in estimates]),
                       np.array([e.confidence for e in estimates]), _candidate_lists(lists),
                       headings=np.array([e.heading for e in estimates]) if method in HEADING_METHODS else None,
                       localized=np.array([e.state == "localized" for e in estimates]), too_short=too_short))
    return out


def paired_comparisons(runs: Sequence[Run], truths: Sequence[GroundTruth]
                       ) -> list[tuple[Run, Run, GroundTruth, PairedComparison, PairedComparison]]:
    """Recall@1's answers compared query by query and in stretches of neighbouring queries, at every tolerance: each
    run against the first method's run in the same mode, and each sequence run against its method's single frame."""
    pairs = []
    for run in runs:
        first = next((r for r in runs if r.mode == run.mode), None)
        if first is not None and first is not run:
            pairs.append((run, first))
        single = next((r for r in runs if r.method == run.method and r.mode == "single"), None)
        if run.mode == "sequence" and single is not None:
            pairs.append((run, single))
    out = []
    for truth in truths:
        for a, b in pairs:
            right = truth.is_correct(a.predictions), truth.is_correct(b.predictions)
            out.append((a, b, truth, paired_comparison(*right), paired_comparison(*right, stretches=True)))
    return out


def _candidate_lists(lists: Sequence[Sequence[int]], k: int = 10) -> np.ndarray:
    out = np.full((len(lists), k), -1, dtype=np.int64)
    for i, row in enumerate(lists):
        row = list(row)[:k]
        out[i, : len(row)] = row
    return out


def evaluate_pair(
    pair: DatasetPair,
    config: Config,
    cache: Path,
    methods: Sequence[str] = tuple(METHODS),
    modes: Sequence[str] = MODES,
    tolerances: Sequence[float] | None = None,
    unit: str | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
    true_heading: str | None = None,
) -> tuple[list[Run], list[GroundTruth]]:
    """Run every method in every mode and evaluate each at every tolerance: the oracle view (every
    threshold tried afterwards) and the deployed one (the ``localized`` answers). ``true_heading``,
    where known, scores the heading the localizer reported."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(METHODS)}")
    unit = unit or pair.default_unit
    tolerances = list(tolerances) if tolerances else list(DEFAULT_TOLERANCES[unit])
    truths = pair.ground_truth(tolerances, unit)  # fails early on a pair without ground truth
    cache.mkdir(parents=True, exist_ok=True)
    backbone = load_backbone(config.backbone) if any(m in NETWORK_METHODS for m in methods) else None
    start = time.perf_counter()
    maps = reference_maps(pair, config, cache, methods, backbone, progress)
    descriptions = None
    if backbone is not None:
        describer = PlaceMatcher(maps["lost"], config, backbone)
        descriptions = query_descriptions(pair.query, describer, cache, config, progress)
    log(f"described {len(pair.reference)} reference and {len(pair.query)} query frames "
        f"in {time.perf_counter() - start:.1f} s (cache: {cache})")
    if "lost" in maps and maps["lost"].layout_settings is None and any(m in LAYOUT_METHODS for m in methods):
        log("the reference frames carry no camera geometry: no layout, so " + " and ".join(
            m for m in methods if m in LAYOUT_METHODS) + " are left out (they would be LoST-X)")
        methods = [m for m in methods if m not in LAYOUT_METHODS]
    runs: list[Run] = []
    for method in methods:
        results = single_results(method, pair, maps, config, descriptions, backbone, progress)
        refmap = maps["thumbnail" if method == "thumbnail" else "lost"]
        for run in runs_of(method, results, refmap, pair.query, config, backbone, modes):
            run.evaluations = evaluate_tolerances(run.predictions, run.confidences, truths, run.candidates,
                                                  higher_is_better=True)
            run.deployed = [operating_point(run.predictions, run.localized, truth) for truth in truths]
            run.reliability = [reliability(run.confidences, truth.is_correct(run.predictions)) for truth in truths]
            run.true_heading = true_heading
            runs.append(run)
    return runs, truths
