"""Sinks: what the service hands each answer to besides the results socket.

A sink is any callable ``sink(frame, estimate)``; it may also have ``close()``,
called once when the service stops. The service calls sinks in its own loop
after the result is published, so a slow sink slows the service down (and a
sink that raises is counted and reported, never fatal). The frame carries the
decoded image and the estimate its evidence: what a viewer needs.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from lostx.core.decide.estimate import Estimate
from lostx.core.frame import Frame


@runtime_checkable
class Sink(Protocol):
    def __call__(self, frame: Frame, estimate: Estimate) -> None: ...


def close_sink(sink: Any) -> None:
    close = getattr(sink, "close", None)
    if callable(close):
        close()


class JsonlSink:
    """Writes every estimate's summary as one JSON line (flushed per line, so a tail -f shows it live)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "a", encoding="utf-8")

    def __call__(self, frame: Frame, estimate: Estimate) -> None:
        self._file.write(json.dumps(estimate.summary()) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()
