"""The wire protocol on its own: encoding, strict decoding, limits, error codes."""

from __future__ import annotations

import dataclasses
import json
import re
import struct
import tracemalloc
from pathlib import Path

import cv2
import msgpack
import numpy as np
import pytest

from lostx.core.decide.estimate import Candidate, Estimate
from lostx.core.frame import Frame
from lostx.core.geometry import CameraGeometry
from lostx.replay.folder import folder_traverse
from lostx.stream import messages, wire
from lostx.stream.errors import ProtocolError
from lostx.stream.images import header_size
from lostx.stream.messages import (
    Ack, ErrorMessage, Fetch, Hello, History, JournalInfo, Limits, Ready, Result, Stats, StreamStats, Tag,
)
from lostx.stream.sockets import check_bind_endpoint, history_endpoint, is_local_endpoint
from lostx.stream.errors import StreamError

LIMITS = Limits()
GEOMETRY = {"fx": 800.0, "fy": 800.0, "cx": 799.5, "cy": 449.5, "width": 1600, "height": 900, "x": -0.5, "y": 0.0,
            "z": 1.6, "yaw": 180.0, "pitch": 2.0, "roll": -0.5, "body": 0.09}


@pytest.fixture(scope="module")
def night_frame(robotcar) -> Frame:
    return dataclasses.replace(folder_traverse(robotcar / "night").frame(3), camera="front")


def valid_fields(frame: Frame) -> dict:
    return msgpack.unpackb(wire.encode_frame(frame, "raw", stream="s"))


def refused(data: bytes, limits: Limits = LIMITS) -> ProtocolError:
    with pytest.raises(ProtocolError) as info:
        message = wire.decode_request(data, limits)
        if isinstance(message, messages.FrameMessage):
            message.to_frame()
    return info.value


# -- round trips -------------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["raw", "png"])
def test_lossless_encodings_round_trip_the_exact_frame(night_frame, encoding):
    frame = dataclasses.replace(night_frame, timestamp=12.5, position=(1.0, -2.0), metadata={"k": [1, "a", None]})
    message = wire.decode_request(wire.encode_frame(frame, encoding, stream="run-1"), LIMITS)
    assert isinstance(message, messages.FrameMessage)
    got = message.to_frame()
    assert np.array_equal(got.image, frame.image)
    assert (got.id, got.timestamp, got.camera, got.position, got.name) == (3, 12.5, "front", (1.0, -2.0), frame.name)
    assert got.metadata == {"k": [1, "a", None]}
    assert message.stream == "run-1"
    assert got.image.flags.writeable  # the localizer owns its copy, not a view of the message


def test_version_3_frames_carry_odometry_and_geometry(night_frame):
    camera = CameraGeometry(**GEOMETRY, source="calibration.toml")
    frame = dataclasses.replace(night_frame, odometry=(12.5, -3.0, 0.25), geometry=camera)
    data = wire.encode_frame(frame, "jpeg", stream="run-1")
    fields = msgpack.unpackb(data)
    assert fields["v"] == messages.VERSION == 4
    assert fields["odometry"] == [12.5, -3.0, 0.25] and fields["geometry"] == GEOMETRY
    message = wire.decode_request(data, LIMITS)
    assert message.odometry == (12.5, -3.0, 0.25) and message.geometry.to_dict() == GEOMETRY
    got = message.to_frame()
    assert got.odometry == (12.5, -3.0, 0.25)
    assert isinstance(got.geometry, CameraGeometry) and got.geometry.to_dict() == camera.to_dict()
    assert got.geometry.horizon_row() == pytest.approx(camera.horizon_row())
    # Only the required keys: the others take a camera file's defaults. Integers are fine where floats are due.
    fields["geometry"] = {"fx": 800, "fy": 800, "cx": 800, "cy": 450, "width": 1600, "height": 900}
    got = wire.decode_request(msgpack.packb(fields), LIMITS).to_frame()
    assert (got.geometry.z, got.geometry.yaw, got.geometry.body) == (1.5, 0.0, 0.0)
    # Nil is as good as leaving them out; a frame without them sends neither.
    fields.update(odometry=None, geometry=None)
    got = wire.decode_request(msgpack.packb(fields), LIMITS).to_frame()
    assert got.odometry is None and got.geometry is None
    assert not {"odometry", "geometry"} & set(msgpack.unpackb(wire.encode_frame(night_frame, "raw")))


