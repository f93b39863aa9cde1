"""``lostx ros2``: the localizer as a ROS 2 node without ROS, over DDS (Cyclone DDS) as ROS 2's middlewares speak it.

It subscribes to one or more camera topics (``sensor_msgs/Image`` or ``CompressedImage``), each camera's
``camera_info`` and ``/tf_static`` for the camera's geometry, and an odometry topic (``nav_msgs/Odometry``)
for the motion, and answers every frame it takes on ``<namespace>/place`` (``lostx_msgs/Place``) and, where
the map has positions, ``<namespace>/pose`` (``geometry_msgs/PoseWithCovarianceStamped``).

Each camera topic is a stream with its own localizer state over the one map, kept as the ZeroMQ service keeps
its streams (:mod:`lostx.stream.streams`): created by the first frame, forgotten after ``stream_expiry``
idle seconds, restarted when the camera's clock jumps back (a bag played again). One thread does the work:
it waits for a frame, takes the side topics that have arrived (odometry, camera infos, transforms), waits a
little for the odometry and camera info of the frame's stamp where they are due, steps the localizer and
publishes. With the sensor-data QoS a camera does not wait for the localizer: the newest frame is taken and
older ones waiting are dropped (counted); with reliable keep-all images every frame is answered, in order,
and the publisher is held back instead. Answers are written keep-last, which never waits for a subscriber.
"""

from __future__ import annotations

import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from lostx.core.config import Config
from lostx.core.errors import LostxError
from lostx.core.frame import Camera, Frame
from lostx.core.geometry import CameraGeometry
from lostx.core.localizer import Localizer
from lostx.core.maps.refmap import ReferenceMap

from ..errors import ProtocolError
from ..sinks import Sink
from ..stats import LatencyWindow
from ..streams import StreamState, StreamTable, check_time
from . import dds, msgs
from .answers import FrameAnswer, MapPlaces, place_message, pose_message
from .inputs import CameraTopics, OdometryTrack, StaticTransforms, decode_image
from .names import answer_topics, camera_info_topic, check_topic, dds_topic, is_compressed

POLL_S = 0.1
"""Longest wait for a frame: how soon a stop is noticed."""
SIDE_POLL_S = 0.002
"""How often the side topics are looked at while a frame waits for its odometry or camera info."""
HEALTH_S = 2.0
LOGGED_BAD = 10
"""Bad frames logged in full per camera; after them, one in :data:`LOGGED_BAD_EVERY` (a camera sending garbage
must not flood the log)."""
LOGGED_BAD_EVERY = 100
"""How often the topics' matches are looked at, to say once what is missing."""


@dataclass
class _Pending:
    sample: Any
    frame: int
    taken: float
    """time.monotonic() when it was taken from DDS."""


@dataclass
class CameraCounts:
    received: int = 0
    answered: int = 0
    bad: int = 0
    dropped: int = 0


@dataclass
class _Camera:
    topic: str
    compressed: bool
    reader: Any
    info_reader: Any
    topics: CameraTopics
    counts: CameraCounts = field(default_factory=CameraCounts)
    pending: _Pending | None = None
    said: set[str] = field(default_factory=set)
    """Notes given once (geometry, missing topics)."""


@dataclass(frozen=True)
class NodeStats:
    """What the node did, per camera topic, and how long a frame took."""

    cameras: dict[str, CameraCounts]
    latency_ms: dict[str, dict[str, float]]
    uptime_s: float


