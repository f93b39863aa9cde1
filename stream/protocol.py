"""The wire protocol: msgpack messages with a schema version (docs/protocol.md is the spec).

Two channels, both bound by the service:

* frames (ROUTER at the service, DEALER at each producer): ``hello`` and ``frame``
  in; ``ready``, ``ack`` and ``error`` back to the producer that sent them.
* results (XPUB at the service, SUB at each listener): two-part messages
  ``[topic, payload]`` with topic ``result``, ``error`` or ``stats``.
* history (ROUTER at the service, DEALER at a listener; with a journal): ``fetch``
  in, ``history`` (journaled answers) or ``error`` back.

Every payload is one msgpack map with ``v`` (schema version) and ``type``.
Decoding never trusts the peer: the size is checked before msgpack sees the
bytes, msgpack's own length limits stop a hostile length field from
allocating memory, every field is type-checked, and every failure raises a
:class:`ProtocolError` carrying an error code and, where it could be read,
the frame id.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Mapping

import msgpack
import numpy as np

from lostx.core.config import StreamConfig
from lostx.core.frame import CAMERAS, HEADINGS, Frame

from .errors import ProtocolError
from .images import ENCODINGS, check_pixels, decode_image, encode_image, header_size

VERSION = 2
"""Schema version carried in every message's ``v``; a receiver refuses any other."""

TOPICS: tuple[bytes, ...] = (b"result", b"error", b"stats")
"""First part of every message on the results channel."""

