"""Checking what a peer sent before anything trusts it: the envelope (schema version and type), every
field's msgpack type against the message's schema, and the values (names, shapes, image sizes,
metadata), each failure a :class:`ProtocolError` with its code.

:mod:`lostx.stream.wire` reads bytes into a msgpack map and hands it here; the message types are in
:mod:`lostx.stream.messages`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from lostx.core.errors import InputError
from lostx.core.frame import CAMERAS, HEADINGS
from lostx.core.geometry import CameraGeometry

from .errors import ProtocolError
from .images import ENCODINGS, check_pixels, header_size
from .messages import (
    MAX_METADATA_DEPTH, MAX_NAME, VERSIONS, ErrorMessage, FrameMessage, Hello, JournalInfo, Limits, Result,
    ResultCandidate, Stats, StreamStats, Tag,
)


def envelope(message: Mapping[str, Any], types: tuple[str, ...]) -> str:
    if "v" not in message:
        raise ProtocolError("missing_field", "no schema version v")
    version = message["v"]
    if not is_int(version):
        raise ProtocolError("bad_version", f"v must be an integer, got a {kind_of(version)}")
    if version not in VERSIONS:
        speaks = " and ".join(str(v) for v in VERSIONS)
        raise ProtocolError("bad_version", f"schema version {version} is not supported (this peer speaks {speaks})")
    if "type" not in message:
        raise ProtocolError("missing_field", "no message type")
    kind = message["type"]
    if not isinstance(kind, str):
        raise ProtocolError("bad_type", f"type must be a string, got a {kind_of(kind)}")
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


def is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_uint(v: Any) -> bool:
    return is_int(v) and 0 <= v < 2**63


def is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


_INT = _Kind("an integer", is_int)
_UINT = _Kind("a non-negative integer below 2**63", is_uint)
_NUMBER = _Kind("a finite number", is_number)
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
_FRAME_V3: Schema = {**_FRAME, "odometry": (_ARRAY.or_nil(), False), "geometry": (_MAP.or_nil(), False)}
FRAME_SCHEMAS: dict[int, Schema] = {2: _FRAME, 3: _FRAME_V3, 4: _FRAME_V3}
"""The frame's fields by schema version: version 3 adds ``odometry`` and ``geometry``; 4 changes replies only."""
GEOMETRY_REQUIRED = ("fx", "fy", "cx", "cy", "width", "height")
GEOMETRY_FIELDS = (*GEOMETRY_REQUIRED, "x", "y", "z", "yaw", "pitch", "roll", "body")
"""A frame's ``geometry``: the keys of a camera file (docs/datasets.md)."""
READY: Schema = {
    "v": (_INT, True), "type": (_STR, True), "session": (_STR, True), "mode": (_STR, True),
    "window": (_UINT, True), "max_message_bytes": (_UINT, True), "max_pixels": (_UINT, True),
}
READY_V4: Schema = {**READY, "journal": (_STR.or_nil(), True), "history": (_STR.or_nil(), True)}
ACK: Schema = {"v": (_INT, True), "type": (_STR, True), "session": (_STR, True), "frame_id": (_UINT, True)}
ACK_V4: Schema = {**ACK, "stream": (_STR, True)}
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
    "cue_weights": (_MAP, False), "disagrees": (_BOOL, False), "latency_ms": (_MAP, True), **_TAG,
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
                    "segments": (_UINT, True), "blocked": (_STR.or_nil(), False), "withdrawn": (_UINT, False)}
_STREAM_STATS: Schema = {
    **{name: (_UINT, True) for name in ("received", "answered", "errors", "dropped", "missing", "duplicates",
                                        "restarts", "queued")},
    "idle_s": (_NUMBER, True),
}
FETCH: Schema = {"v": (_INT, True), "type": (_STR, True), "after": (_UINT, True), "max": (_UINT, False)}
HISTORY: Schema = {
    "v": (_INT, True), "type": (_STR, True), "session": (_STR, True), "journal": (_STR, True),
    "after": (_UINT, True), "first": (_UINT, True), "last": (_UINT, True), "items": (_ARRAY, True),
}


