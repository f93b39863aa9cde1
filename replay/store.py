"""Where a traverse's images are kept: one file per frame, or many frames inside one recording.

A :class:`~lostx.replay.folder.Traverse` reads its pixels through an :class:`ImageStore`.
Rows are the frames of the recording as read (0..N-1); a traverse that is a subset,
a decimation or a reversal of it holds the rows it shows, in its own order. Stores of
recordings that are expensive to seek in (video, bags) read increasing rows in one pass.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator, Protocol, Sequence

import numpy as np

from lostx.core.images import read_image

ImageLoader = Callable[[Path], np.ndarray]


class ImageStore(Protocol):
    """Frames by row: their names, their pixels (RGB uint8), and what identifies them on disk."""

    @property
    def origin(self) -> Path:
        """The folder or the recording file the frames come from."""
        ...

    def __len__(self) -> int: ...

    def name(self, row: int) -> str:
        """A label of the frame for tables and logs (a file name, a message stamp, a frame number)."""
        ...

    def read(self, row: int) -> np.ndarray: ...

    def read_rows(self, rows: Sequence[int]) -> Iterator[np.ndarray]:
        """The images of ``rows`` in that order; one pass through the recording when they increase."""
        ...

    def fingerprint(self, rows: Sequence[int]) -> list:
        """JSON-able identity of these frames: changes when the recording or the choice of frames does."""
        ...


class ImageFiles:
    """One image file per frame, read with ``loader`` (RGB uint8)."""

    def __init__(self, files: list[Path], loader: ImageLoader = read_image) -> None:
        self.files = list(files)
        self.loader = loader

    @property
    def origin(self) -> Path:
        return self.files[0].parent

    def __len__(self) -> int:
        return len(self.files)

    def name(self, row: int) -> str:
        return self.files[row].name

    def read(self, row: int) -> np.ndarray:
        return self.loader(self.files[row])

    def read_rows(self, rows: Sequence[int]) -> Iterator[np.ndarray]:
        for row in rows:
            yield self.read(int(row))

    def fingerprint(self, rows: Sequence[int]) -> list:
        out = []
        for row in rows:
            stat = self.files[int(row)].stat()
            out.append((self.files[int(row)].name, stat.st_size, stat.st_mtime_ns))
        return out


def file_identity(path: Path) -> list:
    """A recording file's name, size and modification time (what a cache key needs of it)."""
    stat = path.stat()
    return [path.name, stat.st_size, stat.st_mtime_ns]
