"""ROS 2 bags (MCAP): bags written here from the RobotCar frames read back as the folder does."""

from __future__ import annotations

import csv
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from lostx.core.errors import ImageError, InputError
from lostx.core.images import list_images, read_image
from lostx.replay.bag import bag_traverse
from lostx.replay.dataset import SourceOptions, detect_format, open_traverse
from lostx.replay.folder import folder_traverse
from lostx.replay.rosmsg import compressed_image_rgb, raw_image_rgb

from bagtools import compressed_image, nav_sat_fix, odometry, raw_image, write_bag
from test_cli import assert_one_line_error, lostx

T0 = 1_700_000_000_000_000_000  # ns
FRAME_NS = 100_000_000  # images at 10 Hz
LATENCY_NS = 7_000_000  # logged after their capture stamp, as a recorder does
SPEED = 10.0  # m/s east, odometry at 20 Hz starting 50 ms before the first image


def drive(images: list[np.ndarray]):
    """Messages of a drive: raw and PNG-compressed images of the same frames, and odometry."""
    for k in range(2 * len(images) + 2):
        t = T0 - 50_000_000 + k * 50_000_000
        yield "/odom", "nav_msgs/msg/Odometry", odometry(SPEED * (t - T0) / 1e9, -2.0, t), t
    for k, image in enumerate(images):
        t = T0 + k * FRAME_NS
        yield "/camera/image_raw", "sensor_msgs/msg/Image", raw_image(image, t, "bgr8"), t + LATENCY_NS
        yield "/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", compressed_image(image, t), \
            t + LATENCY_NS + 1000


@pytest.fixture(scope="module")
def bags(tmp_path_factory, robotcar) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bags")
    out = {}
    for side in ("day", "night"):
        images = [read_image(f) for f in list_images(robotcar / side)]
        out[side] = write_bag(root / f"{side}.mcap", drive(images))
    return out


def expected_positions(n: int) -> np.ndarray:
    return np.stack([SPEED * np.arange(n) * FRAME_NS / 1e9, np.full(n, -2.0)], axis=1)


@pytest.mark.parametrize("topic", ["/camera/image_raw", "/camera/image_raw/compressed"])
def test_bag_frames_are_the_folder_frames_with_stamps_and_odometry(bags, robotcar, topic):
    traverse = open_traverse(bags["day"], options=SourceOptions(topic=topic))
    folder = folder_traverse(robotcar / "day")
    assert detect_format(bags["day"]) == "bag" and len(traverse) == len(folder) == 10
    for from_bag, from_folder in zip(traverse, folder):
        assert np.array_equal(from_bag.image, from_folder.image)  # raw and PNG: lossless
    # Header stamps, not log times; positions interpolated between the 20 Hz odometry samples.
    np.testing.assert_allclose(traverse.timestamps - T0 / 1e9, np.arange(10) * 0.1, atol=1e-6)
    np.testing.assert_allclose(traverse.positions, expected_positions(10), atol=1e-9)
    assert traverse.names[3] == "1700000000.300000000"
    assert any("positions from /odom" in n for n in traverse.notes)


def test_a_reversed_or_subsampled_bag_reads_the_right_messages(bags, robotcar):
    traverse = bag_traverse(bags["night"], "/camera/image_raw")
    folder = folder_traverse(robotcar / "night")
    backwards = traverse.reversed()  # out of recording order: each message found through the index
    assert [f.name for f in backwards][:2] == ["1700000000.900000000", "1700000000.800000000"]
    for k, frame in enumerate(backwards):
        assert np.array_equal(frame.image, folder.image(9 - k))
    every_third = traverse.subset([0, 3, 6, 9])  # in order: one pass, decoding only these
    assert all(np.array_equal(f.image, folder.image(i)) for f, i in zip(every_third, [0, 3, 6, 9]))


def test_map_and_matches_from_bags_equal_those_from_the_folders(bags, robotcar, tmp_path):
    """The acceptance test: map from the raw topic, queries from the compressed topic, against the folders."""
    runs = {"folder": (robotcar / "day", robotcar / "night", []),
            "bag": (bags["day"], bags["night"], ["--topic", "/camera/image_raw"])}
    matches = {}
    for name, (day, night, topic) in runs.items():
        built = lostx("map", "build", day, "--out", tmp_path / name, "--quiet", *topic)
        assert built.returncode == 0, built.stderr
        query_topic = ["--topic", "/camera/image_raw/compressed"] if topic else []
        matched = lostx("match", tmp_path / name, night, "--out", tmp_path / f"{name}.csv", "--quiet", *query_topic)
        assert matched.returncode == 0, matched.stderr
        matches[name] = list(csv.DictReader((tmp_path / f"{name}.csv").open()))
    for array in ("descriptors.npy", "appearance.npy", "slot_channels.npy", "slot_values.npy"):
        assert np.array_equal(np.load(tmp_path / "folder" / array), np.load(tmp_path / "bag" / array)), array
    np.testing.assert_allclose(np.load(tmp_path / "bag" / "positions.npy"), expected_positions(10), atol=1e-9)
    columns = ("match_index", "candidates", "score", "confidence", "correspondences", "heading")
    assert [[r[c] for c in columns] for r in matches["bag"]] == [[r[c] for c in columns] for r in matches["folder"]]
    assert sum(int(r["match_index"]) == int(r["query_index"]) for r in matches["bag"]) == 6


