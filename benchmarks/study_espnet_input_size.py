"""Which input size for ESPNetv2 on the 1024 x 640 RobotCar frames (issue 7): labels, time, day/night.

For each candidate size every frame is resized to it. Reported per size: the
share of road in the bottom centre and of building at the left and right
sides of the full-resolution label maps (mean over the ten day and the ten
night frames; the bottom centre is road in every frame, the sides are mostly
houses, with trees in a few day frames), the median network time per frame,
and the night -> day single-frame result for each scoring.

    python benchmarks/study_espnet_input_size.py [--sizes 1024x640 1024x512 768x384 512x256]
                                                 [--out benchmarks/results/espnet_input_size.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse

import numpy as np

import lostx.core.backbones.espnet as espnet
from bench_backbones import SCORINGS, cell, day_night, network_time
from common import parse, print_table, write_json
from lostx.core import Config, load_backbone
from lostx.core.config import BackboneConfig
from lostx.core.paths import data_dir
from lostx.replay.folder import folder_traverse

REGIONS = {  # name: (rows, columns as fractions of the frame, class)
    "road_bottom_centre": ((0.75, 1.0), (0.35, 0.65), "road"),
    "building_left": ((0.2, 0.6), (0.0, 0.2), "building"),
    "building_right": ((0.2, 0.6), (0.8, 1.0), "building"),
}


def region_shares(labels: np.ndarray) -> dict[str, float]:
    h, w = labels.shape
    shares = {}
    for name, (rows, cols, cls) in REGIONS.items():
        region = labels[int(rows[0] * h):int(rows[1] * h), int(cols[0] * w):int(cols[1] * w)]
        shares[name] = float((region == espnet.CITYSCAPES_CLASSES.index(cls)).mean())
    return shares


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["1024x640", "1024x512", "768x384", "512x256"])
    parser.add_argument("--repeat", type=int, default=20, help="timed frames per size")
    args = parse(parser, "espnet_input_size", "the smallest size, two timed frames")
    if args.quick:
        args.sizes, args.repeat = ["512x256"], 2

    root = data_dir() / "robotcar-daynight"
    frames = {folder: [f.image for f in folder_traverse(root / folder)] for folder in ("day", "night")}
    default = espnet.INPUT_SIZE
    results: dict[str, dict[str, object]] = {}
    try:
        for size in args.sizes:
            width, height = (int(v) for v in size.split("x"))
            espnet.INPUT_SIZE = (width, height)  # a study only: the backbone itself always uses the default
            config = Config(backbone=BackboneConfig(name="espnetv2-cityscapes"))
            backbone = load_backbone(config.backbone)
            labels = {folder: [region_shares(backbone.segment(image)) for image in images]
                      for folder, images in frames.items()}
            results[size] = {
                "grid": list(backbone.info.grid),
                "labels": {folder: {k: float(np.mean([s[k] for s in shares])) for k in REGIONS}
                           for folder, shares in labels.items()},
                "network": network_time(backbone, frames["day"] + frames["night"], args.repeat),
                "day_night": day_night(backbone, config, window=3),
            }
    finally:
        espnet.INPUT_SIZE = default

    rows = []
    for size, r in results.items():
        shares = [f"{r['labels'][folder][k]:.2f}" for folder in ("day", "night") for k in REGIONS]
        rows.append([size, "x".join(map(str, r["grid"])), *shares, r["network"]["median_ms"],
                     *(cell(r["day_night"][s]["single"]) for s in SCORINGS)])
    print_table("ESPNetv2 input size: label shares (day: road, bld L, bld R | night: same), ms, "
                "night -> day single frame",
                ["input", "grid", "d road", "d bldL", "d bldR", "n road", "n bldL", "n bldR", "median ms",
                 *SCORINGS], rows)
    write_json(args.out, {"benchmark": "espnet_input_size", "sizes": results})


if __name__ == "__main__":
    main()
