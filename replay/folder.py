"""A traverse: frames of one recorded drive, read from disk lazily; and the plain folder-of-images reader."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from lostx.core.errors import InputError
from lostx.core.frame import Camera, Frame
from lostx.core.images import list_images, read_image

from .positions import align_positions, read_positions

ImageLoader = Callable[[Path], np.ndarray]


@dataclass
class Traverse:
    """Frames of one recorded traverse, read from disk lazily, in order.

    Every dataset reader returns these, so everything downstream (maps, matching,
    evaluation, replay) sees one shape whatever the format on disk.
    """

    name: str
    files: list[Path]
    positions: np.ndarray | None = None
    """(N, 2) metres (x east, y north) or None. Derived from ``geo`` when that is set."""
    timestamps: np.ndarray | None = None
    """(N,) seconds, or None."""
    camera: Camera | None = None
    """The camera's direction where the source declares it (``None``: not declared)."""
    mirror: bool = False
    """Flip every image left-right (a test of the flip handling, not an opposite view)."""
    loader: ImageLoader | None = None
    """Reads one file as RGB uint8 (e.g. demosaicing raw Bayer); ``read_image`` when None."""
    geo: np.ndarray | None = None
    """(N, 2) latitude, longitude in degrees when the positions came from them. Two traverses'
    local metres are only comparable after projecting both about one origin (``lostx.evaluation.datasets``)."""
    notes: list[str] = field(default_factory=list)
    """What the reader did that a user should know (frames skipped, fallbacks taken)."""
    source_indices: np.ndarray | None = None
    """(N,) index of each frame in the traverse as read, when this is a subset (subsampling)."""

    def __post_init__(self) -> None:
        n = len(self.files)
        for label, array in (("positions", self.positions), ("timestamps", self.timestamps), ("geo", self.geo)):
            if array is not None and len(array) != n:
                raise InputError(f"{self.name}: {len(array)} {label} for {n} images")

    def __len__(self) -> int:
        return len(self.files)

    @property
    def root(self) -> Path:
        return self.files[0].parent

    def image(self, index: int) -> np.ndarray:
        image = (self.loader or read_image)(self.files[index])
        if self.mirror:
            image = np.ascontiguousarray(image[:, ::-1])
        return image

    def frame(self, index: int) -> Frame:
        position = tuple(float(v) for v in self.positions[index]) if self.positions is not None else None
        return Frame(
            id=index,
            image=self.image(index),
            timestamp=float(self.timestamps[index]) if self.timestamps is not None else None,
            camera=self.camera,
            position=position,  # type: ignore[arg-type]
            name=self.files[index].name,
        )

    def __iter__(self) -> Iterator[Frame]:
        for index in range(len(self.files)):
            yield self.frame(index)

    def subset(self, indices: Sequence[int] | np.ndarray, note: str | None = None) -> "Traverse":
        """The frames at ``indices`` (in that order), remembering where each came from."""
        idx = np.asarray(indices, dtype=np.int64)
        if idx.ndim != 1 or (len(idx) and (idx.min() < 0 or idx.max() >= len(self))):
            raise InputError(f"{self.name}: frame indices out of range 0..{len(self) - 1}")
        if len(idx) == 0:
            raise InputError(f"{self.name}: a subset needs at least one frame")
        original = self.source_indices[idx] if self.source_indices is not None else idx
        return replace(
            self,
            files=[self.files[i] for i in idx],
            positions=self.positions[idx] if self.positions is not None else None,
            timestamps=self.timestamps[idx] if self.timestamps is not None else None,
            geo=self.geo[idx] if self.geo is not None else None,
            notes=[*self.notes, *([note] if note else [])],
            source_indices=original,
        )


    def reversed(self) -> "Traverse":
        """The frames in reverse order, as a vehicle driving the route the other way would meet them.

        Timestamps are reflected (t' = t_first + t_last - t) so that they still increase and
        keep their spacing; positions travel with their frames.
        """
        order = np.arange(len(self) - 1, -1, -1)
        out = self.subset(order, note=f"{self.name}: frames in reverse order")
        if self.timestamps is not None:
            out.timestamps = self.timestamps[0] + self.timestamps[-1] - self.timestamps[order]
        out.name = f"{self.name} (reversed)"
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
    return Traverse(Path(images).name, files, coords, stamps, camera, mirror, geo=geo)
