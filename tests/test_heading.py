"""The heading, found from the evidence: both mirrorings verified, votes, the two-state filter, the direction
of travel tied to a declared camera."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.config import HeadingConfig
from lostx.core.route.heading import HeadingFilter, TwoStateFilter
from lostx.core.describe.keypoints import frame_evidence
from lostx.core.match.matcher import heading_vote
from lostx.core.match.verify import verify


def _image(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    features = np.maximum(rng.normal(size=(24, 8, 12)), 0).astype(np.float32)
    labels = rng.integers(0, 3, size=(8, 12)).astype(np.uint8)
    return features, labels


def test_both_mirrorings_share_the_correspondences(rng):
    features, labels = _image(rng)
    image = frame_evidence(features, labels)
    mirror = frame_evidence(features[:, :, ::-1].copy(), labels[:, ::-1].copy())
    asked_same = verify(mirror, image, np.array([0.3]), opposite=False)
    asked_opposite = verify(mirror, image, np.array([0.3]), opposite=True)
    # One call scores both hypotheses: the other call's scores are its mirror scores.
    assert asked_same.mirror_scores[0] == pytest.approx(asked_opposite.scores[0])
    assert asked_opposite.mirror_scores[0] == pytest.approx(asked_same.scores[0])
    assert asked_opposite.scores[0] < asked_same.scores[0]  # a mirrored image fits the opposite heading


def test_a_vote_is_the_mean_sign_over_candidates_scored_both_ways():
    same = np.array([0.5, 0.4, np.inf, 0.2, 0.9])
    opposite = np.array([0.3, 0.1, 0.2, np.inf, 0.9])
    # Candidates 0 and 1 favour opposite, 4 is a tie; 2 and 3 are not scored finitely both ways.
    assert heading_vote(same, opposite) == pytest.approx(2 / 3)
    assert heading_vote(np.array([np.inf]), np.array([0.1])) == 0.0


def test_votes_move_the_belief_as_far_as_their_reliability_allows():
    f = TwoStateFilter(("same", "opposite"), reliability=0.75, switch=0.0)
    assert f.answer() == ("same", 0.5)
    state, p = f.update(+1.0)
    assert (state, p) == ("opposite", pytest.approx(0.75))
    state, p = f.update(+1.0)
    assert p == pytest.approx(0.75**2 / (0.75**2 + 0.25**2))
    # A split vote counts for less; no vote leaves the belief alone.
    before = f.belief.copy()
    f.update(0.0)
    np.testing.assert_allclose(f.belief, before)
    f.update(-0.5)
    assert f.belief[1] == pytest.approx(0.9 * 0.375 / (0.9 * 0.375 + 0.1 * 0.625))


def test_the_switch_probability_keeps_the_belief_from_freezing():
    f = TwoStateFilter(("same", "opposite"), reliability=0.65, switch=0.01)
    for _ in range(200):
        f.update(-1.0)
    # Steady state: the swap each frame (1 %) against a vote of odds 0.65 / 0.35.
    sure = f.answer()[1]
    assert 0.985 < sure < 0.99
    flips = 0
    while f.answer()[0] == "same":
        f.update(+1.0)
        flips += 1
    assert flips < 20  # a real change of heading (a U-turn) is followed within a few frames


def test_a_declaration_is_a_prior_and_evidence_overrides_it():
    heading = HeadingFilter(HeadingConfig(declared_prior=0.9, vote_reliability=0.7, switch=0.0))
    assert heading.update(0.0, declared="opposite") == ("opposite", pytest.approx(0.9))
    answers = [heading.update(-1.0, declared="opposite") for _ in range(6)]
    assert answers[0][0] == "opposite" and answers[-1][0] == "same"
    # A declaration that changes is a new prior.
    assert heading.update(0.0, declared="same")[0] == "same"


def test_a_trusted_declaration_never_weighs_the_evidence():
    heading = HeadingFilter(HeadingConfig(declared_prior=1.0))
    assert all(heading.update(+1.0, declared="same") == ("same", 1.0) for _ in range(50))
