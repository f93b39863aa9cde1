"""A service that is killed and started again carries on, and one whose journal cannot be written stays up.

Real Nordland frames over the thumbnail map of the summer traverse, with the
sequence filter on: a stream's answers depend on the frames before it, so an
answer after a restart equals the uninterrupted one only if the whole state
came back.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq

from lostx.core.budget import format_bytes, state_bytes
from lostx.core.config import Config, StreamConfig
from lostx.core.errors import InputError
from lostx.core.localizer import Localizer
from lostx.core.outputs import check_output_folder
from lostx.replay.folder import folder_traverse
from lostx.stream import journal as journal_module
from lostx.stream import messages, states as states_module, wire
from lostx.stream.journal import Journal
from lostx.stream.messages import Limits
from lostx.stream.producer import FramePublisher
from lostx.stream.service import LocalizerService
from lostx.stream.states import SavedState, StateFileError, StateStore, journal_space, pack, unpack
from lostx.stream.streams import localizer_factory

from streamtools import (  # noqa: F401  (fixtures)
    Collector, endpoints, free_port, link_frames, lostx_command, procs, read_jsonl, serving, thumb_map, wait_for,
)

FRAMES = 100


@pytest.fixture(scope="module")
def winter100(tmp_path_factory, nordland) -> Path:
    return link_frames(sorted((nordland / "winter").iterdir())[:FRAMES], tmp_path_factory.mktemp("winter100"))


@pytest.fixture(scope="module")
def uninterrupted(thumb_map, winter100) -> list[dict]:
    """What ``lostx match --sequence`` answers: one localizer over the frames in order, in this process."""
    localizer = Localizer(thumb_map)
    return [localizer.step(frame).summary() for frame in folder_traverse(winter100)]


def same(got: dict, expected: dict) -> bool:
    keys = ("frame_id", "state", "match_index", "single_match_index", "heading", "window", "warming_up")
    return all(got[k] == expected[k] for k in keys) and all(
        got[k] == pytest.approx(expected[k], abs=1e-9) for k in ("confidence", "score", "speed"))


# -- the localizer's state ------------------------------------------------------------------------


def test_a_restored_localizer_answers_as_the_one_that_went_on(thumb_map, winter100, uninterrupted):
    frames = list(folder_traverse(winter100))
    before = Localizer(thumb_map)
    for frame in frames[:37]:  # the tracker is following by now, the window full
        before.step(frame)
    assert before.tracker.tracking and before.sequence.full
    packed = pack(before.state())
    after = Localizer(thumb_map)
    after.restore(unpack(packed))
    answers = [after.step(frame).summary() for frame in frames[37:]]
    assert all(same(a, e) for a, e in zip(answers, uninterrupted[37:]))
    fresh = Localizer(thumb_map)  # what the service did before: the stream started afresh
    differ = sum(not same(fresh.step(frame).summary(), e) for frame, e in zip(frames[37:], uninterrupted[37:]))
    assert differ >= 20  # at least the new window's warm-up


def test_a_state_over_another_map_is_refused(thumb_map, winter100):
    localizer = Localizer(thumb_map)
    localizer.step(next(iter(folder_traverse(winter100))))
    state = unpack(pack(localizer.state()))
    state["map_frames"] = 10
    with pytest.raises(Exception, match="a saved state over a map of 10 frames, this map has 3576"):
        Localizer(thumb_map).restore(state)


def test_states_pack_arrays_exactly_and_nothing_executable():
    state = {"a": np.arange(12, dtype=np.float32).reshape(3, 4), "b": [np.int64(7), None, 0.5],
             "c": np.array([[True, False]])}
    back = unpack(pack(state))
    assert back["a"].dtype == np.float32 and back["a"].shape == (3, 4) and (back["a"] == state["a"]).all()
    assert back["b"] == [7, None, 0.5] and back["c"].dtype == bool
    costs = np.array([[0.1, np.nan], [np.inf, 2.0]])  # float64 holding a value float32 does not: kept whole
    wide = unpack(pack({"x": costs, "y": costs.astype(np.float32).astype(np.float64)}))
    assert wide["x"].dtype == wide["y"].dtype == np.float64
    assert np.array_equal(wide["x"], costs, equal_nan=True) and wide["x"][0, 0] == 0.1
    assert len(pack(np.zeros(1000))) < 4100 < len(pack(np.full(1000, 0.1)))
    with pytest.raises(TypeError, match="holds a object, which does not pack"):
        pack({"x": object()})
    forged = msgpack.packb(msgpack.ExtType(1, msgpack.packb(["|O", [1], b"\0" * 8])))
    with pytest.raises(StateFileError, match="an array of objects"):
        unpack(forged)


def test_answers_and_states_of_an_incomplete_batch_are_cut_off_on_opening(tmp_path):
    def state(stream: str, seq: int) -> SavedState:
        return SavedState(stream, seq, seq, float(seq), f"{stream}{seq}".encode())

    with Journal(tmp_path) as journal:
        store = StateStore(tmp_path)
        for seq in (1, 2, 3):
            journal.append(seq, b"answer %d" % seq)
        journal.flush()
        store.complete(3, [state("a", 2), state("b", 3)])
        journal.commit(3)
        for seq in (4, 5):  # the next batch: answered and state "c" written, then "b" and "c" again...
            journal.append(seq, b"answer %d" % seq)
        journal.flush()
        store.complete(5, [state("c", 4), state("b", 5)])
        journal.commit(5)
        store.forget("a")  # ...then "a" expired, and the next batch was killed before its file was complete
        journal.append(6, b"answer 6")
        journal.flush()
        assert journal.read(0, 10, 1 << 20)[-1] == b"answer 5"  # flushed is not shown: not durable yet
    assert sorted(p.name for p in (tmp_path / "states").iterdir()) == [f"{3:020d}.batch", f"{5:020d}.batch"]
    with Journal(tmp_path) as journal:
        store = StateStore(tmp_path)
        assert store.durable() == 5
        journal.cut_after(5)
        assert journal.last == 5 and journal.read(3, 10, 1 << 20) == [b"answer 4", b"answer 5"]
        assert store.recover(5) == {"a": state("a", 2), "b": state("b", 5), "c": state("c", 4)}
        journal.append(6, b"again")  # the journal goes on from the cut
        journal.flush()
        store.forget("a")
        store.complete(6, [state("c", 6)])
        journal.commit()
    # Batch 3 held only "a"'s state, forgotten: no index names it any more.
    assert sorted(p.name for p in (tmp_path / "states").iterdir()) == [f"{5:020d}.batch", f"{6:020d}.batch"]
    with Journal(tmp_path) as journal:
        assert StateStore(tmp_path).recover(journal.last) == {"b": state("b", 5), "c": state("c", 6)}


def test_a_failed_batch_is_rolled_back_in_every_segment_it_reached(tmp_path):
    with Journal(tmp_path, segment_bytes=64, max_bytes=1 << 20) as journal:
        for seq in range(1, 4):
            journal.append(seq, b"x" * 40)
        journal.commit()
        for seq in range(4, 9):  # spills over two more segments, then the batch fails
            journal.append(seq, b"y" * 40)
        journal.flush()
        assert (journal.committed, journal.last, journal.segments) == (3, 8, 4)
        journal.rollback()
        assert (journal.committed, journal.last, journal.segments) == (3, 3, 2)
        assert journal.read(0, 10, 1 << 20) == [b"x" * 40] * 3
        journal.append(4, b"z" * 40)
        journal.commit()
    with Journal(tmp_path, segment_bytes=64, max_bytes=1 << 20) as journal:
        assert journal.read(0, 10, 1 << 20) == [b"x" * 40] * 3 + [b"z" * 40]


# -- restart mid-stream ---------------------------------------------------------------------------


def _lossless_run(thumb_map, winter100: Path, procs, tmp_path: Path, rate: float) -> tuple[str, str, list[str], Path]:
    """A listener and a replay of ``winter100`` (stream train-1) started for a lossless service with a journal in
    tmp_path/journal: the results and history endpoints, the service's command line (to start, and start again) and
    the listener's JSON-lines file."""
    frames, results = endpoints("tcp", tmp_path)
    history = f"tcp://127.0.0.1:{free_port()}"
    jsonl = tmp_path / "listen.jsonl"
    service = lostx_command("serve", "--map", str(thumb_map.path), "--frames", frames, "--results", results,
                            "--mode", "lossless", "--journal", str(tmp_path / "journal"), "--history", history,
                            "--stats-interval", "0.2")
    procs.start("listen", lostx_command("listen", results, "--history", history, "--jsonl", str(jsonl),
                                        "--count", str(FRAMES)))
    procs.start("replay", lostx_command("replay", str(winter100), "--to", frames, "--quiet", "--wait", "60",
                                        "--rate", str(rate), "--stream", "train-1"))
    return results, history, service, jsonl



