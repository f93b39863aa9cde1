"""Writing reference maps: frames gathered in chunks, committed as one map folder in one atomic rename.

A build hands the writer its frames one by one (:class:`MapFrame`) or a chunk at a time
(:class:`MapChunk`: a run of frames packed as the map stores them, before the normalisation that
needs all of them). Chunks may live on disk (a build's checkpoint, :mod:`lostx.core.maps.checkpoint`)
and may come from other processes (a cluster: :mod:`lostx.cluster`). The commit streams through
them in frame order, so it never holds more than a block of frames in memory, and gives the same
bytes however the frames were cut into chunks: the descriptor statistics are summed over fixed
blocks of frames, and everything else is per frame.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
from numpy.lib.format import open_memmap

from ..backbones import BackboneInfo
from ..config import VerifyConfig
from ..describe.inputcheck import Looks, ProfileBuilder
from ..describe.keypoints import KeypointEvidence, row_norms
from ..describe.lost import DescriptorStats, standardise
from ..describe.reduce import learn_projection, project_rows, reduced_dims, sample_rows
from ..errors import MapError
from ..outputs import check_output_folder, sync_folder
from .format import MAP_FORMAT, MAP_VERSION, WHOLE_VERSION, MapKind, backbone_dict
from .index import build_index, file_sha256

CHUNK_FRAMES = 256
"""Frames per chunk: what a crash can lose of a build, and what one Ray task describes."""
ROW_BLOCK = 8192
"""Frames per block of the streaming commit (about 90 MB of float64 LoST descriptors)."""
EVIDENCE = ("keypoints", "labels", "frame_slots", "frame_entries", "slot_locations", "slot_counts", "slot_norms",
            "slot_channels", "slot_values")
REDUCED = ("keypoints", "labels", "frame_slots", "slot_locations")
"""The evidence arrays a map with reduced keypoint descriptors copies from its chunks as they are."""
SLOT_BLOCK = 4096
"""Slots projected at a time (16 MB of float32 features at 1,024 channels)."""


@dataclass
class MapFrame:
    """One reference frame as the builder hands it to the writer."""

    name: str
    descriptor: np.ndarray
    """Raw global descriptor (before normalisation)."""
    evidence: KeypointEvidence | None = None
    appearance: np.ndarray | None = None
    """GeM-pooled network features (the appearance baseline), for LoST maps."""
    position: tuple[float, float] | None = None
    timestamp: float | None = None
    looks: Looks | None = None
    """What the frame looked like (lostx.core.describe.inputcheck), for the map's input profile."""
    label_frequencies: np.ndarray | None = None
    """How often the network gave each grouped label in the frame (LoST maps)."""
    camera: str | None = None
    """The camera the frame declared (the map records it when all its frames agree)."""
    layout: tuple[np.ndarray, np.ndarray] | None = None
    """The frame's layout grid packed (lostx.core.layout.grid.pack): values and mask bits."""
    step: np.ndarray | None = None
    """(3,) the frame's camera ground frame in the previous frame's (lostx.core.motion), where motion is known."""


