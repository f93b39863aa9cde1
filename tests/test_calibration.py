"""Confidence calibrated on the map itself: wrong answers measured by matching the map against itself."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy import integrate, optimize, stats

from lostx.core import Config, Localizer, ReferenceMap, build_map
from lostx.core.config import DecisionConfig, SequenceConfig
from lostx.core.decide.calibration import CALIBRATION_FILE, PLACES, load, settings_key
from lostx.core.decide.tail import fit_tail, leads
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.core.localizer import calibrate
from lostx.replay.folder import folder_traverse


def exact_lead_survival(law, n: int, x: float) -> float:
    """P(the best of n independent draws of ``law`` leads the second best by more than x), integrated exactly."""
    def density(y: float) -> float:  # of the second best at y, the best above y + x
        return n * (n - 1) * law.pdf(y) * law.cdf(y) ** (n - 2) * law.sf(y + x)

    return integrate.quad(density, law.ppf(1e-9), law.isf(1e-12), limit=200)[0]


def wrong_leads(law, frames: int, places: int, seed: int) -> np.ndarray:
    """Draws of a wrong answer's lead from ``frames`` frames, each compared with ``places`` wrong places whose
    scores follow ``law`` (higher is surer; costs are their negatives, as the localizer's scores are)."""
    rng = np.random.default_rng(seed)
    positions = 10.0 * np.arange(places)  # far apart: every place counts
    return np.concatenate([leads(-law.rvs(size=places, random_state=rng), positions, 5, PLACES)
                           for _ in range(frames)])


def test_the_fitted_tail_gives_the_exact_law_of_a_wrong_answers_lead():
    # Wrong scores from a Gumbel law, 90 wrong places per frame, 400 frames (a map of about 400 frames).
    law, n = stats.gumbel_r, 90
    tail = fit_tail(wrong_leads(law, 400, n, seed=1))
    assert tail.draws == 400 * (PLACES - 1)
    for x in (0.5, 1.0, 2.0, 4.0):
        exact = exact_lead_survival(law, n, x)
        # On the safe side (never below the exact probability), and within 15 % of it.
        assert exact <= tail.survival(x) <= 1.15 * exact, x
    exact_x = optimize.brentq(lambda x: exact_lead_survival(law, n, x) - 1e-3, 0.1, 20)
    fitted_x = optimize.brentq(lambda x: tail.confidence(x) - 0.999, 0.1, 50)
    assert exact_x <= fitted_x <= 1.1 * exact_x  # measured: 6.92 exact, 7.39 fitted


def test_a_map_sized_sample_reaches_0999_soon_after_the_exact_law():
    # Normal wrong scores (the localizer's are means of many costs), 90 places, a map of about 100 frames (80 with
    # a full window). The normal's top spacings shrink slowly with the level, so deeper ones overstate the top's:
    # the fit is conservative.
    law, n = stats.norm, 90
    tail = fit_tail(wrong_leads(law, 80, n, seed=2))
    assert tail.ceiling >= 0.999
    exact_x = optimize.brentq(lambda x: exact_lead_survival(law, n, x) - 1e-3, 0.1, 20)
    fitted_x = optimize.brentq(lambda x: tail.confidence(x) - 0.999, 0.1, 50)
    assert exact_x <= fitted_x <= 1.6 * exact_x  # measured: 2.07 exact, 3.09 fitted
    assert tail.confidence(np.inf) == tail.ceiling < 1


def test_a_handful_of_draws_cannot_claim_0999():
    tail = fit_tail(np.full(20, 0.1))
    assert tail.confidence(np.inf) == pytest.approx(1 - 1 / 210)
    assert tail.draws_for(0.999) == 99
    assert fit_tail(np.zeros(0)).confidence(np.inf) == 0.0


def test_leads_are_the_spacings_of_the_best_distinct_places():
    # Scores (lower is better) at positions; 1.0 and 1.1 lie within 2 of each other: one place.
    scores = np.array([1.0, 1.1, 1.5, 2.5, 4.0, np.nan])
    positions = np.array([10.0, 11.0, 20.0, 30.0, 40.0, 50.0])
    assert leads(scores, positions, 2, 4) == pytest.approx([0.5, 2 * 1.0, 3 * 1.5])


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
    # Single frame, one margin per frame; in sequence mode once the window is full, up to PLACES - 1 leads a frame.
    assert stored.frames == 400 and len(stored.single) == 400
    full = 400 - (Config().sequence.length - 1)
    assert 0.9 * full * (PLACES - 1) <= len(stored.sequence) <= full * (PLACES - 1)
    assert np.all(np.isfinite(stored.sequence)) and np.all(stored.sequence >= 0)


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
    # Ten frames: the 20-frame window never fills, so nothing is known of wrong sequence answers.
    short = calibrate(stretch_map, Config(decision=DecisionConfig(calibration_frames=10)))
    assert len(short.sequence) == 0
    assert short.sequence_confidence(np.inf) == 0.0
    assert short.too_short(True, 0.999) == ("the map is too short to be sure: matched against itself, its 10 frames "
                                            "gave 0 samples of how far wrong answers lead, and a confidence of 0.999 "
                                            "needs 99")
    assert Localizer(stretch_map, Config()).calibration.too_short(True, 0.999) is None


# Measured: 56 of the 100 answers localized; 76 of the 200, where a trajectory that slowed at a tunnel's mouth
# (query 46) led by as much as a right one while two frames behind its confirmed track, and was localized before
# a localized answer had to agree with the track within a frame.
@pytest.mark.parametrize("start, length, localized_count", [(993, 100, 56), (3376, 200, 76)])
def test_a_short_map_is_localized_and_right(nordland, tmp_path, start, length, localized_count):
    """A map of a stretch of summer frames, calibrated on itself alone; its winter frames as queries."""
    frames = range(start, start + length)
    build_map(folder_traverse(nordland / "summer").subset(frames), tmp_path / "map", describer=ThumbnailDescriber(),
              progress=False)
    refmap = ReferenceMap.open(tmp_path / "map")
    winter = folder_traverse(nordland / "winter")
    localizer = Localizer(refmap, Config())
    estimates = [localizer.step(dataclasses.replace(winter.frame(q), id=k)) for k, q in enumerate(frames)]
    localized = [e for e in estimates if e.state == "localized"]
    assert len(localized) == localized_count
    assert all(abs(e.match_index - e.frame_id) <= 1 for e in localized)


def test_a_calibration_stored_by_the_ranks_of_before_is_measured_again(tmp_path):
    # What the margins' ranks stored: sorted margins under settings without the model's name.
    old = settings_key(Config())
    old.pop("model")
    (tmp_path / CALIBRATION_FILE).write_text(json.dumps([{"settings": old, "sequence": [0.1], "single": [0.2]}]))
    assert load(tmp_path, Config()) is None


def test_a_damaged_calibration_file_is_measured_again(stretch_map):
    (stretch_map.path / CALIBRATION_FILE).write_text("{not json")
    assert load(stretch_map.path, Config()) is None
    Localizer(stretch_map, Config())
    assert load(stretch_map.path, Config()) is not None