def test_a_service_killed_mid_stream_carries_on_as_if_it_had_not_been(thumb_map, winter100, uninterrupted, procs,
                                                                        tmp_path):
    results, history, service, jsonl = _lossless_run(thumb_map, winter100, procs, tmp_path, rate=40)
    first = procs.start("serve", service)
    wait_for(lambda: len(read_jsonl(jsonl)) >= 35, 60, "35 answers from the first service")
    first.kill()  # SIGKILL: no flushing, no goodbye
    first.wait(10)
    stats = Collector(results, topics=("stats",))
    try:
        procs.start("serve-again", service)
        assert procs.processes["replay"].wait(120) == 0
        assert procs.processes["listen"].wait(60) == 0
    finally:
        stats.stop()
    rows = read_jsonl(jsonl)
    assert [r["frame_id"] for r in rows] == list(range(FRAMES)) and [r["seq"] for r in rows] == list(range(1, 101))
    sessions = list(dict.fromkeys(r["session"] for r in rows))
    assert len(sessions) == 2
    before = sum(r["session"] == sessions[0] for r in rows)
    assert before >= 35 and FRAMES - before >= 30
    wrong = [r["frame_id"] for r, e in zip(rows, uninterrupted) if not same(r, e)]
    assert wrong == []
    # The restarted service's stats count on from the journal's last answer, before it answers anything.
    assert stats.stats[0].session == sessions[1] and stats.stats[0].seq >= before
    assert [r["stream_seq"] for r in rows] == list(range(1, 101))


