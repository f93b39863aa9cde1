"""How well a map's approximate index finds what exact search finds: Recall@k on sampled map frames.

Each sampled map frame's own descriptor is the query, the frame itself left out (a query from
another traverse is never the map frame itself). A frame the index returns counts as found when
its exact distance is no larger than that of the k-th exact nearest: frames at equal distance
(the black frames of a tunnel) are equally right answers, whichever of them either search lists.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..config import SearchConfig
from ..errors import MapError
from .search import CandidateSearch

if TYPE_CHECKING:
    from ..maps.refmap import ReferenceMap

SAMPLES = 500
"""Map frames sampled by default (evenly spaced along the map)."""


@dataclass(frozen=True)
class IndexRecall:
    """The index's answers against exact search over the same map frames."""

    recall: float
    """Mean fraction of the k exact nearest that the index search found (1.0: always all of them)."""
    worst: float
    """The lowest fraction over the sampled frames."""
    k: int
    queries: int
    breadth: int
    shortlist: int
    index_ms: float
    """Median milliseconds per index search (exact distances of its shortlist included)."""
    exact_ms: float
    """Median milliseconds per exact search over every map frame."""


def sample_frames(n_frames: int, samples: int) -> np.ndarray:
    """``samples`` map frames evenly spaced from the first to the last (all of them on a smaller map)."""
    return np.unique(np.linspace(0, n_frames - 1, min(samples, n_frames)).round().astype(np.int64))


def index_recall(refmap: "ReferenceMap", config: SearchConfig | None = None, k: int = 10,
                 samples: int = SAMPLES, progress: Callable[[int], None] | None = None) -> IndexRecall:
    """Recall@``k`` of the map's index, searched with ``config``'s breadth and shortlist, against exact search."""
    config = config or SearchConfig()
    if refmap.index is None:
        raise MapError(f"{refmap.path} has no approximate index (built by an older lostx); rebuild the map")
    if refmap.n_frames < 2:
        raise MapError(f"{refmap.path} has {refmap.n_frames} frame; recall needs at least two")
    approximate = CandidateSearch(refmap, dataclasses.replace(config, index="on"))
    exact = CandidateSearch(refmap, dataclasses.replace(config, index="off"))
    k = min(k, refmap.n_frames - 1)
    found: list[float] = []
    index_times: list[float] = []
    exact_times: list[float] = []
    for frame in sample_frames(refmap.n_frames, samples):
        query = refmap.descriptor_rows(np.array([frame]))[0]
        itself = slice(int(frame), int(frame) + 1)
        t0 = time.perf_counter()
        _, near = approximate.nearest(query, k, itself)
        t1 = time.perf_counter()
        _, truth = exact.nearest(query, k, itself)
        t2 = time.perf_counter()
        index_times.append(t1 - t0)
        exact_times.append(t2 - t1)
        # A tolerance of float32 rounding: both distances are the same exact computation on the same rows.
        found.append(float(np.count_nonzero(near <= truth[-1] + 1e-6)) / k)
        if progress is not None:
            progress(1)
    return IndexRecall(recall=float(np.mean(found)), worst=float(np.min(found)), k=k, queries=len(found),
                       breadth=config.index_breadth, shortlist=config.index_shortlist,
                       index_ms=1e3 * float(np.median(index_times)), exact_ms=1e3 * float(np.median(exact_times)))
