"""The ROS 2 messages lostx reads and writes, as Cyclone DDS types named as ROS 2's middlewares name them.

Each class mirrors its ROS 2 interface (``sensor_msgs/msg/Image`` ...) field by field, in order, so that a
sample is CDR-encoded (XCDR1, little-endian, as ``rmw_cyclonedds`` and ``rmw_fastrtps`` send ROS 2 messages)
byte for byte as a ROS 2 node encodes it, and carries the DDS type name a ROS 2 node gives it
(``sensor_msgs::msg::dds_::Image_``). ``lostx_msgs`` is lostx's own answer type; its ``.msg`` files are in
``interfaces/lostx_msgs`` beside this module.

A ``uint8[]`` field (an image's pixels) is read and written as ``bytes`` in one piece: Cyclone DDS's Python
binding would otherwise make a list of one Python int per byte (tens of milliseconds for a camera frame).
The bytes on the wire are the same (a 4-byte length, then the bytes).

No ``from __future__ import annotations`` here: the IDL types are read from the annotations at run time.
"""

import math
from dataclasses import dataclass, field

from lostx.core.errors import InputError

try:
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl import types as t
    from cyclonedds.idl._machinery import BytesMachine, StructMachine
except ImportError:  # pragma: no cover - depends on the install
    raise InputError('lostx ros2 needs Cyclone DDS: pip install "lostx[ros2]"') from None

from .names import dds_type


def _ros(ros_type: str) -> str:
    return dds_type(ros_type)


@dataclass
class Time(IdlStruct, typename=_ros("builtin_interfaces/msg/Time")):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0

    @classmethod
    def from_ns(cls, stamp_ns: int) -> "Time":
        return cls(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


@dataclass
class Header(IdlStruct, typename=_ros("std_msgs/msg/Header")):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Image(IdlStruct, typename=_ros("sensor_msgs/msg/Image")):
    header: Header = field(default_factory=Header)
    height: t.uint32 = 0
    width: t.uint32 = 0
    encoding: str = ""
    is_bigendian: t.uint8 = 0
    step: t.uint32 = 0
    data: t.sequence[t.uint8] = field(default_factory=bytes)


@dataclass
class CompressedImage(IdlStruct, typename=_ros("sensor_msgs/msg/CompressedImage")):
    header: Header = field(default_factory=Header)
    format: str = ""
    data: t.sequence[t.uint8] = field(default_factory=bytes)


@dataclass
class RegionOfInterest(IdlStruct, typename=_ros("sensor_msgs/msg/RegionOfInterest")):
    x_offset: t.uint32 = 0
    y_offset: t.uint32 = 0
    height: t.uint32 = 0
    width: t.uint32 = 0
    do_rectify: bool = False


@dataclass
class CameraInfo(IdlStruct, typename=_ros("sensor_msgs/msg/CameraInfo")):
    header: Header = field(default_factory=Header)
    height: t.uint32 = 0
    width: t.uint32 = 0
    distortion_model: str = ""
    d: t.sequence[t.float64] = field(default_factory=list)
    k: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    r: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    p: t.array[t.float64, 12] = field(default_factory=lambda: [0.0] * 12)
    binning_x: t.uint32 = 0
    binning_y: t.uint32 = 0
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)


@dataclass
class Point(IdlStruct, typename=_ros("geometry_msgs/msg/Point")):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Vector3(IdlStruct, typename=_ros("geometry_msgs/msg/Vector3")):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename=_ros("geometry_msgs/msg/Quaternion")):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0

    @classmethod
    def from_yaw(cls, yaw: float) -> "Quaternion":
        """A rotation of ``yaw`` radians anticlockwise about z."""
        return cls(0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


@dataclass
class Pose(IdlStruct, typename=_ros("geometry_msgs/msg/Pose")):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance(IdlStruct, typename=_ros("geometry_msgs/msg/PoseWithCovariance")):
    pose: Pose = field(default_factory=Pose)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class PoseWithCovarianceStamped(IdlStruct, typename=_ros("geometry_msgs/msg/PoseWithCovarianceStamped")):
    header: Header = field(default_factory=Header)
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)


