"""``lostx ros2`` against a ROS 2 peer written apart from it (tests/ros2tools.py): real frames replayed from a bag
over DDS on loopback by another process, answered by lostx in a third, every answer received by a subscriber with
the ROS 2 type definitions and equal to ``lostx match`` on the same bag; bad frames; a stalled subscriber."""

from __future__ import annotations

import csv
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="lostx[ros2] is part of the test extra")

import ros2tools  # noqa: E402
from bagtools import camera_info, compressed_image, odometry, tf_message, transform, write_bag  # noqa: E402
from test_cli import lostx  # noqa: E402

from lostx.core.images import list_images  # noqa: E402

HERE = Path(__file__).resolve().parent
IMAGES = "/camera/image_raw/compressed"
T0 = 1_700_000_000_000_000_000
STARTUP_S = 120.0
"""Longest a node may take to start (the model loads) on a loaded machine."""


def night_bag(robotcar: Path, path: Path) -> Path:
    """The ten RobotCar night frames as CompressedImage (their PNG files' bytes), 0.5 s apart."""
    def messages():
        for k, file in enumerate(list_images(robotcar / "night")):
            stamp = T0 + k * 500_000_000
            data = file.read_bytes()
            yield IMAGES, "sensor_msgs/msg/CompressedImage", {
                "header": {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}, "frame_id": "camera"},
                "format": "png", "data": data}, stamp
    return write_bag(path, messages())


class Peer:
    """The test's side of the DDS conversation: a ROS domain and a discovery tag of its own, and a subscriber to the
    answers, in this process."""

    def __init__(self) -> None:
        self.domain = ros2tools.unused_domain()  # the tag isolates it; this spreads the ports
        self.env = ros2tools.isolated(self.domain)
        os.environ["CYCLONEDDS_URI"] = self.env["CYCLONEDDS_URI"]
        try:
            self.participant = ros2tools.domain(self.domain)
        finally:
            del os.environ["CYCLONEDDS_URI"]
        self.types = ros2tools.Types()
        self.answers = ros2tools.Answers(self.participant, self.types)


@pytest.fixture
def peer() -> Peer:
    return Peer()


class Node:
    """``lostx ros2`` in a process of its own, stopped with SIGINT as a user would."""

    def __init__(self, *args: object, env: dict[str, str], log: Path) -> None:
        self.log = log
        self._out = open(log, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", "lostx.cli", "ros2", *map(str, args)], env=env,
                                     stdout=self._out, stderr=subprocess.STDOUT, text=True)

    def wait_for(self, text: str, timeout: float = STARTUP_S) -> None:
        """Until the node's log says ``text`` (it started: "answering"; it found a publisher: "TOPIC: 1 publisher";
        frames published before that never reach it, as with any DDS subscriber)."""
        end = time.monotonic() + timeout
        while text not in self.log.read_text():
            if self.proc.poll() is not None or time.monotonic() > end:
                raise AssertionError(f"lostx ros2 did not say {text!r}:\n{self.log.read_text()}")
            time.sleep(0.05)

    def stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._out.close()
        return self.log.read_text()


