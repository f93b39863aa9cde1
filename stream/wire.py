"""The wire format: messages to msgpack bytes and back (docs/protocol.md is the spec).

Three channels, all bound by the service:

* frames (ROUTER at the service, DEALER at each producer): ``hello`` and ``frame``
  in; ``ready``, ``ack`` and ``error`` back to the producer that sent them.
* results (XPUB at the service, SUB at each listener): two-part messages
  ``[topic, payload]`` with topic ``result``, ``error`` or ``stats``.
* history (ROUTER at the service, DEALER at a listener; with a journal): ``fetch``
  in, ``history`` (journaled answers) or ``error`` back.

Every payload is one msgpack map with ``v`` (schema version: lostx's producers send 4, everything else
lostx sends says 3 as it is unchanged; it reads 2, 3 and 4) and ``type``.
Decoding never trusts the peer: the size is checked before msgpack sees the
bytes, msgpack's own length limits stop a hostile length field from
allocating memory, and every field is checked (:mod:`lostx.stream.validate`);
every failure raises a :class:`ProtocolError` carrying an error code and,
where it could be read, the frame id.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any, Mapping

import msgpack
import numpy as np

from lostx.core.frame import Frame

from .errors import ProtocolError
from .images import encode_image
from .messages import (
    MAX_FETCH, STEADY_VERSION, TOPICS, VERSION, Ack, Answer, ErrorMessage, Fetch, FrameMessage, Hello, History, Limits, Published,
    Ready, Reply, Stats, Tag,
)
from .validate import (
    ACK, ACK_V4, FETCH, HISTORY, READY, READY_V4, Fields, envelope, is_uint, kind_of, read_error, read_frame, read_hello, read_result,
    read_stats, short,
)


def _pack(message: dict[str, Any], version: int = STEADY_VERSION) -> bytes:
    return msgpack.packb({"v": version, **message}, use_bin_type=True)


def reply_version(request_version: int) -> int:
    """The version of the service's reply to a request in ``request_version``: a producer that speaks
    version 4 gets version 4, an older one version 3 (what it has always read)."""
    return VERSION if request_version >= VERSION else STEADY_VERSION


def encode_hello(stream: str | None = None, name: str | None = None) -> bytes:
    message: dict[str, Any] = {"type": "hello"}
    if stream is not None:
        message["stream"] = stream
    if name is not None:
        message["name"] = name
    return _pack(message, VERSION)


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
    if frame.odometry is not None:
        message["odometry"] = [float(v) for v in frame.odometry]
    if frame.geometry is not None:
        message["geometry"] = {key: value if isinstance(value, int) else float(value)
                               for key, value in frame.geometry.to_dict().items()}
    return _pack(message, VERSION)


def encode_ready(ready: Ready, version: int = VERSION) -> bytes:
    """``ready`` for a producer that spoke ``version``: its ``journal`` and ``history`` from version 4 on."""
    message = {"type": "ready", **asdict(ready)}
    if version < VERSION:
        del message["journal"], message["history"]
    return _pack(message, reply_version(version))


def encode_ack(ack: Ack, version: int = VERSION) -> bytes:
    """``ack`` for a producer that spoke ``version``: with the frame's ``stream`` from version 4 on."""
    message: dict[str, Any] = {"type": "ack", "session": ack.session, "frame_id": ack.frame_id}
    if version >= VERSION:
        message["stream"] = ack.stream or ""
    return _pack(message, reply_version(version))


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
        raise ProtocolError("malformed", f"not a valid msgpack message ({short(exc)})") from None
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise ProtocolError("not_a_map", f"message is a msgpack {kind_of(value)}, not a map with string keys")
    return value


def read_frame_id(message: Mapping[str, Any]) -> int | None:
    """The frame id of a message where one can be read (an ``id`` that is a valid id), for error
    replies; read whatever else is wrong with the message, so a sender learns which frame failed."""
    value = message.get("id")
    return int(value) if is_uint(value) else None


def decode_request(data: bytes | memoryview, limits: Limits) -> Hello | FrameMessage:
    """A frames-channel message from a producer."""
    message = unpack(data, limits)
    frame_id = read_frame_id(message)
    try:
        kind = envelope(message, ("hello", "frame"))
        if kind == "hello":
            return read_hello(message)
        return read_frame(message, limits)
    except ProtocolError as exc:
        exc.frame_id = frame_id
        raise


def decode_reply(data: bytes, limits: Limits) -> Reply:
    """A frames-channel message from the service, as a producer reads it."""
    message = unpack(data, limits)
    kind = envelope(message, ("ready", "ack", "error"))
    # From version 4 on a producer ignores reply fields it does not know: the service may add some.
    v4 = message["v"] >= VERSION
    if kind == "ready":
        f = Fields(message, READY_V4 if v4 else READY, strict=not v4)
        mode = f.value("mode")
        if mode not in ("live", "lossless"):
            raise ProtocolError("bad_value", f"mode {mode!r} is not live or lossless")
        window = f.value("window")
        if window < 1 and mode == "lossless":
            raise ProtocolError("bad_value", f"window {window} must be at least 1")
        return Ready(f.value("session"), mode, window, f.value("max_message_bytes"), f.value("max_pixels"),
                     f.value("journal"), f.value("history"))
    if kind == "ack":
        f = Fields(message, ACK_V4 if v4 else ACK, strict=not v4)
        return Ack(f.value("session"), f.value("frame_id"), f.value("stream"))
    return read_error(message)


def decode_published(topic: bytes, data: bytes, limits: Limits) -> Published:
    """A results-channel message (its two parts) as a listener reads it.

    Listeners tolerate fields they do not know (a newer service may add some within the
    same version); every field they do know is type-checked.
    """
    if topic not in TOPICS:
        raise ProtocolError("unknown_type", f"unknown topic {topic[:32]!r}")
    message = unpack(data, limits)
    kind = envelope(message, (topic.decode(),))
    if kind == "result":
        return read_result(message)
    if kind == "error":
        return read_error(message, strict=False)
    return read_stats(message)


def decode_answer(data: bytes, limits: Limits) -> Answer:
    """One journaled answer (an item of a ``history`` reply): a result or a frame's error."""
    message = unpack(data, limits)
    if envelope(message, ("result", "error")) == "result":
        return read_result(message)
    error = read_error(message, strict=False)
    if error.tag is None:
        raise ProtocolError("missing_field", "a journaled error needs its stream, seq and stream_seq")
    return error


def decode_fetch(data: bytes | memoryview, limits: Limits) -> Fetch:
    """A history-channel request, as the service reads it."""
    message = unpack(data, limits)
    envelope(message, ("fetch",))
    f = Fields(message, FETCH)
    count = f.value("max", 256)
    if not 1 <= count <= MAX_FETCH:
        raise ProtocolError("bad_value", f"max is {count}; ask for 1 to {MAX_FETCH} answers")
    return Fetch(f.value("after"), count)


def decode_history(data: bytes, limits: Limits) -> History | ErrorMessage:
    """A history-channel reply, as a listener reads it."""
    message = unpack(data, limits)
    if envelope(message, ("history", "error")) == "error":
        return read_error(message, strict=False)
    f = Fields(message, HISTORY, strict=False)
    items = f.value("items")
    if not all(isinstance(item, bytes) for item in items):
        raise ProtocolError("bad_type", "history items must be bin")
    return History(f.value("session"), f.value("journal"), f.value("after"), f.value("first"), f.value("last"),
                   tuple(items))
