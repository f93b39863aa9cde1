"""The online sequence filter (paper Sec. III-D, after OpenSeqSLAM), causal and incremental.

Every frame t brings its single-frame scores, its verified candidates and the nearest map frames of
its search. Its cost at reference r, c_t(r), is the score locally contrast-normalised over neighbouring
references as in SeqSLAM and standardised against r's own running statistics (hub suppression), so that
costs of different frames are comparable and a reference that is close to everything does not win
everywhere; lower is better, 0 is an average reference. Where the costs come from
(:mod:`lostx.core.match.costs`): computed for every map frame as each frame arrives, or looked up where the
filter looks, never for the whole map (``sequence.costs``: on large maps).

A *trajectory* is a straight line in the (frame, reference) plane through
one anchor (t_a, r_a) of a frame in the window, at a speed v from the
configured set (reference frames per query frame; 0 = stopped):
r(t) = r_a + v (t - t_a). Where the map and the frames have motion, the line is straight in the distance
travelled instead: the map's route position P(r) (metres travelled along it) follows the frames' progress q_t
(metres advanced along their camera's axis), P(r(t)) = P(r_a) + v (q_t - q_{t_a}), v in metres per metre, so
that turns, stops and changes of speed do not bend it. On it, frame t costs

    cost_t = min { c_t(r) : |r - r(t)| <= radius },  or the penalty where r(t) is off the map,

and the trajectory's sequence score is its mean cost over the window's n frames, or, where that is lower, the
cost of entering the map: a trajectory that lies off the map before frame e_i (the vehicle came from outside
it) pays J (``switch``) for those frames, which count at the lowest sum any trajectory had over them, not as
average ones:

    S_i = min( sum_t cost_t(i),  min_j sum_{t<e_i} cost_t(j) + J + sum_{t>=e_i} cost_t(i) ) / n

so that a look-alike that led while the vehicle was still off the map keeps the answer only until the trajectory
entering the map has out-scored it by J since, not until the look-alike's frames have left the window (J
infinite: each trajectory's own mean, as SeqSLAM).
The answer is the lowest-scoring trajectory's position at the newest frame; the confidence's margin and the
direction's vote weigh the trajectories' own means (the borrowed frames say nothing for a place).

A frame's anchors are its candidates and its ``anchors`` lowest costs: over the whole map where every
cost is known, else among those around the nearest map frames of its search and where the live
trajectories pass.

A trajectory's line is fixed in the plane, so each cost_t is looked up once:
a new frame adds one cost to every live trajectory and spawns anchors x
speeds new ones, whose costs over the window are looked up once. A step
costs O(L x anchors x speeds) look-ups for window length L, independent of the
number of reference frames, and reads no future frame.

Kept whole, the trajectories are those anchored in the window: anchors x speeds x L of them. Bounded (the design's
filter on a city map, where costs are looked up), at most ``bound`` are live: a new anchor that falls on a live
trajectory of its speed (within half a reference frame at the newest frame) *supports* it instead of spawning a
copy, a trajectory lives until a window has passed without support (however old its first anchor), and beyond
``bound`` the best-scoring ones are kept. Only anchors that fall on no live trajectory look their window up, so a
step reads one cost per live trajectory and the pasts of the new ones: bounded by ``bound``, the anchors, the speeds
and the window, not by the map.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..errors import StateError


def signed(magnitudes: tuple[float, ...], stopped: bool) -> np.ndarray:
    """Speeds of both signs for the given magnitudes (a reference index rising or falling), plus 0
    (standing still) when ``stopped``; sorted."""
    values = {float(m) for m in magnitudes if m > 0} | {-float(m) for m in magnitudes if m > 0}
    if stopped:
        values.add(0.0)
    return np.asarray(sorted(values), dtype=np.float64)


class WindowCosts(Protocol):
    """The costs of the frames in the window, looked up by (frame, reference) (:mod:`lostx.core.match.costs`)."""

    n_refs: int
    seconds: float

    def add(self, t: int, scores: Any) -> None:
        """Frame t's scores or costs (None: a frame without costs); it replaces frame t - length."""

    def at(self, times: np.ndarray, refs: np.ndarray) -> np.ndarray:
        """Costs at (times, refs) broadcast together, refs on the map; NaN where there is none."""

    def known(self, times: np.ndarray, refs: np.ndarray) -> np.ndarray:
        """The costs known so far at (times, refs), NaN elsewhere; computes nothing."""

    def lowest(self, t: int, k: int, near: np.ndarray) -> np.ndarray:
        """The references of frame t's k lowest costs (among ``near`` where not every cost is known)."""

    def reset(self) -> None:
        """Forget every frame."""

    def state(self) -> dict:
        """What carries from frame to frame, as plain values and arrays."""

    def restore(self, state: dict) -> None:
        """Continue from :meth:`state`."""


