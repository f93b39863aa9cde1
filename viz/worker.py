"""A one-slot background worker for the heavy logging.

JPEG encoding and reading reference images cost tens of milliseconds a frame;
done here they overlap with the localizer's next frame instead of delaying it.
The slot holds one pending job: a new job replaces a pending one (the viewer
wants the newest frame, not a backlog), so a busy worker drops frames instead
of queueing them without bound. The thread runs at a lower scheduling priority
(Linux: per-thread nice) so that on a saturated CPU the localizer wins.
"""

from __future__ import annotations

import logging
import os
import threading
from typing import Callable, Generic, TypeVar

log = logging.getLogger(__name__)

Job = TypeVar("Job")
NICE = 10


class LatestWorker(Generic[Job]):
    def __init__(self, run: Callable[[Job], None], name: str = "lostx-viz", nice: int = NICE) -> None:
        self._run_job = run
        self._nice = nice
        self._cond = threading.Condition()
        self._pending: Job | None = None
        self._closed = False
        self._busy = False
        self.done = 0
        self.dropped = 0
        self.failed = 0
        self.error: BaseException | None = None
        """The first exception a job raised (re-raised by the owner where it wants to be strict)."""
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, job: Job) -> None:
        with self._cond:
            if self._closed:
                raise RuntimeError("the worker is closed")
            if self._pending is not None:
                self.dropped += 1
            self._pending = job
            self._cond.notify_all()

    def wait_idle(self, timeout: float | None = None) -> None:
        """Block until no job is pending or running; TimeoutError after ``timeout`` seconds."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._pending is None and not self._busy, timeout):
                raise TimeoutError(f"the viewer's worker is still busy after {timeout} s")

    def close(self, timeout: float | None = None) -> None:
        """Finish the pending job, then stop; TimeoutError if the thread is still running after ``timeout`` seconds."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise TimeoutError(f"the viewer's worker did not finish within {timeout} s")

    def _loop(self) -> None:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self._nice)
        except (AttributeError, OSError):  # not Linux, or not permitted: run at normal priority
            pass
        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait()
                job, self._pending = self._pending, None
                self._busy = job is not None
            if job is None:
                return
            try:
                self._run_job(job)
                self.done += 1
            except Exception as exc:  # a viewer problem must not end the thread (or the localizer)
                self.failed += 1
                if self.error is None:
                    self.error = exc
                    log.exception("the Rerun sink's worker failed; it goes on")
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
