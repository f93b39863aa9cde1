"""lostx.stream.ros2: the localizer as a ROS 2 node without ROS (``lostx ros2``, docs/ros2.md).

Camera topics in and answers out over DDS, as ROS 2's middlewares speak it, through Cyclone DDS's Python
binding (``pip install "lostx[ros2]"``). It sits in the stream layer beside the ZeroMQ service and keeps its
streams the same way (:mod:`lostx.stream.streams`); the messages and names are ROS 2's own
(:mod:`.msgs`, :mod:`.names`), the DDS settings :mod:`.dds`, what a frame is made of :mod:`.inputs`, the
answers :mod:`.answers`, the node :mod:`.node`.

    from lostx.stream.ros2 import Ros2Localizer

Names are imported on first use (Cyclone DDS loads only then).
"""

from lostx.core.lazy import lazy_exports

_EXPORTS = {"Ros2Localizer": ".node", "NodeStats": ".node"}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
