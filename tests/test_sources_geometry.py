"""Every source's camera geometry and odometry: nuScenes' calibration and ego poses (checked by hand
against the shared scene's calibration.json and tables), a camera file beside a folder or a video or
given with --camera-file, odometry.csv, RobotCar's visual odometry, a bag's camera info and static
transforms, a live camera."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.core.geometry import CAMERA_FILE, CameraGeometry, write_camera_file
from lostx.core.images import list_images
from lostx.core.paths import data_dir
from lostx.replay.camera import LiveCamera
from lostx.replay.dataset import SourceOptions, open_traverse
from lostx.replay.robotcar import robotcar_traverse

from bagtools import camera_info, odometry, raw_image, tf_message, transform, write_bag
from test_cli import assert_one_line_error, lostx

SCENE = data_dir() / "nuscenes-frontrear"
SIDES = {"front": "CAM_FRONT", "rear": "CAM_BACK"}
A_CAMERA = CameraGeometry(fx=500.0, fy=500.0, cx=511.5, cy=319.5, width=1024, height=640, x=1.5, y=-0.2, z=1.4,
                          yaw=0.0, pitch=3.0, roll=-1.0, body=0.05)


@pytest.fixture(scope="module")
def scene() -> Path:
    if not SCENE.exists():
        pytest.fail(f"test data missing: {SCENE}")
    return SCENE


def calibration(scene: Path, side: str) -> dict:
    return json.loads((scene / "scene-0523" / "calibration.json").read_text())[side]


def rotation_by_hand(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The rotation matrix of a unit quaternion, written out here (not lostx's)."""
    return np.array([[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]])


def image_folder(robotcar: Path, folder: Path) -> Path:
    """A folder of the ten RobotCar day frames (links to them: the images are never copied)."""
    folder.mkdir(parents=True, exist_ok=True)
    for file in list_images(robotcar / "day"):
        (folder / file.name).symlink_to(file)
    return folder


# -- nuScenes ----------------------------------------------------------------------------------------


def test_nuscenes_geometry_is_the_calibration(scene):
    front = open_traverse(scene / "scene-0523" / "front").geometry
    rear = open_traverse(scene / "scene-0523" / "rear").geometry
    assert front is not None and rear is not None
    c = calibration(scene, "front")
    assert (front.fx, front.fy, front.cx, front.cy) == pytest.approx(
        (c["camera_intrinsic"][0][0], c["camera_intrinsic"][1][1], c["camera_intrinsic"][0][2],
         c["camera_intrinsic"][1][2]))
    assert (front.width, front.height) == (1600, 900)
    assert (front.x, front.y, front.z) == pytest.approx((1.722, 0.005, 1.495), abs=0.001)
    # The front camera looks a little up (-0.49 deg), and straight ahead.
    assert front.pitch == pytest.approx(-0.49, abs=0.01) and front.yaw == pytest.approx(0.58, abs=0.01)
    assert front.roll == pytest.approx(-0.70, abs=0.01)
    assert front.body == 0.0 and front.facing == "front"
    assert rear.yaw == pytest.approx(179.48, abs=0.01) and rear.facing == "rear"
    assert rear.z == pytest.approx(1.568, abs=0.001) and rear.pitch == pytest.approx(-0.40, abs=0.01)
    assert rear.body == pytest.approx(0.09)  # the boot lid: its top edge at row 826 of 900, mid-image
    assert "calibrated_sensor.json (CAM_BACK" in rear.source


@pytest.mark.parametrize("side, point", [("front", (21.72, 0.5, 0.0)), ("rear", (-15.0, -1.0, 0.0)),
                                         ("front", (40.0, -3.0, 1.2))])
def test_a_point_projects_where_the_calibration_puts_it(scene, side, point):
    """u, v computed here from calibration.json alone: the camera's pose on the vehicle and its K."""
    c = calibration(scene, side)
    rotation = rotation_by_hand(*c["rotation_in_ego_wxyz"])
    k = np.asarray(c["camera_intrinsic"])
    in_camera = rotation.T @ (np.asarray(point) - np.asarray(c["translation_in_ego_m"]))
    u, v = k[0, 0] * in_camera[0] / in_camera[2] + k[0, 2], k[1, 1] * in_camera[1] / in_camera[2] + k[1, 2]
    geometry = open_traverse(scene / "scene-0523" / side).geometry
    (pu, pv), ahead = geometry.project(np.asarray(point))
    assert ahead and (pu, pv) == pytest.approx((u, v), abs=1e-6)
    if point[2] == 0.0:  # and a pixel of the road goes back to its point
        (gx, gy), down = geometry.ground(u, v)
        assert down and (gx, gy) == pytest.approx(point[:2], abs=1e-6)