def play(bag: Path, peer: Peer, node: Node, topics: list[str], answers: tuple[str, ...] = ("/lostx/place",),
         lockstep: bool = True) -> None:
    """Replay ``bag`` over DDS from a process of its own, once ``node`` has found its publisher of each of
    ``topics`` and the subscribers to its ``answers``."""
    args = [sys.executable, str(HERE / "ros2tools.py"), "publish", str(bag), "--domain", str(peer.domain)]
    if lockstep:
        args += ["--lockstep", "/lostx"]
    player = subprocess.Popen(args, env=peer.env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        assert player.stdout.readline().strip() == "matched", player.stderr.read()
        for topic in topics:
            node.wait_for(f"{topic}: 1 publisher", 60)
        for topic in answers:  # this test's subscriber and the player's
            node.wait_for(f"{topic}: 2 subscribers", 60)
        out, err = player.communicate("go\n", timeout=600)
    finally:
        if player.poll() is None:
            player.kill()
            player.wait()
    assert player.returncode == 0, err


def match_rows(map_path: Path, bag: Path, out: Path, *options: str) -> list[dict[str, str]]:
    proc = lostx("match", map_path, bag, "--sequence", "--out", out, "--quiet", *options)
    assert proc.returncode == 0, proc.stderr
    with open(out) as handle:
        return list(csv.DictReader(handle))


def assert_same_answers(places: list, rows: list[dict[str, str]]) -> None:
    """Each Place says what ``lostx match`` wrote for the same frame."""
    assert len(places) == len(rows)
    for place, row in zip(places, rows):
        assert place.frame == int(row["query_index"])
        stamp = f"{place.header.stamp.sec}.{place.header.stamp.nanosec:09d}"
        assert stamp == row["query_file"]
        assert place.state == row["state"]
        assert place.match_index == int(row["match_index"]) and place.match_name == row["match_file"]
        assert place.single_match_index == int(row["single_match_index"])
        assert " ".join(str(c.index) for c in place.candidates) == row["candidates"]
        assert f"{place.confidence:.4f}" == row["confidence"]
        assert f"{place.score:.6g}" == row["score"]
        assert place.heading == row["heading"] and f"{place.heading_confidence:.4f}" == row["heading_confidence"]
        speed = "" if math.isnan(place.speed) else f"{place.speed:.3f}"
        assert speed == row["speed"]
        if "x" in row:
            assert (place.x, place.y) == (float(row["x"]), float(row["y"]))


def test_robotcar_frames_over_dds_get_the_answers_of_lostx_match(day_map, robotcar, tmp_path, peer):
    bag = night_bag(robotcar, tmp_path / "night.mcap")
    rows = match_rows(day_map.path, bag, tmp_path / "match.csv", "--window", "3")
    node = Node("--map", day_map.path, "--topic", IMAGES, "--window", "3", "--domain-id", peer.domain,
                "--image-qos", "reliable", env=peer.env, log=tmp_path / "node.log")
    try:
        node.wait_for("answering")
        play(bag, peer, node, [IMAGES])
        places = peer.answers.wait(10, 60)
    finally:
        log = node.stop()
    assert node.proc.returncode == 0, log
    assert f"{IMAGES}: answered 10 of 10 frames" in log
    assert [p.stream for p in places] == [IMAGES] * 10
    assert_same_answers(places, rows)
    assert [p.warming_up for p in places[:2]] == [True, True]
    stages = {lat.stage for lat in places[-1].latency}
    assert {"network", "total", "decode", "node"} <= stages
    assert peer.answers.poses == []  # the sample's map has no positions: no pose to give


def quaternion_by_hand(r: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix (Shepperd's method, written out here)."""
    trace = np.trace(r)
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        return 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    i = int(np.argmax(np.diag(r)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2.0 * math.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
    q = [0.0, 0.0, 0.0, 0.0]
    q[0] = (r[k, j] - r[j, k]) / s
    q[1 + i] = 0.25 * s
    q[1 + j] = (r[j, i] + r[i, j]) / s
    q[1 + k] = (r[k, i] + r[i, k]) / s
    return q[0], q[1], q[2], q[3]


def drive_bag(scene: Path, path: Path, frames: int) -> Path:
    """A drive as a ROS 2 robot records it: the nuScenes front camera's JPEGs (CompressedImage), its camera info,
    its place on the vehicle in /tf_static, and the ego poses as odometry, one a frame and one after the last."""
    from lostx.replay.dataset import SourceOptions, open_traverse

    drive = open_traverse(scene / "front", options=SourceOptions(look_at=15.0))
    g = drive.geometry
    files = list_images(scene / "front")
    stamps = [int(f.stem.rsplit("__", 1)[1]) * 1000 for f in files]
    optical = "cam_front_optical"

    def messages():
        yield "/tf_static", "tf2_msgs/msg/TFMessage", tf_message(
            transform("base_footprint", optical, (g.x, g.y, g.z), quaternion_by_hand(g.rotation))), stamps[0] - 1000
        for k in range(frames + 1):
            x, y, yaw = drive.odometry[k]
            yield "/odom", "nav_msgs/msg/Odometry", odometry(x, y, stamps[k], yaw), stamps[k]
            if k == frames:
                break
            yield "/camera/camera_info", "sensor_msgs/msg/CameraInfo", camera_info(
                stamps[k], (g.fx, g.fy, g.cx, g.cy), g.width, g.height, optical), stamps[k] + 1
            image = compressed_image(np.zeros((2, 2, 3), np.uint8), stamps[k])
            image.update(format="jpeg", data=files[k].read_bytes())
            image["header"]["frame_id"] = optical
            yield IMAGES, "sensor_msgs/msg/CompressedImage", image, stamps[k] + 2
    return write_bag(path, messages())


def test_a_drive_with_camera_info_tf_and_odometry_gets_the_answers_and_poses_of_lostx_match(robotcar, tmp_path,
                                                                                           peer):
    """The camera's geometry (camera info and /tf_static) and the motion (odometry) reach the localizer as the bag
    reader gives them to lostx match (without the odometry the answers differ): the layout takes part, and the
    map's positions come back as poses."""
    scene = robotcar.parent / "nuscenes-frontrear" / "scene-0523"
    bag = drive_bag(scene, tmp_path / "front.mcap", 12)
    rear = tmp_path / "rear.map"
    built = lostx("map", "build", scene / "rear", "--look-at", "--out", rear, "--quiet")
    assert built.returncode == 0, built.stderr
    rows = match_rows(rear, bag, tmp_path / "match.csv", "--topic", IMAGES, "--pose-topic", "/odom", "--window", "5")
    node = Node("--map", rear, "--topic", IMAGES, "--odom-topic", "/odom", "--window", "5", "--image-qos", "reliable",
                "--odom-qos", "reliable", "--odometry-wait", "5", "--map-frame", "world", "--domain-id", peer.domain,
                env=peer.env, log=tmp_path / "node.log")
    try:
        node.wait_for("answering")
        play(bag, peer, node, [IMAGES, "/odom", "/camera/camera_info", "/tf_static"], ("/lostx/place", "/lostx/pose"))
        places = peer.answers.wait(12, 60)
    finally:
        log = node.stop()
    assert node.proc.returncode == 0, log
    assert "camera geometry from /camera/camera_info and /tf_static (cam_front_optical in base_footprint)" in log
    assert "no odometry" not in log
    assert_same_answers(places, rows)
    assert all(any(lat.stage == "layout" and lat.ms > 0 for lat in p.latency) for p in places)  # geometry used
    assert len(peer.answers.poses) == 12
    for place, pose in zip(places, peer.answers.poses):
        assert pose.header.frame_id == "world" and pose.header.stamp == place.header.stamp
        assert (pose.pose.pose.position.x, pose.pose.pose.position.y) == (place.x, place.y)
        assert pose.pose.covariance[0] == pose.pose.covariance[7] > 0


def raw_image(types: ros2tools.Types, rgb: np.ndarray | None, stamp: int, *, height: int = 0, width: int = 0,
              data: bytes | None = None) -> object:
    if rgb is not None:
        height, width = rgb.shape[:2]
        data = rgb.tobytes()
    return types.build("sensor_msgs/msg/Image", {
        "header": {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}, "frame_id": "cam"},
        "height": height, "width": width, "encoding": "rgb8", "step": 3 * width, "data": data})


def test_frames_that_cannot_be_answered_get_bad_frame_and_the_node_goes_on(day_map, robotcar, tmp_path, peer):
    """Two cameras (raw and compressed): garbage bytes, a frame too small to localize, pixels short of the size
    declared and a size over the limit are each answered with bad_frame and a logged error; the good frames after
    them are answered, each camera a stream of its own."""
    import cv2

    node = Node("--map", day_map.path, "--topic", "/cam/image_raw", "--topic", "/cam/image_raw/compressed",
                "--image-qos", "reliable", "--window", "3", "--domain-id", peer.domain, env=peer.env,
                log=tmp_path / "node.log")
    types, participant = peer.types, peer.participant
    raw = ros2tools.DataWriter(participant, ros2tools.Topic(participant, "rt/cam/image_raw",
                                                            types["sensor_msgs/msg/Image"]), ros2tools.qos())
    packed = ros2tools.DataWriter(participant, ros2tools.Topic(participant, "rt/cam/image_raw/compressed",
                                                               types["sensor_msgs/msg/CompressedImage"]),
                                  ros2tools.qos())
    night = list_images(robotcar / "night")
    frames = [
        (packed, types.build("sensor_msgs/msg/CompressedImage", {"format": "png", "data": b"not an image at all"})),
        (raw, raw_image(types, np.zeros((8, 8, 3), np.uint8), T0 + 1)),
        (raw, raw_image(types, None, T0 + 2, height=100, width=100, data=bytes(10))),
        (raw, raw_image(types, None, T0 + 3, height=100_000, width=100_000, data=bytes(3))),
        (packed, types.build("sensor_msgs/msg/CompressedImage", {
            "header": {"stamp": {"sec": T0 // 10**9 + 1}}, "format": "png", "data": night[0].read_bytes()})),
        (raw, raw_image(types, cv2.cvtColor(cv2.imread(str(night[1])), cv2.COLOR_BGR2RGB), T0 + 10**9)),
    ]
    try:
        for found in ("/cam/image_raw: 1 publisher", "/cam/image_raw/compressed: 1 publisher",
                      "/lostx/place: 1 subscriber"):
            node.wait_for(found)
        for n, (writer, message) in enumerate(frames, start=1):
            writer.write(message)
            assert len(peer.answers.wait(n, 60)) == n, node.log.read_text()
    finally:
        log = node.stop()
    assert node.proc.returncode == 0, log
    places = peer.answers.places
    assert [p.state for p in places[:4]] == ["bad_frame"] * 4
    assert [p.stream for p in places] == ["/cam/image_raw/compressed"] + ["/cam/image_raw"] * 3 + [
        "/cam/image_raw/compressed", "/cam/image_raw"]
    assert "cannot be decoded" in places[0].error
    assert places[1].error == "image of 8x8 pixels is too small"
    assert "too few" in places[2].error
    assert "over the limit" in places[3].error
    assert all(p.match_index == -1 for p in places[:4])
    assert [p.state for p in places[4:]] == ["not_localized"] * 2 and [p.warming_up for p in places[4:]] == [True] * 2
    assert [p.frame for p in places] == [0, 0, 1, 2, 1, 3]  # numbered per camera
    assert log.count("bad_frame") == 4
    assert "/cam/image_raw: answered 1 of 4 frames, 3 bad" in log
    assert "/cam/image_raw/compressed: answered 1 of 2 frames, 1 bad" in log


def test_answers_never_wait_for_a_stalled_subscriber(tmp_path):
    """A subscriber that stops reading (SIGSTOP) takes none of the localizer's time: the answers' writer keeps the
    last answers for it and goes on. A keep-all writer would stop at Cyclone's history limit (500 kB) and fail."""
    from lostx.core.config import Ros2Config
    from lostx.stream.ros2 import dds, msgs

    domain = ros2tools.unused_domain()
    env = ros2tools.isolated(domain)
    stalled = subprocess.Popen([sys.executable, str(HERE / "ros2tools.py"), "listen", "--domain", str(domain)],
                               env=env, stdout=subprocess.PIPE, text=True)
    try:
        os.environ["CYCLONEDDS_URI"] = env["CYCLONEDDS_URI"]
        try:
            participant = dds.participant(Ros2Config(domain_id=domain))
        finally:
            del os.environ["CYCLONEDDS_URI"]
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        writer = DataWriter(participant, Topic(participant, "rt/lostx/place", msgs.Place), dds.answer_qos(Ros2Config()))
        assert stalled.stdout.readline().strip() == "listening"
        ros2tools.wait_matched(writer)
        os.kill(stalled.pid, signal.SIGSTOP)
        answer = msgs.Place(stream="/camera/image_raw", state="localized", error="x" * 2000,
                            candidates=[msgs.Candidate(k, 0.5, 1.5, 40) for k in range(10)])
        for frame in range(2000):  # 5 MB of answers, ten times the writer's history limit
            answer.frame = frame
            writer.write(answer)
        assert writer.get_publication_matched_status().current_count == 1  # still there, still stalled
    finally:
        stalled.kill()
        stalled.wait()


def test_a_fast_dds_peer_gets_the_answers_of_lostx_match(tmp_path):
    """Fast DDS (rmw_fastrtps' middleware) on the other side: a C++ peer (scripts/fastdds_peer.cpp) publishes the
    RobotCar night frames and decodes every Place and pose with Fast CDR; each is what lostx match says. Runs where
    Fast DDS's headers are installed (apt-get install libfastrtps-dev libfastcdr-dev)."""
    sys.path.insert(0, str(HERE.parent / "scripts"))
    import check_fastdds

    missing = check_fastdds.fast_dds_missing()
    if missing is not None:
        pytest.skip(f"no Fast DDS peer here: {missing}")
    found = check_fastdds.run(tmp_path)
    assert check_fastdds.differences(found) == []
    assert len(found["places"]) == len(found["poses"]) == 10
    assert all(pose["frame_id"] == "map" for pose in found["poses"])
    assert re.search(r"answered (\d+) of \1 frames", found["node"]) and found["probes"] >= 1  # and the probe
