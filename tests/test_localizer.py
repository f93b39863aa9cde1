"""The Localizer on real RobotCar frames: its answers, its bad-input handling, its CLI."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest

from lostx.core import Config, Frame, Localizer
from lostx.core.backbones import SemanticFrame
from lostx.core.config import SequenceConfig, TrackerConfig
from lostx.core.errors import ImageError, InputError
from lostx.replay.folder import folder_traverse

from test_cli import lostx


def _night(robotcar) -> list[Frame]:
    return [dataclasses.replace(f, timestamp=float(f.id)) for f in folder_traverse(robotcar / "night")]


def _same(a, b) -> bool:
    return (a.match_index, a.state, a.confidence, a.speed, a.single_match_index) == (
        b.match_index, b.state, b.confidence, b.speed, b.single_match_index)


@pytest.mark.parametrize("tracker, exact", [(False, 7), (True, 7)])
def test_short_window_on_the_day_night_pair(day_map, robotcar, mosaic, tracker, exact):
    config = Config(sequence=SequenceConfig(length=3), tracker=TrackerConfig(enabled=tracker))
    localizer = Localizer(day_map, config, mosaic)
    found = np.array([localizer.step(f).match_index for f in _night(robotcar)])
    assert int((found == np.arange(10)).sum()) == exact  # measured
    assert int((np.abs(found - np.arange(10)) <= 1).sum()) == 10


def test_estimate_carries_what_was_promised(day_map, robotcar, mosaic):
    localizer = Localizer(day_map, Config(sequence=SequenceConfig(length=3)), mosaic)
    estimates = [localizer.step(f) for f in _night(robotcar)]
    last = estimates[-1]
    assert len(last.candidates) == 10 and last.candidates[0].index == last.single_match_index
    assert {"network", "descriptor", "search", "verify", "sequence", "tracker", "total"} <= set(last.latency_ms)
    assert last.evidence.correspondences[last.match_index].channel.size > 0  # drawable even off the shortlist
    assert last.evidence.sequence_window.shape == (3, 31)
    assert [e.warming_up for e in estimates[:3]] == [True, True, False]
    assert all(0.0 <= e.confidence <= 1.0 for e in estimates)
    assert all(e.confidence == 0.0 for e in estimates[:2])  # warming up
    # After it, the confidence is the margin's, from the wrong answers measured on the map itself.
    for e in estimates[2:]:
        assert e.confidence == localizer.calibration.sequence_confidence(e.margin)
    # Ten map frames give too few wrong answers to measure: never enough to be sure of anything.
    assert localizer.calibration.too_short(True, Config().decision.min_confidence) is not None
    assert not any(e.state == "localized" for e in estimates)
    assert [e.heading for e in estimates[2:]] == ["same"] * 8


@pytest.mark.parametrize(
    "bad, error, message",
    [
        (np.zeros((480, 640), dtype=np.float32), ImageError, "expected uint8 pixels"),
        (np.zeros((480, 640, 4), dtype=np.uint8), ImageError, "H x W x 3"),
        (np.zeros((8, 8, 3), dtype=np.uint8), ImageError, "too small"),
        ("not an image", ImageError, "numpy array"),
    ],
)
def test_a_bad_frame_is_refused_and_the_state_survives(day_map, robotcar, mosaic, bad, error, message):
    frames = _night(robotcar)
    clean = Localizer(day_map, Config(sequence=SequenceConfig(length=3)), mosaic)
    want = [clean.step(f) for f in frames[:6]]
    localizer = Localizer(day_map, Config(sequence=SequenceConfig(length=3)), mosaic)
    got = [localizer.step(f) for f in frames[:5]]
    with pytest.raises(error, match=message):
        localizer.step(Frame(id=99, image=bad, timestamp=4.5))  # type: ignore[arg-type]
    got.append(localizer.step(frames[5]))
    assert all(_same(a, b) for a, b in zip(got, want))


def test_timestamps_going_backwards(day_map, robotcar, mosaic):
    frames = _night(robotcar)
    localizer = Localizer(day_map, Config(sequence=SequenceConfig(length=3)), mosaic)
    want = [Localizer(day_map, Config(sequence=SequenceConfig(length=3)), mosaic).step(f) for f in frames[:1]]
    for f in frames[:4]:
        localizer.step(f)
    with pytest.raises(InputError, match="earlier than the previous frame's"):
        localizer.step(dataclasses.replace(frames[4], timestamp=1.0))
    localizer.step(frames[4])  # the next good frame is taken as usual
    localizer.reset()  # a new traverse may start again at any time
    assert _same(localizer.step(frames[0]), want[0])


class NaNOnce:
    """The real backbone, except that one frame comes out as NaN (a faulty accelerator, say)."""

    def __init__(self, backbone, bad_call: int) -> None:
        self.backbone, self.info, self.calls, self.bad_call = backbone, backbone.info, 0, bad_call

    def __call__(self, image):
        out = self.backbone(image)
        self.calls += 1
        if self.calls == self.bad_call:
            return SemanticFrame(np.full_like(out.features, np.nan), out.probs)
        return out


def test_nan_features_are_refused_and_the_state_survives(day_map, robotcar, mosaic):
    frames = _night(robotcar)
    config = Config(sequence=SequenceConfig(length=3))
    clean = Localizer(day_map, config, mosaic)
    want = [clean.step(f) for f in frames[:4]]
    localizer = Localizer(day_map, config, NaNOnce(mosaic, bad_call=3))
    got = [localizer.step(f) for f in frames[:2]]
    with pytest.raises(InputError, match="non-finite"):
        localizer.step(frames[2])
    got += [localizer.step(f) for f in frames[2:4]]
    assert all(_same(a, b) for a, b in zip(got, want))


def test_match_sequence_writes_the_extra_columns(robotcar, tmp_path):
    out = tmp_path / "day"
    assert lostx("map", "build", robotcar / "day", "--out", out, "--quiet").returncode == 0
    proc = lostx("match", out, robotcar / "night", "--out", tmp_path / "s.csv", "--sequence", "--window", "3",
                 "--no-tracker", "--quiet")
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader((tmp_path / "s.csv").open()))
    assert {"single_match_index", "state", "speed"} <= set(rows[0])
    assert sum(int(r["match_index"]) == int(r["query_index"]) for r in rows) == 7
    assert [r["state"] for r in rows[:2]] == ["not_localized"] * 2
