"""The command line: real runs, and one-line errors (no traceback, non-zero exit) on bad input."""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from streamtools import link_frames, thumb_map  # noqa: F401  (fixture)


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


def test_match_csv_gives_the_matched_position_where_the_map_has_positions(cli_map, robotcar, tmp_path):
    names = sorted(os.listdir(robotcar / "day"))
    positions = tmp_path / "pos.csv"
    # Map coordinates as large as UTM northings, to the centimetre: written back as they were given.
    positions.write_text("file,x,y\n" + "".join(f"{n},{500123.25 + 3.5 * i},{5735001.75 - i}\n"
                                                for i, n in enumerate(names)))
    located = tmp_path / "located"
    proc = lostx("map", "build", robotcar / "day", "--out", located, "--positions", positions, "--quiet")
    assert proc.returncode == 0, proc.stderr
    for refmap, has_positions in ((located, True), (cli_map, False)):
        out = tmp_path / f"{refmap.name}.csv"
        proc = lostx("match", refmap, robotcar / "night", "--out", out, "--quiet")
        assert proc.returncode == 0, proc.stderr
        rows = list(csv.DictReader(out.open()))
        assert len(rows) == 10
        assert ({"x", "y"} <= set(rows[0])) == has_positions
        for row in rows if has_positions else ():
            i = int(row["match_index"])
            assert (row["x"], row["y"]) == (str(500123.25 + 3.5 * i), str(5735001.75 - i))


def test_match_warns_once_that_classes_asked_for_are_not_the_maps(cli_map, robotcar, tmp_path):
    config = tmp_path / "c.toml"
    config.write_text('[lost]\nclasses = { road = ["road"], wall = ["wall"] }\n')
    out = tmp_path / "m.csv"
    proc = lostx("match", cli_map, robotcar / "night", "--out", out, "--quiet", "--config", config)
    assert proc.returncode == 0, proc.stderr
    assert len(list(csv.DictReader(out.open()))) == 10
    assert proc.stderr.splitlines() == [
        (f"lostx: warning: [lost] classes in {config} is ignored: {cli_map} was built with the classes road, "
         f"building, vegetation, and a map is matched with its own (build the map with these classes to use them)")]
    # The map's own classes by name: nothing to warn about.
    proc = lostx("match", cli_map, robotcar / "night", "--out", out, "--quiet", "--class-preset", "street")
    assert proc.returncode == 0 and proc.stderr == ""


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


def test_a_folder_of_folders_names_them_and_how_to_point_at_one(robotcar, tmp_path):
    root = tmp_path / "traverses"
    for name in ("autumn", "spring", "summer", "winter"):
        (root / name).mkdir(parents=True)
    shutil.copy(min((robotcar / "day").glob("*.png")), root / "spring")
    proc = lostx("map", "build", root, "--out", tmp_path / "m")
    assert_one_line_error(proc, f"no images in {root}", "it holds folders (autumn, spring, summer and 1 more): "
                          f"give one of them as the source, e.g. {root / 'spring'}")
    assert proc.returncode == 2 and not (tmp_path / "m").exists()


def test_a_config_that_is_a_folder_is_one_line(cli_map, robotcar, tmp_path):
    folder = tmp_path / "empty"
    folder.mkdir()
    proc = lostx("match", cli_map, robotcar / "night", "--out", tmp_path / "m.csv", "--config", folder)
    assert_one_line_error(proc, f"lostx: error: config file {folder} is a folder: give the TOML file of settings "
                          f"in it (see docs/config.md)")
    assert proc.returncode == 2 and not (tmp_path / "m.csv").exists()


