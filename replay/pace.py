"""Playing a recorded traverse back as a live stream: at a fixed rate, at its recorded rate, or flat out.

:func:`paced` works on any sized, re-iterable collection of Frames (a folder
traverse or any other reader), yields them in order at their scheduled times,
and is deterministic in what it yields: the same frames with the same ids in
the same order on every run. Only the timing depends on the machine.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Literal, Protocol

from lostx.core.errors import InputError
from lostx.core.frame import Frame

PaceMode = Literal["rate", "realtime", "unlimited"]


class FrameSource(Protocol):
    """What a replay reads: frames in order, a length, and iterable more than once (for loops)."""

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[Frame]: ...


@dataclass(frozen=True)
class Pace:
    mode: PaceMode = "rate"
    rate: float = 10.0
    """Frames per second for ``rate`` (and between laps of a ``realtime`` loop with no recorded gap)."""

    def __post_init__(self) -> None:
        if self.mode not in ("rate", "realtime", "unlimited"):
            raise InputError(f"unknown pace {self.mode!r}: use rate, realtime or unlimited")
        if self.mode == "rate" and not self.rate > 0:
            raise InputError(f"replay rate must be above 0 Hz, got {self.rate}")

    def describe(self) -> str:
        return {"rate": f"{self.rate:g} Hz", "realtime": "recorded rate", "unlimited": "as fast as possible"}[self.mode]


@dataclass(frozen=True)
class Paced:
    lap: int
    frame: Frame


def paced(
    frames: FrameSource,
    pace: Pace,
    loop: bool = False,
    should_stop: Callable[[], bool] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[Paced]:
    """Yield each frame at its time; with ``loop``, start over after the last one, forever.

    Lap ``k`` renumbers frame ids as ``id + k * len(frames)`` (unique ids in one run) and
    records ``lap`` and ``index`` in the metadata. When the consumer falls behind
    (a lossless service holding it back), late frames go at once but the schedule
    does not try to catch up in a burst.
    """
    n = len(frames)
    if n == 0:
        raise InputError("nothing to replay: the traverse has no frames")
    deadline: float | None = None
    previous_stamp: float | None = None
    lap = 0
    while True:
        for frame in frames:
            if should_stop is not None and should_stop():
                return
            interval = _interval(pace, previous_stamp, frame)
            previous_stamp = frame.timestamp
            now = clock()
            deadline = now if deadline is None else max(deadline + interval, now)
            if deadline > now:
                sleep(deadline - now)
            if loop:
                frame = dataclasses.replace(
                    frame, id=frame.id + lap * n, metadata={**frame.metadata, "lap": lap, "index": frame.id}
                )
            yield Paced(lap, frame)
        if not loop:
            return
        lap += 1
        previous_stamp = None


def _interval(pace: Pace, previous_stamp: float | None, frame: Frame) -> float:
    if pace.mode == "unlimited":
        return 0.0
    if pace.mode == "rate":
        return 1.0 / pace.rate
    if frame.timestamp is None:
        raise InputError(f"frame {frame.id} has no timestamp: --realtime needs recorded timestamps; use --rate")
    if previous_stamp is None:
        return 1.0 / pace.rate  # the first frame, or the jump back to the start of a loop
    return max(0.0, frame.timestamp - previous_stamp)


def check_realtime(frames: Iterable[Frame] | object) -> None:
    """Fail early when --realtime is asked of a traverse without timestamps (where this is known)."""
    if getattr(frames, "timestamps", "unknown") is None:
        raise InputError("this traverse has no timestamps: --realtime needs them (a positions CSV with a "
                         "timestamp column); use --rate HZ")
