"""Feeding the service from a recording (paced by lostx.replay.pace) or a live source, through a :class:`FramePublisher`."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator, Protocol

from tqdm import tqdm

from lostx.core.frame import Frame
from lostx.replay.pace import FrameSource, Pace, paced

from .producer import FramePublisher, PublisherCounts


@dataclass
class ReplaySummary:
    frames: int = 0
    """Frames taken from the traverse (all laps)."""
    counts: PublisherCounts = field(default_factory=PublisherCounts)
    """What the publisher sent, dropped, had answered, resent and had refused."""
    laps: int = 0
    seconds: float = 0.0
    mode: str = ""
    errors: list[str] = field(default_factory=list)
    unanswered: int = 0
    interrupted: bool = False
    stale: int = 0
    """Live source: frames it dropped for newer ones while the publisher was busy."""

    def line(self) -> str:
        c = self.counts
        rate = c.sent / self.seconds if self.seconds > 0 else 0.0
        parts = [f"sent {c.sent} of {self.frames} frames in {self.seconds:.1f} s ({rate:.1f} frames/s)",
                 f"{self.mode} service"]
        if self.mode == "lossless":
            parts.append(f"{c.acked} answered")
            if self.unanswered:
                parts.append(f"{self.unanswered} NOT answered")
        if c.dropped:
            parts.append(f"{c.dropped} dropped (service busy or absent)")
        if self.stale:
            parts.append(f"{self.stale} camera frames skipped for newer ones")
        if c.resent:
            parts.append(f"{c.resent} resent")
        if c.refused:
            parts.append(f"{c.refused} refused: {self.errors[-1] if self.errors else ''}")
        if len(c.sessions) > 1:
            parts.append(f"the service restarted {len(c.sessions) - 1} time(s)")
        if self.interrupted:
            parts.append("interrupted")
        return "; ".join(parts)


def replay(
    frames: FrameSource,
    publisher: FramePublisher,
    pace: Pace,
    *,
    loop: bool = False,
    progress: bool = True,
    wait: float | None = None,
    flush_timeout: float | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> ReplaySummary:
    """Wait for the service (``wait`` seconds at most, None = forever), send every frame at the
    pace, and in lossless mode wait until all are answered (``flush_timeout``)."""
    ready = publisher.wait_ready(wait)
    items = ((item.lap, item.frame) for item in paced(frames, pace, loop=loop, should_stop=should_stop))
    return _publish(items, publisher, ReplaySummary(mode=ready.mode), None if loop else len(frames), progress,
                    flush_timeout)


class LiveSource(Protocol):
    """Frames as they happen (e.g. :class:`lostx.replay.camera.LiveCamera`), and how many it dropped."""

    dropped: int

    def __iter__(self) -> Iterator[Frame]: ...


def relay_live(
    camera: LiveSource,
    publisher: FramePublisher,
    *,
    progress: bool = True,
    wait: float | None = None,
    flush_timeout: float | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> ReplaySummary:
    """Send a live source's frames as they come, each the newest when the publisher is free
    (frames that arrive while it is busy are dropped by the source, not queued)."""
    ready = publisher.wait_ready(wait)

    def frames() -> Iterator[tuple[int, Frame]]:
        for frame in camera:
            if should_stop is not None and should_stop():
                return
            yield 0, frame

    summary = _publish(frames(), publisher, ReplaySummary(mode=ready.mode), None, progress, flush_timeout)
    summary.stale = camera.dropped
    return summary


def _publish(items: Iterable[tuple[int, Frame]], publisher: FramePublisher, summary: ReplaySummary,
             total: int | None, progress: bool, flush_timeout: float | None) -> ReplaySummary:
    base_stream = publisher.stream
    bar = tqdm(total=total, unit="frame", desc="replay", disable=not progress, leave=False, dynamic_ncols=True)
    start = time.perf_counter()
    try:
        for lap, frame in items:
            # Each lap is a traverse of its own: a new stream, so the service starts it afresh.
            publisher.stream = base_stream if lap == 0 else f"{base_stream}.{lap}"
            summary.laps = lap + 1
            summary.frames += 1
            publisher.send(frame)
            bar.update(1)
            if publisher.counts.dropped or publisher.counts.refused:
                bar.set_postfix(dropped=publisher.counts.dropped, refused=publisher.counts.refused, refresh=False)
        if publisher.lossless:
            bar.set_description("waiting for answers")
            publisher.flush(flush_timeout)
    except KeyboardInterrupt:
        summary.interrupted = True
    finally:
        bar.close()
        counts = publisher.counts
        summary.seconds = time.perf_counter() - start
        summary.counts = dataclasses.replace(counts, sessions=list(counts.sessions))
        summary.errors = [f"frame {e.frame_id}: {e.code}: {e.text}" for e in publisher.errors]
        summary.unanswered = publisher.in_flight
        summary.mode = publisher.ready.mode if publisher.ready else summary.mode
    return summary