class Fields:
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
                    "bad_type", f"{where}field {name!r} must be {check.description}, got a {kind_of(message[name])}"
                )

    def value(self, name: str, default: Any = None) -> Any:
        return self.message.get(name, default)


def _short_str(f: Fields, name: str, default: str | None = None) -> str | None:
    value = f.value(name, default)
    if value is not None and len(value) > MAX_NAME:
        raise ProtocolError("bad_value", f"{f.where}{name} is {len(value)} characters long (at most {MAX_NAME})")
    return value


def read_hello(message: Mapping[str, Any]) -> Hello:
    f = Fields(message, _HELLO)
    return Hello(stream=_short_str(f, "stream"), name=_short_str(f, "name"), version=f.value("v"))


def read_frame(message: Mapping[str, Any], limits: Limits) -> FrameMessage:
    f = Fields(message, FRAME_SCHEMAS.get(message.get("v"), _FRAME_V3))
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
        if len(position) != 2 or not all(is_number(v) for v in position):
            raise ProtocolError("bad_value", "position must be two finite numbers [x, y]")
        position = (float(position[0]), float(position[1]))
    metadata = f.value("metadata", {})
    _check_metadata(metadata)
    timestamp = f.value("timestamp")
    return FrameMessage(
        id=int(f.value("id")), camera=camera, encoding=encoding, image=image, shape=shape,
        timestamp=None if timestamp is None else float(timestamp), position=position,
        name=_short_str(f, "name", "") or "", stream=_short_str(f, "stream"), metadata=metadata,
        odometry=_odometry(f.value("odometry")), geometry=_geometry(f.value("geometry")), version=f.value("v"),
    )


def _odometry(value: Any) -> tuple[float, float, float] | None:
    if value is None:
        return None
    if len(value) != 3 or not all(is_number(v) for v in value):
        raise ProtocolError("bad_value", "odometry must be three finite numbers [x, y, yaw] (metres, radians)")
    return float(value[0]), float(value[1]), float(value[2])


def _geometry(value: Any) -> CameraGeometry | None:
    """The camera of a frame's ``geometry`` map; a key, value or camera that cannot be is ``bad_value``,
    naming the field."""
    if value is None:
        return None
    for key, item in value.items():
        if key not in GEOMETRY_FIELDS:
            raise ProtocolError("bad_value", f"geometry has no field {key[:MAX_NAME]!r}; its fields: "
                                             f"{', '.join(GEOMETRY_FIELDS)}")
        if not is_number(item):
            raise ProtocolError("bad_value", f"geometry.{key} must be a finite number, got a {kind_of(item)}")
        if key in ("width", "height") and item != int(item):
            raise ProtocolError("bad_value", f"geometry.{key} must be a whole number of pixels, got {item!r}")
    missing = [key for key in GEOMETRY_REQUIRED if key not in value]
    if missing:
        raise ProtocolError("bad_value", f"geometry lacks {', '.join(missing)} (intrinsics in pixels and the "
                                         f"image size they are for)")
    numbers = {key: int(item) if key in ("width", "height") else float(item) for key, item in value.items()}
    try:
        return CameraGeometry(**numbers)
    except InputError as exc:
        raise ProtocolError("bad_value", f"geometry.{str(exc).removeprefix('camera ')}") from None


def _shape(value: Any) -> tuple[int, ...] | None:
    if value is None:
        return None
    if len(value) not in (2, 3) or not all(is_uint(v) for v in value):
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
        raise ProtocolError("bad_type", f"metadata holds a {kind_of(value)}; only nil, bool, numbers, strings, arrays, maps")


