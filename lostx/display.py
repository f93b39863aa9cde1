"""How the commands word what the service answers: the state of an answer, and why answers were
missing (one wording in ``listen``, ``serve`` and ``demo``). Imports nothing heavy."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lostx.stream.messages import Result, Stats


def state_label(result: Result) -> str:
    """``localized``, ``not localized``, or ``warming up`` while the sequence window fills."""
    return "warming up" if result.warming_up else result.state.replace("_", " ")


def window_note(window: int, frames: int, source: object) -> str | None:
    """Said before a traverse of ``frames`` frames from ``source`` is answered with a sequence window of
    ``window`` frames that it can never fill; None where it fills."""
    if window <= frames:
        return None
    return (f"note: the sequence window is {window} frames and {source} has {frames}: the window never fills, so "
            f"every answer is not_localized; pass --window {frames} or less")


def warm_up_line(warming: int, answers: int, seen: int) -> str | None:
    """Why ``warming`` of ``answers`` were not localized while the sequence window filled (``seen``: the
    most frames the window held); None when none were."""
    if not warming:
        return None
    if warming == answers:
        return (f"all {warming} answers came while the sequence window was filling ({seen} frames seen): the stream "
                f"is shorter than the window; serve with --window {seen} or less")
    return f"{warming} of {answers} answers came while the sequence window was filling (not localized)"


def drop_line(stats: Stats) -> str | None:
    """Why a live service answered fewer frames than it received, and what to do; None when it did not."""
    if stats.mode != "live" or not stats.dropped:
        return None
    step = stats.latency_ms.get("step", {}).get("p50")
    pace = f" ({step:.0f} ms per frame, about {1e3 / step:.1f} frames/s)" if step else ""
    return (f"{stats.dropped} of {stats.received} frames dropped: the localizer{pace} is slower than the frames "
            f"arrived; replay at a lower --rate, or serve with --mode lossless --journal DIR to answer every frame")
