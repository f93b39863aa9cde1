"""Video files through OpenCV (FFmpeg): every frame of the file, timed by its recorded frame rate.

Frame k of a file that declares F frames per second is at ``k / F`` seconds (a
constant rate, as the container declares it). Reading in increasing order is one
pass through the file; going backwards (a reversed traverse) seeks.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from lostx.core.errors import ImageError, InputError
from lostx.core.frame import Camera

from .folder import Traverse
from .store import file_identity

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".ts", ".mts", ".wmv", ".flv")

# FFmpeg reports a damaged file on stderr before OpenCV returns; lostx says it once, on one line.
# Read once, when FFmpeg is first used; a user's own setting is kept.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")


def is_video(path: str | Path) -> bool:
    path = Path(path)
    return path.suffix.lower() in VIDEO_SUFFIXES


@contextmanager
def quiet_opencv() -> Iterator[None]:
    """OpenCV's own warnings off while a capture opens (a failed open is reported by lostx)."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)


def open_capture(source: str | int) -> cv2.VideoCapture:
    with quiet_opencv():
        return cv2.VideoCapture(source)


class VideoFrames:
    """The frames of one video file, decoded on demand (one capture kept open, read forward)."""

    def __init__(self, path: Path, count: int) -> None:
        self.path = path
        self.count = count
        self._capture: cv2.VideoCapture | None = None
        self._next = 0  # the row the open capture decodes next

    @property
    def origin(self) -> Path:
        return self.path

    def __len__(self) -> int:
        return self.count

    def name(self, row: int) -> str:
        return f"{self.path.name}#{row}"

    def read(self, row: int) -> np.ndarray:
        if self._capture is None:
            self._capture = open_capture(str(self.path))
            self._next = 0
        capture = self._capture
        if row < self._next:  # backwards: seek (forwards, decoding is exact on every container)
            capture.set(cv2.CAP_PROP_POS_FRAMES, row)
            self._next = row
        while self._next < row and capture.grab():
            self._next += 1
        ok, image = capture.read()
        if not ok or image is None or self._next != row:
            self.close()
            raise ImageError(f"{self.path}: frame {row} of {self.count} cannot be decoded "
                             f"(the file ends early or is damaged)")
        self._next = row + 1
        return np.ascontiguousarray(image[:, :, ::-1])

    def read_rows(self, rows: Sequence[int]) -> Iterator[np.ndarray]:
        for row in rows:
            yield self.read(int(row))

    def fingerprint(self, rows: Sequence[int]) -> list:
        return [file_identity(self.path), [int(r) for r in rows]]

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None


def video_traverse(path: str | Path, camera: Camera | None = None, mirror: bool = False) -> Traverse:
    """Every frame of a video file, with timestamps from its frame rate."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"video not found: {path}")
    capture = open_capture(str(path))
    try:
        if not capture.isOpened():
            raise InputError(f"cannot read video {path}: not a video file OpenCV can decode")
        ok, first = capture.read()
        if not ok or first is None:
            raise InputError(f"cannot read video {path}: no decodable frame")
        fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        declared = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        notes: list[str] = []
        count = declared if declared > 0 and _decodes(capture, declared - 1) else 0
        if count == 0:
            # The container does not say, or says more than there is (a recording cut short): count by decoding.
            capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
            while capture.grab():
                count += 1
            said = f"declares {declared} frames" if declared > 0 else "declares no frame count"
            notes.append(f"{path.name} {said}: counted {count} by decoding")
    finally:
        capture.release()
    timestamps = None
    if np.isfinite(fps) and fps > 0:
        timestamps = np.arange(count, dtype=np.float64) / fps
    else:
        notes.append(f"{path.name} declares no frame rate: the frames have no timestamps")
    return Traverse(path.name, VideoFrames(path, count), timestamps=timestamps, camera=camera, mirror=mirror,
                    notes=notes)



def _decodes(capture: cv2.VideoCapture, row: int) -> bool:
    """Can frame ``row`` be decoded (the last frame a container declares is not always there)?"""
    capture.set(cv2.CAP_PROP_POS_FRAMES, row)
    ok, image = capture.read()
    return bool(ok) and image is not None
