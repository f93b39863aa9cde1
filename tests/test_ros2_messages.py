"""lostx's ROS 2 messages and names as ROS 2 has them: each message's CDR bytes against the ``rosbags`` package's
serialiser (an implementation of ROS 2's CDR written apart from Cyclone DDS), the DDS names, the pose covariance,
the odometry at a frame's stamp, the Cyclone DDS configuration, and the command line around them."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="lostx[ros2] is part of the test extra")

from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402
from test_cli import assert_one_line_error, lostx  # noqa: E402

from lostx.core.config import Ros2Config  # noqa: E402
from lostx.core.errors import InputError  # noqa: E402
from lostx.replay.odometry import interpolate_poses  # noqa: E402
from lostx.stream.ros2 import dds, msgs, names  # noqa: E402
from lostx.stream.ros2.answers import ANY_HEADING_VARIANCE, RIGHT_HEADING_SIGMA, MapPlaces  # noqa: E402
from lostx.stream.ros2.inputs import OdometryTrack  # noqa: E402


@pytest.fixture(scope="module")
def typestore():
    """ROS 2's message definitions (Humble's), and lostx_msgs from the .msg files lostx ships."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    found = {}
    for path in sorted(names.INTERFACES.glob("msg/*.msg")):
        found.update(get_types_from_msg(path.read_text(), f"lostx_msgs/msg/{path.stem}"))
    store.register(found)
    return store


def as_rosbags(store, ros_type: str, value):
    """The same message as a rosbags instance, field by field (primitive arrays as numpy arrays)."""
    kind = store.types[ros_type]
    values = {}
    for f in dataclasses.fields(kind):
        if f.name.startswith("__") or f.name.isupper():
            continue  # rosbags' own bookkeeping (the type's name) and the message's constants
        raw = getattr(value, f.name)
        nested = next((t for t, n in msgs.ROS_TYPES.items() if isinstance(raw, t)), None)
        if nested is not None:
            values[f.name] = as_rosbags(store, msgs.ROS_TYPES[nested], raw)
        elif isinstance(raw, bytes):
            values[f.name] = np.frombuffer(raw, dtype=np.uint8)
        elif isinstance(raw, list) and raw and isinstance(raw[0], tuple(msgs.ROS_TYPES)):
            values[f.name] = [as_rosbags(store, msgs.ROS_TYPES[type(v)], v) for v in raw]
        elif isinstance(raw, list):
            values[f.name] = np.asarray(raw, dtype=np.float64)
        else:
            values[f.name] = raw
    return kind(**values)


def header(stamp_ns: int = 1_700_000_000_123_456_789, frame: str = "cam_front_optical") -> msgs.Header:
    return msgs.Header(msgs.Time.from_ns(stamp_ns), frame)


