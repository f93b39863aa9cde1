"""Which way the query views the route relative to the map, found from the evidence.

Two hypotheses: ``same`` (the query camera looks along the route the way the map's camera did) and ``opposite``
(a rear camera against a front-camera map, or the mapped road driven the other way). Voters cast a vote in [-1, 1]
each frame (> 0 favours opposite, 0 says nothing):

- ``mirror``: every frame is verified under both headings (the query's x mirrored or not, paper Sec. III-C); the
  mirroring that fits its candidates better (:func:`lostx.core.match.matcher.heading_vote`; a flipped thumbnail's for
  thumbnail maps);
- ``motion``: which heading's combined answer landed where that heading's own trajectory predicted it
  (:mod:`lostx.core.route.agreement`): +1 the opposite's alone, -1 the same's alone, 0 both or neither. A mirrored
  verification asks whether left and right swap; this asks whether the places come in the order the motion says.

A voter is trusted as far as its votes measure on this stream. Its effect is d_i = m_i / s_i (the mean of its votes
over their standard deviation, forgetting over 1 / ``switch`` frames), known to within se_i = 1 / sqrt(n_i), n_i its
votes discounted for their lag-one autocorrelation r_i (neighbouring frames see much the same: n (1 - r) / (1 + r)).
How far a voter can tell the headings apart on this road, c_i, is not known: as likely as not it cannot tell at all
(c_i = 0: a road that looks alike both ways); where it can, it points the right way by anything up to C standard
deviations, but it may be misled by the road (a turn where neither heading holds) with probability e (``misled``),
pointing the wrong way just as consistently:

    c_i ~ 1/2 delta(0) + 1/2 [(1 - e) U(0, C) + e U(-C, 0)],    d_i ~ N(T c_i, se_i^2),    T = +1 opposite, -1 same
    P(opposite) = prior * prod_i L_i(+1) / (prior * prod_i L_i(+1) + (1 - prior) * prod_i L_i(-1))

So a voter that cannot tell (d_i near 0) has no say, a sure one moves the odds by at most (1 - e) / e, voters that
agree multiply their odds, and voters that disagree leave the heading uncertain however many frames each has seen.
A declared camera direction is the prior (``declared_prior``; 1 fixes the heading, 1/2 without one). The answer is
the more probable heading and its probability.
"""

from __future__ import annotations

import math

import numpy as np

from ..config import HeadingConfig
from ..frame import HEADINGS, Heading


VOTERS: tuple[str, ...] = ("mirror", "motion")
MIN_VOTES = 3
"""A voter counts once it has voted this many times (before that its spread is unknown)."""


class VoteTally:
    """One voter's votes: their mean, spread and lag-one autocorrelation, forgetting with ``memory`` frames."""

    def __init__(self, memory: float) -> None:
        self.keep = 1.0 - 1.0 / memory if np.isfinite(memory) else 1.0
        self.reset()

    def reset(self) -> None:
        self.n = self.total = self.squares = self.lagged = 0.0
        self.previous: float | None = None

    def add(self, vote: float) -> None:
        k = self.keep
        if self.previous is not None:
            self.lagged = k * self.lagged + vote * self.previous
        self.n, self.total, self.squares = k * self.n + 1.0, k * self.total + vote, k * self.squares + vote * vote
        self.previous = vote

    @property
    def votes(self) -> float:
        return self.n

    def effect(self) -> tuple[float, float]:
        """(d, se): the mean vote over its spread, and its standard error."""
        n = self.n
        mean = self.total / n
        variance = max(self.squares / n - mean * mean, 0.0)
        variance = (variance * n + 2.0) / (n + 2.0)  # two votes' worth of prior: a full vote's spread
        lag = self.lagged / max(n - 1.0, 1.0) - mean * mean
        r = float(np.clip(lag / max(self.squares / n - mean * mean, 1e-9), 0.0, 0.9))
        effective = max(n * (1.0 - r) / (1.0 + r), 1.0)
        return mean / float(np.sqrt(variance)), 1.0 / float(np.sqrt(effective))

    def state(self) -> list:
        return [self.n, self.total, self.squares, self.lagged, self.previous]

    def restore(self, state: list) -> None:
        self.n, self.total, self.squares, self.lagged = (float(v) for v in state[:4])
        self.previous = None if state[4] is None else float(state[4])


REACH = 2.0
"""C: the largest effect, in standard deviations, a voter is expected to show."""