def test_positions_from_navsatfix_and_posestamped(tmp_path):
    image = np.full((32, 48, 3), 90, np.uint8)
    messages = []
    for k in range(5):
        t = T0 + k * 200_000_000
        status = -1 if k == 2 else 0  # no fix: left out, interpolated across
        messages.append(("/fix", "sensor_msgs/msg/NavSatFix", nav_sat_fix(51.75 + 1e-4 * k, -1.25, t, status), t))
        pose = {"header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": "map"},
                "pose": {"position": {"x": 3.0 * k, "y": 1.0, "z": 0.0},
                         "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
        messages.append(("/pose", "geometry_msgs/msg/PoseStamped", pose, t))
    for k in range(4):
        t = T0 + 100_000_000 + k * 200_000_000
        messages.append(("/image", "sensor_msgs/msg/Image", raw_image(image, t), t))
    bag = write_bag(tmp_path / "gps.mcap", messages)
    undecided = bag_traverse(bag)
    assert undecided.positions is None
    assert "2 pose topics (/fix, /pose) and no --pose-topic: no positions" in undecided.notes
    gps = bag_traverse(bag, pose_topic="/fix")
    # Images halfway between fixes; the fix without a position (k = 2) is interpolated over.
    np.testing.assert_allclose(gps.geo[:, 0], 51.75 + 1e-4 * (np.arange(4) + 0.5), atol=1e-9)
    # Metres north of the first image: 1e-4 degree of latitude per frame.
    np.testing.assert_allclose(gps.positions, np.stack([np.zeros(4), np.radians(1e-4) * 6_371_008.8 * np.arange(4)],
                                                       axis=1), atol=1e-6)
    pose = bag_traverse(bag, pose_topic="/pose")
    np.testing.assert_allclose(pose.positions, [[1.5 + 3.0 * k, 1.0] for k in range(4)], atol=1e-9)
    assert pose.geo is None


def test_a_split_recording_is_read_in_recording_order(tmp_path):
    folder = tmp_path / "drive"
    folder.mkdir()
    shades = [np.full((16, 16, 3), 10 * k, np.uint8) for k in range(6)]
    # Named so that name order is not recording order: the files' start times decide.
    for name, part in (("drive_b.mcap", range(0, 3)), ("drive_a.mcap", range(3, 6))):
        write_bag(folder / name, [("/image", "sensor_msgs/msg/Image", raw_image(shades[k], T0 + k * FRAME_NS),
                                   T0 + k * FRAME_NS) for k in part])
    traverse = open_traverse(folder)
    assert len(traverse) == 6 and [int(f.image[0, 0, 0]) for f in traverse] == [0, 10, 20, 30, 40, 50]
    assert [int(f.image[0, 0, 0]) for f in traverse.reversed()] == [50, 40, 30, 20, 10, 0]


# --- image encodings ---------------------------------------------------------------------------------------


def raw(image: np.ndarray, encoding: str, step: int | None = None, bigendian: bool = False):
    height, width = image.shape[:2]
    row = image.reshape(height, -1).view(np.uint8)
    step = step or row.shape[1]
    padded = np.zeros((height, step), np.uint8)
    padded[:, : row.shape[1]] = row
    return SimpleNamespace(encoding=encoding, height=height, width=width, step=step, is_bigendian=int(bigendian),
                           data=padded.tobytes())


def test_raw_encodings_come_out_as_rgb(rng):
    rgb = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    assert np.array_equal(raw_image_rgb(raw(rgb, "rgb8", step=32)), rgb)  # row padding skipped
    assert np.array_equal(raw_image_rgb(raw(np.ascontiguousarray(rgb[:, :, ::-1]), "bgr8")), rgb)
    grey = rng.integers(0, 256, (6, 8), dtype=np.uint8)
    assert np.array_equal(raw_image_rgb(raw(grey, "mono8")), np.stack([grey] * 3, axis=2))
    deep = grey.astype(np.uint16) * 257  # 16-bit, most significant byte first
    assert np.array_equal(raw_image_rgb(raw(deep.astype(">u2"), "mono16", bigendian=True)),
                          np.stack([grey] * 3, axis=2))
    bayer = rng.integers(0, 256, (8, 8), dtype=np.uint8)
    assert np.array_equal(raw_image_rgb(raw(bayer, "bayer_rggb8")), cv2.cvtColor(bayer, cv2.COLOR_BayerRGGB2RGB))
    with pytest.raises(ImageError, match="encoding '32FC1' is not supported"):
        raw_image_rgb(raw(grey.astype(np.float32), "32FC1"))
    with pytest.raises(ImageError, match="too few"):
        raw_image_rgb(SimpleNamespace(encoding="rgb8", height=6, width=8, step=24, is_bigendian=0, data=b"\0" * 50))


def test_compressed_images_in_either_channel_order(rng):
    rgb = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1].tobytes()
    assert np.array_equal(compressed_image_rgb(SimpleNamespace(format="png", data=png)), rgb)
    as_rgb = cv2.imencode(".png", rgb)[1].tobytes()  # payload stored R first, as its format says
    assert np.array_equal(compressed_image_rgb(SimpleNamespace(format="rgb8; png compressed rgb8", data=as_rgb)), rgb)
    with pytest.raises(ImageError, match="cannot be decoded"):
        compressed_image_rgb(SimpleNamespace(format="jpeg", data=b"not a jpeg"))


