"""ROS 2 names as they travel over DDS (the ``rmw`` layers' mapping), and the topic names lostx derives.

A ROS topic ``/camera/image_raw`` is the DDS topic ``rt/camera/image_raw``; a ROS message type
``sensor_msgs/msg/Image`` is the DDS type ``sensor_msgs::msg::dds_::Image_``. Pure functions: nothing here
needs Cyclone DDS.
"""

from __future__ import annotations

import re
from pathlib import Path

from lostx.core.errors import InputError

INTERFACES = Path(__file__).parent / "interfaces" / "lostx_msgs"
"""The ``lostx_msgs`` ROS 2 package: the ``.msg`` definitions of lostx's answers, ready for ``colcon build``."""
TOPIC_PREFIX = "rt"
"""The prefix ROS 2's DDS middlewares put before a topic's name (``rq``/``rr`` are services')."""
TRANSPORTS = ("compressed", "compressedDepth", "theora", "zstd", "ffmpeg", "h264")
"""image_transport's suffixes: ``/cam/image_raw/compressed`` is a transport of ``/cam/image_raw``."""

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def check_topic(name: str, what: str = "topic") -> str:
    """``name`` as an absolute ROS topic name (a leading ``/`` added), or an error naming what is wrong."""
    full = name if name.startswith("/") else f"/{name}"
    tokens = full[1:].split("/")
    if not full[1:] or any(not _TOKEN.match(t) or "__" in t for t in tokens) or full.endswith("/"):
        raise InputError(f"{what} {name!r} is not a ROS 2 topic name: '/'-separated words of letters, digits and "
                         f"single underscores, each starting with a letter or an underscore")
    return full


def dds_topic(name: str) -> str:
    """The DDS topic of a ROS topic: ``/camera/image_raw`` -> ``rt/camera/image_raw``."""
    return f"{TOPIC_PREFIX}{check_topic(name)}"


def dds_type(ros_type: str) -> str:
    """The DDS type name of a ROS message type: ``sensor_msgs/msg/Image`` -> ``sensor_msgs::msg::dds_::Image_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def is_compressed(image_topic: str) -> bool:
    """An image_transport ``compressed`` topic carries ``sensor_msgs/CompressedImage``; any other, ``Image``."""
    return image_topic.rstrip("/").rsplit("/", 1)[-1] == "compressed"


def camera_info_topic(image_topic: str) -> str:
    """The ``camera_info`` topic that goes with an image topic, as image_transport names it:
    ``/cam/image_raw`` and ``/cam/image_raw/compressed`` -> ``/cam/camera_info``."""
    parts = check_topic(image_topic).split("/")
    if len(parts) > 2 and parts[-1] in TRANSPORTS:
        parts = parts[:-1]
    return "/".join([*parts[:-1], "camera_info"]) if len(parts) > 2 else "/camera_info"


def answer_topics(namespace: str) -> tuple[str, str]:
    """The topics of the full answers and of the poses: ``<namespace>/place``, ``<namespace>/pose``."""
    base = check_topic(namespace, "namespace")
    return f"{base}/place", f"{base}/pose"
