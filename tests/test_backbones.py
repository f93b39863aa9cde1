"""Models described as data: the generic TFLite backbone configured by a TOML file only, ``lostx backbones
inspect``, maps that refuse another backbone's features, class presets and the class-coverage warning."""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from backbonetools import MOSAIC, answers, describe_mosaic, lostx
from lostx.core.backbones import BackboneInfo, SemanticFrame, load_backbone, preset_classes, read_description
from lostx.core.backbones.espnet import CITYSCAPES_CLASSES
from lostx.core.backbones.mosaic import ADE20K_CLASSES
from lostx.core.config import BackboneConfig, LostConfig
from lostx.core.describe.coverage import ClassCoverageWarning, coverage_message
from lostx.core.describe.describer import LostDescriber
from lostx.core.errors import InputError, MapError, ModelError
from lostx.core.describe.keypoints import frame_evidence
from lostx.core.maps.mapwriter import MapFrame, MapWriter
from lostx.core.maps.refmap import ReferenceMap
from lostx.replay.folder import folder_traverse


@pytest.fixture(scope="module")
def described(tmp_path_factory) -> Path:
    """The shared MOSAIC model with a TOML description beside it."""
    return describe_mosaic(tmp_path_factory.mktemp("described"))


@pytest.fixture(scope="module")
def tflite_map(described, robotcar) -> Path:
    """The RobotCar day map built through the generic TFLite backbone, named by the TOML alone."""
    from lostx.cli import main

    out = described.parent / "day"
    assert main(["map", "build", str(robotcar / "day"), "--out", str(out), "--backbone", "tflite", "--model",
                 str(described.with_suffix(".toml")), "--quiet"]) == 0
    return out


def test_mosaic_described_by_toml_gives_the_builtin_answers(robotcar, mosaic, day_map, described, tflite_map,
                                                            tmp_path, capsys):
    generic = load_backbone(BackboneConfig(name="tflite", model_path=described))
    assert generic.info.grid == mosaic.info.grid == (32, 32) and generic.info.feature_dim == 448
    assert generic.info.default_classes == mosaic.info.default_classes
    assert generic.info.feature_quantisation == mosaic.info.feature_quantisation
    for folder in ("day", "night"):
        for frame in folder_traverse(robotcar / folder):
            ours, builtin = generic(frame.image), mosaic(frame.image)
            np.testing.assert_array_equal(ours.features, builtin.features)
            np.testing.assert_array_equal(ours.probs, builtin.probs)

    recorded = json.loads((tflite_map / "manifest.json").read_text())["backbone"]
    assert (recorded["name"], recorded["feature_tensor"], recorded["grid"]) == ("tflite", "MobilenetV3/Conv_1/Relu",
                                                                                [32, 32])
    # Matched with the model file alone (its TOML beside it) and no --backbone: the map's own backbone
    # with this --model, not the default backbone's file.
    assert lostx(capsys, "match", tflite_map, robotcar / "night", "--out", tmp_path / "generic.csv", "--model",
                 described, "--quiet").code == 0
    assert lostx(capsys, "match", day_map.path, robotcar / "night", "--out", tmp_path / "builtin.csv",
                 "--quiet").code == 0
    found = answers(tmp_path / "generic.csv")
    assert found == answers(tmp_path / "builtin.csv")
    assert sum(match == k for k, (match, _) in enumerate(found)) == 6  # the README's 6 / 10

    lostx(capsys, "match", tflite_map, robotcar / "night", "--out", tmp_path / "x.csv").error_line(
        "backbone 'tflite' needs its model", "--model PATH")
    assert not (tmp_path / "x.csv").exists()


def test_map_refuses_features_of_another_layer_from_the_same_backbone_and_file(robotcar, tflite_map, tmp_path,
                                                                                capsys):
    # The same name and model file, its features read from an earlier layer: 192 channels on a 64 x 64 grid.
    model = describe_mosaic(tmp_path, features="MobilenetV3/expanded_conv_5/depthwise/Relu")
    line = lostx(capsys, "match", tflite_map, robotcar / "night", "--out", tmp_path / "x.csv", "--model",
                 model).error_line(
        "was built with backbone tflite", "'MobilenetV3/Conv_1/Relu' 448 x 32x32",
        "'MobilenetV3/expanded_conv_5/depthwise/Relu' 192 x 64x64", "(feature tensor, feature size, grid differ)",
        "rebuild the map")
    assert line.count("model mosaic.tflite md5 b7a7620b8b818d64305b51ab796bfb1d") == 2


