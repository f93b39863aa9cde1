"""Monocular visual odometry on real frames: nuScenes scene-0523, front and rear camera, against the ego poses.

40 frames per camera at 2 Hz, about 3 m apart: 126 m with a roundabout (a left turn of about 23 degrees in, a
right turn of about 31 degrees out). Steps are in the camera's ground frame, so the rear camera of the car driving
forward moves backwards (dx < 0).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import re
import warnings

import cv2
import numpy as np
import pytest

from lostx.core.geometry import CameraGeometry, quaternion_matrix
from lostx.core.motion.pose import camera_ground_pose, relative, wrap
from lostx.core.motion.visual import CameraPitchWarning, Step, VisualOdometry
from lostx.core.paths import data_dir

SCENE = data_dir() / "nuscenes-frontrear" / "scene-0523"
BODY = {"front": 0.0, "rear": 0.12}  # the rear camera sees the boot lid along its bottom edge
LEFT_TURN, RIGHT_TURN = slice(17, 24), slice(25, 32)  # steps into and out of the roundabout


class Camera:
    """One camera's frames (RGB, loaded on first use), calibration and true ground poses."""

    def __init__(self, name: str) -> None:
        if not SCENE.exists():
            pytest.fail(f"test data missing: {SCENE} (set LOSTX_SHARED to the folder holding data/ and models/)")
        calibration = json.loads((SCENE / "calibration.json").read_text())[name]
        self.geometry = CameraGeometry.from_pose(
            np.array(calibration["camera_intrinsic"]), quaternion_matrix(calibration["rotation_in_ego_wxyz"]),
            np.array(calibration["translation_in_ego_m"]), 1600, 900, body=BODY[name], source=f"{SCENE.name} {name}")
        with open(SCENE / name / "positions.csv", newline="") as handle:
            rows = list(csv.DictReader(handle))
        self.files = [SCENE / name / row["file"] for row in rows]
        vehicle = np.array([[float(r["x"]), float(r["y"]), math.radians(float(r["vehicle_yaw_deg"]))] for r in rows])
        self.poses = camera_ground_pose(vehicle, self.geometry)
        self.true_steps = relative(self.poses[:-1], self.poses[1:])
        self._frames: dict[int, np.ndarray] = {}

    def frame(self, i: int) -> np.ndarray:
        if i not in self._frames:
            self._frames[i] = cv2.cvtColor(cv2.imread(str(self.files[i])), cv2.COLOR_BGR2RGB)
        return self._frames[i]

    def run(self, indices: range | list[int], odometry: VisualOdometry | None = None, **masks) -> list[Step]:
        odometry = odometry or VisualOdometry(self.geometry)
        steps = [odometry.step(self.frame(i), **masks) for i in indices]
        assert steps[0] is None
        return steps[1:]


@pytest.fixture(scope="module")
def cameras() -> dict[str, Camera]:
    return {name: Camera(name) for name in ("front", "rear")}


@pytest.fixture(scope="module")
def whole_scene(cameras) -> dict[str, np.ndarray]:
    """Each camera's 39 steps over the whole scene, as (39, 3) motions."""
    return {name: np.array([s.motion for s in camera.run(range(len(camera.files)))])
            for name, camera in cameras.items()}


@pytest.mark.parametrize("name, tolerance", [("front", 0.08), ("rear", 0.10)])
def test_distance_travelled_matches_the_ego_poses(cameras, whole_scene, name, tolerance):
    travelled = np.linalg.norm(whole_scene[name][:, :2], axis=1).sum()
    true = np.linalg.norm(cameras[name].true_steps[:, :2], axis=1).sum()
    assert 120 < true < 130
    assert abs(travelled / true - 1) < tolerance, (travelled, true)


@pytest.mark.parametrize("name, step_error", [("front", 0.3), ("rear", 0.4)])
def test_each_step_is_close_to_the_ego_poses(cameras, whole_scene, name, step_error):
    errors = np.linalg.norm(whole_scene[name][:, :2] - cameras[name].true_steps[:, :2], axis=1)
    assert errors.mean() < step_error and errors.max() < 1.0, errors.round(2)
    turn_errors = np.degrees(np.abs(wrap(whole_scene[name][:, 2] - cameras[name].true_steps[:, 2])))
    assert np.median(turn_errors) < 0.3, turn_errors.round(2)


