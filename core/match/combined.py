"""The single-frame cues and their combination: each cue's score of any map frame standardised over the map,
weighted, added.

    s(r) = sum_c w_c z_c(r),    z_c(r) = (x_c(r) - mean x_c) / std x_c,    sum_c w_c^2 = 1

The cues (:class:`Cues`): LoST-X (x: its single-frame score, lower is better: the verification score of the verified
candidates, the descriptor distance times their median factor elsewhere, :class:`MapScores`), the layout (its
similarity, higher is better, negated: :mod:`lostx.core.layout.compare`) under the same heading, and appearance (the
GeM cosine distance of the same network's pooled features; it cannot tell the headings apart). The means and standard
deviations are a frame's own over the map (every map frame where the map is small enough to compare them all, else an
even sample of it), so that no cue's scale decides: what each says is how far a map frame stands out from the rest of
the map. The weights w_c >= 0 are what each cue earned on this stream (:mod:`lostx.core.route.agreement`), scaled to
unit length, so that the combined score of independent cues keeps a unit spread whatever the weights. Lower is
better, like every single-frame score.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..layout.compare import Alignment, GridStack, StoredGrids, aligned, refined, similarities
from ..layout.grid import Gathering, LayoutGrid, as_grid
from ..config import CUES
from .scores import MapScores

EVERY_FRAME_MAX = 20000
"""Maps up to this many frames compare the layout with every map frame; larger ones where they are asked."""
SAMPLE = 512
"""Map frames (evenly spaced) whose scores give a larger map's means and standard deviations."""
REFINE = 64
"""The map frames most similar to a query as the grids lie that are compared again shifted sideways."""
SAME, OPPOSITE = 0, 1
"""The rows of a comparison's scores, and the index of the frame's view each compares (:attr:`LayoutComparison.views`).
SAME: the frame's grid as it lies against the map's grids as its camera saw them (the same heading); OPPOSITE:
turned 180 degrees, its most similar ones against the grids as each stretch's other end sees it (the opposite
heading)."""


class PendingComparison(Protocol):
    def result(self) -> np.ndarray:
        """(2, N) each row's similarity with every map frame (:class:`LayoutComparison`; waiting for it)."""


class Comparer(Protocol):
    """Where comparisons run beside the caller (:mod:`.comparers`)."""

    alive: bool
    """Whether it still compares where it was set up to (else its comparisons are computed where asked for)."""

    def submit(self, comparison: LayoutComparison) -> PendingComparison:
        """Start ``comparison`` with every map frame, under both headings."""