def test_nuscenes_odometry_is_the_ego_poses(scene):
    tables = scene / "v1.0-mini-extract"
    records = {Path(r["filename"]).name: r for r in json.loads((tables / "sample_data.json").read_text())}
    poses = {p["token"]: p for p in json.loads((tables / "ego_pose.json").read_text())}
    for side in SIDES:
        traverse = open_traverse(scene / "scene-0523" / side, options=SourceOptions(look_at=15.0))
        expected = []
        for name in traverse.names:
            pose = poses[records[name]["ego_pose_token"]]
            w, x, y, z = pose["rotation"]
            expected.append((*pose["translation"][:2], math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))))
        # The vehicle's poses, whatever --look-at does to the positions.
        np.testing.assert_allclose(traverse.odometry, expected, atol=1e-9)
        assert traverse.frame(5).odometry == pytest.approx(expected[5])
        assert traverse.frame(5).geometry is traverse.geometry


def test_a_camera_file_overrides_the_dataset_calibration(scene, tmp_path):
    path = tmp_path / "mine.toml"
    write_camera_file(A_CAMERA, path)
    traverse = open_traverse(scene / "scene-0523" / "front", options=SourceOptions(camera_file=path))
    assert traverse.geometry.to_dict() == A_CAMERA.to_dict() and traverse.geometry.source == str(path)
    assert any(f"camera geometry from {path}, in place of the source's own" in n for n in traverse.notes)
    assert traverse.odometry is not None  # the poses stay


# -- folders, videos, live cameras ---------------------------------------------------------------------


def test_a_folder_reads_its_camera_file_and_the_option_overrides_it(robotcar, tmp_path):
    folder = image_folder(robotcar, tmp_path / "day")
    assert open_traverse(folder).geometry is None
    write_camera_file(A_CAMERA, folder / CAMERA_FILE)
    traverse = open_traverse(folder)
    assert traverse.geometry.to_dict() == A_CAMERA.to_dict()
    assert f"camera geometry from {folder / CAMERA_FILE}" in traverse.notes
    assert all(frame.geometry == traverse.geometry for frame in traverse.subset([0, 4]))
    other = tmp_path / "other.toml"
    other.write_text("fx = 300\nfy = 300\ncx = 100\ncy = 80\nwidth = 200\nheight = 160\nz = 2.5\n")
    given = open_traverse(folder, options=SourceOptions(camera_file=other))
    assert (given.geometry.fx, given.geometry.z, given.geometry.width) == (300.0, 2.5, 200)
    assert given.frame(0).geometry.scaled_to(1024, 640).fx == pytest.approx(300 * 1024 / 200)


@pytest.mark.parametrize("text, field", [("fx = 300\nfy = 300\ncx = 1\ncy = 1\nwidth = 200\nheight = 160\nz = 'high'\n",
                                          "camera z must be a number, got 'high'"),
                                         ("fx = 300\nfy = 300\ncx = 1\ncy = 1\nwidth = 200\n", "needs height"),
                                         ("fx = 300\nfy = 300\ncx = 1\ncy = 1\nwidth = 200\nheight = 160\nzoom = 2\n",
                                          "unknown camera setting 'zoom'"),
                                         ("fx = -300\nfy = 300\ncx = 1\ncy = 1\nwidth = 200\nheight = 160\n",
                                          "camera fx must be a positive number"),
                                         ("fx = 300\nfy = [\n", "not a valid TOML camera file")])
def test_a_malformed_camera_file_is_one_line_naming_file_and_field(robotcar, tmp_path, text, field):
    folder = image_folder(robotcar, tmp_path / "day")
    (folder / CAMERA_FILE).write_text(text)
    with pytest.raises(InputError, match=field):
        open_traverse(folder)
    proc = lostx("map", "build", folder, "--out", tmp_path / "day.map")
    assert proc.returncode == 2
    assert_one_line_error(proc, f"lostx: error: {folder / CAMERA_FILE}: ", field)
    assert not (tmp_path / "day.map").exists()


def test_camera_file_options_on_the_commands(robotcar, tmp_path):
    missing = tmp_path / "nowhere.toml"
    for args in (["map", "build", robotcar / "day", "--out", tmp_path / "m", "--camera-file", missing],
                 ["replay", robotcar / "day", "--to", "tcp://127.0.0.1:1", "--camera-file", missing],
                 ["eval", "--reference", robotcar / "day", "--query", robotcar / "night", "--out", tmp_path / "r",
                  "--query-camera-file", missing]):
        proc = lostx(*args)
        assert proc.returncode == 2, args
        assert_one_line_error(proc, f"lostx: error: camera file not found: {missing}")
    for command in (["map", "build"], ["match"], ["replay"], ["camera", "check"]):
        assert "--camera-file" in lostx(*command, "--help").stdout, command
    assert "--reference-camera-file" in lostx("eval", "--help").stdout


