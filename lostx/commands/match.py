"""``lostx match MAP QUERY_DIR --out matches.csv``: match a folder of query images against a map."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lostx.core.errors import InputError, MapError
from lostx.core.estimate import Estimate
from lostx.core.localizer import Localizer
from lostx.core.refmap import ReferenceMap
from lostx.options import add_config_options, add_viewer_options, config_from_args, live_view, serve_until_interrupted
from lostx.replay.folder import folder_traverse

COLUMNS = ["query_index", "query_file", "match_index", "match_file", "score", "confidence", "candidates",
           "distance", "correspondences"]
SEQUENCE_COLUMNS = ["single_match_index", "state", "speed"]
HEADING_COLUMNS = ["heading", "heading_confidence"]


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("match", help="match a folder of query images against a reference map")
    parser.add_argument("map", type=Path, help="reference map folder (from `lostx map build`)")
    parser.add_argument("queries", type=Path, help="folder of query images, matched in name order")
    parser.add_argument("--out", type=Path, required=True, help="CSV file to write, one row per query")
    parser.add_argument("--opposite", action="store_true", help="the query camera faces opposite to the map's")
    parser.add_argument("--sequence", action="store_true",
                        help="answer with the online sequence filter and tracker (frames in name order)")
    parser.add_argument("--mirror", action="store_true",
                        help="flip the query images left-right first (tests the flip handling; not an opposite view)")
    parser.add_argument("--descriptor", choices=["lost", "thumbnail"],
                        help="check that the map holds this descriptor (default: whatever it holds)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_config_options(parser)
    add_viewer_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    config = dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, enabled=args.sequence))
    refmap = ReferenceMap.open(args.map)
    if args.descriptor and args.descriptor != refmap.kind:
        raise InputError(f"{args.map} is a {refmap.kind} map, not {args.descriptor}")
    built_with = (refmap.backbone or {}).get("name")
    if args.backbone and refmap.kind == "lost" and args.backbone != built_with:
        # Without --backbone the matcher takes the map's own; a different one named explicitly is a mistake.
        raise MapError(f"{args.map} was built with backbone {built_with}, but --backbone asks for {args.backbone}; "
                       f"use --backbone {built_with} (or leave it out) or rebuild the map")
    camera = {"front": "rear", "rear": "front"}[refmap.camera] if args.opposite else None
    queries = folder_traverse(args.queries, camera=camera, mirror=args.mirror)  # type: ignore[arg-type]
    localizer = Localizer(refmap, config)
    with live_view(args, refmap) as sink:
        start = time.perf_counter()
        rows, estimates = [], []
        for frame in tqdm(queries, total=len(queries), desc="matching", unit="frame", disable=args.quiet, leave=False):
            estimate = localizer.step(frame)
            if sink is not None:
                sink(frame, estimate)
            estimates.append(estimate)
            rows.append(csv_row(frame.name, estimate, refmap, args.sequence))
        elapsed = time.perf_counter() - start
        write_csv(args.out, COLUMNS + (SEQUENCE_COLUMNS if args.sequence else []) + HEADING_COLUMNS, rows)
        print(summary_line(estimates, elapsed, args.out), flush=True)
        # The results are written: the web viewer may stay up as long as the user likes.
        serve_until_interrupted(sink)
    return 0


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
    if sequence:
        row["single_match_index"] = estimate.single_match_index
        row["state"] = estimate.state
        row["speed"] = "" if estimate.speed is None else f"{estimate.speed:.3f}"
    return row


def write_csv(path: Path, columns: list[str], rows: list[dict[str, object]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    with open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(path)


def summary_line(estimates: list[Estimate], elapsed: float, out: Path) -> str:
    stages = {k: float(np.mean([e.latency_ms.get(k, 0.0) for e in estimates])) for k in estimates[0].latency_ms}
    detail = ", ".join(f"{k} {v:.1f}" for k, v in stages.items() if k != "total")
    localized = sum(e.state == "localized" for e in estimates)
    return (f"matched {len(estimates)} queries in {elapsed:.1f} s ({1e3 * elapsed / len(estimates):.0f} ms per frame; "
            f"{detail} ms); {localized} localized; wrote {out}")
