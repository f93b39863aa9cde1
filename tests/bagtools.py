"""Writing ROS 2 bags (MCAP, CDR) for the tests with the ``mcap-ros2-support`` writer.

The message definitions are the ROS 2 interfaces' fields, in the concatenated form
rosbag2 stores (the message, then each type it uses after a separator line).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np
from mcap_ros2.writer import Writer

SEPARATOR = "=" * 80

TYPES = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance",
    "sensor_msgs/NavSatStatus": "int8 status\nuint16 service",
    "sensor_msgs/RegionOfInterest": "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform",
}
MESSAGES = {
    "sensor_msgs/msg/Image": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\n"
        "uint8[] data", ["std_msgs/Header", "builtin_interfaces/Time"]),
    "sensor_msgs/msg/CompressedImage": (
        "std_msgs/Header header\nstring format\nuint8[] data", ["std_msgs/Header", "builtin_interfaces/Time"]),
    "nav_msgs/msg/Odometry": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
        "geometry_msgs/TwistWithCovariance twist",
        ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/PoseWithCovariance", "geometry_msgs/Pose",
         "geometry_msgs/Point", "geometry_msgs/Quaternion", "geometry_msgs/TwistWithCovariance",
         "geometry_msgs/Twist", "geometry_msgs/Vector3"]),
    "geometry_msgs/msg/PoseStamped": (
        "std_msgs/Header header\ngeometry_msgs/Pose pose",
        ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Pose", "geometry_msgs/Point",
         "geometry_msgs/Quaternion"]),
    "sensor_msgs/msg/NavSatFix": (
        "std_msgs/Header header\nsensor_msgs/NavSatStatus status\nfloat64 latitude\nfloat64 longitude\n"
        "float64 altitude\nfloat64[9] position_covariance\nuint8 position_covariance_type",
        ["std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/NavSatStatus"]),
    "sensor_msgs/msg/CameraInfo": (
        ("std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
         "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\n"
         "sensor_msgs/RegionOfInterest roi"),
        ["std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/RegionOfInterest"]),
    "tf2_msgs/msg/TFMessage": (
        "geometry_msgs/TransformStamped[] transforms",
        ["geometry_msgs/TransformStamped", "std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Transform",
         "geometry_msgs/Vector3", "geometry_msgs/Quaternion"]),
}


def definition(name: str) -> str:
    text, uses = MESSAGES[name]
    return "\n".join([text, *(f"{SEPARATOR}\nMSG: {used}\n{TYPES[used]}" for used in uses)])


def header(stamp_ns: int, frame: str = "camera") -> dict:
    return {"stamp": {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000}, "frame_id": frame}


def raw_image(rgb: np.ndarray, stamp_ns: int, encoding: str = "rgb8") -> dict:
    pixels = rgb if encoding == "rgb8" else cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    height, width = rgb.shape[:2]
    return {"header": header(stamp_ns), "height": height, "width": width, "encoding": encoding,
            "is_bigendian": 0, "step": width * 3, "data": np.ascontiguousarray(pixels).tobytes()}


def compressed_image(rgb: np.ndarray, stamp_ns: int, codec: str = ".png") -> dict:
    ok, data = cv2.imencode(codec, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert ok
    return {"header": header(stamp_ns), "format": codec.lstrip("."), "data": data.tobytes()}


def odometry(x: float, y: float, stamp_ns: int, yaw: float = 0.0) -> dict:
    """An Odometry of base_link at (x, y) heading ``yaw`` radians anticlockwise."""
    orientation = {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}
    pose = {"position": {"x": x, "y": y, "z": 0.0}, "orientation": orientation}
    zero = {"x": 0.0, "y": 0.0, "z": 0.0}
    return {"header": header(stamp_ns, "odom"), "child_frame_id": "base_link",
            "pose": {"pose": pose, "covariance": [0.0] * 36},
            "twist": {"twist": {"linear": zero, "angular": zero}, "covariance": [0.0] * 36}}


def nav_sat_fix(lat: float, lon: float, stamp_ns: int, status: int = 0) -> dict:
    return {"header": header(stamp_ns, "gps"), "status": {"status": status, "service": 1}, "latitude": lat,
            "longitude": lon, "altitude": 0.0, "position_covariance": [0.0] * 9, "position_covariance_type": 0}


def camera_info(stamp_ns: int, k: tuple[float, float, float, float], width: int, height: int,
                frame: str = "camera_optical_frame") -> dict:
    """A CameraInfo of a pinhole camera without distortion: ``k`` is fx, fy, cx, cy."""
    fx, fy, cx, cy = k
    return {"header": header(stamp_ns, frame), "height": height, "width": width, "distortion_model": "plumb_bob",
            "d": [0.0] * 5, "k": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0], "r": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
            "p": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0], "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


def transform(parent: str, child: str, translation: tuple[float, float, float],
              wxyz: tuple[float, float, float, float], stamp_ns: int = 0) -> dict:
    """A TransformStamped: ``child``'s pose in ``parent``."""
    w, x, y, z = wxyz
    return {"header": header(stamp_ns, parent), "child_frame_id": child,
            "transform": {"translation": dict(zip("xyz", translation)),
                          "rotation": {"x": x, "y": y, "z": z, "w": w}}}


def tf_message(*transforms: dict) -> dict:
    return {"transforms": list(transforms)}


def write_bag(path: Path, messages: Iterable[tuple[str, str, dict, int]]) -> Path:
    """A bag of (topic, message type, message, log time in ns), written in the order given."""
    with open(path, "wb") as handle:
        writer = Writer(handle)
        schemas = {}
        for topic, kind, message, log_time in messages:
            if kind not in schemas:
                schemas[kind] = writer.register_msgdef(kind, definition(kind))
            writer.write_message(topic, schemas[kind], message, log_time=log_time)
        writer.finish()
    return path
