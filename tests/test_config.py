"""The one typed configuration: TOML overrides, errors naming the key, and docs that list every setting."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from lostx.core.config import Config, config_from_dict, load_config
from lostx.core.errors import InputError

DOCS = Path(__file__).resolve().parents[1] / "docs" / "config.md"


def test_docs_list_every_setting():
    text = DOCS.read_text()
    for section in dataclasses.fields(Config):
        assert f"## [{section.name}]" in text
        body = text.split(f"## [{section.name}]")[1].split("\n## ")[0]
        for setting in dataclasses.fields(getattr(Config(), section.name)):
            assert f"| `{setting.name}` |" in body, f"docs/config.md lacks [{section.name}] {setting.name}"


def test_the_documented_example_loads(tmp_path):
    example = re.search(r"```toml\n(.*?)```", DOCS.read_text(), re.S).group(1)
    path = tmp_path / "settings.toml"
    path.write_text(example)
    config = load_config(path)
    assert config.verify.scoring == "released" and config.verify.top_k == 20
    assert config.sequence.acquire_speeds == (0.9, 1.0, 1.1)
    assert config.tracker.enabled is False
    assert config.lost == Config().lost  # untouched sections keep their defaults


@pytest.mark.parametrize(
    "data, message",
    [
        ({"verfy": {}}, "unknown section [verfy]"),
        ({"verify": {"topk": 3}}, "unknown setting 'topk'"),
        ({"verify": {"scoring": "best"}}, "'best' is not one of"),
        ({"sequence": {"length": "ten"}}, "expected int"),
        ({"sequence": {"speeds": 1.0}}, "expected a list"),
    ],
)
def test_bad_settings_name_the_key(data, message):
    with pytest.raises(InputError, match=re.escape(message)):
        config_from_dict(data)


def test_integers_are_accepted_for_floats_and_paths_are_paths():
    config = config_from_dict({"tracker": {"gate_sigma": 3}, "backbone": {"model_path": "/x/model.tflite"}})
    assert config.tracker.gate_sigma == 3.0 and isinstance(config.tracker.gate_sigma, float)
    assert config.backbone.model_path == Path("/x/model.tflite")


def test_broken_toml_is_an_input_error(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[verify\ntop_k = 3")
    with pytest.raises(InputError, match="not valid TOML"):
        load_config(path)
    with pytest.raises(InputError, match="config file not found"):
        load_config(tmp_path / "missing.toml")
