"""Every setting's memory is known before any work: what does not fit is refused at once, in one line naming it;
what fits runs; and a signal ends the start-up within a second."""

from __future__ import annotations

import dataclasses
import re
import resource
import signal
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import pytest

from lostx.core.budget import (FILTERS, REFERENCE_STATISTICS, check_memory, format_bytes, needed_bytes, state_bytes,
                               stream_bytes)
from lostx.core.config import BackboneConfig, Config, SequenceConfig
from lostx.core.errors import InputError
from lostx.core.localizer import Localizer
from lostx.replay.folder import folder_traverse
from lostx.stream.states import pack

from streamtools import link_frames, thumb_map  # noqa: F401  (fixture)

ADDRESS_SPACE = 6 << 30
"""The commands below run with at most this much address space (``ulimit -v``): what they may take is the same on
any machine with that much free, and a command that ignored its memory could not take the machine's."""


def lostx(*args: object, timeout: float = 120) -> tuple[subprocess.CompletedProcess, float]:
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))

    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "lostx.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, preexec_fn=limit)
    return proc, time.monotonic() - start


def window(length: int) -> Config:
    return Config(sequence=SequenceConfig(length=length))


def test_the_memory_model_bounds_what_a_stream_takes_and_saves(thumb_map, nordland):
    """Over Nordland's 3,576-frame thumbnail map and 60 winter frames (the window full, the track acquired): the
    peak of the localizer's allocations and its packed state stay within the model, and not far under it."""
    frames = list(folder_traverse(nordland / "winter"))[:60]
    localizer = Localizer(thumb_map)
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        for frame in frames:
            localizer.step(frame)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    state = len(pack(localizer.state()))
    config = Config()
    assert stream_bytes(config, thumb_map.n_frames) / 3 < peak <= stream_bytes(config, thumb_map.n_frames)
    assert state_bytes(config, thumb_map.n_frames) / 8 < state <= state_bytes(config, thumb_map.n_frames)


def test_what_does_not_fit_is_refused_naming_the_setting_its_memory_and_the_largest_that_fits():
    budget = 2_000_000_000
    with pytest.raises(InputError) as refused:
        check_memory(window(100_000), 3576, budget=budget)
    largest = int(re.search(r"the largest window that fits is (\d+) frames$", str(refused.value)).group(1))
    assert str(refused.value).startswith(f"[sequence] length (--window) 100000 would need "
                                         f"{format_bytes(needed_bytes(window(100_000), 3576))} (at most, 1 stream "
                                         f"over a map of 3576 frames), more than the 2 GB of memory available")
    assert needed_bytes(window(largest), 3576) <= budget < needed_bytes(window(largest + 1), 3576)
    check_memory(window(largest), 3576, budget=budget)  # and that one passes
    # Many streams: the window alone cannot make room for 256 of them; fewer streams can.
    with pytest.raises(InputError, match=r"^\[stream\] max_streams 256 would need .* at most (\d+) streams fit$") as many:
        check_memory(Config(), 3576, streams=256, budget=200_000_000)
    most = int(re.search(r"at most (\d+) streams", str(many.value)).group(1))
    assert needed_bytes(Config(), 3576, most) <= 200_000_000 < needed_bytes(Config(), 3576, most + 1)
    threads = Config(sequence=SequenceConfig(length=1), backbone=BackboneConfig(threads=256))
    with pytest.raises(InputError, match=r"^\[backbone\] threads \(--threads\) 256 would need 2.15 GB .* at most "
                                         r"\d+ fit$"):
        check_memory(threads, 3576, budget=1_000_000_000)
    with pytest.raises(InputError, match=r"^the map of 400000 frames would need .*: the largest map that fits these "
                                         r"settings has \d+ frames$"):
        check_memory(dataclasses.replace(threads, backbone=BackboneConfig(threads=1)), 400_000, budget=50_000_000)


@pytest.mark.parametrize("command", [
    ["match", "{map}", "{frames}", "--out", "{out}", "--sequence", "--window", "100000"],
    ["match", "{map}", "{frames}", "--out", "{out}", "--window", "100000"],  # the calibration runs the filter too
    ["serve", "--map", "{map}", "--mode", "lossless", "--no-journal", "--window", "100000", "--frames",
     "tcp://127.0.0.1:0", "--results", "tcp://127.0.0.1:0"],
])
def test_the_largest_window_allowed_is_refused_at_once_with_its_memory(command, thumb_map, nordland, tmp_path):
    frames = link_frames(sorted((nordland / "winter").iterdir())[:30], tmp_path / "winter")
    args = [a.format(map=thumb_map.path, frames=frames, out=tmp_path / "m.csv") for a in command]
    try:
        proc, seconds = lostx(*args, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("still starting after 60 s")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    streams = "64 streams" if command[0] == "serve" else "1 stream"
    assert re.fullmatch(rf"lostx: error: \[sequence\] length \(--window\) 100000 would need [\d.]+ [PT]B \(at most, "
                        rf"{streams} over a map of 3576 frames\), more than the [\d.]+ [kMG]B of memory available: the "
                        rf"largest window that fits is \d+ frames", lines[0]), lines[0]
    assert seconds < 30


def test_every_thread_count_allowed_runs(day_map, robotcar, tmp_path):
    proc, _ = lostx("match", day_map.path, robotcar / "night", "--out", tmp_path / "m.csv", "--sequence", "--window",
                    "3", "--threads", "256", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("matched 10 queries")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_while_the_service_starts_ends_it_within_a_second(signum, thumb_map, tmp_path):
    """A window whose calibration takes minutes to measure on this map (and fits): the signal comes while it is
    being measured, and the service is gone within a second, saying so."""
    proc = subprocess.Popen([sys.executable, "-m", "lostx.cli", "serve", "--map", str(thumb_map.path), "--window",
                             "97", "--max-streams", "1", "--frames", "tcp://127.0.0.1:0", "--results",
                             "tcp://127.0.0.1:0"],
                            stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(6.0)
        assert proc.poll() is None  # still starting
        sent = time.monotonic()
        proc.send_signal(signum)
        proc.wait(10)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = proc.stderr.read()
    assert proc.returncode == 130 and took < 1.0, (took, stderr)
    assert f"lostx: interrupted: {signal.Signals(signum).name} while starting; nothing was served" in stderr


def test_map_info_sizes_a_map_up_to_a_city(thumb_map, capsys):  # noqa: F811 (fixture)
    """``lostx map info`` says what a million frames like the map's would take: on disk at the map's own bytes per
    frame, and a stream's working memory and saved state as the budget counts them (costs looked up at that size: the
    filters hold a bounded number of trajectories, only each map frame's running cost statistics grow with the map,
    and no state is saved)."""
    from lostx.cli import main
    from lostx.commands.map import SCALE_FRAMES

    assert main(["map", "info", str(thumb_map.path)]) == 0
    (line,) = [line for line in capsys.readouterr().out.splitlines() if line.startswith("scale")]
    per_frame = thumb_map.nbytes / thumb_map.n_frames
    working = stream_bytes(Config(), SCALE_FRAMES)
    assert f"{SCALE_FRAMES:,} such frames: {format_bytes(per_frame * SCALE_FRAMES)} on disk" in line
    assert f"working memory {format_bytes(working)}" in line and "no saved state" in line
    assert state_bytes(Config(), SCALE_FRAMES) == 0
    assert stream_bytes(Config(), 2 * SCALE_FRAMES) - working == FILTERS * REFERENCE_STATISTICS * SCALE_FRAMES
