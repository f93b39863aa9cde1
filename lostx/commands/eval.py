"""``lostx eval --reference SOURCE --query SOURCE --out REPORT_DIR``: several methods, their metrics, plots, a table."""

from __future__ import annotations

import argparse
from pathlib import Path

from lostx.evaluation.methods import METHODS, MODES, evaluate_pair
from lostx.options import add_config_options, add_source_options, config_from_args, print_notes, source_options_from_args
from lostx.evaluation.datasets import FORMATS, open_pair
from lostx.evaluation.report import (
    markdown_table,
    plot_max_f1_vs_tolerance,
    plot_pr_curves,
    report_entry,
    write_markdown,
    write_report_json,
)


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("eval", help="evaluate LoST-X and baselines on a reference/query pair")
    parser.add_argument("--reference", type=Path, required=True,
                        help="reference traverse (the map): a folder, a RobotCar folder, a bag, a video, a nuScenes "
                             "scene, or a VPR-Bench dataset (see docs/datasets.md)")
    parser.add_argument("--query", type=Path, help="query traverse (not for a VPR-Bench folder)")
    parser.add_argument("--format", choices=FORMATS, help="dataset layout (default: recognised from the paths)")
    parser.add_argument("--out", type=Path, required=True, help="report folder to write")
    camera = parser.add_mutually_exclusive_group()
    camera.add_argument("--query-camera", choices=["front", "rear"],
                        help="declare the query camera's direction (default: as the source declares it)")
    camera.add_argument("--opposite", action="store_true", help="the query camera faces opposite to the reference's")
    parser.add_argument("--mirror-query", action="store_true",
                        help="flip the query images left-right (a test of the flip handling, not an opposite view)")
    parser.add_argument("--reference-positions", type=Path, help="positions CSV of the reference images")
    parser.add_argument("--query-positions", type=Path, help="positions CSV of the query images")
    parser.add_argument("--spacing", type=float, help="keep one frame every SPACING metres travelled (the paper: 2)")
    parser.add_argument("--tolerances", type=float, nargs="+",
                        help="ground-truth tolerances (default: 0 1 2 frames, or 5 10 20 40 80 m with positions)")
    parser.add_argument("--unit", choices=["frames", "m"], help="unit of the tolerances (default: m with positions)")
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    parser.add_argument("--modes", nargs="+", choices=list(MODES), default=list(MODES))
    parser.add_argument("--cache", type=Path, help="cache of network outputs (default: REPORT_DIR/cache)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_source_options(parser, format=False, reverse=True)
    add_config_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    pair = open_pair(
        args.reference, args.query, args.format,
        query_camera="rear" if args.opposite else args.query_camera,
        reference_positions=args.reference_positions, query_positions=args.query_positions,
        mirror_query=args.mirror_query, spacing=args.spacing,
        options=source_options_from_args(args), reverse_query=args.reverse,
    )
    print_notes(pair.notes)
    runs, truths = evaluate_pair(pair, config, args.cache or args.out / "cache", args.methods, args.modes,
                                 args.tolerances, args.unit, progress=not args.quiet)
    entries = [report_entry(r.method, r.mode, e, label=METHODS[r.method]) for r in runs for e in r.evaluations]
    args.out.mkdir(parents=True, exist_ok=True)
    title = f"{pair.reference.name} (reference) vs {pair.query.name} (query)"
    if args.mirror_query:
        title += ", query images mirrored (not an opposite-direction traverse)"
    write_report_json(args.out / "report.json", entries)
    write_markdown(args.out / "report.md", entries, title)
    unit = truths[0].unit
    for k, truth in enumerate(truths):
        plot_pr_curves([(r.label, r.evaluations[k].curve) for r in runs], args.out / f"pr_{_tag(truth.tolerance)}{unit}.png",
                       f"{title}\nprecision-recall at a tolerance of {_quantity(truth.tolerance, unit)}")
    plot_max_f1_vs_tolerance([(r.label, r.evaluations) for r in runs], args.out / "max_f1_vs_tolerance.png",
                             f"{title}\nmax F1 against the localization tolerance")
    print(markdown_table(entries))
    print(f"wrote {args.out / 'report.json'}, report.md and {len(truths) + 1} figures")
    return 0


def _quantity(value: float, unit: str) -> str:
    return f"{value:g} {'frame' if unit == 'frames' and value == 1 else unit}"


def _tag(value: float) -> str:
    return f"{value:g}".replace(".", "p")