def read_error(message: Mapping[str, Any], strict: bool = True) -> ErrorMessage:
    f = Fields(message, _ERROR, strict=strict)
    tag = read_tag(f) if "seq" in message else None
    return ErrorMessage(code=f.value("code")[:MAX_NAME], text=f.value("text"), frame_id=f.value("frame_id"),
                        session=f.value("session"), tag=tag)


def read_tag(f: Fields) -> Tag:
    for name, (_, required) in _TAG.items():
        if required and name not in f.message:
            raise ProtocolError("missing_field", f"required field {name!r} is missing")
    return Tag(f.value("stream"), f.value("seq"), f.value("stream_seq"), f.value("journal"))


def read_result(message: Mapping[str, Any]) -> Result:
    f = Fields(message, _RESULT, strict=False)
    if f.value("state") not in ("localized", "not_localized"):
        raise ProtocolError("bad_value", f"state {f.value('state')!r} is not localized or not_localized")
    if f.value("heading") not in HEADINGS:
        raise ProtocolError("bad_value", f"heading {f.value('heading')!r} is not one of {', '.join(HEADINGS)}")
    candidates = []
    for i, item in enumerate(f.value("candidates")):
        if not isinstance(item, dict):
            raise ProtocolError("bad_type", f"candidates[{i}] must be a map")
        c = Fields(item, _CANDIDATE, strict=False, where=f"candidates[{i}]: ")
        candidates.append(ResultCandidate(c.value("index"), _opt_float(c.value("distance")),
                                          _opt_float(c.value("score")), c.value("correspondences")))
    latency = f.value("latency_ms")
    if not all(isinstance(k, str) and is_number(v) for k, v in latency.items()):
        raise ProtocolError("bad_type", "latency_ms must map stage names to numbers")
    cue_weights = f.value("cue_weights", {})
    if not all(isinstance(k, str) and is_number(v) for k, v in cue_weights.items()):
        raise ProtocolError("bad_type", "cue_weights must map cue names to numbers")
    position = f.value("position")
    if position is not None:
        if len(position) != 2 or not all(is_number(v) for v in position):
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
        cue_weights={k: float(v) for k, v in cue_weights.items()}, disagrees=bool(f.value("disagrees", False)),
        latency_ms={k: float(v) for k, v in latency.items()}, tag=read_tag(f), session=f.value("session", ""),
    )


def read_stats(message: Mapping[str, Any]) -> Stats:
    f = Fields(message, _STATS, strict=False)
    by_code = f.value("errors_by_code")
    if not all(isinstance(k, str) and is_uint(v) for k, v in by_code.items()):
        raise ProtocolError("bad_type", "errors_by_code must map codes to counts")
    latency: dict[str, dict[str, float]] = {}
    for name, values in f.value("latency_ms").items():
        if not isinstance(values, dict) or not all(isinstance(k, str) and is_number(v) for k, v in values.items()):
            raise ProtocolError("bad_type", f"latency_ms.{name} must map statistics to numbers")
        latency[name] = {k: int(v) if k == "n" else float(v) for k, v in values.items()}
    journal = f.value("journal")
    if journal is not None:
        j = Fields(journal, _JOURNAL, strict=False, where="journal: ")
        journal = JournalInfo(j.value("id"), j.value("first"), j.value("last"), j.value("bytes"), j.value("segments"),
                              j.value("blocked"), j.value("withdrawn", 0))
    streams: dict[str, StreamStats] = {}
    for name, values in f.value("streams").items():
        if not isinstance(values, dict):
            raise ProtocolError("bad_type", f"streams[{name[:MAX_NAME]!r}] must be a map")
        s = Fields(values, _STREAM_STATS, strict=False, where=f"streams[{name[:MAX_NAME]!r}]: ")
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


def kind_of(value: Any) -> str:
    names = {dict: "map", list: "array", str: "string", bytes: "bin", bool: "boolean", int: "integer",
             float: "float", type(None): "nil"}
    return names.get(type(value), type(value).__name__)


def short(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) < 120 else text[:117] + "..."
