"""A frame's single-frame score of any map frame, computed when asked.

The matcher verifies only its top candidates; the sequence filter needs a score for every map frame it
looks at. :class:`MapScores` holds what is needed to give one on demand (the query's exact descriptor
distance, the verified candidates' own scores, the frames a calibration query leaves out) rather than
an array over the whole map, so that a search through the map's approximate index computes no distance
it does not need.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

_EMPTY = np.zeros(0, dtype=np.int64)


@dataclass
class MapScores:
    """One frame's single-frame score of any map frame, computed when asked.

    The descriptor distance times ``factor`` (LoST-X: the verification scores of the candidates are
    about their distance times a factor, and the others get the candidates' median factor), or
    ``constant`` where the score ignores the distance (plain Eq. 4); the verified candidates their
    own scores; ``removed_score`` for the map frames ``removed`` (the neighbourhood a calibration query
    leaves out: the worst score of the others, so that no answer falls there).
    """

    distances: Callable[[np.ndarray | None], np.ndarray]
    """The exact descriptor distance of the query to the map frames given (None: every map frame)."""
    n_frames: int
    factor: float = 1.0
    constant: float | None = None
    known: np.ndarray = field(default_factory=lambda: _EMPTY)
    """Sorted map frames with scores of their own (the verified candidates)."""
    known_scores: np.ndarray = field(default_factory=lambda: np.zeros(0))
    removed: slice | None = None
    removed_score: float = np.nan

    @classmethod
    def of_array(cls, scores: np.ndarray) -> "MapScores":
        """Scores already computed for every map frame."""
        scores = np.asarray(scores, dtype=np.float64)
        return cls(lambda refs: scores if refs is None else scores[refs], len(scores))

    def every(self) -> np.ndarray:
        """(N,) float64 scores of every map frame (one pass over the map's descriptors)."""
        return self._finish(np.arange(self.n_frames, dtype=np.int64), None)

    def at(self, refs: np.ndarray) -> np.ndarray:
        """(m,) float64 scores of the map frames ``refs``."""
        refs = np.asarray(refs, dtype=np.int64)
        return self._finish(refs, refs)

    def _finish(self, refs: np.ndarray, asked: np.ndarray | None) -> np.ndarray:
        """The scores of ``refs``, their distances computed for ``asked`` (None: every map frame)."""
        if self.constant is not None:
            out = np.full(len(refs), self.constant, dtype=np.float64)
        else:
            out = np.asarray(self.distances(asked), dtype=np.float64) * self.factor
        if len(self.known):
            pos = np.clip(np.searchsorted(self.known, refs), 0, len(self.known) - 1)
            hit = self.known[pos] == refs
            out[hit] = self.known_scores[pos[hit]]
        if self.removed is not None:
            out[(refs >= self.removed.start) & (refs < self.removed.stop)] = self.removed_score
        return out
