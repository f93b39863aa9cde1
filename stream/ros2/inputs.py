"""What a camera frame arriving over ROS 2 is made of besides its pixels: the vehicle's odometry at the image's
stamp and the camera's geometry from its camera info and ``/tf_static``, as the bag reader takes them from a
recording (:mod:`lostx.replay.bag`), and the image decoded with its size checked first.

These work on decoded messages (attribute access), so they are the same for a live topic and a test.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from lostx.core.geometry import CameraGeometry
from lostx.replay.bagcamera import add_transforms, camera_geometry
from lostx.replay.odometry import interpolate_poses
from lostx.replay.rosmsg import COMPRESSED_IMAGE, RAW_IMAGE, image_rgb, pose_yaw, stamp_ns

from ..errors import ProtocolError
from ..images import check_pixels, header_size

ODOMETRY = "nav_msgs/msg/Odometry"
MAX_ODOMETRY = 10_000
"""Odometry messages kept (minutes at the usual 50 Hz: far more than a frame ever waits)."""
MAX_INFOS = 64
"""Camera infos kept per camera, to find the one stamped as a frame is."""


class OdometryTrack:
    """The vehicle's recent poses from an odometry topic, in stamp order, one per stamp."""

    def __init__(self, capacity: int = MAX_ODOMETRY) -> None:
        self.capacity = capacity
        self._times: list[int] = []
        self._poses: list[tuple[float, float, float]] = []
        self.child_frame: str | None = None
        """The vehicle frame the poses are of (the first message's ``child_frame_id``)."""

    def __len__(self) -> int:
        return len(self._times)

    @property
    def newest(self) -> int | None:
        return self._times[-1] if self._times else None

    def add(self, message: Any) -> None:
        """An Odometry message (its pose at its header stamp); one without a heading or a stamp is left out."""
        yaw = pose_yaw(message, ODOMETRY)
        stamp = stamp_ns(message)
        position = message.pose.pose.position
        x, y = float(position.x), float(position.y)
        if yaw is None or stamp == 0 or not (math.isfinite(x) and math.isfinite(y)):
            return
        self.child_frame = self.child_frame or (str(message.child_frame_id).lstrip("/") or None)
        at = bisect.bisect_left(self._times, stamp)
        if at < len(self._times) and self._times[at] == stamp:
            return  # one sample per stamp, the first, as the bag reader keeps
        self._times.insert(at, stamp)
        self._poses.insert(at, (x, y, yaw))
        if len(self._times) > self.capacity:
            del self._times[0], self._poses[0]

    def covers(self, stamp: int) -> bool:
        """Whether a pose stamped at or after ``stamp`` has arrived (so the pose at ``stamp`` is interpolated)."""
        return bool(self._times) and self._times[-1] >= stamp

    def pose_at(self, stamp: int, max_extrapolation_ns: int) -> tuple[float, float, float] | None:
        """The pose (x, y, yaw) at ``stamp``: interpolated between the poses around it; past the newest pose by
        at most ``max_extrapolation_ns``, carried on at the last two poses' speed; None otherwise."""
        times = self._times
        if not times or stamp < times[0]:
            return None
        if stamp <= times[-1]:
            pose = interpolate_poses(np.asarray(times), np.asarray(self._poses), np.asarray([stamp]))[0]
            return float(pose[0]), float(pose[1]), float(pose[2])
        if len(times) < 2 or stamp - times[-1] > max_extrapolation_ns:
            return None
        (t0, p0), (t1, p1) = (times[-2], self._poses[-2]), (times[-1], self._poses[-1])
        ahead = (stamp - t1) / (t1 - t0)
        turn = math.remainder(p1[2] - p0[2], 2.0 * math.pi)
        yaw = math.remainder(p1[2] + ahead * turn, 2.0 * math.pi)
        return p1[0] + ahead * (p1[0] - p0[0]), p1[1] + ahead * (p1[1] - p0[1]), yaw


@dataclass
class Geometry:
    """A camera's geometry as its topics give it, and what to tell the user when that changes."""

    geometry: CameraGeometry | None
    note: str | None


class CameraTopics:
    """One camera's calibration as it arrives: its camera infos (by stamp) and the static transforms."""

    def __init__(self, info_topic: str, rectified: bool, fixed: CameraGeometry | None = None) -> None:
        self.info_topic = info_topic
        self.rectified = rectified
        self.fixed = fixed
        """A camera file's geometry: it replaces the topics' (--camera-file)."""
        self._infos: deque[tuple[int, Any]] = deque(maxlen=MAX_INFOS)
        self._cache: dict[tuple, Geometry] = {}

    def add_info(self, message: Any) -> None:
        self._infos.append((stamp_ns(message), message))

    def has_info(self, stamp: int) -> bool:
        return any(s == stamp for s, _ in self._infos)

    @property
    def any_info(self) -> bool:
        return bool(self._infos)

    def geometry(self, stamp: int, tree: dict[str, tuple[str, np.ndarray]], tree_version: int,
                 vehicle_frame: str | None) -> Geometry:
        """The geometry for a frame stamped ``stamp``: from the camera info stamped as it is, else the newest."""
        if self.fixed is not None:
            return Geometry(self.fixed, None)
        if not self._infos:
            return Geometry(None, f"no camera info on {self.info_topic} yet: no camera geometry")
        info = next((m for s, m in reversed(self._infos) if s == stamp), self._infos[-1][1])
        key = (_info_key(info), tree_version, vehicle_frame)
        found = self._cache.get(key)
        if found is None:
            if len(self._cache) > MAX_INFOS:
                self._cache.clear()
            calibration = camera_geometry(info, tree, self.info_topic, vehicle_frame, self.rectified)
            found = self._cache[key] = Geometry(calibration.geometry, calibration.note)
        return found


def _info_key(info: Any) -> tuple:
    """What of a camera info the geometry depends on."""
    return (int(info.width), int(info.height), str(info.header.frame_id), tuple(info.k), tuple(info.p))


class StaticTransforms:
    """The transform tree of ``/tf_static``, with a version that changes whenever it does."""

    def __init__(self) -> None:
        self.tree: dict[str, tuple[str, np.ndarray]] = {}
        self.version = 0

    def add(self, message: Any) -> None:
        add_transforms(self.tree, message)
        self.version += 1


def decode_image(message: Any, compressed: bool, max_pixels: int) -> np.ndarray:
    """RGB pixels of an Image or CompressedImage, its declared size checked against ``max_pixels`` first;
    :class:`ProtocolError` (``bad_image``, ``image_too_large``) naming what is wrong."""
    from lostx.core.errors import ImageError

    data = message.data
    if compressed:
        kind = "png" if data.startswith(b"\x89PNG") else "jpeg" if data.startswith(b"\xff\xd8") else None
        if kind is not None:
            check_pixels(*header_size(data, kind), max_pixels)
    else:
        check_pixels(int(message.height), int(message.width), max_pixels)
    try:
        return image_rgb(message, COMPRESSED_IMAGE if compressed else RAW_IMAGE)
    except ImageError as exc:
        raise ProtocolError("bad_image", str(exc)) from None
