"""Where a frame's layout comparison runs: a process of its own holding the map's grids, or a thread. Synthetic
grids (the comparison's numbers do not depend on real frames here; tests/test_opposite.py compares the two on the
real ones)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from lostx.core.config import LayoutConfig
from lostx.core.layout.classes import CHANNELS, CONTACTS
from lostx.core.layout.compare import GridStack
from lostx.core.layout.describer import LiveLayout, Placed
from lostx.core.layout.grid import LayoutGrid, accumulate, grid_shape
from lostx.core.layout.projection import FramePoints
from lostx.core.match.combined import LayoutComparison
from lostx.core.match.comparers import ComparisonProcess, ThreadComparer

SHAPE = grid_shape(LayoutConfig())


@pytest.fixture(scope="module")
def stack() -> GridStack:
    rng = np.random.default_rng(3)
    n = 4000
    levels = rng.integers(0, 256, size=(n, len(CHANNELS), *SHAPE), dtype=np.uint8)
    return GridStack(levels, rng.random((n, *SHAPE)) < 0.8, np.full(len(CHANNELS), 255.0))


def _comparisons(stack: GridStack, count: int) -> list[LayoutComparison]:
    rng = np.random.default_rng(4)
    weights = np.ones(len(CHANNELS))
    return [LayoutComparison(LayoutGrid(rng.random((len(CHANNELS), *SHAPE)).astype(np.float32),
                                        rng.random(SHAPE) < 0.9), stack, weights, 1, 25, (-2.0, 0.0, 2.0))
            for _ in range(count)]


def test_many_comparisons_handed_to_the_process_at_once_each_get_their_own_scores(stack):
    """Frames described ahead each hand their grid over before any scores are read. Their replies (64 kB each on a
    4,000-frame map) would fill the socket and stop the process while the caller goes on handing grids over, which
    it would then stop reading: the caller reads what has come before handing the next one over. Each comparison
    gets its own scores; those whose reply was dropped unasked for (all but the last ``KEPT_REPLIES``) are computed
    where they are asked for, the same."""
    comparisons = _comparisons(stack, 60)
    process = ComparisonProcess(comparisons[0])
    got: list[np.ndarray] = []

    def run() -> None:
        pending = [process.submit(c) for c in comparisons]
        got.extend(p.result() for p in reversed(pending))

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(120)
    stuck = worker.is_alive()
    process.close()
    assert not stuck, "handing 60 grids over without reading stopped both sides"
    assert process.alive is False
    for comparison, scores in zip(reversed(comparisons), got):
        assert np.array_equal(scores, comparison.compute())


def test_a_thread_and_a_process_give_the_same_scores(stack):
    comparisons = _comparisons(stack, 3)
    process, thread = ComparisonProcess(comparisons[0]), ThreadComparer()
    in_process = [process.submit(c).result() for c in comparisons]
    on_thread = [thread.submit(c).result() for c in comparisons]
    process.close()
    for a, b in zip(in_process, on_thread):
        assert np.array_equal(a, b)
        assert a.shape == (2, stack.n) and np.isfinite(a).all()


def _frame(rng: np.random.Generator) -> FramePoints:
    """A frame's road-plane points: rays of three kinds and contacts, ahead of the camera."""
    n, m = rng.integers(200, 400), rng.integers(20, 60)
    def ahead(k: int) -> np.ndarray:
        return rng.uniform([2, -20], [45, 20], (k, 2)).astype(np.float32)

    return FramePoints(ahead(n), rng.integers(0, 3, n).astype(np.int8), rng.uniform(1, 5, n).astype(np.float32),
                       ahead(m), rng.integers(0, len(CONTACTS), m).astype(np.int8),
                       rng.uniform(0.1, 2, m).astype(np.float32))


def test_the_process_gathers_each_grid_from_the_frames_it_was_sent_once(stack, monkeypatch):
    """Where the process gathers a live frame's grid, it is sent each frame of the stream once and keeps those the
    stream keeps. Along a drive with changes of speed, a stop, a frame whose motion is unknown, a reset and grids
    handed over ahead of their scores being read, every grid is gathered there (none here, where a failed reply
    would be computed again) and is, with its scores, what gathering the same frames here gives, to the bit."""
    rng = np.random.default_rng(5)
    config = LayoutConfig()
    live = LiveLayout(config)
    steps = [2.0] * 12 + [0.4] * 20 + [0.0] * 15 + [3.5] * 10 + [1.0] * 12
    unknown, reset = {25}, 45
    x, placed = 0.0, []
    for i, step in enumerate(steps):
        x += step
        placed.append(Placed(_frame(rng), np.array([x, 0.1 * np.sin(x / 9), 0.02 * np.cos(x / 7)]), x,
                             known=i not in unknown))
    gatherings = []
    for i, frame in enumerate(placed):
        if i == reset:
            live.reset()
        gatherings.append(live.add(frame))
    expected = [accumulate(g.frames, g.poses, g.current, config) for g in gatherings]
    weights = np.ones(len(CHANNELS))
    comparisons = [LayoutComparison(g, stack, weights, 1, 25, (-2.0, 0.0, 2.0)) for g in gatherings]
    process = ComparisonProcess(comparisons[0])
    from lostx.core.layout import grid as grid_module

    gathered_here = []
    monkeypatch.setattr(grid_module, "accumulate", lambda *args: gathered_here.append(args) or accumulate(*args))
    sent: list[int] = []  # the numbers of the frames handed over, in order
    send = process._send

    def recorded(message: tuple) -> None:
        if message[1] == "gather":
            sent.extend(message[2][0])
        send(message)

    monkeypatch.setattr(process, "_send", recorded)
    try:
        for start in range(0, len(comparisons), 4):
            # Four handed over before any is read, read newest first.
            pending = [process.submit(c) for c in comparisons[start:start + 4]]
            got = [p.result() for p in reversed(pending)][::-1]
            for k, scores in enumerate(got):
                i = start + k
                assert gatherings[i].gathered and gatherings[i].frames == ()
                grid = gatherings[i].grid()
                assert np.array_equal(grid.values, expected[i].values), i
                assert np.array_equal(grid.mask, expected[i].mask), i
                assert np.array_equal(scores, LayoutComparison(expected[i], stack, weights, 1, 25,
                                                               (-2.0, 0.0, 2.0)).compute()), i
            assert not gathered_here, f"grids gathered here, not in the process, by frame {start + 4}"
        assert process.alive
    finally:
        process.close()
    gathered = {n for g in gatherings for n in g.keys}
    assert sorted(sent) == sorted(gathered), "a frame sent twice, or one gathered that was never sent"
