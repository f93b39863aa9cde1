"""``lostx match MAP SOURCE --out matches.csv``: match a traverse of queries (any format) against a map."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.display import window_note
from lostx.options import (
    IgnoredSettingWarning,
    add_config_options,
    add_source_options,
    add_viewer_options,
    config_from_args,
    ignored_classes_note,
    live_view,
    print_notes,
    serve_until_interrupted,
    source_options_from_args,
)

if TYPE_CHECKING:
    from lostx.core.config import Config
    from lostx.core.decide.estimate import Estimate
    from lostx.core.maps.refmap import ReferenceMap

COLUMNS = ["query_index", "query_file", "match_index", "match_file", "score", "confidence", "candidates",
           "distance", "correspondences"]
SEQUENCE_COLUMNS = ["single_match_index", "state", "speed", "disagrees"]
HEADING_COLUMNS = ["heading", "heading_confidence", "cue_weights"]
POSITION_COLUMNS = ["x", "y"]
"""The map position of ``match_index``, where the map has positions."""


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("match", help="match a traverse of queries (images, a bag, a video, ...) against a map")
    parser.add_argument("map", type=Path, help="reference map folder (from `lostx map build`)")
    parser.add_argument("queries", type=Path, help="the query traverse: a folder of images (name order), a RobotCar "
                        "folder, a ROS 2 bag (.mcap), a video, a nuScenes scene (see docs/datasets.md)")
    parser.add_argument("--out", type=Path, required=True, help="CSV file to write, one row per query")
    camera = parser.add_mutually_exclusive_group()
    camera.add_argument("--camera", choices=["front", "rear"],
                        help="declare the query camera's direction (default: as the source declares it)")
    camera.add_argument("--opposite", action="store_true", help="the query camera faces opposite to the map's")
    parser.add_argument("--sequence", action="store_true",
                        help="answer with the online sequence filter and tracker (frames in traverse order)")
    parser.add_argument("--mirror", action="store_true",
                        help="flip the query images left-right first (tests the flip handling; not an opposite view)")
    parser.add_argument("--descriptor", choices=["lost", "thumbnail"],
                        help="check that the map holds this descriptor (default: whatever it holds)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_source_options(parser, reverse=True)
    add_config_options(parser)
    add_viewer_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from lostx.core.budget import check_memory
    from lostx.core.errors import InputError, LostxError, MapError
    from lostx.core.localizer import Localizer
    from lostx.core.outputs import check_output_file
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.replay.dataset import open_traverse

    config = config_from_args(args)
    config = dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, enabled=args.sequence))
    check_output_file(args.out, "--out")
    refmap = ReferenceMap.open(args.map)
    check_memory(config, refmap.n_frames)
    if args.descriptor and args.descriptor != refmap.kind:
        raise InputError(f"{args.map} is a {refmap.kind} map, not {args.descriptor}")
    built_with = (refmap.backbone or {}).get("name")
    if args.backbone and refmap.kind == "lost" and args.backbone != built_with:
        # Without --backbone the matcher takes the map's own; a different one named explicitly is a mistake.
        raise MapError(f"{args.map} was built with backbone {built_with}, but --backbone asks for {args.backbone}; "
                       f"use --backbone {built_with} (or leave it out) or rebuild the map")
    camera = {"front": "rear", "rear": "front"}[refmap.camera] if args.opposite else args.camera
    queries = open_traverse(args.queries, args.format, camera, mirror=args.mirror,
                            options=source_options_from_args(args))
    if args.reverse:
        queries = queries.reversed()
    print_notes(queries.notes)
    window = config.sequence.length
    note = window_note(window, len(queries), args.queries) if args.sequence else None
    if note is not None:
        print(note)
    localizer = Localizer(refmap, config)
    backbone = getattr(localizer.matcher.describer, "backbone", None)  # a thumbnail map has none
    ignored = ignored_classes_note(args, config, refmap, None if backbone is None else backbone.info)
    if ignored is not None:
        warnings.warn(ignored, IgnoredSettingWarning, stacklevel=1)
    columns = (COLUMNS + (SEQUENCE_COLUMNS if args.sequence else []) + HEADING_COLUMNS
               + (POSITION_COLUMNS if refmap.positions is not None else []))
    with live_view(args, refmap) as sink, AnswersFile(args.out, columns, len(queries)) as answers:
        start = time.perf_counter()
        estimates = []
        with tqdm(queries, total=len(queries), desc="matching", unit="frame", disable=args.quiet,
                  leave=False) as bar:
            try:
                for frame in bar:
                    estimate = localizer.step(frame)
                    if sink is not None:
                        sink(frame, estimate)
                    estimates.append(estimate)
                    answers.add(csv_row(frame.name, estimate, refmap, args.sequence))
            except LostxError as exc:
                raise type(exc)(f"{exc} ({answers.kept()})") from None
        elapsed = time.perf_counter() - start
        answers.complete = True
        too_short = localizer.calibration.too_short(args.sequence, config.decision.min_confidence)
        print(summary_line(estimates, elapsed, args.out, window if args.sequence else None,
                           none_localized(estimates, config, too_short)), flush=True)
        # The results are written: the web viewer may stay up as long as the user likes.
        serve_until_interrupted(sink)
    return 0


class AnswersFile:
    """The CSV of answers, written as they come: each row flushed to the disk, so that whatever stops the
    command (Ctrl-C, SIGTERM, a frame it cannot read) leaves a complete CSV of the frames answered so far, and
    says so. Opened before any frame is matched: an ``--out`` that cannot be written fails at once."""

    def __init__(self, path: Path, columns: list[str], total: int) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path, self.total, self.rows = path, total, 0
        self.complete = False
        self._handle = open(path, "w", newline="")
        self._writer = csv.DictWriter(self._handle, fieldnames=columns)
        self._writer.writeheader()
        self._handle.flush()

    def __enter__(self) -> "AnswersFile":
        return self

    def add(self, row: dict[str, object]) -> None:
        self._writer.writerow(row)
        self._handle.flush()
        self.rows += 1

    def kept(self) -> str:
        return f"{self.rows} of {self.total} frames answered before it stopped; their answers are in {self.path}"

    def __exit__(self, kind: type | None, *exc: object) -> None:
        self._handle.close()
        if kind is KeyboardInterrupt:  # an error's message says it already
            print(f"lostx: {self.kept()}", file=sys.stderr, flush=True)


def csv_row(name: str, estimate: Estimate, refmap: ReferenceMap, sequence: bool) -> dict[str, object]:
    single = estimate.candidates[0]
    row: dict[str, object] = {
        "query_index": estimate.frame_id,
        "query_file": name,
        "match_index": estimate.match_index,
        "match_file": refmap.names[estimate.match_index],
        "score": f"{estimate.score:.6g}",
        "confidence": f"{estimate.confidence:.4f}",
        "candidates": " ".join(str(c.index) for c in estimate.candidates),
        "distance": f"{single.distance:.6g}",
        "correspondences": single.correspondences if refmap.kind == "lost" else "",
    }
    row["heading"] = estimate.heading
    row["heading_confidence"] = f"{estimate.heading_confidence:.4f}"
    row["cue_weights"] = " ".join(f"{name}={weight:.3f}" for name, weight in estimate.cue_weights.items())
    if estimate.position is not None:
        # Exactly as the map holds them: map coordinates may be large (UTM) or fine (degrees).
        row["x"], row["y"] = (float(v) for v in estimate.position)
    if sequence:
        row["single_match_index"] = estimate.single_match_index
        row["state"] = estimate.state
        row["speed"] = "" if estimate.speed is None else f"{estimate.speed:.3f}"
        row["disagrees"] = int(estimate.disagrees)
    return row


def none_localized(estimates: list[Estimate], config: Config, too_short: str | None) -> str | None:
    """Why no answer is ``localized``, where none is and some were past the sequence window's warm-up (whose
    answers never are, as the summary says): the map too short to be sure (``too_short``, from its calibration), no
    answer confident enough (the highest confidence), the confident ones unsure of their heading, or each of those
    disagreeing with the route tracker."""
    if any(e.state == "localized" for e in estimates):
        return None
    answered = [e for e in estimates if not e.warming_up]
    if not answered:
        return None
    if too_short:
        return too_short
    bar, heading_bar = config.decision.min_confidence, config.heading.min_confidence
    best = max(answered, key=lambda e: e.confidence)
    confident = [e for e in answered if e.confidence >= bar]
    if not confident:
        return (f"no answer reached the confidence a localized one needs, {bar:g} ([decision] min_confidence): "
                f"the highest was {best.confidence:.4f}, frame {best.frame_id}'s")
    sure = [e for e in confident if e.heading_confidence >= heading_bar]
    if not sure:
        surest = max(e.heading_confidence for e in confident)
        return (f"{len(confident)} answer(s) reached the confidence of {bar:g}, none with its heading at least "
                f"{heading_bar:g} probable ([heading] min_confidence; the surest {surest:.3f})")
    return (f"{len(sure)} answer(s) reached the confidence of {bar:g} with a sure heading, and each disagreed with "
            f"the route tracker's prediction (--no-tracker answers without it)")


def summary_line(estimates: list[Estimate], elapsed: float, out: Path, window: int | None = None,
                 reason: str | None = None) -> str:
    """One line: queries, time per frame and per stage (stages that ran), what was localized; ``window``
    is the sequence window (None: single-frame answers); ``reason``: why no answer is ``localized``, where
    none is (:func:`none_localized`)."""
    n = len(estimates)
    stages = {k: sum(e.latency_ms.get(k, 0.0) for e in estimates) / n for k in estimates[0].latency_ms}
    detail = ", ".join(f"{k} {v:.1f}" for k, v in stages.items() if k != "total" and v > 0)
    localized = sum(e.state == "localized" for e in estimates)
    states = f"{localized} localized"
    warming = sum(bool(e.warming_up) for e in estimates)
    if window is not None and warming:
        states += f", {warming} not_localized while the {window}-frame sequence window filled"
    if reason:
        states += f" ({reason})"
    return (f"matched {n} queries in {elapsed:.1f} s ({1e3 * elapsed / n:.0f} ms per frame; {detail} ms); "
            f"{states}; wrote {out}")
