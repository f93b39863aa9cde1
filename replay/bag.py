"""ROS 2 bags stored as MCAP (rosbag2's default storage), read without a ROS installation.

A bag is one ``.mcap`` file, or a rosbag2 folder of them (split recordings are read
in the order they were recorded). The frames are the messages of one image topic
(``sensor_msgs/msg/Image`` or ``sensor_msgs/msg/CompressedImage``) in log-time order,
timed by their header stamps. Positions come from one pose topic
(``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped``,
``geometry_msgs/msg/PoseWithCovarianceStamped``: x, y in metres; or
``sensor_msgs/msg/NavSatFix``: latitude, longitude) interpolated linearly at the
image stamps; images outside the pose topic's time span are dropped (noted). The pose topics
but NavSatFix also give the odometry (x, y and the heading, interpolated likewise), and the
camera's geometry comes from its ``camera_info`` topic and ``/tf_static`` (:mod:`.bagcamera`).
Needs the ``mcap`` and ``mcap-ros2-support`` packages (``pip install "lostx[bags]"``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
from tqdm import tqdm

from lostx.core.errors import ImageError, InputError, LostxError
from lostx.core.frame import Camera

from .bagcamera import bag_camera
from .folder import Traverse
from .odometry import interpolate_poses
from .positions import locate
from .rosmsg import IMAGE_TYPES, NAV_SAT_FIX, POSE_TYPES, image_rgb, pose_xy, pose_yaw, stamp_ns
from .store import file_identity

BAG_SUFFIX = ".mcap"


def is_bag(path: str | Path) -> bool:
    """An ``.mcap`` file, or a folder holding them (a rosbag2 recording)."""
    path = Path(path)
    if path.is_dir():
        return any(p.suffix.lower() == BAG_SUFFIX for p in path.iterdir() if p.is_file())
    return path.suffix.lower() == BAG_SUFFIX


def _mcap():
    try:
        from mcap.exceptions import McapError
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory
    except ImportError:
        raise InputError('reading ROS 2 bags needs the mcap packages: pip install "lostx[bags]" '
                         "(mcap and mcap-ros2-support)") from None
    return make_reader, DecoderFactory, McapError


@dataclass(frozen=True)
class Topic:
    name: str
    schema: str
    messages: int | None
    """Message count from the bag's summary (None where the bag has none)."""

    def describe(self) -> str:
        count = "" if self.messages is None else f", {self.messages} messages"
        return f"{self.name} ({self.schema}{count})"


class BagFile:
    """One open MCAP file: its topics, and its messages of one topic in log-time order."""

    def __init__(self, path: Path) -> None:
        make_reader, decoder_factory, self._error = _mcap()
        self.path = path
        try:
            self._handle = open(path, "rb")
        except FileNotFoundError:
            raise InputError(f"bag not found: {path}") from None
        except IsADirectoryError:
            raise InputError(f"{path}: a folder, not an MCAP file") from None
        try:
            self._reader = make_reader(self._handle)
            self.summary = self._reader.get_summary()
        except (self._error, ValueError, OSError) as exc:
            self.close()
            raise InputError(f"{path}: not a readable MCAP bag ({exc})") from None
        self._factory = decoder_factory()
        self._decoders: dict[int, Callable[[bytes], Any]] = {}

    def topics(self) -> dict[str, Topic]:
        if self.summary is not None:
            counts = self.summary.statistics.channel_message_counts if self.summary.statistics else {}
            out = {}
            for channel in self.summary.channels.values():
                schema = self.summary.schemas.get(channel.schema_id)
                out[channel.topic] = Topic(channel.topic, schema.name if schema else "?", counts.get(channel.id))
            return out
        # No summary (a recording that was not closed): the channels are only known by reading through.
        out = {}
        for schema, channel, _ in self._guard(self._reader.iter_messages()):
            if channel.topic not in out:
                out[channel.topic] = Topic(channel.topic, schema.name if schema else "?", None)
        return out

    @property
    def start_time(self) -> int:
        stats = self.summary.statistics if self.summary is not None else None
        return int(stats.message_start_time) if stats is not None else 0

    def messages(self, topic: str, at: int | None = None) -> Iterator[tuple[int, Callable[[], Any]]]:
        """(log time, decode) of each message on ``topic`` (only those logged at ``at``, when given)."""
        bounds = {} if at is None else {"starting_at": at, "ending_at": at}
        for schema, channel, message in self._guard(self._reader.iter_messages(topics=[topic], **bounds)):
            yield message.log_time, partial(self._decode, self._decoder(schema, channel), message)

    def _decode(self, decoder: Callable[[bytes], Any], message: Any) -> Any:
        try:
            return decoder(message.data)
        except (self._error, struct.error, ValueError, IndexError, UnicodeDecodeError, EOFError) as exc:
            raise InputError(f"{self.path}: a message logged at {message.log_time} ns cannot be decoded "
                             f"({type(exc).__name__}: {exc})") from None

    def _decoder(self, schema: Any, channel: Any) -> Callable[[bytes], Any]:
        decoder = self._decoders.get(channel.id)
        if decoder is None:
            decoder = self._factory.decoder_for(channel.message_encoding, schema)
            if decoder is None:
                raise InputError(f"{self.path}: topic {channel.topic} is encoded as {channel.message_encoding!r}; "
                                 f"lostx reads ROS 2 (CDR) messages")
            self._decoders[channel.id] = decoder
        return decoder

    def _guard(self, records: Iterator) -> Iterator:
        try:
            yield from records
        except LostxError:
            raise
        except (self._error, ValueError, EOFError, OSError) as exc:
            raise InputError(f"{self.path}: the bag is damaged or truncated ({exc})") from None

    def close(self) -> None:
        self._handle.close()


