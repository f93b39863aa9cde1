"""Where a frame's layout comparison runs: a process of its own holding the map's grids, or a thread. Synthetic
grids (the comparison's numbers do not depend on real frames here; tests/test_opposite.py compares the two on the
real ones)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from lostx.core.layout.classes import CHANNELS
from lostx.core.layout.compare import GridStack
from lostx.core.layout.grid import LayoutGrid
from lostx.core.match.combined import LayoutComparison
from lostx.core.match.comparers import ComparisonProcess, ThreadComparer

SHAPE = (20, 15)


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
