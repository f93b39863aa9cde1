"""The heading, found from the evidence: both mirrorings verified, votes, the two-state filter, the direction
of travel tied to a declared camera."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.config import HeadingConfig
from lostx.core.route.direction import TwoStateFilter
from lostx.core.route.heading import HeadingFilter, VoteTally
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


def test_the_two_state_filter_moves_the_belief_as_far_as_its_reliability_allows():
    """The direction of travel's filter (lostx.core.route.direction) accumulates votes of a known reliability."""
    f = TwoStateFilter(("same", "opposite"), reliability=0.75, switch=0.0)
    assert f.answer() == ("same", 0.5)
    state, p = f.update(+1.0)
    assert (state, p) == ("opposite", pytest.approx(0.75))
    state, p = f.update(+1.0)
    assert p == pytest.approx(0.75**2 / (0.75**2 + 0.25**2))
    before = f.belief.copy()
    f.update(0.0)
    np.testing.assert_allclose(f.belief, before)


def _votes(rng, mean: float, n: int) -> list[float]:
    return list(np.clip(mean + rng.normal(scale=0.5, size=n), -1, 1))


def test_voters_that_agree_make_the_heading_sure(rng):
    heading = HeadingFilter(HeadingConfig())
    mirror, motion = _votes(rng, 0.5, 40), _votes(rng, 0.5, 40)
    answers = [heading.update({"mirror": a, "motion": b}) for a, b in zip(mirror, motion)]
    assert answers[-1][0] == "opposite" and answers[-1][1] > 0.9
    assert answers[1][1] == 0.5  # no voter has voted three times yet: nothing is known


def test_voters_that_disagree_leave_the_heading_uncertain_however_long_they_vote(rng):
    """Each voter alone is sure of its side after 200 frames; together they say nothing."""
    votes = {"mirror": _votes(rng, 0.4, 200), "motion": _votes(rng, -0.4, 200)}
    alone = {}
    for name in votes:
        only = HeadingFilter(HeadingConfig())
        for v in votes[name]:
            answer = only.update({name: v})
        alone[name] = answer
    assert alone["mirror"][0] == "opposite" and alone["mirror"][1] > 0.85
    assert alone["motion"][0] == "same" and alone["motion"][1] > 0.85
    both = HeadingFilter(HeadingConfig())
    for a, b in zip(votes["mirror"], votes["motion"]):
        answer = both.update({"mirror": a, "motion": b})
    assert answer[1] < 0.6


def test_a_voter_that_is_noise_gets_no_say():
    """A voter whose votes average nothing leaves a sure voter sure, and alone says little: over 20 streams of 60
    frames its heading is a coin toss held with a mean confidence near 1/2, never near certainty."""
    together, alone = [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        sure, noisy = _votes(rng, 0.6, 60), _votes(rng, 0.0, 60)
        with_noise, noise_only = HeadingFilter(HeadingConfig()), HeadingFilter(HeadingConfig())
        for a, b in zip(sure, noisy):
            answer = with_noise.update({"mirror": a, "motion": b})
            noise = noise_only.update({"motion": b})
        together.append(answer)
        alone.append(noise)
    assert all(h == "opposite" and p > 0.85 for h, p in together)
    assert np.mean([p for _, p in alone]) < 0.7 and max(p for _, p in alone) < 0.9
    assert 5 <= sum(h == "opposite" for h, _ in alone) <= 15


def test_correlated_votes_count_for_fewer_frames():
    """The same evidence repeated frame after frame (each vote copied four times: neighbouring frames seeing the same
    road) is known no better than once, not twice as well as four times as many votes would be."""
    rng = np.random.default_rng(7)
    base = _votes(rng, 0.15, 60)
    once, repeated = VoteTally(np.inf), VoteTally(np.inf)
    for v in base:
        once.add(v)
    for v in np.repeat(base, 4):
        repeated.add(float(v))
    (d_once, se_once), (d_repeated, se_repeated) = once.effect(), repeated.effect()
    assert d_repeated == pytest.approx(d_once, rel=0.1)
    assert se_repeated >= se_once > 1.5 * se_once / 2  # independent votes would halve it


def test_a_declaration_is_a_prior_and_evidence_overrides_it(rng):
    heading = HeadingFilter(HeadingConfig(declared_prior=0.9, switch=0.0))
    assert heading.update({}, declared="opposite") == ("opposite", pytest.approx(0.9))
    for vote in _votes(rng, -0.8, 30):
        answer = heading.update({"mirror": vote, "motion": vote}, declared="opposite")
    assert answer[0] == "same"


def test_a_trusted_declaration_never_weighs_the_evidence():
    heading = HeadingFilter(HeadingConfig(declared_prior=1.0))
    assert all(heading.update({"mirror": 1.0, "motion": 1.0}, declared="same") == ("same", 1.0) for _ in range(50))


def test_the_heading_state_carries_its_votes(rng):
    votes = [{"mirror": a, "motion": b} for a, b in zip(_votes(rng, 0.3, 20), _votes(rng, 0.2, 20))]
    whole = HeadingFilter(HeadingConfig())
    answers = [whole.update(v) for v in votes]
    first = HeadingFilter(HeadingConfig())
    for v in votes[:10]:
        first.update(v)
    second = HeadingFilter(HeadingConfig())
    second.restore(first.state())
    assert [second.update(v) for v in votes[10:]] == answers[10:]
