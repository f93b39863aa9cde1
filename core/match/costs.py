"""Where the sequence filter's costs come from (see :mod:`lostx.core.route.sequence`).

A frame's single-frame score of map frame r, s(r) (:class:`MapScores`, lower is better), becomes its cost
in two steps:

1. SeqSLAM's local contrast enhancement over the ``window`` + 1 references centred on r (near the map's
   ends, the ``window`` + 1 nearest the end: :func:`neighbourhoods`)::

       c(r) = (s(r) - mean_W(r) s) / std_W(r) s        (sample std; 0 where the neighbourhood is flat)

2. Hub suppression: c(r) standardised against r's own running mean and standard deviation over the
   queries so far, starting from mean 0 and standard deviation 1 weighing ``prior`` frames. A reference
   close to every query (a tunnel, a blank frame: a *hub*) has a low cost for every query, and a
   trajectory staying on it would win everywhere.

Two sources compute them:

- :class:`EveryFrameCosts` for every map frame, every frame: exact running statistics; a step costs
  O(map size).
- :class:`LookedUpCosts` only where the filter looks (its trajectories, its anchors' neighbourhoods, the
  search's nearest frames), once per frame and cell, kept while the frame is in the window; the hub
  statistics of a reference count the costs computed for it. A step costs O(trajectories), whatever the
  map size: what a map searched through its approximate index needs once it is large.

Both give the filter a frame's cost of any reference in the window (:meth:`at`), its lowest costs among
the references it looks at (:meth:`lowest`), and what was computed so far without computing more
(:meth:`known`, for drawing).
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import StateError
from .scores import MapScores
from .search import top_k


def local_contrast(own: np.ndarray, total: np.ndarray, total_sq: np.ndarray, count: np.ndarray,
                   scale: np.ndarray | float) -> np.ndarray:
    """c = (s - mean) / std of scores ``own`` over neighbourhoods of ``count`` scores summing to ``total``
    (and their squares to ``total_sq``), with the sample std as SeqSLAM; 0 where the neighbourhood is flat
    (std not above 1e-12 times ``scale``, at least 1)."""
    n = np.maximum(count, 1)
    mean = total / n
    var = np.maximum(total_sq / n - mean**2, 0.0)
    std = np.sqrt(var * count / np.maximum(count - 1, 1))
    ok = std > 1e-12 * np.maximum(1.0, scale)
    return np.where(ok, (own - mean) / np.where(ok, std, 1.0), 0.0)


def neighbourhoods(refs: np.ndarray, window: int, n_refs: int) -> tuple[np.ndarray, int]:
    """W(r) for references ``refs`` of a map of ``n_refs``: the first reference of each and their common size, the
    ``window`` + 1 references centred on r, or where r is nearer an end of the map than half of them, the ``window``
    + 1 nearest that end (the whole map where it is shorter). Clipped instead, an end frame's neighbourhood would be
    half as wide and mostly its own peak (a true match's valley spans several frames): its contrast would be weakest
    where a vehicle comes onto the map, the one place a trajectory has to out-score a look-alike from its first
    frames."""
    half = window // 2
    size = min(2 * half + 1, n_refs)
    return np.clip(np.asarray(refs) - half, 0, n_refs - size), size


def contrast_normalise(scores: np.ndarray, window: int) -> np.ndarray:
    """SeqSLAM's local contrast enhancement of one frame's scores over the references:

        c(r) = (s(r) - mean_W(r) s) / std_W(r) s,   W(r) = the ``window`` + 1 references around r

    (:func:`neighbourhoods`), from prefix sums. Where the neighbourhood is flat the cost is 0.
    """
    s = np.asarray(scores, dtype=np.float64)
    n = len(s)
    lo, size = neighbourhoods(np.arange(n), window, n)
    hi = lo + size
    c1 = np.concatenate([[0.0], np.cumsum(s)])
    c2 = np.concatenate([[0.0], np.cumsum(s * s)])
    return local_contrast(s, c1[hi] - c1[lo], c2[hi] - c2[lo], hi - lo,
                          float(np.abs(s).max(initial=0.0))).astype(np.float32)


class RingCosts:
    """The costs of the window's frames, given whole (one value per map frame) as each frame arrives."""

    def __init__(self, n_refs: int, length: int) -> None:
        self.n_refs, self.length = int(n_refs), int(length)
        self.seconds = 0.0
        """Time spent computing costs so far (none here: they arrive computed)."""
        self.reset()

    def reset(self) -> None:
        self._ring = np.full((self.length, self.n_refs), np.nan, dtype=np.float32)

    def add(self, t: int, costs: np.ndarray | None) -> None:
        """Frame t's cost of every map frame (None: a frame without costs)."""
        self._ring[t % self.length] = np.nan if costs is None else costs

    def at(self, times: np.ndarray, refs: np.ndarray) -> np.ndarray:
        """Costs at (times, refs), broadcast together, refs on the map; NaN for a frame without costs."""
        return self._ring[np.asarray(times) % self.length, refs].astype(np.float64)

    known = at

    def lowest(self, t: int, k: int, near: np.ndarray) -> np.ndarray:
        """The k lowest costs of frame t over the whole map (``near`` is not needed: every cost is known)."""
        row = self._ring[t % self.length]
        return np.zeros(0, dtype=np.int64) if np.isnan(row).all() else top_k(row, k)

    def state(self) -> dict:
        return {"ring": self._ring}

    def restore(self, state: dict) -> None:
        ring = np.asarray(state["ring"], dtype=np.float32)
        if ring.shape != self._ring.shape:
            raise StateError(f"saved costs of {ring.shape[1]} map frames x {ring.shape[0]} frames, this map and "
                             f"window have {self.n_refs} x {self.length}")
        self._ring = ring.copy()


class EveryFrameCosts(RingCosts):
    """Contrast-normalised, hub-suppressed costs of every map frame, computed as each frame arrives."""

    def __init__(self, n_refs: int, length: int, contrast_window: int, hub_prior: float) -> None:
        self.window = int(contrast_window)
        self.hub_prior = float(hub_prior)
        super().__init__(n_refs, length)

    def reset(self) -> None:
        super().reset()
        self.hubs = HubNormaliser(self.n_refs, self.hub_prior)

    def add(self, t: int, scores: MapScores | None) -> None:  # type: ignore[override]
        start = time.perf_counter()
        costs = None if scores is None else self.hubs.every(contrast_normalise(scores.every(), self.window))
        super().add(t, costs)
        self.seconds += time.perf_counter() - start

    def state(self) -> dict:
        return {**super().state(), "hubs": self.hubs.state()}

    def restore(self, state: dict) -> None:
        super().restore(state)
        self.hubs.restore(state["hubs"])


class HubNormaliser:
    """Each reference's running cost statistics over the costs it has had so far, starting from mean 0 and
    standard deviation 1 weighing ``prior`` frames: every reference every frame (:meth:`every`), or the
    references whose costs were looked up (:meth:`__call__`)."""

    def __init__(self, n_refs: int, prior: float) -> None:
        self.prior = float(prior)
        self._count = np.zeros(n_refs)
        self._sum = np.zeros(n_refs)
        self._sumsq = np.full(n_refs, self.prior)  # the prior's variance 1 over ``prior`` frames

    def every(self, costs: np.ndarray) -> np.ndarray:
        """Add one cost of every reference to the statistics and return them standardised (float32)."""
        c = costs.astype(np.float64)
        self._count += 1.0
        self._sum += c
        self._sumsq += c * c
        return self._standardised(slice(None), c).astype(np.float32)

    def __call__(self, refs: np.ndarray, costs: np.ndarray) -> np.ndarray:
        """Add ``costs`` (of references ``refs``, which may repeat: one frame each) to the statistics and
        return them standardised; costs computed together are standardised with all of them counted.
        NaN (no cost) passes through and counts for nothing."""
        ok = np.isfinite(costs)
        r, c = refs[ok], costs[ok]
        np.add.at(self._count, r, 1.0)
        np.add.at(self._sum, r, c)
        np.add.at(self._sumsq, r, c * c)
        return self._standardised(refs, costs)

    def state(self) -> dict:
        return {"count": self._count, "sum": self._sum, "sumsq": self._sumsq}

    def restore(self, state: dict) -> None:
        if len(state["count"]) != len(self._count):
            raise StateError(f"saved statistics of {len(state['count'])} map frames, this map has {len(self._count)}")
        self._count, self._sum, self._sumsq = (np.array(state[k], dtype=np.float64) for k in ("count", "sum", "sumsq"))

    def _standardised(self, refs: np.ndarray | slice, costs: np.ndarray) -> np.ndarray:
        n = self.prior + self._count[refs]
        mean = self._sum[refs] / n
        std = np.sqrt(np.maximum(self._sumsq[refs] / n - mean**2, 1e-6))
        return (costs - mean) / std


class WindowCells:
    """A score and a cost, each with a flag saying it is known, per (row, reference) cell of a ring of
    ``rows`` frames over ``n_refs`` references.

    Cells are stored in blocks of :attr:`BLOCK` consecutive references, taken from a pool when a row first
    touches the block and given back when the row is cleared: memory follows what was looked up (a few
    thousand cells a frame), not the map's size, and a long traverse reuses the same pages.
    """

    BLOCK = 64

    def __init__(self, rows: int, n_refs: int) -> None:
        self.n_blocks = -(-int(n_refs) // self.BLOCK)
        self.slot_of = np.full((rows, self.n_blocks), -1, dtype=np.int32)
        """The pool slot holding each (row, block), -1 where none."""
        self._capacity = 0
        self.score = self.cost = np.zeros((0, self.BLOCK))
        self.has_score = self.has_cost = np.zeros((0, self.BLOCK), dtype=bool)
        self.stamp = np.zeros((0, self.BLOCK), dtype=np.int32)
        self._row = self._block = np.zeros(0, dtype=np.int64)
        self._used = np.zeros(0, dtype=bool)
        self._grow(256)

    def _grow(self, capacity: int) -> None:
        def wider(a: np.ndarray) -> np.ndarray:
            out = np.zeros((capacity,) + a.shape[1:], dtype=a.dtype)
            out[: len(a)] = a
            return out

        self.score, self.cost = wider(self.score), wider(self.cost)
        self.has_score, self.has_cost, self.stamp = wider(self.has_score), wider(self.has_cost), wider(self.stamp)
        self._row, self._block, self._used = wider(self._row), wider(self._block), wider(self._used)
        self._capacity = capacity

    def slots(self, rows: np.ndarray, refs: np.ndarray, allocate: bool = True) -> np.ndarray:
        """The pool slot of each cell's block (taken now where the row has none yet, or -1 when not
        ``allocate``); the cell is at column ``refs % BLOCK`` of its slot."""
        blocks = refs // self.BLOCK
        slots = self.slot_of[rows, blocks]
        missing = slots < 0
        if allocate and missing.any():
            keys = np.unique(rows[missing] * self.n_blocks + blocks[missing])
            free = np.flatnonzero(~self._used)
            if len(free) < len(keys):
                self._grow(max(2 * self._capacity, self._capacity + len(keys)))
                free = np.flatnonzero(~self._used)
            taken = free[: len(keys)]
            new_rows, new_blocks = np.divmod(keys, self.n_blocks)
            self.slot_of[new_rows, new_blocks] = taken
            self._row[taken], self._block[taken], self._used[taken] = new_rows, new_blocks, True
            self.has_score[taken] = False
            self.has_cost[taken] = False
            slots = self.slot_of[rows, blocks]
        return slots

    def clear(self, row: int) -> None:
        """Give back every block of ``row``."""
        taken = np.flatnonzero(self._used & (self._row == row))
        self.slot_of[row, self._block[taken]] = -1
        self._used[taken] = False


class LookedUpCosts:
    """Contrast-normalised, hub-suppressed costs computed on the first look-up of a (frame, reference)
    cell and kept while the frame is in the window (:class:`WindowCells`)."""

    def __init__(self, n_refs: int, length: int, contrast_window: int, hub_prior: float) -> None:
        self.n_refs, self.length = int(n_refs), int(length)
        self.window = int(contrast_window)
        self.hub_prior = float(hub_prior)
        self.computed = 0
        """Scores computed so far (each a descriptor distance): what the look-ups cost."""
        self.seconds = 0.0
        """Time spent computing costs so far."""
        self.reset()

    def reset(self) -> None:
        self.hubs = HubNormaliser(self.n_refs, self.hub_prior)
        self.cells = WindowCells(self.length, self.n_refs)
        self._frames: list[MapScores | None] = [None] * self.length

    def add(self, t: int, scores: MapScores | None) -> None:
        """Frame t's scores (None: a frame without costs); it takes the row of the frame leaving the window."""
        row = t % self.length
        self.cells.clear(row)
        self._frames[row] = scores

    def state(self) -> dict:
        # The window's frames keep their search (a closure over the index) to score cells on demand.
        raise StateError(f"costs looked up where the filter looks (a map of {self.n_refs} frames, sequence.costs) "
                         f"do not carry over")

    def restore(self, state: dict) -> None:
        raise StateError("costs looked up where the filter looks do not carry over")

    def known(self, times: np.ndarray, refs: np.ndarray) -> np.ndarray:
        """The costs computed so far at (times, refs) (broadcast together; refs on the map), NaN elsewhere:
        a picture of what was looked up, which computes nothing."""
        rows, refs = np.broadcast_arrays(np.asarray(times) % self.length, np.asarray(refs, dtype=np.int64))
        slots = self.cells.slots(rows, refs, allocate=False)
        column = refs % WindowCells.BLOCK
        held = slots >= 0
        known = np.zeros(rows.shape, dtype=bool)
        known[held] = self.cells.has_cost[slots[held], column[held]]
        out = np.full(rows.shape, np.nan)
        out[known] = self.cells.cost[slots[known], column[known]]
        return out

    def at(self, times: np.ndarray, refs: np.ndarray) -> np.ndarray:
        """Costs at (times, refs), broadcast together, refs on the map; NaN for a frame without scores."""
        rows, refs = np.broadcast_arrays(np.asarray(times) % self.length, np.asarray(refs, dtype=np.int64))
        slots = self.cells.slots(rows, refs)
        column = refs % WindowCells.BLOCK
        missing = ~self.cells.has_cost[slots, column]
        if missing.any():
            start = time.perf_counter()
            self._compute(*self._distinct(rows[missing], refs[missing], slots[missing], column[missing]))
            self.seconds += time.perf_counter() - start
        return self.cells.cost[slots, column]

    def lowest(self, t: int, k: int, near: np.ndarray) -> np.ndarray:
        """The k lowest costs of frame t among the references ``near`` (ties to the lower reference)."""
        near = np.unique(near[(near >= 0) & (near < self.n_refs)])
        costs = self.at(np.array(t), near)
        finite = np.isfinite(costs)
        near, costs = near[finite], costs[finite]
        return near[np.lexsort((near, costs))[:k]]

    def _compute(self, rows: np.ndarray, refs: np.ndarray, slots: np.ndarray, column: np.ndarray) -> None:
        """Costs of the distinct cells (rows, refs), ordered by row, held at (slots, column)."""
        first, size = neighbourhoods(refs, self.window, self.n_refs)
        around = first[:, None] + np.arange(size)[None, :]
        around_rows = np.broadcast_to(rows[:, None], around.shape)
        around_slots = self.cells.slots(around_rows.ravel(), around.ravel()).reshape(around.shape)
        around_column = around % WindowCells.BLOCK
        self._ensure_scores(around_rows.ravel(), around.ravel(), around_slots.ravel(), around_column.ravel())
        s = self.cells.score[around_slots, around_column]
        valid = np.isfinite(s)
        s = np.where(valid, s, 0.0)
        own = self.cells.score[slots, column]
        contrast = local_contrast(own, s.sum(axis=1), (s * s).sum(axis=1), valid.sum(axis=1), np.abs(own))
        contrast = np.where(np.isfinite(own), contrast.astype(np.float32).astype(np.float64), np.nan)
        self.cells.cost[slots, column] = self.hubs(refs, contrast).astype(np.float32)
        self.cells.has_cost[slots, column] = True

    def _ensure_scores(self, rows: np.ndarray, refs: np.ndarray, slots: np.ndarray, column: np.ndarray) -> None:
        """Compute the scores of the cells not computed before: one call per frame (each its own query)."""
        need = ~self.cells.has_score[slots, column]
        if not need.any():
            return
        rows, refs, slots, column = self._distinct(rows[need], refs[need], slots[need], column[need])
        values = np.full(len(rows), np.nan)
        bounds = np.flatnonzero(np.diff(rows)) + 1
        for lo, hi in zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [len(rows)]])):
            source = self._frames[int(rows[lo])]
            if source is not None:
                values[lo:hi] = source.at(refs[lo:hi])
        self.computed += len(rows)
        self.cells.score[slots, column] = values
        self.cells.has_score[slots, column] = True

    def _distinct(self, rows: np.ndarray, refs: np.ndarray, slots: np.ndarray,
                  column: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The distinct cells among those given, ordered by row: each keeps the last of its copies (a stamp
        per cell, no sort of the cells)."""
        order = np.arange(len(rows), dtype=np.int32)
        self.cells.stamp[slots, column] = order
        last = order[self.cells.stamp[slots, column] == order]
        last = last[np.argsort(rows[last], kind="stable")]
        return rows[last], refs[last], slots[last], column[last]
