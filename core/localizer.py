"""The online localizer: one frame in, one place estimate out.

``Localizer(map, config).step(frame) -> Estimate``. This first version answers
from the single frame; the sequence filter and the recursive tracker plug in
behind the same interface.
"""

from __future__ import annotations

import time

from .backbone import Backbone
from .config import Config
from .estimate import Candidate, Estimate, Evidence
from .frame import Frame
from .matcher import MatchResult, PlaceMatcher
from .refmap import ReferenceMap


class Localizer:
    """Stateful place recognition over a stream of frames from one camera."""

    def __init__(self, refmap: ReferenceMap, config: Config | None = None, backbone: Backbone | None = None) -> None:
        self.map = refmap
        self.config = config or Config()
        self.matcher = PlaceMatcher(refmap, self.config, backbone)

    def reset(self) -> None:
        """Forget everything seen so far (start of a new traverse)."""
        self.matcher.reset()

    def step(self, frame: Frame) -> Estimate:
        start = time.perf_counter()
        opposite = frame.camera != self.map.camera
        result = self.matcher.match(frame.image, opposite=opposite)
        latency = {k: 1e3 * v for k, v in result.timings.items()}
        latency["total"] = 1e3 * (time.perf_counter() - start)
        return self._estimate(frame, result, opposite, latency)

    def _estimate(self, frame: Frame, result: MatchResult, opposite: bool, latency: dict[str, float]) -> Estimate:
        index = result.best
        return Estimate(
            frame_id=frame.id,
            timestamp=frame.timestamp,
            state="localized",
            match_index=index,
            match_name=self.map.names[index],
            position=self._position(index),
            confidence=result.confidence,
            score=result.score,
            single_match_index=index,
            candidates=_candidates(result),
            opposite=opposite,
            latency_ms=latency,
            evidence=Evidence(
                query_labels=result.query_labels,
                correspondences=(
                    {int(c): corr for c, corr in zip(result.candidates, result.correspondences)}
                    if result.correspondences is not None else {}
                ),
                grid=getattr(self.map, "grid", None),
            ),
        )

    def _position(self, index: int) -> tuple[float, float] | None:
        if self.map.positions is None:
            return None
        x, y = self.map.positions[index]
        return float(x), float(y)


def _candidates(result: MatchResult) -> list[Candidate]:
    n = result.n_matches
    return [
        Candidate(int(c), float(d), float(s), int(n[i]) if n is not None else 0)
        for i, (c, d, s) in enumerate(zip(result.candidates, result.distances, result.scores))
    ]