def test_version_2_frames_are_still_read(night_frame):
    fields = valid_fields(night_frame)
    fields["v"] = 2
    got = wire.decode_request(msgpack.packb(fields), LIMITS).to_frame()
    assert np.array_equal(got.image, night_frame.image) and got.odometry is None and got.geometry is None
    hello = msgpack.packb({"v": 2, "type": "hello", "stream": "old"})
    assert wire.decode_request(hello, LIMITS) == Hello("old", None, version=2)
    # And the other way round: what a version-2 service sends a version-3 producer and listener.
    assert wire.decode_reply(msgpack.packb({"v": 2, "type": "ack", "session": "s", "frame_id": 3}), LIMITS) == \
        Ack("s", 3)


def test_a_bad_geometry_is_refused_naming_its_field(night_frame):
    fields = valid_fields(night_frame)
    for geometry, text in (({**GEOMETRY, "fx": -1.0}, "geometry.fx must be a positive number, got -1.0"),
                           ({**GEOMETRY, "zoom": 2}, "geometry has no field 'zoom'"),
                           ({**GEOMETRY, "yaw": "back"}, "geometry.yaw must be a finite number, got a string"),
                           ({"fx": 1.0, "fy": 1.0}, "geometry lacks cx, cy, width, height"),
                           ({**GEOMETRY, "pitch": 70.0}, "geometry.pitch 70 and roll -0.5 degrees")):
        fields["geometry"] = geometry
        error = refused(msgpack.packb(fields))
        assert (error.code, error.frame_id) == ("bad_value", 3)
        assert error.text.startswith(text), error.text


def test_jpeg_is_close_and_much_smaller(night_frame):
    data = wire.encode_frame(night_frame, "jpeg", quality=90)
    got = wire.decode_request(data, LIMITS).to_frame()
    assert got.image.shape == night_frame.image.shape
    assert np.abs(got.image.astype(int) - night_frame.image).mean() < 4.0
    assert len(data) < 0.2 * night_frame.image.nbytes


def test_grey_raw_images_become_three_channels():
    grey = (np.arange(32 * 48) % 251).astype(np.uint8).reshape(32, 48)
    data = msgpack.packb({"v": messages.VERSION, "type": "frame", "id": 1, "camera": "rear", "encoding": "raw",
                          "image": grey.tobytes(), "shape": [32, 48], "dtype": "uint8"})
    frame = wire.decode_request(data, LIMITS).to_frame()
    assert frame.image.shape == (32, 48, 3) and frame.camera == "rear"
    assert np.array_equal(frame.image[:, :, 2], grey)


def test_replies_round_trip():
    ready = Ready("abcd", "lossless", 4, 1000, 2000)
    assert wire.decode_reply(wire.encode_ready(ready), LIMITS) == ready
    assert wire.decode_reply(wire.encode_ack(Ack("abcd", 17, "cam")), LIMITS) == Ack("abcd", 17, "cam")
    error = ErrorMessage("bad_type", "field 'id' ...", 17, "abcd")
    assert wire.decode_reply(wire.encode_error(error), LIMITS) == error
    assert wire.decode_request(wire.encode_hello("s", "cam"), LIMITS) == Hello("s", "cam")


