"""Candidate search: the k reference frames nearest to a query descriptor (paper Sec. III-A)."""

from __future__ import annotations

import cv2
import numpy as np


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
