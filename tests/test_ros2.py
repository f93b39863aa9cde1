"""``lostx ros2`` against a ROS 2 peer written apart from it (tests/ros2tools.py): real frames replayed from a bag
over DDS on loopback by another process, answered by lostx in a third, every answer received by a subscriber with
the ROS 2 type definitions and equal to ``lostx match`` on the same bag; bad frames; a stalled subscriber."""

from __future__ import annotations

import csv
import math
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="lostx[ros2] is part of the test extra")

import ros2tools  # noqa: E402
from rosbags import camera_info, compressed_image, odometry, tf_message, transform, write_bag  # noqa: E402
from test_cli import lostx  # noqa: E402

from lostx.core.images import list_images  # noqa: E402

HERE = Path(__file__).resolve().parent
IMAGES = "/camera/image_raw/compressed"
T0 = 1_700_000_000_000_000_000
STARTUP_S = 120.0
"""Longest a node may take to start (the model loads) on a loaded machine."""


def a_domain() -> int:
    """A ROS domain of the test's own (the discovery tag isolates it too; this only spreads the ports)."""
    return random.SystemRandom().randrange(100, 200)


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


class Node:
    """``lostx ros2`` in a process of its own, stopped with SIGINT as a user would."""

    def __init__(self, *args: object, env: dict[str, str], log: Path) -> None:
        self.log = log
        self._out = open(log, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", "lostx.cli", "ros2", *map(str, args)], env=env,
                                     stdout=self._out, stderr=subprocess.STDOUT, text=True)

    def wait_ready(self) -> None:
        end = time.monotonic() + STARTUP_S
        while "answering" not in self.log.read_text():
            if self.proc.poll() is not None or time.monotonic() > end:
                raise AssertionError(f"lostx ros2 did not start:\n{self.log.read_text()}")
            time.sleep(0.1)

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


def play(bag: Path, domain: int, env: dict[str, str], lockstep: bool = True) -> subprocess.CompletedProcess:
    args = [sys.executable, str(HERE / "ros2tools.py"), "publish", str(bag), "--domain", str(domain)]
    if lockstep:
        args += ["--lockstep", "/lostx"]
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=600)


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


def test_robotcar_frames_over_dds_get_the_answers_of_lostx_match(day_map, robotcar, tmp_path):
    bag = night_bag(robotcar, tmp_path / "night.mcap")
    rows = match_rows(day_map.path, bag, tmp_path / "match.csv", "--window", "3")
    domain = a_domain()
    env = ros2tools.isolated(domain)
    os.environ["CYCLONEDDS_URI"] = env["CYCLONEDDS_URI"]  # the subscriber here joins the same tag
    try:
        answers = ros2tools.Answers(ros2tools.domain(domain), ros2tools.Types())
    finally:
        del os.environ["CYCLONEDDS_URI"]
    node = Node("--map", day_map.path, "--topic", IMAGES, "--window", "3", "--domain-id", domain,
                "--image-qos", "reliable", env=env, log=tmp_path / "node.log")
    try:
        node.wait_ready()
        played = play(bag, domain, env)
        assert played.returncode == 0, played.stderr
        places = answers.wait(10, 60)
    finally:
        log = node.stop()
    assert node.proc.returncode == 0, log
    assert f"{IMAGES}: answered 10 of 10 frames" in log
    assert [p.stream for p in places] == [IMAGES] * 10
    assert_same_answers(places, rows)
    assert [p.warming_up for p in places[:2]] == [True, True]
    stages = {lat.stage for lat in places[-1].latency}
    assert {"network", "total", "decode", "node"} <= stages
    assert answers.poses == []  # the sample's map has no positions: no pose to give
