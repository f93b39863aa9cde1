"""``lostx ros2 --map MAP --topic /camera/image_raw``: the localizer as a ROS 2 node, over DDS, without ROS.

It answers like ``lostx serve`` (the sequence filter and the tracker on unless ``--no-sequence`` or
``--no-tracker``), each camera topic a stream of its own. ``lostx ros2 interfaces DIR`` writes the
``lostx_msgs`` package (the ``Place`` message) for a ROS 2 workspace. docs/ros2.md has both."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.options import (
    add_config_options,
    add_viewer_options,
    config_from_args,
    number,
    viewer_sink_from_args,
    whole_number,
)

if TYPE_CHECKING:
    from lostx.core.config import Config
    from lostx.stream.ros2.node import NodeStats

RELIABILITY = ("best_effort", "reliable")


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("ros2", help="run the localizer as a ROS 2 node (camera topics in, places out; "
                                         "see docs/ros2.md)",
                            description="Subscribe to camera topics over DDS as ROS 2 nodes do (no ROS "
                                        "installation needed) and publish every answer as lostx_msgs/Place and "
                                        "geometry_msgs/PoseWithCovarianceStamped.")
    parser.add_argument("--map", type=Path, help="reference map folder (from `lostx map build`)")
    topics = parser.add_argument_group("topics")
    topics.add_argument("--topic", action="append", default=[], metavar="TOPIC",
                        help="a camera's image topic: sensor_msgs/Image, or CompressedImage for a topic ending "
                             "in /compressed (repeatable: each camera is a stream of its own)")
    topics.add_argument("--odom-topic", metavar="TOPIC",
                        help="the vehicle's nav_msgs/Odometry, for the motion between frames (default: none; "
                             "the motion then comes from the images)")
    topics.add_argument("--camera-info-topic", metavar="TOPIC",
                        help="the camera's sensor_msgs/CameraInfo (default: the image topic's sibling "
                             "camera_info, as image_transport names it)")
    topics.add_argument("--namespace", metavar="NS", help="publish on NS/place and NS/pose (default /lostx)")
    topics.add_argument("--map-frame", metavar="FRAME", help="frame_id of the published poses (default map)")
    camera = parser.add_argument_group("camera")
    camera.add_argument("--camera", choices=["front", "rear"],
                        help="declare which way the cameras face along the vehicle's travel (a prior on the heading)")
    camera.add_argument("--camera-file", type=Path, metavar="PATH",
                        help="the camera's intrinsics and mounting (a TOML camera file, see docs/datasets.md), in "
                             "place of its camera info and /tf_static")
    network = parser.add_argument_group("DDS (see docs/ros2.md)")
    network.add_argument("--domain-id", type=whole_number(0, 232), metavar="N",
                         help="the ROS domain (default $ROS_DOMAIN_ID, else 0)")
    network.add_argument("--interface", metavar="NAME",
                         help="loopback (default: this machine only), a network interface's name or address "
                              "(other machines on that network), or auto (Cyclone DDS chooses)")
    network.add_argument("--image-qos", choices=RELIABILITY,
                         help="images and camera infos: best_effort (default, ROS's sensor-data profile: any "
                              "publisher, newest frame first) or reliable")
    network.add_argument("--image-depth", type=whole_number(0, 10_000), metavar="N",
                         help="images held per camera (default 5); 0 with --image-qos reliable: every image, in "
                              "order, the publisher held back while the localizer works")
    network.add_argument("--odom-qos", choices=RELIABILITY, help="odometry: best_effort (default) or reliable")
    network.add_argument("--answer-qos", choices=RELIABILITY, help="answers: reliable (default) or best_effort")
    network.add_argument("--answer-depth", type=whole_number(1, 10_000), metavar="N",
                         help="answers kept for each subscriber (default 10)")
    network.add_argument("--answer-durability", choices=("volatile", "transient_local"),
                         help="transient_local: a subscriber that joins late gets the last answers (default "
                              "volatile)")
    network.add_argument("--odometry-wait", type=number(0.0), metavar="S",
                         help="seconds a frame waits for odometry stamped at or after it (default 0.1)")
    out = parser.add_argument_group("sinks")
    out.add_argument("--jsonl", type=Path, metavar="FILE", help="also append every answer to FILE as JSON lines")
    add_config_options(parser)
    parser.add_argument("--no-sequence", action="store_true",
                        help="answer each frame on its own, without the sequence filter and tracker")
    add_viewer_options(parser)
    parser.set_defaults(run=run)
    verbs = parser.add_subparsers(dest="verb", metavar="VERB")
    interfaces = verbs.add_parser("interfaces", help="write the lostx_msgs package (the Place message) into a ROS 2 "
                                                     "workspace's src folder")
    interfaces.add_argument("folder", type=Path, help="the folder to write lostx_msgs/ into, e.g. ~/ros2_ws/src")
    interfaces.add_argument("--overwrite", action="store_true", help="replace an existing lostx_msgs there")
    interfaces.set_defaults(run=run_interfaces)


def ros2_config_from_args(args: argparse.Namespace, config: Config) -> Config:
    """``config`` with the ROS 2 settings given on the command line applied."""
    changes = {
        "domain_id": args.domain_id, "interface": args.interface, "namespace": args.namespace,
        "map_frame": args.map_frame, "image_reliability": args.image_qos, "image_depth": args.image_depth,
        "odometry_reliability": args.odom_qos, "answer_reliability": args.answer_qos,
        "answer_depth": args.answer_depth, "answer_durability": args.answer_durability,
        "odometry_wait": args.odometry_wait,
    }
    ros2 = dataclasses.replace(config.ros2, **{k: v for k, v in changes.items() if v is not None})
    return dataclasses.replace(config, ros2=ros2)


def run(args: argparse.Namespace) -> int:
    from lostx.core.errors import InputError
    from lostx.core.geometry import read_camera_file
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.core.outputs import check_output_file
    from lostx.stream.ros2.dds import cyclone_config
    from lostx.stream.ros2.names import check_topic
    from lostx.stream.ros2.node import Ros2Localizer
    from lostx.stream.sinks import JsonlSink
    from lostx.stream.streams import localizer_factory

    from .serve import _SignalStop

    if args.map is None:
        raise InputError("lostx ros2 needs --map MAP (the map to localize in)")
    if not args.topic:
        raise InputError("lostx ros2 needs --topic TOPIC: the camera's image topic (e.g. /camera/image_raw)")
    for topic in [*args.topic, args.odom_topic, args.camera_info_topic]:
        if topic is not None:
            check_topic(topic)
    if args.interface is not None:
        cyclone_config(args.interface)  # a bad interface is said before the map loads
    stop = _SignalStop()
    with stop:
        config = ros2_config_from_args(args, config_from_args(args))
        if args.no_sequence:
            config = dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, enabled=False))
        if args.jsonl:
            check_output_file(args.jsonl, "--jsonl")
        geometry = read_camera_file(args.camera_file) if args.camera_file else None
        refmap = ReferenceMap.open(args.map)
        sinks = [JsonlSink(args.jsonl)] if args.jsonl else []
        viewer = viewer_sink_from_args(args, refmap)
        if viewer is not None:
            sinks.append(viewer)
        node = Ros2Localizer(localizer_factory(refmap, config), config, args.topic, args.odom_topic, refmap,
                             info_topic=args.camera_info_topic, camera=args.camera, geometry=geometry, sinks=sinks)
        stop.attach(node)
        try:
            with node:
                final = node.run()
        finally:
            for sink in sinks:
                close = getattr(sink, "close", None)
                if close is not None:
                    close()
    node.log(summary(final))
    return 0


def summary(stats: NodeStats) -> str:
    """One line: per camera topic, what was answered, dropped for newer frames, or bad; how long a frame took."""
    parts = []
    for topic, c in stats.cameras.items():
        extra = "".join(f", {n} {what}" for n, what in ((c.dropped, "dropped for newer ones"), (c.bad, "bad"))
                        if n)
        parts.append(f"{topic}: answered {c.answered} of {c.received} frames{extra}")
    node = stats.latency_ms.get("node", {})
    took = f"; {node['p50']:.0f} ms a frame (median)" if node.get("n") else ""
    return f"{'; '.join(parts)} in {stats.uptime_s:.1f} s{took}"


def run_interfaces(args: argparse.Namespace) -> int:
    import shutil

    from lostx.core.errors import InputError
    from lostx.stream.ros2.names import INTERFACES

    target = args.folder / INTERFACES.name
    if target.exists() and not args.overwrite:
        raise InputError(f"{target} exists: give --overwrite to replace it")
    if target.exists():
        shutil.rmtree(target)
    args.folder.mkdir(parents=True, exist_ok=True)
    shutil.copytree(INTERFACES, target)
    print(f"wrote {target}: build it in your ROS 2 workspace (colcon build --packages-select lostx_msgs), "
          f"source install/setup.bash, then `ros2 topic echo /lostx/place`")
    return 0
