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
        self._frames: deque[tuple[int, np.ndarray, np.ndarray | None]] = deque()  # (t, anchors, costs)
        self._t = -1
        # Live trajectories: anchor time, anchor reference, speed, and one cost per window column
        # (column i holds frame t - length + 1 + i).
        self._anchor_t = np.zeros(0, dtype=np.int64)
        self._anchor_r = np.zeros(0)
        self._speed = np.zeros(0)
        self._costs = np.zeros((0, self.length))

    @property
    def frames(self) -> int:
        return len(self._frames)

    def frame_cost(self, costs: np.ndarray | None, where: np.ndarray) -> np.ndarray:
        """cost_t at positions ``where``: the lowest cost within ``radius``; the penalty off the map or without costs."""
        out = np.full(where.shape, self.penalty, dtype=np.float64)
        if costs is None or len(costs) == 0:
            return out
        nearest = np.rint(where).astype(np.int64)
        on_map = (nearest >= 0) & (nearest < len(costs))
        best = np.full(where.shape, np.inf)
        for offset in range(-self.radius, self.radius + 1):
            idx = np.clip(nearest + offset, 0, len(costs) - 1)
            inside = on_map & (nearest + offset >= 0) & (nearest + offset < len(costs))
            best = np.where(inside, np.minimum(best, costs[idx]), best)
        out[on_map] = best[on_map]
        return out

    def update(self, anchors: np.ndarray, costs: np.ndarray | None, speeds: np.ndarray | None = None) -> SequenceResult:
        """Add the newest frame: its anchor references and its cost for every reference (or None).

        ``speeds`` optionally restricts the speeds of the trajectories this frame spawns
        (a tracker's plausible range); older trajectories keep theirs.
        """
        self._t += 1
        t = self._t
        anchors = np.unique(np.asarray(anchors, dtype=np.float64)) if costs is not None else np.zeros(0)
        self._frames.append((t, anchors, costs))
        if len(self._frames) > self.length:
            self._frames.popleft()
        oldest = self._frames[0][0]

        # Slide the window: drop trajectories anchored before it, shift the cost columns left.
        live = self._anchor_t >= oldest
        self._anchor_t, self._anchor_r, self._speed = self._anchor_t[live], self._anchor_r[live], self._speed[live]
        self._costs = np.concatenate([self._costs[live, 1:], np.full((int(live.sum()), 1), np.nan)], axis=1)
        # The newest frame's cost on every live trajectory.
        self._costs[:, -1] = self.frame_cost(costs, self._anchor_r + self._speed * (t - self._anchor_t))

        # Spawn the trajectories anchored at the newest frame, with their costs over the window.
        spawn = self.speeds if speeds is None or len(speeds) == 0 else np.asarray(speeds, dtype=np.float64)
        new_r = np.repeat(anchors, len(spawn))
        new_v = np.tile(spawn, len(anchors))
        new_costs = np.full((len(new_r), self.length), np.nan)
        for ft, _, fcosts in self._frames:
            new_costs[:, self.length - 1 - (t - ft)] = self.frame_cost(fcosts, new_r + new_v * (ft - t))
        self._anchor_t = np.concatenate([self._anchor_t, np.full(len(new_r), t)])
        self._anchor_r = np.concatenate([self._anchor_r, new_r])
        self._speed = np.concatenate([self._speed, new_v])
        self._costs = np.concatenate([self._costs, new_costs])
        return self._best()

    def scores(self) -> np.ndarray:
        """Mean cost of every live trajectory over the frames in the window."""
        window = self._costs[:, self.length - len(self._frames) :]
        return window.sum(axis=1) / window.shape[1]

    def positions(self) -> np.ndarray:
        """Position of every live trajectory at the newest frame."""
        return self._anchor_r + self._speed * (self._t - self._anchor_t)

    def _best(self) -> SequenceResult:
        scores = self.scores()
        ends = self.positions()
        if len(scores) == 0:
            return SequenceResult(np.nan, np.nan, np.inf, len(self._frames), np.zeros(0))
        # Lowest score; ties go to the slower trajectory, then the lower position, then the newer anchor.
        best = np.lexsort((-self._anchor_t, ends, self._speed, scores))[0]
        times = np.array([ft for ft, _, _ in self._frames])
        return SequenceResult(
            position=float(ends[best]),
            speed=float(self._speed[best]),
            score=float(scores[best]),
            frames=len(self._frames),
            trajectory=self._anchor_r[best] + self._speed[best] * (times - self._anchor_t[best]),
        )

    def runner_up(self, position: float, exclusion: float) -> float:
        """Best score among trajectories ending more than ``exclusion`` reference frames from ``position``."""
        far = np.abs(self.positions() - position) > exclusion
        return float(self.scores()[far].min()) if far.any() else np.inf

    def window(self, width: int) -> tuple[np.ndarray, np.ndarray]:
        """(frames, 2 * width + 1) costs around the best trajectory of each window frame, oldest first,
        and the reference index of each cell (-1 off the map): the picture of the sequence search."""
        best = self._best()
        costs = np.full((len(self._frames), 2 * width + 1), np.nan, dtype=np.float32)
        refs = np.full(costs.shape, -1, dtype=np.int64)
        for i, (_, _, fcosts) in enumerate(self._frames):
            if fcosts is None or not np.isfinite(best.trajectory[i]):
                continue
            centre = int(np.rint(best.trajectory[i]))
            cells = np.arange(centre - width, centre + width + 1)
            ok = (cells >= 0) & (cells < len(fcosts))
            costs[i, ok] = fcosts[cells[ok]]
            refs[i, ok] = cells[ok]
        return costs, refs
