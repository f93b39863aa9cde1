"""ESPNetv2 exported to ONNX (``lostx backbones export-onnx``) and run by the generic ONNX backbone: the
PyTorch path's labels, features within a stated tolerance, the same matches on the RobotCar day/night
pair; inspecting an ONNX model; intermediate tensors; and the one-line errors."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import onnx
import pytest

from backbonetools import lostx
from lostx.core import LostDescriber, PlaceMatcher, ReferenceMap, build_map
from lostx.core.backbones import load_backbone
from lostx.core.backbones.graph import read_graph
from lostx.core.config import BackboneConfig
from lostx.core.errors import ModelError
from lostx.replay.folder import folder_traverse

FEATURE_TOLERANCE = 1e-4
"""Largest feature difference from PyTorch, relative to the largest feature (measured: 2.7e-6)."""
PROBABILITY_TOLERANCE = 1e-4
"""Largest class-probability difference from PyTorch (measured: 8e-6)."""


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> Path:
    from lostx.cli import main

    out = tmp_path_factory.mktemp("onnx") / "espnetv2.onnx"
    assert main(["backbones", "export-onnx", "--out", str(out)]) == 0
    assert out.with_suffix(".toml").is_file()
    return out


class Remembered:
    """A backbone that runs its network once per distinct frame (the tests ask for each frame twice)."""

    def __init__(self, backbone) -> None:
        self.backbone, self.info, self.seen = backbone, backbone.info, {}

    def __call__(self, image: np.ndarray):
        key = hashlib.md5(image.tobytes()).hexdigest()
        if key not in self.seen:
            self.seen[key] = self.backbone(image)
        return self.seen[key]


@pytest.fixture(scope="module")
def pytorch_and_onnx(exported):
    # One thread: PyTorch's spinning OpenMP threads are many times slower on a busy machine (docs/backbones.md).
    pytorch = load_backbone(BackboneConfig(name="espnetv2-cityscapes", device="cpu", threads=1))
    onnx_backbone = load_backbone(BackboneConfig(name="onnx", model_path=exported, device="cpu", threads=1))
    return Remembered(pytorch), Remembered(onnx_backbone)


def test_onnx_gives_the_pytorch_labels_and_features_within_tolerance(robotcar, pytorch_and_onnx):
    pytorch, onnx_backbone = pytorch_and_onnx
    assert onnx_backbone.info.grid == pytorch.info.grid == (24, 48) and onnx_backbone.info.feature_dim == 512
    assert onnx_backbone.info.class_names == pytorch.info.class_names
    assert onnx_backbone.info.default_classes == pytorch.info.default_classes
    assert onnx_backbone.backbone.providers == ["CPUExecutionProvider"]
    for folder in ("day", "night"):
        for frame in folder_traverse(robotcar / folder):
            a, b = pytorch(frame.image), onnx_backbone(frame.image)
            np.testing.assert_array_equal(a.labels(), b.labels())
            assert np.abs(a.features - b.features).max() <= FEATURE_TOLERANCE * np.abs(a.features).max()
            assert np.abs(a.probs - b.probs).max() <= PROBABILITY_TOLERANCE


def test_onnx_and_pytorch_give_the_same_matches_night_to_day(robotcar, pytorch_and_onnx, tmp_path):
    found = {}
    for name, backbone in zip(("pytorch", "onnx"), pytorch_and_onnx):
        build_map(folder_traverse(robotcar / "day"), tmp_path / name, describer=LostDescriber(backbone),
                  progress=False)
        matcher = PlaceMatcher(ReferenceMap.open(tmp_path / name), backbone=backbone)
        found[name] = [matcher.match(frame.image).same.candidates.tolist() for frame in folder_traverse(robotcar / "night")]
    assert found["onnx"] == found["pytorch"]  # every night frame's ranked candidates
    assert sum(candidates[0] == k for k, candidates in enumerate(found["onnx"])) == 2  # as test_espnet.py measures


def test_inspect_suggests_the_exported_outputs(exported, capsys):
    ran = lostx(capsys, "backbones", "inspect", exported)
    assert ran.code == 0, ran.err
    assert "input   image  1x3x384x768  float32" in ran.out
    assert 'features = "features"  # 512 channels on a 24 x 48 grid' in ran.out
    assert 'scores = "logits"  # 20 channels on a 192 x 384 grid' in ran.out


def test_an_intermediate_tensor_can_be_named(robotcar, exported, tmp_path):
    # The input of the PReLU that makes the exported features: the same map before its activation.
    before = read_graph(exported).producers["features"][1]
    text = exported.with_suffix(".toml").read_text().replace('features = "features"', f'features = "{before}"')
    model = tmp_path / "pre.onnx"
    model.symlink_to(exported)
    model.with_suffix(".toml").write_text(text.replace(f'model = "{exported.name}"', 'model = "pre.onnx"'))
    pre = load_backbone(BackboneConfig(name="onnx", model_path=model, device="cpu"))
    post = load_backbone(BackboneConfig(name="onnx", model_path=exported, device="cpu"))
    assert pre.info.feature_tensor == before and pre.info.grid == (24, 48)
    image = next(iter(folder_traverse(robotcar / "day"))).image
    a, b = pre(image).features, post(image).features
    positive = a > 0
    assert 0.05 < positive.mean() < 0.95 and not np.array_equal(a, b)
    np.testing.assert_allclose(a[positive], b[positive], rtol=1e-6)  # PReLU passes positive values unchanged


def test_onnx_description_errors(exported, tmp_path):
    model = tmp_path / "net.onnx"
    model.symlink_to(exported)
    base = exported.with_suffix(".toml").read_text().replace(f'model = "{exported.name}"', 'model = "net.onnx"')
    weight = next(iter(onnx.load(str(exported)).graph.initializer)).name
    for features, message in ((weight, "is a weight, not an activation"), ("nowhere", "is no tensor of the graph")):
        model.with_suffix(".toml").write_text(base.replace('features = "features"', f'features = "{features}"'))
        with pytest.raises(ModelError, match=message):
            load_backbone(BackboneConfig(name="onnx", model_path=model, device="cpu"))
    model.with_suffix(".toml").write_text(base.replace("input_size = [768, 384]", "input_size = [512, 512]"))
    with pytest.raises(ModelError, match="failed to run"):
        load_backbone(BackboneConfig(name="onnx", model_path=model, device="cpu"))


def test_onnx_errors_on_the_command_line(robotcar, exported, tmp_path, capsys):
    build = ("map", "build", robotcar / "day", "--out", tmp_path / "m", "--backbone", "onnx")
    lostx(capsys, *build, "--model", exported, "--device", "cuda").error_line(
        "device 'cuda' was asked for", "onnxruntime-gpu", "--device cpu")
    lostx(capsys, *build, "--model", exported, "--device", "tpu").error_line("'tpu' is not one of auto, cpu, cuda")
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"\x08\x01garbage" * 100)
    garbage.with_suffix(".toml").write_text(exported.with_suffix(".toml").read_text().replace(
        f'model = "{exported.name}"', 'model = "garbage.onnx"'))
    lostx(capsys, *build, "--model", garbage).error_line("garbage.onnx is not an ONNX model")
    lostx(capsys, *build).error_line("backbone 'onnx' needs its model", "--model PATH")
    assert not (tmp_path / "m").exists()


def test_export_errors(exported, tmp_path, capsys):
    lostx(capsys, "backbones", "export-onnx", "--out", exported).error_line("already exists", "--overwrite")
    lostx(capsys, "backbones", "export-onnx", "--out", tmp_path / "net.pt").error_line("must end in .onnx")
    fake = tmp_path / "fake.pth"
    fake.write_bytes(b"not weights")
    lostx(capsys, "backbones", "export-onnx", "--model", fake, "--out", tmp_path / "x.onnx").error_line(
        "fake.pth is not a PyTorch checkpoint")
    assert not (tmp_path / "x.onnx").exists() and not (tmp_path / "x.toml").exists()
