"""The wire protocol on its own: encoding, strict decoding, limits, error codes."""

from __future__ import annotations

import dataclasses
import struct
import tracemalloc

import cv2
import msgpack
import numpy as np
import pytest

from lostx.core.estimate import Candidate, Estimate
from lostx.core.frame import Frame
from lostx.replay.folder import folder_traverse
from lostx.stream import protocol as wire
from lostx.stream.errors import ProtocolError
from lostx.stream.images import header_size
from lostx.stream.protocol import Ack, ErrorMessage, Hello, Limits, Ready, Result, Stats
from lostx.stream.sockets import check_bind_endpoint, is_local_endpoint
from lostx.stream.errors import StreamError

LIMITS = Limits()


@pytest.fixture(scope="module")
def night_frame(robotcar) -> Frame:
    return dataclasses.replace(folder_traverse(robotcar / "night").frame(3), camera="front")


def valid_fields(frame: Frame) -> dict:
    return msgpack.unpackb(wire.encode_frame(frame, "raw", stream="s"))


def refused(data: bytes, limits: Limits = LIMITS) -> ProtocolError:
    with pytest.raises(ProtocolError) as info:
        message = wire.decode_request(data, limits)
        if isinstance(message, wire.FrameMessage):
            message.to_frame()
    return info.value


# -- round trips -------------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["raw", "png"])
def test_lossless_encodings_round_trip_the_exact_frame(night_frame, encoding):
    frame = dataclasses.replace(night_frame, timestamp=12.5, position=(1.0, -2.0), metadata={"k": [1, "a", None]})
    message = wire.decode_request(wire.encode_frame(frame, encoding, stream="run-1"), LIMITS)
    assert isinstance(message, wire.FrameMessage)
    got = message.to_frame()
    assert np.array_equal(got.image, frame.image)
    assert (got.id, got.timestamp, got.camera, got.position, got.name) == (3, 12.5, "front", (1.0, -2.0), frame.name)
    assert got.metadata == {"k": [1, "a", None]}
    assert message.stream == "run-1"
    assert got.image.flags.writeable  # the localizer owns its copy, not a view of the message


def test_jpeg_is_close_and_much_smaller(night_frame):
    data = wire.encode_frame(night_frame, "jpeg", quality=90)
    got = wire.decode_request(data, LIMITS).to_frame()
    assert got.image.shape == night_frame.image.shape
    assert np.abs(got.image.astype(int) - night_frame.image).mean() < 4.0
    assert len(data) < 0.2 * night_frame.image.nbytes


def test_grey_raw_images_become_three_channels():
    grey = (np.arange(32 * 48) % 251).astype(np.uint8).reshape(32, 48)
    data = msgpack.packb({"v": wire.VERSION, "type": "frame", "id": 1, "camera": "rear", "encoding": "raw",
                          "image": grey.tobytes(), "shape": [32, 48], "dtype": "uint8"})
    frame = wire.decode_request(data, LIMITS).to_frame()
    assert frame.image.shape == (32, 48, 3) and frame.camera == "rear"
    assert np.array_equal(frame.image[:, :, 2], grey)


def test_replies_round_trip():
    ready = Ready("abcd", "lossless", 4, 1000, 2000)
    assert wire.decode_reply(wire.encode_ready(ready), LIMITS) == ready
    assert wire.decode_reply(wire.encode_ack(Ack("abcd", 17)), LIMITS) == Ack("abcd", 17)
    error = ErrorMessage("bad_type", "field 'id' ...", 17, "abcd")
    assert wire.decode_reply(wire.encode_error(error), LIMITS) == error
    assert wire.decode_request(wire.encode_hello("s", "cam"), LIMITS) == Hello("s", "cam")


def test_result_carries_every_summary_field():
    estimate = Estimate(
        frame_id=7, timestamp=None, state="not_localized", match_index=12, match_name="x.png", position=(3.0, 4.0),
        confidence=0.25, score=float("inf"), single_match_index=11,
        candidates=[Candidate(12, 0.5, float("inf"), 0), Candidate(11, 0.6, 0.7, 9)],
        sequence_score=1.5, speed=0.9, window=5, warming_up=True, heading="opposite", heading_confidence=0.75,
        latency_ms={"total": 12.0},
    )
    summary = estimate.summary()
    topic, payload = b"result", wire.encode_result(summary, "s1")
    result = wire.decode_published(topic, payload, LIMITS)
    assert isinstance(result, Result)
    plain = result.to_dict()
    assert plain.pop("session") == "s1"
    # The listener's view holds exactly what Estimate.summary() holds, value for value.
    assert plain == summary
    assert set(f.name for f in dataclasses.fields(Result)) - {"session"} == set(summary)