@dataclass
class Twist(IdlStruct, typename=_ros("geometry_msgs/msg/Twist")):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistWithCovariance(IdlStruct, typename=_ros("geometry_msgs/msg/TwistWithCovariance")):
    twist: Twist = field(default_factory=Twist)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Odometry(IdlStruct, typename=_ros("nav_msgs/msg/Odometry")):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class Transform(IdlStruct, typename=_ros("geometry_msgs/msg/Transform")):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename=_ros("geometry_msgs/msg/TransformStamped")):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename=_ros("tf2_msgs/msg/TFMessage")):
    transforms: t.sequence[TransformStamped] = field(default_factory=list)


@dataclass
class Candidate(IdlStruct, typename=_ros("lostx_msgs/msg/Candidate")):
    index: t.int32 = 0
    distance: t.float64 = 0.0
    score: t.float64 = 0.0
    correspondences: t.uint32 = 0


@dataclass
class Latency(IdlStruct, typename=_ros("lostx_msgs/msg/Latency")):
    stage: str = ""
    ms: t.float64 = 0.0


@dataclass
class Place(IdlStruct, typename=_ros("lostx_msgs/msg/Place")):
    header: Header = field(default_factory=Header)
    stream: str = ""
    frame: t.uint64 = 0
    state: str = ""
    warming_up: bool = False
    error: str = ""
    match_index: t.int32 = -1
    match_name: str = ""
    has_position: bool = False
    x: t.float64 = math.nan
    y: t.float64 = math.nan
    confidence: t.float64 = 0.0
    score: t.float64 = math.nan
    single_match_index: t.int32 = -1
    heading: str = ""
    heading_confidence: t.float64 = 0.0
    speed: t.float64 = math.nan
    sequence_score: t.float64 = math.nan
    margin: t.float64 = math.nan
    window: t.uint32 = 0
    candidates: t.sequence[Candidate] = field(default_factory=list)
    latency: t.sequence[Latency] = field(default_factory=list)


ROS_TYPES: dict[type, str] = {
    Time: "builtin_interfaces/msg/Time", Header: "std_msgs/msg/Header", Image: "sensor_msgs/msg/Image",
    CompressedImage: "sensor_msgs/msg/CompressedImage", RegionOfInterest: "sensor_msgs/msg/RegionOfInterest",
    CameraInfo: "sensor_msgs/msg/CameraInfo", Point: "geometry_msgs/msg/Point", Vector3: "geometry_msgs/msg/Vector3",
    Quaternion: "geometry_msgs/msg/Quaternion", Pose: "geometry_msgs/msg/Pose",
    PoseWithCovariance: "geometry_msgs/msg/PoseWithCovariance",
    PoseWithCovarianceStamped: "geometry_msgs/msg/PoseWithCovarianceStamped", Twist: "geometry_msgs/msg/Twist",
    TwistWithCovariance: "geometry_msgs/msg/TwistWithCovariance", Odometry: "nav_msgs/msg/Odometry",
    Transform: "geometry_msgs/msg/Transform", TransformStamped: "geometry_msgs/msg/TransformStamped",
    TFMessage: "tf2_msgs/msg/TFMessage", Candidate: "lostx_msgs/msg/Candidate", Latency: "lostx_msgs/msg/Latency",
    Place: "lostx_msgs/msg/Place",
}
"""Each type's ROS 2 name."""


def _bytes_member(kind: type, member: str) -> None:
    """Read and write the ``uint8[]`` member as one ``bytes`` value (same bytes on the wire)."""
    kind.__idl__.populate()
    for machine in (kind.__idl__.v1_machine, kind.__idl__.v2_machine):
        if not isinstance(machine, StructMachine) or member not in machine.members_machines:
            raise RuntimeError(f"this Cyclone DDS binding builds {kind.__name__} unlike the one lostx was written "
                               f"for; install the version lostx[ros2] names")
        machine.members_machines[member] = BytesMachine()


_bytes_member(Image, "data")
_bytes_member(CompressedImage, "data")
