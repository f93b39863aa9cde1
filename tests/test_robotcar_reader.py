"""The RobotCar reader on a synthetic traverse with the real layout, built from real RobotCar frames.

Raw RobotCar images are single-channel Bayer mosaics: GBRG for the stereo
camera, RGGB for the mono cameras. The test mosaics real RGB frames by
sampling one colour per pixel (numpy, named from the top-left 2x2 block), so it
checks the reader's pattern choice independently of OpenCV's naming.
"""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.evaluation.datasets import open_pair
from lostx.replay.dataset import detect_format
from lostx.replay.robotcar import demosaic, robotcar_traverse

CHANNEL = {"R": 0, "G": 1, "B": 2}
T0 = 1_418_381_000_000_000  # microseconds, December 2014
INS_HEADER = ("timestamp,ins_status,latitude,longitude,altitude,northing,easting,down,utm_zone,"
              "velocity_north,velocity_east,velocity_down,roll,pitch,yaw\n")


def mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """One channel per pixel as a camera with ``pattern`` (top-left 2x2 block, row by row) records it."""
    raw = np.zeros(rgb.shape[:2], np.uint8)
    for k, (dy, dx) in enumerate([(0, 0), (0, 1), (1, 0), (1, 1)]):
        raw[dy::2, dx::2] = rgb[dy::2, dx::2, CHANNEL[pattern[k]]]
    return raw


def real_frames(robotcar, which: str, n: int) -> list[np.ndarray]:
    return [cv2.imread(str(p))[:, :, ::-1] for p in sorted((robotcar / which).iterdir())[:n]]


def ins_rows(n: int = 11, step_us: int = 100_000) -> str:
    """Driving north at 10 m/s and east at 2 m/s from (easting 620000, northing 5735000), one row per 0.1 s."""
    rows = []
    for k in range(n):
        t = T0 + k * step_us
        northing, easting = 5_735_000.0 + 1.0 * k, 620_000.0 + 0.2 * k
        rows.append(f"{t},INS_SOLUTION_GOOD,51.76,-1.26,110.0,{northing},{easting},-110.0,30U,10,2,0,0,0,0.1\n")
    return INS_HEADER + "".join(rows)


@pytest.fixture
def traverse_dir(tmp_path, robotcar):
    """stereo/centre: 3 day frames (GBRG), one more timestamp without an image; mono_rear: 2 night frames (RGGB)."""
    root = tmp_path / "2014-12-12-10-45-15"
    (root / "stereo" / "centre").mkdir(parents=True)
    (root / "mono_rear").mkdir()
    (root / "gps").mkdir()
    front_times = [T0 + 50_000, T0 + 250_000, T0 + 430_000, T0 + 600_000]
    for t, rgb in zip(front_times[:3], real_frames(robotcar, "day", 3)):
        cv2.imwrite(str(root / "stereo" / "centre" / f"{t}.png"), mosaic(rgb, "GBRG"))
    (root / "stereo.timestamps").write_text("".join(f"{t} 1\n" for t in front_times))
    rear_times = [T0 + 120_000, T0 + 900_000]
    for t, rgb in zip(rear_times, real_frames(robotcar, "night", 2)):
        cv2.imwrite(str(root / "mono_rear" / f"{t}.png"), mosaic(rgb, "RGGB"))
    (root / "mono_rear.timestamps").write_text("".join(f"{t} 1\n" for t in rear_times))
    (root / "gps" / "ins.csv").write_text(ins_rows())
    return root


def test_front_camera_demosaiced_close_to_the_original(traverse_dir, robotcar):
    traverse = robotcar_traverse(traverse_dir, "front")
    assert traverse.camera == "front"
    assert [f.parent.name for f in traverse.files] == ["centre"] * 3
    originals = real_frames(robotcar, "day", 3)
    for k in range(3):
        frame = traverse.frame(k)
        assert frame.image.shape == (640, 1024, 3) and frame.image.dtype == np.uint8
        error = np.abs(frame.image.astype(int) - originals[k]).mean()
        assert error < 3.0, f"frame {k}: mean error {error:.2f} grey levels"
    # The rear camera's pattern on the same raw data is visibly wrong: the check above can fail.
    raw = cv2.imread(str(traverse.files[0]), cv2.IMREAD_UNCHANGED)
    assert np.abs(demosaic(raw, "RGGB").astype(int) - originals[0]).mean() > 8.0


def test_rear_camera_uses_mono_rear_and_its_own_pattern(traverse_dir, robotcar):
    traverse = robotcar_traverse(traverse_dir, "rear")
    assert traverse.camera == "rear" and len(traverse) == 2
    assert all(f.parent.name == "mono_rear" for f in traverse.files)
    night = real_frames(robotcar, "night", 2)
    assert np.abs(traverse.frame(1).image.astype(int) - night[1]).mean() < 3.0