def test_a_video_reads_the_camera_file_in_its_folder(robotcar, tmp_path):
    files = list_images(robotcar / "day")[:3]
    video = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5.0, (1024, 640))
    for file in files:
        writer.write(cv2.imread(str(file)))
    writer.release()
    assert open_traverse(video).geometry is None
    write_camera_file(A_CAMERA, tmp_path / CAMERA_FILE)
    assert open_traverse(video).frame(1).geometry.to_dict() == A_CAMERA.to_dict()


def test_a_mirrored_traverse_gets_the_mirrored_camera_and_odometry(scene, robotcar, tmp_path):
    plain = open_traverse(scene / "scene-0523" / "rear")
    mirrored = open_traverse(scene / "scene-0523" / "rear", mirror=True)
    g, m = plain.geometry, mirrored.geometry
    point = np.array([-12.0, 3.0, 0.0])
    (u, v), _ = g.project(point)
    (mu, mv), _ = m.project(point * [1, -1, 1])  # the world reflected left-right
    assert (mu, mv) == pytest.approx((g.width - 1 - u, v))
    np.testing.assert_allclose(mirrored.odometry, plain.odometry * [1, -1, -1])
    folder = image_folder(robotcar, tmp_path / "day")
    write_camera_file(A_CAMERA, folder / CAMERA_FILE)  # a camera file is mirrored as it is read
    assert open_traverse(folder, mirror=True).geometry.roll == pytest.approx(-A_CAMERA.roll)


def test_a_live_camera_carries_the_camera_file(tmp_path):
    class OneFrame:
        def __init__(self) -> None:
            self.given = False

        def isOpened(self) -> bool:
            return True

        def read(self):
            if self.given:
                return False, None
            self.given = True
            return True, np.zeros((48, 64, 3), np.uint8)

        def release(self) -> None:
            pass

    with LiveCamera(0, opener=lambda index: OneFrame(), geometry=A_CAMERA) as live:
        frame = live.next_frame(5.0)
    assert frame is not None and frame.geometry is A_CAMERA


# -- odometry.csv --------------------------------------------------------------------------------------


def test_odometry_csv_by_file_name(robotcar, tmp_path):
    folder = image_folder(robotcar, tmp_path / "day")
    names = [f.name for f in list_images(folder)]
    rows = [f"{name},{2.0 * k},{-0.5 * k},{10.0 * k}" for k, name in reversed(list(enumerate(names)))]
    (folder / "odometry.csv").write_text("file,x,y,yaw\n" + "\n".join(rows) + "\n")
    traverse = open_traverse(folder)
    k = np.arange(10)
    np.testing.assert_allclose(traverse.odometry, np.stack([2.0 * k, -0.5 * k, np.radians(10.0 * k)], axis=1))
    assert traverse.frame(3).odometry == pytest.approx((6.0, -1.5, math.radians(30)))
    assert traverse.reversed().frame(0).odometry == pytest.approx((18.0, -4.5, math.radians(90)))
    (folder / "odometry.csv").write_text("file,x,y,yaw\n" + "\n".join(rows[1:]) + "\n")
    with pytest.raises(InputError, match=r"odometry.csv: no odometry for 1 image\(s\), e.g. 0000096.png"):
        open_traverse(folder)


def test_odometry_csv_by_nearest_timestamp(robotcar, tmp_path):
    folder = image_folder(robotcar, tmp_path / "day")
    names = [f.name for f in list_images(folder)]
    (folder / "positions.csv").write_text("file,x,y,timestamp\n" + "".join(
        f"{name},{k},0,{100.0 + 0.5 * k}\n" for k, name in enumerate(names)))
    # 20 Hz odometry starting 0.11 s before the first frame: frame k (t = 100 + 0.5 k) is nearest to row 10 k + 2.
    samples = [(99.89 + 0.05 * j, 0.1 * j, 0.0, 0.5 * j) for j in range(95)]
    (folder / "odometry.csv").write_text("timestamp,x,y,yaw\n" + "".join(f"{t:.3f},{x},{y},{yaw}\n"
                                                                         for t, x, y, yaw in samples))
    traverse = open_traverse(folder)
    rows = 10 * np.arange(10) + 2
    np.testing.assert_allclose(traverse.odometry[:, 0], 0.1 * rows)
    np.testing.assert_allclose(traverse.odometry[:, 2], np.radians(0.5 * rows))
    (folder / "odometry.csv").write_text("timestamp,x,y,yaw\n" + "".join(f"{t + 50:.3f},{x},{y},{yaw}\n"
                                                                         for t, x, y, yaw in samples))
    with pytest.raises(InputError, match=r"0000024.png at 100.000 s is 49.890 s from the nearest odometry row"):
        open_traverse(folder)
    (folder / "positions.csv").unlink()
    with pytest.raises(InputError, match="matches frames by timestamp, and these frames have none"):
        open_traverse(folder)