@dataclass
class MapChunk:
    """Frames ``start`` to ``start + len(names)`` of a map being built, packed as the map stores them,
    their descriptors not yet normalised."""

    start: int
    names: np.ndarray
    """(n,) frame names (unicode)."""
    cameras: np.ndarray
    """(n,) the camera each frame declared (unicode; empty where it declared none)."""
    descriptors: np.ndarray
    """(n, K) float32 raw LoST descriptors, or uint8 thumbnails."""
    positions: np.ndarray
    """(n, 2) float64, NaN where a frame has none."""
    timestamps: np.ndarray
    """(n,) float64, NaN where a frame has none."""
    looks: np.ndarray
    """(n, 4) float64: width, height, brightness, greyscale (1, 0, NaN: cannot tell)."""
    label_frequencies: np.ndarray
    """(n, L) float64 (L = 0 for thumbnails)."""
    appearance: np.ndarray
    """(n, D) float16, or (0, 0) when not every frame has one."""
    layout_values: np.ndarray
    """(n, V) uint8 packed layout grids, or (0, 0) when not every frame has one."""
    layout_mask: np.ndarray
    """(n, B) uint8 their observed cells as bits, or (0, 0)."""
    steps: np.ndarray
    """(n, 3) float64 each frame's motion from the previous frame, NaN where unknown."""
    keypoints: np.ndarray
    labels: np.ndarray
    frame_slots: np.ndarray
    """(n + 1,) int64, from 0: the chunk's own slots."""
    frame_entries: np.ndarray
    slot_locations: np.ndarray
    slot_counts: np.ndarray
    slot_norms: np.ndarray
    slot_channels: np.ndarray
    slot_values: np.ndarray

    @property
    def stop(self) -> int:
        return self.start + len(self.names)

    @classmethod
    def of_frames(cls, start: int, frames: list[MapFrame], kind: MapKind, backbone: BackboneInfo | None,
                  n_labels: int) -> "MapChunk":
        n = len(frames)
        if kind == "lost":
            if any(f.evidence is None for f in frames):
                raise ValueError("a LoST map frame needs its keypoint evidence")
            packed = pack_evidence([f.evidence for f in frames], backbone)  # type: ignore[misc]
            descriptors = np.stack([f.descriptor for f in frames]).astype(np.float32)
        else:
            packed = _no_evidence(n)
            descriptors = np.stack([f.descriptor for f in frames]).astype(np.uint8)
        appearance = (np.stack([f.appearance for f in frames]).astype(np.float16)
                      if all(f.appearance is not None for f in frames) else np.zeros((0, 0), np.float16))
        laid = all(f.layout is not None for f in frames)
        layout_values = (np.stack([f.layout[0] for f in frames]) if laid  # type: ignore[index]
                         else np.zeros((0, 0), np.uint8))
        layout_mask = np.stack([f.layout[1] for f in frames]) if laid else np.zeros((0, 0), np.uint8)  # type: ignore[index]
        return cls(
            start=start,
            names=np.array([f.name for f in frames], dtype=str),
            cameras=np.array([f.camera or "" for f in frames], dtype=str).reshape(n),
            descriptors=descriptors,
            positions=np.array([f.position if f.position is not None else (np.nan, np.nan) for f in frames],
                               dtype=np.float64).reshape(n, 2),
            timestamps=np.array([np.nan if f.timestamp is None else f.timestamp for f in frames], dtype=np.float64),
            looks=np.array([_looks_row(f.looks) for f in frames], dtype=np.float64).reshape(n, 4),
            label_frequencies=np.array([f.label_frequencies if f.label_frequencies is not None else np.zeros(n_labels)
                                        for f in frames], dtype=np.float64).reshape(n, n_labels),
            appearance=appearance,
            layout_values=layout_values.astype(np.uint8),
            layout_mask=layout_mask.astype(np.uint8),
            steps=np.array([f.step if f.step is not None else (np.nan, np.nan, np.nan) for f in frames],
                           dtype=np.float64).reshape(n, 3),
            **packed,
        )

    def head(self) -> np.ndarray:
        """The sizes the commit needs before it reads the arrays: descriptor and appearance dimensions and
        rows, and the length of every evidence array."""
        return np.array([self.descriptors.shape[1], len(self.appearance), self.appearance.shape[1],
                         *(len(getattr(self, name)) for name in EVIDENCE), len(self.layout_values),
                         self.layout_values.shape[1], self.layout_mask.shape[1]], dtype=np.int64)

    def save(self, path: Path) -> None:
        """Write the chunk to ``path`` (an .npz) atomically."""
        tmp = path.with_name(f".{path.name}.{os.getpid()}.npz")
        arrays = {f.name: getattr(self, f.name) for f in fields(self)}
        arrays["start"] = np.array(self.start)
        arrays["head"] = self.head()
        np.savez(tmp, **arrays)
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: Path) -> "MapChunk":
        with np.load(path, allow_pickle=False) as data:
            values = {f.name: data[f.name] for f in fields(cls)}
        values["start"] = int(values["start"])
        return cls(**values)


