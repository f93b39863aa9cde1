"""What a user types or feeds that lostx cannot use: a one-line error with exit code 2, never a traceback,
and nothing that eats the machine first."""

from __future__ import annotations

import shutil
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from lostx.core.errors import ImageError
from lostx.core.images import read_image

from test_cli import assert_one_line_error, lostx


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def bomb_png(width: int = 100_000, height: int = 100_000) -> bytes:
    """A PNG of a few kilobytes whose header declares ``width`` x ``height`` pixels."""
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(b"\0" * 3000))
            + _chunk(b"IEND", b""))


@pytest.fixture
def bomb_folder(tmp_path, robotcar) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, path in enumerate(sorted((robotcar / "night").glob("*.png"))[:3]):
        shutil.copy(path, folder / f"{i:03d}.png")
    (folder / "003.png").write_bytes(bomb_png())
    return folder


def test_an_image_declaring_too_many_pixels_is_refused_before_decoding(tmp_path):
    path = tmp_path / "bomb.png"
    path.write_bytes(bomb_png())
    assert path.stat().st_size < 4096
    with pytest.raises(ImageError, match="bomb.png: it declares too many pixels"):
        read_image(path)
    path.write_bytes(bomb_png(12_000, 9_000))  # 108 megapixels: under Pillow's own limit, over lostx's
    with pytest.raises(ImageError, match="declares 12000 x 9000 pixels, over the limit of 100 megapixels"):
        read_image(path)


@pytest.mark.parametrize("command", ["build", "match"])
def test_commands_refuse_the_image_in_one_line(bomb_folder, day_map, tmp_path, command):
    if command == "build":
        proc = lostx("map", "build", bomb_folder, "--out", tmp_path / "m", "--quiet")
    else:
        proc = lostx("match", day_map.path, bomb_folder, "--out", tmp_path / "m.csv", "--quiet")
    assert_one_line_error(proc, "003.png", "declares too many pixels")
    assert proc.returncode == 2


def test_a_corrupt_image_is_reported_by_lostx_alone(tmp_path, day_map):
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "000.png").write_bytes(bomb_png(64, 64)[:40] + b"not the rest of a png")
    proc = lostx("match", day_map.path, folder, "--out", tmp_path / "m.csv", "--quiet")
    assert_one_line_error(proc, "000.png", "not a decodable image")
    assert "WARN" not in proc.stderr


@pytest.mark.parametrize("args, fragments", [
    (["--window", "1000000000"], ["--window", "between 1 and 100000"]),
    (["--threads", "100000"], ["--threads", "between 1 and 256"]),
    (["--fps", "1e9"], ["--fps", "at most 1000"]),
    (["--every", "0"], ["--every", "at least 1"]),
    (["--web", "--web-port", "70000"], ["--web-port", "between 0 and 65535"]),
    (["--web", "--grpc-port", "-1"], ["--grpc-port", "between 0 and 65535"]),
    (["--web", "--viewer-memory", "lots"], ["--viewer-memory", "4GiB"]),
    (["--web", "--viewer-rate", "-1"], ["--viewer-rate", "at least 0"]),
])
def test_numbers_out_of_range_are_one_line_errors(day_map, robotcar, tmp_path, args, fragments):
    proc = lostx("match", day_map.path, robotcar / "night", "--out", tmp_path / "m.csv", *args)
    assert_one_line_error(proc, *fragments)
    assert proc.returncode == 2


def test_a_setting_out_of_range_in_a_file_is_one_line(day_map, robotcar, tmp_path):
    config = tmp_path / "c.toml"
    config.write_text("[backbone]\nthreads = 100000\n")
    proc = lostx("match", day_map.path, robotcar / "night", "--out", tmp_path / "m.csv", "--config", config)
    assert_one_line_error(proc, "[backbone] threads must be between 1 and 256, got 100000")


def test_a_reader_that_stops_early_is_no_error(day_map):
    proc = subprocess.run(f"{sys.executable} -m lostx.cli map info {day_map.path} | head -1", shell=True,
                          capture_output=True, text=True, timeout=120)
    assert proc.stdout.startswith("map ") and proc.stdout.count("\n") == 1
    assert proc.stderr == ""


def test_a_frame_of_reasonable_size_still_reads(robotcar):
    image = read_image(sorted((robotcar / "day").glob("*.png"))[0])
    assert image.shape == (640, 1024, 3) and image.dtype == np.uint8


def _rows(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines()[1:] if line]


def test_match_keeps_the_answers_before_a_frame_it_cannot_read(day_map, robotcar, tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, path in enumerate(sorted((robotcar / "night").glob("*.png"))[:6]):
        shutil.copy(path, folder / f"{i:03d}.png")
    (folder / "004.png").write_bytes(b"not an image at all")
    out = tmp_path / "m.csv"
    proc = lostx("match", day_map.path, folder, "--out", out, "--quiet")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "4 of 6 frames answered before it stopped; their answers are in" in proc.stderr
    assert "004.png" in proc.stderr
    rows = _rows(out)
    assert [row.split(",")[1] for row in rows] == [f"{i:03d}.png" for i in range(4)]


def test_match_keeps_the_answers_when_terminated(day_map, nordland, tmp_path):
    out = tmp_path / "m.csv"
    # 3576 frames: the command is still matching when it is told to stop.
    proc = subprocess.Popen([sys.executable, "-m", "lostx.cli", "match", str(day_map.path), str(nordland / "winter"),
                             "--out", str(out), "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not out.exists() or len(_rows(out)) < 2):
        time.sleep(0.05)
    proc.terminate()
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "Traceback" not in stderr
    answered = len(_rows(out))
    assert 2 <= answered < 3576
    assert f"{answered} of 3576 frames answered before it stopped" in stderr


def test_an_output_that_cannot_be_written_fails_before_any_frame(day_map, robotcar):
    start = time.monotonic()
    proc = lostx("match", day_map.path, robotcar / "night", "--out", "/proc/nope.csv")
    assert_one_line_error(proc, "/proc/nope.csv")
    assert "matching" not in proc.stderr and time.monotonic() - start < 30


def test_match_connecting_to_no_viewer_says_so_in_one_line(day_map, robotcar, tmp_path):
    from lostx.viz.rerun_app import free_port

    url = f"rerun+http://127.0.0.1:{free_port()}/proxy"  # nothing listens there
    out = tmp_path / "m.csv"
    proc = lostx("match", day_map.path, robotcar / "night", "--out", out, "--quiet", "--connect", url)
    assert proc.returncode == 0, proc.stderr
    assert len(_rows(out)) == 10
    port = url.split(":")[2].split("/")[0]
    assert proc.stderr.splitlines() == [(f"lostx: live view: no Rerun viewer at {url} (nothing accepts connections "
                                         f"on 127.0.0.1:{port}); going on without it (start the viewer first: "
                                         f"`rerun`)")]


def test_match_connect_to_what_is_not_a_viewer_url_is_one_line(day_map, robotcar, tmp_path):
    proc = lostx("match", day_map.path, robotcar / "night", "--out", tmp_path / "m.csv", "--connect", "foo")
    assert_one_line_error(proc, "--connect", '"foo"', "rerun+http://")
    assert proc.returncode == 2
