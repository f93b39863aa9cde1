"""Warnings for query frames unlike the map's: synthetic frames for each rule, real frames for the thresholds."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from lostx.core.describe.inputcheck import InputCheck, InputProfile, InputWarning, ProfileBuilder, looks
from lostx.core.localizer import Localizer
from lostx.replay.folder import folder_traverse


def street(rng, height=640, width=1024, brightness=140) -> np.ndarray:
    """A colour frame: smooth colour gradients plus noise, mean close to ``brightness``."""
    y, x = np.mgrid[0:height, 0:width]
    image = np.stack([x / width * 80, y / height * 80, (x + y) / (width + height) * 40], axis=-1)
    image = image - image.mean() + brightness + rng.normal(0, 10, (height, width, 3))
    return np.clip(image, 0, 255).astype(np.uint8)


def grey(image: np.ndarray) -> np.ndarray:
    return np.repeat(image.mean(axis=2, keepdims=True), 3, axis=2).astype(np.uint8)


def caught(check: InputCheck, frames) -> list[str]:
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for i, (image, labels) in enumerate(frames):
            check(i, image, labels)
    assert all(w.category is InputWarning for w in record)
    return [str(w.message) for w in record]


@pytest.fixture
def colour_profile(rng) -> InputProfile:
    builder = ProfileBuilder(["road", "building", "vegetation", "sky"])
    labels = np.repeat(np.arange(4), 16).reshape(8, 8)  # a quarter of each label
    for brightness in (90, 140, 190):
        builder.add(street(rng, brightness=brightness), labels)
    return builder.profile()


def test_the_profile_records_size_colour_brightness_and_labels(colour_profile):
    assert colour_profile.width == (1024, 1024) and colour_profile.height == (640, 640)
    assert colour_profile.greyscale == 0.0
    assert colour_profile.brightness == pytest.approx((90, 190), abs=2)
    assert colour_profile.labels == {"road": 0.25, "building": 0.25, "vegetation": 0.25, "sky": 0.25}
    assert InputProfile.from_dict(colour_profile.to_dict()) == colour_profile
    assert InputProfile.from_dict(None) is None  # a map built before profiles were kept


def test_frames_like_the_maps_raise_no_warning(colour_profile, rng):
    # A darker, half-size colour frame of the same shape is the same camera at night, not another kind of input.
    frames = [(street(rng, 320, 512, brightness=40), None), (street(rng, brightness=200), None)]
    assert caught(InputCheck(colour_profile), frames) == []


def test_a_small_greyscale_frame_warns_once_naming_both_differences(colour_profile, rng):
    small = grey(street(rng, 32, 64))
    assert looks(small).greyscale
    messages = caught(InputCheck(colour_profile), [(small, None)] * 3)
    assert messages == [
        "frame 0 is 64 x 32 pixels (the map's frames: 1024 x 640); greyscale (the map's frames: colour): "
        "not what the map was built from, so its answers may not mean much"
    ]


def test_another_aspect_ratio_and_a_black_frame_each_warn_once(colour_profile, rng):
    square = street(rng, 800, 800)
    black = np.zeros((640, 1024, 3), np.uint8)
    messages = caught(InputCheck(colour_profile), [(square, None), (black, None), (square, None), (black, None)])
    assert len(messages) == 2
    assert messages[0].startswith("frame 0 is 800 x 800 pixels")
    assert messages[1].startswith("frame 1 is almost black (mean brightness 0 of 255; the map's darkest frame: 89)")


def test_colour_frames_against_a_greyscale_map_warn(rng):
    builder = ProfileBuilder()
    builder.add(grey(street(rng, 32, 64)))
    messages = caught(InputCheck(builder.profile()), [(street(rng, 32, 64), None)])
    assert len(messages) == 1 and "in colour (the map's frames: greyscale)" in messages[0]


def test_labels_unlike_the_maps_warn_after_several_frames(colour_profile, rng):
    image = street(rng)
    mostly_sky = np.full((8, 8), 3)
    mostly_sky[0] = 1
    alike = np.repeat(np.arange(4), 16).reshape(8, 8)
    assert caught(InputCheck(colour_profile), [(image, alike)] * 8) == []
    messages = caught(InputCheck(colour_profile), [(image, mostly_sky)] * 8)
    assert len(messages) == 1
    assert messages[0].startswith("in frames 0 to 4 the network finds sky 88 %, building 12 %, road 0 %, against ")


def test_real_frames(day_map, robotcar, nordland, tmp_path):
    """Night RobotCar frames against the day map: no warning. Nordland's 64 x 32 greyscale frames: the size and
    colour warning on the first frame, and the labels warning once five frames are pooled."""
    localizer = Localizer(day_map)
    night = [(f.id, f) for f in folder_traverse(robotcar / "night")]
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for _, frame in night:
            localizer.step(frame)
    assert [str(w.message) for w in record] == []

    subset = tmp_path / "winter"
    subset.mkdir()
    for path in sorted((nordland / "winter").iterdir())[1000:1006]:
        cv2.imwrite(str(subset / path.name), cv2.imread(str(path)))
    localizer = Localizer(day_map)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for frame in folder_traverse(subset):
            localizer.step(frame)
    messages = [str(w.message) for w in record]
    assert len(messages) == 2, messages
    assert messages[0].startswith("frame 0 is 64 x 32 pixels (the map's frames: 1024 x 640); greyscale")
    assert messages[1].startswith("in frames 0 to 4 the network finds building")


def test_after_the_first_frames_one_in_every_few_is_checked(colour_profile, rng):
    """Input rarely changes kind mid-stream: a camera covered later is reported at the next checked frame."""
    from lostx.core.describe.inputcheck import CHECK_EVERY, CHECK_FIRST

    image, black = street(rng), np.zeros((640, 1024, 3), np.uint8)
    frames = [(image, None)] * CHECK_FIRST + [(black, None)] * CHECK_EVERY
    messages = caught(InputCheck(colour_profile), frames)
    assert len(messages) == 1 and messages[0].startswith(f"frame {CHECK_EVERY - 1} is almost black")