def test_map_names_each_part_of_the_backbone_that_differs(tmp_path, rng):
    info = BackboneInfo(name="net", model_file="a.tflite", model_md5="0" * 32, feature_dim=16, grid=(4, 6),
                        class_names=("other", "road"), default_classes={"road": ("road",)}, feature_tensor="conv5")
    evidence = frame_evidence(rng.random((16, 4, 6)).astype(np.float32), np.zeros((4, 6), np.uint8))
    with MapWriter(tmp_path / "map", "lost", {}, backbone=info) as writer:
        writer.add(MapFrame("0.png", rng.random(8).astype(np.float32), evidence))
        writer.commit()
    refmap = ReferenceMap.open(tmp_path / "map")
    refmap.check_backbone(info)
    for change, words in (({"feature_tensor": "conv4"}, "feature tensor"), ({"feature_dim": 32}, "feature size"),
                          ({"grid": (8, 12)}, "grid"), ({"model_md5": "f" * 32}, "model"),
                          ({"name": "other"}, "name")):
        with pytest.raises(MapError, match=f"\\({words} differ\\)") as error:
            refmap.check_backbone(dataclasses.replace(info, **change))
        assert "\n" not in str(error.value) and "was built with backbone net (model a.tflite" in str(error.value)


@pytest.mark.parametrize("changes, fragments", [
    ({"features": "MobilenetV3/Conv_1"}, ["no tensor named 'MobilenetV3/Conv_1'", "inspect"]),
    ({"features": "MobilenetV3/Conv_1/BatchNorm_Fold/bias"}, ["has shape 448", "a weight"]),
    ({"scores": "SemanticPredictions"}, ["shape 1 x 512 x 512"]),
    ({"classes": list(ADE20K_CLASSES[:20])}, ["32 channels", "lists 20 classes"]),
    ({"features": None}, ["lacks the key 'features'"]),
    ({"colour": "rgb"}, ["unknown key 'colour'"]),
    ({"input_size": "big"}, ["input_size", "expected a list"]),
    ({"input_size": [512, 0]}, ["input_size", "2 positive numbers"]),
    ({"input_size": [256, 256]}, ["cannot take 256 x 256 frames"]),
    ({"mean": [0, 0, 0]}, ["mean and std together"]),
    ({"default_classes": "forest"}, ["unknown preset 'forest'"]),
    ({"default_classes": {"road": ["asphalt"]}}, ["group 'road' names 'asphalt'"]),
    ({"scores_are": "odds"}, ["'odds' is not one of"]),
    ({"model": "elsewhere.tflite"}, ["describes", "elsewhere.tflite", "not"]),
])
def test_description_errors_name_the_problem(tmp_path, changes, fragments):
    model = describe_mosaic(tmp_path, **changes)
    with pytest.raises((ModelError, InputError)) as error:
        load_backbone(BackboneConfig(name="tflite", model_path=model))
    message = str(error.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message


def test_description_file_errors(tmp_path):
    model = tmp_path / "net.tflite"
    model.symlink_to(MOSAIC)
    with pytest.raises(ModelError, match=r"has no description beside it: write .*net\.toml"):
        read_description(model)
    (tmp_path / "net.toml").write_text("features = [")
    with pytest.raises(ModelError, match="not valid TOML"):
        read_description(model)
    (tmp_path / "net.toml").write_text('model = "missing.tflite"\n')
    with pytest.raises(ModelError, match="model file not found: .*missing.tflite"):
        read_description(tmp_path / "net.toml")
    with pytest.raises(ModelError, match="model file not found"):
        read_description(tmp_path / "absent.tflite")


def test_cli_description_error_is_one_line(robotcar, tmp_path, capsys):
    model = describe_mosaic(tmp_path, features="MobilenetV3/Conv_1")
    lostx(capsys, "map", "build", robotcar / "day", "--out", tmp_path / "m", "--backbone", "tflite", "--model",
          model).error_line("no tensor named 'MobilenetV3/Conv_1'")
    assert not (tmp_path / "m").exists()


def test_inspect_lists_tensors_and_suggests_mosaic_features_and_scores(capsys):
    ran = lostx(capsys, "backbones", "inspect", MOSAIC)
    assert ran.code == 0, ran.err
    lines = ran.out.splitlines()
    assert "input   PreprocessedImageTensor  1x512x512x3  uint8" in lines
    listed = {line.split()[0]: line.split()[1] for line in lines if line.startswith(("MobilenetV3/", "decoder/"))}
    assert listed["MobilenetV3/Conv_1/Relu"] == "1x32x32x448" and listed["decoder/add"] == "1x128x128x32"
    assert "MobilenetV3/Conv_1/BatchNorm_Fold/bias" not in listed  # weights are not listed
    assert 'features = "MobilenetV3/Conv_1/Relu"  # 448 channels on a 32 x 32 grid' in lines
    assert 'scores = "decoder/add"  # 32 channels on a 128 x 128 grid' in lines


def test_inspect_errors(tmp_path, capsys):
    fake = tmp_path / "fake.tflite"
    fake.write_bytes(b"\0" * 4000)
    lostx(capsys, "backbones", "inspect", fake).error_line("fake.tflite", "not a loadable TFLite model")
    (tmp_path / "net.pt").write_bytes(b"x")
    lostx(capsys, "backbones", "inspect", tmp_path / "net.pt").error_line("reads .tflite", ".onnx")
    lostx(capsys, "backbones", "inspect", tmp_path / "none.onnx").error_line("not found")


def test_presets_resolve_against_each_model():
    assert preset_classes("street", ADE20K_CLASSES) == {
        "road": ("road", "sidewalk", "earth"), "building": ("building", "house", "wall"),
        "vegetation": ("tree", "plant", "grass", "field")}
    assert preset_classes("street", CITYSCAPES_CLASSES) == {
        "road": ("road", "sidewalk"), "building": ("building", "wall"), "vegetation": ("vegetation", "terrain")}
    assert preset_classes("indoor", ADE20K_CLASSES) == {"wall": ("wall",), "floor": ("floor",),
                                                        "ceiling": ("ceiling",)}
    with pytest.raises(InputError, match="'indoor' does not fit .* floor: floor; ceiling: ceiling"):
        preset_classes("indoor", CITYSCAPES_CLASSES)
    with pytest.raises(InputError, match="unknown class preset 'garden'"):
        preset_classes("garden", ADE20K_CLASSES)
    # A model described with ADE20K's published names (synonyms after the class's own) or Mapillary Vistas' paths:
    # the groups keep the model's own names.
    published = ("wall", "building;edifice", "sky", "tree", "road;route", "sidewalk;pavement", "earth;ground",
                 "streetlight;street;lamp", "plant;flora;plant;life")
    assert preset_classes("street", published) == {
        "road": ("road;route", "sidewalk;pavement", "earth;ground"), "building": ("building;edifice", "wall"),
        "vegetation": ("tree", "plant;flora;plant;life")}
    vistas = ("construction--flat--road", "construction--structure--building", "nature--vegetation",
              "construction--flat--sidewalk")
    assert preset_classes("street", vistas) == {
        "road": ("construction--flat--road", "construction--flat--sidewalk"),
        "building": ("construction--structure--building",), "vegetation": ("nature--vegetation",)}


def test_coverage_warning_once_naming_what_dominates(robotcar, mosaic):
    frames = [frame.image for frame in folder_traverse(robotcar / "day")]
    indoor = LostDescriber(mosaic, LostConfig(class_preset="indoor"))
    assert indoor.groups.names == ("wall", "floor", "ceiling")
    with pytest.warns(ClassCoverageWarning) as caught:
        for image in frames:
            indoor(image)
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "(wall, floor, ceiling) label 0% of the first 5 frames" in message
    assert "mostly building" in message and "road" in message and "sky" in message
    assert "--class-preset street (covers 7" in message  # measured: 72 %
    street = LostDescriber(mosaic, LostConfig(class_preset="street"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ClassCoverageWarning)
        for image in frames:
            street(image)


def test_coverage_message_is_pure_arithmetic():
    names = ("other", "road", "wall", "floor", "ceiling")
    groups = {"road": ("road",)}
    shares = np.array([0.1, 0.05, 0.5, 0.25, 0.1])
    message = coverage_message(shares, names, groups, frames=5, threshold=0.2)
    assert "label 5% of the first 5 frames (warning below 20%)" in message
    assert "mostly wall 50%, floor 25%, other 10%" in message and "--class-preset indoor (covers 85%)" in message
    assert coverage_message(shares, names, groups, frames=5, threshold=0.05) is None


def test_cli_class_preset_is_recorded_and_its_warning_is_one_line(robotcar, tmp_path, capsys):
    ran = lostx(capsys, "map", "build", robotcar / "day", "--out", tmp_path / "m", "--class-preset", "indoor",
                "--quiet")
    assert ran.code == 0, ran.err
    warned = [line for line in ran.err.splitlines() if line.strip()]
    assert len(warned) == 1 and warned[0].startswith("lostx: warning: the descriptor's classes (wall, floor, ceiling)")
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    assert manifest["classes"] == {"wall": ["wall"], "floor": ["floor"], "ceiling": ["ceiling"]}
    lostx(capsys, "map", "build", robotcar / "day", "--out", tmp_path / "e", "--class-preset", "indoor",
          "--backbone", "espnetv2-cityscapes").error_line("'indoor' does not fit this model")


class LyingBackbone:
    """Promises a 4 x 4 grid, delivers 2 x 2."""

    info = BackboneInfo(name="liar", model_file="", model_md5="", feature_dim=3, grid=(4, 4),
                        class_names=("other", "road"), default_classes={"road": ("road",)})

    def __call__(self, image: np.ndarray) -> SemanticFrame:
        return SemanticFrame(np.ones((3, 2, 2), np.float32), np.full((2, 2, 2), 0.5, np.float32))


def test_a_backbone_output_that_breaks_its_promise_is_an_error():
    with pytest.raises(ModelError, match="gave features 3 x 2 x 2 .* promises 3 x 4 x 4"):
        LostDescriber(LyingBackbone())(np.zeros((8, 8, 3), np.uint8))
