"""The online sequence filter (paper Sec. III-D, after OpenSeqSLAM), causal and incremental.

Every frame t brings its top candidates (reference indices, the *anchors*)
and its cost for every reference, c_t(r): the single-frame score, locally
contrast-normalised over neighbouring references as in SeqSLAM
(:func:`contrast_normalise`), so that costs of different frames are
comparable and a reference that is close to everything does not win
everywhere. Lower is better; 0 is an average reference.

A *trajectory* is a straight line in the (frame, reference) plane through
one anchor (t_a, r_a) of a frame in the window, at a speed v from the
configured set (reference frames per query frame; 0 = stopped):
r(t) = r_a + v (t - t_a). On it, frame t costs

    cost_t = min { c_t(r) : |r - r(t)| <= radius },  or the penalty where r(t) is off the map,

and the trajectory's sequence score is the mean cost over the window's frames.
The answer is the lowest-scoring trajectory's position at the newest frame.

A trajectory's line is fixed in the plane, so each cost_t is looked up once:
a new frame adds one cost to every live trajectory and spawns anchors x
speeds new ones, whose costs over the window are looked up once. A step
costs O(L x anchors x speeds) look-ups for window length L, independent of the
number of reference frames, and reads no future frame.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


def contrast_normalise(scores: np.ndarray, window: int) -> np.ndarray:
    """SeqSLAM's local contrast enhancement of one frame's scores over the references:

        c(r) = (s(r) - mean_W(r) s) / std_W(r) s,   W(r) = the ``window`` + 1 references centred on r

    (clipped at the ends). Where the neighbourhood is flat the cost is 0.
    """
    s = np.asarray(scores, dtype=np.float64)
    n = len(s)
    half = window // 2
    lo = np.clip(np.arange(n) - half, 0, n)
    hi = np.clip(np.arange(n) + half + 1, 0, n)
    c1 = np.concatenate([[0.0], np.cumsum(s)])
    c2 = np.concatenate([[0.0], np.cumsum(s * s)])
    count = hi - lo
    mean = (c1[hi] - c1[lo]) / count
    var = np.maximum((c2[hi] - c2[lo]) / count - mean**2, 0.0)
    std = np.sqrt(var * count / np.maximum(count - 1, 1))  # sample std, as SeqSLAM
    out = np.zeros(n)
    ok = std > 1e-12 * max(1.0, float(np.abs(s).max(initial=0.0)))
    out[ok] = (s[ok] - mean[ok]) / std[ok]
    return out.astype(np.float32)


def signed(magnitudes: tuple[float, ...], stopped: bool) -> np.ndarray:
    """Speeds of both signs for the given magnitudes (a reference index rising or falling), plus 0
    (standing still) when ``stopped``; sorted."""
    values = {float(m) for m in magnitudes if m > 0} | {-float(m) for m in magnitudes if m > 0}
    if stopped:
        values.add(0.0)
    return np.asarray(sorted(values), dtype=np.float64)


class ReferenceNormaliser:
    """Standardises each reference's cost against its own history over the queries seen so far.

    A reference that is close to every query (a tunnel, a blank frame: a *hub*)
    has a low contrast-normalised cost for every query, and a trajectory that
    stays on it wins everywhere. Subtracting each reference's running mean cost
    and dividing by its running standard deviation removes that, causally.
    The running statistics start from mean 0 and standard deviation 1 (what
    contrast normalisation gives on average) with a weight of ``prior`` frames.
    """

    def __init__(self, prior: float) -> None:
        self.prior = float(prior)
        self.reset()

    def reset(self) -> None:
        self._n = self.prior
        self._sum: np.ndarray | None = None
        self._sumsq: np.ndarray | None = None

    def __call__(self, costs: np.ndarray) -> np.ndarray:
        c = costs.astype(np.float64)
        if self._sum is None or len(self._sum) != len(c):
            self._n = self.prior
            self._sum = np.zeros_like(c)
            self._sumsq = np.full_like(c, self.prior)
        self._n += 1.0
        self._sum += c
        self._sumsq += c * c
        mean = self._sum / self._n
        std = np.sqrt(np.maximum(self._sumsq / self._n - mean**2, 1e-6))
        return ((c - mean) / std).astype(np.float32)


@dataclass
class SequenceResult:
    position: float
    """Position of the best trajectory at the newest frame, in reference frames (fractional)."""
    speed: float
    score: float
    """Mean cost along the best trajectory (lower is better)."""
    frames: int
    """Frames in the window."""
    trajectory: np.ndarray
    """(frames,) the best trajectory's reference position at each window frame, oldest first."""


