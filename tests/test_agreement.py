"""Cues earn their weight by agreeing with the motion: synthetic scores of a vehicle driving along a map."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.match.costs import EveryFrameCosts
from lostx.core.match.scores import MapScores
from lostx.core.motion.odometer import forwards, mounting
from lostx.core.route.agreement import CueAgreement, Disagreement, Tally, agrees, chance
from lostx.core.route.sequence import SequenceFilter, SequenceResult, signed

N = 200


def _filter() -> SequenceFilter:
    return SequenceFilter(20, tuple(signed((0.8, 0.9, 1.0, 1.1, 1.2), stopped=False)), 0, 0.0,
                          EveryFrameCosts(N, 20, 10, 100.0), 20, 5)


def _seeing(rng: np.random.Generator, place: int) -> np.ndarray:
    """A cue that sees the place: a valley around it over noise."""
    return np.abs(np.arange(N) - place) / 2.0 + rng.normal(scale=0.5, size=N)


def _blind(rng: np.random.Generator, place: int) -> np.ndarray:
    return rng.normal(size=N)


def _run(cue, frames: int = 60, seed: int = 0) -> CueAgreement:
    rng = np.random.default_rng(seed)
    agreement = CueAgreement(_filter, memory=40.0, within=2.0)
    for t in range(frames):
        scores = cue(rng, 20 + t)
        ranked = np.argsort(scores)
        agreement.update(MapScores.of_array(scores), int(ranked[0]), ranked[:10], ranked[:10], None)
    return agreement


def test_a_cue_that_sees_the_places_earns_weight_and_noise_earns_none():
    seeing = [_run(_seeing, seed=s).weight(N) for s in range(5)]
    blind = [_run(_blind, seed=s).weight(N) for s in range(5)]
    assert min(seeing) > 0.5
    assert max(blind) < 0.05


def test_a_cue_starts_with_no_weight_and_a_lucky_frame_is_not_enough():
    tally = Tally(memory=40.0)
    assert tally.weight(0.05) == 0.0
    tally.add(True)
    assert tally.weight(0.05) < 0.5  # one agreement in one prediction: shown only so far
    for _ in range(39):
        tally.add(True)
    assert tally.weight(0.05) > 0.85
    counted = tally.predicted
    tally.add(None)  # no prediction: nothing counted
    assert tally.predicted == counted


def test_agreement_is_judged_against_the_trajectory_before_the_frame():
    before = SequenceResult(position=50.0, speed=1.2, score=-1.0, frames=10, trajectory=np.zeros(10), mean=-1.0)
    # It predicts 51.2: the position plus the speed, the reference frames it moves a frame.
    assert agrees(53, before, 2.0) and agrees(50, before, 2.0)
    assert not agrees(54, before, 2.0) and not agrees(49, before, 2.0)
    assert agrees(53, None, 2.0) is None
    assert chance(200, 2.0) == pytest.approx(5 / 200)


def test_the_motion_and_the_matches_disagree_when_few_answers_keep_to_the_line():
    d = Disagreement()
    for agreed in (True, False, False):
        d.add(agreed)
    assert not d.disagree  # too few predictions to tell
    d.add(False)
    assert d.disagree  # 1 of 4
    for agreed in (True, True, False, False):
        d.add(agreed)
    assert not d.disagree  # 3 of the last 8
    d.add(None)
    assert not d.disagree


def test_progress_is_along_the_vehicle_whichever_way_its_camera_looks():
    """A vehicle driving 2 m straight ahead: the step each camera sees in its own ground frame."""
    for yaw in (0.0, 55.0, 90.0, 180.0, -110.0):
        a = np.radians(yaw)
        step = np.array([2.0 * np.cos(-a), 2.0 * np.sin(-a), 0.0])  # the vehicle's motion turned into the camera's
        assert forwards(step, yaw) == pytest.approx(2.0)
    assert forwards(np.array([2.0, 0.0, 0.0]), 180.0) == pytest.approx(-2.0)  # a rear camera moving its own way


def test_the_mounting_ties_the_heading_to_the_direction_of_travel():
    assert mounting(0.0, 0.0) == 1 and mounting(180.0, 180.0) == 1 and mounting(55.0, 110.0) == 1
    assert mounting(0.0, 180.0) == -1 and mounting(-55.0, 110.0) == -1
    assert mounting(90.0, 0.0) == 0 and mounting(-110.0, 0.0) == 0
