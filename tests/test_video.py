"""Video files through OpenCV: a video encoded here from the RobotCar night frames replays and matches."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.core.images import list_images
from lostx.core.localizer import Localizer
from lostx.evaluation.datasets import open_pair
from lostx.replay.dataset import SourceOptions, detect_format, open_traverse
from lostx.replay.folder import folder_traverse
from lostx.replay.subsample import rate_subsample_indices

from streamtools import Collector, endpoints, lostx_command, procs, wait_for  # noqa: F401  (fixtures)
from test_cli import assert_one_line_error, lostx

FPS = 5.0


def encode_video(folder: Path, path: Path) -> Path:
    """The images of ``folder`` as an MPEG-4 Part 2 video at 5 frames per second (lossy, as a dash cam's)."""
    files = list_images(folder)
    height, width = cv2.imread(str(files[0])).shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (width, height))
    assert writer.isOpened()
    for file in files:
        writer.write(cv2.imread(str(file)))
    writer.release()
    return path


@pytest.fixture(scope="module")
def night_video(tmp_path_factory, robotcar) -> Path:
    return encode_video(robotcar / "night", tmp_path_factory.mktemp("video") / "night.mp4")


def test_a_video_reads_as_its_frames_at_the_recorded_rate(night_video, robotcar):
    video = open_traverse(night_video)
    folder = folder_traverse(robotcar / "night")
    assert detect_format(night_video) == "video" and len(video) == 10
    np.testing.assert_allclose(video.timestamps, np.arange(10) / FPS)
    assert video.names[:2] == ["night.mp4#0", "night.mp4#1"]
    for from_video, from_folder in zip(video, folder):
        error = np.abs(from_video.image.astype(int) - from_folder.image.astype(int)).mean()
        assert error < 8.0, f"{from_video.name}: mean error {error:.1f} grey levels"  # lossy, but the same picture
    # Backwards (seeking) gives the very frames read forwards.
    forwards = [f.image for f in video]
    assert all(np.array_equal(f.image, forwards[9 - k]) for k, f in enumerate(video.reversed()))


def test_every_and_fps_choose_frames(night_video):
    every = open_traverse(night_video, options=SourceOptions(every=4))
    assert every.names == ["night.mp4#0", "night.mp4#4", "night.mp4#8"]
    slower = open_traverse(night_video, options=SourceOptions(fps=2.0))  # every 0.5 s of a 5 fps recording
    np.testing.assert_allclose(slower.timestamps, [0.0, 0.4, 1.0, 1.4])  # nearest frames to 0, 0.5, 1.0, 1.5
    assert slower.source_indices.tolist() == [0, 2, 5, 7]


def test_videos_without_positions_are_index_aligned_pairs(night_video, robotcar, tmp_path):
    day = encode_video(robotcar / "day", tmp_path / "day.mp4")
    pair = open_pair(day, night_video)
    assert pair.format == "pairs" and pair.aligned
    assert pair.ground_truth(1)[0].matches(9).tolist() == [8, 9]
    mixed = open_pair(robotcar / "day", night_video, format="pairs")
    assert mixed.aligned and mixed.query.names[0] == "night.mp4#0" and mixed.reference.names[0] == "0000024.png"


def test_rate_subsampling_takes_the_nearest_frame_to_each_tick():
    times = np.arange(31) / 30.0
    assert rate_subsample_indices(times, 10.0).tolist() == list(range(0, 31, 3))
    assert rate_subsample_indices(times, 7.0).tolist() == [0, 4, 9, 13, 17, 21, 26, 30]  # 7 Hz on average
    assert rate_subsample_indices(times, 60.0).tolist() == list(range(31))  # no frame twice
    with pytest.raises(InputError, match="positive number of frames per second"):
        rate_subsample_indices(times, 0.0)


def test_a_video_matches_like_its_frames(night_video, robotcar, day_map, tmp_path):
    proc = lostx("match", day_map.path, night_video, "--out", tmp_path / "video.csv", "--quiet")
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader((tmp_path / "video.csv").open()))
    assert [r["query_file"] for r in rows] == [f"night.mp4#{k}" for k in range(10)]
    offsets = np.array([int(r["match_index"]) - int(r["query_index"]) for r in rows])
    # The folder gives 6 exact and 10 within one frame; the lossy video (measured) 5 and 10.
    assert (offsets == 0).sum() >= 5 and (np.abs(offsets) <= 1).all()


def test_a_video_replays_into_the_service_and_is_answered(night_video, day_map, mosaic, procs, tmp_path):
    frames, results = endpoints("ipc", tmp_path)
    client = Collector(results, topics=("result",))
    try:
        procs.start("serve", lostx_command("serve", "--map", str(day_map.path), "--frames", frames, "--results",
                                           results, "--mode", "lossless", "--no-journal", "--wait-listeners", "1"))
        procs.start("replay", lostx_command("replay", str(night_video), "--to", frames, "--quiet", "--wait", "60",
                                            "--as-fast-as-possible"))
        assert procs.processes["replay"].wait(120) == 0
        wait_for(lambda: len(client.results) == 10, 30, "the ten answers")
    finally:
        client.stop()
    assert "10 answered" in procs.log("replay")
    direct = Localizer(day_map, backbone=mosaic)
    expected = [direct.step(frame) for frame in open_traverse(night_video)]
    assert [r.frame_id for r in client.results] == list(range(10))
    assert [(r.match_index, r.single_match_index) for r in client.results] == \
        [(e.match_index, e.single_match_index) for e in expected]
    # The single-frame answers are those of `lostx match` on the video (see above).
    single = np.array([r.single_match_index - r.frame_id for r in client.results])
    assert (single == 0).sum() >= 5 and (np.abs(single) <= 1).all()


def test_unreadable_videos_are_one_line_errors(tmp_path, day_map):
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 40)
    assert_one_line_error(lostx("match", day_map.path, broken, "--out", tmp_path / "m.csv"),
                          "cannot read video", "broken.mp4")
    assert not (tmp_path / "m.csv").exists()
    with pytest.raises(InputError, match="video not found"):
        open_traverse(tmp_path / "missing.mp4", format="video")
    with pytest.raises(InputError, match="notes.txt: a file, but neither an MCAP bag"):
        (tmp_path / "notes.txt").write_text("hello")
        open_traverse(tmp_path / "notes.txt")


def test_a_recording_cut_short_is_read_up_to_where_it_ends(robotcar, tmp_path):
    whole = tmp_path / "whole.avi"
    writer = cv2.VideoWriter(str(whole), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (256, 160))
    for file in list_images(robotcar / "night"):
        writer.write(cv2.resize(cv2.imread(str(file)), (256, 160)))
    writer.release()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(whole.read_bytes()[: int(whole.stat().st_size * 0.75)])  # the index still says 10 frames
    video = open_traverse(cut)
    assert len(video) < 10 and len(list(video)) == len(video)
    assert video.notes == [f"cut.avi declares 10 frames: counted {len(video)} by decoding"]
