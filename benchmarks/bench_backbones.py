"""Per-frame network time of each backbone, and its RobotCar day/night single-frame result (issue 7).

Network time: the backbone call alone (resize, network, probabilities on the
feature grid), over the twenty real RobotCar frames (day and night), cycled.
Day/night: a map of the ten day frames, the ten night frames localized against
it in order (the k-th night frame's true match is day frame k), for each
scoring: the single-frame answer and the sequence filter's (window of 3 frames
by default, as in ``lostx demo``: the sample has only ten).
The machine is shared, so the load average before and after is recorded.

    python benchmarks/bench_backbones.py [--backbones NAME ...] [--repeat 30] [--threads 2] [--window 3]
                                         [--out benchmarks/results/backbones.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import itertools
import os
import tempfile
from pathlib import Path

import numpy as np

from common import RESULTS, print_table, summary, time_call, write_json
from lostx.core import Config, Localizer, LostDescriber, ReferenceMap, backbone_names, build_map, load_backbone
from lostx.core.backbones import Backbone
from lostx.core.config import BackboneConfig, SequenceConfig, VerifyConfig
from lostx.core.paths import data_dir
from lostx.replay.folder import folder_traverse

SCORINGS = ("eq4-lost", "eq4", "released")


def network_time(backbone: Backbone, images: list[np.ndarray], repeat: int) -> dict[str, float]:
    frames = itertools.cycle(images)
    return summary(time_call(lambda: backbone(next(frames)), repeat))


def counts(found: np.ndarray, truth: np.ndarray) -> dict[str, object]:
    return {"matches": found.tolist(), "exact": int((found == truth).sum()),
            "within_one": int((np.abs(found - truth) <= 1).sum())}


def day_night(backbone: Backbone, config: Config, window: int) -> dict[str, dict[str, dict[str, object]]]:
    """Per scoring, the single-frame and the sequence filter's night -> day result."""
    root = data_dir() / "robotcar-daynight"
    night = list(folder_traverse(root / "night"))
    truth = np.array([frame.id for frame in night])
    results: dict[str, dict[str, dict[str, object]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        build_map(folder_traverse(root / "day"), Path(tmp) / "day", config, LostDescriber(backbone, config.lost),
                  {"camera": "front"}, progress=False)
        refmap = ReferenceMap.open(Path(tmp) / "day")
        for scoring in SCORINGS:
            localizer = Localizer(refmap, dataclasses.replace(
                config, verify=VerifyConfig(scoring=scoring), sequence=SequenceConfig(length=window)), backbone)
            estimates = [localizer.step(frame) for frame in night]
            results[scoring] = {
                "single": counts(np.array([e.single_match_index for e in estimates]), truth),
                "sequence": counts(np.array([e.match_index for e in estimates]), truth),
            }
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backbones", nargs="+", default=backbone_names(), help="backbones to measure")
    parser.add_argument("--repeat", type=int, default=30, help="timed frames per backbone")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for the networks")
    parser.add_argument("--window", type=int, default=3, help="frames in the sequence filter's window")
    parser.add_argument("--out", type=Path, default=RESULTS / "backbones.json")
    args = parser.parse_args()

    root = data_dir() / "robotcar-daynight"
    images = [frame.image for folder in ("day", "night") for frame in folder_traverse(root / folder)]
    load_before = os.getloadavg()[0]
    measured: dict[str, dict[str, object]] = {}
    for name in args.backbones:
        config = Config(backbone=BackboneConfig(name=name, threads=args.threads))
        backbone = load_backbone(config.backbone)
        info = backbone.info
        measured[name] = {
            "grid": list(info.grid),
            "feature_dim": info.feature_dim,
            "classes": len(info.class_names),
            "network": network_time(backbone, images, args.repeat),
            "day_night": day_night(backbone, config, args.window),
        }
    load_after = os.getloadavg()[0]

    print_table(f"network time per frame ({args.threads} threads, 1024 x 640 RobotCar frames)",
                ["backbone", "grid", "D", "median ms", "p90 ms"],
                [[name, "x".join(map(str, m["grid"])), m["feature_dim"], m["network"]["median_ms"],
                  m["network"]["p90_ms"]] for name, m in measured.items()])
    for answer in ("single", "sequence"):
        print_table(f"RobotCar night -> day, {answer}, of 10: exact / within one frame",
                    ["backbone", *SCORINGS],
                    [[name, *(cell(m["day_night"][s][answer]) for s in SCORINGS)] for name, m in measured.items()])
    print(f"\nload average (1 min): {load_before:.2f} before, {load_after:.2f} after")
    write_json(args.out, {"benchmark": "backbones", "threads": args.threads, "repeat": args.repeat, "window": args.window,
                          "load_average": [load_before, load_after], "backbones": measured})


def cell(result: dict[str, object]) -> str:
    return f"{result['exact']} / {result['within_one']}"


if __name__ == "__main__":
    main()
