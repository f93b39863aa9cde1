"""The streaming system with real processes, real maps and the real Localizer.

Every process a test starts is stopped by the ``procs`` fixture (TERM, then KILL);
every wait has a timeout; endpoints are free TCP ports on loopback or IPC paths
in the test's temporary folder.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import re
import signal
import sys
import subprocess
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq

from lostx.core.config import Config, StreamConfig, load_config
from lostx.core.frame import Frame
from lostx.core.localizer import Localizer
from lostx.replay.folder import folder_traverse
from lostx.replay.pace import Pace, paced
from lostx.stream import messages, wire
from lostx.stream.client import Listener
from lostx.stream.errors import ProtocolError, StreamError
from lostx.stream.journal import Journal
from lostx.stream.producer import FramePublisher
from lostx.stream.messages import ErrorMessage, Limits, Ready, Result
from lostx.stream.replay import replay
from lostx.stream.service import LocalizerService
from lostx.stream.sockets import ClientKeys
from lostx.stream.streams import AnsweredIds, StreamTable, check_time, localizer_factory

from streamtools import (  # noqa: F401  (fixtures)
    Collector, endpoints, free_port, link_frames, lostx_command, nordland_subset, procs, read_jsonl, serving,
    thumb_map, wait_for, winter_runs,
)

WINTER_FRAMES = 3576


def serve(refmap, frames: str, results: str, mode: str, *extra: str) -> list[str]:
    """``lostx serve``; in lossless mode without a journal unless ``extra`` names one."""
    if mode == "lossless" and "--journal" not in extra:
        extra = ("--no-journal", *extra)
    return lostx_command("serve", "--map", str(refmap.path), "--frames", frames, "--results", results,
                         "--mode", mode, "--stats-interval", "0.2", *extra)


def replay_cmd(source: Path, frames: str, *extra: str) -> list[str]:
    return lostx_command("replay", str(source), "--to", frames, "--quiet", "--wait", "60", *extra)


@pytest.fixture(scope="module")
def night_expected(day_map, robotcar, mosaic) -> list[dict]:
    """The Localizer run directly, in this process, over the night frames in order."""
    localizer = Localizer(day_map, backbone=mosaic)
    return [localizer.step(frame).summary() for frame in folder_traverse(robotcar / "night")]


def same_answer(got: dict, expected: dict) -> None:
    for key in ("frame_id", "state", "match_index", "match_name", "single_match_index", "heading", "window"):
        assert got[key] == expected[key], (key, got[key], expected[key])
    assert got["confidence"] == pytest.approx(expected["confidence"], abs=1e-9)
    assert got["score"] == pytest.approx(expected["score"], abs=1e-9)
    assert [(c["index"], c["correspondences"]) for c in got["candidates"]] == \
        [(c["index"], c["correspondences"]) for c in expected["candidates"]]


# -- replay -> serve -> listen ----------------------------------------------------------------


@pytest.mark.parametrize("transport", ["tcp", "ipc"])
def test_streamed_answers_equal_the_localizer_run_directly(transport, day_map, robotcar, night_expected, procs,
                                                           tmp_path):
    frames, results = endpoints(transport, tmp_path)
    client = Collector(results, topics=("result",))  # the Python client API, in this process
    try:
        procs.start("serve", serve(day_map, frames, results, "lossless", "--wait-listeners", "2"))
        jsonl = tmp_path / "listen.jsonl"
        procs.start("listen", lostx_command("listen", results, "--jsonl", str(jsonl), "--count", "10", "--quiet"))
        procs.start("replay", replay_cmd(robotcar / "night", frames, "--as-fast-as-possible"))
        assert procs.processes["replay"].wait(120) == 0
        assert procs.processes["listen"].wait(30) == 0
        wait_for(lambda: len(client.results) == 10, 10, "the Python client's 10 results")
    finally:
        client.stop()
    assert "10 answered" in procs.log("replay")
    from_cli = read_jsonl(jsonl)
    assert [r["frame_id"] for r in from_cli] == list(range(10))
    for got, expected in zip(from_cli, night_expected):
        same_answer(got, expected)
    for got, expected in zip(client.results, night_expected):
        same_answer(got.to_dict(), expected)
    # The streamed matches are the ones the method finds (a sanity check on the data, not the wire).
    assert sum(r["match_index"] == r["frame_id"] for r in from_cli) >= 4


def test_live_mode_answers_the_newest_frame_and_counts_the_dropped(day_map, robotcar, procs, tmp_path):
    frames, results = endpoints("ipc", tmp_path)
    listener = Collector(results)
    try:
        procs.start("serve", serve(day_map, frames, results, "live", "--wait-listeners", "1"))
        with FramePublisher(frames) as publisher:
            sent = replay(folder_traverse(robotcar / "night"), publisher, Pace("unlimited"), progress=False, wait=60)
        assert sent.mode == "live" and sent.frames == 10
        wait_for(lambda: 9 in listener.ids(), 60, "the answer to the last frame")
        assert procs.stop("serve") == 0
        wait_for(lambda: listener.final is not None, 10, "the final stats")
    finally:
        listener.stop()
    ids, final = listener.ids(), listener.final
    assert ids == sorted(set(ids)) and ids[-1] == 9
    # All ten frames leave within a few ms; the localizer takes ~100 ms each: most must be skipped.
    assert len(ids) < 10
    assert final.answered == len(ids)
    assert final.dropped == final.received - final.answered > 0
    # Frames the producer could not even send (its queue full) arrive nowhere: the service sees the gaps.
    assert final.received + final.missing == 10 and final.missing == sent.counts.dropped


def wait_until_still(count, quiet: float, timeout: float, what: str) -> int:
    """Wait until ``count()`` has not changed for ``quiet`` seconds; its value then."""
    deadline = time.monotonic() + timeout
    last, since = count(), time.monotonic()
    while time.monotonic() - since < quiet:
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.05)
        now = count()
        if now != last:
            last, since = now, time.monotonic()
    return last


def test_lossless_nordland_a_slow_and_a_stopped_then_killed_listener_lose_nothing(thumb_map, nordland, procs,
                                                                                  tmp_path):
    """3576 winter frames against the summer map, with a journal. One listener is slow throughout.
    `lostx listen` is stopped (SIGSTOP) after 300 answers, which holds the whole chain, then killed with
    answers buffered for it; `lostx listen --resume` on the same file picks up where it stopped. Both
    listeners get every answer once, in order."""
    frames, results = endpoints("ipc", tmp_path)
    config = tmp_path / "stream.toml"
    config.write_text("[stream]\nresult_hwm = 10\n")
    jsonl = tmp_path / "listen.jsonl"
    listen = lostx_command("listen", results, "--jsonl", str(jsonl), "--resume")
    slow = Collector(results, topics=("result",), delay=lambda n: 0.001, hwm=1, rcvbuf=4096)
    start = time.monotonic()
    try:
        procs.start("serve", serve(thumb_map, frames, results, "lossless", "--journal", str(tmp_path / "journal"),
                                   "--wait-listeners", "2", "--config", str(config)))
        first = procs.start("listen", listen + ["--quiet", "--count", str(WINTER_FRAMES)])
        procs.start("replay", replay_cmd(nordland / "winter", frames, "--as-fast-as-possible"))
        wait_for(lambda: len(read_jsonl(jsonl)) >= 300, 120, "300 answers in the listener's file")
        first.send_signal(signal.SIGSTOP)
        # Its queue fills, and the service waits for it: nobody gets answers any more, the producer waits.
        held_at = wait_until_still(lambda: len(slow.results), 2.0, 60, "the stopped listener to hold the service")
        assert held_at < WINTER_FRAMES - 500, "the stopped listener did not hold the service back"
        first.kill()  # with everything buffered for it
        first.wait(10)
        done = len(read_jsonl(jsonl))
        assert done < held_at
        procs.start("listen-again", listen + ["--count", str(WINTER_FRAMES - done)])
        assert procs.processes["replay"].wait(400) == 0
        assert procs.processes["listen-again"].wait(120) == 0
        wait_for(lambda: len(slow.results) == WINTER_FRAMES, 60, "the slow listener's last result")
        elapsed = time.monotonic() - start
        assert procs.stop("serve") == 0
    finally:
        slow.stop()
    everything = list(range(WINTER_FRAMES))
    rows = read_jsonl(jsonl)
    assert [r["frame_id"] for r in rows] == everything
    assert [r["seq"] for r in rows] == [n + 1 for n in everything]
    assert slow.ids() == everything and [r.tag.seq for r in slow.results] == [n + 1 for n in everything]
    assert f"{WINTER_FRAMES - done} results; " in procs.log("listen-again")
    assert "recovered from the journal" in procs.log("listen-again")
    assert "MISSED" not in procs.log("listen-again")
    assert f"{WINTER_FRAMES} answered" in procs.log("replay")
    assert "0 dropped, 0 missing, 0 errors" in procs.log("serve")
    print(f"lossless Nordland: {WINTER_FRAMES} frames in {elapsed:.1f} s; held at {held_at}, resumed after {done}")


def test_four_robots_interleaved_on_one_service_get_the_answers_each_gets_alone(thumb_map, winter_runs, procs,
                                                                               tmp_path):
    expected = {}
    for k, folder in enumerate(winter_runs):
        localizer = Localizer(thumb_map)
        expected[f"robot-{k}"] = [localizer.step(frame).summary() for frame in folder_traverse(folder)]
    frames, results = endpoints("ipc", tmp_path)
    listener = Collector(results)
    try:
        for k, folder in enumerate(winter_runs):
            procs.start(f"replay-{k}", lostx_command("replay", str(folder), "--to", frames, "--wait", "60",
                                                     "--as-fast-as-possible", "--stream", f"robot-{k}"))
        # All four wait for the service, so that they start together and their frames interleave.
        wait_for(lambda: all("waiting for the service" in procs.log(f"replay-{k}") for k in range(4)), 60,
                 "the four producers")
        procs.start("serve", serve(thumb_map, frames, results, "lossless", "--journal", str(tmp_path / "journal")))
        for k in range(4):
            assert procs.processes[f"replay-{k}"].wait(300) == 0
        wait_for(lambda: len(listener.results) == 1200, 30, "every result")
        assert procs.stop("serve") == 0
        wait_for(lambda: listener.final is not None, 10, "the final stats")
    finally:
        listener.stop()
    got = listener.results
    assert not listener.errors
    assert [r.tag.seq for r in got] == list(range(1, 1201))
    switches = sum(a.tag.stream != b.tag.stream for a, b in zip(got, got[1:]))
    assert switches > 300, f"the streams hardly interleaved ({switches} switches)"
    for name, answers in expected.items():
        mine = [r for r in got if r.tag.stream == name]
        assert [r.tag.stream_seq for r in mine] == list(range(1, len(answers) + 1))
        assert [r.frame_id for r in mine] == list(range(len(answers)))
        for result, alone in zip(mine, answers):
            same_answer(result.to_dict(), alone)
        # Not warming up for ever, as a service that reset the localizer at every switch of stream was.
        assert sum(not r.warming_up for r in mine) == sum(not a["warming_up"] for a in answers) > 0
        stats = listener.final.streams[name]
        assert (stats.received, stats.answered, stats.errors, stats.missing) == (len(answers), len(answers), 0, 0)


# -- a socket never trusts its peer ------------------------------------------------------------


def _small_frame(frame_id: int, **fields) -> dict:
    image = (np.arange(48 * 64 * 3) % 251).astype(np.uint8).reshape(48, 64, 3)
    message = msgpack.unpackb(wire.encode_frame(Frame(frame_id, image, camera="front")))
    message.update(fields)
    return message


def fuzz_cases(rng: np.random.Generator, max_bytes: int) -> list[tuple[list[bytes], str | None, int | None]]:
    """Bad messages: (parts, expected code or None for "any code", expected frame id)."""
    cases: list[tuple[list[bytes], str | None, int | None]] = []
    base = msgpack.packb(_small_frame(1))
    for cut in rng.integers(0, len(base), 200):
        cases.append(([base[:cut]], "malformed", None))
    for n in rng.integers(1, 20, 50):
        cases.append(([base + rng.bytes(int(n))], "malformed", None))
    for n in rng.integers(1, 200, 150):
        cases.append(([rng.bytes(int(n))], None, None))  # random bytes: any refusal will do
    for value in (None, True, 7, "frame", [1, 2], 2.5):
        cases.append(([msgpack.packb(value)], "not_a_map", None))
    big = max_bytes + 1
    for size in np.linspace(big, 2 * max_bytes - 100, 8).astype(int):
        cases.append(([msgpack.packb({"v": 1, "type": "frame", "id": 9, "image": b"\0" * int(size)})],
                      "too_large", None))
    for header in (b"\xc6\xff\xff\xff\xf0", b"\xdb\xff\xff\xff\xf0", b"\xdd\xff\xff\xff\xf0", b"\xdf\xff\xff\xff\xf0"):
        for _ in range(10):
            cases.append(([b"\x82\xa1v\x01\xa5image" + header + rng.bytes(int(rng.integers(0, 64)))],
                          "malformed", None))
    for depth in (2000, 10_000, 100_000):
        cases.append(([b"\x81\xa8metadata" + b"\x91" * depth + b"\xc0"], "malformed", None))
    cases.append(([msgpack.packb({"v": messages.VERSION, "type": "frame", "id": 5, "x": msgpack.ExtType(1, b"abc")})],
                  "malformed", None))
    cases.append(([base, b"second part"], "multipart", None))
    cases.append(([b"", base], "multipart", None))
    mutations: list[tuple[dict, str]] = [
        ({"v": 0}, "bad_version"), ({"v": 1}, "bad_version"), ({"v": 99}, "bad_version"), ({"v": -1}, "bad_version"),
        ({"v": "2"}, "bad_version"), ({"v": 2.0}, "bad_version"), ({"v": None}, "bad_version"),
        ({"v": [2]}, "bad_version"),
        ({"type": "result"}, "unknown_type"), ({"type": "ack"}, "unknown_type"), ({"type": ""}, "unknown_type"),
        ({"type": 5}, "bad_type"), ({"type": None}, "bad_type"),
        ({"camera": "left"}, "bad_value"), ({"camera": 0}, "bad_type"),
        ({"encoding": "gif"}, "bad_value"), ({"encoding": 1}, "bad_type"),
        ({"image": "pixels"}, "bad_type"), ({"image": None}, "bad_type"), ({"image": [1, 2]}, "bad_type"),
        ({"image": b"\0" * 10}, "bad_image"),
        ({"shape": "48x64"}, "bad_type"), ({"shape": [48]}, "bad_value"), ({"shape": [48, 64, 3, 1]}, "bad_value"),
        ({"shape": [48, 64, 4]}, "bad_value"), ({"shape": [-48, 64, 3]}, "bad_value"),
        ({"shape": [48, 64.0, 3]}, "bad_value"), ({"shape": [100_000, 100_000, 3]}, "image_too_large"),
        ({"dtype": "float32"}, "bad_value"), ({"dtype": 8}, "bad_type"),
        ({"timestamp": "now"}, "bad_type"), ({"timestamp": [1.0]}, "bad_type"), ({"timestamp": True}, "bad_type"),
        ({"timestamp": float("nan")}, "bad_type"), ({"timestamp": float("inf")}, "bad_type"),
        ({"position": [1.0]}, "bad_value"), ({"position": ["a", "b"]}, "bad_value"),
        ({"position": "here"}, "bad_type"), ({"position": {"x": 1}}, "bad_type"),
        ({"name": 5}, "bad_type"), ({"name": b"raw"}, "bad_type"), ({"name": "n" * 1000}, "bad_value"),
        ({"stream": 3}, "bad_type"), ({"metadata": [1]}, "bad_type"), ({"metadata": "x"}, "bad_type"),
        ({"metadata": {"blob": b"x"}}, "bad_type"), ({"metadata": {"a": [[[[[1]]]]]}}, "bad_value"),
        ({"colour": "red"}, "unknown_field"), ({"extra": None}, "unknown_field"),
        ({"encoding": "png", "image": b"\x89PNG\r\n\x1a\n" + b"\0\0\0\rIHDR" + b"\x00\x01\x86\xa0" * 2 + b"\x08\x02\0\0\0"},
         "image_too_large"),
        ({"encoding": "png", "image": b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\0\x40\0\0\0\x30\x08\x02\0\0\0" + b"\0" * 50},
         "bad_image"),  # a plausible header and a corrupt body: refused by the decoder in the worker
        ({"encoding": "jpeg", "image": b"\xff\xd8\xff\xe0\x00\x10JFIF"}, "bad_image"),
        ({"image": b"\0" * 12, "shape": [2, 2, 3]}, "localizer_failed"),  # decodes, but too small to localize
    ]
    frame_id = 1000
    while len(cases) < 1100:
        for change, code in mutations:
            frame_id += 1
            message = _small_frame(frame_id)
            message.update(change)
            cases.append(([msgpack.packb(message)], code, frame_id))
    for field in ("v", "type", "encoding", "image", "shape", "dtype"):
        message = _small_frame(7)
        del message[field]
        cases.append(([msgpack.packb(message)], "missing_field", 7))
    for bad_id in (-1, 2**64 - 1, 1.5, "7", True, None, b"7"):
        cases.append(([msgpack.packb(_small_frame(0, id=bad_id))], "bad_type", None))
    return cases


def test_fuzz_the_service_answers_every_bad_message_and_stays_up(day_map, robotcar, night_expected, procs,
                                                                 tmp_path):
    max_bytes = 3 * 1024 * 1024  # a raw 1024x640 frame (1.97 MB) fits
    frames, results = endpoints("ipc", tmp_path)
    cases = fuzz_cases(np.random.default_rng(20240611), max_bytes)
    assert len(cases) >= 1000
    listener = Collector(results)
    context = zmq.Context()
    dealer = context.socket(zmq.DEALER)
    dealer.setsockopt(zmq.LINGER, 0)
    try:
        procs.start("serve", serve(day_map, frames, results, "lossless", "--max-message-bytes", str(max_bytes)))
        dealer.connect(frames)
        dealer.send(wire.encode_hello())  # a lossless service is ready once a listener has subscribed
        assert dealer.poll(60_000) and isinstance(wire.decode_reply(dealer.recv(), Limits()), Ready)
        replies = []
        for parts, code, frame_id in cases:
            dealer.send_multipart(parts)
            assert dealer.poll(10_000), f"no answer to a bad message (expected {code})"
            reply = wire.decode_reply(dealer.recv(), Limits())
            assert isinstance(reply, ErrorMessage), reply
            assert code is None or reply.code == code, (code, reply)
            assert reply.frame_id == frame_id, (code, frame_id, reply)
            replies.append(reply)
        assert procs.processes["serve"].poll() is None, "the service died"
        # Now one good frame: answered, and exactly as the Localizer answers it in this process.
        night0 = folder_traverse(robotcar / "night").frame(0)
        dealer.send(wire.encode_frame(night0, "raw"))
        assert dealer.poll(60_000)
        ack = wire.decode_reply(dealer.recv(), Limits())
        assert isinstance(ack, messages.Ack) and ack.frame_id == 0
        wait_for(lambda: listener.results, 10, "the good frame's result")
        same_answer(listener.results[0].to_dict(), night_expected[0])
        assert procs.stop("serve") == 0
        wait_for(lambda: listener.final is not None, 10, "the final stats")
    finally:
        dealer.close()
        context.term()
        listener.stop()
    final = listener.final
    assert final.errors == len(cases) and final.answered == 1
    by_code: dict[str, int] = {}
    for reply in replies:
        by_code[reply.code] = by_code.get(reply.code, 0) + 1
    assert final.errors_by_code == by_code
    # Listeners heard of every refusal too (frame ids included), in the order they happened.
    assert [(e.code, e.frame_id) for e in listener.errors] == [(r.code, r.frame_id) for r in replies]
    # The text does not repeat the frame id its own field carries ("frame 7: frame 7: ...").
    assert any(r.code == "localizer_failed" for r in replies)
    assert not [r.text for r in replies if r.text.startswith(f"frame {r.frame_id}:")]
    # Hundreds of broken images, and not a line about them in the service's log.
    log = procs.log("serve")
    assert "libpng" not in log and "JPEG" not in log and len(log.splitlines()) <= 4, log[-2000:]


def test_a_message_over_twice_the_limit_is_cut_off_by_the_transport(thumb_map, procs, tmp_path):
    frames, results = endpoints("tcp", tmp_path)
    procs.start("serve", serve(thumb_map, frames, results, "live", "--max-message-bytes", "65536"))
    context = zmq.Context()
    dealer = context.socket(zmq.DEALER)
    dealer.setsockopt(zmq.LINGER, 0)
    try:
        dealer.connect(frames)
        dealer.send(wire.encode_hello())
        assert dealer.poll(30_000), "the service did not start"
        assert isinstance(wire.decode_reply(dealer.recv(), Limits()), Ready)
        dealer.send(b"\x85" + b"\0" * (3 * 65536))  # announces 192 KiB: libzmq drops the connection
        assert not dealer.poll(1500), "a message over the transport limit was answered"
        dealer.send(wire.encode_hello())  # the DEALER has reconnected by itself
        assert dealer.poll(10_000)
        assert isinstance(wire.decode_reply(dealer.recv(), Limits()), Ready)
        assert procs.processes["serve"].poll() is None
    finally:
        dealer.close()
        context.term()


# -- security ----------------------------------------------------------------------------------


def test_curve_only_clients_with_known_keys_get_anything(thumb_map, nordland, procs, tmp_path):
    for folder, name in (("server", "server"), ("clients", "alice"), ("others", "mallory")):
        subprocess.run(lostx_command("keys", str(tmp_path / folder), "--name", name), check=True,
                       capture_output=True, timeout=60)
    assert oct((tmp_path / "clients" / "alice.key_secret").stat().st_mode & 0o777) == "0o600"
    server_key = tmp_path / "server" / "server.key"
    alice = ClientKeys(server_key, tmp_path / "clients" / "alice.key_secret")
    mallory = ClientKeys(server_key, tmp_path / "others" / "mallory.key_secret")
    frames, results = endpoints("tcp", tmp_path)
    listeners = {"alice": Collector(results, keys=alice), "plain": Collector(results),
                 "mallory": Collector(results, keys=mallory)}
    try:
        procs.start("serve", serve(thumb_map, frames, results, "lossless",
                                   "--curve-secret", str(tmp_path / "server" / "server.key_secret"),
                                   "--curve-clients", str(tmp_path / "clients")))
        for keys in (None, mallory):
            with FramePublisher(frames, keys=keys) as intruder:
                with pytest.raises(StreamError, match="no service answered"):
                    intruder.wait_ready(1.5)
                intruder.send(folder_traverse(nordland / "winter").frame(0))  # sent into nothing
        with FramePublisher(frames, keys=alice) as publisher:
            publisher.wait_ready(30)
            for frame in list(folder_traverse(nordland / "winter"))[:5]:
                publisher.send(frame, timeout=30)
            assert publisher.flush(30)
        wait_for(lambda: len(listeners["alice"].results) == 5, 10, "alice's results")
        assert procs.stop("serve") == 0
        wait_for(lambda: listeners["alice"].final is not None, 10, "the final stats")
    finally:
        for listener in listeners.values():
            listener.stop()
    assert listeners["alice"].final.received == 5
    for name in ("plain", "mallory"):
        got = listeners[name]
        assert not got.results and not got.errors and not got.stats, f"{name} received something"


def test_the_service_binds_loopback_unless_told_otherwise(thumb_map, procs, tmp_path):
    from lostx.cli import build_parser
    from lostx.options import config_from_args, stream_config_from_args

    args = build_parser().parse_args(["serve", "--map", str(thumb_map.path)])
    stream = stream_config_from_args(args, config_from_args(args)).stream
    assert stream.frames == "tcp://127.0.0.1:5555" and stream.results == "tcp://127.0.0.1:5556"
    port = free_port()
    refused = subprocess.run(serve(thumb_map, f"tcp://0.0.0.0:{port}", f"tcp://127.0.0.1:{free_port()}", "live"),
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2
    assert f"refusing to bind tcp://0.0.0.0:{port} (not loopback) without CurveZMQ keys" in refused.stderr


# -- lifecycle ---------------------------------------------------------------------------------


def test_sigterm_finishes_the_frame_in_hand_flushes_and_exits_0(day_map, robotcar, procs, tmp_path):
    frames, results = endpoints("ipc", tmp_path)
    listener = Collector(results)
    try:
        serve_process = procs.start("serve", serve(day_map, frames, results, "lossless"))
        procs.start("replay", replay_cmd(robotcar / "night", frames, "--as-fast-as-possible"))
        wait_for(lambda: listener.results, 60, "a first result")
        time.sleep(0.04)  # the next frame is in the worker's hands now (a step takes ~100 ms)
        before = len(listener.results)
        serve_process.send_signal(signal.SIGTERM)
        assert serve_process.wait(30) == 0
        wait_for(lambda: listener.final is not None, 10, "the final stats")
    finally:
        listener.stop()
    final, ids = listener.final, listener.ids()
    assert len(ids) > before, "the frame in hand at SIGTERM was not answered"
    assert final.answered == len(ids) < 10 and ids == list(range(len(ids)))
    log = procs.log("serve")
    assert re.search(rf"SIGTERM: last answered frame {ids[-1]}, stopping after {len(ids)} answers; "
                     r"\d+ queued frame\(s\) left unanswered", log), log


def test_producer_and_listener_start_first_and_survive_a_service_restart(thumb_map, nordland_subset, procs,
                                                                         tmp_path):
    frames, results = endpoints("tcp", tmp_path)
    listener = Collector(results, topics=("result",))
    try:
        procs.start("replay", replay_cmd(nordland_subset, frames, "--rate", "150"))
        time.sleep(1.0)  # both wait for a service that is not there yet
        first = procs.start("serve", serve(thumb_map, frames, results, "lossless"))
        wait_for(lambda: len(listener.results) >= 100, 60, "100 results from the first service")
        first.kill()  # a crash: no flushing, no goodbye
        first.wait(10)
        procs.start("serve-again", serve(thumb_map, frames, results, "lossless"))
        assert procs.processes["replay"].wait(120) == 0
    finally:
        listener.stop()
    ids = listener.ids()
    assert set(ids) == set(range(300)), "frames were lost across the restart"
    assert len(ids) - 300 <= StreamConfig().window, "more duplicates than frames in flight"
    sessions = list(dict.fromkeys(r.session for r in listener.results))
    assert len(sessions) == 2
    for session in sessions:
        mine = [r.frame_id for r in listener.results if r.session == session]
        assert mine == sorted(mine)
    assert "300 answered" in procs.log("replay") and "restarted 1 time" in procs.log("replay")


def test_kill_9_of_a_service_with_a_journal_loses_and_duplicates_nothing(thumb_map, nordland_subset, procs,
                                                                        tmp_path):
    frames, results = endpoints("tcp", tmp_path)
    history = f"tcp://127.0.0.1:{free_port()}"
    journal, jsonl = tmp_path / "journal", tmp_path / "listen.jsonl"
    service = serve(thumb_map, frames, results, "lossless", "--journal", str(journal), "--history", history)
    procs.start("listen", lostx_command("listen", results, "--history", history, "--jsonl", str(jsonl),
                                        "--count", "300"))
    procs.start("replay", replay_cmd(nordland_subset, frames, "--rate", "150", "--stream", "train-1"))
    first = procs.start("serve", service)
    wait_for(lambda: len(read_jsonl(jsonl)) >= 100, 60, "100 answers from the first service")
    first.kill()  # a crash: no flushing, no goodbye
    first.wait(10)
    procs.start("serve-again", service)
    assert procs.processes["replay"].wait(120) == 0
    assert procs.processes["listen"].wait(60) == 0
    assert procs.stop("serve-again") == 0
    rows = read_jsonl(jsonl)
    # Every frame answered once, in order, numbered without a gap across the two services.
    assert [r["frame_id"] for r in rows] == list(range(300))
    assert [r["seq"] for r in rows] == list(range(1, 301))
    assert {r["stream"] for r in rows} == {"train-1"} and len({r["session"] for r in rows}) == 2
    assert "300 answered" in procs.log("replay") and "restarted 1 time" in procs.log("replay")
    assert "MISSED" not in procs.log("listen")
    with Journal(journal) as kept:  # both services are gone: the journal holds each answer once
        payloads = kept.read(0, 1000, 1 << 30)
    assert [msgpack.unpackb(p)["frame_id"] for p in payloads] == list(range(300))
    assert "journal holds answers 1-300" in procs.log("serve-again")


def test_a_bad_timestamp_refuses_that_frame_only_and_the_stream_goes_on(thumb_map, nordland, tmp_path):
    source = list(folder_traverse(nordland / "winter"))[:40]
    stamps = [100.0 + 0.1 * i for i in range(40)]
    stamps[20] = 1e18  # absurdly far ahead
    stamps[25] = stamps[24] - 0.05  # a little back in time
    stamps[30:] = [-5000.0 + 0.1 * i for i in range(10)]  # back by more than max_time_jump: a restarted clock
    frames = [dataclasses.replace(frame, timestamp=t) for frame, t in zip(source, stamps)]
    frames_at, results_at = endpoints("ipc", tmp_path)
    config = StreamConfig(frames=frames_at, results=results_at, mode="lossless", journal=tmp_path / "journal",
                          stats_interval=0.1)
    logs: list[str] = []
    service = LocalizerService(localizer_factory(thumb_map, Config()), config, log=logs.append)
    listener = Collector(results_at)
    with serving(service, listener):
        with FramePublisher(frames_at, stream="cam") as publisher:
            publisher.wait_ready(30)
            for frame in frames:
                publisher.send(frame, timeout=30)
            assert publisher.flush(30)
            refused = [(e.frame_id, e.code) for e in publisher.errors]
        wait_for(lambda: len(listener.results) + len(listener.errors) == 40, 10, "40 answers")
        history = _fetch_history(service.history_endpoint)
    assert refused == [(20, "bad_timestamp"), (25, "bad_timestamp")]
    errors = {e.frame_id: e for e in listener.errors}
    assert "timestamp 1e+18 is 1e+18 s after the stream's previous frame" in errors[20].text
    assert "is earlier than the stream's previous frame" in errors[25].text
    assert [r.frame_id for r in listener.results] == [i for i in range(40) if i not in (20, 25)]
    # Answers and errors share one numbering, in the frames' order.
    answers = sorted(listener.results + listener.errors, key=lambda m: m.tag.seq)
    assert [m.frame_id for m in answers] == list(range(40)) and [m.tag.seq for m in answers] == list(range(1, 41))
    # The refused frames never touched the stream's state; the restarted clock began a new traverse.
    alone, again = Localizer(thumb_map), Localizer(thumb_map)
    expected = [alone.step(f).summary() for f in frames[:30] if f.id not in (20, 25)]
    expected += [again.step(f).summary() for f in frames[30:]]
    for result, summary in zip(listener.results, expected):
        same_answer(result.to_dict(), summary)
    assert listener.results[-10].window == 1
    stream = listener.final.streams["cam"]
    assert (stream.received, stream.answered, stream.errors, stream.restarts) == (40, 38, 2, 1)
    assert sum("starting a new traverse" in line for line in logs) == 1
    # The history serves the journal, and refuses what it cannot read.
    reply, refusal = history
    assert [wire.decode_answer(item, Limits()).tag.seq for item in reply.items] == list(range(11, 41))
    assert (reply.first, reply.last) == (1, 40)
    assert isinstance(refusal, ErrorMessage) and refusal.code == "malformed"


def _fetch_history(endpoint: str) -> tuple[messages.History, ErrorMessage]:
    """A fetch after answer 10, and a garbage request, straight on the history socket."""
    context = zmq.Context()
    dealer = context.socket(zmq.DEALER)
    dealer.setsockopt(zmq.LINGER, 0)
    dealer.connect(endpoint)
    try:
        dealer.send(wire.encode_fetch(messages.Fetch(after=10, max=100)))
        assert dealer.poll(10_000)
        reply = wire.decode_history(dealer.recv(), Limits())
        dealer.send(b"\xc1garbage")
        assert dealer.poll(10_000)
        refusal = wire.decode_history(dealer.recv(), Limits())
    finally:
        dealer.close()
        context.term()
    return reply, refusal  # type: ignore[return-value]


def test_a_producer_hears_its_own_version_journal_history_and_the_stream_of_each_ack(thumb_map, nordland,
                                                                                     tmp_path):
    frame = folder_traverse(nordland / "winter").frame(0)
    frames, results = endpoints("ipc", tmp_path)
    config = StreamConfig(frames=frames, results=results, mode="lossless", journal=tmp_path / "journal")
    service = LocalizerService(localizer_factory(thumb_map, Config()), config, log=lambda text: None)

    def as_version(payload: bytes, version: int) -> bytes:
        return msgpack.packb({**msgpack.unpackb(payload), "v": version})

    context = zmq.Context()
    listener, producer = context.socket(zmq.SUB), context.socket(zmq.DEALER)
    listener.setsockopt(zmq.SUBSCRIBE, b"result")
    with service:
        listener.connect(results)
        producer.connect(frames)
        thread = threading.Thread(target=service.run, daemon=True)
        thread.start()
        replies = []
        try:
            wait_for(lambda: service._listeners() == 1, 10, "the listener's subscription")
            # One socket, two streams, the same frame id in each: only the stream tells the acks apart.
            for payload in (as_version(wire.encode_hello("a"), 3), wire.encode_hello("a"),
                            wire.encode_frame(frame, stream="a"), wire.encode_frame(frame, stream="b"),
                            as_version(wire.encode_frame(frame, stream="c"), 3)):
                producer.send(payload)
                assert producer.poll(30_000)
                replies.append(msgpack.unpackb(producer.recv()))
        finally:
            service.stop("test over")
            thread.join(30)
            listener.close(linger=0)
            producer.close(linger=0)
            context.term()
    journal = service.journal.id  # type: ignore[union-attr]
    old_ready = {"type": "ready", "session": service.session, "mode": "lossless", "window": 4,
                 "max_message_bytes": config.max_message_bytes, "max_pixels": config.max_pixels}
    assert replies[0] == {"v": 3, **old_ready}
    assert replies[1] == {"v": 4, **old_ready, "journal": journal, "history": f"{results}-history"}
    assert replies[2:] == [{"v": 4, "type": "ack", "session": service.session, "frame_id": 0, "stream": "a"},
                           {"v": 4, "type": "ack", "session": service.session, "frame_id": 0, "stream": "b"},
                           {"v": 3, "type": "ack", "session": service.session, "frame_id": 0}]


def test_streams_are_bounded_and_idle_ones_expire(thumb_map, nordland, tmp_path):
    winter = list(folder_traverse(nordland / "winter"))[:3]
    frames, results = endpoints("ipc", tmp_path)
    config = StreamConfig(frames=frames, results=results, mode="lossless", max_streams=2, stream_expiry=1.0,
                          stats_interval=0.1)
    made: list[int] = []

    def new_localizer() -> Localizer:
        made.append(1)
        return Localizer(thumb_map)

    service = LocalizerService(new_localizer, config, log=lambda text: None)
    listener = Collector(results)
    answers: dict[str, list] = {}
    with serving(service, listener):
        publishers = {name: FramePublisher(frames, stream=name) for name in "abc"}
        try:
            for publisher in publishers.values():
                publisher.wait_ready(30)

            def send(stream: str, frame: Frame) -> list[ErrorMessage]:
                publisher = publishers[stream]
                before = len(publisher.errors)
                publisher.send(frame, timeout=30)
                assert publisher.flush(30)
                return list(publisher.errors)[before:]

            assert send("a", winter[0]) == [] and send("b", winter[0]) == []
            refused = send("c", winter[0])
            assert [(e.code, e.frame_id) for e in refused] == [("too_many_streams", 0)]
            assert "stream 'c' would be one more than the 2 live streams (max_streams)" in refused[0].text
            time.sleep(1.2)  # a and b expire
            assert send("c", winter[1]) == [] and send("a", winter[2]) == []
            wait_for(lambda: len(listener.results) == 4 and listener.stats and listener.stats[-1].seq == 4, 10,
                     "four results and the stats after them")
            stats = listener.stats[-1]
        finally:
            for publisher in publishers.values():
                publisher.close()
    for result in listener.results:
        answers.setdefault(result.tag.stream, []).append((result.frame_id, result.tag.stream_seq, result.window))
    # a's second frame came after its state expired: a new traverse, numbered from 1 again.
    assert answers == {"a": [(0, 1, 1), (2, 1, 1)], "b": [(0, 1, 1)], "c": [(1, 1, 1)]}
    assert sorted(stats.streams) == ["a", "c"] and len(made) == 4
    assert stats.errors_by_code == {"too_many_streams": 1}


def test_a_flood_of_stream_ids_from_one_producer_leaves_room_for_a_new_robot(thumb_map, nordland, tmp_path):
    winter = list(folder_traverse(nordland / "winter"))[:22]
    frames, results = endpoints("ipc", tmp_path)
    config = StreamConfig(frames=frames, results=results, mode="lossless", max_streams=4, max_streams_per_peer=2,
                          stats_interval=0.1)
    logged: list[str] = []
    service = LocalizerService(localizer_factory(thumb_map, Config()), config, log=logged.append)
    listener = Collector(results)
    with serving(service, listener):
        flood, robot = FramePublisher(frames, stream="flood-0"), FramePublisher(frames, stream="robot")
        try:
            flood.wait_ready(30)
            robot.wait_ready(30)
            # Twenty stream ids from one connection within the expiry: ten one at a time (each answered
            # before the next), then ten at the window's pace.
            for i, frame in enumerate(winter[:20]):
                flood.stream = f"flood-{i}"
                flood.send(frame, timeout=30)
                if i < 10:
                    assert flood.flush(30)
            assert flood.flush(30)
            for frame in winter[20:]:
                robot.send(frame, timeout=30)
            assert robot.flush(30)
            answered = 20 + 2 - len(flood.errors)
            wait_for(lambda: listener.stats and listener.stats[-1].seq == answered, 10, "the answers and the stats")
            stats = listener.stats[-1]
        finally:
            flood.close()
            robot.close()
    assert list(robot.errors) == []
    robot_answers = [(r.frame_id, r.tag.stream_seq) for r in listener.results if r.tag.stream == "robot"]
    assert robot_answers == [(20, 1), (21, 2)]
    # One at a time, each new stream took the place of the producer's oldest: all ten answered. At the
    # window's pace its streams had frames in service when the next came: some were refused, on their own.
    flood_answered = sorted(r.frame_id for r in listener.results if r.tag.stream.startswith("flood"))
    assert flood_answered[:10] == list(range(10))
    assert {e.code for e in flood.errors} <= {"too_many_streams"}
    assert all("max_streams_per_peer" in e.text for e in flood.errors)
    assert len(flood_answered) + len(flood.errors) == 20
    assert len([name for name in stats.streams if name.startswith("flood")]) == 2 and "robot" in stats.streams
    assert sum("max_streams_per_peer" in line for line in logged) == 1


def test_one_peer_holds_at_most_its_share_of_the_stream_slots():
    table = StreamTable(lambda: None, max_streams=4, expiry=300.0, max_per_peer=2)  # type: ignore[arg-type]
    a, b = b"peer-a", b"peer-b"
    for t, name in enumerate(("a0", "a1", "a2")):
        table.get(name, float(t), a)
    assert [s.name for s in table] == ["a1", "a2"] and table.released == 1
    for state in table:
        state.in_service = 1  # frames of both wait for the localizer: neither can be given up
    with pytest.raises(ProtocolError, match="2 streams one producer may hold") as info:
        table.get("a3", 3.0, a)
    assert info.value.code == "too_many_streams"
    for name in ("b0", "b1"):
        table.get(name, 3.0, b)
    assert [s.name for s in table] == ["a1", "a2", "b0", "b1"]
    # A producer that reconnects (a new routing id) takes its stream along.
    table.get("a1", 4.0, b"peer-a-again")
    assert [s.name for s in table.held_by(a)] == ["a2"]


def test_a_live_listener_that_falls_behind_counts_what_it_missed(thumb_map, nordland, tmp_path):
    frames, results = endpoints("ipc", tmp_path)
    # The service waits for the listener, so it hears of every answer from the first; the listener takes 10
    # answers a second, far fewer than the service gives even on a busy machine.
    config = StreamConfig(frames=frames, results=results, result_hwm=2, stats_interval=0.1, wait_listeners=1)
    service = LocalizerService(localizer_factory(thumb_map, Config()), config, log=lambda text: None)
    slow = Collector(results, delay=lambda n: 0.1, hwm=1, rcvbuf=4096)
    with serving(service, slow):
        started = time.monotonic()
        with FramePublisher(frames) as publisher:
            replay(list(folder_traverse(nordland / "winter"))[:800], publisher, Pace("rate", 400.0),
                   progress=False, wait=30)
        # Every frame taken is answered or dropped, and the slow listener has heard the last answer's
        # number: from an answer, or from the stats once its queue drained.
        def caught_up() -> bool:
            stats = slow.stats[-1] if slow.stats else None
            return (stats is not None and stats.received == stats.answered + stats.dropped
                    and slow.listener.last_seq == stats.seq)

        wait_for(caught_up, 60, "the slow listener to hear of the last answer")
        last = slow.stats[-1].seq
        elapsed = time.monotonic() - started
    got = len(slow.results) + len(slow.errors)
    # How many answers the service gives depends on the machine; the listener hears at its own pace (10 a
    # second, plus what the queues held) and counts the rest as missed.
    assert 0 < got <= 10 * elapsed + 20
    assert slow.listener.missed > 0 and slow.listener.missed + got == last
    assert slow.listener.recovered == 0  # no journal: nothing to recover from
    ids = slow.ids()
    assert ids == sorted(ids)


def test_serve_answers_as_match_does_with_the_same_settings(thumb_map, nordland, procs, tmp_path):
    from lostx.cli import main

    queries = link_frames(sorted((nordland / "winter").iterdir())[:40], tmp_path / "queries")
    short = tmp_path / "short.toml"
    short.write_text("[sequence]\nlength = 5\n\n[tracker]\nenabled = false\n")
    variants = {"default": [], "config": ["--config", str(short)], "single": ["--no-sequence"]}
    settings = {"default": Config(), "config": load_config(short),
                "single": dataclasses.replace(Config(), sequence=dataclasses.replace(Config().sequence, enabled=False))}
    got: dict[str, list[Result]] = {}
    for name, extra in variants.items():
        (tmp_path / name).mkdir()
        frames, results = endpoints("ipc", tmp_path / name)
        procs.start(f"serve-{name}", serve(thumb_map, frames, results, "lossless", *extra))
    for name in variants:
        listener = Collector(f"ipc://{tmp_path / name}/results", topics=("result",))
        try:
            with FramePublisher(f"ipc://{tmp_path / name}/frames") as publisher:
                replay(folder_traverse(queries), publisher, Pace("unlimited"), progress=False, wait=60)
            wait_for(lambda: len(listener.results) == 40, 30, f"{name}'s results")
        finally:
            listener.stop()
        got[name] = listener.results
    for option in ("--sequence", None):
        out = tmp_path / f"match{option or ''}.csv"
        assert main(["match", str(thumb_map.path), str(queries), "--quiet", "--out", str(out),
                     *([option] if option else [])]) == 0
    for name, config in settings.items():
        localizer = Localizer(thumb_map, config)
        for result, frame in zip(got[name], folder_traverse(queries)):
            expected = localizer.step(frame).summary()
            same_answer(result.to_dict(), expected)
            assert result.sequence_score == expected["sequence_score"]
    assert max(r.window for r in got["config"]) == 5
    assert all(r.sequence_score is None for r in got["single"])
    # The default answers as `lostx match --sequence`; --no-sequence as `lostx match`.
    for name, csv_file in (("default", "match--sequence.csv"), ("single", "match.csv")):
        with open(tmp_path / csv_file) as handle:
            rows = list(csv.DictReader(handle))
        assert [int(row["match_index"]) for row in rows] == [r.match_index for r in got[name]]
    assert [r.match_index for r in got["default"]] != [r.match_index for r in got["single"]]


def test_bad_stream_settings_are_one_line_errors(thumb_map, tmp_path, capsys):
    from lostx.cli import main

    taken = Journal(tmp_path / "taken")
    (tmp_path / "not-json.jsonl").write_text("hello\n")
    m = str(thumb_map.path)
    cases = [
        (["serve", "--map", m, "--mode", "lossless"], "lossless mode needs a result journal: give --journal DIR"),
        (["serve", "--map", m, "--max-streams", "0"], "[stream] max_streams must be between 1 and 256, got 0"),
        (["serve", "--map", m, "--max-streams", "300"], "[stream] max_streams must be between 1 and 256, got 300"),
        (["serve", "--map", m, "--stream-expiry", "0"], "[stream] stream_expiry must be above 0, got 0.0"),
        (["serve", "--map", m, "--history", "tcp://127.0.0.1:7"], "--history serves the journal: give --journal DIR"),
        (["serve", "--map", m, "--mode", "lossless", "--journal", str(tmp_path / "taken"),
          "--frames", f"ipc://{tmp_path}/f", "--results", f"ipc://{tmp_path}/r"],
         f"journal {tmp_path / 'taken'} is in use by another service (pid {os.getpid()})"),
        (["listen", "tcp://127.0.0.1:1", "--resume"], "--resume continues a --jsonl FILE: give the file"),
        (["listen", "tcp://127.0.0.1:1", "--resume", "--jsonl", str(tmp_path / "not-json.jsonl")],
         "is not a lostx listen JSON-lines file"),
        (["replay", str(tmp_path), "--to", "tcp://127.0.0.1:1", "--stream", ""], "--stream must be 1 to 240 characters"),
    ]
    try:
        for argv, message in cases:
            assert main(argv) == 2, argv
            err = capsys.readouterr().err
            assert err.startswith("lostx: error: ") and message in err and err.count("\n") == 1, (argv, err)
    finally:
        taken.close()


def test_listen_timeout_counts_answers_not_the_stats_heartbeats(thumb_map, procs, tmp_path):
    frames, results = endpoints("ipc", tmp_path)
    config = StreamConfig(frames=frames, results=results, stats_interval=0.1)
    service = LocalizerService(localizer_factory(thumb_map, Config()), config, log=lambda text: None)
    with serving(service):
        # Stats arrive ten times a second and no frame comes: the listener ends after 2 s without an answer.
        listen = procs.start("listen", lostx_command("listen", results, "--timeout", "2"))
        code = listen.wait(60)
    log = procs.log("listen")
    assert code == 0, log
    assert "0 results; service: received 0, answered 0" in log and "lostx: error" not in log


def test_listen_timeout_with_nothing_behind_the_port_says_no_service_answered(tmp_path, capsys):
    from lostx.cli import main

    endpoint = f"tcp://127.0.0.1:{free_port()}"
    out = tmp_path / "answers.jsonl"
    assert main(["listen", endpoint, "--timeout", "0.5", "--jsonl", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == f"listening to {endpoint}\nlostx: error: no service answered at {endpoint} within 0.5 s\n"
    assert out.read_text() == ""


def test_resuming_reads_the_last_answer_of_the_file_and_drops_a_line_cut_short(tmp_path):
    from lostx.commands.listen import resume_point

    path = tmp_path / "answers.jsonl"
    assert resume_point(path) == (0, None)
    lines = [{"type": "result", "seq": 7, "journal": "j1"}, {"type": "error", "seq": 8, "journal": "j1"},
             {"type": "stats", "seq": 9}]
    whole = "".join(json.dumps(line) + "\n" for line in lines)
    path.write_text(whole + '{"type": "result", "seq": 9, "jour')  # killed in the middle of a line
    assert resume_point(path) == (8, "j1")
    assert path.read_text() == whole  # the next run appends after the last whole line


def test_time_checks_refuse_one_frame_or_start_a_new_traverse():
    assert check_time(None, 5.0, 10.0) == "ok" and check_time(5.0, None, 10.0) == "ok"
    assert check_time(5.0, 5.0, 10.0) == "ok" and check_time(5.0, 15.0, 10.0) == "ok"
    assert check_time(5.0, -5.5, 10.0) == "restart"
    for timestamp, words in ((15.5, "after the stream's previous frame"), (4.0, "earlier than")):
        with pytest.raises(ProtocolError, match=words) as info:
            check_time(5.0, timestamp, 10.0)
        assert info.value.code == "bad_timestamp"


def test_answered_ids_are_bounded_per_stream_and_in_streams():
    ids = AnsweredIds(per_stream=3, streams=2)
    for i in range(5):
        ids.add(("a", i))
    assert [("a", i) in ids for i in range(5)] == [False, False, True, True, True]
    ids.add(("b", 0))
    ids.add(("a", 5))  # a is the most recent now
    ids.add(("c", 0))  # b goes
    assert ("a", 5) in ids and ("c", 0) in ids and ("b", 0) not in ids


def test_sinks_get_every_frame_and_estimate_and_a_failing_sink_is_not_fatal(thumb_map, nordland, tmp_path):
    seen: list[tuple[int, tuple, int, bool]] = []

    class Keep:
        closed = False

        def __call__(self, frame, estimate):
            seen.append((frame.id, frame.image.shape, estimate.match_index, estimate.evidence is not None))

        def close(self):
            Keep.closed = True

    def broken(frame, estimate):
        raise RuntimeError("this sink always fails")

    frames, results = endpoints("ipc", tmp_path)
    config = dataclasses.replace(StreamConfig(), frames=frames, results=results, mode="lossless")
    logs: list[str] = []
    service = LocalizerService(lambda: Localizer(thumb_map), config, sinks=[broken, Keep()], log=logs.append)
    listener = Collector(results)
    with serving(service, listener) as thread:
        with FramePublisher(frames) as publisher:
            publisher.wait_ready(30)
            for frame in list(folder_traverse(nordland / "winter"))[:20]:
                publisher.send(frame, timeout=30)
            assert publisher.flush(30)
        wait_for(lambda: len(listener.results) == 20, 10, "20 results")
    assert not thread.is_alive()
    assert [s[0] for s in seen] == list(range(20))
    assert all(shape == (32, 64, 3) and has_evidence for _, shape, _, has_evidence in seen)
    assert [s[2] for s in seen] == [r.match_index for r in listener.results]
    assert Keep.closed
    assert listener.final.errors_by_code == {"sink_failed": 20} and listener.final.errors == 0
    assert sum("this sink always fails" in line for line in logs) == 1  # in full once, then counted


# -- the producer side -------------------------------------------------------------------------


class FakeService(threading.Thread):
    """A ROUTER that says it is a lossless service, keeps every frame message it gets and acks it."""

    def __init__(self, endpoint: str) -> None:
        super().__init__(daemon=True)
        self.context = zmq.Context()
        self.socket = self.context.socket(zmq.ROUTER)
        self.socket.bind(endpoint)
        self.frames: list[messages.FrameMessage] = []
        self.done = threading.Event()
        self.start()

    def run(self) -> None:
        ready = wire.encode_ready(Ready("fake", "lossless", 8, 16 << 20, 1 << 24))
        while not self.done.is_set():
            if not self.socket.poll(50):
                continue
            identity, data = self.socket.recv_multipart()
            message = wire.decode_request(data, Limits())
            if isinstance(message, messages.Hello):
                self.socket.send_multipart([identity, ready])
            else:
                self.frames.append(message)
                self.socket.send_multipart([identity, wire.encode_ack(messages.Ack("fake", message.id))])
        self.socket.close(linger=0)
        self.context.term()


def test_a_producer_told_its_version_is_too_new_says_so_at_once(tmp_path):
    """A service older than version 4 refuses a version-4 hello as it refuses any version it does not speak."""
    context = zmq.Context()
    old = context.socket(zmq.ROUTER)
    old.bind(f"ipc://{tmp_path}/old")
    refusal = wire.encode_error(ErrorMessage("bad_version", "schema version 4 is not supported (this peer speaks "
                                                            "2 and 3)", None, "old"))

    def answer() -> None:
        if old.poll(10_000):
            identity, _ = old.recv_multipart()
            old.send_multipart([identity, refusal])

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        with FramePublisher(f"ipc://{tmp_path}/old") as publisher:
            with pytest.raises(StreamError, match=r"is older than this producer: it refused protocol version 4 "
                                                  r"\(schema version 4 is not supported .*\); upgrade the service"):
                publisher.wait_ready(30)
    finally:
        thread.join(15)
        old.close(linger=0)
        context.term()


def _replay_into_fake(source, tmp_path: Path, name: str, **kwargs) -> list[messages.FrameMessage]:
    fake = FakeService(f"ipc://{tmp_path}/{name}")
    try:
        with FramePublisher(f"ipc://{tmp_path}/{name}", encoding="png") as publisher:
            replay(source, publisher, Pace("unlimited"), progress=False, wait=10, **kwargs)
    finally:
        fake.done.set()
        fake.join(5)
    return fake.frames


def test_replay_is_deterministic_and_loops_with_fresh_ids_and_streams(nordland_subset, tmp_path):
    source = folder_traverse(nordland_subset).subset(range(20))
    runs = [_replay_into_fake(source, tmp_path, f"run{i}") for i in range(2)]
    for frames in runs:
        assert [m.id for m in frames] == list(range(20))
        assert len({m.stream for m in frames}) == 1
    first, second = runs
    assert [(m.id, m.name, m.camera, m.image) for m in first] == [(m.id, m.name, m.camera, m.image) for m in second]
    assert np.array_equal(first[7].to_frame().image, source.frame(7).image)
    sent: list[int] = []
    looped = _replay_into_fake(source, tmp_path, "loop", loop=True, should_stop=lambda: len(sent) >= 45 or
                               sent.append(0) is not None)
    assert [m.id for m in looped] == list(range(45))
    assert [m.metadata["lap"] for m in looped] == [0] * 20 + [1] * 20 + [2] * 5
    assert [m.metadata["index"] for m in looped] == list(range(20)) * 2 + list(range(5))
    assert len({m.stream for m in looped}) == 3  # each lap starts the service's localizer afresh


def test_pacing_keeps_the_schedule_without_bursting():
    clock = [0.0]
    sleeps: list[float] = []

    def sleep(seconds: float) -> None:
        sleeps.append(round(seconds, 6))
        clock[0] += seconds

    frames = [Frame(i, np.zeros((16, 16, 3), np.uint8), timestamp=100.0 + [0, 0.5, 0.6, 1.6][i]) for i in range(4)]

    class Source(list):
        pass

    source = Source(frames)
    assert [p.frame.id for p in paced(source, Pace("rate", 4.0), clock=lambda: clock[0], sleep=sleep)] == [0, 1, 2, 3]
    assert sleeps == [0.25, 0.25, 0.25]
    sleeps.clear()
    list(paced(source, Pace("realtime"), clock=lambda: clock[0], sleep=sleep))
    assert sleeps == [0.5, 0.1, 1.0]
    sleeps.clear()
    late = []
    for item in paced(source, Pace("rate", 10.0), clock=lambda: clock[0], sleep=sleep):
        late.append(item.frame.id)
        if item.frame.id == 0:
            clock[0] += 5.0  # held back 5 s by a lossless service
    assert sleeps == [0.1, 0.1]  # frame 1 goes at once, then the rate holds: no burst to catch up
    assert list(paced(source, Pace("unlimited"), clock=lambda: clock[0], sleep=sleep)) and sleeps == [0.1, 0.1]


def test_a_listener_skips_what_it_cannot_read(tmp_path):
    context = zmq.Context()
    publisher = context.socket(zmq.XPUB)
    publisher.bind(f"ipc://{tmp_path}/results")
    try:
        with Listener(f"ipc://{tmp_path}/results") as listener:
            assert publisher.poll(5000) and publisher.recv()[0] == 1  # a subscription
            summary = {"frame_id": 4, "timestamp": None, "state": "localized", "match_index": 3, "match_name": "a",
                       "position": None, "confidence": 0.5, "score": 0.1, "single_match_index": 3, "candidates": [],
                       "sequence_score": None, "speed": None, "window": 0, "warming_up": False, "margin": None, "heading": "same",
                       "heading_confidence": 1.0, "latency_ms": {}}
            time.sleep(0.2)
            publisher.send_multipart([b"result", b"\xc1garbage"])
            publisher.send_multipart([b"result", msgpack.packb({"v": messages.VERSION, "type": "result", **summary,
                                                                "match_index": "three"})])
            publisher.send_multipart([b"result", b"x", b"three parts"])
            publisher.send_multipart([b"result", wire.encode_result(summary, "s", messages.Tag("", 1, 1))])
            got = listener.receive(5)
            assert isinstance(got, Result) and got.frame_id == 4 and got.match_index == 3
            assert listener.bad_messages == 3
    finally:
        publisher.close(linger=0)
        context.term()


# -- the demo ----------------------------------------------------------------------------------


def _children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.fixture(scope="module")
def demo_workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("demo")


def test_demo_runs_the_whole_loop(demo_workdir, robotcar, tmp_path):
    # Run from a folder holding a clone named lostx/, as the README's layout has it: the demo and its
    # children must import the installed package, not that folder.
    (tmp_path / "lostx").mkdir()
    (tmp_path / "lostx" / "README.md").write_text("a clone")
    done = subprocess.run(lostx_command("demo", "--workdir", str(demo_workdir), "--data", str(robotcar.parent),
                                        "--rate", "3"), capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if line.strip().endswith(("exact", "+-1", "wrong"))]
    answered = re.search(r"night -> day \(answered (\d+) of 10", done.stdout)
    sequence = re.search(r"sequence filter: +(\d+)/(\d+) exact, (\d+)/(\d+) within one frame; (\d+) localized",
                         done.stdout)
    single = re.search(r"single frame: +(\d+)/(\d+) exact, (\d+)/(\d+) within one frame", done.stdout)
    assert answered and sequence and single, done.stdout
    # Lossless: every frame is answered, however loaded the machine.
    assert int(answered.group(1)) == int(sequence.group(2)) == int(single.group(2)) == len(rows) == 10
    assert sum("warming up" in row for row in rows) == 2  # the 3-frame window fills on the third frame
    assert int(sequence.group(3)) == len(rows)  # every answer within one frame of the truth (measured)
    assert int(sequence.group(5)) == 0  # and none localized: ten frames are too few to be sure, as it says
    assert ("(the map is too short to be sure: matched against itself, its 10 frames gave 0 samples of how far "
            "wrong answers lead, and a confidence of 0.999 needs 99)") in done.stdout
    assert "the authors' LoST-X on the same frames (single frame): 6/10 exact, 8/10 within one frame" in done.stdout


def test_demo_stops_every_process_it_started_on_ctrl_c(demo_workdir, robotcar):
    demo = subprocess.Popen(lostx_command("demo", "--workdir", str(demo_workdir), "--data", str(robotcar.parent),
                                          "--rate", "1"), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        children: list[int] = []
        for line in demo.stdout:
            if "query" in line:  # the service and the replay are running now
                children = _children(demo.pid)
                break
        assert len(children) == 2, children
        demo.send_signal(signal.SIGINT)
        assert demo.wait(30) == 130
        wait_for(lambda: not any(_alive(pid) for pid in children), 10, "the demo's children to exit")
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()


def test_children_stop_when_their_parent_is_killed(tmp_path):
    """A parent that dies without cleaning up (SIGKILL, a crash) still leaves no service behind."""
    script = (
        "import os, sys, time\n"
        "from lostx.stream.processes import ProcessGroup, lostx_command\n"
        f"child = ProcessGroup().start('listen', lostx_command('listen', 'ipc://{tmp_path}/results', '--quiet'))\n"
        "print(child.pid, flush=True)\n"
        "time.sleep(float(sys.argv[1]))\n"
        "os._exit(0)  # no cleanup at all\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script, "6"], stdout=subprocess.PIPE, text=True)
    child = int(parent.stdout.readline())
    assert parent.wait(60) == 0
    try:
        wait_for(lambda: not _alive(child), 10, "the orphaned child to stop")
    finally:
        if _alive(child):
            os.kill(child, signal.SIGKILL)