@pytest.mark.parametrize("text, message", [("file,x,y\n", "lacks yaw"),
                                           ("file,x,y,yaw\n0000024.png,1,2,north\n", "odometry.csv:2: not a number"),
                                           ("x,y,yaw\n1,2,3\n", "1 odometry rows for 10 images"),
                                           ("file,x,y,yaw\n", "no odometry rows after the header")])
def test_a_bad_odometry_csv_is_one_error_naming_file_and_line(robotcar, tmp_path, text, message):
    folder = image_folder(robotcar, tmp_path / "day")
    (folder / "odometry.csv").write_text(text)
    with pytest.raises(InputError, match=message):
        open_traverse(folder)


# -- RobotCar visual odometry --------------------------------------------------------------------------

T0 = 1_418_381_000_000_000  # microseconds


def robotcar_folder(tmp_path: Path, robotcar: Path, times: list[int]) -> Path:
    root = tmp_path / "2014-12-12-10-45-15"
    (root / "stereo" / "centre").mkdir(parents=True)
    for t, file in zip(times, list_images(robotcar / "day")):
        cv2.imwrite(str(root / "stereo" / "centre" / f"{t}.png"), cv2.imread(str(file))[::8, ::8])
    (root / "stereo.timestamps").write_text("".join(f"{t} 1\n" for t in times))
    return root


def test_robotcar_visual_odometry_is_chained_and_interpolated(robotcar, tmp_path):
    # A pose every 0.1 s, each 1 m forward of the last and turned 0.1 rad to the right (RobotCar: z down).
    vo_times = [T0 + 100_000 * k for k in range(8)]
    root = robotcar_folder(tmp_path, robotcar, [T0 + 100_000, T0 + 250_000, T0 + 800_000])
    (root / "vo").mkdir()
    rows = [f"{vo_times[k + 1]},{vo_times[k]},1.0,0.0,0.0,0.0,0.0,0.1" for k in range(7)]
    (root / "vo" / "vo.csv").write_text(
        "source_timestamp,destination_timestamp,x,y,z,roll,pitch,yaw\n" + "\n".join(rows) + "\n")
    heading = -0.1 * np.arange(8)  # lostx: anticlockwise, so a right turn is negative
    steps = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    positions = np.vstack([[0.0, 0.0], np.cumsum(steps[:-1], axis=0)])
    poses = np.column_stack([positions, heading])
    traverse = robotcar_traverse(root)
    expected = np.stack([poses[1], (poses[2] + poses[3]) / 2, poses[7]])
    np.testing.assert_allclose(traverse.odometry, expected, atol=1e-12)
    assert any("1 images outside the time span of vo/vo.csv" in n for n in traverse.notes)  # T0 + 800 000
    assert traverse.geometry is None  # RobotCar's sample has no calibration


def test_a_robotcar_traverse_without_vo_has_no_odometry(robotcar, tmp_path):
    root = robotcar_folder(tmp_path, robotcar, [T0 + 100_000, T0 + 250_000])
    assert robotcar_traverse(root).odometry is None
    (root / "vo").mkdir()
    (root / "vo" / "vo.csv").write_text("source_timestamp,destination_timestamp,x,y\n1,0,1,2\n")
    with pytest.raises(InputError, match=r"vo.csv:1: header .* lacks z, roll, pitch, yaw"):
        robotcar_traverse(root)


# -- bags ----------------------------------------------------------------------------------------------

B0 = 1_700_000_000_000_000_000  # ns
OPTICAL = (0.5, -0.5, 0.5, -0.5)  # wxyz: camera_link (x forward, z up) -> its optical frame (z forward, y down)


def tilted_down(degrees: float) -> tuple[float, float, float, float]:
    half = math.radians(degrees) / 2
    return (math.cos(half), 0.0, math.sin(half), 0.0)  # about y: +x tips towards -z


