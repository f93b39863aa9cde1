"""Candidate search: the k reference frames nearest to a query descriptor (paper Sec. III-A)."""

from __future__ import annotations

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
    """1 - cos between a unit query (K,) and unit reference descriptors (N, K)."""
    return 1.0 - refs @ query


def sad_distances(query: np.ndarray, refs: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Mean absolute difference (SeqSLAM's sum of absolute differences, per pixel) of int8 thumbnails:
    query (K,) against refs (N, K), in chunks so the temporary stays small for large maps."""
    q = query.astype(np.int16)
    out = np.empty(len(refs), dtype=np.float32)
    for start in range(0, len(refs), chunk):
        block = refs[start : start + chunk].astype(np.int16)
        out[start : start + chunk] = np.abs(block - q).sum(axis=1) / refs.shape[1]
    return out
