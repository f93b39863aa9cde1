"""The command line: real runs, and one-line errors (no traceback, non-zero exit) on bad input."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest


def lostx(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lostx.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


def assert_one_line_error(proc: subprocess.CompletedProcess, *fragments: str) -> None:
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip() and "%|" not in line]
    assert len(lines) == 1, proc.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.fixture(scope="module")
def cli_map(tmp_path_factory, robotcar) -> Path:
    out = tmp_path_factory.mktemp("cli") / "day"
    proc = lostx("map", "build", robotcar / "day", "--out", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "10 frames" in proc.stdout
    return out


def test_build_and_match_write_the_documented_csv(cli_map, robotcar, tmp_path):
    out = tmp_path / "matches.csv"
    proc = lostx("match", cli_map, robotcar / "night", "--out", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 10
    assert {"query_index", "query_file", "match_index", "match_file", "score", "confidence", "candidates"} <= set(rows[0])
    matches = np.array([int(r["match_index"]) for r in rows])
    assert int((matches == np.arange(10)).sum()) == 6
    for r in rows:
        candidates = [int(c) for c in r["candidates"].split()]
        assert len(candidates) == 10 and candidates[0] == int(r["match_index"])
        assert 0.0 <= float(r["confidence"]) <= 1.0
        assert r["query_file"] == sorted(os.listdir(robotcar / "night"))[int(r["query_index"])]


def test_positions_are_stored(robotcar, tmp_path):
    names = sorted(os.listdir(robotcar / "day"))
    positions = tmp_path / "pos.csv"
    positions.write_text("file,x,y\n" + "".join(f"{n},{3.0 * i},{-1.0 * i}\n" for i, n in enumerate(reversed(names))))
    out = tmp_path / "map"
    proc = lostx("map", "build", robotcar / "day", "--out", out, "--positions", positions, "--descriptor", "thumbnail",
                 "--quiet")
    assert proc.returncode == 0, proc.stderr
    stored = np.load(out / "positions.npy")
    np.testing.assert_allclose(stored[0], [27.0, -9.0])  # the first image is the last CSV row


def test_unreadable_image_stops_the_build_and_leaves_nothing(robotcar, tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    for name in sorted(os.listdir(robotcar / "day"))[:3]:
        shutil.copy(robotcar / "day" / name, images / name)
    (images / "0000030.png").write_bytes(b"this is not a png")
    out = tmp_path / "map"
    proc = lostx("map", "build", images, "--out", out, "--quiet")
    assert_one_line_error(proc, "0000030.png", "not a decodable image")
    assert sorted(os.listdir(tmp_path)) == ["images"]


def test_empty_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    assert_one_line_error(lostx("map", "build", tmp_path / "empty", "--out", tmp_path / "m"), "no images in")


def test_missing_model(robotcar, tmp_path):
    proc = lostx("map", "build", robotcar / "day", "--out", tmp_path / "m", "--model", tmp_path / "nope.tflite")
    assert_one_line_error(proc, "nope.tflite", "not found", "--model")


def test_wrong_model_file(robotcar, tmp_path):
    fake = tmp_path / "fake.tflite"
    fake.write_bytes(os.urandom(5000))
    proc = lostx("map", "build", robotcar / "day", "--out", tmp_path / "m", "--model", fake)
    assert_one_line_error(proc, "fake.tflite", "--model")


def test_truncated_map_file(cli_map, robotcar, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(cli_map, broken)
    target = broken / "slot_channels.npy"
    target.write_bytes(target.read_bytes()[: target.stat().st_size // 2])
    proc = lostx("match", broken, robotcar / "night", "--out", tmp_path / "m.csv")
    assert_one_line_error(proc, "slot_channels.npy", "truncated")


def test_map_from_another_backbone(cli_map, robotcar, tmp_path):
    other = tmp_path / "other"
    shutil.copytree(cli_map, other)
    manifest = json.loads((other / "manifest.json").read_text())
    manifest["backbone"]["model_md5"] = "0" * 32  # as if built by another model file
    (other / "manifest.json").write_text(json.dumps(manifest))
    proc = lostx("match", other, robotcar / "night", "--out", tmp_path / "m.csv")
    assert_one_line_error(proc, "was built with backbone", "rebuild the map")


def test_match_against_a_folder_that_is_not_a_map(robotcar, tmp_path):
    proc = lostx("match", robotcar / "day", robotcar / "night", "--out", tmp_path / "m.csv")
    assert_one_line_error(proc, "not a complete lostx map")


def test_malformed_positions_csv_names_the_line(robotcar, tmp_path):
    positions = tmp_path / "pos.csv"
    positions.write_text("x,y\n1,2\n3,four\n")
    proc = lostx("map", "build", robotcar / "day", "--out", tmp_path / "m", "--positions", positions)
    assert_one_line_error(proc, "pos.csv:3", "not a number")
