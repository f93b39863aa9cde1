"""Choosing frames of a traverse: by distance travelled (the paper keeps a frame every 2 m), every N-th, or at a rate."""

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


def rate_subsample_indices(timestamps: np.ndarray, fps: float) -> np.ndarray:
    """Indices of the frames nearest to a clock ticking ``fps`` times a second from the first frame.

    Each tick takes the frame closest in time (ties to the earlier one); a frame nearest to
    several ticks is kept once, so a rate above the recording's keeps every frame.
    """
    times = np.asarray(timestamps, dtype=np.float64)
    if not np.isfinite(fps) or fps <= 0:
        raise InputError(f"frame rate must be a positive number of frames per second, got {fps}")
    if times.ndim != 1 or len(times) == 0:
        return np.zeros(0, dtype=np.int64)
    if np.any(np.diff(times) < 0):
        raise InputError("choosing frames by rate needs timestamps that do not go backwards")
    if len(times) == 1:
        return np.zeros(1, dtype=np.int64)
    ticks = times[0] + np.arange(int(np.floor((times[-1] - times[0]) * fps + 1e-9)) + 1) / fps
    after = np.clip(np.searchsorted(times, ticks), 1, len(times) - 1)  # first frame at or after each tick
    before = after - 1
    chosen = np.where(times[after] - ticks < ticks - times[before], after, before)
    return np.unique(chosen).astype(np.int64)


def select_frames(traverse: Traverse, every: int | None = None, fps: float | None = None) -> Traverse:
    """Every ``every``-th frame, or frames at ``fps`` per second of recorded time (not both)."""
    if every is not None and fps is not None:
        raise InputError("choose frames by --every or by --fps, not both")
    if every is not None:
        if every < 1:
            raise InputError(f"--every must be a whole number of frames >= 1, got {every}")
        kept = np.arange(0, len(traverse), every)
        return traverse.subset(kept, f"every {every} frames: kept {len(kept)} of {len(traverse)}")
    if fps is not None:
        if traverse.timestamps is None:
            raise InputError(f"{traverse.name}: --fps needs timestamps, and this traverse has none; use --every")
        kept = rate_subsample_indices(traverse.timestamps, fps)
        return traverse.subset(kept, f"{fps:g} frames per second: kept {len(kept)} of {len(traverse)}")
    return traverse
