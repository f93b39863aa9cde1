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
from lostx.core.backbones.graph import names_activation, read_graph
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


def _tiny_segmenter(path: Path) -> Path:
    """A small ONNX segmenter shaped like DeepLabV3+ on MobileNetV2: at 1/16 of the input, a block's ReLU6
    output (192 channels) feeds its linear projection (96 channels), which three decoder branches read."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    weights, nodes = [], []

    def conv(name: str, source: str, out: int, into: int, kernel: int = 1, stride: int = 1) -> None:
        weights.append(numpy_helper.from_array(
            rng.standard_normal((out, into, kernel, kernel)).astype(np.float32) * 0.1, f"{name}_w"))
        nodes.append(helper.make_node("Conv", [source, f"{name}_w"], [name], strides=[stride, stride],
                                      pads=[kernel // 2] * 4 if stride == 1 else [0] * 4))

    conv("stem", "image", 64, 3, kernel=16, stride=16)
    nodes.append(helper.make_node("Relu", ["stem"], ["stem_relu"]))
    conv("expand", "stem_relu", 192, 64)
    weights += [numpy_helper.from_array(np.array(v, np.float32), n) for v, n in ((0.0, "low"), (6.0, "high"))]
    nodes.append(helper.make_node("Clip", ["expand", "low", "high"], ["expand_relu6"]))
    conv("project", "expand_relu6", 96, 192)
    for branch, kernel in (("aspp_a", 1), ("aspp_b", 3), ("aspp_c", 1)):
        conv(branch, "project", 16, 96, kernel=kernel)
    nodes.append(helper.make_node("Concat", ["aspp_a", "aspp_b", "aspp_c"], ["aspp"], axis=1))
    conv("logits_small", "aspp", 5, 48)
    weights.append(numpy_helper.from_array(np.array([1, 1, 16, 16], np.float32), "scales"))
    nodes.append(helper.make_node("Resize", ["logits_small", "", "scales"], ["logits"], mode="linear"))
    graph = helper.make_graph(
        nodes, "tiny", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 128, 128])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, 5, 128, 128])], weights)
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)]), path)
    return path


def test_inspect_prefers_the_activation_to_the_linear_projection_it_feeds(tmp_path, capsys):
    model = _tiny_segmenter(tmp_path / "tiny.onnx")
    graph = read_graph(model)
    tensors = {t.name: t for t in graph.activations}
    assert tensors["project"].readers == 3 and tensors["expand_relu6"].readers == 1  # the projection is read most
    assert tensors["expand_relu6"].activation and tensors["stem_relu"].activation and not tensors["project"].activation
    ran = lostx(capsys, "backbones", "inspect", model)
    assert ran.code == 0, ran.err
    assert 'features = "expand_relu6"  # 192 channels on a 8 x 8 grid' in ran.out
    assert 'scores = "logits_small"  # 5 channels on a 8 x 8 grid' in ran.out


@pytest.mark.parametrize("name, fused", [
    ("MobilenetV2/expanded_conv_16/depthwise/Relu6", True), ("MobilenetV3/Conv_1/Relu", True),
    ("block/hard_swish", True), ("MobilenetV2/expanded_conv_16/project/add_fold", False), ("decoder/add", False),
    ("aspp/concat_projection/BatchNorm/FusedBatchNorm", False),
])
def test_a_fused_activation_is_told_by_the_tensor_name(name, fused):
    assert names_activation(name) is fused
