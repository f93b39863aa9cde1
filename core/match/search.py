"""Candidate search: the k reference frames nearest to a query descriptor (paper Sec. III-A).

Below ``search.index_min_frames`` map frames (or with ``search.index = "off"``) every map frame is
compared. Above it, the map's approximate index (:mod:`lostx.core.maps.index`, built with the map)
proposes ``search.index_shortlist`` frames, ranked again by their exact distance: the k nearest
returned are the exact nearest whenever the index found them (``lostx map info --verify``
measures how often it does). The distance itself is always exact: LoST cosine distance, or the
thumbnails' mean absolute difference.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from ..config import SearchConfig
from ..errors import MapError

if TYPE_CHECKING:
    from ..maps.refmap import ReferenceMap


def top_k(distances: np.ndarray, k: int) -> np.ndarray:
    """Indices of the k smallest distances, smallest first (ties by lower index)."""
    k = min(k, len(distances))
    if k <= 0:
        return np.zeros(0, dtype=np.int64)
    if k < len(distances):
        part = np.argpartition(distances, k - 1)[:k]
    else:
        part = np.arange(len(distances))
    return part[np.lexsort((part, distances[part]))]


def cosine_distances(query: np.ndarray, refs: np.ndarray) -> np.ndarray:
    """1 - cos between a unit query (K,) and unit reference descriptors (N, K).

    numpy's own loop, not BLAS: a threaded BLAS sums in an order that depends on its thread
    count, and the same query would get other last bits (and a tie another winner) in a
    process with another ``OPENBLAS_NUM_THREADS``."""
    return 1.0 - np.einsum("nk,k->n", refs, query)


def sad_distances(query: np.ndarray, refs: np.ndarray, chunk: int = 1024) -> np.ndarray:
    """Mean absolute difference (SeqSLAM's sum of absolute differences, per pixel) of uint8 thumbnails:
    query (K,) against refs (N, K). OpenCV's vectorised absdiff and row sums, in chunks that stay in cache."""
    query = np.ascontiguousarray(query, dtype=np.uint8)
    tiled = np.broadcast_to(query, (min(chunk, len(refs)), len(query))).copy()
    out = np.empty(len(refs), dtype=np.float32)
    for start in range(0, len(refs), chunk):
        block = np.ascontiguousarray(refs[start : start + chunk])
        diff = cv2.absdiff(block, tiled[: len(block)])
        out[start : start + len(block)] = cv2.reduce(diff, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).ravel()
    return out / refs.shape[1]


class CandidateSearch:
    """The nearest map frames of a query descriptor, exactly or through the map's index."""

    def __init__(self, refmap: "ReferenceMap", config: SearchConfig | None = None) -> None:
        self.map = refmap
        self.config = config or SearchConfig()
        self.index = None
        if uses_index(self.config, refmap.n_frames):
            self.index = refmap.index
            if self.index is None:
                raise MapError(f"{refmap.path} has no approximate index (built by an older lostx); rebuild the map "
                               f"with `lostx map build`, or search every frame with [search] index = \"off\"")

    @property
    def approximate(self) -> bool:
        return self.index is not None

    def nearest(self, query: np.ndarray, k: int, removed: slice | None = None,
                distances: "QueryDistances | None" = None) -> tuple[np.ndarray, np.ndarray]:
        """The k map frames nearest to ``query`` (those in ``removed`` left out), nearest first (ties to the
        lower index), and their exact distances. ``distances``: the query's distances to share with later
        look-ups (an exact search computes the whole map's once for both)."""
        distances = distances or QueryDistances(self, query)
        if self.index is None:
            every = distances()
            if removed is not None:
                every = every.copy()
                every[removed] = np.inf
                k = min(k, len(every) - (removed.stop - removed.start))
            found = top_k(every, k)
            return found, every[found]
        fetch = max(k, self.config.index_shortlist) + (0 if removed is None else removed.stop - removed.start)
        found = self.index.search(query, fetch, max(self.config.index_breadth, fetch))
        if removed is not None:
            found = found[(found < removed.start) | (found >= removed.stop)]
        near = distances(found)
        order = np.lexsort((found, near))[:k]
        return found[order], near[order]

    def distances(self, query: np.ndarray, refs: np.ndarray | None = None) -> np.ndarray:
        """Exact distances of ``query`` to the map frames ``refs`` (every frame when None), float32 or float64."""
        rows = self.map.descriptors if refs is None else self.map.descriptor_rows(refs)
        if self.map.kind == "lost":
            return cosine_distances(np.asarray(query, dtype=np.float32), rows)
        return sad_distances(query, rows)


class QueryDistances:
    """Exact distances of one query to the map frames asked for (None: every one); the whole map's are
    computed at most once, and then every later look-up reads them."""

    def __init__(self, search: CandidateSearch, query: np.ndarray) -> None:
        self.search, self.query = search, query
        self._every: np.ndarray | None = None

    def __call__(self, refs: np.ndarray | None = None) -> np.ndarray:
        if self._every is None and refs is None:
            self._every = self.search.distances(self.query)
        if self._every is not None:
            return self._every if refs is None else self._every[refs]
        return self.search.distances(self.query, refs)


def uses_index(config: SearchConfig, n_frames: int) -> bool:
    """Whether a search with these settings goes through the index of a map of ``n_frames``."""
    return config.index == "on" or (config.index == "auto" and n_frames >= config.index_min_frames)
