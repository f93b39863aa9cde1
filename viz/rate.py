"""A rate limit for the heavy entities (images, label maps, lines).

The viewer's GPU texture cache is not covered by its memory limit, and users
of Rerun report running out of memory when camera-rate images are logged for
hours (rerun-io/rerun#12591; dimos PR #1509 settled on 10 Hz per entity).
The light entities (scalars, text, the map) are logged for every frame.
"""

from __future__ import annotations

import time
from typing import Callable


class RateGate:
    """Opens at most ``hz`` times per second of ``clock``; always on the first call. ``hz`` None or <= 0: always open."""

    def __init__(self, hz: float | None, clock: Callable[[], float] = time.monotonic) -> None:
        self.period = 1.0 / hz if hz and hz > 0 else 0.0
        self.clock = clock
        self._next: float | None = None

    def ready(self) -> bool:
        if self.period == 0.0:
            return True
        now = self.clock()
        if self._next is not None and now < self._next:
            return False
        # Schedule from the previous slot, not from now, so the long-run rate is exact;
        # after a pause, restart from now rather than firing a burst.
        self._next = now + self.period if self._next is None or now - self._next > self.period else self._next + self.period
        return True
