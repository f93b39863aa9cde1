"""Counters and latency percentiles of a running service (the payload of stats messages)."""

from __future__ import annotations

import time
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np


class LatencyWindow:
    """Milliseconds of the last ``size`` events, summarised as percentiles."""

    def __init__(self, size: int = 1000) -> None:
        self.values: deque[float] = deque(maxlen=size)

    def add(self, ms: float) -> None:
        self.values.append(float(ms))

    def summary(self) -> dict[str, float]:
        """``n`` (a count) and the percentiles in ms; ``{"n": 0}`` before any event."""
        if not self.values:
            return {"n": 0}
        a = np.fromiter(self.values, dtype=np.float64)
        p50, p90, p99 = np.percentile(a, [50, 90, 99])
        return {"n": len(a), "p50": float(p50), "p90": float(p90), "p99": float(p99), "max": float(a.max())}


@dataclass
class ServiceCounters:
    """Everything a stats message reports, updated by the service loop."""

    started: float = field(default_factory=time.monotonic)
    received: int = 0
    answered: int = 0
    dropped: int = 0
    missing: int = 0
    duplicates: int = 0
    errors: Counter = field(default_factory=Counter)
    step_ms: LatencyWindow = field(default_factory=LatencyWindow)
    service_ms: LatencyWindow = field(default_factory=LatencyWindow)

    @property
    def uptime(self) -> float:
        return time.monotonic() - self.started
