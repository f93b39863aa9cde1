"""The messages of the wire protocol as Python types (docs/protocol.md is the spec): the schema version,
the topics and error codes, the limits a receiver applies, and one dataclass per message type.

How they travel as bytes is :mod:`lostx.stream.wire`; how a received message is checked is
:mod:`lostx.stream.validate`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from lostx.core.config import StreamConfig
from lostx.core.frame import Frame
from lostx.core.geometry import CameraGeometry

from .errors import ProtocolError
from .images import decode_image

VERSION = 4
"""Newest schema version (``v``): what lostx's producers send (``hello``, ``frame``), and what the service's
replies to such a producer say (``ready`` with ``journal`` and ``history``, ``ack`` with ``stream``)."""
VERSIONS: tuple[int, ...] = (2, 3, 4)
"""Schema versions a receiver reads; it refuses any other. Version 3 adds a frame's ``odometry`` and
``geometry``; a version-2 frame that carries them is refused (``unknown_field``), as version 2 always did."""
STEADY_VERSION = 3
"""The version of every message version 4 left as it was (errors, the results and history channels) and of
the replies to a producer that speaks 2 or 3: lostx sends these as version 3, so peers written for it read
them unchanged."""

TOPICS: tuple[bytes, ...] = (b"result", b"error", b"stats")
"""First part of every message on the results channel."""

ERROR_CODES: dict[str, str] = {
    "too_large": "the message is over the size limit",
    "multipart": "a frames-channel message had more than one part",
    "malformed": "not one complete msgpack value (truncated, trailing bytes, too deep, over a length limit, bad UTF-8)",
    "not_a_map": "the message is not a msgpack map with string keys",
    "missing_field": "a required field is absent",
    "bad_version": "v is not a schema version this peer speaks",
    "unknown_type": "type names no message this channel carries",
    "unknown_field": "a field this message type does not have",
    "bad_type": "a field has the wrong msgpack type",
    "bad_value": "a field has the right type but an unusable value",
    "image_too_large": "the image declares more pixels than the limit",
    "bad_image": "the image bytes do not decode, or do not match the declared shape",
    "localizer_failed": "the localizer could not answer this frame",
    "bad_timestamp": "the timestamp goes back in its stream, or jumps further ahead than max_time_jump",
    "too_many_streams": "the frame starts a stream while max_streams streams are live",
    "journal_failed": "the journal could not be read",
    "journal_unwritable": "the journal cannot be written now (a full or failing disk); the frame was not accepted",
}

MAX_NAME = 256
"""Characters in short strings: stream, name, camera, encoding, codes."""
MAX_METADATA_DEPTH = 4
"""Nesting of maps and arrays inside ``metadata``."""
MAX_FETCH = 1024
"""Most answers a ``fetch`` may ask for at once."""


@dataclass(frozen=True)
class Limits:
    """What a receiver accepts. Built from :class:`StreamConfig` so both sides agree."""

    max_message_bytes: int = 16 * 1024 * 1024
    max_pixels: int = 4096 * 4096
    max_str_len: int = 64 * 1024
    max_array_len: int = 4096
    max_map_len: int = 256

    @classmethod
    def from_config(cls, config: StreamConfig) -> "Limits":
        return cls(max_message_bytes=config.max_message_bytes, max_pixels=config.max_pixels)


@dataclass(frozen=True)
class Hello:
    """Producer -> service: announce yourself; the service answers with :class:`Ready`."""

    stream: str | None = None
    name: str | None = None
    version: int = VERSION
    """The schema version the producer spoke; its ``ready`` is given in it."""


@dataclass
class FrameMessage:
    """Producer -> service: one camera frame, image still encoded."""

    id: int
    camera: str | None
    encoding: str
    image: bytes
    shape: tuple[int, ...] | None = None
    timestamp: float | None = None
    position: tuple[float, float] | None = None
    name: str = ""
    stream: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    odometry: tuple[float, float, float] | None = None
    """The vehicle's pose (x, y metres, yaw radians) in the producer's odometry frame (version 3)."""
    geometry: CameraGeometry | None = None
    """The camera's intrinsics and mounting, checked when the message was read (version 3)."""
    version: int = VERSION
    """The schema version the producer spoke; its ``ack`` is given in it."""

    def to_frame(self) -> Frame:
        """Decode the image (its size was checked when the message was read)."""
        try:
            image = decode_image(self.image, self.encoding, self.shape)
        except ProtocolError as exc:
            exc.frame_id = self.id
            raise
        return Frame(
            id=self.id, image=image, timestamp=self.timestamp, camera=self.camera,  # type: ignore[arg-type]
            position=self.position, name=self.name, metadata=self.metadata, geometry=self.geometry,
            odometry=self.odometry,
        )


@dataclass(frozen=True)
class Ready:
    """Service -> producer: the service is up. In lossless mode, send at most ``window``
    frames that have not been acknowledged."""

    session: str
    mode: str
    window: int
    max_message_bytes: int
    max_pixels: int
    journal: str | None = None
    """The id of the service's journal; None without one (version 4)."""
    history: str | None = None
    """The history endpoint as the service bound it; None without a journal (version 4)."""