def test_ctrl_c_in_map_build_says_what_was_kept_and_how_to_resume(nordland, tmp_path):
    import signal
    import threading
    import time

    out = tmp_path / "winter"
    argv = ["map", "build", str(nordland / "winter"), "--out", str(out)]
    proc = subprocess.Popen([sys.executable, "-m", "lostx.cli", *argv], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    seen: list[str] = []
    reader = threading.Thread(target=lambda: seen.extend(iter(lambda: proc.stderr.read(1), "")), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 240
        # The progress bar has counted a few frames: 3576 are far from done.
        while not re.search(r"\b([2-9]|\d\d+)/3576\b", "".join(seen)) and time.monotonic() < deadline:
            time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(60) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    reader.join(10)
    last = "".join(seen).replace("\r", "\n").strip().splitlines()[-1]
    found = re.fullmatch(r"lostx: interrupted: (\d+) of 3576 frames described are kept \(in (.+)\); to resume, run "
                         r"the same command again: (.+)", last)
    assert found, last
    kept, checkpoint, command = int(found.group(1)), Path(found.group(2)), found.group(3)
    assert 2 <= kept < 3576
    assert checkpoint == tmp_path / ".winter.build"
    chunks = sorted(checkpoint.glob("chunk-*.npz"))
    assert sum(int(c.stem.split("-")[2]) - int(c.stem.split("-")[1]) for c in chunks) == kept
    assert command == "lostx " + " ".join(argv)


def test_missing_model(robotcar, tmp_path):
    proc = lostx("map", "build", robotcar / "day", "--out", tmp_path / "m", "--model", tmp_path / "nope.tflite")
    assert_one_line_error(proc, "nope.tflite", "not found", "--model")


def test_wrong_model_file(robotcar, tmp_path):
    fake = tmp_path / "fake.tflite"
    fake.write_bytes(os.urandom(5000))
    proc = lostx("map", "build", robotcar / "day", "--out", tmp_path / "m", "--model", fake)
    assert_one_line_error(proc, "fake.tflite", "--model")


@pytest.mark.parametrize("content", [b"hello\n", b"", os.urandom(3000)], ids=["text", "empty", "random"])
def test_a_junk_pth_model_is_one_clean_line(robotcar, tmp_path, content):
    junk = tmp_path / "junk.pth"
    junk.write_bytes(content)
    proc = lostx("map", "build", robotcar / "day", "--out", tmp_path / "m", "--backbone", "espnetv2-cityscapes",
                 "--model", junk)
    # Nothing of what PyTorch said (a pickle opcode, an errno, advice on torch.load): the file and what was expected.
    assert_one_line_error(proc)
    assert proc.stderr == (f"lostx: error: {junk} is not a PyTorch checkpoint ({len(content)} bytes: truncated, or "
                           f"another kind of file); pass the ESPNetv2 Cityscapes weights with --model PATH\n")


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


# -- start-up, help and usage errors ---------------------------------------------------------------

HEAVY = ("numpy", "cv2", "zmq", "torch", "matplotlib", "rerun", "scipy", "tqdm", "ai_edge_litert")


def test_building_the_parser_loads_no_heavy_library():
    """`lostx --help` and `--version` start at once: command modules load their libraries only when they run."""
    code = ("import sys; from lostx.cli import build_parser; build_parser(); "
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-P", "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""


def test_lostx_alone_lists_the_commands():
    from lostx.cli import COMMANDS

    proc = lostx()
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    for name in COMMANDS:
        assert re.search(rf"^\s+{name}\b", proc.stdout, re.M), name


def test_map_build_help_lists_only_the_options_that_act_there():
    build, match = lostx("map", "build", "--help").stdout, lostx("match", "--help").stdout
    for option in ("--scoring", "--top-k", "--window", "--no-tracker"):
        assert option not in build and option in match
    for option in ("--out", "--config", "--backbone", "--model", "--threads"):
        assert option in build


@pytest.mark.parametrize(
    "args, message",
    [
        (["match", "M", "Q", "--out", "o.csv", "--window", "-1"], "argument --window: must be between 1 and 100000, got -1"),
        (["match", "M", "Q", "--out", "o.csv", "--window", "0"], "argument --window: must be between 1 and 100000, got 0"),
        (["match", "M", "Q", "--out", "o.csv", "--window", "ten"],
         "argument --window: expected a whole number, got 'ten'"),
        (["match", "M", "Q", "--out", "o.csv", "--top-k", "-2"], "argument --top-k: must be at least 1, got -2"),
        (["match", "M", "Q", "--out", "o.csv", "--top-k", "0"], "argument --top-k: must be at least 1, got 0"),
        (["map", "build", "I", "--out", "m", "--threads", "0"], "argument --threads: must be between 1 and 256, got 0"),
        (["map", "build", "I", "--out", "m", "--window", "3"],
         "unrecognized arguments: --window 3 (see 'lostx map build --help')"),
        (["serve", "--map", "M", "--window", "0"], "argument --window: must be between 1 and 100000, got 0"),
        (["demo", "--window", "0"], "argument --window: must be between 1 and 100000, got 0"),
        (["demo", "--rate", "0"], "argument --rate: must be above 0, got 0"),
        (["replay", "S", "--to", "tcp://127.0.0.1:1", "--rate", "-5"], "argument --rate: must be above 0, got -5"),
        (["replay", "S", "--to", "tcp://127.0.0.1:1", "--wait", "nan"], "argument --wait: must be at least 0, got nan"),
        (["listen", "tcp://127.0.0.1:1", "--count", "0"], "argument --count: must be at least 1, got 0"),
        (["eval", "--reference", "R", "--out", "o", "--spacing", "-2"], "argument --spacing: must be above 0, got -2"),
        (["eval", "--reference", "R", "--out", "o", "--tolerances", "1", "-1"],
         "argument --tolerances: must be at least 0, got -1"),
        (["match", "M", "Q", "--out", "o.csv", "--scoring", "best"], "argument --scoring: invalid choice: 'best'"),
        (["map"], "the following arguments are required: VERB (see 'lostx map --help')"),
    ],
)
def test_a_bad_value_is_one_line_naming_it(args, message, tmp_path):
    proc = lostx(*args, cwd=tmp_path)
    assert proc.returncode == 2
    assert_one_line_error(proc, f"lostx: error: {message}")
    assert os.listdir(tmp_path) == []  # nothing written


def test_a_bad_value_in_a_config_file_is_one_line_naming_file_and_key(cli_map, robotcar, tmp_path):
    config = tmp_path / "bad.toml"
    config.write_text("[sequence]\nlength = -3\n")
    proc = lostx("match", cli_map, robotcar / "night", "--out", tmp_path / "m.csv", "--sequence", "--config", config)
    assert_one_line_error(proc, f"lostx: error: {config}: [sequence] length must be between 1 and 100000, got -3")


def test_the_child_processes_run_the_installed_lostx_whatever_the_working_folder(tmp_path):
    """Started from the folder that holds a clone named lostx/, a child must not import that folder."""
    from lostx import __version__
    from lostx.stream.processes import lostx_command

    (tmp_path / "lostx").mkdir()
    (tmp_path / "lostx" / "README.md").write_text("a clone")
    proc = subprocess.run(lostx_command("--version"), capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"lostx {__version__}"


# -- outputs checked before the work ---------------------------------------------------------------


def test_match_out_that_is_a_folder_fails_before_matching(cli_map, robotcar, tmp_path):
    (tmp_path / "out").mkdir()
    proc = lostx("match", cli_map, robotcar / "night", "--out", tmp_path / "out")  # progress bar on
    assert_one_line_error(proc, f"--out {tmp_path / 'out'} is a folder; give the name of a file to write")
    assert "matching" not in proc.stderr  # not a frame was matched
    assert os.listdir(tmp_path / "out") == [] and os.listdir(tmp_path) == ["out"]


@pytest.mark.parametrize("command", ["match", "map build", "eval", "listen"])
def test_an_output_under_a_file_fails_before_the_work(command, cli_map, robotcar, tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("a file, not a folder")
    out = blocker / "sub" / "out"
    args = {
        "match": ["match", cli_map, robotcar / "night", "--out", out],
        "map build": ["map", "build", robotcar / "day", "--out", out],
        "eval": ["eval", "--reference", robotcar / "day", "--query", robotcar / "night", "--out", out],
        "listen": ["listen", "tcp://127.0.0.1:1", "--jsonl", out, "--timeout", "30"],
    }[command]
    option = "--jsonl" if command == "listen" else "--out"
    proc = lostx(*args)
    assert_one_line_error(proc, f"lostx: error: {option} {out}: {blocker} is a file, not a folder")
    assert not any(word in proc.stderr for word in ("matching", "describing", "listening"))
    assert sorted(os.listdir(tmp_path)) == ["file.txt"]


# -- what the commands say -------------------------------------------------------------------------


def render(stream: str) -> list[str]:
    """Lines as a terminal shows them: a carriage return moves back to the start of the line, and what
    follows overwrites what was there (a line not cleared keeps its tail)."""
    shown = []
    for line in stream.split("\n"):
        cells: list[str] = []
        for part in line.split("\r"):
            cells[: len(part)] = list(part)
        shown.append("".join(cells).rstrip())
    return [line for line in shown if line]


def test_an_error_during_matching_starts_a_line_of_its_own(robotcar, cli_map, tmp_path):
    images = tmp_path / "night"
    images.mkdir()
    for name in sorted(os.listdir(robotcar / "night"))[:4]:
        shutil.copy(robotcar / "night" / name, images / name)
    (images / "0000064.png").write_bytes(b"not an image")  # second in name order
    proc = lostx("match", cli_map, images, "--out", tmp_path / "m.csv")  # progress bar on
    assert proc.returncode == 2 and "matching" in proc.stderr  # it failed during the work
    assert render(proc.stderr)[-1].startswith("lostx: error: ")
    assert "0000064.png" in render(proc.stderr)[-1]
    # The answers before it are kept, and the message says where.
    assert "1 of 5 frames answered before it stopped" in render(proc.stderr)[-1]
    assert len((tmp_path / "m.csv").read_text().splitlines()) == 1 + 1


def test_match_says_why_the_sequence_answers_are_not_localized(cli_map, robotcar, tmp_path):
    proc = lostx("match", cli_map, robotcar / "night", "--out", tmp_path / "s.csv", "--sequence", "--window", "12",
                 "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert (f"note: the sequence window is 12 frames and {robotcar / 'night'} has 10: the window never fills, so "
            f"every answer is not_localized; pass --window 10 or less") in proc.stdout
    assert "0 localized, 10 not_localized while the 12-frame sequence window filled" in proc.stdout
    states = {row["state"] for row in csv.DictReader((tmp_path / "s.csv").open())}
    assert states == {"not_localized"}


def test_demo_says_why_a_window_longer_than_the_night_traverse_never_fills(robotcar, tmp_path):
    from lostx.stream.processes import lostx_command

    demo = subprocess.Popen(lostx_command("demo", "--window", "50", "--workdir", str(tmp_path / "demo"), "--data",
                                          str(robotcar.parent)), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True)
    try:
        first = demo.stdout.readline().rstrip("\n")  # said before the map is built: no need to wait for the rest
    finally:
        demo.terminate()
        demo.wait(60)
    assert first == (f"note: the sequence window is 50 frames and {robotcar / 'night'} has 10: the window never "
                     f"fills, so every answer is not_localized; pass --window 10 or less")


def test_the_summary_lists_only_the_stages_that_ran(robotcar, tmp_path):
    thumbnails = tmp_path / "thumbnails"
    assert lostx("map", "build", robotcar / "day", "--out", thumbnails, "--descriptor", "thumbnail",
                 "--quiet").returncode == 0
    proc = lostx("match", thumbnails, robotcar / "night", "--out", tmp_path / "m.csv", "--quiet")
    assert proc.returncode == 0, proc.stderr
    stages = re.search(r"ms per frame; (.*) ms\)", proc.stdout).group(1)
    # Single frame, the heading's trajectories (which heading's answers keep to them) are the one stage after the search.
    assert [s.split()[0] for s in stages.split(", ")] == ["descriptor", "search", "heading"]


def test_the_summary_says_when_the_map_is_too_short_to_be_sure(robotcar, nordland, tmp_path):
    short = tmp_path / "short"
    assert lostx("map", "build", robotcar / "day", "--out", short, "--descriptor", "thumbnail",
                 "--quiet").returncode == 0
    proc = lostx("match", short, robotcar / "night", "--out", tmp_path / "m.csv", "--sequence", "--window", "3",
                 "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert ("0 localized, 2 not_localized while the 3-frame sequence window filled (the map is too short to be sure: "
            "matched against itself, its 10 frames gave 0 samples of how far wrong answers lead, and a confidence "
            "of 0.999 needs 99)") in proc.stdout
    # 100 frames are enough: some answers are localized, and nothing is said.
    for season in ("summer", "winter"):
        (tmp_path / season).mkdir()
        for path in sorted((nordland / season).iterdir())[993:1093]:
            shutil.copy(path, tmp_path / season / path.name)
    assert lostx("map", "build", tmp_path / "summer", "--out", tmp_path / "map", "--descriptor", "thumbnail",
                 "--quiet").returncode == 0
    proc = lostx("match", tmp_path / "map", tmp_path / "winter", "--out", tmp_path / "m.csv", "--sequence", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "56 localized, 19 not_localized while the 20-frame sequence window filled; wrote" in proc.stdout


def test_frames_unlike_the_maps_get_one_warning_line_each(cli_map, nordland, tmp_path):
    frames = tmp_path / "winter"
    frames.mkdir()
    for path in sorted((nordland / "winter").iterdir())[1000:1006]:
        shutil.copy(path, frames / path.name)
    proc = lostx("match", cli_map, frames, "--out", tmp_path / "m.csv")  # progress bar on
    assert proc.returncode == 0, proc.stderr
    warnings = [line for line in render(proc.stderr) if "warning" in line]
    assert len(warnings) == 2, proc.stderr
    assert warnings[0].startswith("lostx: warning: frame 0 is 64 x 32 pixels (the map's frames: 1024 x 640); "
                                  "greyscale (the map's frames: colour)")
    assert warnings[1].startswith("lostx: warning: in frames 0 to 4 the network finds ")
    assert len(list(csv.DictReader((tmp_path / "m.csv").open()))) == 6  # answered all the same


def test_the_summary_says_why_no_answer_is_localized(thumb_map, nordland, tmp_path):
    """Nordland's winter frames against the summer map one at a time: the map is long enough to be sure, and no
    answer is confident enough. The summary says so, with the highest confidence, as the CSV has it."""
    winter = link_frames(sorted((nordland / "winter").iterdir())[:60], tmp_path / "winter")
    proc = lostx("match", thumb_map.path, winter, "--out", tmp_path / "m.csv", "--quiet")
    assert proc.returncode == 0, proc.stderr
    with open(tmp_path / "m.csv") as handle:
        rows = list(csv.DictReader(handle))
    best = max(rows, key=lambda r: float(r["confidence"]))
    assert float(best["confidence"]) < 0.999
    assert (f"; 0 localized (no answer reached the confidence a localized one needs, 0.999 ([decision] "
            f"min_confidence): the highest was {best['confidence']}, frame {best['query_index']}'s); wrote") \
        in proc.stdout