def test_replies_speak_the_producers_version_and_version_4_tells_journal_history_and_stream():
    ready = Ready("abcd", "lossless", 4, 1000, 2000, "j-1", "tcp://127.0.0.1:5557")
    common = {"type": "ready", "session": "abcd", "mode": "lossless", "window": 4, "max_message_bytes": 1000,
              "max_pixels": 2000}
    assert msgpack.unpackb(wire.encode_ready(ready, 4)) == \
        {"v": 4, **common, "journal": "j-1", "history": "tcp://127.0.0.1:5557"}
    assert wire.decode_reply(wire.encode_ready(ready, 4), LIMITS) == ready
    ack = Ack("abcd", 7, "cam-1")
    assert msgpack.unpackb(wire.encode_ack(ack, 4)) == {"v": 4, "type": "ack", "session": "abcd", "frame_id": 7,
                                                        "stream": "cam-1"}
    assert wire.decode_reply(wire.encode_ack(ack, 4), LIMITS) == ack
    # A producer that spoke version 2 or 3 gets what version 3 sent, field for field (it refuses unknown ones).
    for old in (2, 3):
        assert msgpack.unpackb(wire.encode_ready(ready, old)) == {"v": 3, **common}
        assert msgpack.unpackb(wire.encode_ack(ack, old)) == {"v": 3, "type": "ack", "session": "abcd", "frame_id": 7}
        assert wire.decode_reply(wire.encode_ack(ack, old), LIMITS) == Ack("abcd", 7)
    # From version 4 on a producer ignores reply fields it does not know, and checks those it does.
    later = msgpack.packb({**msgpack.unpackb(wire.encode_ack(ack, 4)), "added_later": [1]})
    assert wire.decode_reply(later, LIMITS) == ack
    with pytest.raises(ProtocolError) as info:
        wire.decode_reply(msgpack.packb({"v": 4, "type": "ack", "session": "abcd", "frame_id": 7}), LIMITS)
    assert info.value.code == "missing_field"
    # Everything version 4 left as it was still says 3, so listeners written for version 3 read it.
    assert msgpack.unpackb(wire.encode_error(ErrorMessage("bad_type", "x", 7, "abcd")))["v"] == 3
    assert msgpack.unpackb(wire.encode_fetch(Fetch(120, 256)))["v"] == 3


def test_result_carries_every_summary_field():
    estimate = Estimate(
        frame_id=7, timestamp=None, state="not_localized", match_index=12, match_name="x.png", position=(3.0, 4.0),
        confidence=0.25, score=float("inf"), single_match_index=11,
        candidates=[Candidate(12, 0.5, float("inf"), 0), Candidate(11, 0.6, 0.7, 9)],
        sequence_score=1.5, speed=0.9, window=5, warming_up=True, heading="opposite", heading_confidence=0.75,
        latency_ms={"total": 12.0},
    )
    summary = estimate.summary()
    tag = Tag("robot-2", 41, 7, "0123abcd")
    topic, payload = b"result", wire.encode_result(summary, "s1", tag)
    result = wire.decode_published(topic, payload, LIMITS)
    assert isinstance(result, Result)
    assert result.tag == tag
    plain = result.to_dict()
    assert plain.pop("session") == "s1"
    assert {k: plain.pop(k) for k in ("stream", "seq", "stream_seq", "journal")} == \
        {"stream": "robot-2", "seq": 41, "stream_seq": 7, "journal": "0123abcd"}
    # The listener's view holds exactly what Estimate.summary() holds, value for value.
    assert plain == summary
    assert set(f.name for f in dataclasses.fields(Result)) - {"session", "tag"} == set(summary)
    # Without a journal the field is left out, not sent empty.
    bare = wire.decode_published(b"result", wire.encode_result(summary, "s1", Tag("", 1, 1)), LIMITS)
    assert bare.tag == Tag("", 1, 1, None) and "journal" not in msgpack.unpackb(wire.encode_result(summary, "s",
                                                                                                  Tag("", 1, 1)))


