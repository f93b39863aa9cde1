"""``lostx match MAP QUERY_DIR --out matches.csv``: match a folder of query images against a map."""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lostx.core.errors import InputError
from lostx.core.matcher import MatchResult, PlaceMatcher
from lostx.core.refmap import ReferenceMap
from lostx.options import add_config_options, config_from_args
from lostx.replay.folder import folder_traverse

COLUMNS = ["query_index", "query_file", "match_index", "match_file", "score", "confidence", "candidates",
           "distance", "correspondences"]


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("match", help="match a folder of query images against a reference map")
    parser.add_argument("map", type=Path, help="reference map folder (from `lostx map build`)")
    parser.add_argument("queries", type=Path, help="folder of query images, matched in name order")
    parser.add_argument("--out", type=Path, required=True, help="CSV file to write, one row per query")
    parser.add_argument("--opposite", action="store_true", help="the query camera faces opposite to the map's")
    parser.add_argument("--mirror", action="store_true",
                        help="flip the query images left-right first (tests the flip handling; not an opposite view)")
    parser.add_argument("--descriptor", choices=["lost", "thumbnail"],
                        help="check that the map holds this descriptor (default: whatever it holds)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_config_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    refmap = ReferenceMap.open(args.map)
    if args.descriptor and args.descriptor != refmap.kind:
        raise InputError(f"{args.map} is a {refmap.kind} map, not {args.descriptor}")
    queries = folder_traverse(args.queries, mirror=args.mirror)
    matcher = PlaceMatcher(refmap, config)
    start = time.perf_counter()
    rows, results = [], []
    for frame in tqdm(queries, total=len(queries), desc="matching", unit="frame", disable=args.quiet, leave=False):
        result = matcher.match(frame.image, opposite=args.opposite)
        results.append(result)
        rows.append(csv_row(frame.id, frame.name, result, refmap))
    elapsed = time.perf_counter() - start
    write_csv(args.out, COLUMNS, rows)
    print(summary_line(results, elapsed, args.out))
    return 0


def csv_row(index: int, name: str, result: MatchResult, refmap: ReferenceMap) -> dict[str, object]:
    return {
        "query_index": index,
        "query_file": name,
        "match_index": result.best,
        "match_file": refmap.names[result.best],
        "score": f"{result.score:.6g}",
        "confidence": f"{result.confidence:.4f}",
        "candidates": " ".join(str(int(c)) for c in result.candidates),
        "distance": f"{float(result.distances[0]):.6g}",
        "correspondences": int(result.n_matches[0]) if result.n_matches is not None else "",
    }


def write_csv(path: Path, columns: list[str], rows: list[dict[str, object]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    with open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(path)


def summary_line(results: list[MatchResult], elapsed: float, out: Path) -> str:
    stages = {k: 1e3 * float(np.mean([r.timings.get(k, 0.0) for r in results])) for k in results[0].timings}
    detail = ", ".join(f"{k} {v:.1f}" for k, v in stages.items())
    return (f"matched {len(results)} queries in {elapsed:.1f} s ({1e3 * elapsed / len(results):.0f} ms per frame; "
            f"{detail} ms); wrote {out}")


