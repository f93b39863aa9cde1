"""Per-frame network time of each backbone, and its RobotCar day/night single-frame result (issue 7).

Network time: the backbone call alone (resize, network, probabilities on the
feature grid), over the twenty real RobotCar frames (day and night), cycled.
Day/night: a map of the ten day frames, the ten night frames matched against
it (the k-th night frame's true match is day frame k), for each scoring.
The machine is shared, so the load average before and after is recorded.

    python benchmarks/bench_backbones.py [--backbones NAME ...] [--repeat 30] [--threads 2]
                                         [--out benchmarks/results/backbones.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import os
import tempfile
from pathlib import Path

import numpy as np

from common import RESULTS, print_table, summary, time_call, write_json
from lostx.core import Config, LostDescriber, PlaceMatcher, ReferenceMap, backbone_names, build_map, load_backbone
from lostx.core.backbone import Backbone
from lostx.core.config import BackboneConfig, VerifyConfig
from lostx.core.paths import data_dir
from lostx.replay.folder import folder_traverse

SCORINGS = ("eq4-lost", "eq4", "released")


def network_time(backbone: Backbone, images: list[np.ndarray], repeat: int) -> dict[str, float]:
    frames = itertools.cycle(images)
    return summary(time_call(lambda: backbone(next(frames)), repeat))


def day_night(backbone: Backbone, config: Config) -> dict[str, dict[str, object]]:
    root = data_dir() / "robotcar-daynight"
    night = list(folder_traverse(root / "night"))
    truth = np.array([frame.id for frame in night])
    results: dict[str, dict[str, object]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        build_map(folder_traverse(root / "day"), Path(tmp) / "day", config, LostDescriber(backbone, config.lost),
                  {"camera": "front"}, progress=False)
        refmap = ReferenceMap.open(Path(tmp) / "day")
        for scoring in SCORINGS:
            scored = dataclasses.replace(config, verify=VerifyConfig(scoring=scoring))
            matcher = PlaceMatcher(refmap, scored, backbone)
            found = np.array([matcher.match(frame.image).best for frame in night])
            results[scoring] = {
                "matches": found.tolist(),
                "exact": int((found == truth).sum()),
                "within_one": int((np.abs(found - truth) <= 1).sum()),
            }
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backbones", nargs="+", default=backbone_names(), help="backbones to measure")
    parser.add_argument("--repeat", type=int, default=30, help="timed frames per backbone")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for the networks")
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
            "day_night": day_night(backbone, config),
        }
    load_after = os.getloadavg()[0]

    print_table(f"network time per frame ({args.threads} threads, 1024 x 640 RobotCar frames)",
                ["backbone", "grid", "D", "median ms", "p90 ms"],
                [[name, "x".join(map(str, m["grid"])), m["feature_dim"], m["network"]["median_ms"],
                  m["network"]["p90_ms"]] for name, m in measured.items()])
    print_table("RobotCar night -> day, single frame, of 10: exact / within one frame",
                ["backbone", *SCORINGS],
                [[name, *(f"{m['day_night'][s]['exact']} / {m['day_night'][s]['within_one']}" for s in SCORINGS)]
                 for name, m in measured.items()])
    print(f"\nload average (1 min): {load_before:.2f} before, {load_after:.2f} after")
    write_json(args.out, {"benchmark": "backbones", "threads": args.threads, "repeat": args.repeat,
                          "load_average": [load_before, load_after], "backbones": measured})


if __name__ == "__main__":
    main()
