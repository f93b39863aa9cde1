"""Semantic keypoints (paper Sec. III-B): one per feature channel, at its arg-max location.

Channel k of the query corresponds to channel k of the reference, giving D
correspondences per image pair. Many channels peak at the same few locations
(about 245 distinct locations for 448 channels on MOSAIC's 32 x 32 grid), so a
frame's evidence keeps the D-dim feature vectors only once per distinct
keypoint location, its *slots*, and of each only the non-zero entries (ReLU
features are about 90 % zeros), in compressed sparse rows. Wide descriptors can be compared in
fewer dimensions instead (:meth:`KeypointEvidence.projected`, lostx.core.describe.reduce).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .reduce import project_rows, project_slots

NO_KEYPOINT = -1


def argmax_keypoints(features: np.ndarray) -> np.ndarray:
    """(D, N) features -> (D,) flat arg-max location per channel; -1 for a channel that never fires
    (constant over the frame), which therefore has no keypoint."""
    flat = features.reshape(features.shape[0], -1)
    keypoints = flat.argmax(axis=1).astype(np.int32)
    # argmax gives the first maximum, so a constant channel peaks at location 0: only those need the minimum.
    first = np.flatnonzero(keypoints == 0)
    rows = flat[first]
    keypoints[first[rows[:, 0] <= rows.min(axis=1)]] = NO_KEYPOINT
    return keypoints


@dataclass
class KeypointEvidence:
    """What verification needs from C frames, stacked.

    Slot r is the distinct keypoint location ``slot_keys[r] = c * N + location``
    of frame c (sorted); its feature vector is sparse: channels
    ``channels[slot_offsets[r]:slot_offsets[r + 1]]`` hold ``values[...]``, the
    other channels are zero. A live query keeps its frame's whole features instead
    (``frame_features``; the sparse arrays and slot norms are then empty) and reads its slots from them
    when asked (:meth:`dense_slots`, :meth:`projected`); :meth:`sparse` converts where
    they are stored. Evidence compared in fewer dimensions keeps each slot as a unit
    vector on the map's projection (``reduced``, k columns).
    """

    keypoints: np.ndarray  # (C, D) int32, -1 = no keypoint
    labels: np.ndarray  # (C, N) uint8 grouped labels
    slot_keys: np.ndarray  # (S,) int64, sorted
    slot_offsets: np.ndarray  # (S + 1,) int64
    channels: np.ndarray  # (E,) int channel of each non-zero entry
    values: np.ndarray  # (E,) float32 its value
    slot_norms: np.ndarray  # (S,) float32 L2 norm of each slot's feature vector
    grid: tuple[int, int]
    feature_dim: int
    dense: np.ndarray | None = None  # (S, D) float32 slot features, once read densely
    frame_features: np.ndarray | None = None  # (D, N) float32 a single frame's whole features
    reduced: np.ndarray | None = None  # (S, k) float32 unit slot vectors on a projection (lostx.core.describe.reduce)

    @property
    def n_frames(self) -> int:
        return int(self.keypoints.shape[0])

    @property
    def n_locations(self) -> int:
        return int(self.labels.shape[1])

    def slot_rows(self, frame: np.ndarray | int, location: np.ndarray) -> np.ndarray:
        """Slot row of each (frame, keypoint location) pair; the location must be a keypoint of the frame."""
        keys = np.asarray(frame, dtype=np.int64) * self.n_locations + location
        # A table over every (frame, location) key: one look-up per pair instead of a binary search.
        table = np.zeros(self.n_frames * self.n_locations, dtype=np.int64)
        table[self.slot_keys] = np.arange(len(self.slot_keys))
        return table[keys]

    def dense_slots(self) -> np.ndarray:
        """(S, D) float32 feature vectors of all slots."""
        if self.dense is not None:
            return self.dense
        if self.frame_features is not None:
            self.dense = np.ascontiguousarray(np.take(self.frame_features, self.slot_keys, axis=1).T)
            return self.dense
        dense = np.zeros((len(self.slot_keys), self.feature_dim), dtype=np.float32)
        rows = np.repeat(np.arange(len(self.slot_keys)), np.diff(self.slot_offsets))
        dense[rows, self.channels] = self.values
        return dense

    @property
    def dims(self) -> int:
        """Dimensions its slot features are compared in: the feature size, or k once projected."""
        return int(self.reduced.shape[1]) if self.reduced is not None else self.feature_dim

    def projected(self, projection: np.ndarray) -> "KeypointEvidence":
        """The same evidence with each slot's features as a unit vector of its coordinates on ``projection``'s
        (D, k) directions."""
        if self.frame_features is not None and self.dense is None:
            rows = project_slots(self.frame_features, self.slot_keys, projection)
        else:
            rows = project_rows(self.dense_slots(), projection)
        norms = row_norms(rows)
        return replace(self, slot_offsets=np.zeros(len(self.slot_keys) + 1, dtype=np.int64),
                       channels=np.zeros(0, dtype=np.int32), values=np.zeros(0, dtype=np.float32),
                       slot_norms=norms, dense=None, frame_features=None,
                       reduced=rows / np.maximum(norms, 1e-30)[:, None])

    def sparse(self) -> "KeypointEvidence":
        """The same evidence with its slot features in compressed sparse rows."""
        if self.reduced is not None:
            raise ValueError("projected keypoint evidence has no sparse form")
        if self.dense is None and self.frame_features is None:
            return self
        dense = self.dense_slots()
        offsets, channels, values = sparse_slots(dense)
        return KeypointEvidence(self.keypoints, self.labels, self.slot_keys, offsets, channels, values,
                                np.linalg.norm(dense, axis=1).astype(np.float32), self.grid, self.feature_dim)

    @classmethod
    def stack(cls, frames: list["KeypointEvidence"]) -> "KeypointEvidence":
        frames = [f.sparse() for f in frames]
        n = frames[0].n_locations
        entries = np.cumsum([0] + [len(f.channels) for f in frames])
        return cls(
            keypoints=np.concatenate([f.keypoints for f in frames]),
            labels=np.concatenate([f.labels for f in frames]),
            slot_keys=np.concatenate([f.slot_keys + i * n for i, f in enumerate(frames)]),
            slot_offsets=np.concatenate(
                [[0]] + [f.slot_offsets[1:] + entries[i] for i, f in enumerate(frames)]
            ).astype(np.int64),
            channels=np.concatenate([f.channels for f in frames]),
            values=np.concatenate([f.values for f in frames]),
            slot_norms=np.concatenate([f.slot_norms for f in frames]),
            grid=frames[0].grid,
            feature_dim=frames[0].feature_dim,
        )


def sparse_slots(dense: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S, D) slot features -> CSR (offsets (S + 1,), channels (E,), values (E,))."""
    dense = np.ascontiguousarray(dense)
    flat = np.flatnonzero(dense)
    rows, channels = np.divmod(flat, dense.shape[1])
    offsets = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=dense.shape[0]))]).astype(np.int64)
    return offsets, channels.astype(np.int32), dense.ravel()[flat].astype(np.float32)


def frame_evidence(features: np.ndarray, labels: np.ndarray) -> KeypointEvidence:
    """Evidence of one frame from its dense features (D, h, w) and grouped labels (h, w)."""
    d, h, w = features.shape
    flat = np.ascontiguousarray(features.reshape(d, h * w), dtype=np.float32)
    keypoints = argmax_keypoints(flat)
    slots = np.unique(keypoints[keypoints >= 0]).astype(np.int64)
    empty = np.zeros(0)
    return KeypointEvidence(
        keypoints=keypoints[None],
        labels=labels.reshape(1, h * w).astype(np.uint8),
        slot_keys=slots,
        slot_offsets=np.zeros(len(slots) + 1, dtype=np.int64),
        channels=empty.astype(np.int32),
        values=empty.astype(np.float32),
        slot_norms=empty.astype(np.float32),
        grid=(h, w),
        feature_dim=d,
        frame_features=flat,
    )


def row_norms(rows: np.ndarray) -> np.ndarray:
    """(S,) float32 L2 norm of each row of (S, k)."""
    return np.sqrt(np.einsum("sk,sk->s", rows, rows)).astype(np.float32)
