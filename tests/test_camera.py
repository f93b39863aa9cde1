"""A live camera (``camera:N``): newest frame first, stale frames dropped, never queued.

No camera exists on the test machines: the dropping is tested with capture objects
that stand in for ``cv2.VideoCapture``, and the error path with the real one.
"""

from __future__ import annotations

import queue
import time

import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.core.images import list_images, read_image
from lostx.replay.camera import LiveCamera, camera_index
from lostx.stream.producer import FramePublisher
from lostx.stream.replay import relay_live

from streamtools import Collector, endpoints, lostx_command, procs, wait_for  # noqa: F401  (fixtures)
from test_cli import assert_one_line_error, lostx


class HandFedCapture:
    """Delivers a frame each time the test hands it one; None ends the stream."""

    def __init__(self, opened: bool = True) -> None:
        self.opened = opened
        self.fed: queue.Queue = queue.Queue()
        self.released = False

    def isOpened(self) -> bool:  # noqa: N802
        return self.opened

    def read(self):
        value = self.fed.get()
        if value is None:
            return False, None
        return True, np.full((24, 32, 3), value, np.uint8)

    def release(self) -> None:
        self.released = True


class FastCapture:
    """A camera delivering ``count`` BGR frames at ``rate`` per second, then stopping."""

    def __init__(self, images: list[np.ndarray], rate: float, count: int) -> None:
        self.images, self.interval, self.count, self.given = images, 1.0 / rate, count, 0
        self.next_at: float | None = None

    def isOpened(self) -> bool:  # noqa: N802
        return True

    def read(self):
        if self.given >= self.count:
            return False, None
        self.next_at = (self.next_at or time.monotonic()) + self.interval
        time.sleep(max(0.0, self.next_at - time.monotonic()))
        image = self.images[self.given % len(self.images)][:, :, ::-1]
        self.given += 1
        return True, image

    def release(self) -> None:
        pass


def test_camera_sources_are_written_camera_n():
    assert camera_index("camera:0") == 0 and camera_index("camera:12") == 12
    assert camera_index("camera0") is None and camera_index("videos/camera:1.mp4") is None


def test_a_slow_reader_gets_the_newest_frame_and_the_older_ones_are_dropped():
    capture = HandFedCapture()
    camera = LiveCamera(0, "front", opener=lambda index: capture, clock=iter(range(100)).__next__)
    try:
        for value in (10, 11, 12):
            capture.fed.put(value)
        wait_for(lambda: camera.captured == 3, 5, "three frames captured")
        frame = camera.next_frame(timeout=5)
        assert (frame.id, int(frame.image[0, 0, 0]), frame.timestamp, frame.camera) == (2, 12, 2, "front")
        assert frame.name == "camera:0#2" and camera.dropped == 2
        assert camera.next_frame(timeout=0.2) is None  # nothing new: never the same frame twice
        capture.fed.put(13)
        assert camera.next_frame(timeout=5).id == 3 and camera.dropped == 2  # taken in time: nothing dropped
        capture.fed.put(None)  # the device stops
        assert camera.next_frame(timeout=5) is None
        assert camera.failure == "camera 0 stopped delivering frames (it gave 4)"
    finally:
        camera.close()
    assert capture.released


def test_a_camera_that_cannot_be_opened_is_one_line():
    closed = HandFedCapture(opened=False)
    with pytest.raises(InputError, match=r"cannot open camera 3 \(camera:3\)"):
        LiveCamera(3, opener=lambda index: closed)
    assert closed.released
    # The real OpenCV capture: there is no camera 9 here (nor any camera at all).
    proc = lostx("replay", "camera:9", "--to", "tcp://127.0.0.1:9")
    assert_one_line_error(proc, "cannot open camera 9 (camera:9)")
    proc = lostx("replay", "camera:9", "--to", "tcp://127.0.0.1:9", "--loop", "--rate", "5")
    assert_one_line_error(proc, "camera:9 is a live camera; --rate, --loop are for recordings only")


def test_a_camera_faster_than_the_localizer_is_answered_newest_first(day_map, robotcar, procs, tmp_path):
    """200 frames/s for 1.5 s into the real service (about 10 frames/s here): frames drop at the camera,
    none queue."""
    frames, results = endpoints("ipc", tmp_path)
    listener = Collector(results, topics=("result",))  # a lossless service answers once someone listens
    procs.start("serve", lostx_command("serve", "--map", str(day_map.path), "--frames", frames, "--results",
                                       results, "--mode", "lossless", "--no-journal"))
    images = [read_image(f) for f in list_images(robotcar / "night")]
    capture = FastCapture(images, rate=200.0, count=300)
    ages: list[int] = []
    with FramePublisher(frames) as publisher:
        publisher.wait_ready(60)  # the camera starts once the service is up, so that all its frames meet it
        camera = LiveCamera(0, opener=lambda index: capture)
        handed = camera.next_frame

        def newest(timeout=None):
            frame = handed(timeout)
            if frame is not None:
                ages.append(camera.captured - 1 - frame.id)  # frames captured after it, when it was handed out
            return frame

        camera.next_frame = newest  # type: ignore[method-assign]
        try:
            summary = relay_live(camera, publisher, progress=False, wait=60, flush_timeout=60)
            wait_for(lambda: len(listener.results) == summary.frames, 30, "every answer")
        finally:
            camera.close()
            listener.stop()
    ids = listener.ids()
    assert ids == sorted(set(ids)) and ids[-1] >= 290  # in order, with gaps, up to the last frames
    assert summary.counts.acked == summary.frames and summary.unanswered == 0  # every frame sent was answered
    assert summary.stale > 0 and summary.frames + summary.stale == 300  # the rest were dropped, not queued
    assert 5 <= summary.frames < 150  # about 10 a second here
    assert max(ages) <= 1  # each frame sent was the newest (or the one before it) when it was taken
    assert "camera frames skipped for newer ones" in summary.line()
