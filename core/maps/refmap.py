"""Reference maps on disk: a versioned, atomically written, memory-mapped file set.

A map is a folder::

    manifest.json           format, version, backbone, classes, settings, frames, input (what the
                            frames looked like: lostx.core.describe.inputcheck),
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
    projection.npy          (D, k) float32 } instead of the slot norms, counts, channels and values, for
    slot_projected.npy      (S, k) float16 } features wider than [verify] reduce_above (format version 2):
                                             each slot's unit vector on the map's own projection
                                             (lostx.core.describe.reduce)
    positions.npy           (N, 2) float64 optional
    timestamps.npy          (N,) float64   optional

Verification needs the D-dim features only at each frame's distinct keypoint
locations (its slots). They are stored exactly: a quantised backbone's uint8
values as they came out of the network, or float16 otherwise, and only the
non-zero ones (ReLU features are ~90 % zeros), with a bit mask per slot.

    index.faiss             the approximate index of the descriptors (lostx.core.maps.index)

The manifest is written last, into a temporary folder that is renamed into
place, so an interrupted build never leaves a folder that opens as a map
(lostx.core.maps.mapwriter writes maps).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..backbones import BackboneInfo, Quantisation
from ..config import LayoutConfig
from ..describe.keypoints import KeypointEvidence
from ..describe.lost import DescriptorStats
from ..errors import MapError
from ..frame import Heading
from ..geometry import CameraGeometry
from ..layout.compare import GridStack, StoredGrids
from ..layout.grid import LayoutGrid, grid_shape, holds_both, stored_half, unpack
from ..motion.odometer import forwards
from .format import BACKBONE_IDENTITY, MAP_FORMAT, READABLE_VERSIONS, MapKind, backbone_dict, backbone_identity
from .index import ApproximateIndex, file_sha256


class ReferenceMap:
    """A map opened for matching: its arrays memory-mapped, the descriptors (LoST and appearance) read into memory
    when every map frame is compared."""

    def __init__(self, path: Path, manifest: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        self.path = path
        self.manifest = manifest
        self._arrays = arrays
        self.kind: MapKind = manifest["kind"]
        self.names: list[str] = list(manifest["frames"])
        self._descriptors: np.ndarray | None = None
        self.positions: np.ndarray | None = arrays.get("positions")
        self._appearance: np.ndarray | None = None
        self.timestamps: np.ndarray | None = arrays.get("timestamps")
        self._index: ApproximateIndex | None = None
        self._layout_stacks: dict[bool, GridStack] = {}
        self._stored_grids: dict[bool, StoredGrids] = {}
        self.backbone: dict[str, Any] | None = manifest.get("backbone")
        if self.kind == "lost":
            self.stats = DescriptorStats(arrays["stats_mean"], arrays["stats_std"], len(self.names))
            q = (self.backbone or {}).get("feature_quantisation")
            self.quantisation = Quantisation(q["scale"], q["zero_point"]) if q else None
            h, w = self.backbone["grid"]  # type: ignore[index]
            self.grid: tuple[int, int] = (int(h), int(w))
            self.feature_dim = int(arrays["keypoints"].shape[1])
            self.projection: np.ndarray | None = (
                np.asarray(arrays["projection"], dtype=np.float32) if "projection" in arrays else None)

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
        if manifest.get("version") not in READABLE_VERSIONS:
            raise MapError(
                f"{path} is map format version {manifest.get('version')}; this lostx reads versions "
                f"{', '.join(map(str, READABLE_VERSIONS))}: rebuild the map with `lostx map build`"
            )
        arrays = {}
        for name, entry in manifest["arrays"].items():
            arrays[name] = _open_array(path, entry, verify_checksums)
        if manifest.get("index"):
            _check_file(path, manifest["index"], verify_checksums)
        n = manifest["n_frames"]
        if len(manifest["frames"]) != n or len(arrays["descriptors"]) != n:
            raise MapError(f"{path}: manifest lists {n} frames but the arrays disagree")
        return cls(path, manifest, arrays)

    @property
    def n_frames(self) -> int:
        return len(self.names)

    @property
    def index(self) -> ApproximateIndex | None:
        """The map's approximate index (lostx.core.maps.index), opened on first use; None for a map built without."""
        entry = self.manifest.get("index")
        if self._index is None and entry:
            self._index = ApproximateIndex(self.path / entry["file"], self.n_frames)
        return self._index

    @property
    def descriptors(self) -> np.ndarray:
        """(N, K) every map descriptor in memory: float32 normalised LoST descriptors, or uint8 thumbnails.
        Read on first use (an exact search over the whole map needs them; the index does not)."""
        if self._descriptors is None:
            self._descriptors = np.asarray(self._arrays["descriptors"], dtype=self._descriptor_dtype)
        return self._descriptors

    @property
    def has_appearance(self) -> bool:
        """Whether the map holds its frames' GeM descriptors (the appearance cue's)."""
        return "appearance" in self._arrays

    @property
    def appearance(self) -> np.ndarray | None:
        """(N, D) every frame's GeM descriptor in memory (float32), None for a map without them. Read on first use:
        only a comparison with every map frame needs them all (:meth:`appearance_rows` reads a few)."""
        if self._appearance is None and self.has_appearance:
            self._appearance = np.asarray(self._arrays["appearance"], dtype=np.float32)
        return self._appearance

    def appearance_rows(self, indices: np.ndarray) -> np.ndarray:
        """The GeM descriptors of map frames ``indices`` (float32), from memory or from the memory map."""
        return self._rows(self._appearance, "appearance", indices, np.float32)

    def descriptor_rows(self, indices: np.ndarray) -> np.ndarray:
        """The descriptors of map frames ``indices``, read from memory or from the memory map."""
        return self._rows(self._descriptors, "descriptors", indices, self._descriptor_dtype)

    def _rows(self, in_memory: np.ndarray | None, name: str, indices: np.ndarray, dtype: type) -> np.ndarray:
        """Rows ``indices`` of array ``name``: from its copy in memory where it was read whole, else from the memory
        map."""
        source = in_memory if in_memory is not None else self._arrays[name]
        return np.asarray(source[np.asarray(indices, dtype=np.int64)], dtype=dtype)

    @property
    def _descriptor_dtype(self) -> type:
        return np.float32 if self.kind == "lost" else np.uint8

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
        index = self.manifest.get("index") or {}
        return sum(int(e["bytes"]) for e in self.manifest["arrays"].values()) + int(index.get("bytes", 0))

    @property
    def layout_settings(self) -> LayoutConfig | None:
        """The grid settings the map's layout was built with (None: a map without a layout)."""
        recorded = self.manifest.get("layout")
        if not recorded or "layout_values" not in self._arrays:
            return None
        return LayoutConfig(**recorded["settings"])

    @property
    def camera_geometry(self) -> CameraGeometry | None:
        """The camera the map's frames were taken with, where it was known."""
        recorded = (self.manifest.get("layout") or {}).get("geometry")
        return CameraGeometry(**recorded, source=str(self.path)) if recorded else None

    @property
    def stores_other_ends(self) -> bool:
        """Whether each frame's grid is also stored as the other end of its stretch views it (maps built before
        that compare a query under the opposite heading with the grid as the map's camera saw it)."""
        settings = self.layout_settings
        if settings is None:
            return False
        return holds_both(self._arrays["layout_values"], grid_shape(settings))

    def layout_grid(self, index: int, heading: Heading = "same") -> LayoutGrid:
        """Map frame ``index``'s layout grid (a map with a layout), as a query under ``heading`` is compared with
        it: as the map's camera viewed the stretch, or (``opposite``) as the camera at its other end views it, turned
        back to face the same way (the two differ where the road bends, :mod:`lostx.core.layout.curve`)."""
        settings = self.layout_settings
        assert settings is not None
        shape = grid_shape(settings)
        return unpack(*stored_half(self._arrays["layout_values"][index], self._arrays["layout_mask"][index], shape,
                                   heading == "opposite"), shape)

    def layout_stack(self, heading: Heading = "same") -> GridStack:
        """Every map frame's layout grid as :meth:`layout_grid` gives it, ready to compare (read once, on first
        use; one stack for both headings on a map that stores no other ends)."""
        stored = self.stored_grids(heading)
        if stored.other_end not in self._layout_stacks:
            self._layout_stacks[stored.other_end] = stored.whole()
        return self._layout_stacks[stored.other_end]

    def stored_grids(self, heading: Heading = "same") -> StoredGrids:
        """The map frames' layout grids as :meth:`layout_stack` gives them, left in the memory map and read a few at a
        time (one object for both headings on a map that stores no other ends)."""
        other_end = heading == "opposite" and self.stores_other_ends
        if other_end not in self._stored_grids:
            settings = self.layout_settings
            assert settings is not None
            self._stored_grids[other_end] = StoredGrids(self._arrays["layout_values"], self._arrays["layout_mask"],
                                                        grid_shape(settings), other_end)
        return self._stored_grids[other_end]

    @property
    def progress(self) -> np.ndarray | None:
        """(N,) metres along the map's route at each frame, rising with the index: the distance its camera
        travelled, where its motion is known (None otherwise). Its sign is in :attr:`progress_sign`."""
        steps = self._arrays.get("steps")
        if steps is None:
            return None
        steps = np.asarray(steps, dtype=np.float64)
        return np.concatenate([[0.0], np.cumsum(np.hypot(steps[1:, 0], steps[1:, 1]))])

    @property
    def progress_sign(self) -> int:
        """+1 where the map's vehicle drove forwards (whichever way its camera looks), -1 where it reversed."""
        steps = self._arrays.get("steps")
        geometry = self.camera_geometry
        yaw = geometry.yaw if geometry is not None else 0.0
        return -1 if steps is not None and float(np.sum(forwards(np.asarray(steps)[1:], yaw))) < 0 else 1

    def check_backbone(self, info: BackboneInfo) -> None:
        """Refuse queries described by another backbone than the one that built the map: another name, model
        file, feature tensor, feature size or grid is a one-line error naming both sides."""
        mine = self.backbone or {}
        if self.kind != "lost":
            raise MapError(f"{self.path} is a {self.kind} map; it takes no backbone (use --descriptor {self.kind})")
        theirs = backbone_dict(info) or {}
        # Maps from before the feature tensor was recorded do not compare it.
        differ = [key for key in BACKBONE_IDENTITY if key in mine and mine[key] != theirs[key]]
        if differ:
            raise MapError(
                f"{self.path} was built with backbone {backbone_identity(mine)}, but the query backbone is "
                f"{backbone_identity(theirs)} ({', '.join(BACKBONE_IDENTITY[key] for key in differ)} differ); "
                f"use --backbone {mine.get('name')} with its model, or rebuild the map"
            )

    def query_evidence(self, evidence: KeypointEvidence) -> KeypointEvidence:
        """A query's keypoint evidence as this map's is compared: projected where the map's descriptors are."""
        return evidence if self.projection is None else evidence.projected(self.projection)

    def evidence(self, indices: np.ndarray | list[int]) -> KeypointEvidence:
        """The keypoint evidence of the frames ``indices`` (in that order), read from the memory map."""
        a = self._arrays
        indices = np.asarray(indices, dtype=np.int64)
        if self.projection is not None:
            return self._projected_evidence(indices)
        h, w = self.grid
        lo, hi, slot_keys = self._slots(indices)
        frame_entries = np.asarray(a["frame_entries"])
        e0, e1 = frame_entries[indices], frame_entries[indices + 1]
        stored = _runs(a["slot_values"], e0, e1).astype(np.float32)
        counts = _runs(a["slot_counts"], lo, hi).astype(np.int64)
        if self.quantisation is not None:
            stored = (stored - self.quantisation.zero_point) * self.quantisation.scale
        return KeypointEvidence(
            keypoints=np.asarray(a["keypoints"][indices], dtype=np.int32),
            labels=np.asarray(a["labels"][indices]),
            slot_keys=slot_keys,
            slot_offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            channels=_runs(a["slot_channels"], e0, e1).astype(np.int32),
            values=stored.astype(np.float32),
            slot_norms=_runs(a["slot_norms"], lo, hi).astype(np.float32),
            grid=(h, w),
            feature_dim=self.feature_dim,
        )

    def _slots(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frames ``indices``' runs of slots (their starts and ends in the slot arrays) and the slots' keys:
        their grid locations, the c-th frame's offset by c grids."""
        frame_slots = np.asarray(self._arrays["frame_slots"])
        lo, hi = frame_slots[indices], frame_slots[indices + 1]
        h, w = self.grid
        frame = np.repeat(np.arange(len(indices), dtype=np.int64), hi - lo)
        return lo, hi, _runs(self._arrays["slot_locations"], lo, hi).astype(np.int64) + frame * h * w

    def _projected_evidence(self, indices: np.ndarray) -> KeypointEvidence:
        a = self._arrays
        h, w = self.grid
        lo, hi, slot_keys = self._slots(indices)
        return KeypointEvidence(
            keypoints=np.asarray(a["keypoints"][indices], dtype=np.int32),
            labels=np.asarray(a["labels"][indices]),
            slot_keys=slot_keys,
            slot_offsets=np.zeros(len(slot_keys) + 1, dtype=np.int64),
            channels=np.zeros(0, np.int32),
            values=np.zeros(0, np.float32),
            slot_norms=np.ones(len(slot_keys), np.float32),
            grid=(h, w),
            feature_dim=self.feature_dim,
            reduced=half_to_single(_runs(a["slot_projected"], lo, hi)),
        )


def _runs(array: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The rows lo[0]:hi[0], lo[1]:hi[1], ... of ``array``, one run after the other (copying runs is twice as fast
    as indexing their every row)."""
    rows = np.asarray(array)  # a plain view of a memory map: its slices are cheaper to make
    return np.concatenate([rows[:0]] + [rows[start:stop] for start, stop in zip(lo, hi)])


def half_to_single(half: np.ndarray) -> np.ndarray:
    """float16 values as float32, exactly.

    numpy converts float16 value by value in software (about 1 ns a value where its build's baseline has no
    half-precision instructions: most of the read of a 960-channel map's candidates). A finite half's sign,
    exponent and mantissa move into a single's places by one shift, and its value is then off by 2^112, the
    difference of the two exponent biases: four whole-array operations. Infinities and NaNs go numpy's way.
    """
    if half.size and (half.view(np.uint16) & 0x7FFF).max() >= 0x7C00:  # an infinity or NaN: an all-ones exponent
        return half.astype(np.float32)
    single = half.view(np.int16).astype(np.int32)  # sign-extended
    np.left_shift(single, 13, out=single)  # the sign to bit 31 (and copied into bits 28-30), the rest to their places
    np.bitwise_and(single, np.int32(-0x70000001), out=single)  # 0x8fffffff: the copies cleared
    return np.multiply(single.view(np.float32), np.float32(2.0**112), out=single.view(np.float32))


def _check_file(root: Path, entry: dict[str, Any], verify_checksum: bool) -> Path:
    path = root / entry["file"]
    if not path.is_file():
        raise MapError(f"map file missing: {path}")
    size = path.stat().st_size
    if size != entry["bytes"]:
        raise MapError(f"map file {path} is truncated or altered: {size} bytes, the manifest says {entry['bytes']}")
    if verify_checksum and file_sha256(path) != entry["sha256"]:
        raise MapError(f"map file {path} fails its checksum: it was altered after the build")
    return path


def _open_array(root: Path, entry: dict[str, Any], verify_checksum: bool) -> np.ndarray:
    path = _check_file(root, entry, verify_checksum)
    try:
        array = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise MapError(f"map file {path} is corrupt: {exc}") from None
    if list(array.shape) != entry["shape"] or array.dtype.str != entry["dtype"]:
        raise MapError(f"map file {path} holds {array.dtype}{list(array.shape)}, the manifest says {entry['dtype']}{entry['shape']}")
    return array
