"""A live camera (``camera:N``, an OpenCV device index) as frames, newest first.

A camera does not wait for the localizer. A reader thread takes every frame the
device delivers and keeps only the latest; whoever iterates gets the newest frame
not yet handed out, and frames nobody asked for in time are dropped and counted.
So a slow consumer sees the present, never a queue of the past (OpenCV's own
buffer is read empty as fast as the device fills it).
"""

from __future__ import annotations

import re
import threading
import time
from typing import TYPE_CHECKING, Callable, Iterator, Protocol

import numpy as np

from lostx.core.errors import InputError
from lostx.core.frame import Camera, Frame

from .video import open_capture

if TYPE_CHECKING:
    from lostx.core.geometry import CameraGeometry

PATTERN = re.compile(r"camera:(\d+)")


class Capture(Protocol):
    """What is used of ``cv2.VideoCapture``."""

    def isOpened(self) -> bool: ...  # noqa: N802 (OpenCV's name)

    def read(self) -> tuple[bool, np.ndarray | None]: ...

    def release(self) -> None: ...


def camera_index(source: str) -> int | None:
    """N for a source written ``camera:N``, else None."""
    match = PATTERN.fullmatch(source.strip())
    return int(match.group(1)) if match else None


class LiveCamera:
    """Frames of a camera device, newest first; iterate to receive them, ``close`` to stop."""

    def __init__(
        self,
        index: int,
        camera: Camera | None = None,
        opener: Callable[[int], Capture] = open_capture,
        clock: Callable[[], float] = time.time,
        geometry: CameraGeometry | None = None,
    ) -> None:
        self.index = index
        self.camera = camera
        self.geometry = geometry
        """The camera's intrinsics and mounting (a camera file), carried by every frame."""
        self._capture = opener(index)
        if not self._capture.isOpened():
            self._capture.release()
            raise InputError(f"cannot open camera {index} (camera:{index}): no such device, or it is busy "
                             f"or not permitted")
        self._clock = clock
        self._condition = threading.Condition()
        self._latest: Frame | None = None
        self._stopped = False
        self.failure: str | None = None
        """Why the device stopped delivering frames, once it has."""
        self.captured = 0
        """Frames the device delivered."""
        self.dropped = 0
        """Frames replaced by a newer one before anyone took them."""
        self._thread = threading.Thread(target=self._read_loop, name=f"camera:{index}", daemon=True)
        self._thread.start()

    @property
    def name(self) -> str:
        return f"camera:{self.index}"

    def _read_loop(self) -> None:
        while not self._stopped:
            ok, image = self._capture.read()
            stamp = self._clock()
            with self._condition:
                if self._stopped:
                    return
                if not ok or image is None:
                    self.failure = f"camera {self.index} stopped delivering frames (it gave {self.captured})"
                    self._condition.notify_all()
                    return
                if self._latest is not None:
                    self.dropped += 1
                rgb = np.ascontiguousarray(image[:, :, ::-1]) if image.ndim == 3 else np.stack([image] * 3, axis=2)
                self._latest = Frame(id=self.captured, image=rgb, timestamp=stamp, camera=self.camera,
                                     name=f"{self.name}#{self.captured}", geometry=self.geometry)
                self.captured += 1
                self._condition.notify_all()

    def next_frame(self, timeout: float | None = None) -> Frame | None:
        """The newest frame not yet taken, waiting for one; None after ``timeout`` seconds, once
        the camera is closed, or once the device has stopped (``failure`` says why)."""
        with self._condition:
            self._condition.wait_for(lambda: self._latest is not None or self._stopped or self.failure is not None,
                                     timeout)
            frame, self._latest = self._latest, None
            return frame

    def __iter__(self) -> Iterator[Frame]:
        """Frames until the camera is closed or the device stops."""
        while True:
            frame = self.next_frame()
            if frame is None:
                return
            yield frame

    def close(self) -> None:
        with self._condition:
            self._stopped = True
            self._condition.notify_all()
        self._thread.join(timeout=5)
        self._capture.release()

    def __enter__(self) -> "LiveCamera":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
