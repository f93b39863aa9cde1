"""Following a route driven the mapped way: the direction of travel found from the evidence, the answers while
the window fills, a track held through a bad frame. Real Nordland and RobotCar frames where the behaviour depends
on them, small synthetic numbers where it does not."""

from __future__ import annotations


import numpy as np
import pytest

from lostx.core import Config, Localizer, build_map
from lostx.core.config import SequenceConfig, TrackerConfig
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.core.maps.refmap import ReferenceMap
from lostx.core.route.direction import DirectionFilter
from lostx.core.route.tracker import RouteTracker
from lostx.replay.folder import folder_traverse

from test_localizer import _night


def test_the_direction_follows_the_cheaper_sign_and_turns_with_the_evidence():
    direction = DirectionFilter(reliability=0.65, switch=0.0003, scale=1.0)
    for _ in range(12):
        sign, sure = direction.update(rising=-0.8, falling=0.4)  # rising trajectories cost less
    assert sign == 1 and sure > 0.99
    # A frame without both signs (the other one pruned) casts no vote.
    assert direction.update(rising=-0.8, falling=np.inf) == (1, pytest.approx(sure, abs=1e-3))
    for _ in range(40):
        sign, sure = direction.update(rising=0.5, falling=-0.5)
    assert sign == -1 and sure > 0.99


def test_a_small_difference_votes_in_proportion():
    strong, weak = (DirectionFilter(0.65, 0.0, 1.0) for _ in range(2))
    strong.update(-1.0, 0.0)
    weak.update(-0.1, 0.0)
    assert strong.belief[0] == pytest.approx(0.65)
    assert weak.belief[0] == pytest.approx(0.515)


def test_an_unconfident_track_holds_the_answer_through_one_bad_frame():
    tracker = RouteTracker(TrackerConfig(acquire_after=5))
    steps = [tracker.step(10.0 + t, 1.0, confident=False) for t in range(5)]
    assert [s.accepted for s in steps] == [False] * 4 + [True]  # five answers moving together start a track
    jump = tracker.step(90.0, 1.0, confident=False)  # one frame far off the route
    assert not jump.accepted and jump.position == pytest.approx(15.0, abs=0.5)
    back = tracker.step(16.0, 1.0, confident=False)
    assert back.accepted and back.position == pytest.approx(16.0, abs=0.5)


def test_an_answer_that_slows_against_its_track_is_plausible_but_off_by_its_innovation():
    tracker = RouteTracker(TrackerConfig())
    assert tracker.step(40.0, 1.0, confident=True).relocalised
    steps = [tracker.step(41.0 + t, 1.0, confident=True) for t in range(4)]  # 41..44, on the track
    assert all(s.accepted and abs(s.innovation) < 0.05 for s in steps)
    slowed = tracker.step(43.6, 0.9, confident=True)  # predicted at 45
    assert slowed.accepted and slowed.innovation == pytest.approx(-1.4, abs=0.05)
    assert abs(slowed.innovation) > TrackerConfig().agree_within  # so not localized


def test_answers_that_do_not_move_together_start_no_track():
    tracker = RouteTracker(TrackerConfig(acquire_after=5))
    answers = [(10, 1), (11, 1), (40, 1), (41, 1), (42, 1), (43, 1)]
    accepted = [tracker.step(float(p), float(v), confident=False).accepted for p, v in answers]
    assert accepted == [False] * 6 and not tracker.tracking
    assert tracker.step(44.0, 1.0, confident=False).accepted  # 40..44: five together


def test_without_acquisition_only_a_confident_answer_starts_a_track():
    tracker = RouteTracker(TrackerConfig(acquire_after=0))
    assert not any(tracker.step(10.0 + t, 1.0, confident=False).accepted for t in range(8))
    assert tracker.step(18.0, 1.0, confident=True).relocalised


def test_answers_following_the_distance_start_no_track_by_moving_together():
    tracker = RouteTracker(TrackerConfig(acquire_after=5))
    assert not any(tracker.step(10.0 + t, 1.0, confident=False, acquire=False).accepted for t in range(8))
    assert not tracker.tracking
    assert tracker.step(18.0, 1.0, confident=True, acquire=False).relocalised


@pytest.fixture(scope="module")
def stretch(tmp_path_factory, nordland) -> tuple[ReferenceMap, list]:
    """Summer frames 300-399 as the map, the same places in winter as the queries: a short same-direction route."""
    summer = [f for f in folder_traverse(nordland / "summer")][300:400]
    winter = [f for f in folder_traverse(nordland / "winter")][300:400]
    out = tmp_path_factory.mktemp("stretch") / "summer"
    build_map(iter(summer), out, describer=ThumbnailDescriber(), progress=False)
    return ReferenceMap.open(out), winter


def _right(estimates) -> int:
    return int(sum(abs(e.match_index - i) <= 1 for i, e in enumerate(estimates)))


def test_a_short_route_keeps_to_its_direction(stretch):
    refmap, winter = stretch
    localizer = Localizer(refmap, Config())
    estimates = [localizer.step(f) for f in winter]
    # Measured: 88 of 100 within one frame (83 when the best trajectory of either sign answered; 88 with
    # rising trajectories only). The falling look-alikes that won frames 57-67 no longer answer.
    assert _right(estimates) >= 88
    assert localizer.direction.belief[0] > 0.99  # rising
    assert all(e.match_index > 40 for e in estimates[57:68])


def test_warm_up_answers_come_from_the_window_so_far_or_the_single_frame(day_map, robotcar, mosaic):
    window = Localizer(day_map, Config(sequence=SequenceConfig(length=8)), mosaic)
    single = Localizer(day_map, Config(sequence=SequenceConfig(length=8, warm_up="single")), mosaic)
    pairs = [(window.step(f), single.step(f)) for f in _night(robotcar)]
    warming = [(a, b) for a, b in pairs if a.warming_up]
    assert len(warming) == 7 and all(b.warming_up for _, b in warming)
    assert all(a.state == b.state == "not_localized" and a.confidence == b.confidence == 0.0 for a, b in warming)
    assert all(b.match_index == b.single_match_index for _, b in warming)
    # The window's answer is the best trajectory over the frames so far: here once not the single frame's.
    assert [a.match_index for a, _ in warming] != [a.single_match_index for a, _ in warming]
    assert [a.match_index for a, _ in pairs[7:]] == [b.match_index for _, b in pairs[7:]]  # the same once full
