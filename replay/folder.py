"""A traverse stored as a folder of images in name order, with an optional positions CSV."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from lostx.core.frame import Camera, Frame
from lostx.core.images import list_images, read_image

from .positions import align_positions, read_positions


@dataclass
class Traverse:
    """Frames of one recorded traverse, read from disk lazily, in order."""

    name: str
    files: list[Path]
    positions: np.ndarray | None = None
    timestamps: np.ndarray | None = None
    camera: Camera = "front"
    mirror: bool = False
    """Flip every image left-right (a test of the flip handling, not an opposite view)."""

    def __len__(self) -> int:
        return len(self.files)

    @property
    def root(self) -> Path:
        return self.files[0].parent

    def frame(self, index: int) -> Frame:
        image = read_image(self.files[index])
        if self.mirror:
            image = np.ascontiguousarray(image[:, ::-1])
        position = tuple(float(v) for v in self.positions[index]) if self.positions is not None else None
        return Frame(
            id=index,
            image=image,
            timestamp=float(self.timestamps[index]) if self.timestamps is not None else None,
            camera=self.camera,
            position=position,  # type: ignore[arg-type]
            name=self.files[index].name,
        )

    def __iter__(self) -> Iterator[Frame]:
        for index in range(len(self.files)):
            yield self.frame(index)


def folder_traverse(
    images: str | Path, positions: str | Path | None = None, camera: Camera = "front", mirror: bool = False
) -> Traverse:
    files = list_images(images)
    coords = stamps = None
    if positions is not None:
        coords, stamps = align_positions(read_positions(positions), [f.name for f in files], Path(positions))
    return Traverse(Path(images).name, files, coords, stamps, camera, mirror)
