"""The Rerun sink: ``sink(frame, estimate)`` logs what the localizer saw and answered.

Per frame it logs

- light entities, every frame, on the caller's thread: confidence, sequence
  cost, speed, correspondence count and the matched reference index as time
  series; a status text; the top-10 candidates as a table and as bars at their
  reference indices; the estimate (and the true position, when the frame carries
  one) on the map. They are sent together at the end of each frame, so that no
  panel runs ahead of another;
- heavy entities, at most ``heavy_hz`` frames a second, on a background thread
  (see :mod:`.worker`): the query image (mirrored when it views the route the
  opposite way to the map), the matched reference image, both label maps, the
  correspondence lines and their legend (:mod:`.match_view`), and the sequence
  filter's window (a snapshot with a label per cell: tens of kilobytes).

What is drawn is computed in :mod:`.geometry`, :mod:`.images` and
:mod:`.summary`; this module decides what is logged where and when.
"""

from __future__ import annotations

import logging
import math
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import rerun as rr

from lostx.core.decide.estimate import Estimate
from lostx.core.frame import Frame
from lostx.core.paths import cache_dir
from lostx.core.maps.refmap import ReferenceMap

from . import colours
from . import entities as e
from .blueprint import build_blueprint
from .geometry import map_xy
from .layout_view import log_layout
from .match_view import MatchLogger
from .output import OpenedOutput, open_output
from .rate import RateGate
from .sequence_window import (
    CELL_WIDTH,
    KEY_DOT,
    band_rgb,
    dot_colours,
    index_anchors,
    key_anchors,
    on_map_columns,
    row_height,
    sequence_band,
    trajectory,
    window_dots,
)
from .summary import candidates_markdown, fmt, matched_candidate, status_markdown
from .target import ViewerOutput
from .worker import LatestWorker

log = logging.getLogger(__name__)

WORKER_TIMEOUT = 60.0
"""Seconds :meth:`RerunSink.flush` and :meth:`RerunSink.close` wait for the background thread (one frame's logging)."""
CLOSE_TIMEOUT = 30.0
"""Seconds :meth:`RerunSink.close` waits for the destinations to take the last data."""
EPOCH_AFTER = 1e8
"""Frame timestamps above this many seconds are Unix time (1973 on); below it, seconds since the stream began."""


@dataclass(frozen=True)
class SinkSettings:
    heavy_hz: float | None = 10.0
    """Most frames per second whose images, label maps and lines are logged; None or 0: every frame."""
    background: bool = True
    """Log the heavy entities on a background thread (a busy thread skips frames rather than queueing them)."""
    image_width: int | None = 640
    """About how wide images are shown (the source width over a whole number; never enlarged); None: full size."""
    jpeg_quality: int = 80
    label_opacity: float = 0.15
    """Opacity of the label maps over the images (0 hides them; they can be toggled in the viewer too)."""
    sequence_half_width: int = 25
    """The sequence window image shows the reference frames within this many of the match."""
    reference_cache: int = 64
    """Encoded reference images kept in memory."""
    reference_disk_cache: Path | None = field(default_factory=lambda: cache_dir() / "viewer")
    """Where encoded reference images are kept between runs (about 30 kB each); None: not kept."""
    strict: bool = False
    """Raise logging errors instead of counting them (a viewer must never stop the localizer)."""
    frame_by_frame: bool | None = None
    """Hand each frame's panels over together, so that a live viewer never shows one panel ahead of
    another; False lets Rerun batch several frames into one chunk (about a third smaller, less CPU).
    None: frame by frame where the recording goes to a live viewer (not for an .rrd alone)."""


@dataclass(frozen=True)
class _HeavyJob:
    frame: Frame
    estimate: Estimate


