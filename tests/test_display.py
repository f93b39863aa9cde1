"""How listen, serve and the demo word the service's answers: warm-up and dropped frames explained."""

from __future__ import annotations

import dataclasses

from lostx.commands.listen import format_result
from lostx.display import drop_line, state_label, warm_up_line
from lostx.stream.messages import Result, Stats, Tag

RESULT = Result(frame_id=3, timestamp=None, state="not_localized", match_index=2, match_name="0000040.png",
                position=None, confidence=0.0, score=0.4, single_match_index=2, candidates=(), sequence_score=1.5,
                speed=1.0, window=3, warming_up=True, margin=None, heading="same", heading_confidence=1.0,
                latency_ms={"total": 41.0}, tag=Tag(stream="robot", seq=4, stream_seq=4))
STATS = Stats(session="s", mode="live", uptime_s=3.0, received=10, answered=4, dropped=6, missing=0, duplicates=0,
              errors=0, errors_by_code={}, queued_frames=0, queued_results=0, listeners=1, producers=1,
              latency_ms={"step": {"n": 4, "p50": 250.0, "p90": 260.0, "p99": 270.0, "max": 270.0}}, final=True)


def test_an_answer_in_the_warm_up_reads_warming_up_in_listen_and_the_demo():
    assert state_label(RESULT) == "warming up"
    assert "warming up" in format_result(RESULT) and "not_localized" not in format_result(RESULT)
    assert state_label(dataclasses.replace(RESULT, warming_up=False)) == "not localized"
    assert state_label(dataclasses.replace(RESULT, warming_up=False, state="localized")) == "localized"


def test_the_warm_up_line_says_when_the_stream_is_shorter_than_the_window():
    assert warm_up_line(0, 10, 20) is None
    assert warm_up_line(10, 10, 10) == ("all 10 answers came while the sequence window was filling (10 frames seen): "
                                        "the stream is shorter than the window; serve with --window 10 or less")
    assert warm_up_line(2, 10, 3) == "2 of 10 answers came while the sequence window was filling (not localized)"


def test_dropped_frames_are_explained_with_the_localizers_pace_and_the_way_out():
    assert drop_line(STATS) == ("6 of 10 frames dropped: the localizer (250 ms per frame, about 4.0 frames/s) is "
                                "slower than the frames arrived; replay at a lower --rate, or serve with --mode "
                                "lossless --journal DIR to answer every frame")
    assert drop_line(dataclasses.replace(STATS, dropped=0)) is None
    assert drop_line(dataclasses.replace(STATS, mode="lossless")) is None
    no_timings = drop_line(dataclasses.replace(STATS, latency_ms={}))
    assert no_timings.startswith("6 of 10 frames dropped: the localizer is slower than the frames arrived;")
