"""The two nuScenes front/rear scenes as the studies run them: pairings of the cameras, runs at 2 and 1 Hz, each run's
queries described once and matched with any settings, and the rule every setting is chosen by.

Scenes: ``scene-0523`` (Boston, a straight road and a roundabout) and ``scene-0916`` (Singapore, a car park, mostly
turns), ../shared/data/nuscenes-frontrear. Pairings: S1 maps the rear camera and queries the front one (the paper's
setup); S2 maps the front camera and plays the rear frames backwards (the road driven the other way); S3 maps the front
camera and queries the rear frames as recorded; S4 maps the rear camera and plays the front frames backwards. The
heading is opposite in all four and is not declared. Recall@1 at 7.5 m of the look-at points (15 m along each camera's
axis), counted over the queries that have a counterpart within it.

The rule: a setting's figure on a scene is its Recall@1 summed over S1 and S2, single frame and sequence, at 2 Hz; a
setting is chosen on one scene and reported on the other, both ways; the default is the setting that falls least short
of the family's best on its worse scene (each scene judged against what can be reached there), changed only where that
gains more than two queries (:func:`rule`).
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from lostx.core import Config, Localizer, LostDescriber, ReferenceMap, build_map, load_backbone
from lostx.core.match.matcher import FrameMatch, PlaceMatcher, QueryDescription
from lostx.core.paths import data_dir
from lostx.replay.dataset import SourceOptions, open_traverse
from lostx.replay.folder import Traverse

SCENES = ("scene-0523", "scene-0916")
PAIRINGS = {"S1": ("rear", "front", False), "S2": ("front", "rear", True), "S3": ("front", "rear", False),
            "S4": ("rear", "front", True)}
"""Map camera, query camera, queries played backwards."""
SAME = {"S0": ("front", "front", False)}
"""For contrast, a same-direction pairing: the front camera's even frames as the map, its odd frames as the queries."""
TRUTH = {**{p: "opposite" for p in PAIRINGS}, **{p: "same" for p in SAME}}
HEADLINE = ("S1", "S2")
RATES = {"2 Hz": 1, "1 Hz": 2}
"""Every n-th frame: the recorded rate, and every other frame (the map's and the queries', both halves summed)."""
MODES = ("single", "sequence")
TOLERANCE = 7.5


def variant(base: Config | None = None, **sections: dict) -> Config:
    """``base`` (the defaults) with some settings of some sections changed."""
    config = base or Config()
    for name, values in sections.items():
        config = dataclasses.replace(config, **{name: dataclasses.replace(getattr(config, name), **values)})
    return config


@dataclass(frozen=True)
class Run:
    """One run of a pairing: the map's frames and the queries (in the order played, camera removed), with the
    look-at points of both."""

    scene: str
    pairing: str
    start: int
    every: int
    map_frames: Traverse
    frames: list
    looks: np.ndarray
    map_looks: np.ndarray


def runs(scene: str, pairing: str, every: int = 1) -> list[Run]:
    """The runs of a pairing at every ``every``-th frame: one from each of the first ``every`` frames."""
    map_camera, query_camera, reverse = {**PAIRINGS, **SAME}[pairing]
    root = data_dir() / "nuscenes-frontrear" / scene
    mapped, recorded = open_traverse(root / map_camera), open_traverse(root / query_camera)
    map_looks = open_traverse(root / map_camera, options=SourceOptions(look_at=15.0)).positions
    looks = open_traverse(root / query_camera, options=SourceOptions(look_at=15.0)).positions
    out = []
    if pairing in SAME:
        rows, odd = list(range(0, len(mapped), 2)), list(range(1, len(mapped), 2))
        queries = recorded.subset(odd)
        return [Run(scene, pairing, 0, 2, mapped.subset(rows), [dataclasses.replace(f, camera=None) for f in queries],
                    looks[queries.rows], map_looks[rows])]
    for start in range(every):
        rows = list(range(start, len(mapped), every))
        map_frames, queries = (mapped, recorded) if every == 1 else (mapped.subset(rows), recorded.subset(rows))
        if reverse:
            queries = queries.reversed()
        out.append(Run(scene, pairing, start, every, map_frames, [dataclasses.replace(f, camera=None) for f in queries],
                       looks[queries.rows], map_looks[rows]))
    return out


