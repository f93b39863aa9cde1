"""What makes the opposite view match: every variant, on the real front/rear frames of one road.

Two setups on ``../shared/data/nuscenes-frontrear/scene-0523`` (look-at points 15 m along each camera's
axis as the positions):

- S1, the paper's: map from the rear camera, queries from the front camera;
- S2, the road driven the other way: map from the front camera, queries the rear frames played
  backwards (a front camera of a car driving the other way).

For each variant: Recall@1 at 7.5 m and 15 m, single frame and with the sequence filter; how often the
heading is called right; how many answers are ``localized`` and how many of those are wrong. The
defaults are re-checked on the RobotCar day/night pair (exact matches, single frame) beside it.

    python benchmarks/study_opposite.py [--only NAME ...]

prints a table and writes ``benchmarks/results/study_opposite.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

from common import RESULTS, print_table, write_json  # noqa: I001  (benchmarks/common.py)

from lostx.core import Config, Localizer, ReferenceMap, build_map, load_backbone
from lostx.core.config import BackboneConfig, CameraConfig, HeadingConfig, LostConfig, SequenceConfig, VerifyConfig
from lostx.core.describe.describer import LostDescriber
from lostx.core.paths import data_dir
from lostx.evaluation.groundtruth import from_positions
from lostx.replay.dataset import SourceOptions, open_traverse

SCENE = data_dir() / "nuscenes-frontrear" / "scene-0523"
ROBOTCAR = data_dir() / "robotcar-daynight"
CAMERAS = CameraConfig(hfov_deg={"front": 65.1, "rear": 90.2}, view_hfov_deg=65.1, ignore_bottom={"rear": 0.08})
"""docs/examples/nuscenes-cameras.toml: fields of view from calibration.json (2 atan(800 / fx)), the boot lid."""
STREET5 = {"road": ("road",), "building": ("building", "house"), "vegetation": ("tree", "plant", "grass"),
           "sidewalk": ("sidewalk",), "sky": ("sky",)}
NARROW = {"road": ("road",), "building": ("building", "house"), "vegetation": ("tree", "plant", "grass")}


MOSAIC_LAYERS = {
    "MOSAIC context layer (SPP projection, 128 x 32 x 32)": "spatial_pyramid_pooling_multikernel_conv/concat_projection/Relu",
    "MOSAIC encoder block 15 (96 x 32 x 32)": "MobilenetV3/expanded_conv_15/add",
    "MOSAIC decoder layer (64 x 64 x 64)": "decoder/decoder_feature_conv_0/Relu",
}


@dataclasses.dataclass(frozen=True)
class Variant:
    name: str
    config: Config


def mosaic_layer(name: str, tensor: str, folder: Path) -> Variant:
    """MOSAIC with its features read from another tensor, described by a TOML file (docs/backbones.md)."""
    from lostx.core.backbones.mosaic import ADE20K_CLASSES
    from lostx.core.paths import models_dir

    toml = folder / f"{abs(hash(tensor))}.toml"
    classes = ", ".join(f'"{c}"' for c in ADE20K_CLASSES)
    toml.write_text(f'model = "{models_dir() / "mosaic-r4-ade20k31-uint8.tflite"}"\nfeatures = "{tensor}"\n'
                    f'scores = "decoder/add"\nclasses = [{classes}]\ndefault_classes = "street"\nresize = "area"\n')
    return Variant(name, Config(backbone=BackboneConfig(name="tflite", model_path=toml)))


def variants(folder: Path) -> list[Variant]:
    base = Config()

    def with_(**sections) -> Config:
        return dataclasses.replace(base, **sections)

    out = [
        Variant("defaults", base),
        Variant("fit crop", with_(backbone=dataclasses.replace(base.backbone, fit="crop"))),
        Variant("fit pad", with_(backbone=dataclasses.replace(base.backbone, fit="pad"))),
        Variant("cameras: common field of view, boot lid cut", with_(camera=CAMERAS)),
        Variant("scoring eq4", with_(verify=VerifyConfig(scoring="eq4"))),
        Variant("scoring released", with_(verify=VerifyConfig(scoring="released"))),
        Variant("verify top 20", with_(verify=VerifyConfig(top_k=20))),
        Variant("density test in both images", with_(verify=VerifyConfig(density_filter="both"))),
        Variant("classes + sidewalk, sky", with_(lost=LostConfig(classes=STREET5))),
        Variant("classes grouped narrowly (road; building, house; tree, plant, grass)",
                with_(lost=LostConfig(classes=NARROW))),
        Variant("class means over 5 map frames", with_(lost=LostConfig(reference_window=5))),
        Variant("class means over 3 query frames", with_(lost=LostConfig(query_window=3))),
        Variant("window 8", with_(sequence=SequenceConfig(length=8))),
        Variant("window 12", with_(sequence=SequenceConfig(length=12))),
        Variant("acquisition speeds 0.6-1.4", with_(sequence=SequenceConfig(acquire_speeds=(0.6, 0.8, 1.0, 1.2, 1.4)))),
        Variant("declared prior 0.9 (drives the mapped direction)", with_(heading=HeadingConfig(declared_prior=0.9))),
        *(mosaic_layer(name, tensor, folder) for name, tensor in MOSAIC_LAYERS.items()),
        Variant("ESPNetv2, Cityscapes (512 x 24 x 48)", with_(backbone=BackboneConfig(name="espnetv2-cityscapes"))),
        Variant("cameras + verify top 20", with_(camera=CAMERAS, verify=VerifyConfig(top_k=20))),
        Variant("cameras + density test in both images", with_(camera=CAMERAS, verify=VerifyConfig(density_filter="both"))),
        Variant("cameras + window 8", with_(camera=CAMERAS, sequence=SequenceConfig(length=8))),
        Variant("cameras + classes grouped narrowly", with_(camera=CAMERAS, lost=LostConfig(classes=NARROW))),
        Variant("cameras + ESPNetv2", with_(camera=CAMERAS, backbone=BackboneConfig(name="espnetv2-cityscapes"))),
    ]
    return out


def run_setup(variant: Variant, setup: str, backbone, workdir: Path) -> dict[str, float]:
    look_at = SourceOptions(look_at=15.0)
    ref_side, query_side = ("rear", "front") if setup == "S1" else ("front", "rear")
    reference = open_traverse(SCENE / ref_side, options=look_at)
    queries = open_traverse(SCENE / query_side, options=look_at)
    if setup == "S2":
        queries = queries.reversed()
    out = workdir / f"{setup}-{ref_side}"
    build_map(reference, out, variant.config, LostDescriber(backbone, variant.config.lost), progress=False,
              overwrite=True)
    refmap = ReferenceMap.open(out)
    truths = from_positions(queries.positions, refmap.positions, [7.5, 15.0])
    row: dict[str, float] = {}
    for mode in ("single", "sequence"):
        config = dataclasses.replace(variant.config, sequence=dataclasses.replace(variant.config.sequence,
                                                                                  enabled=mode == "sequence"))
        localizer = Localizer(refmap, config, backbone)
        estimates = [localizer.step(frame) for frame in queries]
        predictions = np.array([e.match_index for e in estimates])
        for truth in truths:
            right = truth.is_correct(predictions)
            row[f"{setup} {mode} R@1 {truth.tolerance:g} m"] = float(right[truth.has_match].mean())
        localized = np.array([e.state == "localized" for e in estimates])
        row[f"{setup} {mode} localized"] = int(localized.sum())
        row[f"{setup} {mode} localized wrong"] = int((localized & ~truths[0].is_correct(predictions)).sum())
        row[f"{setup} {mode} heading right"] = float(np.mean([e.heading == "opposite" for e in estimates]))
    return row


def robotcar_exact(variant: Variant, backbone, workdir: Path) -> int:
    out = workdir / "robotcar-day"
    build_map(open_traverse(ROBOTCAR / "day"), out, variant.config, LostDescriber(backbone, variant.config.lost),
              progress=False, overwrite=True)
    config = dataclasses.replace(variant.config, sequence=dataclasses.replace(variant.config.sequence, enabled=False))
    localizer = Localizer(ReferenceMap.open(out), config, backbone)
    found = np.array([localizer.step(f).match_index for f in open_traverse(ROBOTCAR / "night")])
    return int((found == np.arange(len(found))).sum())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", help="variants to run (names as printed)")
    args = parser.parse_args()
    rows = []
    descriptions = Path(tempfile.mkdtemp())
    for variant in variants(descriptions):
        if args.only and variant.name not in args.only:
            continue
        backbone = load_backbone(variant.config.backbone)
        with tempfile.TemporaryDirectory() as tmp:
            row: dict[str, float | str] = {"variant": variant.name}
            for setup in ("S1", "S2"):
                row.update(run_setup(variant, setup, backbone, Path(tmp)))
            row["RobotCar exact"] = robotcar_exact(variant, backbone, Path(tmp))
        rows.append(row)
        print(f"{variant.name}: done", file=sys.stderr, flush=True)
    columns = ["variant"] + [f"{s} {m} R@1 {t} m" for s in ("S1", "S2") for m in ("single", "sequence")
                             for t in ("7.5", "15")] + ["S1 sequence heading right", "S2 sequence heading right",
                                                         "S1 sequence localized wrong", "S2 sequence localized wrong",
                                                         "RobotCar exact"]
    table = [[row[c] if c in row else "" for c in columns] for row in rows]
    print_table("opposite view: Recall@1 (share of the queries that have a counterpart)", columns, table)
    write_json(RESULTS / "study_opposite.json", {"rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
