"""A map's approximate nearest-neighbour index: faiss HNSW over 8-bit scalar-quantised descriptors.

Built with the map from its stored descriptors (``index.faiss``, listed in the manifest with its
size and checksum), memory-mapped when read. LoST maps are searched by inner product of the
normalised descriptors (their cosine similarity; each dimension quantised to 8 bits over its range
on the map), thumbnail maps by L2 distance of the uint8 thumbnails stored as they are (the search
ranks its shortlist again by the thumbnails' exact mean absolute difference).

faiss was chosen over usearch by measurement (``benchmarks/bench_index.py``): on LoST
descriptors its quantiser, trained per dimension, keeps the recall that usearch's fixed-range
int8 loses on unit vectors of 1344 dimensions, a build gives the same bytes every time (so a map
built on a cluster is the map built in one process), and its wheel is one of those lostx already
installs from.

faiss runs one thread here: a query is one vector (nothing to share out), and a build must give
the same graph every time.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..errors import MapError

if TYPE_CHECKING:
    from .format import MapKind

INDEX_FILE = "index.faiss"
NEIGHBOURS = 32
"""Graph neighbours per map frame (HNSW's M): 32 keeps recall high on descriptors of a thousand dimensions."""
BUILD_BREADTH = 80
"""Candidate list while the graph is built (HNSW's efConstruction)."""
TRAIN_FRAMES = 200_000
"""Map frames (evenly spaced) that set each dimension's quantisation range."""
ADD_BLOCK = 8192


def _faiss(threads: int = 1) -> Any:
    import faiss

    faiss.omp_set_num_threads(threads)
    return faiss


@dataclass(frozen=True)
class IndexInfo:
    """What the manifest records of a map's index."""

    file: str
    bytes: int
    sha256: str
    metric: str
    neighbours: int
    build_breadth: int

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def build_index(descriptors: np.ndarray, kind: "MapKind", folder: Path,
                progress: Callable[[int], None] | None = None, threads: int = 1) -> IndexInfo:
    """Index the (N, K) stored descriptors (float16 LoST, uint8 thumbnails; a memory map will do) into
    ``folder / INDEX_FILE``. ``progress`` is told how many frames were added, block by block.

    ``threads`` above 1 builds faster but not the same graph twice: maps are built with one (a
    benchmark's index, whose bytes do not matter, may take more)."""
    faiss = _faiss(threads)
    n, dim = descriptors.shape
    if kind == "lost":
        index = faiss.IndexHNSWSQ(dim, faiss.ScalarQuantizer.QT_8bit, NEIGHBOURS, faiss.METRIC_INNER_PRODUCT)
        step = max(1, n // TRAIN_FRAMES)
        index.train(np.ascontiguousarray(descriptors[::step], dtype=np.float32))
        metric = "inner product"
    else:
        index = faiss.IndexHNSWSQ(dim, faiss.ScalarQuantizer.QT_8bit_direct, NEIGHBOURS, faiss.METRIC_L2)
        index.train(np.zeros((1, dim), np.float32))  # direct 8-bit codes: nothing to learn
        metric = "L2"
    index.hnsw.efConstruction = BUILD_BREADTH
    for start in range(0, n, ADD_BLOCK):
        block = np.ascontiguousarray(descriptors[start : start + ADD_BLOCK], dtype=np.float32)
        index.add(block)
        if progress is not None:
            progress(len(block))
    path = Path(folder) / INDEX_FILE
    faiss.write_index(index, str(path))
    faiss.omp_set_num_threads(1)
    return IndexInfo(INDEX_FILE, path.stat().st_size, file_sha256(path), metric, NEIGHBOURS, BUILD_BREADTH)


class ApproximateIndex:
    """A map's index opened for searching (memory-mapped: processes that open one map share its pages)."""

    def __init__(self, path: Path, n_frames: int) -> None:
        faiss = _faiss()
        try:
            self._index = faiss.read_index(str(path), faiss.IO_FLAG_MMAP | faiss.IO_FLAG_READ_ONLY)
        except RuntimeError as exc:
            raise MapError(f"map index {path} is corrupt: {str(exc).splitlines()[0]}") from None
        if self._index.ntotal != n_frames:
            raise MapError(f"map index {path} holds {self._index.ntotal} frames, the map {n_frames}")
        self._params = faiss.SearchParametersHNSW
        self.n_frames = n_frames

    def search(self, query: np.ndarray, k: int, breadth: int) -> np.ndarray:
        """Up to ``k`` map frames near ``query``, as the index ranks them (approximately)."""
        k = int(min(k, self.n_frames))  # faiss takes Python ints only
        vector = np.ascontiguousarray(np.asarray(query, dtype=np.float32).reshape(1, -1))
        _, ids = self._index.search(vector, k, params=self._params(efSearch=int(max(breadth, k))))
        found = ids[0]
        return found[found >= 0].astype(np.int64)


def file_sha256(path: Path, block: int = 1 << 24) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(block), b""):
            digest.update(chunk)
    return digest.hexdigest()