def samples() -> list:
    """A message of every type lostx sends or reads, with values in every field (odd lengths, to show the padding)."""
    quaternion = msgs.Quaternion(0.1, -0.2, 0.3, 0.927)
    pose = msgs.Pose(msgs.Point(1.5, -2.25, 0.125), quaternion)
    covariance = [0.01 * k for k in range(36)]
    transform = msgs.TransformStamped(header(frame="base_footprint"), "cam_front_optical",
                                      msgs.Transform(msgs.Vector3(1.7, 0.0, 1.5), quaternion))
    return [
        msgs.Image(header(), 3, 5, "bgr8", 0, 15, bytes(range(45))),
        msgs.CompressedImage(header(), "jpeg", b"\xff\xd8\xff\xe0abc"),
        msgs.CameraInfo(header(), 900, 1600, "plumb_bob", [0.1, -0.2, 0.0, 0.0, 0.01],
                        [1252.8, 0.0, 826.6, 0.0, 1252.8, 470.0, 0.0, 0.0, 1.0], [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
                        [1252.8, 0.0, 826.6, 0.0, 0.0, 1252.8, 470.0, 0.0, 0.0, 0.0, 1.0, 0.0], 1, 1,
                        msgs.RegionOfInterest(1, 2, 3, 4, True)),
        msgs.Odometry(header(frame="odom"), "base_link", msgs.PoseWithCovariance(pose, covariance),
                      msgs.TwistWithCovariance(msgs.Twist(msgs.Vector3(3.0, 0.0, 0.0), msgs.Vector3(0.0, 0.0, 0.1)),
                                               covariance)),
        msgs.TFMessage([transform, transform]),
        msgs.PoseWithCovarianceStamped(header(frame="map"), msgs.PoseWithCovariance(pose, covariance)),
        msgs.Place(header(), "/camera/image_raw/compressed", 12345678901, "localized", False, "", 17, "0000094.png",
                   True, 5712.5, -120.25, 0.9991, 0.431, 16, "opposite", 0.97, -1.0, 0.52, 4.1, 20,
                   [msgs.Candidate(17, 0.21, 0.431, 61), msgs.Candidate(3, 0.33, math.nan, 0)],
                   [msgs.Latency("network", 38.2), msgs.Latency("total", 44.9)]),
        msgs.Place(header(), "/cam", 3, "bad_frame", False, "image of 8x8 pixels is too small"),
    ]


@pytest.mark.parametrize("sample", samples(), ids=lambda s: type(s).__name__)
def test_each_message_is_the_cdr_ros2_sends(sample, typestore):
    ros_type = msgs.ROS_TYPES[type(sample)]
    ours = sample.serialize()
    theirs = bytes(typestore.serialize_cdr(as_rosbags(typestore, ros_type, sample), ros_type))
    assert ours[:4] == b"\x00\x01\x00\x00"  # plain CDR (XCDR1), little-endian
    assert ours == theirs
    assert type(sample).deserialize(theirs).serialize() == ours  # and back: what rosbags writes, lostx reads


def test_a_place_decodes_to_what_was_sent(typestore):
    place = samples()[-2]
    back = typestore.deserialize_cdr(place.serialize(), "lostx_msgs/msg/Place")
    assert (back.stream, back.frame, back.state, back.match_index, back.match_name) == (
        place.stream, place.frame, place.state, place.match_index, place.match_name)
    assert back.header.stamp.sec == 1_700_000_000 and back.header.stamp.nanosec == 123_456_789
    assert [c.index for c in back.candidates] == [17, 3] and math.isnan(back.candidates[1].score)
    assert [(x.stage, x.ms) for x in back.latency] == [("network", 38.2), ("total", 44.9)]
    assert typestore.types["lostx_msgs/msg/Place"].STATE_BAD_FRAME == "bad_frame"


def test_the_answers_are_written_as_plain_cdr_alone():
    """As rmw_cyclonedds allows ROS 2 messages: XCDR1, never XCDR2."""
    from cyclonedds.core import Policy
    from cyclonedds.util import duration

    qos = dds.answer_qos(Ros2Config())
    assert qos[Policy.DataRepresentation] == Policy.DataRepresentation(use_cdrv0_representation=True)
    assert qos[Policy.Reliability] == Policy.Reliability.Reliable(duration(seconds=dds.MAX_BLOCKING_S))
    assert qos[Policy.History] == Policy.History.KeepLast(10)
    images = dds.image_qos(Ros2Config())
    assert images[Policy.Reliability] == Policy.Reliability.BestEffort and images[Policy.History] == \
        Policy.History.KeepLast(5)
    every = dds.image_qos(Ros2Config(image_reliability="reliable", image_depth=0))
    assert every[Policy.History] == Policy.History.KeepAll
    assert dds.tf_static_qos()[Policy.Durability] == Policy.Durability.TransientLocal


def test_dds_names_are_the_rmw_layers():
    assert names.dds_topic("/camera/image_raw") == "rt/camera/image_raw"
    assert names.dds_topic("odom") == "rt/odom"
    assert names.dds_type("sensor_msgs/msg/CompressedImage") == "sensor_msgs::msg::dds_::CompressedImage_"
    assert msgs.Place.__idl__.idl_transformed_typename == "lostx_msgs::msg::dds_::Place_"
    assert msgs.PoseWithCovarianceStamped.__idl__.idl_transformed_typename == \
        "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"
    assert names.camera_info_topic("/cam/image_raw/compressed") == "/cam/camera_info"
    assert names.camera_info_topic("/cam/image_rect") == "/cam/camera_info"
    assert names.camera_info_topic("/image_raw") == "/camera_info"
    assert names.is_compressed("/cam/image_raw/compressed") and not names.is_compressed("/cam/image_raw")
    assert names.answer_topics("/robot1/lostx") == ("/robot1/lostx/place", "/robot1/lostx/pose")
    for bad in ("/cam//image", "/cam/image raw", "/2cam", "/cam/", "/a__b"):
        with pytest.raises(InputError, match="not a ROS 2 topic name"):
            names.dds_topic(bad)


def test_the_loopback_configuration_keeps_to_this_machine(monkeypatch):
    monkeypatch.delenv("CYCLONEDDS_URI", raising=False)
    loopback = dds.cyclone_config("loopback")
    assert '<NetworkInterface address="127.0.0.1" multicast="true"/>' in loopback
    assert '<Peer address="localhost"/>' in loopback and "<ParticipantIndex>auto</ParticipantIndex>" in loopback
    assert '<NetworkInterface name="eth0"/>' in dds.cyclone_config("eth0")
    assert '<NetworkInterface address="192.168.1.20"/>' in dds.cyclone_config("192.168.1.20")
    assert dds.cyclone_config("auto") == ""
    with pytest.raises(InputError, match="network interface"):
        dds.cyclone_config('eth0"/><Peer address="x')
    monkeypatch.setenv("CYCLONEDDS_URI", "file:///etc/cyclone.xml")
    assert dds.cyclone_config("loopback") == f"{loopback},file:///etc/cyclone.xml"  # the user's settings win


def test_the_ros_domain_comes_from_the_setting_then_the_environment(monkeypatch):
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert dds.domain_id(Ros2Config()) == 0
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert dds.domain_id(Ros2Config()) == 42
    assert dds.domain_id(Ros2Config(domain_id=7)) == 7
    monkeypatch.setenv("ROS_DOMAIN_ID", "robot")
    with pytest.raises(InputError, match="ROS_DOMAIN_ID='robot'"):
        dds.domain_id(Ros2Config())


def test_the_pose_covariance_follows_the_confidence():
    """A straight route along x, a frame every 2 m: a right answer is within a step (variance (2/2)^2 = 1 per
    axis); a wrong one anywhere on the map (mean squared distance from the middle frame, 40 m^2, split over x and
    y: 20); between, weighed by the confidence. The heading is the route's, reversed driving it backwards."""
    places = MapPlaces(np.column_stack([np.arange(11) * 2.0, np.full(11, 5.0)]))
    sure, unsure, half = places.pose(5, 1.0, 1.0), places.pose(5, 0.0, 1.0), places.pose(5, 0.5, 1.0)
    assert (sure.x, sure.y) == (10.0, 5.0)
    assert sure.covariance[0] == sure.covariance[7] == pytest.approx(1.0)
    assert unsure.covariance[0] == pytest.approx(20.0) and half.covariance[0] == pytest.approx(10.5)
    assert sure.covariance[35] == pytest.approx(RIGHT_HEADING_SIGMA ** 2)
    assert unsure.covariance[35] == pytest.approx(ANY_HEADING_VARIANCE)
    assert sure.yaw == pytest.approx(0.0) and places.pose(5, 1.0, -1.0).yaw == pytest.approx(math.pi)
    unknown = places.pose(0, 1.0, None)
    assert unknown.covariance[35] == pytest.approx(ANY_HEADING_VARIANCE)
    assert sum(v != 0 for v in sure.covariance) == 3  # planar: z, roll and pitch left out


def odometry_message(x: float, y: float, yaw: float, stamp: int) -> msgs.Odometry:
    pose = msgs.Pose(msgs.Point(x, y, 0.0), msgs.Quaternion.from_yaw(yaw))
    return msgs.Odometry(msgs.Header(msgs.Time.from_ns(stamp), "odom"), "base_link", msgs.PoseWithCovariance(pose))


def test_the_odometry_at_a_frame_is_the_bag_readers():
    track = OdometryTrack()
    stamps = np.array([0, 20, 40, 60, 80]) * 1_000_000 + 10**18
    poses = np.array([[0.0, 0.0, 3.1], [0.2, 0.01, 3.13], [0.4, 0.03, -3.13], [0.6, 0.06, -3.1], [0.8, 0.1, -3.08]])
    for k in (4, 0, 2, 1, 3, 2):  # out of order, and one twice
        track.add(odometry_message(*poses[k], int(stamps[k])))
    frames = stamps[0] + np.array([5, 30, 59, 80]) * 1_000_000
    expected = interpolate_poses(stamps, poses, frames)
    for stamp, pose in zip(frames, expected):
        assert track.covers(int(stamp))
        assert track.pose_at(int(stamp), 0) == pytest.approx(tuple(pose), abs=1e-12)
    # past the newest: carried on at the last speed for up to the limit, then nothing
    ahead = track.pose_at(int(stamps[-1]) + 10_000_000, 500_000_000)
    assert ahead == pytest.approx((0.9, 0.12, -3.07), abs=1e-9)
    assert track.pose_at(int(stamps[-1]) + 600_000_000, 500_000_000) is None
    assert track.pose_at(int(stamps[0]) - 1, 500_000_000) is None
    assert track.child_frame == "base_link" and not track.covers(int(stamps[-1]) + 1)


def test_the_interfaces_command_writes_a_ros2_package(tmp_path, typestore):
    proc = lostx("ros2", "interfaces", tmp_path / "src")
    assert proc.returncode == 0, proc.stderr
    package = tmp_path / "src" / "lostx_msgs"
    assert sorted(p.name for p in (package / "msg").iterdir()) == ["Candidate.msg", "Latency.msg", "Place.msg"]
    assert "<name>lostx_msgs</name>" in (package / "package.xml").read_text()
    assert '"msg/Place.msg"' in (package / "CMakeLists.txt").read_text()
    again = lostx("ros2", "interfaces", tmp_path / "src")
    assert_one_line_error(again, "exists", "--overwrite")


def test_the_command_says_what_it_lacks(tmp_path):
    assert_one_line_error(lostx("ros2", "--topic", "/cam/image_raw"), "--map")
    assert_one_line_error(lostx("ros2", "--map", tmp_path), "--topic")
    assert_one_line_error(lostx("ros2", "--map", tmp_path, "--topic", "/cam/image raw"), "not a ROS 2 topic name")
    assert_one_line_error(lostx("ros2", "--map", tmp_path, "--topic", "/cam", "--domain-id", "300"), "--domain-id")
    assert_one_line_error(lostx("ros2", "--map", tmp_path, "--topic", "/cam", "--interface", "eth0<"), "--interface")


def test_the_ros2_extra_is_in_the_test_extra():
    import tomllib

    project = tomllib.loads((Path(__file__).resolve().parent.parent / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    assert any(d.startswith("cyclonedds") for d in extras["ros2"])
    assert "ros2" in extras["test"][0] and any(d.startswith("rosbags") for d in extras["test"])


def test_keep_all_images_hold_a_reliable_publisher_back(monkeypatch):
    """Every frame, in order, and never more than KEEP_ALL_FRAMES waiting for the localizer: a reliable publisher
    (ros2 bag play) is then made to wait, rather than lostx's memory growing with the recording."""
    import uuid

    from cyclonedds.core import DDSException, Policy, Qos
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    monkeypatch.setenv("CYCLONEDDS_URI", f"<CycloneDDS><Domain><Discovery><Tag>lostx-test-{uuid.uuid4().hex}</Tag>"
                                         f"</Discovery></Domain></CycloneDDS>")
    participant = dds.participant(Ros2Config(domain_id=231))
    topic = Topic(participant, "rt/camera/image_raw/compressed", msgs.CompressedImage)
    reader = DataReader(participant, topic, dds.image_qos(Ros2Config(image_reliability="reliable", image_depth=0)))
    writer = DataWriter(participant, topic, Qos(Policy.Reliability.Reliable(duration(milliseconds=200)),
                                                Policy.History.KeepAll))
    frame = msgs.CompressedImage(msgs.Header(), "jpeg", bytes(100_000))
    for _ in range(dds.KEEP_ALL_FRAMES):
        writer.write(frame)
    with pytest.raises(DDSException, match="TIMEOUT"):
        writer.write(frame)  # one more waits for the localizer, here in vain
    assert len(reader.take(100)) == dds.KEEP_ALL_FRAMES
    writer.write(frame)  # taken: room again