def test_the_front_camera_moves_forwards_and_the_rear_camera_backwards(whole_scene):
    front, rear = whole_scene["front"], whole_scene["rear"]
    assert (front[:, 0] > 1.0).all(), front[:, 0].round(2)
    assert (rear[:, 0] < -1.0).all(), rear[:, 0].round(2)
    # along the camera's axis: sideways far less than forwards
    assert (np.abs(front[:, 1]) < 0.2 * front[:, 0]).all() and (np.abs(rear[:, 1]) < 0.2 * -rear[:, 0]).all()


@pytest.mark.parametrize("name", ["front", "rear"])
def test_the_turns_through_the_roundabout(cameras, whole_scene, name):
    for turn in (LEFT_TURN, RIGHT_TURN):
        measured = math.degrees(whole_scene[name][turn, 2].sum())
        true = math.degrees(cameras[name].true_steps[turn, 2].sum())
        assert abs(true) > 20
        assert abs(measured - true) < 3.0, (turn, measured, true)


def _true_steps(camera: Camera, order: list[int]) -> np.ndarray:
    """The camera's true steps between the frames taken in ``order``."""
    poses = camera.poses[np.asarray(order)]
    return relative(poses[:-1], poses[1:])


def test_a_rear_camera_played_backwards_is_measured_from_its_first_steps(cameras):
    """Played backwards, the rear camera moves towards what it sees, against its facing: the length of each step is
    searched from the frame that sees the road nearer all the same, from the first step on (it was not measured
    until the filter had a speed to go by, and 23 % of the distance was missing)."""
    camera = cameras["rear"]
    order = list(range(len(camera.files)))[::-1]
    steps = camera.run(order)
    true = _true_steps(camera, order)
    assert all(s.motion[0] > 1.0 for s in steps) and (true[:, 0] > 1.0).all()
    assert all(s.measured for s in steps[:9]), [s.measured for s in steps[:9]]
    travelled = sum(np.hypot(*s.motion[:2]) for s in steps)
    assert abs(travelled / np.linalg.norm(true[:, :2], axis=1).sum() - 1) < 0.12


def test_steps_twice_as_long_keep_their_turns(cameras):
    """Every other frame (steps of about 6 m, turns of up to 12 degrees): where tracking from the last step's motion
    loses the corners, keypoints matched by their descriptors find the motion; the turn through the scene stays
    within 3 degrees of the ego poses' (it came out 13 degrees the wrong way)."""
    camera = cameras["front"]
    order = list(range(0, len(camera.files), 2))
    steps = camera.run(order)
    true = _true_steps(camera, order)
    assert np.degrees(np.abs(true[:, 2])).max() > 10
    turned = math.degrees(sum(s.motion[2] for s in steps))
    assert abs(turned - math.degrees(true[:, 2].sum())) < 3.0, (turned, math.degrees(true[:, 2].sum()))


@pytest.mark.parametrize("name, change", [("front", 1.0), ("front", -1.0), ("rear", 1.0)])
def test_a_pitch_a_degree_off_keeps_the_step_lengths(cameras, whole_scene, name, change):
    """A camera file whose pitch is a degree off tilts the road plane the lengths are searched on; the search tries
    the road tilted too, so the step lengths stay within 3 % of the calibrated geometry's (they moved by 5-9 %)."""
    camera = cameras[name]
    off = VisualOdometry(dataclasses.replace(camera.geometry, pitch=camera.geometry.pitch + change))
    steps = camera.run(range(16), off)
    lengths = np.hypot(*np.array([s.motion[:2] for s in steps]).T)
    calibrated = np.hypot(*whole_scene[name][:15, :2].T)
    ratio = np.median(lengths / calibrated)
    assert abs(ratio - 1) < 0.03, ratio


def test_the_first_frame_after_a_reset_gives_no_step(cameras):
    camera = cameras["front"]
    odometry = VisualOdometry(camera.geometry)
    assert odometry.step(camera.frame(0)) is None
    assert isinstance(odometry.step(camera.frame(1)), Step)
    odometry.reset()
    assert odometry.step(camera.frame(2)) is None
    assert odometry.step(camera.frame(3)).motion[0] > 2.0


def test_the_same_frame_twice_is_standing_still(cameras):
    camera = cameras["front"]
    odometry = VisualOdometry(camera.geometry)
    odometry.step(camera.frame(5))
    still = odometry.step(camera.frame(5))
    assert still.measured and still.quality > 0.5
    assert np.hypot(*still.motion[:2]) < 0.05 and abs(math.degrees(still.motion[2])) < 0.1
    moving = odometry.step(camera.frame(6))  # and it moves off again at the next real frame
    assert moving.measured and abs(moving.motion[0] - camera.true_steps[5, 0]) < 0.5