class SequenceFilter:
    """Rolling window of the last ``length`` frames, scoring straight trajectories through their anchors."""

    def __init__(self, length: int, speeds: tuple[float, ...], radius: int, penalty: float) -> None:
        if length < 1 or not speeds:
            raise ValueError("the sequence window needs at least one frame and one speed")
        self.length = length
        self.speeds = np.asarray(sorted(set(speeds)), dtype=np.float64)
        self.radius = int(radius)
        self.penalty = float(penalty)
        self.reset()

    def reset(self) -> None:
        self._t = -1
        self._times: deque[int] = deque()
        self._ring: np.ndarray | None = None  # (length, N) costs of the window's frames; row = t % length
        # Live trajectories: anchor time, anchor reference, speed, and one cost per window column
        # (column i holds frame t - length + 1 + i).
        self._anchor_t = np.zeros(0, dtype=np.int64)
        self._anchor_r = np.zeros(0)
        self._speed = np.zeros(0)
        self._costs = np.zeros((0, self.length))
        self._best_result: SequenceResult | None = None

    @property
    def frames(self) -> int:
        return len(self._times)

    def _lookup(self, times: np.ndarray, where: np.ndarray) -> np.ndarray:
        """cost_t at positions ``where`` of frames ``times`` (broadcast together): the lowest cost within
        ``radius``; the penalty off the map or for a frame without costs."""
        assert self._ring is not None
        n = self._ring.shape[1]
        rows = np.broadcast_to(times % self.length, where.shape)
        nearest = np.rint(where).astype(np.int64)
        best = np.full(where.shape, np.inf)
        for offset in range(-self.radius, self.radius + 1):
            cells = nearest + offset
            inside = (cells >= 0) & (cells < n)
            best = np.where(inside, np.fmin(best, self._ring[rows, np.clip(cells, 0, n - 1)]), best)
        return np.where(np.isfinite(best), best, self.penalty)

    def update(self, anchors: np.ndarray, costs: np.ndarray | None, speeds: np.ndarray | None = None) -> SequenceResult:
        """Add the newest frame: its anchor references and its cost for every reference (or None).

        ``speeds`` optionally restricts the speeds of the trajectories this frame spawns
        (a tracker's plausible range); older trajectories keep theirs.
        """
        self._t += 1
        t = self._t
        if costs is not None and self._ring is None:
            self._ring = np.full((self.length, len(costs)), np.nan, dtype=np.float32)
        if self._ring is not None:
            self._ring[t % self.length] = np.nan if costs is None else costs
        anchors = np.unique(np.asarray(anchors, dtype=np.float64)) if costs is not None else np.zeros(0)
        self._times.append(t)
        if len(self._times) > self.length:
            self._times.popleft()
        oldest = self._times[0]

        # Slide the window: drop trajectories anchored before it, shift the cost columns left.
        live = self._anchor_t >= oldest
        self._anchor_t, self._anchor_r, self._speed = self._anchor_t[live], self._anchor_r[live], self._speed[live]
        self._costs = np.concatenate([self._costs[live, 1:], np.full((int(live.sum()), 1), np.nan)], axis=1)
        if self._ring is not None and len(self._anchor_t):
            # The newest frame's cost on every live trajectory.
            self._costs[:, -1] = self._lookup(np.array(t), self._anchor_r + self._speed * (t - self._anchor_t))

        # Spawn the trajectories anchored at the newest frame, with their costs over the window.
        spawn = self.speeds if speeds is None or len(speeds) == 0 else np.asarray(speeds, dtype=np.float64)
        new_r = np.repeat(anchors, len(spawn))
        new_v = np.tile(spawn, len(anchors))
        new_costs = np.full((len(new_r), self.length), np.nan)
        if len(new_r):
            times = np.asarray(self._times)
            new_costs[:, self.length - len(times) :] = self._lookup(
                times[None, :], new_r[:, None] + new_v[:, None] * (times[None, :] - t)
            )
        self._anchor_t = np.concatenate([self._anchor_t, np.full(len(new_r), t)])
        self._anchor_r = np.concatenate([self._anchor_r, new_r])
        self._speed = np.concatenate([self._speed, new_v])
        self._costs = np.concatenate([self._costs, new_costs])
        self._best_result = self._best()
        return self._best_result

    def keep_direction(self, sign: int) -> None:
        """Drop the live trajectories whose reference index runs against ``sign`` (+1 rising, -1 falling):
        once the direction of travel is known they are no longer plausible."""
        keep = self._speed * sign >= 0
        self._anchor_t, self._anchor_r = self._anchor_t[keep], self._anchor_r[keep]
        self._speed, self._costs = self._speed[keep], self._costs[keep]

    def scores(self) -> np.ndarray:
        """Mean cost of every live trajectory over the frames in the window."""
        window = self._costs[:, self.length - len(self._times) :]
        return window.sum(axis=1) / window.shape[1]

    def positions(self) -> np.ndarray:
        """Position of every live trajectory at the newest frame."""
        return self._anchor_r + self._speed * (self._t - self._anchor_t)

    def _best(self) -> SequenceResult:
        scores = self.scores()
        if len(scores) == 0:
            return SequenceResult(np.nan, np.nan, np.inf, len(self._times), np.full(len(self._times), np.nan))
        ends = self.positions()
        # Lowest score; ties go to the slower trajectory, then the lower position, then the newer anchor,
        # then a rising reference index.
        tied = np.flatnonzero(scores == scores.min())
        speed = self._speed[tied]
        best = tied[np.lexsort((-speed, -self._anchor_t[tied], ends[tied], np.abs(speed)))[0]]
        times = np.asarray(self._times)
        return SequenceResult(
            position=float(ends[best]),
            speed=float(self._speed[best]),
            score=float(scores[best]),
            frames=len(self._times),
            trajectory=self._anchor_r[best] + self._speed[best] * (times - self._anchor_t[best]),
        )

    def runner_up(self, position: float, exclusion: float) -> float:
        """Best score among trajectories ending more than ``exclusion`` reference frames from ``position``."""
        far = np.abs(self.positions() - position) > exclusion
        return float(self.scores()[far].min()) if far.any() else np.inf

    def window(self, width: int) -> tuple[np.ndarray, np.ndarray]:
        """(frames, 2 * width + 1) costs around the best trajectory at each window frame, oldest first,
        and the reference index of each cell (-1 off the map): the picture of the sequence search."""
        frames = len(self._times)
        costs = np.full((frames, 2 * width + 1), np.nan, dtype=np.float32)
        refs = np.full(costs.shape, -1, dtype=np.int64)
        best = self._best_result
        if best is None or self._ring is None or not np.isfinite(best.trajectory).all():
            return costs, refs
        n = self._ring.shape[1]
        times = np.asarray(self._times)
        cells = np.rint(best.trajectory).astype(np.int64)[:, None] + np.arange(-width, width + 1)[None, :]
        inside = (cells >= 0) & (cells < n)
        values = self._ring[np.broadcast_to((times % self.length)[:, None], cells.shape), np.clip(cells, 0, n - 1)]
        costs[inside] = values[inside]
        refs[inside] = cells[inside]
        return costs, refs