def test_positions_interpolated_at_image_times(traverse_dir):
    front = robotcar_traverse(traverse_dir, "front")
    # 0.05 s, 0.25 s, 0.43 s after the first INS row: 10 m/s north, 2 m/s east.
    np.testing.assert_allclose(front.timestamps - T0 / 1e6, [0.05, 0.25, 0.43], atol=1e-6)
    expected = [[620_000 + 2 * s, 5_735_000 + 10 * s] for s in (0.05, 0.25, 0.43)]
    np.testing.assert_allclose(front.positions, expected, atol=1e-6)
    assert any("1 of 4 timestamps" in n for n in front.notes)  # the listed frame without an image


def test_timestamps_file_beside_the_camera_folder(traverse_dir):
    (traverse_dir / "stereo.timestamps").rename(traverse_dir / "stereo" / "stereo.timestamps")
    front = robotcar_traverse(traverse_dir, "front")
    assert len(front) == 3 and not any("no stereo.timestamps" in n for n in front.notes)
    (traverse_dir / "stereo" / "stereo.timestamps").unlink()
    front = robotcar_traverse(traverse_dir, "front")  # falls back to the file names
    assert len(front) == 3 and any("no stereo.timestamps" in n for n in front.notes)


def test_images_outside_the_ins_time_span_are_dropped_and_noted(traverse_dir):
    rear = robotcar_traverse(traverse_dir, "rear")  # 0.12 s is inside; 0.9 s is inside too (INS to 1.0 s)
    assert len(rear) == 2
    (traverse_dir / "gps" / "ins.csv").write_text(ins_rows(n=6))  # INS now ends at 0.5 s
    rear = robotcar_traverse(traverse_dir, "rear")
    assert len(rear) == 1 and rear.files[0].stem == str(T0 + 120_000)
    assert any("outside the time span" in n for n in rear.notes)


def test_latitude_longitude_when_there_is_no_northing(traverse_dir):
    rows = ["timestamp,latitude,longitude\n"] + [f"{T0 + k * 100_000},{51.76 + 1e-5 * k},-1.26\n" for k in range(11)]
    (traverse_dir / "gps" / "ins.csv").write_text("".join(rows))
    front = robotcar_traverse(traverse_dir, "front")
    assert front.geo is not None
    np.testing.assert_allclose(front.geo[:, 0], 51.76 + 1e-4 * np.array([0.05, 0.25, 0.43]), rtol=0, atol=1e-9)
    # metres north of the first image: 1e-4 degree per second * 111 195 m per degree
    np.testing.assert_allclose(front.positions[:, 1], [0.0, 2.2239, 4.2254], atol=1e-3)


def test_detected_and_opened_as_a_front_rear_pair(traverse_dir):
    assert detect_format(traverse_dir) == "robotcar"
    pair = open_pair(traverse_dir, traverse_dir, reference_camera="front", query_camera="rear")
    assert pair.format == "robotcar" and pair.default_unit == "m"
    (gt,) = pair.ground_truth([1.0])
    # rear at 0.12 s: 0.71 m from front at 0.05 s (0.07 s at 10 m/s north, 2 m/s east), 1.33 m from
    # front at 0.25 s; rear at 0.9 s is 4.8 m past the last front frame.
    assert gt.matches(0).tolist() == [0] and gt.matches(1).tolist() == []


def test_bad_ins_and_timestamps_name_file_and_line(traverse_dir):
    ins = traverse_dir / "gps" / "ins.csv"
    ins.write_text(INS_HEADER + f"{T0},GOOD,51.7,-1.2,0,5735000,620000,0,30U,0,0,0,0,0,0\n{T0 + 1},GOOD,51.7\n")
    with pytest.raises(InputError, match=r"ins\.csv:3: expected 15 columns, got 3"):
        robotcar_traverse(traverse_dir, "front")
    ins.write_text(INS_HEADER + f"{T0},GOOD,51.7,-1.2,0,north,620000,0,30U,0,0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"ins\.csv:2: not a number"):
        robotcar_traverse(traverse_dir, "front")
    ins.write_text(ins_rows())
    (traverse_dir / "stereo.timestamps").write_text(f"{T0 + 50_000} 1\n{T0 + 250_000} one\n")
    with pytest.raises(InputError, match=r"stereo\.timestamps:2: expected '<timestamp> <chunk>'"):
        robotcar_traverse(traverse_dir, "front")
    (traverse_dir / "stereo.timestamps").write_text(f"{T0 + 50_000} 1\n{T0 + 250_000} 1\n")
    with pytest.raises(InputError, match=rf"{T0 + 430_000}\.png: not listed in .*stereo\.timestamps"):
        robotcar_traverse(traverse_dir, "front")


def test_missing_camera_folder(traverse_dir):
    shutil.rmtree(traverse_dir / "mono_rear")
    with pytest.raises(InputError, match="no mono_rear/ folder for the rear camera"):
        robotcar_traverse(traverse_dir, "rear")