@dataclass
class SequenceResult:
    position: float
    """Position of the best trajectory at the newest frame, in reference frames (fractional)."""
    speed: float
    """Reference frames per query frame at the newest frame (negative: the index falling)."""
    score: float
    """The best trajectory's sequence score (lower is better; :func:`window_scores`)."""
    frames: int
    """Frames in the window."""
    trajectory: np.ndarray
    """(frames,) the best trajectory's reference position at each window frame, oldest first."""
    mean: float
    """Its own mean cost over the window's frames: its evidence against other places (:meth:`SequenceFilter.means`)."""


class SequenceFilter:
    """Rolling window of the last ``length`` frames, scoring straight trajectories through their anchors."""

    def __init__(self, length: int, speeds: tuple[float, ...], radius: int, penalty: float, costs: WindowCosts,
                 anchors: int = 0, neighbourhood: int = 0, route: np.ndarray | None = None,
                 reach: float | None = None, spacing: float = 0.0, switch: float = np.inf, bound: int = 0) -> None:
        """``costs``: where the window's costs come from; ``anchors``: how many of a frame's lowest costs
        anchor trajectories besides its candidates; ``neighbourhood``: how far around each seed (a nearest
        map frame of the frame's search) they are looked for, where not every cost is known. ``route``: the
        map's route position P(r) of every map frame (rising), to follow the distance travelled (each
        :meth:`update` then gives the frame's progress); None: trajectories straight in frames. ``reach``: the
        window then holds the frames of the last this many metres (at most ``length`` of them), ``spacing``
        metres apart at least but for the newest (a frame nearer the one before the newest takes the newest's
        place: at a high frame rate, or stopped, the window keeps its reach). ``switch``: J, what a trajectory
        pays for entering the map within the window (:func:`window_scores`). ``bound``: at most this many live
        trajectories, followed as long as anchors fall on them (0: every trajectory anchored in the window; see the
        module's docstring)."""
        if length < 1 or not speeds:
            raise ValueError("the sequence window needs at least one frame and one speed")
        self.length = length
        self.speeds = np.asarray(sorted(set(speeds)), dtype=np.float64)
        self.radius = int(radius)
        self.penalty = float(penalty)
        self.costs = costs
        self.anchors = int(anchors)
        self.neighbourhood = int(neighbourhood)
        self.route = None if route is None else np.asarray(route, dtype=np.float64)
        self.reach = reach
        self.spacing = float(spacing)
        self.switch = float(switch)
        self.bound = int(bound)
        self.reset()

    def reset(self) -> None:
        self._t = -1
        self._times: deque[int] = deque()
        self._progress: deque[float] = deque()
        self.costs.reset()
        # Live trajectories: anchor time, anchor progress and route position, speed, and one cost per window
        # column (column i holds frame t - length + 1 + i).
        self._anchor_t = np.zeros(0, dtype=np.int64)
        self._anchor_q = np.zeros(0)
        self._anchor_r = np.zeros(0)
        self._anchor_p = np.zeros(0)  # the anchors' route positions P(r_a), fixed as r_a is
        self._speed = np.zeros(0)
        self._support = np.zeros(0, dtype=np.int64)  # the newest frame anchoring each trajectory (or falling on it)
        self._costs = np.zeros((0, self.length))
        self._best_result: SequenceResult | None = None
        self._changed()

    def _changed(self) -> None:
        """The trajectories or their costs changed: their scores and positions are computed again when next asked
        (once a frame, however many of the frame's decisions ask)."""
        self._scores: np.ndarray | None = None
        self._means: np.ndarray | None = None
        self._ends: np.ndarray | None = None

    @property
    def frames(self) -> int:
        return len(self._times)

    @property
    def full(self) -> bool:
        """The window holds ``length`` frames, or (following the distance travelled) spans ``reach`` metres."""
        if len(self._times) >= self.length:
            return True
        return (self.route is not None and self.reach is not None and len(self._progress) > 1
                and abs(self._progress[-1] - self._progress[0]) >= self.reach)

    def _lookup(self, times: np.ndarray, where: np.ndarray) -> np.ndarray:
        """cost_t at positions ``where`` of frames ``times`` (broadcast together): the lowest cost within
        ``radius``; the penalty off the map or where a frame has no cost."""
        n = self.costs.n_refs
        times = np.broadcast_to(times, where.shape)
        nearest = np.rint(np.where(np.isfinite(where), where, -1.0 - self.radius - n)).astype(np.int64)
        best = np.full(where.shape, np.inf)
        for offset in range(-self.radius, self.radius + 1):
            cells = nearest + offset
            inside = (cells >= 0) & (cells < n)
            values = np.full(where.shape, np.nan)
            values[inside] = self.costs.at(times[inside], cells[inside])
            best = np.fmin(best, values)
        return np.where(np.isfinite(best), best, self.penalty)

    def update(self, scores: Any, candidates: np.ndarray, seeds: np.ndarray | None = None,
               speeds: np.ndarray | None = None, progress: float | None = None) -> SequenceResult:
        """Add the newest frame: its scores (what :attr:`costs` takes; None for a frame without), its
        candidates (each anchors trajectories) and its seeds (map frames around which its lowest costs are
        looked for, besides where the live trajectories pass); ``progress``: its metres along its camera's
        axis, following the distance travelled (a ``route`` was given).

        ``speeds`` optionally restricts the speeds of the trajectories this frame spawns
        (a tracker's plausible range); older trajectories keep theirs.
        """
        if self.route is not None and progress is None:
            raise ValueError("a sequence filter following the distance travelled needs each frame's progress")
        self._changed()
        if self._replaces(progress):
            # The newest frame is still within ``spacing`` of the one before it: the new frame takes its column (and
            # its trajectories' anchors), so that the window keeps its reach in metres at any frame rate or speed.
            t = self._t
            self.costs.add(t, scores)
            self._progress[-1] = float(progress)  # type: ignore[arg-type]
            self._keep(self._anchor_t != t)
        else:
            self._t += 1
            t = self._t
            self.costs.add(t, scores)
            self._times.append(t)
            self._progress.append(float(t) if self.route is None else float(progress))  # type: ignore[arg-type]
            if len(self._times) > self.length:
                self._times.popleft()
                self._progress.popleft()
            # Slide the window: drop trajectories no frame in it anchored, shift the cost columns left.
            self._keep(self._support >= self._times[0])
            self._costs = np.concatenate([self._costs[:, 1:], np.full((len(self._costs), 1), np.nan)], axis=1)
        ends = self._positions()
        if len(self._anchor_t):
            # The newest frame's cost on every live trajectory.
            self._costs[:, -1] = self._lookup(np.array(t), ends)
        anchors = self._new_anchors(t, candidates, seeds, ends) if scores is not None else np.zeros(0)

        # Spawn the trajectories anchored at the newest frame, with their costs over the window.
        spawn = self.speeds if speeds is None or len(speeds) == 0 else np.asarray(speeds, dtype=np.float64)
        new_r = np.repeat(anchors, len(spawn))
        new_v = np.tile(spawn, len(anchors))
        if self.bound:
            fresh = self._supports(t, new_r, new_v, ends)
            new_r, new_v = new_r[fresh], new_v[fresh]
        new_costs = np.full((len(new_r), self.length), np.nan)
        new_p = self._on_route(new_r)
        new_ends = new_r
        q = self._progress[-1]
        if len(new_r):
            times = np.asarray(self._times)
            along = self._at_route(new_p[:, None] + new_v[:, None] * (np.asarray(self._progress) - q))
            new_costs[:, self.length - len(times) :] = self._lookup(times[None, :], along)
            new_ends = along[:, -1]  # their positions at the newest frame, as positions() computes them
        self._anchor_t = np.concatenate([self._anchor_t, np.full(len(new_r), t)])
        self._anchor_q = np.concatenate([self._anchor_q, np.full(len(new_r), q)])
        self._anchor_r = np.concatenate([self._anchor_r, new_r])
        self._anchor_p = np.concatenate([self._anchor_p, new_p])
        self._speed = np.concatenate([self._speed, new_v])
        self._support = np.concatenate([self._support, np.full(len(new_r), t)])
        self._costs = np.concatenate([self._costs, new_costs])
        self._changed()
        self._ends = _read_only(np.concatenate([ends, new_ends]))
        if self.bound and len(self._speed) > self.bound:
            self._prune()
        self._best_result = self._best()
        return self._best_result

    def _replaces(self, progress: float | None) -> bool:
        """Whether a frame at ``progress`` takes the newest frame's place in the window (following the distance)."""
        return (self.route is not None and self.spacing > 0 and len(self._progress) >= 2
                and abs(float(progress) - self._progress[-2]) < self.spacing)  # type: ignore[arg-type]

    def _keep(self, live: np.ndarray) -> None:
        """Keep only the trajectories ``live``."""
        self._anchor_t, self._anchor_r, self._speed = self._anchor_t[live], self._anchor_r[live], self._speed[live]
        self._anchor_q, self._anchor_p, self._costs = self._anchor_q[live], self._anchor_p[live], self._costs[live]
        self._support = self._support[live]
        self._changed()

    def _supports(self, t: int, refs: np.ndarray, speeds: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """Which of the new anchors' trajectories (``refs``, ``speeds``) lie on no live trajectory of the same speed
        (one passing within half a reference frame of the anchor at frame t, live ones at ``ends``); the live ones
        they fall on are supported by frame t and followed for another window."""
        _, kind = np.unique(np.concatenate([self._speed, speeds]), return_inverse=True)
        kinds = int(kind.max(initial=0)) + 1
        on_map = np.isfinite(ends)
        live = np.rint(ends[on_map]).astype(np.int64) * kinds + kind[: len(ends)][on_map]
        new = np.rint(refs).astype(np.int64) * kinds + kind[len(ends) :]
        supported = np.flatnonzero(on_map)[np.isin(live, new)]
        self._support[supported] = t
        return ~np.isin(new, live)

    def _prune(self) -> None:
        """Keep the ``bound`` best-scoring live trajectories (ties to the most recently supported)."""
        order = np.lexsort((-self._support, self.scores()))
        live = np.zeros(len(order), dtype=bool)
        live[order[: self.bound]] = True
        ends = self.positions()
        self._keep(live)
        self._ends = _read_only(ends[live])

    def _new_anchors(self, t: int, candidates: np.ndarray, seeds: np.ndarray | None, ends: np.ndarray) -> np.ndarray:
        """The candidates, and the ``anchors`` lowest costs of frame t: over the map where every cost is
        known, else among the seeds' neighbourhoods and where the live trajectories pass (at ``ends``)."""
        chosen = np.unique(np.asarray(candidates, dtype=np.int64))
        if self.anchors == 0:
            return chosen.astype(np.float64)
        passing = np.rint(ends[np.isfinite(ends)]).astype(np.int64)[:, None] + np.arange(-self.radius, self.radius + 1)
        seeds = np.asarray(seeds if seeds is not None else [], dtype=np.int64)
        around = seeds[:, None] + np.arange(-self.neighbourhood, self.neighbourhood + 1)
        near = np.concatenate([passing.ravel(), chosen, around.ravel()])
        return np.union1d(chosen, self.costs.lowest(t, self.anchors, near)).astype(np.float64)

    def keep_direction(self, sign: int) -> None:
        """Drop the live trajectories whose reference index runs against ``sign`` (+1 rising, -1 falling):
        once the direction of travel is known they are no longer plausible."""
        keep = self._speed * sign >= 0
        if not keep.all():
            self._keep(keep)

    def _counted(self) -> np.ndarray | slice:
        """The window's frames that count (following the distance travelled: those within ``reach`` metres of the
        newest)."""
        if self.route is not None and self.reach is not None:
            progress = np.asarray(self._progress)
            return np.abs(progress[-1] - progress) <= self.reach + 1e-9
        return slice(None)

    def _lines(self, rows: np.ndarray | slice) -> np.ndarray:
        """(len(rows), frames) the reference positions of the trajectories ``rows`` at each window frame, oldest
        first (fractional; following the distance travelled, NaN beyond the map's ends)."""
        if self.route is None:
            times = np.asarray(self._times, dtype=np.float64)
            return self._anchor_r[rows, None] + self._speed[rows, None] * (times - self._anchor_t[rows, None])
        return self._at_route(self._along(rows))

    def _along(self, rows: np.ndarray | slice, frames: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(len(rows), frames) the route positions of the trajectories ``rows`` at the window's ``frames`` (following
        the distance travelled)."""
        progress = np.asarray(self._progress)[frames]
        return self._anchor_p[rows, None] + self._speed[rows, None] * (progress - self._anchor_q[rows, None])

    def _entered(self, counted: np.ndarray | slice) -> np.ndarray:
        """(trajectories,) the first of the ``counted`` frames at which each trajectory lies on the map (their number
        where it never does)."""
        if self.route is None:
            where = np.rint(self._lines(slice(None)))
            on_map = ((where >= 0) & (where < self.costs.n_refs))[:, counted]
        else:
            # On the route is on the map (:meth:`_at_route`): a bounds check, without placing every line on it.
            on_map = self._within_route(self._along(slice(None), counted))
        return np.where(on_map.any(axis=1), on_map.argmax(axis=1), on_map.shape[1])

    def _evaluate(self) -> None:
        """Each live trajectory's own mean and its sequence score, from one look at the window."""
        counted = self._counted()
        window = self._costs[:, self.length - len(self._times) :][:, counted]
        self._means = _read_only(window.sum(axis=1) / max(window.shape[1], 1))
        self._scores = (self._means if not np.isfinite(self.switch)
                        else _read_only(window_scores(window, self._entered(counted), self.switch)))

    def scores(self) -> np.ndarray:
        """Every live trajectory's sequence score, what the answer is chosen by (:func:`window_scores`); read-only."""
        if self._scores is None:
            self._evaluate()
        return self._scores  # type: ignore[return-value]

    def means(self) -> np.ndarray:
        """Every live trajectory's own mean cost over the window's frames; read-only. The evidence that weighs one
        place against another (the direction's vote, the confidence's margin): a trajectory entering the map borrows
        the frames before it from the best one, which says nothing for its own place."""
        if self._means is None:
            self._evaluate()
        return self._means  # type: ignore[return-value]

    def positions(self) -> np.ndarray:
        """Position of every live trajectory at the newest frame (a reference index, fractional; NaN off the map
        where the distance travelled is followed); read-only."""
        if self._ends is None:
            self._ends = _read_only(self._positions())
        return self._ends

    def _positions(self) -> np.ndarray:
        if self.route is None:
            return self._anchor_r + self._speed * (self._t - self._anchor_t)
        return self._at_route(self._anchor_p + self._speed * (self._progress[-1] - self._anchor_q))

    def _on_route(self, refs: np.ndarray) -> np.ndarray:
        """The route position of reference positions (the index itself where trajectories are straight in frames)."""
        if self.route is None:
            return refs
        return np.interp(refs, np.arange(len(self.route)), self.route)

    def _at_route(self, along: np.ndarray) -> np.ndarray:
        """The reference position (fractional index) at route positions ``along``; NaN beyond the map's ends."""
        if self.route is None:
            return along
        return np.where(self._within_route(along), np.interp(along, self.route, np.arange(len(self.route))), np.nan)

    def _within_route(self, along: np.ndarray) -> np.ndarray:
        """Whether route positions ``along`` lie within the map's route."""
        return (along >= self.route[0] - 1e-9) & (along <= self.route[-1] + 1e-9)

    def best_by_sign(self) -> tuple[float, float]:
        """The lowest own mean cost (:meth:`means`) among the live trajectories on the map with the reference index
        rising, and with it falling (inf where there is none): the evidence for the direction of travel."""
        scores = self.means()
        ends = self.positions()
        on_map = np.isfinite(ends)
        rising, falling = on_map & (self._speed > 0), on_map & (self._speed < 0)
        return (float(scores[rising].min()) if rising.any() else np.inf,
                float(scores[falling].min()) if falling.any() else np.inf)

    def choose(self, sign: int) -> SequenceResult:
        """The best trajectory whose reference index does not run against ``sign`` (+1 rising, -1 falling);
        the others stay live (evidence for later frames). It becomes the answer the window picture follows."""
        self._best_result = self._best(sign)
        return self._best_result

    def _best(self, sign: int = 0) -> SequenceResult:
        scores = self.scores()
        if len(scores) == 0:
            return _nowhere(len(self._times))
        ends = self.positions()
        # Lowest score among the trajectories still on the map (along ``sign``); ties go to the slower trajectory,
        # then the lower position, then the newer anchor, then a rising reference index.
        scores = np.where(np.isfinite(ends) & (self._speed * sign >= 0), scores, np.inf)
        if not np.isfinite(scores).any():
            return _nowhere(len(self._times))
        tied = np.flatnonzero(scores == scores.min())
        speed = self._speed[tied]
        best = tied[np.lexsort((-speed, -self._anchor_t[tied], ends[tied], np.abs(speed)))[0]]
        trajectory = self._lines(slice(best, best + 1))[0]
        if self.route is None:
            rate = float(self._speed[best])
        else:
            rate = float(trajectory[-1] - trajectory[-2]) if len(trajectory) > 1 else 0.0
        return SequenceResult(
            position=float(ends[best]),
            speed=rate,
            score=float(scores[best]),
            frames=len(self._times),
            trajectory=trajectory,
            mean=float(self.means()[best]),
        )

    def runner_up(self, position: float, exclusion: float) -> float:
        """The lowest own mean cost (:meth:`means`) among trajectories ending more than ``exclusion`` reference frames
        from ``position``."""
        with np.errstate(invalid="ignore"):
            far = np.abs(self.positions() - position) > exclusion
        return float(self.means()[far].min()) if far.any() else np.inf

    def window(self, width: int) -> tuple[np.ndarray, np.ndarray]:
        """(frames, 2 * width + 1) costs around the best trajectory at each window frame, oldest first,
        and the reference index of each cell (-1 off the map): the picture of the sequence search. Where
        costs are looked up, only what was looked up has one (NaN elsewhere): drawing computes nothing."""
        frames = len(self._times)
        costs = np.full((frames, 2 * width + 1), np.nan, dtype=np.float32)
        refs = np.full(costs.shape, -1, dtype=np.int64)
        best = self._best_result
        if best is None or not np.isfinite(best.trajectory).all():
            return costs, refs
        n = self.costs.n_refs
        times = np.asarray(self._times)
        cells = np.rint(best.trajectory).astype(np.int64)[:, None] + np.arange(-width, width + 1)[None, :]
        inside = (cells >= 0) & (cells < n)
        costs[inside] = self.costs.known(np.broadcast_to(times[:, None], cells.shape)[inside], cells[inside])
        refs[inside] = cells[inside]
        return costs, refs

    def state(self) -> dict:
        """Everything that carries from frame to frame (the window, its trajectories and costs), as plain values
        and arrays: :meth:`restore` on a filter made with the same settings continues exactly."""
        best = self._best_result
        return {
            "t": self._t, "times": list(self._times), "progress": list(self._progress),
            "anchor_t": self._anchor_t, "anchor_q": self._anchor_q, "anchor_r": self._anchor_r,
            "speed": self._speed, "support": self._support, "costs": self._costs, "window_costs": self.costs.state(),
            "best": None if best is None else [best.position, best.speed, best.score, best.frames, best.trajectory,
                                               best.mean],
        }

    def restore(self, state: dict) -> None:
        if state["costs"].shape[1:] != (self.length,):
            raise StateError(f"a saved sequence window of {state['costs'].shape[1:]} frames, this one holds "
                             f"{self.length}")
        self.costs.restore(state["window_costs"])
        self._t = int(state["t"])
        self._times = deque(int(t) for t in state["times"])
        self._progress = deque(float(q) for q in state["progress"])
        self._anchor_t, self._anchor_q = state["anchor_t"].astype(np.int64), state["anchor_q"].astype(np.float64)
        self._anchor_r, self._speed = state["anchor_r"].astype(np.float64), state["speed"].astype(np.float64)
        self._anchor_p = self._on_route(self._anchor_r)
        self._support = np.asarray(state.get("support", self._anchor_t), dtype=np.int64)
        self._costs = state["costs"].astype(np.float64)
        self._changed()
        best = state["best"]
        # A state saved before the own mean was kept: the score was the mean then.
        self._best_result = None if best is None else SequenceResult(float(best[0]), float(best[1]), float(best[2]),
                                                                     int(best[3]), np.asarray(best[4]),
                                                                     float(best[5] if len(best) > 5 else best[2]))


def _nowhere(frames: int) -> SequenceResult:
    """The answer where no trajectory lies on the map."""
    return SequenceResult(np.nan, np.nan, np.inf, frames, np.full(frames, np.nan), np.inf)


def window_scores(costs: np.ndarray, entered: np.ndarray, switch: float) -> np.ndarray:
    """The sequence score of trajectories whose costs over the window's n frames are the rows of ``costs`` (oldest
    frame first) and that first lie on the map at frame ``entered`` e_i: each one's mean cost, or where lower and it
    entered the map within the window, its cost after taking over there from the lowest sum any row had before,
    paying J = ``switch``:

        S_i = min( sum_t c_i(t),  min_j sum_{t<e_i} c_j(t) + J + sum_{t>=e_i} c_i(t) ) / n      (0 < e_i < n)
    """
    n = costs.shape[1]
    if n == 0:
        return np.zeros(len(costs))
    prefix = np.cumsum(costs, axis=1)  # prefix[:, e - 1]: sum_{t<e}
    total = prefix[:, -1]
    entering = (entered > 0) & (entered < n)
    if not np.isfinite(switch) or not entering.any():
        return total / n
    rows = np.flatnonzero(entering)
    before = prefix[rows, entered[rows] - 1]
    envelope = prefix.min(axis=0)[entered[rows] - 1]
    scores = total.copy()
    scores[rows] = np.minimum(total[rows], envelope + switch + total[rows] - before)
    return scores / n


def _read_only(values: np.ndarray) -> np.ndarray:
    values.flags.writeable = False
    return values