# --- bad input -------------------------------------------------------------------------------------------------


def test_a_bag_without_the_topic_lists_the_topics_it_has(bags, tmp_path):
    proc = lostx("map", "build", bags["day"], "--topic", "/front/image", "--out", tmp_path / "m")
    assert_one_line_error(proc, "no topic /front/image", "/camera/image_raw (sensor_msgs/msg/Image, 10 messages)",
                          "/odom (nav_msgs/msg/Odometry, 22 messages)")
    assert not (tmp_path / "m").exists()
    with pytest.raises(InputError, match="2 image topics; choose one with --topic"):
        bag_traverse(bags["day"])
    with pytest.raises(InputError, match="topic /odom holds nav_msgs/msg/Odometry messages, not images"):
        bag_traverse(bags["day"], "/odom")
    with pytest.raises(InputError, match="topic /camera/image_raw holds sensor_msgs/msg/Image messages, not poses"):
        bag_traverse(bags["day"], "/camera/image_raw", pose_topic="/camera/image_raw")
    with pytest.raises(InputError, match="--scene does not apply to a bag source"):
        open_traverse(bags["day"], options=SourceOptions(topic="/camera/image_raw", scene="scene-0523"))


def test_files_that_are_not_bags(tmp_path):
    fake = tmp_path / "fake.mcap"
    fake.write_bytes(b"this is not an MCAP file at all")
    assert_one_line_error(lostx("map", "build", fake, "--out", tmp_path / "m"), "fake.mcap", "not a readable MCAP bag")
    empty = tmp_path / "rosbag"
    empty.mkdir()
    (empty / "rosbag_0.db3").write_bytes(b"")
    with pytest.raises(InputError, match=r"no \.mcap files .* convert it with `ros2 bag convert`"):
        bag_traverse(empty)
    truncated = tmp_path / "cut.mcap"
    whole = write_bag(tmp_path / "whole.mcap", [("/image", "sensor_msgs/msg/Image",
                                                  raw_image(np.zeros((16, 16, 3), np.uint8), T0 + k), T0 + k)
                                                 for k in range(3)])
    truncated.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    with pytest.raises(InputError, match="cut.mcap: not a readable MCAP bag"):
        bag_traverse(truncated)


def test_a_message_that_cannot_be_decoded_is_named(tmp_path):
    from mcap.well_known import SchemaEncoding
    from mcap.writer import Writer

    from bagtools import definition

    with open(tmp_path / "corrupt.mcap", "wb") as handle:
        writer = Writer(handle)
        writer.start(profile="ros2")
        schema = writer.register_schema("sensor_msgs/msg/Image", SchemaEncoding.ROS2,
                                        definition("sensor_msgs/msg/Image").encode())
        channel = writer.register_channel("/image", "cdr", schema)
        writer.add_message(channel, log_time=5, publish_time=5, data=b"\x00\x01\x00\x00\x05")  # a cut-off message
        writer.finish()
    with pytest.raises(InputError, match="corrupt.mcap: a message logged at 5 ns cannot be decoded"):
        bag_traverse(tmp_path / "corrupt.mcap")
