"""The live Rerun view: record real replays to .rrd files and read them back with Rerun's own reader.

The replays are the ten RobotCar night frames localized against the day map,
through the real Localizer; the recordings are read with ``rerun.chunk.RrdReader``.
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
import uuid
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

rr = pytest.importorskip("rerun")
import rerun.blueprint as rrb  # noqa: E402
from rerun.chunk import RrdReader  # noqa: E402

from lostx.core.config import Config, HeadingConfig  # noqa: E402
from lostx.core.decide.estimate import Estimate  # noqa: E402
from lostx.core.frame import Frame  # noqa: E402
from lostx.core.localizer import Localizer  # noqa: E402
from lostx.core.match.verify import verify  # noqa: E402
from lostx.core.maps.refmap import ReferenceMap  # noqa: E402
from lostx.replay.folder import folder_traverse  # noqa: E402
from lostx.viz import entities as e  # noqa: E402
from lostx.viz.blueprint import build_blueprint  # noqa: E402
from lostx.viz.colours import class_colours  # noqa: E402
from lostx.viz.geometry import GAP, Panel, display_size, legend_entries  # noqa: E402
from lostx.viz.sequence_window import CELL_WIDTH, band_rgb, on_map_columns, row_height, sequence_band, trajectory  # noqa: E402
from lostx.viz.rate import RateGate  # noqa: E402
from lostx.viz.sink import RerunSink, SinkSettings  # noqa: E402
from lostx.viz.target import ViewerOutput  # noqa: E402

SYNC = SinkSettings(heavy_hz=None, background=False, strict=True, reference_disk_cache=None)
"""Every frame's images and lines, logged on the caller's thread, errors raised: exact counts to check."""
T0 = 1_400_000_000.0


# -- reading a recording back ----------------------------------------------------------------------


@dataclasses.dataclass
class Column:
    frames: list[int]
    values: list


class Recording:
    """The rows of one .rrd, per entity and component, in frame order (static rows under frame -1)."""

    def __init__(self, path: Path) -> None:
        reader = RrdReader(path)
        self.blueprints = reader.blueprints()
        self.rows: dict[str, dict[str, list[tuple[int, object]]]] = {}
        self.times: dict[str, list[tuple[int, int]]] = {}
        for chunk in reader.stream():
            batch = chunk.to_record_batch()
            names = batch.schema.names
            frames = batch.column("frame").to_pylist() if "frame" in names else [-1] * batch.num_rows
            entity = chunk.entity_path.lstrip("/")
            for name in names:
                if ":" not in name:
                    continue
                for frame, value in zip(frames, batch.column(name).to_pylist()):
                    self.rows.setdefault(entity, {}).setdefault(name, []).append((frame, value))
            stamps = batch.column("time").cast("int64").to_pylist() if "time" in names else [None] * batch.num_rows
            self.times.setdefault(entity, []).extend(zip(frames, stamps))

    def column(self, entity: str, component: str) -> Column:
        rows = sorted(self.rows[entity][component], key=lambda r: r[0])
        return Column([f for f, _ in rows], [v for _, v in rows])

    def has(self, entity: str) -> bool:
        return entity in self.rows


# -- replays -----------------------------------------------------------------------------------------


def replay(refmap: ReferenceMap, night: Path, out: Path, camera: str = "front", settings: SinkSettings = SYNC,
           frames: int = 10, positions: np.ndarray | None = None, clock=None,
           config: Config | None = None) -> list[tuple[Frame, Estimate]]:
    """Localize the night frames (with timestamps, 0.1 s apart) and log each through a sink into ``out``."""
    localizer = Localizer(refmap, config or Config())
    kwargs = {"clock": clock} if clock is not None else {}
    sink = RerunSink(refmap, ViewerOutput(rrd=out), settings, **kwargs)
    seen = []
    for frame in list(folder_traverse(night, camera=camera))[:frames]:  # type: ignore[arg-type]
        frame.timestamp = T0 + 0.1 * frame.id
        if positions is not None:
            frame.position = tuple(positions[frame.id] + [0.5, -1.0])  # type: ignore[assignment]
        estimate = localizer.step(frame)
        sink(frame, estimate)
        seen.append((frame, estimate))
    sink.close()
    return seen


@pytest.fixture(scope="module")
def front(day_map, robotcar, tmp_path_factory):
    out = tmp_path_factory.mktemp("viz") / "night.rrd"
    return replay(day_map, robotcar / "night", out), Recording(out)


def matched(est: Estimate):
    return next(c for c in est.candidates if c.index == est.match_index)


# -- the recording of a replay -------------------------------------------------------------------------


def test_every_entity_has_one_time_point_per_frame(front):
    seen, rec = front
    frames = [f.id for f, _ in seen]
    assert frames == list(range(10))
    per_frame = {
        e.QUERY_IMAGE: "EncodedImage:blob", e.QUERY_LABELS: "SegmentationImage:buffer",
        e.LINES: "LineStrips2D:strips", e.CAPTIONS: "Points2D:labels",
        e.CONFIDENCE: "Scalars:scalars", e.MATCH_INDEX: "Scalars:scalars", e.SINGLE_MATCH_INDEX: "Scalars:scalars",
        e.CORRESPONDENCES: "Scalars:scalars", e.STATUS: "TextDocument:text",
        e.CANDIDATE_SCORES: "BarChart:values", e.ANSWER_SCORE: "BarChart:values", e.CANDIDATE_TABLE: "TextDocument:text",
        e.LEGEND_SWATCHES: "LineStrips2D:strips", e.LEGEND_NAMES: "Points2D:labels",
    }
    for entity, component in per_frame.items():
        assert rec.column(entity, component).frames == frames, entity
    # The reference image and its labels are logged when the match moves to another reference.
    matches = [est.match_index for _, est in seen]
    moved = [f for f in frames if f == 0 or matches[f] != matches[f - 1]]
    assert rec.column(e.REFERENCE_IMAGE, "EncodedImage:blob").frames == moved
    assert rec.column(e.REFERENCE_LABELS, "SegmentationImage:buffer").frames == moved
    # The frame timestamps are a second timeline, in nanoseconds.
    stamps = [t for f, t in sorted(rec.times[e.CONFIDENCE], key=lambda r: r[0]) if f >= 0]  # -1: static styles
    assert np.allclose(stamps, [(T0 + 0.1 * i) * 1e9 for i in frames], rtol=0, atol=1e3)
    # The sequence filter's score, speed and window: every frame, as the Estimates say.
    assert rec.column(e.SEQUENCE_COST, "Scalars:scalars").frames == frames
    logged = [v[0] for v in rec.column(e.SEQUENCE_COST, "Scalars:scalars").values]
    assert np.allclose(logged, [est.sequence_score for _, est in seen])
    assert [v[0] for v in rec.column(e.SPEED, "Scalars:scalars").values] == [est.speed for _, est in seen]
    assert rec.column(e.SEQUENCE_IMAGE, "Image:format").frames == frames
    assert rec.column(e.SEQUENCE_WINDOW, "Points2D:positions").frames == frames
    # The map has no positions: no map entities.
    assert not any(entity.startswith("map") for entity in rec.rows)
    assert rec.blueprints, "the default layout travels in the file"


def test_each_frame_reaches_the_viewer_whole_and_in_order(day_map, robotcar, tmp_path):
    # The panels show one frame at a time: every frame's status, table, bars and series are sent
    # together, before any of the next frame's, whatever Rerun's batching would do by itself
    # (here told to wait 10 s, so that only the sink's own hand-over per frame splits the chunks).
    out = tmp_path / "batched.rrd"
    rec = rr.RecordingStream("lostx", recording_id=str(uuid.uuid4()),
                             batcher_config=rr.ChunkBatcherConfig(flush_tick=10.0, flush_num_bytes=1 << 30,
                                                                  flush_num_rows=1 << 20))
    rec.set_sinks(rr.FileSink(str(out)))
    localizer = Localizer(day_map, Config())
    # Images only for the first frame: what is in step here is the light part's own doing.
    sink = RerunSink(day_map, None, dataclasses.replace(SYNC, heavy_hz=1e-6, frame_by_frame=True), recording=rec)
    frames = list(folder_traverse(robotcar / "night"))[:4]
    for frame in frames:
        sink(frame, localizer.step(frame))
    sink.close()
    light = {e.STATUS, e.CANDIDATE_TABLE, e.CANDIDATE_SCORES, e.CONFIDENCE, e.MATCH_INDEX, e.SEQUENCE_COST, e.SPEED}
    order = []
    for chunk in RrdReader(out).stream():
        entity = chunk.entity_path.lstrip("/")
        batch = chunk.to_record_batch()
        if entity in light and "frame" in batch.schema.names:
            in_chunk = set(batch.column("frame").to_pylist())
            assert len(in_chunk) == 1, (entity, in_chunk)
            order.append((in_chunk.pop(), entity))
    assert [f for f, _ in order] == sorted(f for f, _ in order)
    for frame in frames:
        assert {entity for f, entity in order if f == frame.id} == light


def test_logged_values_equal_the_estimates(front):
    seen, rec = front
    estimates = [est for _, est in seen]
    assert [v[0] for v in rec.column(e.MATCH_INDEX, "Scalars:scalars").values] == [est.match_index for est in estimates]
    assert [v[0] for v in rec.column(e.SINGLE_MATCH_INDEX, "Scalars:scalars").values] == \
        [est.single_match_index for est in estimates]
    assert np.array_equal([v[0] for v in rec.column(e.CONFIDENCE, "Scalars:scalars").values],
                          [est.confidence for est in estimates])
    assert [v[0] for v in rec.column(e.CORRESPONDENCES, "Scalars:scalars").values] == \
        [matched(est).correspondences for est in estimates]
    # The bars stand at their candidates' reference indices; the answer's bar is an entity of its own.
    bars = rec.column(e.CANDIDATE_SCORES, "BarChart:values").values
    where = rec.column(e.CANDIDATE_SCORES, "BarChart:abscissa").values
    answer = rec.column(e.ANSWER_SCORE, "BarChart:values").values
    answer_at = rec.column(e.ANSWER_SCORE, "BarChart:abscissa").values
    for bar, x, one, one_x, est in zip(bars, where, answer, answer_at, estimates):
        others = [c for c in est.candidates if c.index != est.match_index]
        assert np.allclose(bar[0]["buffer"], [c.score for c in others])
        assert np.array_equal(x[0]["buffer"], [c.index for c in others])
        assert np.array_equal(one_x[0]["buffer"], [est.match_index]) and np.allclose(one[0]["buffer"], [matched(est).score])
    tables = rec.column(e.CANDIDATE_TABLE, "TextDocument:text").values
    for table, est in zip(tables, estimates):
        rows = [line for line in table[0].splitlines() if line.startswith("| ") and line[2].isdigit()]
        assert len(rows) == len(est.candidates)
        first = est.candidates[0]
        mark = f"**{first.index} ◀**" if first.index == est.match_index else str(first.index)
        assert rows[0].startswith(f"| 1 | {mark} |") and rows[0].endswith(f"| {first.correspondences} |")
    # The status names the answer's own score once, as what it is (here the sequence cost), and the heading.
    status = rec.column(e.STATUS, "TextDocument:text").values[3][0]
    # The calibrated confidence to three decimals, rounded down: 0.999 (localized) shows only once reached.
    assert f"confidence **{math.floor(estimates[3].confidence * 1000 + 1e-9) / 1000:.3f}**" in status
    assert status.count("sequence cost") == 1 and "score **" not in status
    assert f"heading **same ({100 * estimates[3].heading_confidence:.0f} % sure)**" in status


def test_lines_are_the_estimates_correspondences_coloured_by_class(front, day_map):
    seen, rec = front
    strips = rec.column(e.LINES, "LineStrips2D:strips").values
    classes = rec.column(e.LINES, "LineStrips2D:class_ids").values
    h, w = day_map.grid
    for (frame, est), lines, ids in zip(seen, strips, classes):
        corr = est.evidence.correspondences[est.match_index]
        assert len(lines) == matched(est).correspondences == len(corr.label) > 20
        assert ids == [int(v) for v in corr.label]
        colours = rec.column(e.LINES, "LineStrips2D:colors").values[frame.id]
        table = class_colours(day_map.label_names)
        # Translucent, in their class's colour (Rerun packs RGBA into one 0xRRGGBBAA integer).
        assert colours == [(r << 24) | (g << 16) | (b << 8) | 190 for r, g, b in (table[int(v)] for v in corr.label)]
        lines = np.asarray(lines)
        # Query keypoints on the left image (512 px wide), reference keypoints on the right one, at cell centres.
        assert np.allclose(lines[:, 0, 0], (corr.query_xy[:, 0] + 0.5) * 512 / w)
        assert np.allclose(lines[:, 0, 1], (corr.query_xy[:, 1] + 0.5) * 320 / h)
        assert np.allclose(lines[:, 1, 0], 512 + GAP + (corr.ref_xy[:, 0] + 0.5) * 512 / w)


def test_images_are_jpegs_and_label_maps_carry_the_class_names(front, day_map):
    seen, rec = front
    for blob, (frame, est) in zip(rec.column(e.QUERY_IMAGE, "EncodedImage:blob").values, seen):
        image = Image.open(io.BytesIO(bytes(blob[0])))
        assert image.format == "JPEG" and image.size == (512, 320)
        # The logged image is the frame, shrunk: compare at the same size (JPEG changes pixel values a little).
        assert np.abs(np.asarray(image, np.float64) - frame.image[::2, ::2]).mean() < 12
        assert len(blob[0]) < 80_000
    references = rec.column(e.REFERENCE_IMAGE, "EncodedImage:blob")
    labels = rec.column(e.REFERENCE_LABELS, "SegmentationImage:buffer")
    for frame, blob, logged in zip(references.frames, references.values, labels.values):
        est = seen[frame][1]
        image = Image.open(io.BytesIO(bytes(blob[0])))
        assert image.size == (512, 320)
        day = np.asarray(Image.open(day_map.image_path(est.match_index)).reduce(2), np.float64)
        assert np.abs(np.asarray(image, np.float64) - day).mean() < 12
        assert np.array_equal(np.asarray(logged[0], np.uint8).reshape(day_map.grid), day_map.labels(est.match_index))
    query_labels = rec.column(e.QUERY_LABELS, "SegmentationImage:buffer").values
    assert np.array_equal(np.asarray(query_labels[0][0], np.uint8).reshape(day_map.grid), seen[0][1].evidence.query_labels)
    context = rec.column(e.MATCH, "AnnotationContext:context").values[0][0]
    assert [c["class_description"]["info"]["label"] for c in context] == day_map.label_names
    assert len({c["class_description"]["info"]["color"] for c in context}) == len(context)


def test_an_opposite_camera_is_shown_mirrored_and_says_so(day_map, robotcar, tmp_path):
    out = tmp_path / "rear.rrd"
    # The declared rear camera trusted outright: the heading is opposite from the first frame.
    seen = replay(day_map, robotcar / "night", out, camera="rear", frames=3,
                  config=Config(heading=HeadingConfig(declared_prior=1.0)))
    rec = Recording(out)
    h, w = day_map.grid
    for (frame, est), lines, labels, captions, blob in zip(
        seen,
        rec.column(e.LINES, "LineStrips2D:strips").values,
        rec.column(e.QUERY_LABELS, "SegmentationImage:buffer").values,
        rec.column(e.CAPTIONS, "Points2D:labels").values,
        rec.column(e.QUERY_IMAGE, "EncodedImage:blob").values,
    ):
        assert est.opposite
        corr = est.evidence.correspondences[est.match_index]
        assert np.allclose(np.asarray(lines)[:, 0, 0], (w - 1 - corr.query_xy[:, 0] + 0.5) * 512 / w)
        assert np.array_equal(np.asarray(labels[0], np.uint8).reshape(h, w), est.evidence.query_labels[:, ::-1])
        assert "MIRRORED: rear camera, front map · heading opposite" in captions[0]
        assert captions[1].endswith(f"\n{len(corr.label)} correspondences")
        image = np.asarray(Image.open(io.BytesIO(bytes(blob[0]))), np.float64)
        assert np.abs(image - frame.image[::2, ::-2]).mean() < 12
        assert np.abs(image - frame.image[::2, ::2]).mean() > 20


def test_the_map_shows_route_estimate_and_truth(day_map, robotcar, tmp_path):
    # The RobotCar sample has no positions: give this copy of the map a synthetic straight route
    # (5 m apart) to exercise the map view; the frames carry "truth" next to their reference.
    refmap = ReferenceMap.open(day_map.path)
    refmap.positions = np.stack([np.arange(10) * 5.0, np.arange(10) * 1.0], axis=1)
    out = tmp_path / "map.rrd"
    seen = replay(refmap, robotcar / "night", out, frames=4, positions=refmap.positions)
    rec = Recording(out)
    route = rec.column(e.MAP_ROUTE, "LineStrips2D:strips")
    assert route.frames == [-1]
    assert np.allclose(route.values[0][0], refmap.positions * [1, -1])
    estimates = rec.column(e.MAP_ESTIMATE, "Points2D:positions")
    truths = rec.column(e.MAP_TRUTH, "Points2D:positions")
    assert estimates.frames == truths.frames == [0, 1, 2, 3]
    for (frame, est), here, truth in zip(seen, estimates.values, truths.values):
        assert np.allclose(here, [refmap.positions[est.match_index] * [1, -1]])
        assert np.allclose(truth, [np.asarray(frame.position) * [1, -1]])
    candidates = rec.column(e.MAP_CANDIDATES, "Points2D:positions").values
    assert len(candidates[0]) == len(seen[0][1].candidates)


def test_the_sequence_window_is_drawn_when_the_estimate_has_one(day_map, robotcar, tmp_path):
    # Hand the sink estimates with a window of known content (rows oldest first, a reference index per
    # cell, inf where empty) and an answer, reference 2, that only the first frame verified.
    localizer = Localizer(day_map, Config())
    frames = list(folder_traverse(robotcar / "night"))[:2]
    out = tmp_path / "seq.rrd"
    sink = RerunSink(day_map, ViewerOutput(rrd=out), SYNC)
    windows = []
    for frame in frames:
        est = localizer.step(frame)
        window = np.array([[0.2, 0.5, np.inf], [0.1, 0.4, 0.3], [0.3, 0.2, 0.6]])
        cands = np.array([[0, 3, -1], [1, 4, 2], [2, 1, 5]])
        est.evidence.sequence_window, est.evidence.sequence_candidates = window, cands
        if frame.id == 0:
            verified = verify(localizer.matcher.last_evidence, day_map.evidence([2]), np.array([0.5]))
            est.evidence.correspondences = {2: verified.correspondences(0)}
        else:  # the filter's answer is not among this frame's verified candidates
            est.evidence.correspondences = {}
        est = dataclasses.replace(est, sequence_score=0.2 + frame.id, speed=1.0, match_index=2, window=3)
        sink(frame, est)
        windows.append(est)
    sink.close()
    rec = Recording(out)
    assert [v[0] for v in rec.column(e.SEQUENCE_COST, "Scalars:scalars").values] == [0.2, 1.2]
    assert [v[0] for v in rec.column(e.SPEED, "Scalars:scalars").values] == [1.0, 1.0]
    # The band is centred on the answer (2); its columns on the map, references 0..9, are the image.
    image = rec.column(e.SEQUENCE_IMAGE, "Image:format").values[0][0]
    assert (image["width"], image["height"]) == (10, 3)
    # One dot per filled cell: 8 candidates in the window (the inf is not one), named on hover.
    dots = np.asarray(rec.column(e.SEQUENCE_WINDOW, "Points2D:positions").values[0])
    names = rec.column(e.SEQUENCE_WINDOW, "Points2D:labels").values[0]
    assert len(dots) == len(names) == 8
    first = 2 - 25
    assert "reference 0 · 2 frames ago · cost 0.2" in names and "reference 2 · this frame · cost 0.3" in names
    assert [0.5 + (0 - first)] == [dots[names.index("reference 0 · 2 frames ago · cost 0.2")][0] / CELL_WIDTH]
    path = np.asarray(rec.column(e.SEQUENCE_TRAJECTORY, "LineStrips2D:strips").values[0][0])
    assert np.allclose(path, [[(r - first + 0.5) * CELL_WIDTH, (i + 0.5) * row_height(3)] for i, r in enumerate((0, 1, 2))])
    assert rec.column(e.SEQUENCE_INDICES, "Points2D:labels").values[0] == ["ref 0", "ref 2", "ref 9"]
    assert rec.column(e.SEQUENCE_KEY_NAMES, "Points2D:labels").values[0] == ["best 0.1", "worst 0.6"]
    # Lines to the filter's answer where this frame verified it; none (not the last frame's) where it did not.
    lines = rec.column(e.LINES, "LineStrips2D:strips").values
    assert len(lines[0]) == len(windows[0].evidence.correspondences[2].label) > 0
    assert len(lines[1]) == 0
    # Both frames show reference 2: its image is logged once, and stays on screen.
    assert rec.column(e.REFERENCE_IMAGE, "EncodedImage:blob").frames == [0]
    assert rec.column(e.QUERY_IMAGE, "EncodedImage:blob").frames == [0, 1]


def test_a_frame_without_a_clock_gets_no_time(day_map, robotcar, tmp_path):
    localizer = Localizer(day_map, Config())
    frames = list(folder_traverse(robotcar / "night"))[:3]
    frames[0].timestamp, frames[2].timestamp = T0, T0 + 0.2  # frame 1 has no clock
    out = tmp_path / "clock.rrd"
    sink = RerunSink(day_map, ViewerOutput(rrd=out), SYNC)
    for frame in frames:
        sink(frame, localizer.step(frame))
    sink.close()
    times = {f: t for f, t in Recording(out).times[e.CONFIDENCE] if f >= 0}
    assert times[1] is None
    assert np.allclose([times[0], times[2]], [T0 * 1e9, (T0 + 0.2) * 1e9], rtol=0, atol=1e3)


def test_reference_images_are_read_once_across_runs(day_map, robotcar, tmp_path):
    settings = dataclasses.replace(SYNC, reference_disk_cache=tmp_path / "thumbs", reference_cache=1)
    first, second = tmp_path / "first.rrd", tmp_path / "second.rrd"
    seen = replay(day_map, robotcar / "night", first, settings=settings, frames=4)
    matches = {est.match_index for _, est in seen}
    cached = sorted((tmp_path / "thumbs").glob("*/*.jpg"))
    assert sorted(int(p.stem) for p in cached) == sorted(matches)
    sink = RerunSink(day_map, ViewerOutput(rrd=second), settings)
    for frame, est in seen:
        sink(frame, est)
    sink.close()
    assert sink.match_view.references.decoded == 0  # every reference came from the disk cache
    one, two = (Recording(p).column(e.REFERENCE_IMAGE, "EncodedImage:blob") for p in (first, second))
    assert one.frames == two.frames and one.values == two.values
    # Another build of the map (another manifest), or another display size or quality, has its own images.
    import json
    import shutil

    from lostx.viz.images import ReferenceImages

    rebuilt = tmp_path / "rebuilt"
    shutil.copytree(day_map.path, rebuilt)
    manifest = json.loads((rebuilt / "manifest.json").read_text())
    manifest["created"] = "another build"
    (rebuilt / "manifest.json").write_text(json.dumps(manifest))
    folders = {ReferenceImages(m, width, quality, disk=tmp_path / "thumbs").folder
               for m, width, quality in ((day_map, 640, 80), (ReferenceMap.open(rebuilt), 640, 80),
                                         (day_map, 320, 80), (day_map, 640, 70))}
    assert len(folders) == 4


def view_names(container) -> list[str]:
    names = []
    for item in container.contents:
        names += view_names(item) if isinstance(item, rrb.Container) else [str(item.name)]
    return names


SEQUENCE_PANELS = {"Sequence cost", "Speed ref/frame", "Sequence window"}


def test_without_the_sequence_filter_its_empty_panels_leave_the_layout(day_map, robotcar, tmp_path):
    assert SEQUENCE_PANELS <= set(view_names(build_blueprint(10, (512, 320)).root_container))
    assert "Map" in view_names(build_blueprint(2, None, route=np.array([[0.0, 0.0], [10.0, 5.0]])).root_container)
    config = Config()
    localizer = Localizer(day_map, dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, enabled=False)))
    sink = RerunSink(day_map, ViewerOutput(rrd=tmp_path / "single.rrd"), SYNC)
    assert SEQUENCE_PANELS <= set(view_names(sink.blueprint.root_container))
    frame = folder_traverse(robotcar / "night").frame(0)
    sink(frame, localizer.step(frame))
    sink.close()
    shown = set(view_names(sink.blueprint.root_container))
    assert not SEQUENCE_PANELS & shown and {"Confidence", "Route position", "Status", "Top-10"} <= shown
    status = Recording(tmp_path / "single.rrd").column(e.STATUS, "TextDocument:text").values[0][0]
    assert "(single-frame verification, lower is better) · sequence filter off" in status


# -- pacing and the background thread ---------------------------------------------------------------


class FakeClock:
    def __init__(self, step: float) -> None:
        self.now, self.step = 0.0, step

    def __call__(self) -> float:
        t = self.now
        self.now += self.step
        return t


def test_heavy_entities_follow_the_rate_the_rest_every_frame(day_map, robotcar, tmp_path):
    out = tmp_path / "rate.rrd"
    settings = dataclasses.replace(SYNC, heavy_hz=10.0)
    replay(day_map, robotcar / "night", out, settings=settings, frames=6, clock=FakeClock(0.05))  # 20 fps
    rec = Recording(out)
    assert rec.column(e.CONFIDENCE, "Scalars:scalars").frames == [0, 1, 2, 3, 4, 5]
    for entity in (e.QUERY_IMAGE, e.LINES, e.QUERY_LABELS):
        component = {e.LINES: "LineStrips2D:strips", e.QUERY_LABELS: "SegmentationImage:buffer"}.get(
            entity, "EncodedImage:blob")
        assert rec.column(entity, component).frames == [0, 2, 4], entity


def test_rate_gate():
    gate = RateGate(4.0, FakeClock(0.1))  # asked at 10 Hz, opens at 4 Hz on average
    opened = [gate.ready() for _ in range(40)]
    times = np.flatnonzero(opened) * 0.1
    assert opened[0] and sum(opened) == 16  # 4 a second over 4 s: t = 0, 0.3, 0.5, 0.8, 1.1, ...
    assert np.diff(times).min() >= 0.2 - 1e-9  # never two within one asking interval of a slot
    assert all(RateGate(None).ready() for _ in range(3)) and all(RateGate(0).ready() for _ in range(3))


def test_background_thread_logs_every_frame_it_is_given_time_for(day_map, robotcar, tmp_path):
    localizer = Localizer(day_map, Config())
    frames = list(folder_traverse(robotcar / "night"))[:4]
    out = tmp_path / "bg.rrd"
    sink = RerunSink(day_map, ViewerOutput(rrd=out), dataclasses.replace(SYNC, background=True))
    for frame in frames:
        sink(frame, localizer.step(frame))
        sink.flush()  # as if the next frame took longer than the logging
    # Frames arriving faster than the thread logs them replace the pending one: none queue up.
    est = localizer.step(frames[-1])
    for i in range(20):
        sink(dataclasses.replace(frames[-1], id=10 + i), est)
    sink.close()
    assert sink.heavy_submitted == 24
    assert sink.heavy_logged + sink.heavy_dropped == 24 and sink.heavy_logged >= 5
    rec = Recording(out)
    logged = rec.column(e.QUERY_IMAGE, "EncodedImage:blob").frames
    assert logged[:4] == [0, 1, 2, 3] and len(logged) == sink.heavy_logged
    assert logged[-1] == 29, "the last frame is never dropped"
    assert rec.column(e.CONFIDENCE, "Scalars:scalars").frames == [0, 1, 2, 3] + list(range(10, 30))


def test_a_failing_view_does_not_stop_the_localizer(day_map, robotcar, tmp_path):
    localizer = Localizer(day_map, Config())
    frame = folder_traverse(robotcar / "night").frame(0)
    est = localizer.step(frame)
    broken = dataclasses.replace(est, match_index=10_000)  # no such reference
    sink = RerunSink(day_map, ViewerOutput(rrd=tmp_path / "broken.rrd"), dataclasses.replace(SYNC, strict=False))
    sink(frame, broken)
    sink(frame, est)
    sink.close()
    assert sink.errors == 1 and sink.frames == 2
    strict = RerunSink(day_map, ViewerOutput(rrd=tmp_path / "strict.rrd"), SYNC)
    with pytest.raises(IndexError):
        strict(frame, broken)
    strict.close()


# -- the command line -----------------------------------------------------------------------------------


def test_lostx_match_records_what_it_writes_to_the_csv(day_map, robotcar, tmp_path, monkeypatch):
    import csv

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))

    from lostx.cli import main

    out, rrd = tmp_path / "m.csv", tmp_path / "m.rrd"
    assert main(["match", str(day_map.path), str(robotcar / "night"), "--out", str(out), "--rrd", str(rrd),
                 "--quiet", "--viewer-rate", "0"]) == 0
    rows = list(csv.DictReader(open(out)))
    rec = Recording(rrd)
    assert [int(v[0]) for v in rec.column(e.MATCH_INDEX, "Scalars:scalars").values] == \
        [int(r["match_index"]) for r in rows]
    # The command logs images and lines on the background thread: a frame may be skipped under load,
    # but each one logged shows that frame's correspondences, and the last one is always there.
    lines = rec.column(e.LINES, "LineStrips2D:strips")
    assert lines.frames[-1] == len(rows) - 1
    for frame, strips in zip(lines.frames, lines.values):
        assert len(strips) == int(rows[frame]["correspondences"])


def test_viewer_options_make_a_sink_only_when_asked(day_map, tmp_path, monkeypatch):
    import argparse

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))

    from lostx.options import add_viewer_options, viewer_sink_from_args

    parser = argparse.ArgumentParser()
    add_viewer_options(parser)
    assert viewer_sink_from_args(parser.parse_args([]), day_map) is None
    args = parser.parse_args(["--rrd", str(tmp_path / "x.rrd"), "--viewer-rate", "5", "--viewer-memory", "1GiB"])
    sink = viewer_sink_from_args(args, day_map)
    assert sink is not None and sink.settings.heavy_hz == 5.0
    sink.close()
    assert (tmp_path / "x.rrd").stat().st_size > 0
    assert parser.parse_args(["--connect"]).connect == "rerun+http://127.0.0.1:9876/proxy"


def test_the_viewer_is_found_without_an_activated_environment(monkeypatch):
    from lostx.viz.rerun_app import viewer_executable

    monkeypatch.setenv("PATH", "")
    found = viewer_executable()
    assert found is not None and Path(found).is_file() and os.access(found, os.X_OK)


def test_the_viewer_is_the_program_itself_not_pips_wrapper_in_an_activated_environment(monkeypatch, tmp_path):
    """An activated environment puts pip's ``rerun`` wrapper first on PATH: a Python script that runs the program as
    its child, which would outlive the wrapper when lostx stops it. The program itself is started."""
    from lostx.viz.rerun_app import viewer_executable

    wrapper = tmp_path / "rerun"
    wrapper.write_text("#!/usr/bin/env python3\nimport subprocess, sys\nsys.exit(subprocess.call(['rerun-real']))\n")
    wrapper.chmod(0o755)
    monkeypatch.setenv("PATH", str(tmp_path))
    found = viewer_executable()
    assert found is not None and Path(found) != wrapper
    with open(found, "rb") as program:
        assert program.read(2) != b"#!", f"{found} is a script"


# -- geometry -------------------------------------------------------------------------------------------


def test_display_size_divides_by_a_whole_number():
    assert display_size(640, 1024, 640) == (512, 320)
    assert display_size(640, 1024, 400) == (341, 213)
    assert display_size(480, 640, 640) == (640, 480)
    assert display_size(480, 640, None) == (640, 480)


def test_mirrored_panel_flips_cell_centres():
    xy = np.array([[0, 0], [31, 5]])
    plain = Panel(0, 512, 320).cell_centres(xy, (32, 32))
    mirrored = Panel(0, 512, 320, mirrored=True).cell_centres(xy, (32, 32))
    assert np.allclose(plain, [[8, 5], [504, 55]])
    assert np.allclose(mirrored, [[504, 5], [8, 55]])
    assert np.allclose(Panel(100, 512, 320).cell_centres(xy, (32, 32))[:, 0], plain[:, 0] + 100)


def test_sequence_band_keeps_the_lower_cost_and_centres_the_answer():
    window = np.array([[0.5, 0.2, np.inf], [0.9, 0.1, 0.4]])
    cands = np.array([[7, 7, 8], [30, 5, 6]])
    band = sequence_band(window, cands, n_refs=40, centre=6, half_width=2)
    assert band.first == 4 and band.width == 5 and band.rows == 2
    expected = np.full((2, 5), np.nan)
    expected[0, 3] = 0.2          # reference 7 listed twice: the lower cost
    expected[1, 1], expected[1, 2] = 0.1, 0.4
    assert np.array_equal(np.isnan(band.costs), np.isnan(expected))
    assert np.allclose(band.costs[~np.isnan(band.costs)], expected[~np.isnan(expected)])
    lut = np.array([[0, 0, 0], [255, 255, 255]], np.uint8)
    rgb = band_rgb(band, lut, (0, 5))
    assert tuple(rgb[1, 1]) == (255, 255, 255) and tuple(rgb[0, 3]) == (255, 255, 255)  # 0.1 and 0.2 round up
    assert tuple(rgb[1, 2]) == (0, 0, 0) and tuple(rgb[0, 0]) == (128, 128, 128)        # 0.4 the worst; empty grey
    # Near the start of the map the band still centres the answer; only its columns on the map are drawn.
    edge = sequence_band(window, cands, n_refs=40, centre=1, half_width=4)
    assert edge.first == -3 and on_map_columns(edge, 40) == (3, 9)
    assert on_map_columns(sequence_band(window, cands, n_refs=8, centre=6, half_width=4), 8) == (0, 6)


def test_a_window_of_one_frame_stays_one_row():
    # The filter's first frame: a (1, B) band must be drawn as one row, not as a column of pixels.
    band = sequence_band(np.array([[0.3, 0.1]]), np.array([[4, 5]]), n_refs=20, centre=5, half_width=3)
    rgb = band_rgb(band, np.array([[0, 0, 0], [255, 255, 255]], np.uint8), on_map_columns(band, 20))
    assert rgb.shape == (1, 7, 3)
    assert np.allclose(trajectory(1, 5, 1.0, band.first), [[3.5 * CELL_WIDTH, 0.5 * row_height(1)]])
    assert np.allclose(trajectory(3, 10, 2.0, 4), [[2.5 * CELL_WIDTH, 0.5 * row_height(3)], [4.5 * CELL_WIDTH, 1.5 * row_height(3)],
                                                   [6.5 * CELL_WIDTH, 2.5 * row_height(3)]])


def test_legend_lists_the_frequent_classes_first():
    assert legend_entries(np.array([2, 0, 2, 1, 0, 2, 5])) == [(2, 3), (0, 2), (1, 1), (5, 1)]
    assert legend_entries(np.array([3, 3, 1, 2]), limit=2) == [(3, 2), (1, 1)]
    assert legend_entries(np.zeros(0, np.uint16)) == []


def test_a_viewer_that_is_gone_costs_no_line_per_message(tmp_path):
    import subprocess
    import sys

    from lostx.viz.rerun_app import free_port

    # Rerun's own logging is read once, when it loads: a fresh process, as a lostx command is.
    script = (
        "import lostx.viz\n"
        "import rerun as rr\n"
        "rec = rr.RecordingStream('gone')\n"
        f"rec.set_sinks(rr.GrpcSink('rerun+http://127.0.0.1:{free_port()}/proxy'))\n"
        "for i in range(20):\n"
        "    rec.log('x', rr.Scalars([float(i)]))\n"
        "try:\n"
        "    rec.flush(timeout_sec=1.0)\n"
        "except RuntimeError as exc:\n"
        "    print('flush:', exc)\n"
        "rec.disconnect()\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "ERROR" not in proc.stderr and "WARN" not in proc.stderr, proc.stderr
    assert proc.stdout.startswith("flush:")  # the failure still reaches lostx, which says it once


def test_the_layouts_query_caption_says_how_its_grid_was_turned_and_shifted():
    from lostx.core.decide.estimate import LayoutView
    from lostx.core.layout.grid import LayoutGrid
    from lostx.viz.layout_view import query_caption

    grid = LayoutGrid(np.zeros((6, 20, 15), np.float32), np.ones((20, 15), bool))
    assert query_caption(LayoutView(grid, grid, 0.0, 0.0)) == "query"
    assert query_caption(LayoutView(grid, grid, 2.0, -2.0)) == "query (turned 2 deg left, 2 m left)"
    assert query_caption(LayoutView(grid, grid, -2.0, 0.0)) == "query (turned 2 deg right)"
    assert query_caption(LayoutView(grid, grid, 0.0, 4.0)) == "query (4 m right)"
