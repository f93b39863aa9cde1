"""``lostx eval --reference SOURCE --query SOURCE --out REPORT_DIR``: several methods, their metrics, plots, a report."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lostx import __version__
from lostx.evaluation.catalogue import METHODS, MODES
from lostx.options import (
    CAMERA_FILE_HELP, add_config_options, add_source_options, config_from_args, number, print_notes,
    source_options_from_args,
)
from lostx.replay.formats import FORMATS

if TYPE_CHECKING:
    from lostx.core.config import Config
    from lostx.evaluation.datasets import DatasetPair
    from lostx.evaluation.groundtruth import GroundTruth


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("eval", help="evaluate LoST-X and baselines on a reference/query pair")
    parser.add_argument("--reference", type=Path, required=True,
                        help="reference traverse (the map): a folder, a RobotCar folder, a bag, a video, a nuScenes "
                             "scene, or a VPR-Bench dataset (see docs/datasets.md)")
    parser.add_argument("--query", type=Path, help="query traverse (not for a VPR-Bench folder)")
    parser.add_argument("--format", choices=FORMATS, help="dataset layout (default: recognised from the paths)")
    parser.add_argument("--out", type=Path, required=True, help="report folder to write")
    parser.add_argument("--opposite", action="store_true",
                        help="the queries view the route the opposite way to the reference: the true heading, "
                             "for scoring (the localizer is not told)")
    declared = parser.add_mutually_exclusive_group()
    declared.add_argument("--query-camera", choices=["front", "rear"],
                          help="declare the query camera's direction to the localizer, a prior on the heading "
                               "(default: as the source declares it)")
    declared.add_argument("--no-declare", action="store_true",
                          help="declare no camera direction: the heading is found from the images alone")
    parser.add_argument("--mirror-query", action="store_true",
                        help="flip the query images left-right (a test of the flip handling, not an opposite view)")
    parser.add_argument("--reference-positions", type=Path, help="positions CSV of the reference images")
    parser.add_argument("--query-positions", type=Path, help="positions CSV of the query images")
    parser.add_argument("--reference-camera-file", type=Path, metavar="PATH",
                        help=f"reference: {CAMERA_FILE_HELP}")
    parser.add_argument("--query-camera-file", type=Path, metavar="PATH", help=f"query: {CAMERA_FILE_HELP}")
    parser.add_argument("--spacing", type=number(0, above=True), metavar="METRES",
                        help="keep one frame every SPACING metres travelled (the paper: 2)")
    parser.add_argument("--tolerances", type=number(0), nargs="+",
                        help="ground-truth tolerances (default: 0 1 2 frames, or 5 10 20 40 80 m with positions)")
    parser.add_argument("--unit", choices=["frames", "m"], help="unit of the tolerances (default: m with positions)")
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    parser.add_argument("--modes", nargs="+", choices=list(MODES), default=list(MODES))
    parser.add_argument("--cache", type=Path, help="cache of network outputs (default: REPORT_DIR/cache)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_source_options(parser, format=False, reverse=True, camera_file=False)
    add_config_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from lostx.core.budget import check_memory
    from lostx.core.outputs import check_output_folder
    from lostx.evaluation.datasets import open_pair
    from lostx.evaluation.methods import evaluate_pair, paired_comparisons
    from lostx.evaluation.report import (
        markdown_table,
        method_styles,
        paired_table,
        plot_max_f1_vs_tolerance,
        plot_pr_curves,
        quantity,
        reliability_table,
        report_entry,
        write_markdown,
        write_report_json,
    )

    config = config_from_args(args)
    check_output_folder(args.out, "--out")
    cache = args.cache or args.out / "cache"
    check_output_folder(cache, "--cache")
    pair = open_pair(
        args.reference, args.query, args.format,
        query_camera=args.query_camera, undeclared=args.no_declare,
        reference_positions=args.reference_positions, query_positions=args.query_positions,
        mirror_query=args.mirror_query, spacing=args.spacing,
        options=source_options_from_args(args), reverse_query=args.reverse,
    )
    pair = with_camera_files(pair, args.reference_camera_file, args.query_camera_file)
    check_memory(config, len(pair.reference))
    print_notes(pair.notes)
    runs, truths = evaluate_pair(pair, config, cache, args.methods, args.modes, args.tolerances, args.unit,
                                 progress=not args.quiet, true_heading="opposite" if args.opposite else "same")
    entries = [report_entry(r.method, r.mode, e, label=METHODS[r.method], **r.extras(k))
               for r in runs for k, e in enumerate(r.evaluations)]
    args.out.mkdir(parents=True, exist_ok=True)
    title = f"{pair.reference.name} (reference) vs {pair.query.name} (query)"
    if args.mirror_query:
        title += ", query images mirrored (not an opposite-direction traverse)"
    styles = method_styles([(r.method, r.mode) for r in runs])
    unit = truths[0].unit
    figures: list[tuple[str, str]] = []
    for k, truth in enumerate(truths):
        caption = f"precision-recall at a tolerance of {quantity(truth.tolerance, unit)}"
        name = f"pr_{_tag(truth.tolerance)}{unit}.png"
        plot_pr_curves([(r.label, r.evaluations[k].curve) for r in runs], args.out / name, f"{title}\n{caption}",
                       styles)
        figures.append((caption, name))
    caption = "max F1 against the localization tolerance"
    plot_max_f1_vs_tolerance([(r.label, r.evaluations) for r in runs], args.out / "max_f1_vs_tolerance.png",
                             f"{title}\n{caption}", styles)
    figures.append((caption, "max_f1_vs_tolerance.png"))
    write_report_json(args.out / "report.json", entries)
    reliability = reliability_table([(r.label, r.reliability[0]) for r in runs])
    comparisons = paired_table([(a.label, b.label, quantity(truth.tolerance, unit), c, stretches)
                                for a, b, truth, c, stretches in paired_comparisons(runs, truths)])
    write_markdown(args.out / "report.md", entries, title, report_settings(args, config, pair, truths), figures,
                   reliability, comparisons)
    print(markdown_table(entries))
    for note in too_short_notes(runs):
        print(note)
    print(f"wrote {args.out / 'report.md'}, report.json and {len(figures)} figures")
    return 0


def too_short_notes(runs: list) -> list[str]:
    """One line per map and mode on which no answer could be ``localized``, naming the runs, and why."""
    by_reason: dict[str, list[str]] = {}
    for r in runs:
        if r.too_short:
            by_reason.setdefault(r.too_short, []).append(r.label)
    return [f"note: {', '.join(labels)}: {reason}" for reason, labels in by_reason.items()]


def with_camera_files(pair: DatasetPair, reference: Path | None, query: Path | None) -> DatasetPair:
    """The pair with the camera files given for either side in place of its own geometry."""
    from dataclasses import replace

    from lostx.replay.calibration import with_camera_file

    if reference is not None:
        pair = replace(pair, reference=with_camera_file(pair.reference, reference))
    if query is not None:
        pair = replace(pair, query=with_camera_file(pair.query, query))
    return pair


def report_settings(args: argparse.Namespace, config: Config, pair: DatasetPair,
                    truths: list[GroundTruth]) -> dict[str, Any]:
    """What produced the numbers: the data, the method's settings, the version."""
    from lostx.core.backbones import resolve_model_path
    from lostx.evaluation.report import quantity

    unit = truths[0].unit
    settings: dict[str, Any] = {
        "reference": f"`{pair.reference.root.resolve()}` ({len(pair.reference)} frames)",
        "query": f"`{pair.query.root.resolve()}` ({len(pair.query)} frames"
                 + (", mirrored left-right" if args.mirror_query else "") + ")",
        "format": pair.format,
        "query camera": "opposite to the reference's" if args.opposite else "as the reference's",
    }
    if args.spacing:
        settings["spacing"] = f"one frame every {args.spacing:g} m"
    settings["tolerances"] = ", ".join(quantity(t.tolerance, unit) for t in truths)
    settings["methods"] = ", ".join(METHODS[m] for m in args.methods)
    if any(m != "thumbnail" for m in args.methods):
        settings["backbone"] = f"{config.backbone.name} (`{resolve_model_path(config.backbone).name}`)"
        settings["scoring"] = f"{config.verify.scoring}, top {config.verify.top_k} candidates verified"
    if "sequence" in args.modes:
        settings["sequence window"] = f"{config.sequence.length} frames"
        settings["tracker"] = "on" if config.tracker.enabled else "off"
    if args.config:
        settings["config file"] = f"`{args.config.resolve()}`"
    settings["lostx"] = f"{__version__}, {time.strftime('%Y-%m-%d %H:%M')}"
    return settings


def _tag(value: float) -> str:
    return f"{value:g}".replace(".", "p")
