"""Fewer dimensions for wide keypoint descriptors: a projection learnt from a map's own slot features.

Verification compares each correspondence's two D-dim feature vectors by cosine similarity. For a
wide backbone (960 or 2048 channels) those products, and the bytes a map keeps for them, grow with
D. The features of a network's layer span far fewer directions than they have channels, so the map
keeps them as their coordinates on the k directions that carry most of their energy: the leading
eigenvectors of their uncentred second moment (the rank-k basis that best preserves their dot
products). Queries are projected with the same basis before they are compared.
"""

from __future__ import annotations

import numpy as np

from ..config import VerifyConfig

SAMPLE_SLOTS = 8192
"""Slot vectors the projection is learnt from, spread evenly over the map."""


def reduced_dims(config: VerifyConfig, feature_dim: int) -> int | None:
    """The dimensions a map of ``feature_dim``-channel features keeps its keypoint descriptors in: None where
    they are kept whole."""
    wide = feature_dim > config.reduce_above and feature_dim > config.reduced_dim
    return config.reduced_dim if wide else None


def sample_rows(total: int, limit: int = SAMPLE_SLOTS) -> np.ndarray:
    """Indices of at most ``limit`` rows spread evenly over ``total``, the same however they are stored."""
    step = max(1, -(-total // limit))
    return np.arange(0, total, step, dtype=np.int64)


def learn_projection(rows: np.ndarray, dims: int) -> np.ndarray:
    """(D, k) orthonormal columns: the ``dims`` leading eigenvectors of rows^T rows (rows: (S, D)).

    Each column's sign is fixed (its largest entry positive) so the same rows always give the same
    basis; k is at most D."""
    rows = np.asarray(rows, dtype=np.float64)
    d = rows.shape[1]
    k = min(dims, d)
    moment = rows.T @ rows
    values, vectors = np.linalg.eigh(moment)
    basis = vectors[:, np.argsort(values)[::-1][:k]]
    signs = np.sign(basis[np.abs(basis).argmax(axis=0), np.arange(k)])
    return (basis * np.where(signs == 0, 1.0, signs)).astype(np.float32)


def project_rows(rows: np.ndarray, projection: np.ndarray) -> np.ndarray:
    """(S, D) feature vectors -> (S, k) their coordinates on the projection's directions (float32)."""
    return np.asarray(rows, dtype=np.float32) @ projection


def project_slots(features: np.ndarray, slots: np.ndarray, projection: np.ndarray) -> np.ndarray:
    """(S, k) coordinates on the projection's directions of a frame's (D, N) features at its S slot locations
    (float32)."""
    # Gathering a location's D values costs about two thirds of projecting them: where the slots are fewer
    # than half the locations only theirs are gathered and projected, otherwise every location is projected.
    if 2 * len(slots) < features.shape[1]:
        return np.take(features, slots, axis=1).T @ projection
    return (features.T @ projection)[slots]
