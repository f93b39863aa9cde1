"""Helpers for the streaming tests: real processes that always end, free ports, small maps."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from lostx.stream.client import Listener
from lostx.stream.messages import ErrorMessage, Result, Stats
from lostx.stream.processes import ProcessGroup, lostx_command
from lostx.stream.service import LocalizerService

__all__ = ["ProcessGroup", "lostx_command", "free_port", "endpoints", "Collector", "read_jsonl", "wait_for", "serving",
           "procs", "thumb_map", "nordland_subset", "link_frames", "winter_runs"]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def endpoints(transport: str, tmp_path: Path) -> tuple[str, str]:
    if transport == "tcp":
        return f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    return f"ipc://{tmp_path}/frames", f"ipc://{tmp_path}/results"


def wait_for(condition: Callable[[], bool], timeout: float, what: str, interval: float = 0.05) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(interval)


@contextmanager
def serving(service: LocalizerService, *listeners: Collector) -> Iterator[threading.Thread]:
    """Run ``service`` in a thread for the block; afterwards stop it, wait for its thread (yielded, to check that it
    ended) and stop ``listeners``, whatever the block raised."""
    with service:
        thread = threading.Thread(target=service.run, daemon=True)
        thread.start()
        try:
            yield thread
        finally:
            service.stop("test over")
            thread.join(30)
            for listener in listeners:
                listener.stop()


class Collector(threading.Thread):
    """A listener in a thread of the test process, keeping everything it receives.

    ``delay(n)`` returns the seconds to sleep after the n-th result (a slow listener);
    ``gate`` (an Event) is waited on after the first result when given (a stalled listener).
    """

    def __init__(self, endpoint: str, *, topics=("result", "error", "stats"), delay=None, gate=None,
                 hwm: int = 10_000, rcvbuf: int | None = None, keys=None) -> None:
        super().__init__(daemon=True)
        self.listener = Listener(endpoint, topics=topics, hwm=hwm, rcvbuf=rcvbuf, keys=keys)
        self.results: list[Result] = []
        self.errors: list[ErrorMessage] = []
        self.stats: list[Stats] = []
        self.delay = delay
        self.gate = gate
        self.gate_timed_out = False
        self._halt = threading.Event()
        self.start()

    def run(self) -> None:
        try:
            while not self._halt.is_set():
                message = self.listener.receive(0.1)
                if isinstance(message, Result):
                    self.results.append(message)
                    if self.gate is not None and len(self.results) == 1:
                        self.gate_timed_out = not self.gate.wait(60)
                    if self.delay is not None:
                        time.sleep(self.delay(len(self.results)))
                elif isinstance(message, ErrorMessage):
                    self.errors.append(message)
                elif isinstance(message, Stats):
                    self.stats.append(message)
        finally:
            self.listener.close()

    @property
    def final(self) -> Stats | None:
        return next((s for s in reversed(self.stats) if s.final), None)

    def ids(self) -> list[int]:
        return [r.frame_id for r in self.results]

    def stop(self) -> None:
        self._halt.set()
        self.join(5)


def read_jsonl(path: Path, kind: str = "result") -> list[dict]:
    """The rows of one kind in a JSON-lines file being written (a last line cut short is left out)."""
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except ValueError:
            continue
    return [r for r in rows if r.get("type") == kind]


def link_frames(paths: list[Path], out: Path) -> Path:
    """A folder of links to ``paths``: a traverse of its own (frame ids from 0), without copying images."""
    out.mkdir(parents=True, exist_ok=True)
    for path in paths:
        (out / path.name).symlink_to(path)
    return out


@pytest.fixture
def procs(tmp_path):
    """Processes started by a test; every one is stopped (TERM, then KILL) when the test ends.
    Their output is in tmp_path/NAME.log, printed at teardown (pytest shows it when a test fails)."""
    group = ProcessGroup(log_dir=tmp_path, grace=5.0)
    yield group
    group.close()
    for name in group.processes:
        print(f"----- {name} (exit {group.processes[name].returncode}) -----\n{group.log(name)[-3000:]}")


@pytest.fixture(scope="session")
def thumb_map(tmp_path_factory, nordland):
    """SeqSLAM thumbnail map of the 3576 Nordland summer frames (no network: about a second)."""
    from lostx.core.build import build_map
    from lostx.core.describe.thumbnail import ThumbnailDescriber
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.replay.folder import folder_traverse

    out = tmp_path_factory.mktemp("maps") / "summer"
    traverse = folder_traverse(nordland / "summer")
    build_map(traverse, out, describer=ThumbnailDescriber(), metadata={"camera": "front"}, progress=False)
    return ReferenceMap.open(out)


@pytest.fixture(scope="session")
def nordland_subset(tmp_path_factory, nordland):
    """A folder of links to the first 300 winter frames: a short traverse for restart tests."""
    return link_frames(sorted((nordland / "winter").iterdir())[:300], tmp_path_factory.mktemp("winter300"))


@pytest.fixture(scope="session")
def winter_runs(tmp_path_factory, nordland) -> list[Path]:
    """Four traverses of 300 winter frames, one from each quarter of the route (folders of links):
    four robots' streams."""
    paths = sorted((nordland / "winter").iterdir())
    root = tmp_path_factory.mktemp("runs")
    quarter = len(paths) // 4
    return [link_frames(paths[k * quarter:k * quarter + 300], root / f"run{k}") for k in range(4)]
