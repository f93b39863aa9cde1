"""The heavy part of the view: query and matched reference side by side, label maps, correspondence lines.

Both images live in one 2D space (the ``match`` entity): the query at x = 0,
the reference to its right, their captions and the legend of the line colours
below them, where no line reaches. Their label maps are logged at feature-grid
resolution (32 x 32 cells, a kilobyte) and stretched over the images by a
scale transform, rather than upsampled to image size; the default layout hides
them (the blueprint panel shows them again). The lines join each
correspondence's keypoints at their cell centres, thin and translucent, in the
colour of their semantic class; hovering one names the class (annotation context
on ``match``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from lostx.core.decide.estimate import Estimate
from lostx.core.frame import Frame
from lostx.core.maps.refmap import ReferenceMap

from . import colours
from . import entities as e
from .geometry import Panel, caption_anchors, correspondence_strips, legend_entries, legend_layout, side_by_side
from .images import Jpeg, ReferenceImages, encode
from .summary import captions

LINE_RADIUS = 1.0
"""Correspondence lines are this many UI points wide on each side: thin enough to see the images through."""

class MatchLogger:
    """Logs one frame's match space. Keeps the encoded-reference cache and the current panel layout."""

    def __init__(self, rec: rr.RecordingStream, refmap: ReferenceMap, image_width: int | None, jpeg_quality: int,
                 label_opacity: float, reference_cache: int, reference_disk_cache: Path | None = None) -> None:
        self.rec = rec
        self.map = refmap
        self.image_width = image_width
        self.jpeg_quality = jpeg_quality
        self.label_opacity = label_opacity
        self.references = ReferenceImages(refmap, image_width, jpeg_quality, reference_cache, reference_disk_cache)
        self.grid: tuple[int, int] | None = getattr(refmap, "grid", None)
        self._panels: tuple[Panel, Panel] | None = None
        self._shown: int | None = None
        """The reference index whose image and labels were logged last."""

    def log(self, frame: Frame, est: Estimate) -> None:
        rec = self.rec
        query = encode(frame.image, self.image_width, self.jpeg_quality, mirror=est.opposite)
        reference = self.references.get(est.match_index)
        ref_size = (reference.width, reference.height) if reference is not None else (query.width, query.height)
        panels = side_by_side((query.width, query.height), ref_size, est.opposite)
        if panels != self._panels:
            self._place(panels)
        q_panel, r_panel = panels

        rec.log(e.QUERY_IMAGE, _encoded(query))
        if est.match_index != self._shown:
            # A reference stays on screen until the match moves on: logged again it would
            # only cost memory (the viewer shows the latest image at any time).
            self._shown = est.match_index
            rec.log(e.REFERENCE_IMAGE, _encoded(reference) if reference is not None else rr.Clear(recursive=False))
            if self.map.kind == "lost":
                rec.log(e.REFERENCE_LABELS, rr.SegmentationImage(
                    np.ascontiguousarray(self.map.labels(est.match_index)), opacity=self.label_opacity))
        query_colour = colours.MIRRORED if est.opposite else colours.OUTLINE
        rec.log(e.QUERY_OUTLINE, _outline(q_panel, query_colour))
        rec.log(e.REFERENCE_OUTLINE, _outline(r_panel, colours.OUTLINE))

        ev = est.evidence
        if ev is not None and ev.query_labels is not None:
            labels = ev.query_labels[:, ::-1] if est.opposite else ev.query_labels
            rec.log(e.QUERY_LABELS, rr.SegmentationImage(np.ascontiguousarray(labels), opacity=self.label_opacity))
        grid = (ev.grid if ev is not None else None) or self.grid
        corr = ev.correspondences.get(est.match_index) if ev is not None else None
        if corr is not None and grid is not None:
            strips, class_ids = correspondence_strips(corr, grid, q_panel, r_panel)
        else:
            # No verified correspondences to the answer (e.g. the sequence filter chose a
            # reference outside this frame's top-k): no lines, rather than the last frame's.
            strips, class_ids = np.zeros((0, 2, 2), np.float32), np.zeros(0, np.uint16)
        rec.log(e.LINES, rr.LineStrips2D(strips, class_ids=class_ids, radii=rr.Radius.ui_points(LINE_RADIUS),
                                         colors=colours.line_colours(class_ids.tolist(), self.map.label_names)))
        self._log_legend(legend_entries(class_ids), panels)
        # Captions live in the untransformed match space: the viewer places labels of
        # transformed entities at their untransformed positions.
        rec.log(e.CAPTIONS, rr.Points2D(caption_anchors(q_panel, r_panel),
                                        labels=captions(frame, est, self.map.camera, len(strips)),
                                        colors=[colours.MIRRORED if est.opposite else colours.CAPTION, colours.CAPTION],
                                        radii=rr.Radius.ui_points(0.1), show_labels=True))

    def _log_legend(self, entries: list[tuple[int, int]], panels: tuple[Panel, Panel]) -> None:
        """Swatches of the line colours in this frame, each with its class name and count."""
        swatches, anchors = legend_layout(len(entries), *panels)
        names = self.map.label_names
        table = colours.class_colours(names)
        self.rec.log(e.LEGEND_SWATCHES, rr.LineStrips2D(
            swatches, radii=rr.Radius.ui_points(4.0),
            colors=[table[i] if i < len(table) else colours.UNKNOWN_CLASS for i, _ in entries]))
        self.rec.log(e.LEGEND_NAMES, rr.Points2D(anchors, radii=rr.Radius.ui_points(0.1), colors=[colours.CAPTION],
                                                 labels=[f"{names[i] if i < len(names) else i} {n}" for i, n in entries],
                                                 show_labels=True))

    def _place(self, panels: tuple[Panel, Panel]) -> None:
        """Put both images in the match space and stretch the label maps over them."""
        rec = self.rec
        self._panels = panels
        q, r = panels
        rec.log(e.QUERY, rr.Transform3D(translation=[q.x0, 0.0, 0.0]))
        rec.log(e.REFERENCE, rr.Transform3D(translation=[r.x0, 0.0, 0.0]))
        if self.grid is not None:
            for path, panel in ((e.QUERY_LABELS, q), (e.REFERENCE_LABELS, r)):
                sx, sy = panel.grid_scale(self.grid)
                rec.log(path, rr.Transform3D(scale=[sx, sy, 1.0]))


def _encoded(jpeg: Jpeg) -> rr.EncodedImage:
    return rr.EncodedImage(contents=jpeg.data, media_type="image/jpeg")


def _outline(panel: Panel, colour: colours.Rgb) -> rr.Boxes2D:
    mins, size = panel.outline()
    return rr.Boxes2D(mins=[mins], sizes=[size], colors=[colour], radii=rr.Radius.ui_points(1.0))

