"""The one typed configuration: TOML overrides, errors naming the key, and docs that list every setting."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from lostx.core.config import LIMITS, Config, config_from_dict, load_config
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


@pytest.mark.parametrize(
    "data, message",
    [
        ({"sequence": {"length": -3}}, "[sequence] length must be between 1 and 100000, got -3"),
        ({"sequence": {"length": 0}}, "[sequence] length must be between 1 and 100000, got 0"),
        ({"verify": {"top_k": -2}}, "[verify] top_k must be at least 1, got -2"),
        ({"backbone": {"threads": 0}}, "[backbone] threads must be between 1 and 256, got 0"),
        ({"decision": {"min_confidence": 1.5}}, "[decision] min_confidence must be between 0 and 1, got 1.5"),
        ({"heading": {"misled": 0.6}}, "[heading] misled must be above 0, at most 0.5, got 0.6"),
        ({"cues": {"weights": {"gps": 1.0}}}, "[cues] weights: unknown cue 'gps'; cues: lostx, layout, appearance"),
        ({"camera": {"hfov_deg": {"rear": 0}}}, "[camera] hfov_deg must be above 0, at most 180, got 0.0"),
        ({"sequence": {"speeds": []}}, "[sequence] speeds must not be empty"),
        ({"sequence": {"acquire_speeds": [1.0, float("nan")]}}, "[sequence] acquire_speeds must be above 0, got nan"),
        ({"sequence": {"speeds": [1.0, -0.5]}}, "[sequence] speeds must be at least 0, got -0.5"),
        ({"tracker": {"gate_sigma": 0}}, "[tracker] gate_sigma must be above 0, got 0.0"),
        ({"stream": {"stats_interval": -1}}, "[stream] stats_interval must be above 0, got -1.0"),
    ],
)
def test_values_outside_their_range_name_the_file_and_the_key(data, message):
    with pytest.raises(InputError) as caught:
        config_from_dict(data, source="settings.toml")
    assert str(caught.value) == f"settings.toml: {message}"


def test_every_way_of_making_a_config_checks_the_ranges():
    config = Config()
    with pytest.raises(InputError, match=r"\[sequence\] length must be between 1 and 100000, got -1"):
        dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, length=-1))
    with pytest.raises(InputError, match=r"\[verify\] top_k must be at least 1, got 0"):
        Config(verify=dataclasses.replace(config.verify, top_k=0))
    edge = dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, length=1),
                               decision=dataclasses.replace(config.decision, min_confidence=1.0))
    assert edge.sequence.length == 1  # the ends of a range are valid values


def _numeric(hint) -> bool:
    import typing

    args = typing.get_args(hint)
    return hint in (int, float) or (typing.get_origin(hint) is tuple and args and args[0] in (int, float))


def test_every_numeric_setting_has_a_range_and_every_range_a_setting():
    import typing

    for name, rules in LIMITS.items():
        hints = typing.get_type_hints(type(getattr(Config(), name)))
        for key in rules:
            assert key in hints, f"LIMITS names [{name}] {key}, which is not a setting"
        for key, hint in hints.items():
            if _numeric(hint):
                assert key in rules, f"[{name}] {key} has no valid range in LIMITS"
    assert set(LIMITS) <= {f.name for f in dataclasses.fields(Config)}


def test_docs_list_every_valid_range():
    body = DOCS.read_text().split("## Valid values")[1]
    for name, rules in LIMITS.items():
        for key, bounds in rules.items():
            assert re.search(rf"\| `\[{name}\] {key}` \| {re.escape(bounds.describe())}[ (]", body), (name, key)