@dataclass(frozen=True)
class Ack:
    """Service -> producer (lossless): ``frame_id`` of ``stream`` is answered; one more frame may be sent."""

    session: str
    frame_id: int
    stream: str | None = None
    """The frame's stream (``""`` for a frame that named none); None in a version-3 ack, which lacks it."""


@dataclass(frozen=True)
class Tag:
    """Where an answer stands in the service's sequence of answers (results and frame errors)."""

    stream: str
    """The stream of the answered frame (``""`` for a frame that named none)."""
    seq: int
    """Number of the answer among all the service's answers, from 1; with a journal it goes on
    across restarts of the service, and listeners resume from it."""
    stream_seq: int
    """Number of the answer within its stream's state, from 1."""
    journal: str | None = None
    """Id of the journal that holds the answer; None without one."""


@dataclass(frozen=True)
class ErrorMessage:
    """Service -> producer and listeners: a message was refused, or a frame could not be answered."""

    code: str
    text: str
    frame_id: int | None = None
    session: str | None = None
    tag: Tag | None = None
    """Where an error that answers an accepted frame stands among the answers; None for refusals."""


@dataclass(frozen=True)
class ResultCandidate:
    index: int
    distance: float | None
    score: float | None
    correspondences: int


@dataclass(frozen=True)
class Result:
    """The localizer's answer for one frame: :meth:`Estimate.summary` as it arrives at a listener."""

    frame_id: int
    timestamp: float | None
    state: str
    match_index: int
    match_name: str
    position: tuple[float, float] | None
    confidence: float
    score: float | None
    single_match_index: int
    candidates: tuple[ResultCandidate, ...]
    sequence_score: float | None
    speed: float | None
    window: int
    warming_up: bool
    margin: float | None
    heading: str
    heading_confidence: float
    latency_ms: dict[str, float]
    tag: Tag
    session: str = ""
    cue_weights: dict[str, float] = field(default_factory=dict)
    """The weight each single-frame cue had (``lostx``, ``layout``, ``appearance``); empty from a service that sends
    none."""
    disagrees: bool = False
    """The frames' own answers did not keep to the sequence filter's line."""

    @property
    def localized(self) -> bool:
        return self.state == "localized"

    def to_dict(self) -> dict[str, Any]:
        """Plain types, the keys of :meth:`Estimate.summary` plus ``session`` and the tag's fields."""
        data = asdict(self)
        data["position"] = None if self.position is None else list(self.position)
        data["candidates"] = [asdict(c) for c in self.candidates]
        data.update(data.pop("tag"))
        return data


@dataclass(frozen=True)
class JournalInfo:
    """What the service's journal holds: answers ``first`` to ``last`` (0, 0 when empty), all of them durable."""

    id: str
    first: int
    last: int
    bytes: int
    segments: int
    blocked: str | None = None
    """Why the journal cannot be written now (a full disk, say): frames are refused meanwhile; None while it is."""
    withdrawn: int = 0
    """Answers taken back since the service started because the journal could not make them durable (their frames
    refused with ``journal_unwritable``, to be sent again)."""


@dataclass(frozen=True)
class StreamStats:
    received: int
    answered: int
    errors: int
    dropped: int
    missing: int
    duplicates: int
    restarts: int
    """New traverses started because the stream's clock jumped back by more than max_time_jump."""
    queued: int
    """Frames taken and not yet answered."""
    idle_s: float
    """Seconds since the stream's last frame."""


@dataclass(frozen=True)
class Stats:
    """Service -> listeners, every ``stats_interval`` seconds and once on exit (``final``)."""

    session: str
    mode: str
    uptime_s: float
    received: int
    """Frames read and accepted (valid messages)."""
    answered: int
    """Frames answered with a result."""
    dropped: int
    """Live mode: frames received but superseded by a newer one before the localizer was free."""
    missing: int
    """Frame ids skipped in a stream (never arrived: dropped by the producer or the transport)."""
    duplicates: int
    """Lossless: frames resent by a producer after they were answered, acknowledged again, not re-answered."""
    errors: int
    """Error messages sent."""
    errors_by_code: dict[str, int]
    queued_frames: int
    queued_results: int
    listeners: int
    producers: int
    latency_ms: dict[str, dict[str, float]]
    """``step``: the localizer; ``service``: frame read -> result handed to the socket.
    Each ``{"n", "p50", "p90", "p99", "max"}`` over the last frames (``n`` a count)."""
    final: bool = False
    seq: int = 0
    """The last answer handed to the results socket (0 before any)."""
    journal: JournalInfo | None = None
    streams: dict[str, StreamStats] = field(default_factory=dict)
    """Per stream with a state on the service."""


@dataclass(frozen=True)
class Fetch:
    """Listener -> service (history channel): the journaled answers after ``after``."""

    after: int
    max: int = 256


@dataclass(frozen=True)
class History:
    """Service -> listener: journaled answers ``after + 1`` on (each a results-channel payload),
    and the journal's range. ``first`` above ``after + 1`` means older answers were rotated out."""

    session: str
    journal: str
    after: int
    first: int
    last: int
    items: tuple[bytes, ...]


Reply = Ready | Ack | ErrorMessage
Published = Result | ErrorMessage | Stats
Answer = Result | ErrorMessage
