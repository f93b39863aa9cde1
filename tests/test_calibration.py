"""Confidence calibrated on the map itself: wrong answers measured by matching the map against itself."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lostx.core import Config, Localizer, ReferenceMap, build_map
from lostx.core.config import DecisionConfig, SequenceConfig
from lostx.core.decide.calibration import CALIBRATION_FILE, Calibration, load, settings_key
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.core.localizer import calibrate
from lostx.replay.folder import folder_traverse


def test_confidence_is_a_conservative_rank_among_wrong_answers():
    cal = Calibration(np.array([0.1, 0.2, 0.2, 0.4]), np.array([0.5]), {})
    assert cal.sequence_confidence(0.05) == 0.0
    assert cal.sequence_confidence(0.2) == pytest.approx(1 / 5)  # ties count against the answer
    assert cal.sequence_confidence(0.3) == pytest.approx(3 / 5)
    assert cal.sequence_confidence(np.inf) == pytest.approx(4 / 5)  # above all n: n / (n + 1), never 1
    assert Calibration(np.zeros(0), np.zeros(0), {}).sequence_confidence(5.0) == 0.0


@pytest.fixture(scope="module")
def stretch_map(tmp_path_factory, nordland) -> ReferenceMap:
    """400 summer frames as a thumbnail map; the build stores its calibration."""
    out = tmp_path_factory.mktemp("calibration") / "summer"
    build_map(folder_traverse(nordland / "summer").subset(range(1000, 1400)), out, describer=ThumbnailDescriber(),
              progress=False)
    return ReferenceMap.open(out)


def test_the_build_stores_a_calibration_for_its_settings(stretch_map):
    stored = load(stretch_map.path, Config())
    assert stored is not None
    # One impostor per frame in single-frame mode; sequence margins once the window is full.
    assert len(stored.single) == 400
    assert len(stored.sequence) == 400 - (Config().sequence.length - 1)
    assert np.all(np.diff(stored.sequence) >= 0) and np.all(np.isfinite(stored.sequence))


def test_other_settings_are_measured_again_and_kept(stretch_map):
    config = Config(sequence=SequenceConfig(length=10))
    assert load(stretch_map.path, config) is None
    localizer = Localizer(stretch_map, config)
    assert localizer.calibration.settings == settings_key(config)
    assert load(stretch_map.path, config) is not None  # stored beside the map for next time
    assert load(stretch_map.path, Config()) is not None  # beside the build's own
    # The tracker and the decision threshold do not change what wrong answers look like.
    assert settings_key(dataclasses.replace(config, decision=DecisionConfig(min_confidence=0.5))) == \
        settings_key(config)


def test_impostors_never_include_the_excluded_neighbourhood(stretch_map):
    config = Config()
    localizer = Localizer(stretch_map, config)
    exclusion = config.sequence.exclusion
    for index in (0, 200, 399):
        matches = localizer.matcher.match_reference(index, exclusion)
        assert np.all(np.abs(matches.same.candidates - index) > exclusion)


def test_a_map_too_short_to_calibrate_never_claims_to_be_sure(stretch_map):
    short = calibrate(stretch_map, Config(decision=DecisionConfig(calibration_frames=100)))
    assert len(short.sequence) < 999
    assert short.sequence_confidence(np.inf) < Config().decision.min_confidence


def test_a_damaged_calibration_file_is_measured_again(stretch_map):
    (stretch_map.path / CALIBRATION_FILE).write_text("{not json")
    assert load(stretch_map.path, Config()) is None
    Localizer(stretch_map, Config())
    assert load(stretch_map.path, Config()) is not None
