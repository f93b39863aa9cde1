"""Child processes that always end: the demo and the benchmark start ``lostx serve`` and
``lostx replay`` with a :class:`ProcessGroup`, which stops every one of them on the way
out, whether the block ends normally, by an exception or by Ctrl-C.

A parent killed outright (SIGKILL, a crash) runs no cleanup, so the children are also
told to watch it: with ``LOSTX_EXIT_WITH_PARENT`` set, ``lostx`` sends itself SIGTERM
(a clean stop) as soon as its parent is gone (:func:`exit_with_parent`)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Sequence

EXIT_WITH_PARENT = "LOSTX_EXIT_WITH_PARENT"


def exit_with_parent(interval: float = 0.5) -> None:
    """If ``$LOSTX_EXIT_WITH_PARENT`` is set, SIGTERM this process once its parent has exited."""
    if not os.environ.get(EXIT_WITH_PARENT):
        return
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(interval)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="lostx-parent-watch", daemon=True).start()


def lostx_command(*args: str) -> list[str]:
    """argv that runs ``lostx ARGS`` with this interpreter (no dependence on PATH).

    ``-P`` keeps the working directory off ``sys.path``: run from the folder that holds a clone
    named ``lostx``, the clone would otherwise shadow the installed package."""
    return [sys.executable, "-P", "-m", "lostx.cli", *args]


class ProcessGroup:
    """Start processes; on exit send SIGTERM to those still running, then SIGKILL after ``grace`` seconds."""

    def __init__(self, log_dir: str | Path | None = None, grace: float = 5.0) -> None:
        self.log_dir = Path(log_dir) if log_dir is not None else None
        self.grace = grace
        self.processes: dict[str, subprocess.Popen] = {}
        self._logs: list[IO] = []

    def start(self, name: str, argv: Sequence[str], env: dict[str, str] | None = None) -> subprocess.Popen:
        """Start ``argv``; with a log folder its stdout and stderr go to ``NAME.log`` there."""
        out = None
        if self.log_dir is not None:
            out = open(self.log_dir / f"{name}.log", "w", encoding="utf-8")
            self._logs.append(out)
        process = subprocess.Popen(
            list(argv), stdout=out, stderr=subprocess.STDOUT if out else None, stdin=subprocess.DEVNULL,
            env={**os.environ, EXIT_WITH_PARENT: "1", **(env or {})},
        )
        self.processes[name] = process
        return process

    def log(self, name: str) -> str:
        if self.log_dir is None:
            return ""
        path = self.log_dir / f"{name}.log"
        return path.read_text(encoding="utf-8", errors="replace") if path.exists() else ""

    def stop(self, name: str, timeout: float | None = None) -> int | None:
        """SIGTERM one process and wait for it (SIGKILL after the grace time); its exit code."""
        process = self.processes[name]
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
        try:
            return process.wait(self.grace if timeout is None else timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            return process.wait()

    def close(self) -> None:
        running = [p for p in self.processes.values() if p.poll() is None]
        for process in running:
            process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + self.grace
        for process in running:
            try:
                process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        for handle in self._logs:
            handle.close()
        self._logs.clear()

    def __enter__(self) -> "ProcessGroup":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