def test_stats_round_trip():
    streams = {"a": StreamStats(10, 8, 1, 1, 0, 0, 0, 1, 0.25), "b": StreamStats(3, 3, 0, 0, 2, 1, 1, 0, 12.5)}
    stats = Stats("s", "live", 1.5, 10, 8, 2, 0, 0, 1, {"bad_type": 1}, 1, 0, 2, 1,
                  {"step": {"n": 8, "p50": 100.0}}, final=True, seq=11,
                  journal=JournalInfo("j", 1, 11, 9000, 1, "No space left on device", 3), streams=streams)
    got = wire.decode_published(b"stats", wire.encode_stats(stats), LIMITS)
    assert got == stats
    # A count is sent as an integer, not a float.
    assert msgpack.unpackb(wire.encode_stats(stats))["latency_ms"]["step"]["n"] == 8
    assert type(got.latency_ms["step"]["n"]) is int
    no_journal = dataclasses.replace(stats, journal=None, streams={})
    assert wire.decode_published(b"stats", wire.encode_stats(no_journal), LIMITS) == no_journal
    # A journal map of a service that says nothing of a blocked journal (an older one) is one that is written.
    older = msgpack.unpackb(wire.encode_stats(stats))
    del older["journal"]["blocked"], older["journal"]["withdrawn"]
    got = wire.decode_published(b"stats", msgpack.packb(older), LIMITS)
    assert got.journal == JournalInfo("j", 1, 11, 9000, 1, None, 0)


def test_errors_that_answer_frames_carry_their_place_and_refusals_do_not():
    answer = ErrorMessage("bad_timestamp", "timestamp 1e+18 is ...", 9, "s", Tag("cam", 12, 4, "j1"))
    refusal = ErrorMessage("malformed", "not a valid msgpack message", None, "s")
    for error in (answer, refusal):
        payload = wire.encode_error(error)
        assert wire.decode_published(b"error", payload, LIMITS) == error
        assert wire.decode_reply(payload, LIMITS) == error  # the producer reads the same message
    assert "seq" not in msgpack.unpackb(wire.encode_error(refusal))
    assert wire.decode_answer(wire.encode_error(answer), LIMITS) == answer
    with pytest.raises(ProtocolError, match="journaled error needs"):
        wire.decode_answer(wire.encode_error(refusal), LIMITS)


def test_history_requests_and_replies_round_trip_and_bad_ones_are_refused():
    fetch = Fetch(after=120, max=50)
    assert wire.decode_fetch(wire.encode_fetch(fetch), LIMITS) == fetch
    summary = Estimate(1, 0.0, "localized", 2, "a", None, 0.5, 0.1, 2, []).summary()
    items = (wire.encode_result(summary, "s", Tag("x", 121, 1, "j")),
             wire.encode_error(ErrorMessage("bad_image", "no", 2, "s", Tag("x", 122, 2, "j"))))
    history = History("s", "j", 120, 100, 122, items)
    got = wire.decode_history(wire.encode_history(history), LIMITS)
    assert got == history
    assert [wire.decode_answer(item, LIMITS).tag.seq for item in got.items] == [121, 122]
    for message, code in (({"v": 2, "type": "fetch"}, "missing_field"),
                          ({"v": 2, "type": "fetch", "after": -1}, "bad_type"),
                          ({"v": 2, "type": "fetch", "after": 1, "max": 0}, "bad_value"),
                          ({"v": 2, "type": "fetch", "after": 1, "max": messages.MAX_FETCH + 1}, "bad_value"),
                          ({"v": 2, "type": "fetch", "after": 1, "from": 3}, "unknown_field"),
                          ({"v": 1, "type": "fetch", "after": 1}, "bad_version"),
                          ({"v": 2, "type": "frame", "after": 1}, "unknown_type")):
        with pytest.raises(ProtocolError) as info:
            wire.decode_fetch(msgpack.packb(message), LIMITS)
        assert info.value.code == code, message


def test_the_history_endpoint_goes_with_the_results_endpoint():
    assert history_endpoint("tcp://127.0.0.1:5556") == "tcp://127.0.0.1:5557"
    assert history_endpoint("tcp://*:0") == "tcp://*:0"
    assert history_endpoint("ipc:///run/lostx/results") == "ipc:///run/lostx/results-history"
    with pytest.raises(StreamError, match="cannot derive a history endpoint"):
        history_endpoint("tcp://host")


