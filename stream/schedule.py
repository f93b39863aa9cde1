"""Which accepted frame the service's worker takes next.

``live`` keeps one slot per stream: a newer frame of a stream replaces the one waiting there (the
older is dropped), so a slow localizer always starts on a stream's newest frame, and the streams
waiting take turns. ``lossless`` keeps every frame in arrival order and recognises a frame that a
producer sends again after a reconnection (answered already, by this service or, as its journal
shows, by the one before it), so that it is answered once.
"""

from __future__ import annotations

from collections import deque
from typing import Callable

from .messages import FrameMessage
from .streams import AnsweredIds
from .worker import Job

FrameKey = tuple[str, int]


def frame_key(message: FrameMessage) -> FrameKey | None:
    """A frame's identity for recognising resends: only a frame that names its stream has one
    (without a stream id a new run's frame 0 and a resent frame 0 look alike)."""
    return (message.stream, message.id) if message.stream else None


class FrameSchedule:
    """The frames accepted and not yet started, in the order the mode gives them out."""

    def __init__(self, lossless: bool) -> None:
        self.lossless = lossless
        self._slots: dict[str, Job] = {}  # live: each stream's newest frame not yet started, in turn order
        self._queue: deque[Job] = deque()  # lossless: frames in order
        self.answered = AnsweredIds()
        """Lossless: the frames taken lately, to recognise resent ones."""
        self.unacked: set[FrameKey] = set()
        """Lossless: frames taken whose acknowledgement has not gone out yet."""

    def __len__(self) -> int:
        return len(self._queue) + len(self._slots)

    def add(self, job: Job) -> Job | None:
        """Schedule ``job``; in live mode, the frame of its stream that it supersedes (None if none)."""
        if self.lossless:
            self._queue.append(job)
            return None
        superseded = self._slots.get(job.stream.name)
        self._slots[job.stream.name] = job  # a stream waiting already keeps its turn
        return superseded

    def drain(self) -> list[Job]:
        """Take every frame waiting (they are refused), in the order they would have gone."""
        jobs = list(self._queue) + list(self._slots.values())
        self._queue.clear()
        self._slots.clear()
        return jobs

    def next(self, resent: Callable[[Job, bool], None]) -> Job | None:
        """Lossless: the oldest frame not answered before; live: the newest frame of the next stream.

        A frame resent after it was answered is passed to ``resent`` with whether its acknowledgement
        is owed again (False while the first one is still to come) and skipped."""
        if not self.lossless:
            return self._slots.pop(next(iter(self._slots))) if self._slots else None
        while self._queue:
            job = self._queue.popleft()
            key = frame_key(job.message)
            if key is None or key not in self.answered:
                if key is not None:
                    self.answered.add(key)
                    self.unacked.add(key)
                return job
            resent(job, key not in self.unacked)
        return None