def drive(camera_topic: str = "/front", tf: bool = True, info: bool = True):
    """A drive of five tiny frames at 10 m/s turning left at 0.2 rad/s, a camera 1.2 m ahead and 1.6 m up
    looking 5 degrees down, its camera info and static transforms."""
    if tf:
        yield "/tf_static", "tf2_msgs/msg/TFMessage", tf_message(
            transform("base_footprint", "base_link", (0.0, 0.0, 0.3), (1.0, 0.0, 0.0, 0.0)),
            transform("base_link", "camera_link", (1.2, 0.1, 1.3), tilted_down(5.0))), B0 - 10
        yield "/tf_static", "tf2_msgs/msg/TFMessage", tf_message(
            transform("camera_link", "camera_optical_frame", (0.0, 0.0, 0.0), OPTICAL)), B0 - 5
    for k in range(12):
        t = B0 - 50_000_000 + k * 50_000_000
        yield "/odom", "nav_msgs/msg/Odometry", odometry(10.0 * (t - B0) / 1e9, 0.0, t, yaw=0.2 * (t - B0) / 1e9), t
    rng = np.random.default_rng(0)
    for k in range(5):
        t = B0 + k * 100_000_000
        if info:
            yield f"{camera_topic}/camera_info", "sensor_msgs/msg/CameraInfo", camera_info(t, (40.0, 40.0, 31.5, 23.5),
                                                                                            64, 48), t
        image = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
        yield f"{camera_topic}/image_raw", "sensor_msgs/msg/Image", raw_image(image, t), t + 1000


def test_a_bag_gives_the_camera_from_its_camera_info_and_static_transforms(tmp_path):
    bag = write_bag(tmp_path / "drive.mcap", drive())
    traverse = open_traverse(bag)
    g = traverse.geometry
    assert g is not None, traverse.notes
    assert (g.fx, g.fy, g.cx, g.cy, g.width, g.height) == (40.0, 40.0, 31.5, 23.5, 64, 48)
    # base_footprint is on the ground: the camera is 0.3 + 1.3 m up.
    assert (g.x, g.y, g.z) == pytest.approx((1.2, 0.1, 1.6))
    assert (g.yaw, g.pitch, g.roll) == pytest.approx((0.0, 5.0, 0.0), abs=1e-9)
    assert g.source == "/front/camera_info and /tf_static (camera_optical_frame in base_footprint)"
    # Odometry: the pose topic's x, y and heading at each image stamp.
    np.testing.assert_allclose(traverse.odometry[:, 0], 1.0 * np.arange(5), atol=1e-9)
    np.testing.assert_allclose(traverse.odometry[:, 2], 0.02 * np.arange(5), atol=1e-9)
    assert traverse.frame(2).geometry is g


def test_a_bag_without_calibration_is_read_without_geometry(tmp_path):
    bare = open_traverse(write_bag(tmp_path / "bare.mcap", drive(tf=False, info=False)))
    assert bare.geometry is None and bare.odometry is not None and not any("geometry" in n for n in bare.notes)
    no_tf = open_traverse(write_bag(tmp_path / "no_tf.mcap", drive(tf=False)))
    assert no_tf.geometry is None
    assert any("/tf_static has no transform from camera_optical_frame to base_footprint or base_link" in n
               for n in no_tf.notes)
    given = tmp_path / "camera.toml"
    write_camera_file(A_CAMERA, given)
    override = open_traverse(write_bag(tmp_path / "drive.mcap", drive()), options=SourceOptions(camera_file=given))
    assert override.geometry.to_dict() == A_CAMERA.to_dict()
    assert any("in place of the source's own (/front/camera_info and /tf_static" in n for n in override.notes)


# -- to the service ----------------------------------------------------------------------------------


def test_lostx_replay_carries_the_geometry_and_odometry_to_the_service(scene, tmp_path):
    from test_stream import FakeService

    endpoint = f"ipc://{tmp_path}/frames"
    fake = FakeService(endpoint)
    try:
        proc = lostx("replay", scene / "scene-0523" / "rear", "--to", endpoint, "--every", "10",
                     "--as-fast-as-possible", "--encoding", "jpeg", "--wait", "30", "--quiet")
    finally:
        fake.done.set()
        fake.join(5)
    assert proc.returncode == 0, proc.stderr
    traverse = open_traverse(scene / "scene-0523" / "rear", options=SourceOptions(every=10))
    assert len(fake.frames) == len(traverse) == 4
    for message, k in zip(fake.frames, range(4)):
        frame = message.to_frame()
        assert frame.geometry.to_dict() == traverse.geometry.to_dict()
        assert frame.odometry == pytest.approx(tuple(traverse.odometry[k]))
