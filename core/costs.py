"""The sequence filter's costs, computed only where it looks (see :mod:`lostx.core.sequence`).

A frame's single-frame score of map frame r, s(r) (:class:`MapScores`, lower is better), becomes
its cost in two steps, both computed for the references the filter looks up and for no other:

1. SeqSLAM's local contrast enhancement over the ``window`` + 1 references centred on r (clipped at
   the ends of the map)::

       c(r) = (s(r) - mean_W(r) s) / std_W(r) s        (0 where the neighbourhood is flat)

2. Hub suppression: c(r) standardised against r's own running mean and standard deviation over
   the costs computed for r so far (a prior of mean 0 and standard deviation 1 weighing ``prior``
   frames). A reference that is close to every query (a tunnel, a blank frame) is looked up again
   and again, its running mean falls, and it stops winning everywhere.

What a step costs depends on the number of trajectories, never on the map size: the scores of a
frame are computed for the looked-up references and their contrast neighbourhoods, once each, and
kept while the frame is in the window.
"""

from __future__ import annotations

import time
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

    distances: Callable[[np.ndarray], np.ndarray]
    """The exact descriptor distance of the query to the map frames given."""
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
        return cls(lambda refs: scores[refs], len(scores))

    def at(self, refs: np.ndarray) -> np.ndarray:
        """(m,) float64 scores of the map frames ``refs``."""
        refs = np.asarray(refs, dtype=np.int64)
        if self.constant is not None:
            out = np.full(len(refs), self.constant, dtype=np.float64)
        else:
            out = np.asarray(self.distances(refs), dtype=np.float64) * self.factor
        if len(self.known):
            pos = np.clip(np.searchsorted(self.known, refs), 0, len(self.known) - 1)
            hit = self.known[pos] == refs
            out[hit] = self.known_scores[pos[hit]]
        if self.removed is not None:
            out[(refs >= self.removed.start) & (refs < self.removed.stop)] = self.removed_score
        return out


class HubNormaliser:
    """Each reference's running cost statistics, over the costs computed for it so far.

    Dense arrays over the map, allocated as zeros: the operating system commits their pages only
    where references are looked up, so a long map costs memory only where the traverse has been.
    """

    def __init__(self, n_refs: int, prior: float) -> None:
        self.prior = float(prior)
        self._count = np.zeros(n_refs)
        self._sum = np.zeros(n_refs)
        self._sumsq = np.zeros(n_refs)  # beyond the prior's (variance 1 over ``prior`` frames)

    def __call__(self, refs: np.ndarray, costs: np.ndarray) -> np.ndarray:
        """Add ``costs`` (of references ``refs``, which may repeat: one frame each) to the statistics and
        return them standardised; costs computed together are standardised with all of them counted.
        NaN (no cost) passes through and counts for nothing."""
        ok = np.isfinite(costs)
        np.add.at(self._count, refs[ok], 1.0)
        np.add.at(self._sum, refs[ok], costs[ok])
        np.add.at(self._sumsq, refs[ok], costs[ok] ** 2)
        n = self.prior + self._count[refs]
        mean = self._sum[refs] / n
        std = np.sqrt(np.maximum((self.prior + self._sumsq[refs]) / n - mean**2, 1e-6))
        return (costs - mean) / std