class MapWriter:
    """Collects frames and commits them as a map folder in one atomic rename.

    Use as a context manager: leaving the block by an exception removes the
    temporary folder and leaves any existing map untouched.
    """

    def __init__(
        self,
        out: str | Path,
        kind: MapKind,
        metadata: dict[str, Any],
        backbone: BackboneInfo | None = None,
        overwrite: bool = False,
        spool: Callable[[MapChunk], Path] | None = None,
        index: bool = True,
        verify: VerifyConfig | None = None,
    ) -> None:
        """``spool``: where full chunks go (it saves one and says where; a build's checkpoint); chunks stay
        in memory without one. ``index``: build the approximate index (False: a map only ever searched
        exactly, e.g. a benchmark's, whose search is timed apart; ``search.index = "on"`` refuses it).
        ``verify``: whether the keypoint descriptors are reduced, and to how many dimensions."""
        self.out = check_output_folder(out, "map folder")
        if self.out.exists() and not overwrite:
            raise MapError(f"{self.out} already exists; pass --overwrite to replace it")
        if self.out.exists() and not (self.out / "manifest.json").is_file() and any(self.out.iterdir()):
            raise MapError(f"{self.out} exists and is not a lostx map; refusing to replace it")
        self.kind = kind
        self.metadata = metadata
        self.backbone = backbone
        self.overwrite = overwrite
        self.spool = spool
        self.with_index = index
        self.verify = verify or VerifyConfig()
        self.n_labels = len(metadata.get("label_names") or ())
        self._chunks: list[MapChunk | Path] = []
        self._starts: list[int] = []
        self._pending: list[MapFrame] = []
        self._pending_start = 0
        self.nbytes = 0
        """Bytes of the committed map's files."""
        self._tmp = self.out.parent / f".{self.out.name}.partial-{os.getpid()}"

    def __enter__(self) -> "MapWriter":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)

    @property
    def n_frames(self) -> int:
        """Frames handed to the writer so far."""
        return sum(len(_names(c)) for c in self._chunks) + len(self._pending)

    def add(self, frame: MapFrame, index: int | None = None) -> None:
        """Add the next frame (``index``: its place in the map, when frames arrive out of order by chunks)."""
        if self.kind == "lost" and frame.evidence is None:
            raise ValueError("a LoST map frame needs its keypoint evidence")
        if not self._pending:
            self._pending_start = index if index is not None else self.n_frames
        self._pending.append(frame)
        if len(self._pending) >= CHUNK_FRAMES:
            self.flush()

    def add_chunk(self, chunk: MapChunk | Path, start: int | None = None) -> None:
        """Add a chunk, or a chunk saved at a path (read back at the commit; ``start`` is its first frame)."""
        self._chunks.append(chunk)
        self._starts.append(chunk.start if isinstance(chunk, MapChunk) else int(start))  # type: ignore[arg-type]

    def flush(self) -> None:
        """Pack the frames added since the last chunk into one (and spool it)."""
        if not self._pending:
            return
        chunk = MapChunk.of_frames(self._pending_start, self._pending, self.kind, self.backbone, self.n_labels)
        self._pending = []
        self.add_chunk(self.spool(chunk) if self.spool is not None else chunk, chunk.start)

    def commit(self) -> Path:
        self.flush()
        if not self._chunks:
            raise MapError(f"no frames to write to {self.out}")
        shutil.rmtree(self._tmp, ignore_errors=True)
        self._tmp.mkdir(parents=True)
        try:
            manifest = self._write(self._ordered())
            _write_bytes(self._tmp / "manifest.json", json.dumps(manifest, indent=1).encode())
            sync_folder(self._tmp)
            self._swap_in()
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        return self.out

    def _ordered(self) -> list[MapChunk | Path]:
        order = np.argsort(self._starts, kind="stable")
        chunks = [self._chunks[i] for i in order]
        expected = 0
        for i in order:
            if self._starts[i] != expected:
                raise MapError(f"map frames {expected} to {self._starts[i] - 1} are missing; cannot commit the map")
            expected += len(_names(self._chunks[i]))
        return chunks

    def _write(self, chunks: list[MapChunk | Path]) -> dict[str, Any]:
        heads = [_head(c) for c in chunks]
        n = sum(h["n"] for h in heads)
        names = [str(name) for c in chunks for name in _names(c)]
        files: dict[str, dict[str, Any]] = {}
        has_position = np.concatenate([h["has_position"] for h in heads])
        if has_position.any() and not has_position.all():
            missing = [names[i] for i in np.flatnonzero(~has_position)[:3]]
            raise MapError(f"positions are given for some frames but not for {', '.join(missing)}")
        if self.kind == "lost":
            stats = DescriptorStats.of_blocks(lambda: _row_blocks(chunks, "descriptors"), n)
            files["descriptors"] = self._stream("descriptors", chunks, (n, heads[0]["dim"]), np.float16,
                                                lambda block: standardise(block, stats.mean, stats.std))
            files["stats_mean"] = _write_array(self._tmp / "stats_mean.npy", stats.mean)
            files["stats_std"] = _write_array(self._tmp / "stats_std.npy", stats.std)
            dim = int(_load(chunks[0]).keypoints.shape[1])
            reduced = reduced_dims(self.verify, dim)
            files.update(self._evidence(chunks, heads) if reduced is None else
                         self._reduced_evidence(chunks, heads, dim, reduced))
            if all(h["appearance"] for h in heads):
                files["appearance"] = self._stream("appearance", chunks, (n, heads[0]["appearance_dim"]), np.float16)
        else:
            files["descriptors"] = self._stream("descriptors", chunks, (n, heads[0]["dim"]), np.uint8)
        if all(h["layout"] for h in heads):
            files["layout_values"] = self._stream("layout_values", chunks, (n, heads[0]["layout_dims"][0]), np.uint8)
            files["layout_mask"] = self._stream("layout_mask", chunks, (n, heads[0]["layout_dims"][1]), np.uint8)
        if all(h["has_steps"] for h in heads):
            files["steps"] = self._stream("steps", chunks, (n, 3), np.float64)
        if has_position.all():
            files["positions"] = self._stream("positions", chunks, (n, 2), np.float64)
        if all(h["has_timestamps"] for h in heads):
            files["timestamps"] = self._stream("timestamps", chunks, (n,), np.float64)
        index = None
        if self.with_index:
            descriptors = np.load(self._tmp / "descriptors.npy", mmap_mode="r")
            index = build_index(descriptors, self.kind, self._tmp).to_dict()
            del descriptors
        self.nbytes = sum(entry["bytes"] for entry in files.values()) + (index["bytes"] if index else 0)
        metadata = dict(self.metadata)
        # The map's camera is what its frames declare, unless the caller says otherwise: a declared query
        # camera is read against it (which way the query views and drives the route).
        declared = {str(c) for source in chunks for c in _field(source, "cameras")}
        metadata.setdefault("camera", (declared.pop() or None) if len(declared) == 1 else None)
        profile = _profile(chunks, self.metadata.get("label_names"))
        if profile is not None:
            metadata["input"] = profile.to_dict()
        return {
            "format": MAP_FORMAT,
            "version": MAP_VERSION if "projection" in files else WHOLE_VERSION,
            "kind": self.kind,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "n_frames": n,
            "frames": names,
            "backbone": backbone_dict(self.backbone),
            **metadata,
            "arrays": files,
            "index": index,
        }

    def _stream(self, name: str, chunks: list[MapChunk | Path], shape: tuple[int, ...], dtype: type,
                transform: Callable[[np.ndarray], np.ndarray] | None = None) -> dict[str, Any]:
        """Write one per-frame array block by block."""
        path = self._tmp / f"{name}.npy"
        out = _create(path, dtype, shape)
        row = 0
        for block in _row_blocks(chunks, name):
            out[row : row + len(block)] = transform(block) if transform is not None else block
            row += len(block)
        return _finish(out, path)

    def _evidence(self, chunks: list[MapChunk | Path], heads: list[dict[str, Any]],
                  names: tuple[str, ...] = EVIDENCE) -> dict[str, dict[str, Any]]:
        """The keypoint evidence of every chunk (the arrays ``names``), its slot and entry offsets carried on
        from chunk to chunk."""
        totals = {name: sum(h["lengths"][name] for h in heads) for name in names}
        for name in ("frame_slots", "frame_entries"):
            if name in totals:
                totals[name] -= len(chunks) - 1  # each chunk's closing offset is the next one's opening
        first = _load(chunks[0])
        outs = {name: _create(self._tmp / f"{name}.npy", getattr(first, name).dtype,
                              (totals[name], *getattr(first, name).shape[1:])) for name in names}
        at = dict.fromkeys(names, 0)
        slots = entries = 0
        for source in chunks:
            chunk = _load(source)
            for name in names:
                values = getattr(chunk, name)
                if name == "frame_slots":
                    values = values + slots
                elif name == "frame_entries":
                    values = values + entries
                if name in ("frame_slots", "frame_entries") and at[name]:
                    values = values[1:]
                outs[name][at[name] : at[name] + len(values)] = values
                at[name] += len(values)
            slots += len(chunk.slot_counts)
            entries += len(chunk.slot_values)
        return {name: _finish(out, self._tmp / f"{name}.npy") for name, out in outs.items()}

    def _reduced_evidence(self, chunks: list[MapChunk | Path], heads: list[dict[str, Any]], dim: int,
                          reduced: int) -> dict[str, dict[str, Any]]:
        """The keypoint evidence with each slot's features reduced to a unit vector of ``reduced`` coordinates on
        a projection learnt from an even sample of the map's slots (the same whatever the chunks)."""
        total = sum(h["lengths"]["slot_norms"] for h in heads)
        sample = sample_rows(total)
        picked, first = [], 0
        for source in chunks:
            chunk = _load(source)
            count = len(chunk.slot_norms)
            mine = sample[(sample >= first) & (sample < first + count)] - first
            picked.append(self._slot_features(chunk, mine, dim))
            first += count
        projection = learn_projection(np.concatenate(picked), reduced)
        files = self._evidence(chunks, heads, REDUCED)
        projected = _create(self._tmp / "slot_projected.npy", np.float16, (total, projection.shape[1]))
        at = 0
        for source in chunks:
            chunk = _load(source)
            count = len(chunk.slot_norms)
            for lo in range(0, count, SLOT_BLOCK):
                slots = np.arange(lo, min(lo + SLOT_BLOCK, count))
                rows = project_rows(self._slot_features(chunk, slots, dim), projection)
                projected[at : at + len(rows)] = rows / np.maximum(row_norms(rows), 1e-30)[:, None]
                at += len(rows)
        files["slot_projected"] = _finish(projected, self._tmp / "slot_projected.npy")
        files["projection"] = _write_array(self._tmp / "projection.npy", projection)
        return files

    def _slot_features(self, chunk: MapChunk, rows: np.ndarray, dim: int) -> np.ndarray:
        """(len(rows), D) float32 dense features of a chunk's slots ``rows``, as the backbone gave them."""
        offsets = np.concatenate([[0], np.cumsum(chunk.slot_counts.astype(np.int64))])
        lengths = offsets[rows + 1] - offsets[rows]
        entry = np.repeat(offsets[rows], lengths) + np.arange(int(lengths.sum())) - np.repeat(
            np.cumsum(lengths) - lengths, lengths)
        values = chunk.slot_values[entry].astype(np.float32)
        quant = self.backbone.feature_quantisation if self.backbone else None
        if quant is not None:
            values = (values - quant.zero_point) * quant.scale
        dense = np.zeros((len(rows), dim), dtype=np.float32)
        dense[np.repeat(np.arange(len(rows)), lengths), chunk.slot_channels[entry].astype(np.int64)] = values
        return dense

    def _swap_in(self) -> None:
        old = None
        if self.out.exists():
            old = self.out.parent / f".{self.out.name}.old-{os.getpid()}"
            os.replace(self.out, old)
        os.replace(self._tmp, self.out)
        sync_folder(self.out.parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


def _load(chunk: MapChunk | Path) -> MapChunk:
    return chunk if isinstance(chunk, MapChunk) else MapChunk.load(chunk)


def _field(chunk: MapChunk | Path, name: str) -> np.ndarray:
    """One array of a chunk (read alone from a saved one)."""
    if isinstance(chunk, MapChunk):
        return chunk.head() if name == "head" else getattr(chunk, name)
    with np.load(chunk, allow_pickle=False) as data:
        return data[name]


def _names(chunk: MapChunk | Path) -> np.ndarray:
    return _field(chunk, "names")


def _head(source: MapChunk | Path) -> dict[str, Any]:
    """What the commit must know of a chunk before writing: sizes, which optional arrays it has."""
    head = _field(source, "head")
    n = len(_names(source))
    return {
        "n": n,
        "dim": int(head[0]),
        "appearance": int(head[1]) == n,
        "appearance_dim": int(head[2]),
        "has_position": ~np.isnan(_field(source, "positions")).any(axis=1),
        "has_timestamps": not np.isnan(_field(source, "timestamps")).any(),
        "lengths": dict(zip(EVIDENCE, (int(v) for v in head[3 : 3 + len(EVIDENCE)]))),
        "layout": int(head[3 + len(EVIDENCE)]) == n,
        "layout_dims": (int(head[4 + len(EVIDENCE)]), int(head[5 + len(EVIDENCE)])),
        "has_steps": not np.isnan(_field(source, "steps")).any(),
    }


def _row_blocks(chunks: list[MapChunk | Path], name: str) -> Iterator[np.ndarray]:
    """The per-frame array ``name`` of all chunks, in blocks of ``ROW_BLOCK`` frames whatever the chunks."""
    pending: list[np.ndarray] = []
    held = 0
    for source in chunks:
        rows = _field(source, name)
        while len(rows):
            take = min(len(rows), ROW_BLOCK - held)
            pending.append(rows[:take])
            held += take
            rows = rows[take:]
            if held == ROW_BLOCK:
                yield np.concatenate(pending)
                pending, held = [], 0
    if held:
        yield np.concatenate(pending)


def _profile(chunks: list[MapChunk | Path], label_names: list[str] | None):  # noqa: ANN202 (InputProfile | None)
    builder = ProfileBuilder(label_names)
    for source in chunks:
        for looks, frequencies in zip(_field(source, "looks"), _field(source, "label_frequencies")):
            if not np.isnan(looks[0]):
                builder.add_looks(_looks_of(looks), frequencies if label_names is not None else None)
    return builder.profile()


def _looks_row(looks: Looks | None) -> tuple[float, float, float, float]:
    if looks is None:
        return (np.nan, np.nan, np.nan, np.nan)
    grey = np.nan if looks.greyscale is None else float(looks.greyscale)
    return (float(looks.width), float(looks.height), float(looks.brightness), grey)


def _looks_of(row: np.ndarray) -> Looks:
    grey = None if np.isnan(row[3]) else bool(row[3])
    return Looks(width=int(row[0]), height=int(row[1]), greyscale=grey, brightness=float(row[2]))


def _no_evidence(n: int) -> dict[str, np.ndarray]:
    empty = {name: np.zeros(0, np.int64) for name in EVIDENCE}
    empty["frame_slots"] = empty["frame_entries"] = np.zeros(n + 1, np.int64)
    return empty


def pack_evidence(frames: list[KeypointEvidence], backbone: BackboneInfo | None) -> dict[str, np.ndarray]:
    """The keypoint evidence of consecutive frames as the map stores it (slot and entry offsets from 0)."""
    quant = backbone.feature_quantisation if backbone else None
    frames = [f.sparse() for f in frames]
    values = np.concatenate([f.values for f in frames])
    if quant is not None:
        stored = np.rint(values / quant.scale + quant.zero_point)
        if not np.allclose((stored - quant.zero_point) * quant.scale, values, rtol=0, atol=quant.scale * 1e-3):
            raise MapError("features are not on the backbone's quantisation grid; cannot store them exactly")
        stored = stored.astype(np.uint8)
    else:
        stored = values.astype(np.float16)
    keep = stored != (quant.zero_point if quant else 0)
    slot_of_entry = np.concatenate([np.repeat(np.arange(len(f.slot_keys)), np.diff(f.slot_offsets)) for f in frames])
    first_slot = np.cumsum([0] + [len(f.slot_keys) for f in frames])
    slot_of_entry = slot_of_entry + np.repeat(first_slot[:-1], [len(f.channels) for f in frames])
    counts = np.bincount(slot_of_entry[keep], minlength=first_slot[-1])
    # Frame n's entries start after those of every slot before its first one.
    frame_entries = np.concatenate([[0], np.cumsum(counts)])[first_slot]
    return {
        "keypoints": np.concatenate([f.keypoints for f in frames]).astype(np.int16),
        "labels": np.concatenate([f.labels for f in frames]).astype(np.uint8),
        "frame_slots": first_slot.astype(np.int64),
        "frame_entries": frame_entries.astype(np.int64),
        "slot_locations": np.concatenate([f.slot_keys for f in frames]).astype(np.uint16),
        "slot_counts": counts.astype(np.uint16),
        "slot_norms": np.concatenate([f.slot_norms for f in frames]).astype(np.float32),
        "slot_channels": np.concatenate([f.channels for f in frames])[keep].astype(np.uint16),
        "slot_values": stored[keep],
    }


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())


def _write_array(path: Path, array: np.ndarray) -> dict[str, Any]:
    out = _create(path, array.dtype, array.shape)
    out[...] = array
    return _finish(out, path)


def _create(path: Path, dtype: Any, shape: tuple[int, ...]) -> np.ndarray:
    """An array file to fill in place (memory-mapped; an empty one is written when finished)."""
    if int(np.prod(shape)) == 0:
        return np.zeros(shape, dtype=dtype)
    return open_memmap(path, mode="w+", dtype=dtype, shape=shape)


def _finish(out: np.ndarray, path: Path) -> dict[str, Any]:
    """Flush a written array to the disk and describe it for the manifest."""
    dtype, shape = out.dtype.str, list(out.shape)
    if isinstance(out, np.memmap):
        out.flush()
    else:
        np.save(path, out, allow_pickle=False)
    del out
    with open(path, "rb+") as handle:
        os.fsync(handle.fileno())
    return {"file": path.name, "dtype": dtype, "shape": shape, "bytes": path.stat().st_size,
            "sha256": file_sha256(path)}