ERROR_CODES: dict[str, str] = {
    "too_large": "the message is over the size limit",
    "multipart": "a frames-channel message had more than one part",
    "malformed": "not one complete msgpack value (truncated, trailing bytes, too deep, over a length limit, bad UTF-8)",
    "not_a_map": "the message is not a msgpack map with string keys",
    "missing_field": "a required field is absent",
    "bad_version": "v is not the schema version this peer speaks",
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


# ---------------------------------------------------------------------------------------------
# Messages


@dataclass(frozen=True)
class Hello:
    """Producer -> service: announce yourself; the service answers with :class:`Ready`."""

    stream: str | None = None
    name: str | None = None


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

    def to_frame(self) -> Frame:
        """Decode the image (its size was checked when the message was read)."""
        try:
            image = decode_image(self.image, self.encoding, self.shape)
        except ProtocolError as exc:
            exc.frame_id = self.id
            raise
        return Frame(
            id=self.id, image=image, timestamp=self.timestamp, camera=self.camera,  # type: ignore[arg-type]
            position=self.position, name=self.name, metadata=self.metadata,
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


@dataclass(frozen=True)
class Ack:
    """Service -> producer (lossless): ``frame_id`` is answered; one more frame may be sent."""

    session: str
    frame_id: int


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
    """What the service's journal holds: answers ``first`` to ``last`` (0, 0 when empty)."""

    id: str
    first: int
    last: int
    bytes: int
    segments: int


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


# ---------------------------------------------------------------------------------------------
# Encoding


def _pack(message: dict[str, Any]) -> bytes:
    return msgpack.packb({"v": VERSION, **message}, use_bin_type=True)


def encode_hello(stream: str | None = None, name: str | None = None) -> bytes:
    message: dict[str, Any] = {"type": "hello"}
    if stream is not None:
        message["stream"] = stream
    if name is not None:
        message["name"] = name
    return _pack(message)


def encode_frame(frame: Frame, encoding: str = "raw", quality: int = 90, stream: str | None = None) -> bytes:
    """A frame message. ``raw`` is exact and cheapest on loopback; ``jpeg`` for networks."""
    image = frame.image
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"frame {frame.id}: expected an RGB uint8 H x W x 3 image")
    message: dict[str, Any] = {
        "type": "frame",
        "id": int(frame.id),
        "encoding": encoding,
        "image": encode_image(image, encoding, quality),
        "shape": [int(s) for s in image.shape],
    }
    if encoding == "raw":
        message["dtype"] = "uint8"
    if frame.camera is not None:
        message["camera"] = frame.camera
    if frame.timestamp is not None:
        message["timestamp"] = float(frame.timestamp)
    if frame.position is not None:
        message["position"] = [float(v) for v in frame.position]
    if frame.name:
        message["name"] = frame.name
    if stream is not None:
        message["stream"] = stream
    if frame.metadata:
        message["metadata"] = frame.metadata
    return _pack(message)


def encode_ready(ready: Ready) -> bytes:
    return _pack({"type": "ready", **asdict(ready)})


def encode_ack(ack: Ack) -> bytes:
    return _pack({"type": "ack", **asdict(ack)})


def encode_error(error: ErrorMessage) -> bytes:
    message: dict[str, Any] = {"type": "error", "frame_id": error.frame_id, "code": error.code, "text": error.text}
    if error.session is not None:
        message["session"] = error.session
    if error.tag is not None:
        message.update(_tag_fields(error.tag))
    return _pack(message)


def encode_result(summary: Mapping[str, Any], session: str, tag: Tag) -> bytes:
    """A result message from :meth:`Estimate.summary` (already plain types)."""
    return _pack({"type": "result", "session": session, **summary, **_tag_fields(tag)})


def _tag_fields(tag: Tag) -> dict[str, Any]:
    fields: dict[str, Any] = {"stream": tag.stream, "seq": tag.seq, "stream_seq": tag.stream_seq}
    if tag.journal is not None:
        fields["journal"] = tag.journal
    return fields


def encode_stats(stats: Stats) -> bytes:
    return _pack({"type": "stats", **asdict(stats)})


def encode_fetch(fetch: Fetch) -> bytes:
    return _pack({"type": "fetch", "after": fetch.after, "max": fetch.max})


def encode_history(history: History) -> bytes:
    return _pack({"type": "history", **asdict(history), "items": list(history.items)})


# ---------------------------------------------------------------------------------------------
# Decoding


def unpack(data: bytes | memoryview, limits: Limits) -> dict[str, Any]:
    """One msgpack map from ``data``, within the limits; :class:`ProtocolError` otherwise."""
    if len(data) > limits.max_message_bytes:
        raise ProtocolError("too_large", f"message of {len(data)} bytes is over the limit of {limits.max_message_bytes}")
    try:
        value = msgpack.unpackb(
            data, raw=False, strict_map_key=True, use_list=True,
            max_bin_len=limits.max_message_bytes, max_str_len=limits.max_str_len,
            max_array_len=limits.max_array_len, max_map_len=limits.max_map_len, max_ext_len=0,
        )
    except msgpack.ExtraData:
        raise ProtocolError("malformed", "trailing bytes after the msgpack value") from None
    except msgpack.StackError:
        raise ProtocolError("malformed", "msgpack value nested too deeply") from None
    except (ValueError, TypeError, UnicodeDecodeError, OverflowError) as exc:
        # ValueError covers truncated input, limits exceeded, bad map keys; FormatError is one too.
        raise ProtocolError("malformed", f"not a valid msgpack message ({_short(exc)})") from None
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise ProtocolError("not_a_map", f"message is a msgpack {_kind(value)}, not a map with string keys")
    return value


def read_frame_id(message: Mapping[str, Any]) -> int | None:
    """The frame id of a message where one can be read (an ``id`` that is a valid id), for error
    replies; read whatever else is wrong with the message, so a sender learns which frame failed."""
    value = message.get("id")
    return int(value) if _is_uint(value) else None


def decode_request(data: bytes | memoryview, limits: Limits) -> Hello | FrameMessage:
    """A frames-channel message from a producer."""
    message = unpack(data, limits)
    frame_id = read_frame_id(message)
    try:
        kind = _envelope(message, ("hello", "frame"))
        if kind == "hello":
            return _decode_hello(message)
        return _decode_frame(message, limits)
    except ProtocolError as exc:
        exc.frame_id = frame_id
        raise


def decode_reply(data: bytes, limits: Limits) -> Reply:
    """A frames-channel message from the service, as a producer reads it."""
    message = unpack(data, limits)
    kind = _envelope(message, ("ready", "ack", "error"))
    if kind == "ready":
        f = _Fields(message, _READY)
        mode = f.value("mode")
        if mode not in ("live", "lossless"):
            raise ProtocolError("bad_value", f"mode {mode!r} is not live or lossless")
        window = f.value("window")
        if window < 1 and mode == "lossless":
            raise ProtocolError("bad_value", f"window {window} must be at least 1")
        return Ready(f.value("session"), mode, window, f.value("max_message_bytes"), f.value("max_pixels"))
    if kind == "ack":
        f = _Fields(message, _ACK)
        return Ack(f.value("session"), f.value("frame_id"))
    return _decode_error(message)


def decode_published(topic: bytes, data: bytes, limits: Limits) -> Published:
    """A results-channel message (its two parts) as a listener reads it.

    Listeners tolerate fields they do not know (a newer service may add some within the
    same version); every field they do know is type-checked.
    """
    if topic not in TOPICS:
        raise ProtocolError("unknown_type", f"unknown topic {topic[:32]!r}")
    message = unpack(data, limits)
    kind = _envelope(message, (topic.decode(),))
    if kind == "result":
        return _decode_result(message)
    if kind == "error":
        return _decode_error(message, strict=False)
    return _decode_stats(message)


def decode_answer(data: bytes, limits: Limits) -> Answer:
    """One journaled answer (an item of a ``history`` reply): a result or a frame's error."""
    message = unpack(data, limits)
    if _envelope(message, ("result", "error")) == "result":
        return _decode_result(message)
    error = _decode_error(message, strict=False)
    if error.tag is None:
        raise ProtocolError("missing_field", "a journaled error needs its stream, seq and stream_seq")
    return error


def decode_fetch(data: bytes | memoryview, limits: Limits) -> Fetch:
    """A history-channel request, as the service reads it."""
    message = unpack(data, limits)
    _envelope(message, ("fetch",))
    f = _Fields(message, _FETCH)
    count = f.value("max", 256)
    if not 1 <= count <= MAX_FETCH:
        raise ProtocolError("bad_value", f"max is {count}; ask for 1 to {MAX_FETCH} answers")
    return Fetch(f.value("after"), count)


def decode_history(data: bytes, limits: Limits) -> History | ErrorMessage:
    """A history-channel reply, as a listener reads it."""
    message = unpack(data, limits)
    if _envelope(message, ("history", "error")) == "error":
        return _decode_error(message, strict=False)
    f = _Fields(message, _HISTORY, strict=False)
    items = f.value("items")
    if not all(isinstance(item, bytes) for item in items):
        raise ProtocolError("bad_type", "history items must be bin")
    return History(f.value("session"), f.value("journal"), f.value("after"), f.value("first"), f.value("last"),
                   tuple(items))


def _envelope(message: Mapping[str, Any], types: tuple[str, ...]) -> str:
    if "v" not in message:
        raise ProtocolError("missing_field", "no schema version v")
    version = message["v"]
    if not _is_int(version):
        raise ProtocolError("bad_version", f"v must be an integer, got a {_kind(version)}")
    if version != VERSION:
        raise ProtocolError("bad_version", f"schema version {version} is not supported (this peer speaks {VERSION})")
    if "type" not in message:
        raise ProtocolError("missing_field", "no message type")
    kind = message["type"]
    if not isinstance(kind, str):
        raise ProtocolError("bad_type", f"type must be a string, got a {_kind(kind)}")
    if kind not in types:
        raise ProtocolError("unknown_type", f"type {kind[:MAX_NAME]!r} is not one of {', '.join(types)}")
    return kind


# Field schemas: name -> (kind, required). A wrong kind is bad_type; values are checked after.


@dataclass(frozen=True)
class _Kind:
    description: str
    test: Callable[[Any], bool]

    def __call__(self, value: Any) -> bool:
        return self.test(value)

    def or_nil(self) -> "_Kind":
        return _Kind(f"{self.description} or nil", lambda v: v is None or self.test(v))


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_uint(v: Any) -> bool:
    return _is_int(v) and 0 <= v < 2**63


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


_INT = _Kind("an integer", _is_int)
_UINT = _Kind("a non-negative integer below 2**63", _is_uint)
_NUMBER = _Kind("a finite number", _is_number)
_STR = _Kind("a string", lambda v: isinstance(v, str))
_BIN = _Kind("bin (bytes)", lambda v: isinstance(v, bytes))
_BOOL = _Kind("a boolean", lambda v: isinstance(v, bool))
_ARRAY = _Kind("an array", lambda v: isinstance(v, list))
_MAP = _Kind("a map", lambda v: isinstance(v, dict))

Schema = dict[str, tuple[_Kind, bool]]

_HELLO: Schema = {"v": (_INT, True), "type": (_STR, True), "stream": (_STR, False), "name": (_STR, False)}
_FRAME: Schema = {
    "v": (_INT, True), "type": (_STR, True),
    "id": (_UINT, True), "camera": (_STR.or_nil(), False), "encoding": (_STR, True), "image": (_BIN, True),
    "shape": (_ARRAY, False), "dtype": (_STR, False), "timestamp": (_NUMBER.or_nil(), False),
    "position": (_ARRAY.or_nil(), False), "name": (_STR, False), "stream": (_STR, False),
    "metadata": (_MAP, False),
}
_READY: Schema = {
    "v": (_INT, True), "type": (_STR, True), "session": (_STR, True), "mode": (_STR, True),
    "window": (_UINT, True), "max_message_bytes": (_UINT, True), "max_pixels": (_UINT, True),
}
_ACK: Schema = {"v": (_INT, True), "type": (_STR, True), "session": (_STR, True), "frame_id": (_UINT, True)}
_TAG: Schema = {"stream": (_STR, True), "seq": (_UINT, True), "stream_seq": (_UINT, True), "journal": (_STR, False)}
_ERROR: Schema = {
    "v": (_INT, True), "type": (_STR, True), "frame_id": (_UINT.or_nil(), True),
    "code": (_STR, True), "text": (_STR, True), "session": (_STR, False),
    **{name: (kind, False) for name, (kind, _) in _TAG.items()},
}
_RESULT: Schema = {
    "v": (_INT, True), "type": (_STR, True), "session": (_STR, False),
    "frame_id": (_UINT, True), "timestamp": (_NUMBER.or_nil(), True), "state": (_STR, True),
    "match_index": (_UINT, True), "match_name": (_STR, True), "position": (_ARRAY.or_nil(), True),
    "confidence": (_NUMBER, True), "score": (_NUMBER.or_nil(), True),
    "single_match_index": (_UINT, True), "candidates": (_ARRAY, True),
    "sequence_score": (_NUMBER.or_nil(), True), "speed": (_NUMBER.or_nil(), True),
    "window": (_UINT, True), "warming_up": (_BOOL, True),
    "margin": (_NUMBER.or_nil(), True), "heading": (_STR, True), "heading_confidence": (_NUMBER, True),
    "latency_ms": (_MAP, True), **_TAG,
}
_CANDIDATE: Schema = {
    "index": (_UINT, True), "distance": (_NUMBER.or_nil(), True), "score": (_NUMBER.or_nil(), True),
    "correspondences": (_UINT, True),
}
_STATS: Schema = {
    "v": (_INT, True), "type": (_STR, True), "session": (_STR, True), "mode": (_STR, True),
    "uptime_s": (_NUMBER, True), "received": (_UINT, True), "answered": (_UINT, True),
    "dropped": (_UINT, True), "missing": (_UINT, True), "duplicates": (_UINT, True),
    "errors": (_UINT, True),
    "errors_by_code": (_MAP, True), "queued_frames": (_UINT, True), "queued_results": (_UINT, True),
    "listeners": (_UINT, True), "producers": (_UINT, True), "latency_ms": (_MAP, True),
    "final": (_BOOL, False), "seq": (_UINT, True), "journal": (_MAP.or_nil(), True), "streams": (_MAP, True),
}
_JOURNAL: Schema = {"id": (_STR, True), "first": (_UINT, True), "last": (_UINT, True), "bytes": (_UINT, True),
                    "segments": (_UINT, True)}
_STREAM_STATS: Schema = {
    **{name: (_UINT, True) for name in ("received", "answered", "errors", "dropped", "missing", "duplicates",
                                        "restarts", "queued")},
    "idle_s": (_NUMBER, True),
}
_FETCH: Schema = {"v": (_INT, True), "type": (_STR, True), "after": (_UINT, True), "max": (_UINT, False)}
_HISTORY: Schema = {
    "v": (_INT, True), "type": (_STR, True), "session": (_STR, True), "journal": (_STR, True),
    "after": (_UINT, True), "first": (_UINT, True), "last": (_UINT, True), "items": (_ARRAY, True),
}


class _Fields:
    """Type-checked access to a message's fields against a schema."""

    def __init__(self, message: Mapping[str, Any], schema: Schema, strict: bool = True, where: str = "") -> None:
        self.message = message
        self.where = where
        if strict:
            unknown = [k for k in message if k not in schema]
            if unknown:
                names = ", ".join(repr(k[:MAX_NAME]) for k in unknown[:5])
                raise ProtocolError("unknown_field", f"{where}unknown field(s) {names}")
        for name, (check, required) in schema.items():
            if name not in message:
                if required:
                    raise ProtocolError("missing_field", f"{where}required field {name!r} is missing")
                continue
            if not check(message[name]):
                raise ProtocolError(
                    "bad_type", f"{where}field {name!r} must be {check.description}, got a {_kind(message[name])}"
                )

    def value(self, name: str, default: Any = None) -> Any:
        return self.message.get(name, default)


def _short_str(f: _Fields, name: str, default: str | None = None) -> str | None:
    value = f.value(name, default)
    if value is not None and len(value) > MAX_NAME:
        raise ProtocolError("bad_value", f"{f.where}{name} is {len(value)} characters long (at most {MAX_NAME})")
    return value


def _decode_hello(message: Mapping[str, Any]) -> Hello:
    f = _Fields(message, _HELLO)
    return Hello(stream=_short_str(f, "stream"), name=_short_str(f, "name"))


def _decode_frame(message: Mapping[str, Any], limits: Limits) -> FrameMessage:
    f = _Fields(message, _FRAME)
    camera = _short_str(f, "camera")
    if camera is not None and camera not in CAMERAS:
        raise ProtocolError("bad_value", f"camera {camera!r} is not one of {', '.join(CAMERAS)}")
    encoding = _short_str(f, "encoding")
    if encoding not in ENCODINGS:
        raise ProtocolError("bad_value", f"encoding {encoding!r} is not one of {', '.join(ENCODINGS)}")
    image: bytes = f.value("image")
    shape = _shape(f.value("shape"))
    dtype = _short_str(f, "dtype")
    if encoding == "raw":
        if shape is None:
            raise ProtocolError("missing_field", "a raw image needs its shape")
        if dtype is None:
            raise ProtocolError("missing_field", "a raw image needs its dtype")
        if dtype != "uint8":
            raise ProtocolError("bad_value", f"dtype {dtype!r} is not supported (raw images are uint8)")
        check_pixels(shape[0], shape[1], limits.max_pixels)
        expected = math.prod(shape)
        if len(image) != expected:
            raise ProtocolError(
                "bad_image", f"raw image of shape {list(shape)} needs {expected} bytes, the message has {len(image)}"
            )
    else:
        if dtype is not None and dtype != "uint8":
            raise ProtocolError("bad_value", f"dtype {dtype!r} is not supported (images are uint8)")
        height, width = header_size(image, encoding)
        check_pixels(height, width, limits.max_pixels)
        if shape is not None and (shape[0], shape[1]) != (height, width):
            raise ProtocolError(
                "bad_image", f"the {encoding} header says {width}x{height}, the message says {shape[1]}x{shape[0]}"
            )
    position = f.value("position")
    if position is not None:
        if len(position) != 2 or not all(_is_number(v) for v in position):
            raise ProtocolError("bad_value", "position must be two finite numbers [x, y]")
        position = (float(position[0]), float(position[1]))
    metadata = f.value("metadata", {})
    _check_metadata(metadata)
    timestamp = f.value("timestamp")
    return FrameMessage(
        id=int(f.value("id")), camera=camera, encoding=encoding, image=image, shape=shape,
        timestamp=None if timestamp is None else float(timestamp), position=position,
        name=_short_str(f, "name", "") or "", stream=_short_str(f, "stream"), metadata=metadata,
    )


def _shape(value: Any) -> tuple[int, ...] | None:
    if value is None:
        return None
    if len(value) not in (2, 3) or not all(_is_uint(v) for v in value):
        raise ProtocolError("bad_value", "shape must be [height, width] or [height, width, 3] of non-negative integers")
    if len(value) == 3 and value[2] != 3:
        raise ProtocolError("bad_value", f"shape has {value[2]} channels; images have 3 (RGB) or none (grey)")
    return tuple(int(v) for v in value)


def _check_metadata(value: Any, depth: int = 0) -> None:
    """JSON-like values only, nested at most :data:`MAX_METADATA_DEPTH` deep."""
    if isinstance(value, dict):
        if depth >= MAX_METADATA_DEPTH:
            raise ProtocolError("bad_value", f"metadata is nested more than {MAX_METADATA_DEPTH} levels deep")
        for item in value.values():
            _check_metadata(item, depth + 1)
    elif isinstance(value, list):
        if depth >= MAX_METADATA_DEPTH:
            raise ProtocolError("bad_value", f"metadata is nested more than {MAX_METADATA_DEPTH} levels deep")
        for item in value:
            _check_metadata(item, depth + 1)
    elif isinstance(value, float) and not math.isfinite(value):
        raise ProtocolError("bad_value", "metadata holds a NaN or infinite number")
    elif not (value is None or isinstance(value, (bool, int, float, str))):
        raise ProtocolError("bad_type", f"metadata holds a {_kind(value)}; only nil, bool, numbers, strings, arrays, maps")


def _decode_error(message: Mapping[str, Any], strict: bool = True) -> ErrorMessage:
    f = _Fields(message, _ERROR, strict=strict)
    tag = _decode_tag(f) if "seq" in message else None
    return ErrorMessage(code=f.value("code")[:MAX_NAME], text=f.value("text"), frame_id=f.value("frame_id"),
                        session=f.value("session"), tag=tag)


def _decode_tag(f: _Fields) -> Tag:
    for name, (_, required) in _TAG.items():
        if required and name not in f.message:
            raise ProtocolError("missing_field", f"required field {name!r} is missing")
    return Tag(f.value("stream"), f.value("seq"), f.value("stream_seq"), f.value("journal"))


def _decode_result(message: Mapping[str, Any]) -> Result:
    f = _Fields(message, _RESULT, strict=False)
    if f.value("state") not in ("localized", "not_localized"):
        raise ProtocolError("bad_value", f"state {f.value('state')!r} is not localized or not_localized")
    if f.value("heading") not in HEADINGS:
        raise ProtocolError("bad_value", f"heading {f.value('heading')!r} is not one of {', '.join(HEADINGS)}")
    candidates = []
    for i, item in enumerate(f.value("candidates")):
        if not isinstance(item, dict):
            raise ProtocolError("bad_type", f"candidates[{i}] must be a map")
        c = _Fields(item, _CANDIDATE, strict=False, where=f"candidates[{i}]: ")
        candidates.append(ResultCandidate(c.value("index"), _opt_float(c.value("distance")),
                                          _opt_float(c.value("score")), c.value("correspondences")))
    latency = f.value("latency_ms")
    if not all(isinstance(k, str) and _is_number(v) for k, v in latency.items()):
        raise ProtocolError("bad_type", "latency_ms must map stage names to numbers")
    position = f.value("position")
    if position is not None:
        if len(position) != 2 or not all(_is_number(v) for v in position):
            raise ProtocolError("bad_value", "position must be two finite numbers [x, y]")
        position = (float(position[0]), float(position[1]))
    return Result(
        frame_id=f.value("frame_id"), timestamp=_opt_float(f.value("timestamp")), state=f.value("state"),
        match_index=f.value("match_index"), match_name=f.value("match_name"), position=position,
        confidence=float(f.value("confidence")), score=_opt_float(f.value("score")),
        single_match_index=f.value("single_match_index"), candidates=tuple(candidates),
        sequence_score=_opt_float(f.value("sequence_score")), speed=_opt_float(f.value("speed")),
        window=f.value("window"), warming_up=f.value("warming_up"),
        margin=_opt_float(f.value("margin")),
        heading=f.value("heading"), heading_confidence=float(f.value("heading_confidence")),
        latency_ms={k: float(v) for k, v in latency.items()}, tag=_decode_tag(f), session=f.value("session", ""),
    )


def _decode_stats(message: Mapping[str, Any]) -> Stats:
    f = _Fields(message, _STATS, strict=False)
    by_code = f.value("errors_by_code")
    if not all(isinstance(k, str) and _is_uint(v) for k, v in by_code.items()):
        raise ProtocolError("bad_type", "errors_by_code must map codes to counts")
    latency: dict[str, dict[str, float]] = {}
    for name, values in f.value("latency_ms").items():
        if not isinstance(values, dict) or not all(isinstance(k, str) and _is_number(v) for k, v in values.items()):
            raise ProtocolError("bad_type", f"latency_ms.{name} must map statistics to numbers")
        latency[name] = {k: int(v) if k == "n" else float(v) for k, v in values.items()}
    journal = f.value("journal")
    if journal is not None:
        j = _Fields(journal, _JOURNAL, strict=False, where="journal: ")
        journal = JournalInfo(j.value("id"), j.value("first"), j.value("last"), j.value("bytes"), j.value("segments"))
    streams: dict[str, StreamStats] = {}
    for name, values in f.value("streams").items():
        if not isinstance(values, dict):
            raise ProtocolError("bad_type", f"streams[{name[:MAX_NAME]!r}] must be a map")
        s = _Fields(values, _STREAM_STATS, strict=False, where=f"streams[{name[:MAX_NAME]!r}]: ")
        streams[name] = StreamStats(**{k: s.value(k) for k in _STREAM_STATS if k != "idle_s"},
                                    idle_s=float(s.value("idle_s")))
    return Stats(
        session=f.value("session"), mode=f.value("mode"), uptime_s=float(f.value("uptime_s")),
        received=f.value("received"), answered=f.value("answered"), dropped=f.value("dropped"),
        missing=f.value("missing"), duplicates=f.value("duplicates"), errors=f.value("errors"), errors_by_code=dict(by_code),
        queued_frames=f.value("queued_frames"), queued_results=f.value("queued_results"),
        listeners=f.value("listeners"), producers=f.value("producers"), latency_ms=latency,
        final=f.value("final", False), seq=f.value("seq"), journal=journal, streams=streams,
    )


def _opt_float(value: Any) -> float | None:
    return None if value is None else float(value)


def _kind(value: Any) -> str:
    names = {dict: "map", list: "array", str: "string", bytes: "bin", bool: "boolean", int: "integer",
             float: "float", type(None): "nil"}
    return names.get(type(value), type(value).__name__)


def _short(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) < 120 else text[:117] + "..."