class LayoutComparison:
    """One frame's layout grid against the map's under both headings (as it lies, and turned 180 degrees): every
    map grid, as the map's camera saw it, compared in one pass when first asked; the most similar ones again turned
    a few degrees and shifted sideways, the opposite heading's against the grids as each stretch's other end sees
    it (``opposite``, where the map stores them)."""

    def __init__(self, grid: LayoutGrid | Gathering, maps: GridStack | StoredGrids, weights: np.ndarray, shifts: int,
                 min_cells: int, turns: tuple[float, ...] = (0.0,),
                 opposite: GridStack | StoredGrids | None = None) -> None:
        self.source = grid
        """The frame's grid, or the gathering that gives it (gathered where the comparison runs)."""
        self._views: tuple[LayoutGrid, LayoutGrid] | None = None
        self.maps, self.weights, self.shifts, self.min_cells, self.turns = maps, weights, shifts, min_cells, turns
        self.opposite = opposite
        """The map's grids as each stretch's other end sees it (None: a map that stores none)."""
        self.stacks = (maps, maps if opposite is None else opposite)
        """The map's grids each heading is refined against: as the map's camera saw each stretch, and as its other end
        sees it (gathered in that camera's frame, found on the map's route: :mod:`lostx.core.layout.curve`)."""
        self._every: np.ndarray | None = None
        self._known = [(np.zeros(0, dtype=np.int64), np.zeros(0)) for _ in (SAME, OPPOSITE)]
        """On a map too large to compare every frame: each row's map frames compared so far (sorted) and scores."""
        self._future: PendingComparison | None = None
        self.seconds = 0.0
        """Gathering the grid (where it was not yet) and the comparisons took this long (on the thread or in the
        process :meth:`start` handed them to)."""

    @property
    def views(self) -> tuple[LayoutGrid, LayoutGrid]:
        """The frame's grid as it lies and turned 180 degrees."""
        if self._views is None:
            grid = as_grid(self.source)
            self._views = (grid, grid.turned())
        return self._views

    def heading(self, index: int) -> LayoutScores:
        """The scores of row ``index`` (:data:`SAME` or :data:`OPPOSITE`)."""
        return LayoutScores(self, index)

    def start(self, comparer: Comparer) -> None:
        """Compare with every map frame on ``comparer`` (another thread or process, :mod:`.comparers`) while the
        caller goes on (LoST-X verifies); :meth:`every` then waits for it."""
        self._future = comparer.submit(self)

    def compute(self) -> np.ndarray:
        """(2, N) each row's similarity with every map frame (:data:`SAME`, :data:`OPPOSITE`), computed here."""
        return self._compare((SAME, OPPOSITE))

    def every(self) -> np.ndarray:
        """(2, N) each row's similarity with every map frame."""
        if self._every is None and self._future is not None:
            self._every = self._future.result()
        if self._every is None:
            self._every = self.compute()
        return self._every

    def at(self, refs: np.ndarray, row: int) -> np.ndarray:
        """Row ``row``'s similarity with the map frames ``refs`` (on a map too large to compare every frame, that
        row's alone is computed, each map frame once however often it is asked for)."""
        if self._every is not None or self.maps.n <= EVERY_FRAME_MAX:
            return self.every()[row, refs]
        known, scores = self._known[row]
        missing = np.setdiff1d(refs, known)
        if len(missing):
            known = np.concatenate([known, missing])
            scores = np.concatenate([scores, self._compare((row,), missing)[0]])
            order = np.argsort(known, kind="stable")
            self._known[row] = known, scores = known[order], scores[order]
        return scores[np.searchsorted(known, refs)]

    def _compare(self, rows: tuple[int, ...], refs: np.ndarray | None = None) -> np.ndarray:
        """(len(rows), N): each row's view against every map grid (or those ``refs``) as its camera saw it, in one
        pass; then each row's ``REFINE`` most similar again, best over the small turns and sideways shifts (a turn or
        a shift only ever finds a better fit, and only the best ones matter), the opposite heading's against the other
        ends' grids (as they lie too). Rows refined with one stack share its batch."""
        start = time.perf_counter()
        maps = self.maps if refs is None else self.maps.rows(refs)
        scores = similarities([self.views[r] for r in rows], maps, self.weights, 0, self.min_cells)
        for stack in {id(self.stacks[r]): self.stacks[r] for r in rows}.values():
            mine = [i for i, r in enumerate(rows) if self.stacks[r] is stack]
            scores[mine] = self._refined(scores[mine], stack if refs is None else stack.rows(refs),
                                         [rows[i] for i in mine], whole=stack is not self.maps)
        self.seconds += time.perf_counter() - start
        return scores

    def _refined(self, scores: np.ndarray, maps: GridStack, view_indices: list[int], whole: bool) -> np.ndarray:
        """``scores`` (of the views against the map camera's grids), each view's ``REFINE`` best compared again with
        ``maps``, turned and shifted (and as they lie, where ``whole``: another stack than the first pass's)."""
        turns = [angle for angle in self.turns if angle != 0.0]
        if not (self.shifts or turns or whole) or not maps.n:
            return scores
        scores = scores.copy()
        ranked = np.where(np.isfinite(scores), scores, -np.inf)
        best = np.argsort(-ranked, axis=1, kind="stable")[:, :REFINE]
        again = refined([self.views[v] for v in view_indices], maps, best, self.weights, self.shifts, turns,
                        self.min_cells, whole)
        rows = np.take_along_axis(scores, best, axis=1)
        np.put_along_axis(scores, best, again if whole else np.maximum(rows, again), axis=1)
        return scores


@dataclass
class LayoutScores:
    """One frame's layout similarity with any map frame under one heading (higher is better)."""

    comparison: LayoutComparison
    index: int
    """The comparison's row (:data:`SAME` or :data:`OPPOSITE`)."""

    @property
    def query(self) -> LayoutGrid:
        """The frame's grid under this heading."""
        return self.comparison.views[self.index]

    @property
    def n_frames(self) -> int:
        return self.comparison.maps.n

    def every(self) -> np.ndarray:
        return self.comparison.every()[self.index]

    def at(self, refs: np.ndarray) -> np.ndarray:
        return self.comparison.at(np.asarray(refs, dtype=np.int64), self.index)

    def aligned(self, grid: LayoutGrid) -> Alignment:
        """The frame's grid under this heading, turned and shifted as it best fits ``grid`` (a map frame's)."""
        c = self.comparison
        return aligned(self.query, grid, c.weights, c.shifts, c.turns, c.min_cells)


def sampled(n_frames: int) -> np.ndarray:
    """The map frames a map's spread of scores is measured on: all of a small map, an even sample of a larger one."""
    if n_frames <= EVERY_FRAME_MAX:
        return np.arange(n_frames)
    return np.linspace(0, n_frames - 1, SAMPLE).astype(np.int64)


