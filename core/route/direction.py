"""Which way along the map's route the frames travel (the reference index rising or falling), found from the
sequence filter's evidence where no declared camera or motion ties it to the heading.

Every frame, the sequence filter searches trajectories of both signs. The difference between the best
falling trajectory's mean cost and the best rising one's, d = s_falling - s_rising (in the costs' units,
standard deviations), casts the frame's vote: for rising when d > 0, with strength min(|d| / ``scale``, 1).
The votes feed a two-state discrete Bayes filter (:class:`TwoStateFilter`, filterpy's update). While it is
sure, the answer is the best trajectory along that direction; both signs keep being searched and voting, so
the belief is never its own evidence, and it turns when the evidence does.
"""

from __future__ import annotations

import numpy as np
from filterpy.discrete_bayes import predict, update

DIRECTIONS = ("rising", "falling")


class TwoStateFilter:
    """A discrete Bayes filter over two states fed with votes (> 0 for the second state, < 0 for the first,
    0 none), each ``reliability`` likely to be right, the state swapping with probability ``switch``."""

    def __init__(self, states: tuple[str, str], reliability: float, switch: float) -> None:
        self.states = states
        self.reliability = reliability
        self.switch = switch
        self.reset()

    def reset(self, prior: np.ndarray | None = None) -> None:
        self.belief = np.full(2, 0.5) if prior is None else np.asarray(prior, dtype=np.float64)

    def update(self, vote: float) -> tuple[str, float]:
        s = self.switch
        self.belief = predict(self.belief, 0, [s / 2, 1.0 - s, s / 2])  # on two states: a swap with probability s
        if vote != 0.0:
            # A split vote (its voters disagreeing) counts for less: reliability shrinks towards 1/2.
            p = 0.5 + (self.reliability - 0.5) * min(abs(vote), 1.0)
            self.belief = update(np.array([1.0 - p, p] if vote > 0 else [p, 1.0 - p]), self.belief)
        return self.answer()

    def answer(self) -> tuple[str, float]:
        best = int(np.argmax(self.belief))
        return self.states[best], float(self.belief[best])


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
