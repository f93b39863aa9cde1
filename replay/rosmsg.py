"""ROS 2 messages as lostx needs them: camera images as RGB pixels, poses as positions and headings,
camera info as intrinsics, transforms as matrices, header stamps.

Works on messages decoded by ``mcap-ros2-support`` (attribute access, ``bytes`` for
``uint8[]``), so no ROS installation is involved.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from lostx.core.errors import ImageError
from lostx.core.geometry import quaternion_matrix

RAW_IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (RAW_IMAGE, COMPRESSED_IMAGE)
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
POSE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped",
              "geometry_msgs/msg/PoseWithCovarianceStamped", NAV_SAT_FIX)
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

# encoding -> (channels, bytes per channel, conversion to RGB from the array as stored; None: already RGB)
_RAW: dict[str, tuple[int, int, int | None]] = {
    "rgb8": (3, 1, None), "bgr8": (3, 1, cv2.COLOR_BGR2RGB), "8UC3": (3, 1, cv2.COLOR_BGR2RGB),
    "rgba8": (4, 1, cv2.COLOR_RGBA2RGB), "bgra8": (4, 1, cv2.COLOR_BGRA2RGB), "8UC4": (4, 1, cv2.COLOR_BGRA2RGB),
    "mono8": (1, 1, cv2.COLOR_GRAY2RGB), "8UC1": (1, 1, cv2.COLOR_GRAY2RGB),
    "rgb16": (3, 2, None), "bgr16": (3, 2, cv2.COLOR_BGR2RGB), "16UC3": (3, 2, cv2.COLOR_BGR2RGB),
    "rgba16": (4, 2, cv2.COLOR_RGBA2RGB), "bgra16": (4, 2, cv2.COLOR_BGRA2RGB),
    "mono16": (1, 2, cv2.COLOR_GRAY2RGB), "16UC1": (1, 2, cv2.COLOR_GRAY2RGB),
    "bayer_rggb8": (1, 1, cv2.COLOR_BayerRGGB2RGB), "bayer_bggr8": (1, 1, cv2.COLOR_BayerBGGR2RGB),
    "bayer_gbrg8": (1, 1, cv2.COLOR_BayerGBRG2RGB), "bayer_grbg8": (1, 1, cv2.COLOR_BayerGRBG2RGB),
    "bayer_rggb16": (1, 2, cv2.COLOR_BayerRGGB2RGB), "bayer_bggr16": (1, 2, cv2.COLOR_BayerBGGR2RGB),
    "bayer_gbrg16": (1, 2, cv2.COLOR_BayerGBRG2RGB), "bayer_grbg16": (1, 2, cv2.COLOR_BayerGRBG2RGB),
    "yuv422": (2, 1, cv2.COLOR_YUV2RGB_UYVY), "uyvy": (2, 1, cv2.COLOR_YUV2RGB_UYVY),
    "yuv422_yuy2": (2, 1, cv2.COLOR_YUV2RGB_YUY2), "yuyv": (2, 1, cv2.COLOR_YUV2RGB_YUY2),
}
RAW_ENCODINGS: tuple[str, ...] = tuple(_RAW)


def stamp_ns(message: Any) -> int:
    """The header stamp in integer nanoseconds (0 where the publisher left it unset)."""
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def raw_image_rgb(message: Any) -> np.ndarray:
    """RGB uint8 H x W x 3 from a ``sensor_msgs/Image`` (row padding, byte order and 16-bit depth handled)."""
    encoding = str(message.encoding)
    if encoding not in _RAW:
        raise ImageError(f"sensor_msgs/Image encoding {encoding!r} is not supported "
                         f"(supported: {', '.join(RAW_ENCODINGS)})")
    channels, depth, conversion = _RAW[encoding]
    height, width, step = int(message.height), int(message.width), int(message.step)
    row_bytes = width * channels * depth
    data = np.frombuffer(message.data, dtype=np.uint8)
    if height <= 0 or width <= 0 or step < row_bytes or data.size < step * (height - 1) + row_bytes:
        raise ImageError(f"sensor_msgs/Image of {width}x{height} {encoding} (step {step}) holds "
                         f"{data.size} bytes: too few")
    if data.size < step * height:  # the last row's padding may be left out
        data = np.concatenate([data, np.zeros(step * height - data.size, np.uint8)])
    rows = data[: step * height].reshape(height, step)[:, :row_bytes]
    if depth == 2:
        order = ">u2" if message.is_bigendian else "<u2"
        pixels = (np.ascontiguousarray(rows).view(order).reshape(height, width, channels) >> 8).astype(np.uint8)
    else:
        pixels = rows.reshape(height, width, channels)
    if conversion is None:
        return np.ascontiguousarray(pixels)
    if channels == 1:
        pixels = pixels[:, :, 0]
    return cv2.cvtColor(np.ascontiguousarray(pixels), conversion)


def compressed_image_rgb(message: Any) -> np.ndarray:
    """RGB uint8 from a ``sensor_msgs/CompressedImage`` (JPEG, PNG or anything OpenCV decodes)."""
    data = np.frombuffer(message.data, dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None:
        raise ImageError(f"sensor_msgs/CompressedImage of format {str(message.format)!r} ({data.size} bytes) "
                         f"cannot be decoded")
    # image_transport writes "<original>; <codec> compressed <encoding>": an rgb8 payload decodes with R first.
    if str(message.format).strip().endswith("compressed rgb8"):
        return np.ascontiguousarray(image)
    return np.ascontiguousarray(image[:, :, ::-1])


def image_rgb(message: Any, schema: str) -> np.ndarray:
    return compressed_image_rgb(message) if schema == COMPRESSED_IMAGE else raw_image_rgb(message)


def _pose(message: Any, schema: str) -> Any:
    """The ``geometry_msgs/Pose`` of a pose message."""
    if schema == "geometry_msgs/msg/PoseStamped":
        return message.pose
    return message.pose.pose  # Odometry and PoseWithCovarianceStamped hold a PoseWithCovariance


def pose_yaw(message: Any, schema: str) -> float | None:
    """The heading of a pose message, radians anticlockwise about z; None for a NavSatFix (it has none)."""
    if schema == NAV_SAT_FIX:
        return None
    q = _pose(message, schema).orientation
    w, x, y, z = float(q.w), float(q.x), float(q.y), float(q.z)
    if w == x == y == z == 0.0:
        return None  # an unset orientation
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def camera_intrinsics(message: Any, rectified: bool) -> tuple[np.ndarray, int, int]:
    """(3 x 3 K, width, height) of a ``sensor_msgs/CameraInfo``; from its projection matrix P for
    rectified images (P holds the intrinsics after rectification), else from K."""
    k = np.asarray(message.k, dtype=np.float64).reshape(3, 3)
    if rectified:
        p = np.asarray(message.p, dtype=np.float64).reshape(3, 4)
        if p[0, 0] > 0:
            k = p[:, :3]
    return k, int(message.width), int(message.height)


def transform_matrix(transform: Any) -> np.ndarray:
    """The 4 x 4 matrix of a ``geometry_msgs/Transform`` (the child frame's pose in the parent frame)."""
    t, q = transform.translation, transform.rotation
    wxyz = (float(q.w), float(q.x), float(q.y), float(q.z))
    out = np.eye(4)
    out[:3, :3] = quaternion_matrix(wxyz) if any(wxyz) else np.eye(3)
    out[:3, 3] = (float(t.x), float(t.y), float(t.z))
    return out


def pose_xy(message: Any, schema: str) -> tuple[float, float] | None:
    """(x, y) metres of a pose message, (latitude, longitude) degrees of a NavSatFix; None for no fix."""
    if schema == NAV_SAT_FIX:
        if int(message.status.status) < 0:  # STATUS_NO_FIX
            return None
        return float(message.latitude), float(message.longitude)
    position = _pose(message, schema).position
    return float(position.x), float(position.y)
