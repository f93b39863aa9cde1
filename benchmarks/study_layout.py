"""Every variant of the layout measured on the nuScenes front/rear frames, and which choices carry from one
setup to the other (docs/opposite-view.md).

S1: map from the rear camera, queries from the front one; S2: map from the front camera, queries the rear
frames played backwards. The heading is not declared (the frames' camera is removed). Recall@1 at 7.5 m of the
look-at points, counts of the queries that have a counterpart; single frame and with the sequence filter.
Each variant also at 1 Hz (every other frame of the map and the queries, both halves summed). For each family of
variants the choice made on S1 is reported on S2 and the other way round: chosen at the recorded rate, and over
both rates.

    python benchmarks/study_layout.py [--families weight,window,...] [--out benchmarks/results/study_layout.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import json
import tempfile
import warnings
from contextlib import nullcontext
from pathlib import Path
from typing import Callable
from unittest import mock

import numpy as np

from common import RESULTS, print_table, write_json
from lostx.core import Config, Localizer, LostDescriber, ReferenceMap, build_map, load_backbone
from lostx.core.config import LayoutConfig
from lostx.core.layout.curve import faces_forward, opposite_turns, turned_about_centre
from lostx.core.layout.describer import map_grid, spread
from lostx.core.layout.grid import Gathering, accumulate
from lostx.core.match.combined import CombinedScores, LayoutScores
from lostx.core.match.matcher import PlaceMatcher
from lostx.core.match.scores import MapScores
from lostx.core.paths import data_dir
from lostx.evaluation.significance import paired_comparison
from lostx.replay.dataset import SourceOptions, open_traverse
from lostx.replay.folder import Traverse

SCENE = data_dir() / "nuscenes-frontrear" / "scene-0523"
SETUPS = {"S1": ("rear", "front", False), "S2": ("front", "rear", True)}
"""Map camera, query camera, queries played backwards."""
MODES = ("single", "sequence")
ENTERED = 10
"""Queries counted as just after entering the map, where a run starts off it: the first this many with a counterpart."""
TOLERANCE = 7.5


def variant(**sections: dict) -> Config:
    config = Config()
    for name, values in sections.items():
        config = dataclasses.replace(config, **{name: dataclasses.replace(getattr(config, name), **values)})
    return config


AS_SEEN = dataclasses.replace(Config(), layout=dataclasses.replace(Config().layout))
"""The defaults, with the map's grids compared under the opposite heading as the map's camera saw them, turned 180
degrees (as maps built before the other ends were stored are): told apart from the defaults by identity."""

FACED = dataclasses.replace(Config(), layout=dataclasses.replace(Config().layout))
"""The defaults, with the other end's grid gathering only the ``query_travel`` metres of route on the side the map
camera faces, the road a query at that end has driven (a one-sided gathering against the query's one-sided one),
instead of ``map_travel`` metres either side (told apart by identity)."""


def _gathered_faced(frames: list, index: int, config: LayoutConfig) -> tuple:
    poses = np.stack([f.pose for f in frames])
    turn = float(opposite_turns(poses, config.centre, np.array([index]))[0])
    travelled = np.array([f.travelled for f in frames])
    reach = faces_forward(poses) * config.query_travel
    low, high = sorted((travelled[index], travelled[index] + reach))
    chosen = spread(travelled, low, high, config.max_frames, index)
    other = accumulate([frames[i].points for i in chosen], poses[chosen],
                       turned_about_centre(poses[index], turn, config.centre), config)
    return map_grid(frames, index, config), other


GATHERED = dataclasses.replace(Config(), layout=dataclasses.replace(Config().layout))
"""The defaults, with the layout's weight times the metres the query's grid gathered over ``query_travel`` (from a
quarter, a frame alone, to 1) (told apart by identity)."""

OBSERVED = dataclasses.replace(Config(), layout=dataclasses.replace(Config().layout))
"""The defaults, with the layout's weight times the square of the cells the query's grid observed over the map grids'
median (at most 1) (told apart by identity)."""


def _weighted(share: Callable[[LayoutScores], float]) -> Callable[..., CombinedScores]:
    """The matcher's combined scores with the layout's weight times ``share`` of the frame's comparison."""
    def combined(lost: MapScores, layout: LayoutScores, weight: float) -> CombinedScores:
        return CombinedScores(lost, layout, weight * share(layout))
    return combined


def _gathered_share(scores: LayoutScores) -> float:
    source = scores.comparison.source
    if not isinstance(source, Gathering) or not len(source.poses):
        return 1.0
    return max(0.25, min(1.0, source.reach / source.config.query_travel))


def _observed_share(scores: LayoutScores) -> float:
    comparison = scores.comparison
    return min(1.0, comparison.views[0].observed / float(np.median(comparison.maps.totals[0]))) ** 2


SHARES = {id(GATHERED): _gathered_share, id(OBSERVED): _observed_share}


FAMILIES: dict[str, dict[str, Config]] = {
    "ends": {
        "other end's grid gathered on the map's route (default)": Config(),
        "the same, gathering only the route the map camera faces": FACED,
        "the map camera's grid turned 180 degrees": AS_SEEN,
    },
    "contrast": {f"contrast over {d:g} m{' (default)' if d == 60.0 else ''}":
                 variant(sequence=dict(contrast_distance=d)) for d in (30.0, 60.0, 90.0)},
    "cues": {
        "LoST-X alone": variant(layout=dict(enabled="off")),
        "layout weight 1": variant(layout=dict(weight=1.0)),
        "layout weight 2": variant(layout=dict(weight=2.0)),
        "layout weight 3 (default)": Config(),
        "layout weight 4": variant(layout=dict(weight=4.0)),
        "the layout alone": variant(layout=dict(weight=100.0)),
    },
    "gathered": {
        "layout weight 3 (default)": Config(),
        "times the metres gathered, from a quarter": GATHERED,
        "times the cells observed, squared": OBSERVED,
    },
    "window": {f"distance window {d:g} m{' (default)' if d == Config().sequence.distance_window else ''}":
               variant(sequence=dict(distance_window=d)) for d in (30.0, 45.0, 60.0, 1000.0)},
    "switch": {f"switch cost {j:g}{' (default)' if j == Config().sequence.switch_cost else ''}":
               variant(sequence=dict(switch_cost=j)) for j in (2.0, 4.0, 6.0, 8.0, float("inf"))},
    "follow": {
        "sequence straight in frames": variant(sequence=dict(follow="frames")),
        "sequence following the distance (default)": Config(),
    },
    "grid": {
        "cells 2 m (default)": Config(),
        "cells 1 m": variant(layout=dict(cell=1.0, blur=1.0)),
        "range 30 m": variant(layout=dict(max_range=30.0)),
        "range 40 m": variant(layout=dict(max_range=40.0)),
    },
    "gathering": {
        "one frame each": variant(layout=dict(query_travel=0.0, map_travel=0.0)),
        "query 12 m, map +-9 m": variant(layout=dict(query_travel=12.0, map_travel=9.0)),
        "query 24 m, map +-18 m (default)": Config(),
        "query 36 m, map +-27 m": variant(layout=dict(query_travel=36.0, map_travel=27.0)),
    },
    "comparison": {
        "sideways shift +-4 m (default)": Config(),
        "sideways shift +-6 m": variant(layout=dict(across_shift=6.0)),
        "sideways shift +-2 m": variant(layout=dict(across_shift=2.0)),
        "no sideways shift": variant(layout=dict(across_shift=0.0)),
        "vehicles weighted 1": variant(layout=dict(vehicle_weight=1.0)),
        "vehicles left out": variant(layout=dict(vehicle_weight=0.0)),
    },
    "smoothing": {f"smoothed {b:g} m{' (default)' if b == Config().layout.blur else ''}":
                  variant(layout=dict(blur=b)) for b in (1.0, 2.0, 3.0, 4.0)},
    "frames": {f"at most {k} frames a grid{' (default)' if k == Config().layout.max_frames else ''}":
               variant(layout=dict(max_frames=k)) for k in (6, 12, 20)},
    "overlap": {f"at least {k} cells in common{' (default)' if k == Config().layout.min_cells else ''}":
                variant(layout=dict(min_cells=k)) for k in (12, 25, 50)},
    "buildings": {f"buildings weighted {w:g}{' (default)' if w == Config().layout.building_weight else ''}"
                  if w else "buildings left out": variant(layout=dict(building_weight=w))
                  for w in (1.0, 0.75, 0.5, 0.25, 0.0)},
    "turns": {
        "no turn": variant(layout=dict(turns=(0.0,))),
        "+-1 degree": variant(layout=dict(turns=(-1.0, 0.0, 1.0))),
        "+-2 degrees (default)": Config(),
        "+-3 degrees": variant(layout=dict(turns=(-3.0, 0.0, 3.0))),
        "+-5 degrees": variant(layout=dict(turns=(-5.0, 0.0, 5.0))),
        "+-3, +-6 degrees": variant(layout=dict(turns=(-6.0, -3.0, 0.0, 3.0, 6.0))),
        "+-10, +-20 degrees": variant(layout=dict(turns=(-20.0, -10.0, 0.0, 10.0, 20.0))),
    },
    "motion": {
        "ego poses (default source)": Config(),
        "visual odometry": variant(motion=dict(source="visual")),
    },
}


class Study:
    def __init__(self, root: Path) -> None:
        self.root = root
        self.backbone = load_backbone()
        self._maps: dict[str, ReferenceMap] = {}

    def refmap(self, camera: str, config: Config, run: Run) -> ReferenceMap:
        """The map of ``camera``'s frames of ``run`` with the layout and motion of ``config`` (built once)."""
        key = json.dumps([camera, dataclasses.asdict(config.layout), dataclasses.asdict(config.motion),
                          config is FACED, run.rows], default=str)
        if key not in self._maps:
            path = self.root / f"map-{len(self._maps)}"
            with mock.patch("lostx.core.build.map_grids", _gathered_faced) if config is FACED else nullcontext():
                build_map(run.map_frames, path, config, LostDescriber(self.backbone, config.lost), progress=False)
            self._maps[key] = ReferenceMap.open(path)
        return self._maps[key]

    def run(self, config: Config, every: int = 1) -> dict[str, dict[str, list[int]]]:
        """Per setup, Recall@1 single frame and with the sequence filter, and the frames whose heading is opposite,
        over every ``every``-th frame (the map's and the queries'; the runs from each start summed)."""
        if config is AS_SEEN:
            with mock.patch.object(ReferenceMap, "stores_other_ends", new=property(lambda self: False)):
                return self._run(config, every)
        if id(config) in SHARES:
            with mock.patch("lostx.core.match.matcher.CombinedScores", _weighted(SHARES[id(config)])):
                return self._run(config, every)
        return self._run(config, every)

    def _run(self, config: Config, every: int) -> dict[str, dict[str, list[int]]]:
        out = {}
        for setup, pairing in SETUPS.items():
            counts = self.counts(config, pairing, every)
            out[setup] = {**{mode: [c["right"], c["counted"]] for mode, c in counts.items()},
                          **{f"heading_{mode}": [c["opposite"], c["frames"]] for mode, c in counts.items()},
                          **{f"answers_{mode}": c["answers"] for mode, c in counts.items()}}
        return out

    def counts(self, config: Config, pairing: tuple[str, str, bool], every: int = 1) -> dict[str, dict[str, int]]:
        """:func:`scored`'s counts per mode over the runs of ``pairing`` at every ``every``-th frame, summed (the
        answers joined), with the frames played (``frames``)."""
        total = {mode: {"counted": 0, "right": 0, "opposite": 0, "sure": 0, "entering": 0, "entering right": 0,
                        "frames": 0, "answers": []} for mode in MODES}
        for run in runs(pairing, every):
            for mode, c in scored(self.refmap(pairing[0], config, run), run.frames, run.looks, run.map_looks, config,
                                  self.backbone).items():
                for key, value in c.items():
                    total[mode][key] += value
                total[mode]["frames"] += len(run.frames)
        return total


@dataclasses.dataclass(frozen=True)
class Run:
    """One run of a pairing of the scene's cameras: the map's frames and the queries, with their look-at points."""

    rows: tuple[int, ...]
    """The frames of the scene used, the map's and the queries'."""
    map_frames: Traverse
    frames: list
    """The queries, in the order played, their camera removed (the heading is not declared)."""
    looks: np.ndarray
    map_looks: np.ndarray


def runs(pairing: tuple[str, str, bool], every: int = 1) -> list[Run]:
    """The runs of a pairing (map camera, query camera, queries played backwards) at every ``every``-th frame: one
    from each of the first ``every`` frames (at the recorded rate, the whole scene once)."""
    map_camera, query_camera, reverse = pairing
    mapped, recorded = open_traverse(SCENE / map_camera), open_traverse(SCENE / query_camera)
    map_looks = open_traverse(SCENE / map_camera, options=SourceOptions(look_at=15.0)).positions
    looks = open_traverse(SCENE / query_camera, options=SourceOptions(look_at=15.0)).positions
    out = []
    for start in range(every):
        rows = list(range(start, len(mapped), every))
        map_frames, queries = (mapped, recorded) if every == 1 else (mapped.subset(rows), recorded.subset(rows))
        if reverse:
            queries = queries.reversed()
        out.append(Run(tuple(rows), map_frames, [dataclasses.replace(f, camera=None) for f in queries],
                       looks[queries.rows], map_looks[rows]))
    return out


def scored(refmap: ReferenceMap, frames: list, looks: np.ndarray, map_looks: np.ndarray, config: Config,
           backbone) -> dict[str, dict[str, int]]:
    """``frames`` (their look-at points ``looks``) through localizers of ``config`` on ``refmap`` (its frames' look-at
    points ``map_looks``), single frame and with the sequence filter: per mode the queries with a counterpart within
    ``TOLERANCE`` (counted), those answered within it (right), the frames whose heading is opposite, and opposite
    and sure (at least ``heading.min_confidence``), and where the frames start off the map, the first ``ENTERED``
    queries with a counterpart (entering) and of them those right (entering right); and whether each counted query
    was answered right, in order (answers: to compare two variants query by query)."""
    matcher = PlaceMatcher(refmap, config, backbone)
    matches = [matcher.match_description(matcher.describe(f)) for f in frames]
    distances = [np.hypot(*(map_looks - look).T) for look in looks]
    starts_off = distances[0].min() > TOLERANCE
    out = {}
    for mode in MODES:
        run_config = dataclasses.replace(config, sequence=dataclasses.replace(config.sequence,
                                                                              enabled=mode == "sequence"))
        localizer = Localizer(refmap, run_config, backbone)
        counts = {"counted": 0, "right": 0, "opposite": 0, "sure": 0, "entering": 0, "entering right": 0,
                  "answers": []}
        for frame, match, distance in zip(frames, matches, distances):
            estimate = localizer.update(frame, match)
            opposite = estimate.heading == "opposite"
            counts["opposite"] += opposite
            counts["sure"] += opposite and estimate.heading_confidence >= config.heading.min_confidence
            if distance.min() <= TOLERANCE:
                right = bool(distance[estimate.match_index] <= TOLERANCE)
                if starts_off and counts["counted"] < ENTERED:
                    counts["entering"] += 1
                    counts["entering right"] += right
                counts["counted"] += 1
                counts["right"] += right
                counts["answers"].append(right)
        out[mode] = counts
    return out


RATES = {"2 Hz": 1, "1 Hz": 2}
"""Every n-th frame: the recorded rate, and every other frame (the map's and the queries', both halves summed)."""


def chosen(results: dict[str, dict], on: str, rates: tuple[str, ...] = ("2 Hz",)) -> str:
    """The variant with the best sequence Recall@1 on setup ``on``, summed over ``rates`` (ties: single frame, then
    the listed order)."""
    def figure(name: str, mode: str) -> int:
        return sum(results[name][rate][on][mode][0] for rate in rates)

    return max(results, key=lambda name: (figure(name, "sequence"), figure(name, "single")))


def against(answers: list[bool], default: list[bool]) -> str:
    """A variant's answers against the default's, query by query and in stretches of neighbouring queries, each with
    the exact McNemar test's p: ``+7 -0 (p 0.016), stretches +1 -0 (p 1)``."""
    queries = paired_comparison(np.array(answers), np.array(default))
    runs = paired_comparison(np.array(answers), np.array(default), stretches=True)
    return (f"+{queries.only_first} -{queries.only_second} (p {queries.p_value:.2g}), "
            f"stretches +{runs.only_first} -{runs.only_second} (p {runs.p_value:.2g})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", default=",".join(FAMILIES), help="comma-separated: " + ", ".join(FAMILIES))
    parser.add_argument("--out", type=Path, default=RESULTS / "study_layout.json")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    report: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        study = Study(Path(tmp))
        for family in args.families.split(","):
            results = {name: {rate: study.run(config, every) for rate, every in RATES.items()}
                       for name, config in FAMILIES[family].items()}
            default = next((name for name in results if "(default" in name), None)
            rows = []
            for name, by_rate in results.items():
                r, half = by_rate["2 Hz"], by_rate["1 Hz"]
                rows.append([name, *(f"{r[s][m][0]}/{r[s][m][1]}" for s in SETUPS for m in MODES),
                             f"{r['S1']['heading_sequence'][0]}/{r['S2']['heading_sequence'][0]}",
                             *(f"{half[s][m][0]}/{half[s][m][1]}" for s in SETUPS for m in MODES),
                             *(against(r[s]["answers_sequence"], results[default]["2 Hz"][s]["answers_sequence"])
                               if default is not None and name != default else "" for s in SETUPS)])
            print_table(f"{family}: Recall@1 at 7.5 m, 2 Hz (heading opposite in frames of 40), and 1 Hz; at 2 Hz the "
                        f"sequence's queries right only with the variant / only with the default, and the stretches "
                        f"of neighbouring queries they make (exact McNemar p of each)",
                        ["variant", "S1 single", "S1 sequence", "S2 single", "S2 sequence", "heading S1/S2",
                         "1 Hz S1 single", "S1 sequence", "S2 single", "S2 sequence", "S1 against the default",
                         "S2 against the default"], rows)
            report[family] = {"results": results}
            for rates in (("2 Hz",), tuple(RATES)):
                on_s1, on_s2 = chosen(results, "S1", rates), chosen(results, "S2", rates)
                at = results[on_s1]["2 Hz"]["S2"], results[on_s2]["2 Hz"]["S1"]
                print(f"chosen on {' + '.join(rates)}: on S1 {on_s1} -> S2 {at[0]['single']} {at[0]['sequence']}; "
                      f"on S2 {on_s2} -> S1 {at[1]['single']} {at[1]['sequence']}")
                report[family][f"chosen on {' + '.join(rates)}"] = {"S1": on_s1, "S2": on_s2}
    write_json(args.out, {"benchmark": "study_layout", "tolerance_m": TOLERANCE, "rates": RATES, "families": report})


if __name__ == "__main__":
    main()