@dataclass
class Counts:
    """One mode's figures over some runs."""

    counted: int = 0
    right: int = 0
    frames: int = 0
    heading: int = 0
    """Frames whose heading is right (:data:`TRUTH`)."""
    sure: int = 0
    """Of them, those at least ``heading.min_confidence`` sure."""
    answers: list[bool] = field(default_factory=list)
    """Whether each counted query was answered right, in order."""
    confidences: list[float] = field(default_factory=list)
    """Each frame's heading confidence."""
    right_headings: list[bool] = field(default_factory=list)
    """Whether each frame's heading is right."""
    disagree: int = 0

    def add(self, other: "Counts") -> None:
        for name in ("counted", "right", "frames", "heading", "sure", "disagree"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.answers += other.answers
        self.confidences += other.confidences
        self.right_headings += other.right_headings

    @property
    def figure(self) -> str:
        return f"{self.right}/{self.counted}"


Patch = Callable[[], AbstractContextManager]


class Study:
    """Maps and query descriptions built once per scene, pairing, run and map-building settings; any number of
    settings run on them."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.backbone = load_backbone()
        self._maps: dict[str, ReferenceMap] = {}
        self._described: dict[str, list[QueryDescription]] = {}
        warnings.simplefilter("ignore")

    def refmap(self, run: Run, config: Config) -> ReferenceMap:
        """The run's map, built as ``lostx map build`` builds it: with the layout (and the map's motion) whatever
        ``config.layout.enabled`` says; a setting that turns the layout off does so when matching, as ``lostx eval``
        does for LoST-X without the layout."""
        config = variant(config, layout={"enabled": Config().layout.enabled})
        key = json.dumps([run.scene, {**PAIRINGS, **SAME}[run.pairing][0], run.pairing in SAME, run.start, run.every,
                          dataclasses.asdict(config.layout), dataclasses.asdict(config.motion)], default=str)
        if key not in self._maps:
            path = self.root / f"map-{len(self._maps)}"
            build_map(run.map_frames, path, config, LostDescriber(self.backbone, config.lost), progress=False)
            self._maps[key] = ReferenceMap.open(path)
        return self._maps[key]

    def matches(self, run: Run, config: Config, patch: Patch = nullcontext) -> tuple[ReferenceMap, list[FrameMatch]]:
        """The run's queries matched with ``config`` (described once per map-building settings and patch: a patch
        may change how frames are described). Like the map, the queries are described with the layout, as ``lostx
        eval`` describes them once for every method; a setting that turns the layout off does so when matching."""
        refmap = self.refmap(run, config)
        described = variant(config, layout={"enabled": Config().layout.enabled})
        key = json.dumps([run.scene, run.pairing, run.start, run.every, dataclasses.asdict(described.layout),
                          dataclasses.asdict(config.motion), dataclasses.asdict(config.lost),
                          None if patch is nullcontext else id(patch)], default=str)
        if key not in self._described:
            describer = PlaceMatcher(refmap, described, self.backbone)
            self._described[key] = [describer.describe(f, appearance=True) for f in run.frames]
        matcher = PlaceMatcher(refmap, config, self.backbone)
        return refmap, [matcher.match_description(d) for d in self._described[key]]

    def counts(self, config: Config, scene: str, pairing: str, every: int = 1,
               patch: Patch = nullcontext) -> dict[str, Counts]:
        """Per mode, the figures of ``config`` over the runs of a pairing, summed."""
        total = {mode: Counts() for mode in MODES}
        for run in runs(scene, pairing, every):
            with patch():
                refmap, matches = self.matches(run, config, patch)
                for mode, c in scored(refmap, run, matches, config, self.backbone).items():
                    total[mode].add(c)
        return total

    def figures(self, config: Config, rates: tuple[str, ...] = ("2 Hz",), pairings: tuple[str, ...] = tuple(PAIRINGS),
                patches: tuple[Patch, ...] = (nullcontext,)) -> dict[str, dict[str, dict[str, dict[str, Counts]]]]:
        """scene -> rate -> pairing -> mode -> Counts, summed over the conditions ``patches`` make."""
        out: dict = {}
        for scene in SCENES:
            out[scene] = {}
            for rate in rates:
                out[scene][rate] = {}
                for p in pairings:
                    total = {mode: Counts() for mode in MODES}
                    for patch in patches:
                        for mode, c in self.counts(config, scene, p, RATES[rate], patch).items():
                            total[mode].add(c)
                    out[scene][rate][p] = total
        return out


def scored(refmap: ReferenceMap, run: Run, matches: list[FrameMatch], config: Config, backbone) -> dict[str, Counts]:
    """The run's matches through localizers of ``config``, single frame and with the sequence filter."""
    distances = [np.hypot(*(run.map_looks - look).T) for look in run.looks]
    out = {}
    for mode in MODES:
        localizer = Localizer(refmap, variant(config, sequence={"enabled": mode == "sequence"}), backbone)
        counts = Counts()
        for frame, match, distance in zip(run.frames, matches, distances):
            estimate = localizer.update(frame, match)
            right_heading = estimate.heading == TRUTH[run.pairing]
            counts.frames += 1
            counts.heading += right_heading
            counts.sure += right_heading and estimate.heading_confidence >= config.heading.min_confidence
            counts.confidences.append(estimate.heading_confidence)
            counts.right_headings.append(right_heading)
            counts.disagree += estimate.disagrees
            if distance.min() <= TOLERANCE:
                right = bool(distance[estimate.match_index] <= TOLERANCE)
                counts.counted += 1
                counts.right += right
                counts.answers.append(right)
        out[mode] = counts
    return out