def test_listener_side_tolerates_new_fields_but_checks_known_ones():
    summary = {**Estimate(1, 0.0, "localized", 2, "a", None, 0.5, 0.1, 2, []).summary(),
               "stream": "", "seq": 1, "stream_seq": 1}
    data = msgpack.packb({"v": messages.VERSION, "type": "result", **summary, "added_later": [1, 2]})
    assert wire.decode_published(b"result", data, LIMITS).match_index == 2
    data = msgpack.packb({"v": messages.VERSION, "type": "result", **summary, "confidence": "high"})
    with pytest.raises(ProtocolError) as info:
        wire.decode_published(b"result", data, LIMITS)
    assert info.value.code == "bad_type"


# -- refusals ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, code",
    [
        ({"v": 1}, "bad_version"),  # the previous version is refused, not misread
        ({"v": 5}, "bad_version"),
        ({"v": 0}, "bad_version"),
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
        ({"odometry": [1.0, 2.0]}, "bad_value"),
        ({"odometry": [1.0, 2.0, float("nan")]}, "bad_value"),
        ({"odometry": [1.0, "2", 3.0]}, "bad_value"),
        ({"odometry": "here"}, "bad_type"),
        ({"odometry": {"x": 1}}, "bad_type"),
        ({"geometry": [1, 2]}, "bad_type"),
        ({"geometry": "camera.toml"}, "bad_type"),
        ({"geometry": {**GEOMETRY, "fx": -800.0}}, "bad_value"),
        ({"geometry": {**GEOMETRY, "fx": "800"}}, "bad_value"),
        ({"geometry": {**GEOMETRY, "z": float("inf")}}, "bad_value"),
        ({"geometry": {**GEOMETRY, "width": 1600.5}}, "bad_value"),
        ({"geometry": {**GEOMETRY, "pitch": 75.0}}, "bad_value"),
        ({"geometry": {**GEOMETRY, "body": 0.95}}, "bad_value"),
        ({"geometry": {**GEOMETRY, "zoom": 2.0}}, "bad_value"),
        ({"geometry": {k: v for k, v in GEOMETRY.items() if k != "cy"}}, "bad_value"),
        ({"v": 2, "odometry": [1.0, 2.0, 0.5]}, "unknown_field"),  # version 2 never had them
        ({"v": 2, "geometry": GEOMETRY}, "unknown_field"),
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


def test_images_that_do_not_decode(night_frame, capfd):
    fields = valid_fields(night_frame)
    del fields["dtype"], fields["shape"]
    png = bytearray(cv2.imencode(".png", night_frame.image)[1].tobytes())
    png[5000] ^= 0xFF  # damaged image data: libpng, as OpenCV calls it, prints a line for this
    jpeg = cv2.imencode(".jpg", night_frame.image)[1].tobytes()
    capfd.readouterr()
    for encoding, data in (("png", b"not a png at all, clearly"), ("jpeg", b"\xff\xd8\xff\xe0garbage"),
                           ("png", _png_claiming(64, 32) + b"\x00" * 40), ("png", bytes(png)),
                           ("png", bytes(png[:len(png) // 2])), ("jpeg", jpeg[:len(jpeg) // 2])):
        fields.update(encoding=encoding, image=data)
        error = refused(msgpack.packb(fields))
        assert error.code == "bad_image" and error.frame_id == 3, (encoding, error)
        assert error.text.startswith("image: "), error.text
    # Nothing reaches the process's stderr: a peer sending broken images cannot flood the service's log.
    assert capfd.readouterr().err == ""


def test_compressed_images_decode_to_the_pixels_opencv_gives(night_frame):
    bgr = np.ascontiguousarray(night_frame.image[:, :, ::-1])
    for ext, encoding in ((".png", "png"), (".jpg", "jpeg")):
        data = cv2.imencode(ext, bgr)[1].tobytes()
        fields = valid_fields(night_frame)
        fields.update(encoding=encoding, image=data)
        del fields["dtype"]
        got = wire.decode_request(msgpack.packb(fields), LIMITS).to_frame().image
        assert np.array_equal(got, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1])
    grey = cv2.imencode(".png", night_frame.image[:, :, 1])[1].tobytes()
    fields.update(encoding="png", image=grey)
    got = wire.decode_request(msgpack.packb(fields), LIMITS).to_frame().image
    assert got.shape == (640, 1024, 3) and np.array_equal(got[:, :, 0], night_frame.image[:, :, 1])


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


def test_the_bytes_in_the_protocol_doc_are_what_lostx_reads():
    """docs/protocol.md shows messages as JSON-like text and msgpack hex: each pair must agree."""
    import re
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text()
    blocks = re.findall(r"```\n(\{.*?\})\n((?:[0-9a-f]{2}[ \n])+)```", doc, re.S)
    assert len(blocks) >= 6
    for text, hex_bytes in blocks:
        message = msgpack.unpackb(bytes.fromhex(hex_bytes.replace("\n", " ")))
        assert message["v"] in messages.VERSIONS
        if "<" not in text:  # no placeholder for bytes: the text is the message, value for value
            assert json.loads(text) == message, text
        keys = set(message) | {k for value in message.values() if isinstance(value, dict) for k in value}
        for key in re.findall(r'"(\w+)":', text):
            assert key in keys, (key, text)
        decoded = {"hello": wire.decode_request, "frame": wire.decode_request, "ack": wire.decode_reply,
                   "ready": wire.decode_reply, "fetch": wire.decode_fetch}[message["type"]](bytes.fromhex(hex_bytes.replace("\n", " ")), LIMITS)
        assert decoded is not None


# -- the document ----------------------------------------------------------------------------------

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"


def _section(doc: str, heading: str) -> str:
    """The text of the section whose heading line starts with ``heading``, up to the next heading."""
    match = re.search(rf"^#+ {re.escape(heading)}.*?$(.*?)(?=^#)", doc, re.S | re.M)
    assert match, heading
    return match.group(1)


def _row(section: str, name: str) -> str:
    return next(line for line in section.splitlines() if line.startswith(f"| `{name}`"))


def _versions(row: str) -> list[int]:
    """The versions a table's ``v`` row names, in its order: the one lostx sends first."""
    return [int(v) for v in re.findall(r"`(\d)`", row)]


def test_the_protocol_doc_gives_each_message_the_versions_lostx_sends_and_reads():
    """Each message's ``v`` row names the version lostx sends it in first, then the others a lostx peer sends or
    reads it in; the title and the versioning section name the newest and those read."""
    doc = DOC.read_text()
    assert doc.startswith(f"# lostx wire protocol (schema version {messages.VERSION})\n")
    versioning = _section(doc, "12. Versioning")
    assert f"`v` is the schema version, `{messages.VERSION}` here. lostx reads versions " \
           f"{', '.join(map(str, messages.VERSIONS[:-1]))} and {messages.VERSIONS[-1]};" in " ".join(versioning.split())

    def sent(data: bytes) -> int:
        return msgpack.unpackb(data)["v"]

    def read(decode, message: dict) -> set[int]:
        ok = set()
        for version in range(1, messages.VERSION + 2):
            try:
                decode(msgpack.packb({**message, "v": version}), LIMITS)
                ok.add(version)
            except ProtocolError:
                pass
        return ok

    hello = msgpack.unpackb(wire.encode_hello("cam"))
    frame = msgpack.unpackb(wire.encode_frame(Frame(1, np.zeros((2, 2, 3), np.uint8)), stream="cam"))
    ready = Ready("s", "lossless", 4, 1 << 24, 1 << 24, "j", "tcp://127.0.0.1:5557")
    replies = {version: (sent(wire.encode_ready(ready, version)), sent(wire.encode_ack(Ack("s", 1, "cam"), version)))
               for version in messages.VERSIONS}
    fetch = msgpack.unpackb(wire.encode_fetch(Fetch(0, 10)))
    stats = Stats("s", "live", 1.0, 0, 0, 0, 0, 0, 0, {}, 0, 0, 0, 0, {})
    expected = {
        "3.1 `hello`": (hello["v"], read(wire.decode_request, hello)),
        "3.2 `frame`": (frame["v"], read(wire.decode_request, frame)),
        "3.3 `ready`": (replies[messages.VERSION][0], {r[0] for r in replies.values()}),
        "3.4 `ack`": (replies[messages.VERSION][1], {r[1] for r in replies.values()}),
        "3.5 `error`": (sent(wire.encode_error(ErrorMessage("bad_value", "x"))), None),
        "4.1 `result`": (sent(wire.encode_result({}, "s", Tag("cam", 1, 1))), None),
        "4.3 `stats`": (sent(wire.encode_stats(stats)), None),
        "7.2 `fetch`": (fetch["v"], read(wire.decode_fetch, fetch)),
        "7.3 `history`": (sent(wire.encode_history(History("s", "j", 0, 0, 0, ()))), None),
    }
    # What may change within a version is said of the newest.
    assert set(re.findall(r"within\s+(?:schema\s+)?version\s+(\d)", doc, re.I)) == {str(messages.VERSION)}
    for heading, (first, others) in expected.items():
        named = _versions(_row(_section(doc, heading), "v"))
        assert named[0] == first, (heading, named)
        assert set(named) == (others if others is not None else {first}), (heading, named)


def test_the_protocol_doc_lists_the_fields_and_codes_lostx_sends():
    doc = DOC.read_text()
    stats = Stats("s", "live", 1.0, 0, 0, 0, 0, 0, 0, {}, 0, 0, 0, 0, {}, journal=JournalInfo("j", 0, 0, 0, 0))
    sent = msgpack.unpackb(wire.encode_stats(stats))
    table = re.findall(r"^\| ((?:`\w+`(?:, )?)+) \|", _section(doc, "4.3 `stats`"), re.M)
    assert {name for cell in table for name in re.findall(r"`(\w+)`", cell)} == set(sent)
    journal = re.search(r"`\{(.*?)\}`", _row(_section(doc, "4.3 `stats`"), "journal")).group(1)
    assert [field.split(":")[0] for field in journal.split(", ")] == list(sent["journal"])
    ready = re.findall(r"^\| ((?:`\w+`(?:, )?)+) \|", _section(doc, "3.3 `ready`"), re.M)
    assert {name for cell in ready for name in re.findall(r"`(\w+)`", cell)} == \
        set(msgpack.unpackb(wire.encode_ready(Ready("s", "live", 0, 1, 1))))
    codes = re.findall(r"^\| `(\w+)` \|", _section(doc, "9. Error codes"), re.M)
    assert codes == list(messages.ERROR_CODES)


def test_the_protocol_docs_examples_are_what_lostx_sends():
    """Every example of a message lostx sends is, field for field, what lostx's encoder makes of its content, and
    every frame example reads as the frame lostx would send for it."""
    blocks = re.findall(r"```\n(\{.*?\})\n((?:[0-9a-f]{2}[ \n])+)```", DOC.read_text(), re.S)
    kinds = []
    for _, hex_bytes in blocks:
        data = bytes.fromhex(hex_bytes.replace("\n", " "))
        message = msgpack.unpackb(data)
        kind = message["type"]
        kinds.append(kind)
        if kind == "hello":
            again = wire.encode_hello(message.get("stream"), message.get("name"))
        elif kind == "ready":
            fields = {f.name: message[f.name] for f in dataclasses.fields(Ready) if f.name in message}
            again = wire.encode_ready(Ready(**fields), message["v"])
        elif kind == "ack":
            again = wire.encode_ack(Ack(message["session"], message["frame_id"], message.get("stream")), message["v"])
        elif kind == "fetch":
            again = wire.encode_fetch(Fetch(message["after"], message["max"]))
        else:
            read = wire.decode_request(data, LIMITS)
            again = wire.encode_frame(read.to_frame(), read.encoding, stream=read.stream)
            assert wire.decode_request(again, LIMITS) == read
            continue
        assert msgpack.unpackb(again) == message, kind
    assert sorted(set(kinds)) == ["ack", "fetch", "frame", "hello", "ready"]