def bag_files(path: str | Path) -> list[Path]:
    """The MCAP files of a bag: the file itself, or a rosbag2 folder's files in recording order."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"bag not found: {path}")
    if not path.is_dir():
        return [path]
    files = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() == BAG_SUFFIX)
    if not files:
        others = sorted(p.name for p in path.iterdir() if p.suffix == ".db3")
        hint = f" (found SQLite storage {others[0]}: convert it with `ros2 bag convert` to MCAP)" if others else ""
        raise InputError(f"{path}: no .mcap files in this folder{hint}")
    return files


class BagImages:
    """The image messages of one topic across a bag's files, decoded on demand."""

    def __init__(self, origin: Path, files: list[Path], topic: str, schema: str,
                 file_index: np.ndarray, log_time: np.ndarray, rank: np.ndarray, stamps: np.ndarray) -> None:
        self._origin = origin
        self.files = files
        self.topic = topic
        self.schema = schema
        self.file_index = file_index
        self.log_time = log_time
        self.rank = rank
        """How many messages of the topic in the same file share this one's log time before it."""
        self.stamps = stamps
        self._open: dict[int, BagFile] = {}

    @property
    def origin(self) -> Path:
        return self._origin

    def __len__(self) -> int:
        return len(self.log_time)

    def name(self, row: int) -> str:
        stamp = int(self.stamps[row])
        return f"{stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d}"

    def _file(self, index: int) -> BagFile:
        if index not in self._open:
            self._open[index] = BagFile(self.files[index])
        return self._open[index]

    def _decode(self, row: int, decode: Callable[[], Any]) -> np.ndarray:
        try:
            return image_rgb(decode(), self.schema)
        except ImageError as exc:
            raise ImageError(f"{self.files[self.file_index[row]]}: {self.topic} message at {self.name(row)}: "
                             f"{exc}") from None

    def read(self, row: int) -> np.ndarray:
        bag = self._file(int(self.file_index[row]))
        same_time = bag.messages(self.topic, at=int(self.log_time[row]))
        for rank, (_, decode) in enumerate(same_time):
            if rank == self.rank[row]:
                return self._decode(row, decode)
        raise ImageError(f"{bag.path}: the {self.topic} message at {self.name(row)} is gone (the bag changed?)")

    def read_rows(self, rows: Sequence[int]) -> Iterator[np.ndarray]:
        rows = np.asarray(rows, dtype=np.int64)
        if len(rows) > 1 and np.any(np.diff(rows) <= 0):
            for row in rows:  # out of recording order: each message found through the bag's index
                yield self.read(int(row))
            return
        # In recording order: one pass through each file, decoding only the messages wanted. A message
        # is row r when its (file, log time, rank) is row r's; rows are in that order.
        keys = list(zip(self.file_index.tolist(), self.log_time.tolist(), self.rank.tolist()))
        wanted = iter(rows.tolist())
        target = next(wanted, None)
        row = 0
        for index in sorted(set(self.file_index[rows].tolist())):
            for logged, same, decode in _ranked(self._file(index).messages(self.topic)):
                key = (index, logged, same)
                while row < len(keys) and keys[row] < key:
                    row += 1
                if row < len(keys) and keys[row] == key:
                    if row == target:
                        yield self._decode(row, decode)
                        target = next(wanted, None)
                        if target is None:
                            return
                    row += 1
        if target is not None:
            raise ImageError(f"{self.origin}: the {self.topic} message at {self.name(target)} is gone "
                             f"(the bag changed?)")

    def fingerprint(self, rows: Sequence[int]) -> list:
        return [[file_identity(f) for f in self.files], self.topic, [int(r) for r in rows]]

    def close(self) -> None:
        for bag in self._open.values():
            bag.close()
        self._open.clear()