def test_stats_round_trip():
    stats = Stats("s", "live", 1.5, 10, 8, 2, 0, 0, 1, {"bad_type": 1}, 1, 0, 2, 1,
                  {"step": {"n": 8.0, "p50": 100.0}}, final=True)
    assert wire.decode_published(b"stats", wire.encode_stats(stats), LIMITS) == stats


def test_listener_side_tolerates_new_fields_but_checks_known_ones():
    summary = Estimate(1, 0.0, "localized", 2, "a", None, 0.5, 0.1, 2, []).summary()
    data = msgpack.packb({"v": wire.VERSION, "type": "result", **summary, "added_later": [1, 2]})
    assert wire.decode_published(b"result", data, LIMITS).match_index == 2
    data = msgpack.packb({"v": wire.VERSION, "type": "result", **summary, "confidence": "high"})
    with pytest.raises(ProtocolError) as info:
        wire.decode_published(b"result", data, LIMITS)
    assert info.value.code == "bad_type"


# -- refusals ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, code",
    [
        ({"v": 1}, "bad_version"),  # the previous version is refused, not misread
        ({"v": 3}, "bad_version"),
        ({"v": "2"}, "bad_version"),
        ({"v": None}, "bad_version"),
        ({"type": "frames"}, "unknown_type"),
        ({"type": 3}, "bad_type"),
        ({"camera": "left"}, "bad_value"),
        ({"camera": 1}, "bad_type"),
        ({"encoding": "gif"}, "bad_value"),
        ({"image": "pixels"}, "bad_type"),
        ({"shape": [640, 1024, 4]}, "bad_value"),
        ({"shape": [640, -1024, 3]}, "bad_value"),
        ({"shape": "640x1024"}, "bad_type"),
        ({"shape": [640, 1000, 3]}, "bad_image"),
        ({"dtype": "float32"}, "bad_value"),
        ({"timestamp": "now"}, "bad_type"),
        ({"timestamp": float("nan")}, "bad_type"),
        ({"timestamp": True}, "bad_type"),
        ({"position": [1.0]}, "bad_value"),
        ({"position": ["a", "b"]}, "bad_value"),
        ({"name": b"bytes"}, "bad_type"),
        ({"name": "n" * 300}, "bad_value"),
        ({"metadata": [1, 2]}, "bad_type"),
        ({"metadata": {"a": {"b": {"c": {"d": {"e": 1}}}}}}, "bad_value"),
        ({"metadata": {"blob": b"\x00"}}, "bad_type"),
        ({"metadata": {"x": float("inf")}}, "bad_value"),
        ({"colour": "red"}, "unknown_field"),
    ],
)
def test_each_bad_field_is_refused_with_its_code_and_the_frame_id(night_frame, change, code):
    fields = valid_fields(night_frame)
    fields.update(change)
    error = refused(msgpack.packb(fields))
    assert error.code == code, str(error)
    assert error.frame_id == 3


@pytest.mark.parametrize("field", ["v", "type", "id", "encoding", "image", "shape", "dtype"])
def test_missing_required_fields(night_frame, field):
    fields = valid_fields(night_frame)
    del fields[field]
    error = refused(msgpack.packb(fields))
    assert error.code == "missing_field"
    assert error.frame_id == (None if field == "id" else 3)


@pytest.mark.parametrize("bad_id", [-1, 2**64 - 1, 1.5, "3", True, None])
def test_bad_ids_are_refused_and_not_echoed(night_frame, bad_id):
    fields = valid_fields(night_frame)
    fields["id"] = bad_id
    error = refused(msgpack.packb(fields))
    assert error.code == "bad_type" and error.frame_id is None


def test_malformed_messages(night_frame):
    good = wire.encode_frame(night_frame, "raw")
    assert refused(good[:1000]).code == "malformed"  # truncated
    assert refused(good + b"\x00").code == "malformed"  # trailing bytes
    assert refused(b"").code == "malformed"
    assert refused(b"\xc1").code == "malformed"  # the one byte msgpack never uses
    assert refused(msgpack.packb([1, 2, 3])).code == "not_a_map"
    assert refused(msgpack.packb({1: 2})).code == "malformed"  # strict_map_key: no integer keys
    assert refused(msgpack.packb({b"v": 1})).code == "not_a_map"  # bin keys are not field names
    assert refused(b"\x91" * 5000 + b"\xc0").code == "malformed"  # nested too deep
    assert refused(msgpack.packb({"v": msgpack.ExtType(5, b"xyz")})).code == "malformed"
    assert refused(b"\x81\xa1v\xa2\xff\xfe").code == "malformed"  # invalid UTF-8