# -- a journal that cannot be written -------------------------------------------------------------


def test_a_service_killed_while_its_disk_is_full_takes_back_no_answer_anybody_heard_of(
        thumb_map, winter100, uninterrupted, procs, tmp_path):
    """Real processes. After 20 answers the service's disk fills, from outside (its file size limit set so that the
    journal's next few records still fit but the states of their batch do not); a listener takes everything the
    history serves meanwhile (section 7.4: fetching until nothing more comes); then kill -9, a restart on the same
    journal, and every answer a listener holds must be the journal's answer of that number: none was served that a
    restart took back or numbered again."""
    resource = pytest.importorskip("resource")
    results, history, service, running = _lossless_run(thumb_map, winter100, procs, tmp_path, rate=20)
    journal = tmp_path / "journal"
    first = procs.start("serve", service)
    stats = Collector(results, topics=("stats",))
    try:
        wait_for(lambda: len(read_jsonl(running)) >= 20, 60, "20 answers")
        segment = max(journal.glob("*.journal"))
        # A full disk: room for about four more answers' records, none for a batch's states (0.8 MB).
        resource.prlimit(first.pid, resource.RLIMIT_FSIZE, (segment.stat().st_size + 4096, resource.RLIM_INFINITY))
        time.sleep(3.0)
        taken = _fetch_all(history)
        session = stats.stats[-1].session
        first.kill()  # SIGKILL with the disk full
        first.wait(10)
        while_full = [s for s in list(stats.stats) if s.session == session]
        procs.start("serve-again", service)
        assert procs.processes["replay"].wait(120) == 0
        assert procs.processes["listen"].wait(60) == 0
    finally:
        stats.stop()
    procs.stop("serve-again")
    kept = {a["seq"]: a for a in (msgpack.unpackb(p) for p in _payloads(journal))}
    assert sorted(kept) == list(range(1, FRAMES + 1))
    fields = ("session", "frame_id", "match_index", "stream_seq")
    assert taken and [a for a in taken if any(a[k] != kept[a["seq"]][k] for k in fields)] == []
    rows = read_jsonl(running)
    assert [r["seq"] for r in rows] == list(range(1, FRAMES + 1)) and [r["frame_id"] for r in rows] == \
        list(range(FRAMES))
    assert [r["seq"] for r in rows if any(r[k] != kept[r["seq"]][k] for k in fields)] == []
    assert [r["frame_id"] for r, e in zip(rows, uninterrupted) if not same(r, e)] == []
    # While full: the stats spoke of the durable answers alone, and said why nothing more was taken.
    assert while_full and max(s.journal.last for s in while_full) == max(s.seq for s in while_full) == \
        max(a["seq"] for a in taken)
    assert while_full[-1].journal.blocked == "File too large"