class RerunSink:
    """Logs each (frame, estimate) of one stream to Rerun. Call :meth:`close` at the end.

    The background thread reads the frame's image and the estimate's evidence after the
    call returns: hand over arrays that are not overwritten afterwards (the localizer's
    estimates and decoded frames never are; a camera driver's reused buffer would be).
    """

    def __init__(
        self,
        refmap: ReferenceMap,
        output: ViewerOutput | None = None,
        settings: SinkSettings | None = None,
        recording: rr.RecordingStream | None = None,
        application_id: str = "lostx",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``output`` says where the recording goes (see :class:`ViewerOutput`); alternatively pass a
        ``recording`` whose sinks are already set. ``clock`` paces the heavy entities (tests pass their own)."""
        self.map = refmap
        self.settings = s = settings or SinkSettings()
        self.rec = recording or rr.RecordingStream(application_id, recording_id=uuid.uuid4())
        self.match_view = MatchLogger(self.rec, refmap, s.image_width, s.jpeg_quality, s.label_opacity,
                                      s.reference_cache, s.reference_disk_cache)
        self.blueprint = self._layout(sequence=True)
        self.opened = open_output(self.rec, output, self.blueprint) if output is not None else OpenedOutput()
        live = output is None or output.spawn or output.connect is not None or output.web
        self._frame_by_frame = s.frame_by_frame if s.frame_by_frame is not None else live
        self.gate = RateGate(s.heavy_hz, clock)
        self.worker: LatestWorker[_HeavyJob] | None = LatestWorker(self._log_heavy) if s.background else None
        self.frames = 0
        self.heavy_submitted = 0
        self.errors = 0
        self.seconds = 0.0
        """Time the caller spent in this sink (the background thread's time is not in it)."""
        self._lut = _colour_lut()
        self._closed = False
        self._sequence_seen: bool | None = None
        """Whether the estimates come from the sequence filter; None before the first frame."""
        self._log_static()

    def _layout(self, sequence: bool):
        return build_blueprint(n_refs=self.map.n_frames, image_size=self.match_view.references.display_size(),
                               sequence=sequence, sequence_width=2 * self.settings.sequence_half_width + 1,
                               route=self.map.positions, layout=self.map.layout_settings is not None)

    # -- the sink protocol -------------------------------------------------------------------

    def __call__(self, frame: Frame, estimate: Estimate) -> None:
        start = time.perf_counter()
        try:
            self._log_light(frame, estimate)
            if self.gate.ready():
                self.heavy_submitted += 1
                job = _HeavyJob(frame, estimate)
                if self.worker is not None:
                    self.worker.submit(job)
                else:
                    self._log_heavy(job)
        except Exception:
            self.errors += 1
            if self.settings.strict:
                raise
            if self.errors == 1:
                log.exception("the Rerun sink failed on frame %s; the localizer goes on", frame.id)
        finally:
            self.seconds += time.perf_counter() - start

    def flush(self, timeout: float = WORKER_TIMEOUT) -> None:
        """Wait until everything submitted so far is logged and handed to the destinations."""
        if self.worker is not None:
            self.worker.wait_idle(timeout)
        self._hand_over(timeout)

    def _hand_over(self, timeout: float) -> None:
        try:
            self.rec.flush(timeout_sec=timeout)
        except RuntimeError as exc:  # a viewer closed or gone: the other destinations still get everything
            log.warning("the live view could not hand everything over: %s", exc)

    def close(self) -> None:
        """Finish the pending heavy frame, flush, and close the destinations (an .rrd gets its footer)."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.worker is not None:
                self.worker.close(WORKER_TIMEOUT)
            self._hand_over(CLOSE_TIMEOUT)
            self.rec.disconnect()
        finally:
            self.opened.close()
        if self.settings.strict and self.worker is not None and self.worker.error is not None:
            raise self.worker.error

    @property
    def heavy_logged(self) -> int:
        """Frames whose images and lines were logged (fewer than submitted where the worker was busy)."""
        if self.worker is None:
            return self.heavy_submitted
        return self.worker.done

    @property
    def heavy_dropped(self) -> int:
        """Frames whose images and lines were skipped because the background thread was still busy."""
        return self.worker.dropped if self.worker is not None else 0

    @property
    def heavy_failed(self) -> int:
        """Frames whose images and lines failed to log on the background thread (see the log)."""
        return self.worker.failed if self.worker is not None else 0

    # -- what is logged --------------------------------------------------------------------------

    def _set_time(self, frame: Frame) -> None:
        rec = self.rec
        # Time is per thread in Rerun, and a frame without a clock must not inherit the previous frame's time.
        rec.reset_time()
        rec.set_time(e.FRAME_TIMELINE, sequence=int(frame.id))
        if frame.timestamp is not None and math.isfinite(frame.timestamp):
            if frame.timestamp > EPOCH_AFTER:
                rec.set_time(e.TIME_TIMELINE, timestamp=float(frame.timestamp))
            else:
                rec.set_time(e.TIME_TIMELINE, duration=float(frame.timestamp))

    def _log_static(self) -> None:
        rec = self.rec
        names = self.map.label_names
        if names:
            rec.log(e.MATCH, rr.AnnotationContext(colours.annotation_entries(names)), static=True)
        for path, name, colour in (
            (e.CONFIDENCE, "confidence", colours.CONFIDENCE),
            (e.SEQUENCE_COST, "sequence cost", colours.SEQUENCE_COST),
            (e.SPEED, "speed", colours.SPEED),
            (e.MATCH_INDEX, "answer", colours.MATCH_INDEX),
            (e.CORRESPONDENCES, "correspondences", colours.MATCH_INDEX),
        ):
            rec.log(path, rr.SeriesLines(colors=[colour], names=[name], widths=[2.0]), static=True)
        # Dots, not a line: where the single-frame answer agrees with the answer, both stay visible.
        rec.log(e.SINGLE_MATCH_INDEX, rr.SeriesPoints(colors=[colours.SINGLE_MATCH_INDEX], names=["single-frame answer"],
                                                      markers=["circle"], marker_sizes=[3.0]), static=True)
        if self.map.positions is not None:
            rec.log(e.MAP_ROUTE, rr.LineStrips2D([map_xy(self.map.positions)], colors=[colours.ROUTE],
                                                 radii=rr.Radius.ui_points(1.5)), static=True)

    def _log_light(self, frame: Frame, est: Estimate) -> None:
        self._set_time(frame)
        self.frames += 1
        self._check_sequence_panels(est)
        self._log_series(est)
        self.rec.log(e.STATUS, rr.TextDocument(status_markdown(frame, est, self.map), media_type="text/markdown"))
        self._log_candidates(est)
        if self.map.positions is not None:
            self._log_map(frame, est)
        if self._frame_by_frame:
            # Start sending this frame's chunks now (without waiting): the panels get one frame at a time.
            self.rec.flush(timeout_sec=0.0)

    def _check_sequence_panels(self, est: Estimate) -> None:
        """On the first frame, drop the sequence filter's panels from the layout if it is not running."""
        sequence = est.sequence_score is not None
        if self._sequence_seen is None and not sequence:
            self.blueprint = self._layout(sequence=False)
            self.rec.send_blueprint(self.blueprint, make_active=True, make_default=True)
        self._sequence_seen = sequence

    def _log_heavy(self, job: _HeavyJob) -> None:
        self._set_time(job.frame)
        self.match_view.log(job.frame, job.estimate)
        if self.map.layout_settings is not None:
            log_layout(self.rec, job.estimate)
        self._log_sequence(job.estimate)
        if self._frame_by_frame:
            self.rec.flush(timeout_sec=0.0)

    def _log_series(self, est: Estimate) -> None:
        rec = self.rec
        rec.log(e.CONFIDENCE, rr.Scalars(float(est.confidence)))
        rec.log(e.MATCH_INDEX, rr.Scalars(float(est.match_index)))
        rec.log(e.SINGLE_MATCH_INDEX, rr.Scalars(float(est.single_match_index)))
        if est.sequence_score is not None and math.isfinite(est.sequence_score):
            rec.log(e.SEQUENCE_COST, rr.Scalars(float(est.sequence_score)))
        if est.speed is not None and math.isfinite(est.speed):
            rec.log(e.SPEED, rr.Scalars(float(est.speed)))
        matched = matched_candidate(est)
        if matched is not None:
            rec.log(e.CORRESPONDENCES, rr.Scalars(float(matched.correspondences)))

    def _log_candidates(self, est: Estimate) -> None:
        rec = self.rec
        rec.log(e.CANDIDATE_TABLE, rr.TextDocument(candidates_markdown(est), media_type="text/markdown"))
        # A candidate with nothing verified scores inf: no bar rather than a misleading height.
        shown = [c for c in est.candidates if math.isfinite(c.score)]
        others = [c for c in shown if c.index != est.match_index]
        answer = [c for c in shown if c.index == est.match_index]
        for path, chosen, colour in ((e.CANDIDATE_SCORES, others, colours.CANDIDATE), (e.ANSWER_SCORE, answer, colours.ANSWER)):
            rec.log(path, rr.BarChart(np.array([c.score for c in chosen], dtype=np.float64), color=colour,
                                      abscissa=np.array([c.index for c in chosen], dtype=np.float64),
                                      widths=np.full(len(chosen), self._bar_width, dtype=np.float32)))

    @property
    def _bar_width(self) -> float:
        """Bars one reference wide, or wider on a long map so that ten of them stay visible."""
        return max(1.0, self.map.n_frames / 60.0)

    def _log_sequence(self, est: Estimate) -> None:
        rec = self.rec
        ev = est.evidence
        if ev is None or ev.sequence_window is None or ev.sequence_candidates is None or len(ev.sequence_window) == 0:
            return
        band = sequence_band(ev.sequence_window, ev.sequence_candidates, self.map.n_frames, est.match_index,
                             self.settings.sequence_half_width)
        dots = window_dots(band)
        columns = on_map_columns(band, self.map.n_frames)
        cells = band_rgb(band, self._lut, columns)
        # The format given explicitly: a window of one frame is still a (1, B) image, not a column of pixels.
        rec.log(e.SEQUENCE_IMAGE, rr.Image(bytes=cells.tobytes(), width=cells.shape[1], height=cells.shape[0],
                                           color_model="RGB", datatype="u8", magnification_filter="Nearest"),
                rr.Transform3D(translation=[columns[0] * CELL_WIDTH, 0.0, 0.0],
                               scale=[CELL_WIDTH, row_height(band.rows), 1.0]))
        if len(dots.cost):
            lo, hi = float(dots.cost.min()), float(dots.cost.max())
            labels = [f"reference {r} · {_age(a)} · cost {fmt(c)}" for r, a, c in zip(dots.reference, dots.age, dots.cost)]
            rec.log(e.SEQUENCE_WINDOW, rr.Points2D(dots.xy, radii=dots.radius, colors=dot_colours(dots.cost, self._lut, lo, hi),
                                                   labels=labels, show_labels=False))
            key = key_anchors(band.width)
            rec.log(e.SEQUENCE_KEY, rr.Points2D(key, radii=KEY_DOT, colors=dot_colours(np.array([lo, hi]), self._lut, lo, hi)))
            # The names in their own entity: a label takes its point's colour, and the worst cost's is near black.
            rec.log(e.SEQUENCE_KEY_NAMES, rr.Points2D(key + [0.0, KEY_DOT], radii=rr.Radius.ui_points(0.1),
                                                      colors=[colours.CAPTION], show_labels=True,
                                                      labels=[f"best {fmt(lo)}", f"worst {fmt(hi)}"]))
        else:
            for path in (e.SEQUENCE_WINDOW, e.SEQUENCE_KEY, e.SEQUENCE_KEY_NAMES):
                rec.log(path, rr.Clear(recursive=False))
        anchors, shown = index_anchors(band, self.map.n_frames)
        rec.log(e.SEQUENCE_INDICES, rr.Points2D(anchors, radii=rr.Radius.ui_points(0.1), colors=[colours.CAPTION],
                                                labels=[f"ref {i}" for i in shown], show_labels=True))
        if est.speed is not None and math.isfinite(est.speed):
            path = trajectory(band.rows, est.match_index, est.speed, band.first)
            rec.log(e.SEQUENCE_TRAJECTORY, rr.LineStrips2D([path], colors=[colours.TRAJECTORY],
                                                           radii=rr.Radius.ui_points(1.5), draw_order=40.0))
        else:
            rec.log(e.SEQUENCE_TRAJECTORY, rr.Clear(recursive=False))

    def _log_map(self, frame: Frame, est: Estimate) -> None:
        rec = self.rec
        positions = self.map.positions
        assert positions is not None
        idx = np.array([c.index for c in est.candidates], dtype=np.int64)
        if len(idx):
            rec.log(e.MAP_CANDIDATES, rr.Points2D(map_xy(positions[idx]), colors=[colours.CANDIDATE],
                                                  radii=rr.Radius.ui_points(3.0)))
        here = map_xy(positions[[est.match_index]])
        colour = colours.LOCALIZED if est.state == "localized" else colours.NOT_LOCALIZED
        rec.log(e.MAP_ESTIMATE, rr.Points2D(here, colors=[colour], radii=rr.Radius.ui_points(6.0),
                                            labels=[f"answer {est.match_index}"], show_labels=True))
        if frame.position is not None:
            truth = map_xy(np.asarray([frame.position], dtype=np.float64))
            rec.log(e.MAP_TRUTH, rr.Points2D(truth, colors=[colours.TRUTH], radii=rr.Radius.ui_points(4.0),
                                             labels=["truth"]))
            rec.log(e.MAP_ERROR, rr.LineStrips2D([np.concatenate([here, truth])], colors=[colours.NOT_LOCALIZED],
                                                 radii=rr.Radius.ui_points(1.0)))


def _age(frames: int) -> str:
    return "this frame" if frames == 0 else f"{frames} frame{'s' if frames > 1 else ''} ago"


def _colour_lut() -> np.ndarray:
    """256 colours of viridis, dark (high cost) to bright (low cost)."""
    from matplotlib import colormaps

    return (colormaps["viridis"](np.linspace(0.0, 1.0, 256))[:, :3] * 255).astype(np.uint8)