class _Table:
    """float64 values under sorted int64 keys, with insertion and removal of a prefix."""

    def __init__(self) -> None:
        self.keys = _EMPTY
        self.values = np.zeros(0)

    def find(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions of ``keys`` and whether each is present."""
        pos = np.searchsorted(self.keys, keys)
        present = pos < len(self.keys)
        present[present] = self.keys[pos[present]] == keys[present]
        return pos, present

    def insert(self, keys: np.ndarray, values: np.ndarray) -> None:
        """Add sorted keys that are not present."""
        if len(keys):
            at = np.searchsorted(self.keys, keys)
            self.keys = np.insert(self.keys, at, keys)
            self.values = np.insert(self.values, at, values)

    def drop_below(self, key: int) -> None:
        cut = int(np.searchsorted(self.keys, key))
        self.keys, self.values = self.keys[cut:], self.values[cut:]


class LookedUpCosts:
    """The costs of the frames in the sequence window, computed on the first look-up and kept.

    Keys are ``t * n_refs + r`` (frame t, reference r), so that one sorted table holds the whole window
    and the frames leaving it are a prefix.
    """

    def __init__(self, n_refs: int, contrast_window: int, hub_prior: float) -> None:
        self.n_refs = int(n_refs)
        self.half = int(contrast_window) // 2
        self.hub_prior = float(hub_prior)
        self.computed = 0
        """Scores computed so far (each a descriptor distance): what the look-ups cost."""
        self.seconds = 0.0
        """Time spent computing costs so far."""
        self.reset()

    def reset(self) -> None:
        self.hubs = HubNormaliser(self.n_refs, self.hub_prior)
        self._frames: dict[int, MapScores | None] = {}
        self._scores = _Table()
        self._costs = _Table()

    def add(self, t: int, scores: MapScores | None) -> None:
        self._frames[t] = scores

    def drop_before(self, t: int) -> None:
        for old in [k for k in self._frames if k < t]:
            del self._frames[old]
        self._scores.drop_below(t * self.n_refs)
        self._costs.drop_below(t * self.n_refs)

    def known(self, times: np.ndarray, refs: np.ndarray) -> np.ndarray:
        """The costs already computed at (times, refs) (broadcast together; refs on the map), NaN elsewhere:
        a picture of what was looked up, which computes nothing."""
        keys = self._keys(times, refs)
        pos, present = self._costs.find(keys.ravel())
        out = np.full(keys.size, np.nan)
        out[present] = self._costs.values[pos[present]]
        return out.reshape(keys.shape)

    def _keys(self, times: np.ndarray, refs: np.ndarray) -> np.ndarray:
        return np.asarray(times, dtype=np.int64) * self.n_refs + np.asarray(refs, dtype=np.int64)

    def at(self, times: np.ndarray, refs: np.ndarray) -> np.ndarray:
        """Costs at (times, refs), broadcast together, refs on the map; NaN for a frame without scores and a
        removed reference."""
        keys = self._keys(times, refs)
        unique, inverse = np.unique(keys.ravel(), return_inverse=True)
        pos, present = self._costs.find(unique)
        if not present.all():
            start = time.perf_counter()
            missing = unique[~present]
            self._costs.insert(missing, self._compute(missing))
            pos, present = self._costs.find(unique)
            self.seconds += time.perf_counter() - start
        return self._costs.values[pos][inverse].reshape(np.shape(keys))

    def _compute(self, keys: np.ndarray) -> np.ndarray:
        """Contrast-normalised, hub-suppressed costs at sorted keys not computed before."""
        n, h = self.n_refs, self.half
        t, r = np.divmod(keys, n)
        base = t * n
        lo = base + np.maximum(r - h, 0)
        hi = base + np.minimum(r + h, n - 1)  # inclusive
        cover = _union(lo, hi)  # every score a contrast neighbourhood needs, sorted
        contrast = local_contrast(cover, self._scores_at(cover), lo, hi, keys)
        return self.hubs(r, contrast.astype(np.float32).astype(np.float64))

    def _scores_at(self, keys: np.ndarray) -> np.ndarray:
        pos, present = self._scores.find(keys)
        out = np.full(len(keys), np.nan)
        out[present] = self._scores.values[pos[present]]
        missing = keys[~present]
        if len(missing):
            values = np.full(len(missing), np.nan)
            t, r = np.divmod(missing, self.n_refs)
            # One call per frame (at most the window's length): each frame has its own query.
            bounds = np.flatnonzero(np.diff(t)) + 1
            for lo, hi in zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [len(t)]])):
                source = self._frames.get(int(t[lo]))
                if source is not None:
                    values[lo:hi] = source.at(r[lo:hi])
            self.computed += len(missing)
            self._scores.insert(missing, values)
            out[~present] = values
        return out


def local_contrast(cover: np.ndarray, scores: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   at: np.ndarray) -> np.ndarray:
    """SeqSLAM's contrast enhancement at the sorted points ``at`` over their neighbourhoods [lo, hi]
    (inclusive), from the ``scores`` on ``cover``: sorted points holding every neighbourhood whole.

        c = (s - mean) / std        (sample std; 0 where the neighbourhood is flat, NaN where s is)

    Window sums come from prefix sums over ``cover``, so a point costs two binary searches.
    """
    valid = np.isfinite(scores)
    zero = np.zeros(1)
    s1 = np.concatenate([zero, np.cumsum(np.where(valid, scores, 0.0))])
    s2 = np.concatenate([zero, np.cumsum(np.where(valid, scores * scores, 0.0))])
    sc = np.concatenate([zero, np.cumsum(valid)])
    a = np.searchsorted(cover, lo)
    b = np.searchsorted(cover, hi, side="right")
    count = sc[b] - sc[a]
    mean = (s1[b] - s1[a]) / np.maximum(count, 1)
    var = np.maximum((s2[b] - s2[a]) / np.maximum(count, 1) - mean**2, 0.0)
    std = np.sqrt(var * count / np.maximum(count - 1, 1))  # sample std, as SeqSLAM
    own = scores[np.searchsorted(cover, at)]
    flat = ~(std > 1e-12 * np.maximum(1.0, np.abs(own)))
    contrast = np.where(flat, 0.0, (own - mean) / np.where(flat, 1.0, std))
    contrast[~np.isfinite(own)] = np.nan
    return contrast


def _union(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The sorted integers in the union of the inclusive intervals [lo, hi] (lo and hi non-decreasing)."""
    if len(lo) == 0:
        return _EMPTY
    reach = np.maximum.accumulate(hi)
    starts = np.concatenate([[True], lo[1:] > reach[:-1] + 1])
    first = lo[starts]
    last = np.concatenate([reach[np.flatnonzero(starts)[1:] - 1], [reach[-1]]])
    lengths = last - first + 1
    offsets = np.repeat(first - np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths)
    return np.arange(int(lengths.sum()), dtype=np.int64) + offsets
