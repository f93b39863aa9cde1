"""Reference maps on disk: a versioned, atomically written, memory-mapped file set.

A map is a folder::

    manifest.json           format, version, backbone, classes, settings, frames, input (what the
                            frames looked like: lostx.core.inputcheck),
                            and every array's dtype, shape, size and sha256
    descriptors.npy         (N, K) float16 normalised LoST descriptors, or uint8 thumbnails
    stats_mean.npy          (K,) float32  } per-dimension statistics of the raw
    stats_std.npy           (K,) float32  } descriptors, for normalising queries
    appearance.npy          (N, D) float16 GeM-pooled network features (the appearance baseline)
    keypoints.npy           (N, D) int16   arg-max location per channel, -1 = none
    labels.npy              (N, h*w) uint8 grouped semantic labels
    frame_slots.npy         (N+1,) int64   frame n owns slots frame_slots[n]:frame_slots[n+1]
    frame_entries.npy       (N+1,) int64   ... and entries frame_entries[n]:frame_entries[n+1]
    slot_locations.npy      (S,) uint16    flat grid location of each slot
    slot_counts.npy         (S,) uint16    non-zero channels of each slot's feature vector
    slot_norms.npy          (S,) float32   L2 norm of each slot's feature vector
    slot_channels.npy       (E,) uint16    channel of each non-zero entry, slot by slot
    slot_values.npy         (E,)           its value: uint8 as quantised, or float16
    positions.npy           (N, 2) float64 optional
    timestamps.npy          (N,) float64   optional

Verification needs the D-dim features only at each frame's distinct keypoint
locations (its slots). They are stored exactly: a quantised backbone's uint8
values as they came out of the network, or float16 otherwise, and only the
non-zero ones (ReLU features are ~90 % zeros), with a bit mask per slot.

The manifest is written last, into a temporary folder that is renamed into
place, so an interrupted build never leaves a folder that opens as a map.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from .backbones import BackboneInfo, Quantisation
from .errors import MapError
from .keypoints import KeypointEvidence
from .lost import DescriptorStats, standardise
from .outputs import check_output_folder

if TYPE_CHECKING:
    from .calibration import Calibration
    from .config import Config

MAP_FORMAT = "lostx-map"
MAP_VERSION = 1
MapKind = Literal["lost", "thumbnail"]


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
    ) -> None:
        self.out = check_output_folder(out, "map folder")
        if self.out.exists() and not overwrite:
            raise MapError(f"{self.out} already exists; pass --overwrite to replace it")
        if self.out.exists() and not (self.out / "manifest.json").is_file() and any(self.out.iterdir()):
            raise MapError(f"{self.out} exists and is not a lostx map; refusing to replace it")
        self.kind = kind
        self.metadata = metadata
        self.backbone = backbone
        self.overwrite = overwrite
        self.frames: list[MapFrame] = []
        self.cameras: list[str | None] = []
        """The camera each frame declared (the map records it when they agree)."""
        self.nbytes = 0
        """Bytes of the committed map's files."""
        self._tmp = self.out.parent / f".{self.out.name}.partial-{os.getpid()}"

    def __enter__(self) -> "MapWriter":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def add(self, frame: MapFrame) -> None:
        if self.kind == "lost" and frame.evidence is None:
            raise ValueError("a LoST map frame needs its keypoint evidence")
        self.frames.append(frame)

    def commit(self) -> Path:
        if not self.frames:
            raise MapError(f"no frames to write to {self.out}")
        shutil.rmtree(self._tmp, ignore_errors=True)
        self._tmp.mkdir(parents=True)
        try:
            arrays = self._arrays()
            files = {name: _write_array(self._tmp / f"{name}.npy", array) for name, array in arrays.items()}
            self.nbytes = sum(entry["bytes"] for entry in files.values())
            manifest = {
                "format": MAP_FORMAT,
                "version": MAP_VERSION,
                "kind": self.kind,
                "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                "n_frames": len(self.frames),
                "frames": [f.name for f in self.frames],
                "backbone": _backbone_dict(self.backbone),
                **self.metadata,
                "arrays": files,
            }
            _write_bytes(self._tmp / "manifest.json", json.dumps(manifest, indent=1).encode())
            _fsync_dir(self._tmp)
            self._swap_in()
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        return self.out

    def _swap_in(self) -> None:
        old = None
        if self.out.exists():
            old = self.out.parent / f".{self.out.name}.old-{os.getpid()}"
            os.replace(self.out, old)
        os.replace(self._tmp, self.out)
        _fsync_dir(self.out.parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def _arrays(self) -> dict[str, np.ndarray]:
        raw = np.stack([f.descriptor for f in self.frames]).astype(np.float32)
        arrays: dict[str, np.ndarray] = {}
        if self.kind == "lost":
            stats = DescriptorStats.of(raw)
            arrays["descriptors"] = standardise(raw, stats.mean, stats.std).astype(np.float16)
            arrays["stats_mean"] = stats.mean
            arrays["stats_std"] = stats.std
            arrays.update(_pack_evidence([f.evidence for f in self.frames], self.backbone))  # type: ignore[misc]
            if all(f.appearance is not None for f in self.frames):
                arrays["appearance"] = np.stack([f.appearance for f in self.frames]).astype(np.float16)
        else:
            arrays["descriptors"] = np.stack([f.descriptor for f in self.frames]).astype(np.uint8)
        positions = [f.position for f in self.frames]
        if any(p is not None for p in positions):
            if any(p is None for p in positions):
                missing = [f.name for f in self.frames if f.position is None][:3]
                raise MapError(f"positions are given for some frames but not for {', '.join(missing)}")
            arrays["positions"] = np.asarray(positions, dtype=np.float64)
        stamps = [f.timestamp for f in self.frames]
        if all(t is not None for t in stamps):
            arrays["timestamps"] = np.asarray(stamps, dtype=np.float64)
        return arrays


BACKBONE_IDENTITY = {
    "name": "name", "model_md5": "model", "feature_tensor": "feature tensor", "feature_dim": "feature size",
    "grid": "grid",
}
"""What a map records of its backbone that a query backbone must match, and how errors call each."""


def _identity(backbone: dict[str, Any]) -> str:
    h, w = backbone.get("grid", ("?", "?"))
    tensor = f" {backbone['feature_tensor']!r}" if backbone.get("feature_tensor") else ""
    return (f"{backbone.get('name')} (model {backbone.get('model_file')} md5 {backbone.get('model_md5')}, "
            f"features{tensor} {backbone.get('feature_dim')} x {h}x{w})")


def _backbone_dict(info: BackboneInfo | None) -> dict[str, Any] | None:
    if info is None:
        return None
    data = asdict(info)
    data["grid"] = list(info.grid)
    data["class_names"] = list(info.class_names)
    data["default_classes"] = {k: list(v) for k, v in info.default_classes.items()}
    return data


def _pack_evidence(frames: list[KeypointEvidence], backbone: BackboneInfo | None) -> dict[str, np.ndarray]:
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
    array = np.ascontiguousarray(array)
    with open(path, "wb") as handle:
        np.save(handle, array, allow_pickle=False)
        handle.flush()
        os.fsync(handle.fileno())
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return {
        "file": path.name,
        "dtype": array.dtype.str,
        "shape": list(array.shape),
        "bytes": path.stat().st_size,
        "sha256": digest,
    }


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class ReferenceMap:
    """A map opened for matching: descriptors in memory, keypoint evidence memory-mapped."""

    def __init__(self, path: Path, manifest: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        self.path = path
        self.manifest = manifest
        self._arrays = arrays
        self.kind: MapKind = manifest["kind"]
        self.names: list[str] = list(manifest["frames"])
        self.descriptors = np.asarray(arrays["descriptors"], dtype=np.float32 if self.kind == "lost" else np.uint8)
        self.positions: np.ndarray | None = arrays.get("positions")
        self.appearance: np.ndarray | None = (
            np.asarray(arrays["appearance"], dtype=np.float32) if "appearance" in arrays else None
        )
        self.timestamps: np.ndarray | None = arrays.get("timestamps")
        self.backbone: dict[str, Any] | None = manifest.get("backbone")
        if self.kind == "lost":
            self.stats = DescriptorStats(arrays["stats_mean"], arrays["stats_std"], len(self.names))
            q = (self.backbone or {}).get("feature_quantisation")
            self.quantisation = Quantisation(q["scale"], q["zero_point"]) if q else None
            h, w = self.backbone["grid"]  # type: ignore[index]
            self.grid: tuple[int, int] = (int(h), int(w))
            self.feature_dim = int(arrays["keypoints"].shape[1])

    @classmethod
    def open(cls, path: str | Path, verify_checksums: bool = False) -> "ReferenceMap":
        path = Path(path)
        manifest_path = path / "manifest.json"
        if not path.is_dir():
            raise MapError(f"no map at {path}: not a folder (build one with `lostx map build`)")
        if not manifest_path.is_file():
            raise MapError(f"{path} is not a complete lostx map: it has no manifest.json (an interrupted build?)")
        try:
            manifest = json.loads(manifest_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise MapError(f"{manifest_path} is corrupt: {exc}") from None
        if not isinstance(manifest, dict) or manifest.get("format") != MAP_FORMAT:
            raise MapError(f"{manifest_path} is not a lostx map manifest")
        if manifest.get("version") != MAP_VERSION:
            raise MapError(
                f"{path} is map format version {manifest.get('version')}; this lostx reads version "
                f"{MAP_VERSION}: rebuild the map with `lostx map build`"
            )
        arrays = {}
        for name, entry in manifest["arrays"].items():
            arrays[name] = _open_array(path, entry, verify_checksums)
        n = manifest["n_frames"]
        if len(manifest["frames"]) != n or len(arrays["descriptors"]) != n:
            raise MapError(f"{path}: manifest lists {n} frames but the arrays disagree")
        return cls(path, manifest, arrays)

    @property
    def n_frames(self) -> int:
        return len(self.names)

    @property
    def camera(self) -> str:
        """The map's camera direction: a declared query camera is read against it (front where unknown)."""
        return str(self.manifest.get("camera") or "front")

    @property
    def image_root(self) -> Path | None:
        root = self.manifest.get("image_root")
        return Path(root) if root else None

    def image_path(self, index: int) -> Path | None:
        root = self.image_root
        return root / self.names[index] if root else None

    def labels(self, index: int) -> np.ndarray:
        """(h, w) uint8 grouped semantic labels of reference frame ``index`` (LoST maps)."""
        return np.asarray(self._arrays["labels"][index]).reshape(self.grid)

    @property
    def label_names(self) -> list[str]:
        return list(self.manifest.get("label_names", []))

    @property
    def nbytes(self) -> int:
        return sum(int(e["bytes"]) for e in self.manifest["arrays"].values())

    def calibration(self, config: "Config") -> "Calibration | None":
        """The stored calibration measured with these settings, if any (see lostx.core.calibration)."""
        from .calibration import load, settings_key

        return load(self.path, settings_key(config))

    def store_calibration(self, calibration: "Calibration") -> None:
        """Keep a calibration beside the map; a map on a read-only disk simply goes without."""
        from .calibration import store

        try:
            store(self.path, calibration)
        except OSError:
            pass

    def check_backbone(self, info: BackboneInfo) -> None:
        """Refuse queries described by another backbone than the one that built the map: another name, model
        file, feature tensor, feature size or grid is a one-line error naming both sides."""
        mine = self.backbone or {}
        if self.kind != "lost":
            raise MapError(f"{self.path} is a {self.kind} map; it takes no backbone (use --descriptor {self.kind})")
        theirs = _backbone_dict(info) or {}
        # Maps from before the feature tensor was recorded do not compare it.
        differ = [key for key in BACKBONE_IDENTITY if key in mine and mine[key] != theirs[key]]
        if differ:
            raise MapError(
                f"{self.path} was built with backbone {_identity(mine)}, but the query backbone is "
                f"{_identity(theirs)} ({', '.join(BACKBONE_IDENTITY[key] for key in differ)} differ); "
                f"use --backbone {mine.get('name')} with its model, or rebuild the map"
            )

    def evidence(self, indices: np.ndarray | list[int]) -> KeypointEvidence:
        """The keypoint evidence of the frames ``indices`` (in that order), read from the memory map."""
        a = self._arrays
        indices = np.asarray(indices, dtype=np.int64)
        h, w = self.grid
        frame_slots, frame_entries = a["frame_slots"], a["frame_entries"]
        keys, counts, norms, channels, values = [], [], [], [], []
        for c, index in enumerate(indices):
            lo, hi = int(frame_slots[index]), int(frame_slots[index + 1])
            keys.append(np.asarray(a["slot_locations"][lo:hi], dtype=np.int64) + c * h * w)
            counts.append(a["slot_counts"][lo:hi])
            norms.append(a["slot_norms"][lo:hi])
            e0, e1 = int(frame_entries[index]), int(frame_entries[index + 1])
            channels.append(a["slot_channels"][e0:e1])
            values.append(a["slot_values"][e0:e1])
        def joined(parts: list[np.ndarray], dtype: type) -> np.ndarray:
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

        stored = joined(values, np.float32)
        if self.quantisation is not None:
            stored = (stored - self.quantisation.zero_point) * self.quantisation.scale
        return KeypointEvidence(
            keypoints=np.asarray(a["keypoints"][indices], dtype=np.int32),
            labels=np.asarray(a["labels"][indices]),
            slot_keys=joined(keys, np.int64),
            slot_offsets=np.concatenate([[0], np.cumsum(joined(counts, np.int64))]).astype(np.int64),
            channels=joined(channels, np.int32),
            values=stored.astype(np.float32),
            slot_norms=joined(norms, np.float32),
            grid=(h, w),
            feature_dim=self.feature_dim,
        )


def _open_array(root: Path, entry: dict[str, Any], verify_checksum: bool) -> np.ndarray:
    path = root / entry["file"]
    if not path.is_file():
        raise MapError(f"map file missing: {path}")
    size = path.stat().st_size
    if size != entry["bytes"]:
        raise MapError(f"map file {path} is truncated or altered: {size} bytes, the manifest says {entry['bytes']}")
    if verify_checksum and hashlib.sha256(path.read_bytes()).hexdigest() != entry["sha256"]:
        raise MapError(f"map file {path} fails its checksum: it was altered after the build")
    try:
        array = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise MapError(f"map file {path} is corrupt: {exc}") from None
    if list(array.shape) != entry["shape"] or array.dtype.str != entry["dtype"]:
        raise MapError(f"map file {path} holds {array.dtype}{list(array.shape)}, the manifest says {entry['dtype']}{entry['shape']}")
    return array
