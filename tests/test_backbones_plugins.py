"""Backbones from outside the package: an entry-point plugin installed in the test environment, a
``module:factory`` on the command line, the documented ``register_backbone`` example, and the one-line
errors for each (torch and onnxruntime not installed included)."""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from backbonetools import answers, lostx, lostx_child
from lostx.core import PlaceMatcher, backbone_names, load_backbone
from lostx.core.backbones import registry
from lostx.core.config import BackboneConfig
from lostx.replay.folder import folder_traverse

DOCS = Path(__file__).resolve().parents[1] / "docs" / "backbones.md"

PLUGIN = '''
import dataclasses

from lostx.core.backbones import load_backbone


def street_mosaic(config, model_path):
    """The default network under the plugin's own name."""
    return load_backbone(dataclasses.replace(config, name="mosaic-ade20k", model_path=model_path))


def not_a_backbone(config, model_path):
    return {"features": None}
'''


@pytest.fixture
def isolated(monkeypatch):
    """Undo what loading plugins changes: the Python path and the registered backbones (each test's plugin
    modules have names of their own)."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    monkeypatch.setattr(registry, "_REGISTERED", dict(registry._REGISTERED))
    return monkeypatch


def install_plugin(site: Path, module_name: str, entry_points: str, module: str = PLUGIN) -> Path:
    """A package with entry points, visible to importlib.metadata once ``site`` is on the Python path."""
    site.mkdir(parents=True, exist_ok=True)
    (site / f"{module_name}.py").write_text(module)
    dist = site / f"{module_name}-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {module_name.replace('_', '-')}\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[lostx.backbones]\n{entry_points}\n")
    return site


def test_entry_point_plugin_builds_and_matches_a_map(robotcar, day_map, tmp_path, capsys, isolated):
    site = install_plugin(tmp_path / "site", "lostx_street_plugin", "street-mosaic = lostx_street_plugin:street_mosaic")
    with isolated.context() as installed:
        installed.syspath_prepend(str(site))
        listed = lostx(capsys, "backbones")
        assert re.search(r"^street-mosaic\s", listed.out, re.M), listed.out
        assert lostx(capsys, "map", "build", robotcar / "day", "--out", tmp_path / "day", "--backbone",
                     "street-mosaic", "--quiet").code == 0
        # Matched without --backbone: the plugin is found again by the name the map records.
        ran = lostx(capsys, "match", tmp_path / "day", robotcar / "night", "--out", tmp_path / "plugin.csv", "--quiet")
        assert ran.code == 0, ran.err
    assert json.loads((tmp_path / "day" / "manifest.json").read_text())["backbone"]["name"] == "street-mosaic"
    np.testing.assert_array_equal(np.load(tmp_path / "day" / "descriptors.npy"),
                                  np.load(day_map.path / "descriptors.npy"))
    builtin = PlaceMatcher(day_map)
    assert [m for m, _ in answers(tmp_path / "plugin.csv")] == \
        [builtin.match(frame.image).same.best for frame in folder_traverse(robotcar / "night")]
    # Without the plugin installed, the map's backbone is unknown, and said so.
    lostx(capsys, "match", tmp_path / "day", robotcar / "night", "--out", tmp_path / "x.csv").error_line(
        "unknown backbone 'street-mosaic'", "package.module:factory")


def test_entry_point_errors_are_one_line(robotcar, tmp_path, capsys, isolated):
    site = install_plugin(tmp_path / "site", "lostx_odd_plugin",
                          "broken = lostx_odd_plugin:street_mosaic\nodd = lostx_odd_plugin:not_a_backbone\n"
                          "gone = lostx_odd_plugin:nothing_here",
                          module="import package_that_is_not_installed\n" + PLUGIN)
    isolated.syspath_prepend(str(site))
    build = ("map", "build", robotcar / "day", "--out", tmp_path / "m", "--backbone")
    lostx(capsys, *build, "broken").error_line("backbone 'broken' (plugin of lostx-odd-plugin)",
                                               "cannot import lostx_odd_plugin", "package_that_is_not_installed")
    (site / "lostx_odd_plugin.py").write_text(PLUGIN)
    lostx(capsys, *build, "odd").error_line("backbone 'odd' gave a dict, not a backbone")
    lostx(capsys, *build, "gone").error_line("lostx_odd_plugin has no 'nothing_here'")
    assert not (tmp_path / "m").exists()


def documented_example() -> str:
    """The complete backbone module of docs/backbones.md."""
    module = [b for b in re.findall(r"```python\n(.*?)```", DOCS.read_text(), re.S) if "@register_backbone" in b]
    assert len(module) == 1
    return module[0]


def test_documented_register_backbone_example_runs(robotcar, tmp_path, capsys, isolated):
    (tmp_path / "my_backbones.py").write_text(documented_example())
    spec = importlib.util.spec_from_file_location("my_backbones", tmp_path / "my_backbones.py")
    spec.loader.exec_module(importlib.util.module_from_spec(spec))  # registers "edges"
    assert "edges" in backbone_names()
    frame = load_backbone(BackboneConfig(name="edges"))(next(iter(folder_traverse(robotcar / "day"))).image)
    assert frame.features.shape == (8, 16, 24) and frame.probs.shape == (3, 16, 24)
    np.testing.assert_allclose(frame.probs.sum(axis=0), 1.0, rtol=1e-6)

    # The command line takes the same class as module:factory from the current folder.
    isolated.chdir(tmp_path)
    assert lostx(capsys, "map", "build", robotcar / "day", "--out", tmp_path / "day", "--backbone",
                 "my_backbones:EdgeBackbone", "--quiet").code == 0
    recorded = json.loads((tmp_path / "day" / "manifest.json").read_text())["backbone"]
    assert (recorded["name"], recorded["grid"], recorded["feature_dim"]) == ("my_backbones:EdgeBackbone", [16, 24], 8)
    assert lostx(capsys, "match", tmp_path / "day", robotcar / "day", "--out", tmp_path / "day.csv",
                 "--quiet").code == 0
    assert [m for m, _ in answers(tmp_path / "day.csv")] == list(range(10))  # each day frame finds itself


@pytest.mark.parametrize("spec, fragment", [
    ("no_such_module_here:make", "cannot import no_such_module_here"),
    ("json:no_such_factory", "json has no 'no_such_factory'"),
    ("not-a-backbone", "unknown backbone 'not-a-backbone'; available: espnetv2-cityscapes, mosaic-ade20k, onnx"),
])
def test_module_factory_errors_are_one_line(robotcar, tmp_path, capsys, isolated, spec, fragment):
    lostx(capsys, "map", "build", robotcar / "day", "--out", tmp_path / "m", "--backbone", spec).error_line(fragment)


@pytest.mark.parametrize("missing, args, fragment", [
    ("torch", ("--backbone", "espnetv2-cityscapes"), "needs torch, which is not installed: pip install 'lostx[torch]'"),
    ("onnxruntime", ("--backbone", "onnx", "--model", "MODEL"),
     "needs onnxruntime, which is not installed: pip install 'lostx[onnx]'"),
])
def test_a_missing_optional_package_names_its_extra(robotcar, tmp_path, missing, args, fragment):
    toml = tmp_path / "net.toml"
    toml.write_text('model = "net.onnx"\nfeatures = "f"\nscores = "s"\nclasses = ["road"]\n'
                    'default_classes = { road = ["road"] }\n')
    (tmp_path / "net.onnx").write_bytes(b"x")
    args = tuple(str(toml) if a == "MODEL" else a for a in args)
    lostx_child("map", "build", robotcar / "day", "--out", tmp_path / "m", *args, blocked=(missing,)).error_line(
        fragment)


def test_the_default_backbone_and_help_need_neither_torch_nor_onnxruntime(robotcar, tmp_path):
    ran = lostx_child("map", "build", robotcar / "day", "--out", tmp_path / "m", "--quiet",
                      blocked=("torch", "onnxruntime", "onnx"))
    assert ran.code == 0 and "built" in ran.out, ran.err
    check = ("import sys; from lostx.cli import build_parser; build_parser(); "
             "print(sorted({'torch', 'onnxruntime', 'onnx'} & set(sys.modules)))")
    assert subprocess.run([sys.executable, "-c", check], capture_output=True, text=True).stdout.strip() == "[]"
