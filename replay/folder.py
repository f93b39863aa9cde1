"""A traverse: frames of one recorded drive, read lazily, in order; and the plain folder-of-images reader."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from lostx.core.errors import InputError
from lostx.core.frame import Camera, Frame
from lostx.core.geometry import CameraGeometry
from lostx.core.images import list_images

from .positions import align_positions, read_positions
from .store import ImageFiles, ImageStore


@dataclass
class Traverse:
    """Frames of one recorded traverse, read lazily, in order.

    Every dataset reader returns these, so everything downstream (maps, matching,
    evaluation, replay) sees one shape whatever the format on disk.
    """

    name: str
    images: ImageStore
    """Where the pixels are (``ImageFiles`` for one file per frame; a list of paths is taken as that)."""
    positions: np.ndarray | None = None
    """(N, 2) metres (x east, y north) or None. Derived from ``geo`` when that is set."""
    timestamps: np.ndarray | None = None
    """(N,) seconds, or None."""
    camera: Camera | None = None
    """The camera's direction where the source declares it (``None``: not declared)."""
    mirror: bool = False
    """Flip every image left-right (a test of the flip handling, not an opposite view)."""
    geo: np.ndarray | None = None
    """(N, 2) latitude, longitude in degrees when the positions came from them. Two traverses'
    local metres are only comparable after projecting both about one origin (``lostx.evaluation.datasets``)."""
    notes: list[str] = field(default_factory=list)
    """What the reader did that a user should know (frames skipped, fallbacks taken)."""
    source_indices: np.ndarray | None = None
    """(N,) row of each frame in the recording as read, when this is a subset (subsampling, reversal)."""
    metadata: dict[str, np.ndarray] = field(default_factory=dict)
    """Per-frame values (each an (N,) array) that each :class:`Frame` carries in its ``metadata``
    (e.g. nuScenes' vehicle and camera headings)."""
    geometry: CameraGeometry | None = None
    """The camera's intrinsics and pose on the vehicle, where the source knows them: a dataset's calibration,
    a bag's camera info and transforms, or a camera file beside the frames."""
    odometry: np.ndarray | None = None
    """(N, 3) the vehicle's pose (x, y metres, yaw radians) in the source's odometry frame at each frame, where
    the source has one (only the motion between frames is used)."""

    def __post_init__(self) -> None:
        if isinstance(self.images, list):
            self.images = ImageFiles(self.images)
        n = len(self)
        arrays = {"positions": self.positions, "timestamps": self.timestamps, "geo": self.geo,
                  "odometry poses": self.odometry, **self.metadata}
        for label, array in arrays.items():
            if array is not None and len(array) != n:
                raise InputError(f"{self.name}: {len(array)} {label} for {n} images")

    def __len__(self) -> int:
        return len(self.source_indices) if self.source_indices is not None else len(self.images)

    @property
    def rows(self) -> np.ndarray:
        """The recording's row of each frame, in this traverse's order."""
        return self.source_indices if self.source_indices is not None else np.arange(len(self.images))

    @property
    def root(self) -> Path:
        """The folder or recording file the frames come from."""
        return self.images.origin

    @property
    def names(self) -> list[str]:
        return [self.images.name(int(row)) for row in self.rows]

    @property
    def files(self) -> list[Path]:
        """The image file of each frame, for traverses stored one file per frame."""
        if not isinstance(self.images, ImageFiles):
            raise InputError(f"{self.name}: the frames are inside {self.root}, not one file each")
        return [self.images.files[int(row)] for row in self.rows]

    def fingerprint(self) -> list:
        """JSON-able identity of the frames shown (recording, choice and order of frames, mirroring)."""
        return [self.images.fingerprint(self.rows), self.mirror]

    def _flip(self, image: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(image[:, ::-1]) if self.mirror else image

    def image(self, index: int) -> np.ndarray:
        return self._flip(self.images.read(int(self.rows[index])))

    def _frame(self, index: int, image: np.ndarray) -> Frame:
        position = tuple(float(v) for v in self.positions[index]) if self.positions is not None else None
        return Frame(
            id=index,
            image=image,
            timestamp=float(self.timestamps[index]) if self.timestamps is not None else None,
            camera=self.camera,
            position=position,  # type: ignore[arg-type]
            name=self.images.name(int(self.rows[index])),
            metadata={key: values[index].item() for key, values in self.metadata.items()},
            geometry=self.geometry,
            odometry=tuple(float(v) for v in self.odometry[index]) if self.odometry is not None else None,  # type: ignore[arg-type]
        )

    def frame(self, index: int) -> Frame:
        return self._frame(index, self.image(index))

    def __iter__(self) -> Iterator[Frame]:
        for index, image in enumerate(self.images.read_rows(self.rows)):
            yield self._frame(index, self._flip(image))

    def subset(self, indices: Sequence[int] | np.ndarray, note: str | None = None) -> "Traverse":
        """The frames at ``indices`` (in that order), remembering where each came from."""
        idx = np.asarray(indices, dtype=np.int64)
        if idx.ndim != 1 or (len(idx) and (idx.min() < 0 or idx.max() >= len(self))):
            raise InputError(f"{self.name}: frame indices out of range 0..{len(self) - 1}")
        if len(idx) == 0:
            raise InputError(f"{self.name}: a subset needs at least one frame")
        return replace(
            self,
            positions=self.positions[idx] if self.positions is not None else None,
            timestamps=self.timestamps[idx] if self.timestamps is not None else None,
            geo=self.geo[idx] if self.geo is not None else None,
            odometry=self.odometry[idx] if self.odometry is not None else None,
            notes=[*self.notes, *([note] if note else [])],
            source_indices=self.rows[idx],
            metadata={key: values[idx] for key, values in self.metadata.items()},
        )

    def reversed(self) -> "Traverse":
        """The frames in reverse order, as a vehicle driving the route the other way would meet them.

        Timestamps are reflected (t' = t_first + t_last - t) so that they still increase and
        keep their spacing; positions travel with their frames. A declared camera direction is
        relative to the direction of travel, so it turns round too: a rear camera played backwards
        looks where a front camera of the vehicle driving the other way looks.
        """
        order = np.arange(len(self) - 1, -1, -1)
        out = self.subset(order, note=f"{self.name}: frames in reverse order")
        if self.timestamps is not None:
            out.timestamps = self.timestamps[0] + self.timestamps[-1] - self.timestamps[order]
        out.name = f"{self.name} (reversed)"
        out.camera = {"front": "rear", "rear": "front"}.get(self.camera) if self.camera else None  # type: ignore[assignment]
        return out


def folder_traverse(
    images: str | Path, positions: str | Path | None = None, camera: Camera | None = None, mirror: bool = False
) -> Traverse:
    """A folder of images in name order, with an optional positions CSV (see ``replay.positions``)."""
    files = list_images(images)
    coords = stamps = geo = None
    if positions is not None:
        table = read_positions(positions)
        coords, stamps, geo = align_positions(table, [f.name for f in files], Path(positions))
    return Traverse(Path(images).name, ImageFiles(files), coords, stamps, camera, mirror, geo=geo)