def _choose(path: Path, topics: dict[str, Topic], wanted: str | None, kinds: tuple[str, ...],
            what: str) -> list[Topic]:
    """The topic named ``wanted`` (checked to be of one of ``kinds``), or every topic of those kinds."""
    if wanted is None:
        return [t for t in topics.values() if t.schema in kinds]
    if wanted not in topics:
        listing = "; ".join(t.describe() for t in topics.values()) or "none"
        raise InputError(f"{path}: no topic {wanted} in the bag; its topics: {listing}")
    topic = topics[wanted]
    if topic.schema not in kinds:
        raise InputError(f"{path}: topic {wanted} holds {topic.schema} messages, not {what} ({' or '.join(kinds)})")
    return [topic]


def bag_traverse(
    path: str | Path,
    topic: str | None = None,
    pose_topic: str | None = None,
    camera: Camera | None = None,
    mirror: bool = False,
) -> Traverse:
    """The frames of one image topic of a bag, with positions from a pose topic where there is one.

    ``topic`` may be left out when the bag has exactly one image topic, ``pose_topic``
    when it has at most one pose topic.
    """
    path = Path(path)
    bags: list[BagFile] = []
    try:
        for file in bag_files(path):
            bags.append(BagFile(file))
        bags.sort(key=lambda b: (b.start_time, b.path.name))
        topics = _merged_topics(bags)
        listing = "; ".join(t.describe() for t in topics.values()) or "none"
        found = _choose(path, topics, topic, IMAGE_TYPES, "images")
        if len(found) != 1:
            reason = "no image topic" if not found else f"{len(found)} image topics; choose one with --topic"
            raise InputError(f"{path}: {reason}; its topics: {listing}")
        image_topic = found[0]
        notes: list[str] = []
        found = _choose(path, topics, pose_topic, POSE_TYPES, "poses")
        if len(found) > 1:
            notes.append(f"{len(found)} pose topics ({', '.join(t.name for t in found)}) and no --pose-topic: "
                         f"no positions")
        file_index, log_time, rank, stamps = _index_images(bags, image_topic)
        if len(stamps) == 0:
            raise InputError(f"{path}: topic {image_topic.name} has no messages")
        if np.any(stamps == 0):
            notes.append(f"{int((stamps == 0).sum())} images without a header stamp: timed by their log time")
            stamps = np.where(stamps == 0, log_time, stamps)
        positions = geo = odometry = None
        pose_child = None
        if len(found) == 1:
            poses = found[0]
            sample_times, values, yaws, pose_child = _pose_samples(bags, poses)
            if len(sample_times) < 2:
                raise InputError(f"{path}: topic {poses.name} has {len(sample_times)} usable poses; "
                                 f"positions need at least two")
            located = locate(sample_times, values, poses.schema == NAV_SAT_FIX, stamps)
            inside = located.inside
            if not inside.any():
                raise InputError(f"{path}: {poses.name} covers {sample_times[0] / 1e9:.3f}.."
                                 f"{sample_times[-1] / 1e9:.3f} s, none of the {len(stamps)} images of "
                                 f"{image_topic.name}")
            if not inside.all():
                notes.append(f"{int((~inside).sum())} images outside the time span of {poses.name}: dropped")
                file_index, log_time, rank, stamps = (a[inside] for a in (file_index, log_time, rank, stamps))
            positions, geo = located.positions, located.geo
            notes.append(f"positions from {poses.describe()}")
            if np.isfinite(yaws).all():
                odometry = interpolate_poses(sample_times, np.column_stack([values, yaws]), stamps)
        calibration = bag_camera(bags, topics, image_topic.name, pose_child, "rect" in image_topic.name)
        if calibration.note:
            notes.append(calibration.note)
    finally:
        for bag in bags:
            bag.close()
    files = [bag.path for bag in bags]
    images = BagImages(path, files, image_topic.name, image_topic.schema, file_index, log_time, rank, stamps)
    return Traverse(f"{path.name}{image_topic.name}", images, positions, stamps.astype(np.float64) / 1e9,
                    camera, mirror, geo=geo, notes=notes, geometry=calibration.geometry, odometry=odometry)


