"""The tail of wrong answers' leads, modelled with extreme value theory (numpy only).

A wrong answer is the best of the N wrong places a frame is compared with, and its margin is its lead
over the best of the others: the spacing between the two largest of N wrong scores. For wrong scores whose
tail is light or exponential (normal, Gumbel, logistic, any sum of many costs), the Renyi representation of
extreme order statistics makes the normalised spacings of the k largest,

    i * (X_(i) - X_(i+1)),   i = 1 .. k - 1,

independent draws of one exponential law, whose scale is the tail scale of the wrong scores where their best
lies. So every frame matched against the map with its neighbourhood excluded gives k - 1 draws of what a wrong
answer's lead looks like, not one. Frames differ in that scale; a mixture of exponentials over scales is a
generalised Pareto law with shape >= 0, which is what :func:`fit_tail` fits, by maximum likelihood.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REACH = 10.0
"""How far beyond its sample a fitted tail is believed: a probability below 1 / (REACH (n + 1)) is never
claimed from n draws. It keeps a fit on a handful of draws from promising what only many can show."""


@dataclass(frozen=True)
class Tail:
    """Generalised Pareto law of wrong answers' leads: P(lead > x) = (1 + shape x / scale) ^ (-1 / shape)."""

    shape: float
    """>= 0: 0 is the exponential law, larger a heavier tail."""
    scale: float
    draws: int
    """Draws it was fitted on."""

    def survival(self, x: float) -> float:
        """P(a wrong answer's lead exceeds x), on the safe side: with the scale at its one-sided 95 % upper
        bound, so that a tail fitted on few draws claims less (the scale's standard error is scale / sqrt(n))."""
        if self.draws == 0 or not self.scale > 0:
            return 1.0
        if not x > 0:
            return 1.0
        if not np.isfinite(x):
            return 0.0
        scale = self.scale * (1.0 + 1.645 / np.sqrt(self.draws))
        if self.shape < 1e-9:
            return float(np.exp(-x / scale))
        return float(np.exp(-np.log1p(self.shape * x / scale) / self.shape))

    @property
    def ceiling(self) -> float:
        """The highest confidence these draws can support (:data:`REACH`)."""
        return 1.0 - 1.0 / (REACH * (self.draws + 1))

    def confidence(self, lead: float) -> float:
        """1 - P(a wrong answer leads by at least ``lead``), at most :attr:`ceiling`."""
        return min(1.0 - self.survival(lead), self.ceiling)

    def draws_for(self, confidence: float) -> int:
        """Draws needed before :attr:`ceiling` reaches ``confidence``."""
        return int(np.ceil(1.0 / (REACH * (1.0 - confidence)))) - 1 if confidence < 1 else np.iinfo(np.int64).max


def fit_tail(draws: np.ndarray) -> Tail:
    """Maximum-likelihood generalised Pareto law (shape >= 0, location 0) of ``draws`` (finite, >= 0).

    Profile likelihood in theta = shape / scale (Grimshaw): for a given theta the shape's estimate is the mean
    of log(1 + theta x), and the log-likelihood -n (log scale + shape + 1); theta = 0 is the exponential law.
    """
    x = np.asarray(draws, dtype=np.float64)
    x = x[np.isfinite(x) & (x >= 0)]
    n = len(x)
    mean = float(x.mean()) if n else 0.0
    if n == 0 or mean <= 0:
        return Tail(0.0, 0.0, n)
    best = (-(np.log(mean) + 1.0), 0.0, mean)  # the exponential law
    for theta in np.geomspace(1e-3, 1e3, 241) / mean:
        shape = float(np.log1p(theta * x).mean())
        scale = shape / float(theta)
        loglik = -(np.log(scale) + shape + 1.0)
        if loglik > best[0]:
            best = (loglik, shape, scale)
    return Tail(best[1], best[2], n)


def leads(values: np.ndarray, positions: np.ndarray, exclusion: float, places: int) -> np.ndarray:
    """Normalised spacings i (v_(i+1) - v_(i)) of the ``places`` best (lowest) ``values`` at distinct places:
    each next best more than ``exclusion`` from every one before it, as a runner-up is. The first is the
    best's margin over the runner-up. Non-finite values and positions are left out."""
    v = np.asarray(values, dtype=np.float64)
    p = np.asarray(positions, dtype=np.float64)
    keep = np.isfinite(v) & np.isfinite(p)
    v, p = v[keep], p[keep]
    best: list[float] = []
    while len(best) < places and len(v):
        i = int(np.argmin(v))
        best.append(float(v[i]))
        far = np.abs(p - p[i]) > exclusion
        v, p = v[far], p[far]
    return np.arange(1, len(best)) * np.diff(np.asarray(best))