def figure(results: dict, scene: str, rate: str = "2 Hz") -> int:
    """A setting's figure on a scene: Recall@1 summed over the headline pairings run, single frame and sequence."""
    return sum(results[scene][rate][p][m].right for p in HEADLINE if p in results[scene][rate] for m in MODES)


def chosen_on(results: dict[str, dict], scene: str) -> str:
    """The setting with the best figure on ``scene``; a tie keeps the default (nothing shows a change is better),
    else the first listed."""
    names = list(results)
    return max(names, key=lambda name: (figure(results[name], scene), "(default" in name, -names.index(name)))


NOISE = 2
"""Queries: a difference of two is noise."""


def carries(results: dict[str, dict]) -> bool:
    """Whether a family's choice carries from one scene to the other: the setting chosen on each scene falls at most
    :data:`NOISE` queries short of the best on the other. A family that does not is no setting to offer: whichever
    way a user chose it on their road, another road could lose by it."""
    return all(max(figure(r, other) for r in results.values()) - figure(results[chosen_on(results, on)], other) <= NOISE
               for on in SCENES for other in SCENES if other != on)


def regret(results: dict[str, dict], name: str) -> int:
    """A setting's worse loss over the scenes: how many queries it falls short of the family's best on each."""
    return max(max(figure(r, s) for r in results.values()) - figure(results[name], s) for s in SCENES)


def rule(results: dict[str, dict]) -> str:
    """The default the rule gives: the setting whose worse loss against the family's best, over the two scenes, is
    least; the default as it stands unless that gains more than :data:`NOISE` queries (ties: the better sum)."""
    names = list(results)
    best = min(names, key=lambda name: (regret(results, name), -sum(figure(results[name], s) for s in SCENES),
                                        names.index(name)))
    current = next((name for name in names if "(default" in name), None)
    if current is not None and regret(results, current) - regret(results, best) <= NOISE:
        return current
    return best
