"""Which way the query views the route relative to the map, found from the evidence.

Two hypotheses: ``same`` (the query camera looks along the route the way the
map's camera did) and ``opposite`` (a rear camera against a front-camera map,
or the mapped road driven the other way). Every frame is verified under both
(the query's x mirrored or not, paper Sec. III-C); the mirroring that fits its
candidates better casts the frame's vote (:func:`lostx.core.match.matcher.heading_vote`).

A two-state discrete Bayes filter (filterpy) accumulates the votes:

    predict:  P(h) <- (1 - s) P(h) + s P(other h)        s = ``switch``
    update:   P(h) <- P(h) * (p if the vote says h else 1 - p), normalised
              p = 1/2 + (``vote_reliability`` - 1/2) |vote|

A declared camera direction only sets the prior: P(declared) =
``declared_prior`` when the declaration first appears or changes. The
answer is the more probable heading and its probability. The direction of
travel along the map (reference index rising or falling) is a separate
question, answered by the sign of the sequence filter's speed.
"""

from __future__ import annotations

import numpy as np
from filterpy.discrete_bayes import predict, update

from ..config import HeadingConfig
from ..frame import HEADINGS, Heading


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


class HeadingFilter:
    """P(same), P(opposite) over the frames of one traverse."""

    def __init__(self, config: HeadingConfig | None = None) -> None:
        self.config = config or HeadingConfig()
        self._filter = TwoStateFilter(HEADINGS, self.config.vote_reliability, self.config.switch)  # type: ignore[arg-type]
        self.reset()

    def reset(self) -> None:
        self._filter.reset()
        self._declared: Heading | None = None

    @property
    def belief(self) -> np.ndarray:
        return self._filter.belief

    def update(self, vote: float, declared: Heading | None = None) -> tuple[Heading, float]:
        """Add one frame: its vote (> 0 favours opposite, 0 none) and the heading its camera declares.
        Returns the more probable heading and its probability."""
        cfg = self.config
        if declared is not None and declared != self._declared:
            self._declared = declared
            self._filter.reset(_prior(declared, cfg.declared_prior))
        if declared is not None and cfg.declared_prior >= 1.0:
            return self._filter.answer()  # type: ignore[return-value]
        return self._filter.update(vote)  # type: ignore[return-value]

    def state(self) -> dict:
        return {"belief": self._filter.belief, "declared": self._declared}

    def restore(self, state: dict) -> None:
        self._filter.reset(np.asarray(state["belief"], dtype=np.float64))
        self._declared = state["declared"]


def _prior(declared: Heading, strength: float) -> np.ndarray:
    belief = np.full(len(HEADINGS), 1.0 - strength)
    belief[HEADINGS.index(declared)] = strength
    return belief / belief.sum()