def _moments(values: np.ndarray) -> tuple[float, float]:
    finite = values[np.isfinite(values)]
    if len(finite) < 2:
        return 0.0, 1.0
    return float(finite.mean()), float(max(finite.std(), 1e-9))


class CueScores(Protocol):
    """One cue's score of any map frame (:class:`MapScores`, :class:`LayoutScores`)."""

    n_frames: int

    def every(self) -> np.ndarray: ...

    def at(self, refs: np.ndarray) -> np.ndarray: ...


@dataclass
class Cues:
    """One frame's cues under one heading: LoST-X's scores, and the layout's and appearance's where they took part."""

    lostx: MapScores
    layout: LayoutScores | None = None
    appearance: MapScores | None = None

    def present(self) -> dict[str, CueScores]:
        """The cues that took part, by name, in :data:`CUES` order."""
        found = {"lostx": self.lostx, "layout": self.layout, "appearance": self.appearance}
        return {name: scores for name, scores in found.items() if scores is not None}

    def lower_is_better(self, name: str) -> bool:
        return name != "layout"


@dataclass
class CombinedScores:
    """The combined score of any map frame (see the module docstring); a :class:`MapScores` in use."""

    cues: Cues
    weights: dict[str, float]
    """Each cue's weight (missing or 0: it takes no part); scaled to unit length here."""
    removed: slice | None = None
    removed_score: float = np.nan

    def __post_init__(self) -> None:
        present = self.cues.present()
        raw = {name: max(float(self.weights.get(name, 0.0)), 0.0) for name in present}
        norm = float(np.sqrt(sum(w * w for w in raw.values())))
        if norm == 0.0:  # nothing earned yet: LoST-X, the method the others join
            raw, norm = {"lostx": 1.0}, 1.0
        self.used = {name: w / norm for name, w in raw.items() if w > 0.0}
        """The weights in use (unit length), by cue."""
        n = self.cues.lostx.n_frames
        sample = sampled(n)
        lost = self.cues.lostx
        if lost.removed is not None:
            sample = sample[(sample < lost.removed.start) | (sample >= lost.removed.stop)]
        self._every: dict[str, np.ndarray] = {}
        self._moments: dict[str, tuple[float, float]] = {}
        self._floors: dict[str, float] = {}
        for name in self.used:
            scores = present[name]
            if n <= EVERY_FRAME_MAX:
                # A small map's scores of every frame, computed once for the moments and every look-up.
                self._every[name] = np.asarray(scores.every(), dtype=np.float64)
                values = self._every[name][sample]
            else:
                values = np.asarray(scores.at(sample), dtype=np.float64)
            self._moments[name] = _moments(values)
            finite = values[np.isfinite(values)]
            # A map frame a cue cannot score (the layout: too few cells seen by both) counts as its worst.
            worst = (finite.max() if self.cues.lower_is_better(name) else finite.min()) if len(finite) else 0.0
            self._floors[name] = float(worst)

    @property
    def n_frames(self) -> int:
        return self.cues.lostx.n_frames

    @property
    def known(self) -> np.ndarray:
        return self.cues.lostx.known

    def _standardised(self, name: str, values: np.ndarray) -> np.ndarray:
        mean, std = self._moments[name]
        values = np.where(np.isfinite(values), values, self._floors[name])
        z = (values - mean) / std
        return z if self.cues.lower_is_better(name) else -z

    def standardised(self, name: str, refs: np.ndarray | None = None) -> np.ndarray:
        """z_c of cue ``name`` (one in use) at ``refs`` (None: every map frame), lower is better."""
        if refs is None:
            values = self._every.get(name)
            if values is None:
                values = self.cues.present()[name].every()
        else:
            refs = np.asarray(refs, dtype=np.int64)
            values = self._every[name][refs] if name in self._every else self.cues.present()[name].at(refs)
        return self._standardised(name, np.asarray(values, dtype=np.float64))

    def every(self) -> np.ndarray:
        total = sum(w * self.standardised(name) for name, w in self.used.items())
        return self._removed(np.arange(self.n_frames), np.asarray(total, dtype=np.float64))

    def at(self, refs: np.ndarray) -> np.ndarray:
        refs = np.asarray(refs, dtype=np.int64)
        total = sum(w * self.standardised(name, refs) for name, w in self.used.items())
        return self._removed(refs, np.asarray(total, dtype=np.float64))

    def _removed(self, refs: np.ndarray, out: np.ndarray) -> np.ndarray:
        if self.removed is not None:
            out[(refs >= self.removed.start) & (refs < self.removed.stop)] = self.removed_score
        return out