BLIND = 0.5
"""The prior probability that a voter cannot tell the headings apart on a road (c_i = 0)."""


def likelihoods(d: float, se: float, misled: float) -> tuple[float, float]:
    """L(+1), L(-1): the density of a voter's effect ``d`` (known to ``se``) under each heading (module docstring)."""
    def uniform(low: float, high: float) -> float:  # d ~ N(c, se^2), c ~ U(low, high)
        return (_phi((d - low) / se) - _phi((d - high) / se)) / (high - low)

    ahead, behind = uniform(0.0, REACH), uniform(-REACH, 0.0)
    blind = math.exp(-0.5 * (d / se) ** 2) / (se * math.sqrt(2.0 * math.pi))  # c = 0
    seeing = (1.0 - misled) * ahead + misled * behind, (1.0 - misled) * behind + misled * ahead
    return BLIND * blind + (1.0 - BLIND) * seeing[0], BLIND * blind + (1.0 - BLIND) * seeing[1]


def _phi(x: float) -> float:
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


def pooled(effects: list[tuple[float, float]], misled: float, prior: float = 0.5) -> float:
    """P(opposite) from the voters' (d, se) and the prior P(opposite) (see the module docstring)."""
    log_odds = math.log(prior / (1.0 - prior))
    for d, se in effects:
        plus, minus = likelihoods(d, se, misled)
        log_odds += math.log(max(plus, 1e-300)) - math.log(max(minus, 1e-300))
    return 1.0 / (1.0 + math.exp(-float(np.clip(log_odds, -700.0, 700.0))))


class HeadingFilter:
    """P(same), P(opposite) over the frames of one traverse, from its voters' votes."""

    def __init__(self, config: HeadingConfig | None = None) -> None:
        self.config = config or HeadingConfig()
        memory = 1.0 / self.config.switch if self.config.switch > 0 else np.inf
        self.tallies = {name: VoteTally(memory) for name in VOTERS}
        self.reset()

    def reset(self) -> None:
        for tally in self.tallies.values():
            tally.reset()
        self._declared: Heading | None = None
        self._lean = 0.0
        self.belief = np.full(2, 0.5)

    def update(self, votes: dict[str, float], declared: Heading | None = None) -> tuple[Heading, float]:
        """Add one frame: each voter's vote (> 0 favours opposite; a voter missing or None did not vote) and the
        heading its camera declares. Returns the more probable heading and its probability."""
        cfg = self.config
        self._declared = declared
        if declared is not None and cfg.declared_prior >= 1.0:
            self.belief = _prior(declared, 1.0)
            return self.answer()
        for name, vote in votes.items():
            if vote is not None and name in self.tallies:
                self.tallies[name].add(float(np.clip(vote, -1.0, 1.0)))
        effects = [t.effect() for t in self.tallies.values() if t.votes >= MIN_VOTES]
        prior = 0.5 if declared is None else float(_prior(declared, cfg.declared_prior)[1])
        opposite = pooled(effects, cfg.misled, prior)
        self.belief = np.array([1.0 - opposite, opposite])
        # Even odds (no voter has voted long enough to count): the frame's own votes say which heading to answer
        # under, without making it any surer.
        self._lean = float(sum(v for v in votes.values() if v is not None))
        return self.answer()

    def answer(self) -> tuple[Heading, float]:
        best = int(np.argmax(self.belief))
        if self.belief[0] == self.belief[1] and self._lean != 0.0:
            best = HEADINGS.index("opposite" if self._lean > 0 else "same")
        return HEADINGS[best], float(self.belief[best])  # type: ignore[return-value]

    def state(self) -> dict:
        return {"belief": self.belief, "declared": self._declared, "lean": self._lean,
                "tallies": {name: t.state() for name, t in self.tallies.items()}}

    def restore(self, state: dict) -> None:
        self.reset()
        self.belief = np.asarray(state["belief"], dtype=np.float64)
        self._declared = state["declared"]
        self._lean = float(state.get("lean", 0.0))
        for name, saved in state.get("tallies", {}).items():
            if name in self.tallies:
                self.tallies[name].restore(saved)


def _prior(declared: Heading, strength: float) -> np.ndarray:
    belief = np.full(len(HEADINGS), 1.0 - strength)
    belief[HEADINGS.index(declared)] = strength
    return belief / belief.sum()
