"""Subsampling a traverse by distance travelled (the paper keeps a frame every 2 m)."""

from __future__ import annotations

import numpy as np

from lostx.core.errors import InputError

from .folder import Traverse


def distance_subsample_indices(positions: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of the frames kept when keeping one every ``spacing`` metres of path.

    Frame 0 is kept. Walking the path frame by frame, the path length since the
    last kept frame accumulates the straight segments between consecutive
    positions; the first frame at which it reaches ``spacing`` (``>=``) is kept and
    the count restarts from zero there (no remainder is carried, so the spacing
    between kept frames is at least ``spacing``, never less). A vehicle standing
    still adds no length, so its repeated frames are dropped.
    """
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise InputError(f"positions must be (N, 2) metres, got shape {pos.shape}")
    if not np.isfinite(spacing) or spacing <= 0:
        raise InputError(f"subsampling distance must be a positive number of metres, got {spacing}")
    bad = np.flatnonzero(~np.isfinite(pos).all(axis=1))
    if len(bad):
        raise InputError(f"frame {int(bad[0])} has no finite position; cannot subsample by distance")
    if len(pos) == 0:
        return np.zeros(0, dtype=np.int64)
    steps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    kept = [0]
    travelled = 0.0
    # A loop, not a cumulative sum: the reset at each kept frame makes the choice sequential.
    for i, step in enumerate(steps, start=1):
        travelled += float(step)
        if travelled >= spacing:
            kept.append(i)
            travelled = 0.0
    return np.asarray(kept, dtype=np.int64)


def subsample_by_distance(traverse: Traverse, spacing: float) -> Traverse:
    """The traverse with one frame kept every ``spacing`` metres travelled (needs positions)."""
    if traverse.positions is None:
        raise InputError(f"{traverse.name}: subsampling by distance needs positions, and this traverse has none")
    kept = distance_subsample_indices(traverse.positions, spacing)
    note = f"subsampled every {spacing:g} m of path: kept {len(kept)} of {len(traverse)} frames"
    return traverse.subset(kept, note)