def test_size_limit_is_checked_before_decoding(night_frame):
    data = wire.encode_frame(night_frame, "raw")
    small = Limits(max_message_bytes=len(data) - 1)
    error = refused(data, small)
    assert error.code == "too_large" and error.frame_id is None


@pytest.mark.parametrize(
    "header",
    [
        b"\xc6\xff\xff\xff\xf0",  # bin 32 of 4 GiB
        b"\xdb\xff\xff\xff\xf0",  # str 32 of 4 GiB
        b"\xdd\xff\xff\xff\xf0",  # array 32 of 4 G elements
        b"\xdf\xff\xff\xff\xf0",  # map 32 of 4 G pairs
        b"\xc9\xff\xff\xff\xf0\x01",  # ext 32 of 4 GiB
    ],
)
def test_hostile_length_fields_allocate_nothing(header):
    # A map whose "image" claims gigabytes, followed by a few real bytes.
    data = b"\x82\xa1v\x01\xa5image" + header + b"x" * 100
    tracemalloc.start()
    try:
        error = refused(data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert error.code == "malformed"
    assert peak < 1_000_000, f"decoding allocated {peak} bytes"


def test_msgpack_limits_hold_even_inside_the_size_limit():
    limits = Limits(max_array_len=10, max_map_len=10, max_str_len=100)
    assert refused(msgpack.packb({"v": 1, "metadata": {"a": list(range(11))}}), limits).code == "malformed"
    assert refused(msgpack.packb({"v": 1, "name": "x" * 101}), limits).code == "malformed"
    assert refused(msgpack.packb({f"k{i}": i for i in range(11)}), limits).code == "malformed"


# -- images ------------------------------------------------------------------------------------


def test_image_headers_match_the_decoder(night_frame):
    for encoding, ext in (("png", ".png"), ("jpeg", ".jpg")):
        data = cv2.imencode(ext, night_frame.image)[1].tobytes()
        assert header_size(data, encoding) == (640, 1024)
    progressive = cv2.imencode(".jpg", night_frame.image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    assert header_size(progressive, "jpeg") == (640, 1024)


def _png_claiming(width: int, height: int) -> bytes:
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)


def test_decompression_bombs_are_refused_before_decoding(night_frame):
    fields = valid_fields(night_frame)
    fields.update(encoding="png", image=_png_claiming(100_000, 100_000) + b"\x00" * 64)
    del fields["dtype"], fields["shape"]
    tracemalloc.start()
    try:
        error = refused(msgpack.packb(fields))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert error.code == "image_too_large" and error.frame_id == 3
    assert peak < 5_000_000
    jpeg = bytearray(cv2.imencode(".jpg", night_frame.image)[1].tobytes())
    sof = jpeg.index(b"\xff\xc0")
    jpeg[sof + 5:sof + 9] = struct.pack(">HH", 65000, 65000)  # height, width
    fields["encoding"], fields["image"] = "jpeg", bytes(jpeg)
    assert refused(msgpack.packb(fields)).code == "image_too_large"
    raw = valid_fields(night_frame)
    raw["shape"] = [5000, 5000, 3]
    assert refused(msgpack.packb(raw)).code == "image_too_large"


def test_images_that_do_not_decode(night_frame):
    fields = valid_fields(night_frame)
    del fields["dtype"], fields["shape"]
    for encoding, data in (("png", b"not a png at all, clearly"), ("jpeg", b"\xff\xd8\xff\xe0garbage"),
                           ("png", _png_claiming(64, 32) + b"\x00" * 40)):
        fields.update(encoding=encoding, image=data)
        error = refused(msgpack.packb(fields))
        assert error.code == "bad_image" and error.frame_id == 3, (encoding, error)


# -- endpoints ---------------------------------------------------------------------------------


def test_loopback_detection():
    for endpoint in ("tcp://127.0.0.1:5555", "tcp://127.4.5.6:1", "tcp://[::1]:5555", "tcp://localhost:9",
                     "ipc:///tmp/x", "inproc://a"):
        assert is_local_endpoint(endpoint), endpoint
    for endpoint in ("tcp://*:5555", "tcp://0.0.0.0:5555", "tcp://192.168.1.4:5555", "tcp://eth0:5555",
                     "tcp://example.org:1", "pgm://x"):
        assert not is_local_endpoint(endpoint), endpoint


def test_binding_a_network_address_needs_keys_or_insecure():
    check_bind_endpoint("tcp://127.0.0.1:5555", secure=False)
    check_bind_endpoint("tcp://0.0.0.0:5555", secure=True)
    check_bind_endpoint("tcp://0.0.0.0:5555", secure=False, insecure_ok=True)
    with pytest.raises(StreamError, match="refusing to bind tcp://0.0.0.0:5555"):
        check_bind_endpoint("tcp://0.0.0.0:5555", secure=False)