class Ros2Localizer:
    """``with Ros2Localizer(new_localizer, config, ["/cam/image_raw"], "/odom", refmap) as node: node.run()``."""

    def __init__(
        self,
        new_localizer: Callable[[], Localizer],
        config: Config,
        image_topics: Sequence[str],
        odometry_topic: str | None,
        refmap: ReferenceMap,
        *,
        info_topic: str | None = None,
        camera: Camera | None = None,
        geometry: CameraGeometry | None = None,
        sinks: Sequence[Sink] = (),
        log: Callable[[str], None] | None = None,
    ) -> None:
        if not image_topics:
            raise LostxError("lostx ros2 needs at least one image topic")
        if info_topic is not None and len(image_topics) > 1:
            raise LostxError("a camera info topic names one camera's: give it with one image topic only")
        self.config = config
        self.settings = config.ros2
        self.image_topics = [check_topic(t, "image topic") for t in image_topics]
        if len(set(self.image_topics)) < len(self.image_topics):
            raise LostxError(f"an image topic is given twice: {', '.join(self.image_topics)}")
        self.odometry_topic = check_topic(odometry_topic, "odometry topic") if odometry_topic else None
        self.info_topic = check_topic(info_topic, "camera info topic") if info_topic else None
        self.place_topic, self.pose_topic = answer_topics(self.settings.namespace)
        self.camera = camera
        self.geometry = geometry
        self.sinks = list(sinks)
        self.log = log or (lambda text: print(f"lostx ros2: {text}", file=sys.stderr, flush=True))
        self.places = MapPlaces(refmap.positions) if refmap.positions is not None else None
        stream = config.stream
        self.streams = StreamTable(new_localizer, max(len(self.image_topics), 1), stream.stream_expiry,
                                   max(len(self.image_topics), 1))
        self.latency = {"node": LatencyWindow(), "decode": LatencyWindow()}
        self._stop = threading.Event()
        self._stop_reason = ""
        self._participant: Any = None
        self._cameras: list[_Camera] = []
        self._odometry = OdometryTrack()
        self._odometry_reader: Any = None
        self._transforms = StaticTransforms()
        self._tf_reader: Any = None
        self._place_writer: Any = None
        self._pose_writer: Any = None
        self._waitset: Any = None
        self._next_health = 0.0
        self._said: set[str] = set()
        self._matched: dict[str, int] = {}
        self._started = time.monotonic()

    # -- lifecycle -----------------------------------------------------------------------------

    def __enter__(self) -> "Ros2Localizer":
        self.open()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def open(self) -> None:
        """Join the ROS domain, subscribe and advertise."""
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        s = self.settings
        self._participant = participant = dds.participant(s)
        try:
            topics: dict[str, Any] = {}

            def topic(name: str, kind: type) -> Any:
                if name not in topics:
                    topics[name] = Topic(participant, dds_topic(name), kind)
                if topics[name].data_type is not kind:
                    raise LostxError(f"topic {name} is used for both {topics[name].data_type.__name__} and "
                                     f"{kind.__name__}")
                return topics[name]

            self._waitset = WaitSet(participant)
            any_sample = SampleState.Any | ViewState.Any | InstanceState.Any
            side = dds.side_qos(s.image_reliability)
            for name in self.image_topics:
                compressed = is_compressed(name)
                reader = DataReader(participant, topic(name, msgs.CompressedImage if compressed else msgs.Image),
                                    dds.image_qos(s))
                self._waitset.attach(ReadCondition(reader, any_sample))
                info_name = self.info_topic or camera_info_topic(name)
                info_reader = DataReader(participant, topic(info_name, msgs.CameraInfo), side)
                cameras = CameraTopics(info_name, "rect" in name, self.geometry)
                self._cameras.append(_Camera(name, compressed, reader, info_reader, cameras))
            self._tf_reader = DataReader(participant, topic("/tf_static", msgs.TFMessage), dds.tf_static_qos())
            if self.odometry_topic is not None:
                self._odometry_reader = DataReader(participant, topic(self.odometry_topic, msgs.Odometry),
                                                   dds.side_qos(s.odometry_reliability))
            answers = dds.answer_qos(s)
            self._place_writer = DataWriter(participant, topic(self.place_topic, msgs.Place), answers)
            if self.places is not None:
                self._pose_writer = DataWriter(participant, topic(self.pose_topic, msgs.PoseWithCovarianceStamped),
                                               answers)
        except BaseException:
            self.close()
            raise

    def stop(self, reason: str = "stop requested") -> None:
        """Finish the frame in hand and return from :meth:`run`. Safe in signal handlers."""
        self._stop_reason = reason
        self._stop.set()

    def close(self) -> None:
        participant, self._participant = self._participant, None
        self._cameras = []
        self._waitset = self._place_writer = self._pose_writer = self._tf_reader = self._odometry_reader = None
        del participant  # the last reference: Cyclone DDS deletes it and its readers and writers, and tells the peers

    # -- the loop ------------------------------------------------------------------------------

    def run(self) -> NodeStats:
        """Answer frames until :meth:`stop`; the counts and latencies."""
        from cyclonedds.util import duration

        if self._participant is None:
            self.open()
        what = ", ".join(c.topic for c in self._cameras)
        self.log(f"ROS domain {dds.domain_id(self.settings)} on {self.settings.interface}: answering {what} on "
                 f"{self.place_topic}" + (f" and {self.pose_topic}" if self._pose_writer is not None else ""))
        while not self._stop.is_set():
            self._take_side_topics()
            self._watch_matches()
            self._check_health()
            camera = self._next_camera()
            if camera is None:
                self._waitset.wait(duration(seconds=POLL_S))
                continue
            pending, camera.pending = camera.pending, None
            assert pending is not None
            self._answer(camera, pending)
        if self._stop_reason:
            self.log(f"{self._stop_reason}: stopping")
        return self.stats()

    def stats(self) -> NodeStats:
        return NodeStats({c.topic: c.counts for c in self._cameras},
                         {k: w.summary() for k, w in self.latency.items()}, time.monotonic() - self._started)

    def _take_side_topics(self) -> None:
        for message in _take_all(self._tf_reader, self._said, self.log, "/tf_static"):
            self._transforms.add(message)
        if self._odometry_reader is not None:
            for message in _take_all(self._odometry_reader, self._said, self.log, self.odometry_topic):
                self._odometry.add(message)
        for camera in self._cameras:
            for message in _take_all(camera.info_reader, camera.said, self.log, camera.topics.info_topic):
                camera.topics.add_info(message)

    def _next_camera(self) -> _Camera | None:
        """Fill each camera's slot (the newest frame, or with keep-all the next one); the camera whose frame
        waits longest."""
        keep_all = self.settings.image_reliability == "reliable" and self.settings.image_depth == 0
        for camera in self._cameras:
            if keep_all and camera.pending is not None:
                continue
            while True:
                try:
                    samples = camera.reader.take(1)
                except Exception as exc:  # a sample that is not the message it claims to be
                    self._bad_sample(camera, exc)
                    continue
                if not samples:
                    break
                if not _valid(samples[0]):
                    continue  # a publisher went away: news of the topic, not a frame
                if camera.pending is not None:
                    camera.counts.dropped += 1
                camera.pending = _Pending(samples[0], camera.counts.received, time.monotonic())
                camera.counts.received += 1
                if keep_all:
                    break
        waiting = [c for c in self._cameras if c.pending is not None]
        return min(waiting, key=lambda c: c.pending.taken) if waiting else None  # type: ignore[union-attr]

    def _bad_sample(self, camera: _Camera, exc: Exception) -> None:
        frame = camera.counts.received
        camera.counts.received += 1
        kind = "CompressedImage" if camera.compressed else "Image"
        text = f"a message on {camera.topic} does not decode as {kind} ({type(exc).__name__}: {exc})"
        self._publish(camera, FrameAnswer(camera.topic, frame, 0, "", error=text), time.monotonic())

    def _wait_for_side_topics(self, camera: _Camera, stamp: int) -> None:
        """Give the odometry and the camera info stamped as the frame a moment to arrive, where they are due."""
        s = self.settings
        info_due = (self.geometry is None and not camera.topics.has_info(stamp)
                    and _publishers(camera.info_reader) > 0)
        odometry_due = (self._odometry_reader is not None and not self._odometry.covers(stamp)
                        and _publishers(self._odometry_reader) > 0)
        start = time.monotonic()
        while (info_due or odometry_due) and not self._stop.is_set():
            waited = time.monotonic() - start
            if (not info_due or waited >= s.camera_info_wait) and (not odometry_due or waited >= s.odometry_wait):
                return
            time.sleep(SIDE_POLL_S)
            self._take_side_topics()
            info_due = info_due and not camera.topics.has_info(stamp)
            odometry_due = odometry_due and not self._odometry.covers(stamp)

    def _answer(self, camera: _Camera, pending: _Pending) -> None:
        message = pending.sample
        stamp = _stamp(message)
        answer = FrameAnswer(camera.topic, pending.frame, stamp, str(message.header.frame_id))
        if stamp == 0:
            answer.stamp_ns = stamp = time.time_ns()  # an unset stamp: timed on arrival
            self._say(camera, "stamp", f"{camera.topic}: images without a header stamp, timed as they arrive")
        self._wait_for_side_topics(camera, stamp)
        started = time.perf_counter()
        try:
            image = decode_image(message, camera.compressed, self.config.stream.max_pixels)
        except ProtocolError as exc:
            answer.error = exc.text
            self._publish(camera, answer, pending.taken)
            return
        self.latency["decode"].add(1e3 * (time.perf_counter() - started))
        answer.latency_ms["decode"] = 1e3 * (time.perf_counter() - started)
        frame = Frame(id=pending.frame, image=image, timestamp=stamp / 1e9, camera=self.camera,
                      name=f"{stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d}",
                      geometry=self._geometry(camera, stamp), odometry=self._pose(stamp))
        state = self.streams.get(camera.topic, time.monotonic())
        try:
            answer.estimate = self._step(state, frame)
        except ProtocolError as exc:
            answer.error = exc.text
        except Exception as exc:  # the localizer must not take the node down with it
            if not isinstance(exc, LostxError):
                self.log(f"{camera.topic} frame {pending.frame}: unexpected {type(exc).__name__}\n"
                         f"{traceback.format_exc()}")
            answer.error = (str(exc) or type(exc).__name__).removeprefix(f"frame {frame.id}: ")  # the Place says which
        self._publish(camera, answer, pending.taken)
        if answer.estimate is not None:
            for sink in self.sinks:
                try:
                    sink(frame, answer.estimate)
                except Exception:
                    self._say(camera, f"sink {id(sink)}", f"sink {sink!r} failed on frame {frame.id}:\n"
                                                          f"{traceback.format_exc()}")

    def _step(self, state: StreamState, frame: Frame) -> Any:
        verdict = check_time(state.last_timestamp, frame.timestamp, self.config.stream.max_time_jump)
        if verdict == "restart":
            state.localizer.reset()
            state.counts.restarts += 1
            self.log(f"{state.name}: its clock went back by more than max_time_jump: a new traverse")
        state.last_timestamp = frame.timestamp
        return state.localizer.step(frame)

    def _geometry(self, camera: _Camera, stamp: int) -> CameraGeometry | None:
        found = camera.topics.geometry(stamp, self._transforms.tree, self._transforms.version,
                                       self._odometry.child_frame)
        if found.note is not None:
            self._say(camera, found.note, f"{camera.topic}: {found.note}")
        elif found.geometry is not None:
            self._say(camera, f"geometry {found.geometry.source}", f"{camera.topic}: camera geometry from "
                                                                   f"{found.geometry.source or 'the camera file'}")
        return found.geometry

    def _pose(self, stamp: int) -> tuple[float, float, float] | None:
        if self._odometry_reader is None:
            return None
        pose = self._odometry.pose_at(stamp, int(self.settings.max_extrapolation * 1e9))
        if pose is None:
            newest = self._odometry.newest
            why = "none has arrived" if newest is None else f"the newest is {(stamp - newest) / 1e9:.3f} s older"
            key = "odometry missing" if newest is None else "odometry late"
            self._say(None, key, f"no odometry on {self.odometry_topic} for a frame ({why}): its motion comes "
                                 f"from the images")
        return pose

    def _publish(self, camera: _Camera, answer: FrameAnswer, taken: float) -> None:
        if answer.estimate is None:
            camera.counts.bad += 1
            if camera.counts.bad <= LOGGED_BAD or camera.counts.bad % LOGGED_BAD_EVERY == 0:
                more = (f" (from here on one in {LOGGED_BAD_EVERY} is logged; all are answered)"
                        if camera.counts.bad == LOGGED_BAD else "")
                self.log(f"{camera.topic} frame {answer.frame}: bad_frame: {answer.error}{more}")
        else:
            camera.counts.answered += 1
        answer.latency_ms["node"] = node_ms = 1e3 * (time.monotonic() - taken)
        self.latency["node"].add(node_ms)
        self._place_writer.write(place_message(answer))
        pose = pose_message(answer, self.places, self.settings.map_frame)
        if pose is not None and self._pose_writer is not None:
            self._pose_writer.write(pose)

    # -- telling the user ----------------------------------------------------------------------

    def _say(self, camera: _Camera | None, key: str, text: str) -> None:
        said = camera.said if camera is not None else self._said
        if key not in said:
            said.add(key)
            self.log(text)

    def _watch_matches(self) -> None:
        """Say when a topic gains or loses publishers (or, for the answers, subscribers): DDS discovery takes a
        moment, and a message sent before both ends have found each other does not reach the other end."""
        ends = [(name, _publishers(reader), "publisher") for name, reader in self._readers().items()]
        ends += [(name, int(writer.get_publication_matched_status().current_count), "subscriber")
                 for name, writer in ((self.place_topic, self._place_writer), (self.pose_topic, self._pose_writer))
                 if writer is not None]
        for name, count, what in ends:
            if count != self._matched.get(name, 0):
                self._matched[name] = count
                self.log(f"{name}: {count} {what}{'' if count == 1 else 's'}")

    def _readers(self) -> dict[str, Any]:
        """Every reader, by its topic."""
        readers = {c.topic: c.reader for c in self._cameras}
        readers.update({c.topics.info_topic: c.info_reader for c in self._cameras})
        if self._odometry_reader is not None:
            readers[self.odometry_topic] = self._odometry_reader  # type: ignore[index]
        if self._tf_reader is not None:
            readers["/tf_static"] = self._tf_reader
        return readers

    def _check_health(self) -> None:
        """Say once what does not match: a topic offered with QoS this node cannot take, or nothing published."""
        now = time.monotonic()
        if now < self._next_health:
            return
        self._next_health = now + HEALTH_S
        self.streams.expire(now)
        for name, reader in self._readers().items():
            status = reader.get_requested_incompatible_qos_status()
            if status.total_count > 0:
                self._say(None, f"qos {name}", f"{name}: a publisher offers QoS this node cannot take (policy "
                                               f"{status.last_policy_id}); see docs/ros2.md, QoS")


def _take_all(reader: Any, said: set[str], log: Callable[[str], None], name: str | None) -> list[Any]:
    out = []
    while True:
        try:
            samples = reader.take(64)
        except Exception as exc:
            if f"undecodable {name}" not in said:
                said.add(f"undecodable {name}")
                log(f"a message on {name} does not decode ({type(exc).__name__}: {exc}); left out")
            continue
        if not samples:
            return out
        out.extend(s for s in samples if _valid(s))


def _valid(sample: Any) -> bool:
    """A message, not news of a publisher that went away (DDS's samples without data)."""
    return bool(sample.sample_info.valid_data)


def _publishers(reader: Any) -> int:
    return int(reader.get_subscription_matched_status().current_count)


def _stamp(message: Any) -> int:
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
