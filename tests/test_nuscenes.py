"""nuScenes: the shared front/rear scene read from its tables gives the frames and positions of its CSVs."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.core.paths import data_dir
from lostx.evaluation.datasets import open_pair
from lostx.replay.dataset import SourceOptions, detect_format, open_traverse
from lostx.replay.nuscenes import nuscenes_traverse, yaw_deg

from test_cli import lostx

SIDES = {"front": ("CAM_FRONT", "front"), "rear": ("CAM_BACK", "rear")}


@pytest.fixture(scope="module")
def shared() -> Path:
    root = data_dir() / "nuscenes-frontrear"
    if not root.exists():
        pytest.fail(f"test data missing: {root}")
    return root


def table(path: Path) -> list[dict]:
    return list(csv.DictReader(path.open()))


@pytest.mark.parametrize("side", ["front", "rear"])
def test_the_shared_scene_gives_the_frames_and_positions_of_its_csvs(shared, side):
    folder = shared / "scene-0523" / side
    vehicle, look = table(folder / "positions.csv"), table(folder / "positions_lookat15m.csv")
    traverse = open_traverse(folder)
    assert detect_format(folder) == "nuscenes"
    channel, camera = SIDES[side]
    assert traverse.name == f"scene-0523/{channel}" and traverse.camera == camera and not traverse.notes
    assert traverse.names == [r["file"] for r in vehicle] and len(traverse) == 40
    np.testing.assert_allclose(traverse.positions, [[float(r["x"]), float(r["y"])] for r in vehicle], atol=0.001)
    np.testing.assert_allclose(traverse.timestamps, [float(r["timestamp"]) for r in vehicle], atol=1e-6)
    frame = traverse.frame(7)
    assert frame.metadata["vehicle_yaw_deg"] == pytest.approx(float(vehicle[7]["vehicle_yaw_deg"]), abs=0.006)
    assert frame.metadata["camera_yaw_deg"] == pytest.approx(float(vehicle[7]["camera_yaw_deg"]), abs=0.006)
    looking = open_traverse(folder, options=SourceOptions(look_at=15.0))
    np.testing.assert_allclose(looking.positions, [[float(r["x"]), float(r["y"])] for r in look], atol=0.001)


def test_a_dataset_root_and_a_download_layout_read_the_same_frames(shared, tmp_path):
    rear = open_traverse(shared / "scene-0523" / "rear")
    # The dataset's root holds two scenes' images: it names them until one is chosen.
    with pytest.raises(InputError, match=r"holds 2 scenes \(scene-0523, scene-0916\); choose one with --scene"):
        open_traverse(shared, options=SourceOptions(channel="CAM_BACK"))
    from_root = open_traverse(shared, options=SourceOptions(channel="CAM_BACK", scene="scene-0523"))
    assert from_root.names == rear.names and np.array_equal(from_root.positions, rear.positions)
    # A nuScenes download: v1.0-mini/ tables and samples/CAM_FRONT/<file>.
    download = tmp_path / "nuscenes"
    shutil.copytree(shared / "v1.0-mini-extract", download / "v1.0-mini")
    samples = download / "samples" / "CAM_FRONT"
    samples.mkdir(parents=True)
    front = shared / "scene-0523" / "front"
    for image in sorted(front.glob("*.jpg"))[:30]:  # a partial download
        (samples / image.name).symlink_to(image)
    at_root = open_traverse(download, options=SourceOptions(scene="scene-0523"))
    in_samples = open_traverse(samples)
    expected = open_traverse(front).subset(range(30))
    for traverse in (at_root, in_samples):
        assert traverse.names == expected.names and traverse.camera == "front"
        np.testing.assert_allclose(traverse.positions, expected.positions)
        assert traverse.notes == ["10 of 40 frames have no image file: skipped"]
    assert np.array_equal(at_root.frame(29).image, expected.frame(29).image)


def test_front_queries_against_a_rear_map_by_look_at_distance(shared):
    """The look-at ground truth of the pair is the dataset's own index file."""
    pair = open_pair(shared / "scene-0523" / "rear", shared / "scene-0523" / "front",
                     options=SourceOptions(look_at=15.0))
    assert pair.format == "nuscenes" and (pair.reference.camera, pair.query.camera) == ("rear", "front")
    rows = table(shared / "scene-0523" / "gt_front_query_to_rear_reference.csv")
    (truth,) = pair.ground_truth(7.5, "m")
    for q, row in enumerate(rows):
        listed = [int(i) for i in row["acceptable_ref_indices"].split()]
        # The index file also asks for optical axes >= 135 degrees apart, which holds for every listed pair.
        assert set(listed) <= set(truth.matches(q).tolist()), q
    best = [int(np.argmin(np.linalg.norm(pair.reference.positions - p, axis=1))) for p in pair.query.positions]
    assert best == [int(r["best_ref_index"]) for r in rows]


def test_rear_frames_reversed_as_a_forward_camera_drive_the_road_the_other_way(shared):
    """The data README's second use: map from front, queries = rear frames in reverse, a forward camera: the
    rear camera played backwards looks where a front camera driving the other way looks."""
    rear = nuscenes_traverse(shared / "scene-0523" / "rear")
    query = rear.reversed()
    assert (rear.camera, query.camera) == ("rear", "front")
    assert query.names[0].endswith("1535639736187558.jpg")
    assert np.all(np.diff(query.timestamps) > 0)


def test_yaw_of_a_quaternion():
    half = np.radians(30.0) / 2
    assert yaw_deg([np.cos(half), 0.0, 0.0, np.sin(half)]) == pytest.approx(30.0)


def test_bad_nuscenes_input(shared, tmp_path):
    with pytest.raises(InputError, match=r"no scene 'scene-9999'; scenes: scene-0523, scene-0916"):
        open_traverse(shared, options=SourceOptions(scene="scene-9999"))
    with pytest.raises(InputError, match="none of the 41 images of this scene and channel is here"):
        open_traverse(shared, options=SourceOptions(scene="scene-0916", channel="CAM_FRONT_LEFT"))
    with pytest.raises(InputError, match="unknown nuScenes camera channel 'CAM_TOP'"):
        open_traverse(shared, options=SourceOptions(channel="CAM_TOP"))
    with pytest.raises(InputError, match="holds CAM_FRONT images, not CAM_BACK"):
        open_traverse(shared / "scene-0523" / "front", options=SourceOptions(channel="CAM_BACK"))
    tables = tmp_path / "v1.0-mini"
    shutil.copytree(shared / "v1.0-mini-extract", tables)
    (tables / "ego_pose.json").write_text("[{")
    folder = tmp_path / "front"
    folder.mkdir()
    for image in sorted((shared / "scene-0523" / "front").glob("*.jpg"))[:2]:
        (folder / image.name).symlink_to(image)
    with pytest.raises(InputError, match=r"ego_pose\.json: not valid JSON"):
        open_traverse(folder)


def test_map_build_takes_a_nuscenes_scene_and_declares_its_camera(shared, tmp_path):
    proc = lostx("map", "build", shared, "--scene", "scene-0523", "--channel", "CAM_BACK", "--look-at",
                 "--descriptor", "thumbnail",
                 "--out", tmp_path / "rear", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "positions 15 m along the camera's heading" in proc.stdout
    info = lostx("map", "info", tmp_path / "rear")
    assert "40 (rear camera)" in info.stdout
    expected = open_traverse(shared / "scene-0523" / "rear", options=SourceOptions(look_at=15.0)).positions
    np.testing.assert_allclose(np.load(tmp_path / "rear" / "positions.npy"), expected)
