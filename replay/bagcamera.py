"""A bag's camera geometry: the intrinsics of its ``sensor_msgs/CameraInfo`` and the camera's pose on the
vehicle from its static transforms (``/tf_static``, ``tf2_msgs/TFMessage``).

The camera info is the image topic's sibling ``camera_info`` (``/cam/image_raw`` and
``/cam/image_raw/compressed`` -> ``/cam/camera_info``), or the bag's only CameraInfo topic. Its
``header.frame_id`` is the camera's optical frame (REP 103: x right, y down, z forward), whose pose
in the vehicle's base frame the transforms give: ``base_footprint`` (on the ground, REP 120), else the
pose topic's child frame (an Odometry's ``child_frame_id``), else ``base_link``. lostx takes the
base frame's origin to be on the road; a base frame at axle height makes the camera's height too
small by as much (give a camera file then). A bag without these is read without geometry (noted):
place recognition does not need it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from lostx.core.errors import InputError
from lostx.core.geometry import CameraGeometry

from .rosmsg import CAMERA_INFO, TF_MESSAGE, camera_intrinsics, transform_matrix


class Topic(Protocol):
    """What is used of a bag's topic (:class:`lostx.replay.bag.Topic`)."""

    name: str
    schema: str


class BagFile(Protocol):
    """What is used of an open bag file (:class:`lostx.replay.bag.BagFile`)."""

    def messages(self, topic: str) -> Iterator[tuple[int, Callable[[], Any]]]: ...

BASE_FRAMES = ("base_footprint", "base_link")
TRANSPORTS = ("compressed", "compressedDepth", "theora", "zstd", "ffmpeg", "h264")
"""image_transport suffixes: ``/cam/image_raw/compressed`` is a transport of ``/cam/image_raw``."""


@dataclass
class BagCamera:
    """What a bag says about its camera: the geometry where it says enough, else why not."""

    geometry: CameraGeometry | None
    note: str | None = None


def camera_info_topic(image_topic: str, topics: dict[str, Topic]) -> Topic | None:
    """The CameraInfo topic that goes with ``image_topic`` (see the module docstring)."""
    parts = image_topic.rstrip("/").split("/")
    if len(parts) > 2 and parts[-1] in TRANSPORTS:
        parts = parts[:-1]
    sibling = "/".join([*parts[:-1], "camera_info"])
    found = topics.get(sibling)
    if found is not None and found.schema == CAMERA_INFO:
        return found
    infos = [t for t in topics.values() if t.schema == CAMERA_INFO]
    return infos[0] if len(infos) == 1 else None


def static_transforms(bags: list[BagFile], topics: dict[str, Topic]) -> dict[str, tuple[str, np.ndarray]]:
    """child frame -> (parent frame, the child's pose in the parent) from every ``tf_static`` topic."""
    tree: dict[str, tuple[str, np.ndarray]] = {}
    for topic in topics.values():
        if topic.schema != TF_MESSAGE or not topic.name.rstrip("/").endswith("tf_static"):
            continue
        for bag in bags:
            for _, decode in bag.messages(topic.name):
                add_transforms(tree, decode())
    return tree


def add_transforms(tree: dict[str, tuple[str, np.ndarray]], message: Any) -> None:
    """Put the transforms of a ``tf2_msgs/TFMessage`` into ``tree`` (child frame -> parent, pose)."""
    for stamped in message.transforms:
        child, parent = _frame(stamped.child_frame_id), _frame(stamped.header.frame_id)
        tree[child] = (parent, transform_matrix(stamped.transform))


def _frame(name: str) -> str:
    return str(name).lstrip("/")  # ROS 1 habits: "/base_link" is "base_link"


def _to_root(tree: dict[str, tuple[str, np.ndarray]], frame: str) -> tuple[str, np.ndarray]:
    """The root of ``frame``'s tree and ``frame``'s pose in it."""
    pose = np.eye(4)
    seen = {frame}
    while frame in tree:
        frame, step = tree[frame]
        if frame in seen:
            raise InputError(f"the static transforms loop through {frame}")
        seen.add(frame)
        pose = step @ pose
    return frame, pose


def pose_in(tree: dict[str, tuple[str, np.ndarray]], frame: str, base: str) -> np.ndarray | None:
    """``frame``'s pose in ``base`` (4 x 4), or None when the transforms do not connect them."""
    root, frame_pose = _to_root(tree, frame)
    base_root, base_pose = _to_root(tree, base)
    if root != base_root:
        return None
    return np.linalg.inv(base_pose) @ frame_pose


def bag_camera(bags: list[BagFile], topics: dict[str, Topic], image_topic: str,
               pose_child: str | None, rectified: bool) -> BagCamera:
    """The camera geometry of ``image_topic`` from the bag's camera info and static transforms."""
    info_topic = camera_info_topic(image_topic, topics)
    if info_topic is None:
        return BagCamera(None)  # no calibration recorded: nothing to say
    info = _first(bags, info_topic.name)
    if info is None:
        return BagCamera(None, f"{info_topic.name} has no messages: no camera geometry")
    return camera_geometry(info, static_transforms(bags, topics), info_topic.name, pose_child, rectified)


def camera_geometry(info: Any, tree: dict[str, tuple[str, np.ndarray]], info_topic: str, pose_child: str | None,
                    rectified: bool) -> BagCamera:
    """The camera geometry of a ``sensor_msgs/CameraInfo`` (from ``info_topic``) placed on the vehicle by the static
    transforms ``tree`` (:func:`static_transforms`): a recording's or a live topic's alike."""
    intrinsics, width, height = camera_intrinsics(info, rectified)
    camera_frame = _frame(info.header.frame_id)
    if width <= 0 or height <= 0 or not camera_frame:
        return BagCamera(None, f"{info_topic} gives no image size or frame_id: no camera geometry")
    candidates = [f for f in (BASE_FRAMES[0], pose_child, BASE_FRAMES[1]) if f]
    known = set(tree) | {parent for parent, _ in tree.values()}
    for base in candidates:
        try:
            pose = pose_in(tree, camera_frame, base) if base in known else None
        except InputError as exc:
            return BagCamera(None, f"no camera geometry: {exc}")
        if pose is not None:
            source = f"{info_topic} and /tf_static ({camera_frame} in {base})"
            try:
                geometry = CameraGeometry.from_pose(intrinsics, pose[:3, :3], pose[:3, 3], width, height,
                                                    source=source)
            except InputError as exc:
                return BagCamera(None, f"no camera geometry: {exc} (is {camera_frame} the camera's optical frame, "
                                       f"z forward, y down? give --camera-file otherwise)")
            return BagCamera(geometry)
    return BagCamera(None, f"{info_topic} is there, but /tf_static has no transform from {camera_frame} to "
                           f"{' or '.join(dict.fromkeys(candidates))}: no camera geometry (give --camera-file)")


def _first(bags: list[BagFile], topic: str) -> Any:
    for bag in bags:
        for _, decode in bag.messages(topic):
            return decode()
    return None
