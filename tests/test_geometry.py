"""Bringing cameras of different fields of view to a common geometry before the network."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lostx.core import Config, ReferenceMap, build_map
from lostx.core.describe.camera import Geometry, cut_rows, fit_aspect, narrow_to_fov
from lostx.core.config import BackboneConfig, CameraConfig
from lostx.core.describe.describer import LostDescriber
from lostx.core.errors import InputError
from lostx.core.match.matcher import PlaceMatcher
from lostx.replay.folder import folder_traverse


def _ramp(h: int, w: int) -> np.ndarray:
    image = np.zeros((h, w, 3), np.uint8)
    image[..., 0] = np.arange(w)[None, :] % 256
    image[..., 1] = np.arange(h)[:, None] % 256
    return image


def test_a_wide_camera_is_narrowed_to_the_common_field_of_view():
    image = _ramp(900, 1600)
    narrowed = narrow_to_fov(image, 90.0, 65.0)  # the nuScenes rear camera to the front's field of view
    scale = math.tan(math.radians(32.5)) / math.tan(math.radians(45.0))
    assert narrowed.shape[:2] == (round(900 * scale), round(1600 * scale))
    # Centred: as many columns and rows dropped on each side (the ramp holds x and y mod 256).
    x0, y0 = (1600 - narrowed.shape[1]) // 2, (900 - narrowed.shape[0]) // 2
    assert (narrowed[0, 0, 0], narrowed[0, 0, 1]) == (x0 % 256, y0 % 256)
    assert narrow_to_fov(image, 65.0, 90.0) is image  # a narrower camera cannot be widened


def test_rows_are_cut_and_too_few_left_is_an_error():
    image = _ramp(100, 40)
    cut = cut_rows(image, 0.1, 0.25)
    assert cut.shape[0] == 65 and cut[0, 0, 1] == 10
    with pytest.raises(InputError, match="leaves 10 rows of 100"):
        cut_rows(image, 0.5, 0.4)


@pytest.mark.parametrize("fit, shape", [("squash", (900, 1600)), ("crop", (900, 900)), ("pad", (1600, 1600))])
def test_fitting_to_a_square_input(fit, shape):
    image = _ramp(900, 1600)
    fitted = fit_aspect(image, 1.0, fit)
    assert fitted.shape[:2] == shape
    if fit == "pad":
        assert fitted[:350].max() == 0 and fitted[1250:].max() == 0
        np.testing.assert_array_equal(fitted[350:1250], image)
    if fit == "crop":
        np.testing.assert_array_equal(fitted, image[:, 350:1250])


def test_each_camera_takes_its_own_settings():
    cameras = CameraConfig(hfov_deg={"front": 65.0, "rear": 90.0}, ignore_bottom={"rear": 0.1})
    geometry = Geometry(cameras, 65.0, "squash", None)
    image = _ramp(900, 1600)
    assert geometry.prepare(image, "front").shape == image.shape  # already the common field of view
    rear = geometry.prepare(image, "rear")
    scale = math.tan(math.radians(32.5)) / math.tan(math.radians(45.0))
    assert rear.shape[:2] == (round(810 * scale), round(1600 * scale))  # boot lid cut, then narrowed
    assert geometry.prepare(image, None).shape == image.shape  # a frame that declares no camera: as it is


def test_a_camera_setting_for_an_unknown_camera_is_refused():
    with pytest.raises(InputError, match="unknown camera 'left'"):
        Config(camera=CameraConfig(hfov_deg={"left": 60.0}))


def test_a_map_records_its_geometry_and_queries_follow_it(tmp_path, robotcar, mosaic):
    config = Config(camera=CameraConfig(hfov_deg={"front": 80.0}, view_hfov_deg=60.0, ignore_bottom={"front": 0.1}),
                    backbone=BackboneConfig(fit="crop"))
    day = folder_traverse(robotcar / "day", camera="front").subset(range(3))
    build_map(day, tmp_path / "day", config, LostDescriber(mosaic), progress=False)
    refmap = ReferenceMap.open(tmp_path / "day")
    assert refmap.manifest["geometry"] == {"view_hfov_deg": 60.0, "fit": "crop", "hfov_deg": {"front": 80.0},
                                           "ignore_top": {}, "ignore_bottom": {"front": 0.1}}
    # A query from the same camera is prepared exactly as the map's frames were: it finds itself at 0.
    query = PlaceMatcher(refmap, Config(camera=config.camera), mosaic)
    assert query.geometry == Geometry(config.camera, 60.0, "crop", 1.0)
    result = query.match(day.image(1), camera="front").same
    assert result.best == 1 and result.score == pytest.approx(0.0, abs=1e-9)
    assert query.match(day.image(1)).same.score > 0  # undeclared, the frame is not prepared as the map's were
