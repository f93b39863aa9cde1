"""--reverse on the query side of match, eval and replay: the route driven the other way."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

from lostx.core.images import list_images

from test_cli import lostx
from test_stream import FakeService


@pytest.fixture(scope="module")
def thumb_day(tmp_path_factory, robotcar):
    out = tmp_path_factory.mktemp("reverse") / "day"
    proc = lostx("map", "build", robotcar / "day", "--descriptor", "thumbnail", "--out", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    return out


def rows(path):
    return list(csv.DictReader(path.open()))


@pytest.fixture
def trusted_heading(tmp_path):
    """Settings under which a single-frame answer depends on the frame alone: the declared camera is trusted,
    so no heading evidence carries over from frame to frame."""
    path = tmp_path / "trusted.toml"
    path.write_text("[heading]\ndeclared_prior = 1.0\n")
    return path


def test_match_reverse_runs_the_queries_backwards(thumb_day, robotcar, tmp_path, trusted_heading):
    """Reversed, each file gets the answer it got forwards (single frame, the heading given)."""
    forwards, backwards = tmp_path / "f.csv", tmp_path / "b.csv"
    given = ("--camera", "front", "--config", trusted_heading)
    assert lostx("match", thumb_day, robotcar / "night", "--out", forwards, "--quiet", *given).returncode == 0
    # Reversing turns a declared camera round: declared rear, the reversed frames are declared front, as forwards.
    proc = lostx("match", thumb_day, robotcar / "night", "--out", backwards, "--quiet", "--reverse",
                 "--camera", "rear", "--config", trusted_heading)
    assert proc.returncode == 0, proc.stderr
    assert "note: night: frames in reverse order" in proc.stdout
    f, b = rows(forwards), rows(backwards)
    assert [r["query_index"] for r in b] == [str(k) for k in range(10)]
    assert [r["query_file"] for r in b] == sorted(p.name for p in list_images(robotcar / "night"))[::-1]
    keys = ("query_file", "match_index", "score", "confidence", "candidates")
    assert [[r[k] for k in keys] for r in b] == [[r[k] for k in keys] for r in f[::-1]]


def test_eval_reverse_keeps_the_ground_truth_on_the_original_frames(robotcar, tmp_path, trusted_heading):
    reports = {}
    for name, extra in (("forwards", ["--query-camera", "front"]), ("backwards", ["--reverse", "--query-camera", "rear"])):
        proc = lostx("eval", "--reference", robotcar / "day", "--query", robotcar / "night", "--out", tmp_path / name,
                     "--methods", "thumbnail", "--modes", "single", "--quiet", "--config", trusted_heading, *extra)
        assert proc.returncode == 0, proc.stderr
        reports[name] = json.loads((tmp_path / name / "report.json").read_text())
    assert "night (reversed) (query)" in (tmp_path / "backwards" / "report.md").read_text()
    forwards, backwards = reports["forwards"], reports["backwards"]
    assert backwards == forwards  # the same answers scored against the same places, in another order


def test_replay_reverse_sends_the_frames_backwards_on_a_forward_clock(robotcar, tmp_path):
    video = tmp_path / "night.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (160, 100))
    for file in list_images(robotcar / "night")[:6]:
        writer.write(cv2.resize(cv2.imread(str(file)), (160, 100)))
    writer.release()
    receiver = FakeService(f"ipc://{tmp_path}/frames")
    try:
        proc = lostx("replay", video, "--to", f"ipc://{tmp_path}/frames", "--reverse", "--every", "2",
                     "--as-fast-as-possible", "--quiet", "--wait", "30")
    finally:
        receiver.done.set()
        receiver.join(5)
    assert proc.returncode == 0, proc.stderr
    assert [m.name for m in receiver.frames] == ["night.mp4#4", "night.mp4#2", "night.mp4#0"]
    assert [m.id for m in receiver.frames] == [0, 1, 2]
    np.testing.assert_allclose([m.timestamp for m in receiver.frames], [0.0, 0.2, 0.4])