def test_a_noise_frame_gives_a_prediction_not_a_crash(cameras):
    camera = cameras["front"]
    noise = np.random.default_rng(0).integers(0, 256, camera.frame(0).shape, dtype=np.uint8)
    odometry = VisualOdometry(camera.geometry)
    steps = camera.run(range(8, 12), odometry)
    last = steps[-1]
    assert last.measured
    guess = odometry.step(noise)
    assert not guess.measured and guess.quality < 0.05
    np.testing.assert_allclose(guess.motion[:2], last.motion[:2], atol=0.2)  # the same speed and direction
    after = odometry.step(camera.frame(12))  # compared with the noise: again a prediction
    assert not after.measured and np.isfinite(after.motion).all()
    back = odometry.step(camera.frame(13))
    assert back.measured and abs(back.motion[0] - camera.true_steps[12, 0]) < 0.5
    odometry.reset()  # noise from the start: nothing measured, nothing known
    odometry.step(noise)
    first = odometry.step(noise[::-1].copy())
    assert not first.measured and first.quality < 0.05 and np.allclose(first.motion, 0.0)


def test_masks_at_any_resolution_are_honoured(cameras):
    camera = cameras["front"]
    frames = range(20, 24)
    plain = camera.run(frames)
    everywhere, nowhere = np.ones((45, 80), bool), np.zeros((90, 160), bool)
    with_road = camera.run(frames, ground=everywhere)
    for a, b in zip(plain, with_road):  # all of it road: as without a mask
        np.testing.assert_allclose(a.motion, b.motion, atol=1e-6)
    for step in camera.run(frames, ground=nowhere):  # no road: no length, but the turn and direction still
        assert not step.measured and step.quality == 0.0
    for step in camera.run(frames, movers=everywhere):  # everything moving: nothing to measure
        assert not step.measured and step.quality == 0.0


def test_the_vehicles_own_body_is_not_looked_at(cameras):
    """Texture on the rear camera's boot lid moves with the camera; seen, it would say the car stands still."""
    camera = cameras["rear"]
    frames = range(4, 10)
    plain = camera.run(frames)
    texture = np.random.default_rng(1).integers(0, 256, (90, 1600, 3), dtype=np.uint8)
    odometry = VisualOdometry(camera.geometry)
    painted = []
    for i in frames:
        image = camera.frame(i).copy()
        image[-90:] = texture  # the bottom 10 % of the rows, inside body = 0.12
        painted.append(odometry.step(image))
    for a, b in zip(plain, painted[1:]):
        assert np.hypot(*(a.motion[:2] - b.motion[:2])) < 0.15 and abs(a.motion[2] - b.motion[2]) < 0.005


def test_a_road_that_does_not_match_gives_no_length(cameras):
    """Fresh noise on the road in every frame: no length to measure (a prediction), the turn still measured."""
    camera = cameras["front"]
    horizon = int(camera.geometry.ground_row(25.0))  # the road below; buildings, trees and sky above
    rng = np.random.default_rng(2)
    odometry = VisualOdometry(camera.geometry)
    for i in range(20, 25):
        image = camera.frame(i).copy()
        noise = cv2.GaussianBlur(rng.normal(128.0, 30.0, (900 - horizon, 1600)).astype(np.float32), (0, 0), 2.0)
        image[horizon:] = np.clip(noise, 0, 255).astype(np.uint8)[..., None]
        step = odometry.step(image)
        if i > 20:
            assert not step.measured and step.quality < 0.05
            assert abs(math.degrees(step.motion[2] - camera.true_steps[i - 1, 2])) < 0.5


@pytest.mark.parametrize("error", [0.0, 2.0, -2.0])
def test_a_camera_pitch_off_by_degrees_is_said_once(cameras, error):
    """The direction of travel lies on the horizon: a geometry whose pitch is 2 degrees off is named, with the pitch
    the frames show (the same whatever the geometry says); the calibrated one is not."""
    front = cameras["front"]
    odometry = VisualOdometry(dataclasses.replace(front.geometry, pitch=front.geometry.pitch + error))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        front.run(range(20), odometry)
    said = [str(w.message) for w in caught if w.category is CameraPitchWarning]
    if error == 0.0:
        assert said == []
        return
    assert len(said) == 1
    seen = float(re.search(r"pitch at (-?[\d.]+) degrees", said[0]).group(1))
    assert abs(seen - front.geometry.pitch) < 0.75  # the frames' own pitch, near the calibration's
    assert f"geometry says {front.geometry.pitch + error:.1f}" in said[0] and "lostx camera check" in said[0]
