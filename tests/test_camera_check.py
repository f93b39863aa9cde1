"""``lostx camera check``: the camera's numbers and the rows of the horizon and the road, printed and drawn."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from lostx.commands.camera_check import HORIZON_BGR, ROAD_BGR
from lostx.core.geometry import CAMERA_FILE, write_camera_file
from lostx.core.images import list_images
from lostx.core.paths import data_dir
from lostx.replay.dataset import open_traverse

from test_cli import assert_one_line_error, lostx

FRONT = data_dir() / "nuscenes-frontrear" / "scene-0523" / "front"
REAR = data_dir() / "nuscenes-frontrear" / "scene-0523" / "rear"


@pytest.fixture(scope="module")
def front() -> Path:
    if not FRONT.exists():
        pytest.fail(f"test data missing: {FRONT}")
    return FRONT


def printed_row(stdout: str, label: str) -> float:
    return float(re.search(rf"^{label}\s+row (-?[\d.]+)", stdout, re.MULTILINE).group(1))


def near(image: np.ndarray, row: float, column: int, colour: tuple[int, int, int]) -> bool:
    """Is a pixel of ``colour`` (BGR, within a few levels) in ``column`` within 3 rows of ``row``?"""
    strip = image[int(row) - 3:int(row) + 4, column].astype(int)
    return bool((np.abs(strip - colour).max(axis=1) <= 40).any())


def test_the_front_camera_check_prints_and_draws_the_horizon_and_the_road(front, tmp_path):
    out = tmp_path / "check.png"
    proc = lostx("camera", "check", front, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert printed_row(proc.stdout, "horizon") == pytest.approx(481, abs=1)
    for distance, row in ((10, 668), (20, 574), (40, 528)):
        assert printed_row(proc.stdout, f"road {distance} m") == pytest.approx(row, abs=1)
    assert "calibrated_sensor.json (CAM_FRONT" in proc.stdout
    assert re.search(r"height 1\.495 m", proc.stdout) and re.search(r"pitch -0\.49", proc.stdout)
    assert "fx 1252.8" in proc.stdout and "a front camera" in proc.stdout
    drawn = cv2.imread(str(out))
    assert drawn.shape == (900, 1600, 3)
    # The lines are where the rows say, in their colours (at a column clear of the labels).
    geometry = open_traverse(front).geometry
    assert near(drawn, geometry.horizon_row(1400.0), 1400, HORIZON_BGR)
    assert near(drawn, 668.2, 700, ROAD_BGR)  # near the middle: the road lines tilt with the roll too
    original = cv2.imread(str(list_images(front)[0]))
    assert np.abs(drawn[100:300].astype(int) - original[100:300]).max() == 0  # the sky is left as it was


def test_the_check_compares_the_pitch_with_the_direction_of_travel(front, tmp_path):
    proc = lostx("camera", "check", front)
    assert proc.returncode == 0, proc.stderr
    agrees = re.search(r"^motion .* over (\d+) steps puts the pitch at (-?[\d.]+) degrees \(the geometry: -0\.49\): "
                       r"agrees$", proc.stdout, re.MULTILINE)
    assert agrees and int(agrees.group(1)) >= 30 and abs(float(agrees.group(2)) + 0.49) < 0.75
    geometry = dataclasses.replace(open_traverse(front).geometry, pitch=2.0)  # a camera file 2.5 degrees off
    write_camera_file(geometry, tmp_path / "camera.toml")
    proc = lostx("camera", "check", front, "--camera-file", tmp_path / "camera.toml")
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"^motion .*puts the pitch at -0\.\d+ degrees \(the geometry: 2\.00\): DISAGREES", proc.stdout,
                     re.MULTILINE), proc.stdout


def test_the_rear_camera_check_shows_the_body_rows(tmp_path):
    proc = lostx("camera", "check", REAR, "--frame", "30", "--out", tmp_path / "rear.png")
    assert proc.returncode == 0, proc.stderr
    assert "body       0.090 of the height: rows 819 to 900 show the vehicle" in proc.stdout
    assert "a rear camera" in proc.stdout and "#30" in proc.stdout
    drawn, original = cv2.imread(str(tmp_path / "rear.png")), cv2.imread(str(sorted(REAR.glob("*.jpg"))[30]))
    assert drawn[880, 800, 2] > original[880, 800, 2]  # the lid's rows shaded red


def test_the_rows_that_stay_the_same_are_found_and_set_against_the_body(front, tmp_path):
    """The rear camera's boot lid stays the same from frame to frame while the road and the scene move past: the
    check finds it where the calibration puts it (0.09 of the height), says so where a camera file leaves it out,
    and finds nothing in the front camera's frames."""
    proc = lostx("camera", "check", REAR)
    assert proc.returncode == 0, proc.stderr
    seen = re.search(r"^still +the bottom ([\d.]+) % of the frames stays the same over 39 pairs of frames: agrees "
                     r"with body 0\.090$", proc.stdout, re.MULTILINE)
    assert seen and 7.0 <= float(seen.group(1)) <= 11.0, proc.stdout
    write_camera_file(dataclasses.replace(open_traverse(REAR).geometry, body=0.0), tmp_path / "camera.toml")
    proc = lostx("camera", "check", REAR, "--camera-file", tmp_path / "camera.toml")
    assert re.search(r"^still .*: the vehicle itself\? body = 0\.(08|09|10) in the camera file", proc.stdout,
                     re.MULTILINE), proc.stdout
    proc = lostx("camera", "check", front)
    assert re.search(r"^still +no rows at the bottom stay the same over 39 pairs of frames: agrees with body "
                     r"0\.000$", proc.stdout, re.MULTILINE), proc.stdout


