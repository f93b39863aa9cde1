"""Which way along the map's route the frames travel (the reference index rising or falling), found from the
sequence filter's evidence where no declared camera or motion ties it to the heading.

Every frame, the sequence filter searches trajectories of both signs. The difference between the best
falling trajectory's mean cost and the best rising one's, d = s_falling - s_rising (in the costs' units,
standard deviations), casts the frame's vote: for rising when d > 0, with strength min(|d| / ``scale``, 1).
The votes feed the same two-state discrete Bayes filter as the heading (:class:`TwoStateFilter`). While it is
sure, the answer is the best trajectory along that direction; both signs keep being searched and voting, so
the belief is never its own evidence, and it turns when the evidence does.
"""

from __future__ import annotations

import numpy as np

from .heading import TwoStateFilter

DIRECTIONS = ("rising", "falling")


class DirectionFilter:
    """P(rising), P(falling) over the frames of one traverse."""

    def __init__(self, reliability: float, switch: float, scale: float) -> None:
        self.scale = scale
        self._filter = TwoStateFilter(DIRECTIONS, reliability, switch)

    def reset(self) -> None:
        self._filter.reset()

    @property
    def belief(self) -> np.ndarray:
        """P(rising), P(falling)."""
        return self._filter.belief

    def restore(self, belief: np.ndarray) -> None:
        """Continue from a :attr:`belief`."""
        self._filter.reset(np.asarray(belief, dtype=np.float64))

    def update(self, rising: float, falling: float) -> tuple[int, float]:
        """Add one frame's best rising and best falling trajectory scores (lower is better; inf: none).
        Returns the more probable direction (+1 rising, -1 falling) and its probability."""
        vote = 0.0
        if np.isfinite(rising) and np.isfinite(falling):
            vote = float(np.clip((rising - falling) / self.scale, -1.0, 1.0))  # > 0: falling is cheaper
        direction, sure = self._filter.update(vote)
        return (1 if direction == "rising" else -1), sure