def _merged_topics(bags: list[BagFile]) -> dict[str, Topic]:
    """Every topic of the bag's files, with its message count summed over them (where all say)."""
    topics: dict[str, Topic] = {}
    for bag in bags:
        for name, found in bag.topics().items():
            known = topics.get(name)
            if known is not None:
                both = known.messages is not None and found.messages is not None
                found = Topic(name, found.schema, known.messages + found.messages if both else None)  # type: ignore[operator]
            topics[name] = found
    return topics


def _ranked(messages: Iterator[tuple[int, Callable[[], Any]]]) -> Iterator[tuple[int, int, Callable[[], Any]]]:
    """(log time, rank among the messages before it with the same log time, decode): with the
    file, what identifies a message in a bag."""
    previous, same = None, 0
    for logged, decode in messages:
        same = same + 1 if logged == previous else 0
        previous = logged
        yield logged, same, decode


def _index_images(bags: list[BagFile], topic: Topic) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(file, log time, rank, header stamp) of every message on ``topic``."""
    messages = ((index, logged, same, decode)
                for index, bag in enumerate(bags) for logged, same, decode in _ranked(bag.messages(topic.name)))
    # A bar only when it takes a while (a long recording of raw images).
    progress = tqdm(messages, total=topic.messages, desc=f"reading {topic.name}", unit="image", delay=2.0,
                    leave=False)
    rows = [(index, logged, same, stamp_ns(decode())) for index, logged, same, decode in progress]
    table = np.asarray(rows, dtype=np.int64).reshape(-1, 4)
    return table[:, 0], table[:, 1], table[:, 2], table[:, 3]


def _pose_samples(bags: list[BagFile], topic: Topic) -> tuple[np.ndarray, np.ndarray, np.ndarray, str | None]:
    """Time-ordered (stamp ns, (x, y) or (lat, lon), heading in radians or NaN) of a pose topic, fixes
    without a position left out; and the vehicle frame the poses are of (an Odometry's child frame)."""
    times, values, yaws = [], [], []
    child = None
    for bag in bags:
        for logged, decode in bag.messages(topic.name):
            message = decode()
            xy = pose_xy(message, topic.schema)
            if xy is None or not all(np.isfinite(xy)):
                continue
            times.append(stamp_ns(message) or logged)
            values.append(xy)
            yaw = pose_yaw(message, topic.schema)
            yaws.append(np.nan if yaw is None else yaw)
            child = child or (str(getattr(message, "child_frame_id", "")).lstrip("/") or None)
    order = np.argsort(np.asarray(times, dtype=np.int64), kind="stable")
    t = np.asarray(times, dtype=np.int64)[order]
    v = np.asarray(values, dtype=np.float64).reshape(-1, 2)[order]
    h = np.asarray(yaws, dtype=np.float64)[order]
    keep = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, bool)  # one sample per stamp
    return t[keep], v[keep], h[keep], child