def test_a_camera_file_is_checked_at_the_frame_size(robotcar, tmp_path):
    folder = tmp_path / "day"
    folder.mkdir()
    for file in list_images(robotcar / "day"):
        (folder / file.name).symlink_to(file)
    # Intrinsics for half-size frames: the rows are printed in the frame's own pixels.
    (folder / CAMERA_FILE).write_text("fx = 200\nfy = 200\ncx = 255.5\ncy = 159.5\nwidth = 512\nheight = 320\n"
                                      "z = 1.5\npitch = 5\n")
    proc = lostx("camera", "check", folder)
    assert proc.returncode == 0, proc.stderr
    assert f"note: camera geometry from {folder / CAMERA_FILE}" in proc.stdout
    assert "scaled     to the frame's 1024 x 640 pixels" in proc.stdout
    # Horizon at cy - fy tan(pitch) in the frame's pixels: (159.5 + 0.5) * 2 - 0.5 - 400 tan(5 deg).
    assert printed_row(proc.stdout, "horizon") == pytest.approx(319.5 - 400 * np.tan(np.radians(5)), abs=0.05)
    assert "--out check.png draws" in proc.stdout
    other = tmp_path / "square.toml"
    other.write_text("fx = 200\nfy = 200\ncx = 255.5\ncy = 255.5\nwidth = 512\nheight = 512\n")
    proc = lostx("camera", "check", folder, "--camera-file", other)
    assert f"geometry   from {other}" in proc.stdout
    assert "warning    the frame is 1024 x 640 pixels but the intrinsics are for 512 x 512" in proc.stdout


def test_bad_checks_are_one_line_errors(robotcar, front, tmp_path):
    proc = lostx("camera", "check", robotcar / "day")
    assert proc.returncode == 2
    assert_one_line_error(proc, f"lostx: error: {robotcar / 'day'}: no camera geometry: give a camera file with "
                                "--camera-file PATH, or put camera.toml beside the frames (its format: "
                                "docs/datasets.md")
    proc = lostx("camera", "check", front, "--frame", "40")
    assert_one_line_error(proc, f"lostx: error: --frame 40: {front} has 40 frames (0 to 39)")
    bad = tmp_path / "bad.toml"
    bad.write_text("fx = 1\nfy = 1\ncx = 1\ncy = 1\nwidth = 10\nheight = 10\npitch = 75\n")
    proc = lostx("camera", "check", front, "--camera-file", bad)
    assert proc.returncode == 2
    assert_one_line_error(proc, f"lostx: error: {bad}: camera pitch 75 and roll 0 degrees")
    proc = lostx("camera", "check", "camera:7")
    assert_one_line_error(proc, "lostx: error: camera:7: a live camera carries no calibration; give its camera file "
                                "with --camera-file PATH")
    proc = lostx("camera", "check", front, "--out", tmp_path)
    assert_one_line_error(proc, f"lostx: error: --out {tmp_path} is a folder")