def _fetch_all(endpoint: str) -> list[dict]:
    """Every answer a history serves, fetched as a listener resuming from the start does (section 7.4)."""
    from lostx.stream.history import HistoryClient

    client = HistoryClient(endpoint, timeout=10)
    try:
        answers: list[dict] = []
        while True:
            reply = client.fetch(answers[-1]["seq"] if answers else 0, 1024)
            if not reply.items:
                return answers
            answers += [msgpack.unpackb(item) for item in reply.items]
    finally:
        client.close()


@pytest.mark.parametrize("failing", ["journal", "states"])
def test_a_full_disk_is_said_at_once_serves_only_durable_answers_and_loses_nothing_once_freed(
        thumb_map, winter100, uninterrupted, tmp_path, monkeypatch, failing):
    """The disk fills after 20 answers: under the journal's next records, or (``states``) under the batch's states
    while the journal's records still fit. Either way the frames in flight are refused at once with
    ``journal_unwritable`` (no stall), nothing after answer 20 is served, counted or kept, and the stats say why."""
    full = threading.Event()
    write_all, write_whole = journal_module._write_all, states_module._write_whole

    def journal_write(fd: int, data: bytes) -> None:
        if full.is_set() and failing == "journal":
            os.write(fd, data[: len(data) // 2])  # a record cut short, as a disk filling up leaves it
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        write_all(fd, data)

    def state_write(path: Path, data: bytes, fsync: bool) -> None:
        # With the journal's records still fitting, the disk has 100 kB left: less than a batch's states.
        if full.is_set() and (failing == "journal" or len(data) > 100_000):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        write_whole(path, data, fsync)

    monkeypatch.setattr(journal_module, "_write_all", journal_write)
    monkeypatch.setattr(states_module, "_write_whole", state_write)
    source = list(folder_traverse(winter100))[:60]
    frames_at, results_at = endpoints("ipc", tmp_path)
    config = StreamConfig(frames=frames_at, results=results_at, mode="lossless", journal=tmp_path / "journal",
                          stats_interval=0.1)
    logs: list[str] = []
    service = LocalizerService(localizer_factory(thumb_map, Config()), config, log=logs.append)
    listener = Collector(results_at)
    seen: dict[str, object] = {}

    def while_full(publisher: FramePublisher) -> None:
        started = time.monotonic()
        try:
            # Frame 20 is the first whose answer could not be written: its producer must hear of it.
            wait_for(lambda: any(e.code == "journal_unwritable" and e.frame_id == 20 for e in list(publisher.errors)),
                     5, "frame 20 refused")
            seen["heard_after_s"] = time.monotonic() - started
        except AssertionError:
            seen["heard_after_s"] = None  # a stall: the producer heard nothing
        wait_for(lambda: any("cannot write the journal" in line for line in logs), 30, "the failure reported")
        stats_before = len(listener.stats)
        seen["history"] = _fetch(service.history_endpoint, after=0)
        with FramePublisher(frames_at, stream="another") as another:  # a robot that comes along meanwhile
            another.wait_ready(10)
            another.send(source[0], timeout=10)
            wait_for(lambda: not another.flush(0.2) and another.counts.refused >= 1, 10, "its frame refused")
            seen["refused"] = [(e.code, e.frame_id) for e in another.errors]
            time.sleep(1.0)
            seen["stats"] = listener.stats[stats_before:]
            seen["acked"], seen["committed"] = publisher.counts.acked, service.journal.committed
            seen["on_disk"] = _records(tmp_path / "journal")
            full.clear()
            seen["another"] = another.flush(30)  # sent again, and answered

    with serving(service, listener) as thread:
        with FramePublisher(frames_at, stream="cam") as publisher:
            publisher.wait_ready(30)
            for frame in source[:20]:
                publisher.send(frame, timeout=30)
            assert publisher.flush(30)
            full.set()
            freer = threading.Thread(target=while_full, args=(publisher,), daemon=True)
            freer.start()
            for frame in source[20:]:
                publisher.send(frame, timeout=60)
            assert publisher.flush(60)
            freer.join(60)
        wait_for(lambda: len(listener.results) == 61, 20, "61 results")
        assert thread.is_alive()  # up throughout
    # No stall: the producer heard within a bounded time that its frames were not kept, and sent them again.
    assert seen["heard_after_s"] is not None and seen["heard_after_s"] < 3.0
    assert seen["refused"] == [("journal_unwritable", 0)] and seen["another"]
    # While the disk was full: the history served, the stats went out, and all of them spoke of answers 1-20 alone,
    # the journal's file held nothing after them, and the stats said why it was blocked.
    history = seen["history"]
    assert isinstance(history, messages.History) and (history.first, history.last) == (1, 20)
    assert [msgpack.unpackb(item)["seq"] for item in history.items] == list(range(1, 21))
    full_stats = seen["stats"]
    assert len(full_stats) >= 5 and all(s.seq == 20 and s.journal.last == 20 for s in full_stats)
    assert all(s.journal.blocked == "No space left on device" for s in full_stats)
    assert full_stats[-1].journal.withdrawn >= 1 and full_stats[-1].answered == 20
    assert seen["acked"] == seen["committed"] == 20 and seen["on_disk"] == list(range(1, 21))
    # Once freed: every frame answered once, in order, as the uninterrupted localizer answers it.
    cam = [r for r in listener.results if r.tag.stream == "cam"]
    assert [r.frame_id for r in cam] == list(range(60))
    assert [r.tag.seq for r in listener.results] == list(range(1, 62))
    assert all(same(r.to_dict(), e) for r, e in zip(cam, uninterrupted))
    assert listener.final.journal.blocked is None and listener.final.answered == 61
    journaled = [msgpack.unpackb(p) for p in _payloads(tmp_path / "journal")]
    assert [a["frame_id"] for a in journaled if a["stream"] == "cam"] == list(range(60)) and len(journaled) == 61
    assert sum("cannot write the journal" in line and "No space left on device" in line for line in logs) == 1
    assert sum("is written again" in line for line in logs) == 1


def _payloads(folder: Path) -> list[bytes]:
    """Every answer a journal folder holds, read as a restarted service would (the journal's own lock released)."""
    with Journal(folder) as kept:
        return kept.read(0, 1 << 20, 1 << 40)


def _records(folder: Path) -> list[int]:
    """The sequence numbers of every whole record in the journal's segment files, read raw (durable or not)."""
    seqs = []
    for path in sorted(folder.glob("*.journal")):
        data, pos = path.read_bytes(), 0
        while pos + journal_module.HEADER.size <= len(data):
            length, _, seq = journal_module.HEADER.unpack_from(data, pos)
            if pos + journal_module.HEADER.size + length > len(data):
                break
            seqs.append(seq)
            pos += journal_module.HEADER.size + length
    return seqs


def _fetch(endpoint: str, after: int) -> messages.History:
    context = zmq.Context()
    dealer = context.socket(zmq.DEALER)
    dealer.setsockopt(zmq.LINGER, 0)
    dealer.connect(endpoint)
    try:
        dealer.send(wire.encode_fetch(messages.Fetch(after=after, max=100)))
        assert dealer.poll(10_000)
        return wire.decode_history(dealer.recv(), Limits())  # type: ignore[return-value]
    finally:
        dealer.close()
        context.term()


def test_a_read_only_journal_folder_is_named_so(tmp_path, monkeypatch):
    folder = tmp_path / "journal"
    folder.mkdir()
    real_statvfs = os.statvfs

    class ReadOnly:
        def __init__(self, path):
            self.f_flag = real_statvfs(path).f_flag | os.ST_RDONLY

    monkeypatch.setattr(os, "access", lambda path, mode: False)
    with pytest.raises(InputError, match="no permission"):
        check_output_folder(folder, "--journal")
    monkeypatch.setattr(os, "statvfs", ReadOnly)
    with pytest.raises(InputError, match=r"--journal .* cannot be written into \(a read-only file system\)"):
        check_output_folder(folder, "--journal")


def test_a_stream_with_the_layout_and_odometry_carries_over(robotcar, mosaic, tmp_path):
    """The front/rear scene (S1): the layout gathers the frames of the last 24 m with the ego poses; a restored
    localizer gathers the same ones."""
    from lostx.core import LostDescriber, ReferenceMap, build_map
    from lostx.replay.dataset import open_traverse

    scene = robotcar.parent / "nuscenes-frontrear" / "scene-0523"
    build_map(open_traverse(scene / "rear"), tmp_path / "rear", describer=LostDescriber(mosaic), progress=False)
    rear = ReferenceMap.open(tmp_path / "rear")
    front = list(open_traverse(scene / "front"))
    went_on = Localizer(rear, backbone=mosaic)
    expected = [went_on.step(frame).summary() for frame in front]
    before = Localizer(rear, backbone=mosaic)
    for frame in front[:25]:
        before.step(frame)
    assert before.following_distance and before.matcher.layout_off is None
    after = Localizer(rear, backbone=mosaic)
    after.restore(unpack(pack(before.state())))
    answers = [after.step(frame).summary() for frame in front[25:]]
    assert all(same(a, e) for a, e in zip(answers, expected[25:]))
    fresh = Localizer(rear, backbone=mosaic)  # without the gathered frames and the motion: other answers
    assert sum(not same(fresh.step(frame).summary(), e) for frame, e in zip(front[25:], expected[25:])) >= 5


def test_a_stream_placed_by_visual_odometry_carries_over(robotcar, mosaic, tmp_path):
    """The same with the motion from the frames themselves: the previous frame and the step filter carry over."""
    from lostx.core import LostDescriber, ReferenceMap, build_map
    from lostx.core.config import MotionConfig
    from lostx.replay.dataset import open_traverse

    scene = robotcar.parent / "nuscenes-frontrear" / "scene-0523"
    config = Config(motion=MotionConfig(source="visual"))
    build_map(open_traverse(scene / "rear"), tmp_path / "rear", describer=LostDescriber(mosaic), config=config,
              progress=False)
    rear = ReferenceMap.open(tmp_path / "rear")
    front = list(open_traverse(scene / "front"))
    went_on = Localizer(rear, config, mosaic)
    expected = [went_on.step(frame).summary() for frame in front]
    before = Localizer(rear, config, mosaic)
    for frame in front[:25]:
        before.step(frame)
    assert before.matcher._placer.odometer._visual is not None  # visual odometry places the frames
    after = Localizer(rear, config, mosaic)
    after.restore(unpack(pack(before.state())))
    answers = [after.step(frame).summary() for frame in front[25:]]
    assert all(same(a, e) for a, e in zip(answers, expected[25:]))


def test_the_journal_disk_is_checked_at_start_up_for_the_journal_and_the_states(thumb_map, tmp_path):
    """The journal's bound and the states of every stream it may hold are compared with the disk's free space when
    the service starts: too little is a warning saying what is needed, what is free and what to change."""
    free = shutil.disk_usage(tmp_path).free
    roomy = StreamConfig(journal=tmp_path / "journal", journal_max_bytes=free // 4, max_streams=1)
    assert journal_space(roomy, state_bytes=1000) is None
    states_too_large = dataclasses.replace(roomy, max_streams=256)
    assert journal_space(states_too_large, state_bytes=free // 256) is not None
    config = tmp_path / "big.toml"
    config.write_text(f"[stream]\njournal_max_bytes = {2 * free}\n")
    frames, results = endpoints("tcp", tmp_path)
    proc = subprocess.Popen([*lostx_command("serve", "--map", str(thumb_map.path), "--frames", frames, "--results",
                                            results, "--journal", str(tmp_path / "journal"), "--config", str(config))],
                            stderr=subprocess.PIPE, text=True)
    try:
        lines = []
        while not any("live mode" in line for line in lines):
            line = proc.stderr.readline()
            assert line, "".join(lines)
            lines.append(line)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    warning = next(line for line in lines if line.startswith("lostx: warning: the journal"))
    state = format_bytes(state_bytes(Config(), thumb_map.n_frames))
    assert f"(journal_max_bytes {format_bytes(2 * free)}, and the states of 64 streams, {state} each at most, " \
           f"twice over while a batch replaces them), and its disk has " in warning
    assert warning.rstrip().endswith("when the disk is full, frames are refused (journal_unwritable) until there is "
                                     "room again; lower journal_max_bytes or max_streams, or free some space")
