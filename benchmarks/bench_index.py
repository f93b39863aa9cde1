"""Approximate search of LoST descriptors: faiss (as lostx builds it) against usearch and exact search.

The map descriptors are sampled around real ones, as in bench_localizer.py; the queries are map frames
plus as much noise again. Both graph indices are HNSW with the same shape (32 neighbours, a candidate
list of 80 while building, 64 while searching) and 8-bit codes, built and searched on one thread:

- faiss ``IndexHNSWSQ`` with a scalar quantiser trained per dimension (lostx.core.maps.index);
- usearch ``Index`` with ``i8`` scalars (its fixed range: a component times 127);
- exact: every map frame compared (lostx.core.match.search).

Reported: Recall@10 of the index's own top 10 against exact search, and of lostx's search (the
index's shortlist ranked again by exact distance); ms per query; build seconds; bytes per frame.
usearch is optional: without it its row says it was not measured.

    python benchmarks/bench_index.py [--size 100000] [--queries 200] [--real MAP] [--quick] [--out benchmarks/results/index.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from bench_localizer import BLOCK, QUICK_REAL_FRAMES, DescriptorMap, chosen_real, sampled
from common import parse, print_table, summary, write_json
from lostx.core.config import SearchConfig
from lostx.core.maps.index import BUILD_BREADTH, NEIGHBOURS, ApproximateIndex, build_index
from lostx.core.match.search import CandidateSearch

K = 10
BREADTH = 64


def recall(found: list[np.ndarray], truth: list[np.ndarray], distance: Callable[[int, np.ndarray], np.ndarray]) -> float:
    """Mean fraction of the exact 10 nearest found (a frame at the 10th exact distance or nearer counts)."""
    hits = [np.count_nonzero(distance(i, f) <= distance(i, t)[-1] + 1e-6) / K for i, (f, t) in enumerate(zip(found, truth))]
    return float(np.mean(hits))


def timed(fn: Callable[[np.ndarray], np.ndarray], queries: np.ndarray) -> tuple[list[np.ndarray], list[float]]:
    found, ms = [], []
    for q in queries:
        t = time.perf_counter()
        found.append(fn(q))
        ms.append(1e3 * (time.perf_counter() - t))
    return found, ms


def usearch_row(descriptors: np.ndarray, queries: np.ndarray, folder: Path) -> dict | None:
    try:
        from usearch.index import Index
    except ImportError:
        return None
    index = Index(ndim=descriptors.shape[1], metric="ip", dtype="i8", connectivity=NEIGHBOURS,
                  expansion_add=BUILD_BREADTH, expansion_search=BREADTH)
    t = time.perf_counter()
    index.add(np.arange(len(descriptors)), descriptors, threads=1)
    built = time.perf_counter() - t
    path = folder / "usearch.index"
    index.save(str(path))
    found, ms = timed(lambda q: np.asarray(index.search(q, K, threads=1).keys, dtype=np.int64), queries)
    return {"found": found, "ms": ms, "build_s": built, "bytes": path.stat().st_size}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=100000)
    parser.add_argument("--queries", type=int, default=200)
    parser.add_argument("--real", type=Path, help="a LoST map to sample descriptors around (default: as "
                                                  "bench_localizer.py's)")
    args = parse(parser, "index", quick=f"2,000 descriptors around {QUICK_REAL_FRAMES} real frames, 20 queries")
    if args.quick:
        args.size, args.queries = 2000, 20
    with tempfile.TemporaryDirectory() as scratch:
        real = np.array(chosen_real(args.real, args.quick, Path(scratch)).descriptors, dtype=np.float32)
    rng = np.random.default_rng(args.size)
    descriptors = np.empty((args.size, real.shape[1]), np.float32)
    for start in range(0, args.size, BLOCK):
        stop = min(args.size, start + BLOCK)
        descriptors[start:stop] = sampled(real, rng.integers(0, len(real), stop - start), rng)
    queries = sampled(descriptors, rng.integers(0, args.size, args.queries), rng)
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        stored = descriptors.astype(np.float16)  # as a map stores them: what a search through the index re-ranks
        t = time.perf_counter()
        info = build_index(stored, "lost", folder)
        built = time.perf_counter() - t
        faiss_index = ApproximateIndex(folder / info.file, args.size)
        refs = DescriptorMap(descriptors, stored, faiss_index, folder)
        exact = CandidateSearch(refs, SearchConfig(index="off"))  # type: ignore[arg-type]
        lostx_search = CandidateSearch(refs, SearchConfig(index="on"))  # type: ignore[arg-type]
        truth, exact_ms = timed(lambda q: exact.nearest(q, K)[0], queries)
        rows["exact"] = {"found": truth, "ms": exact_ms, "build_s": 0.0, "bytes": descriptors.nbytes // 2}
        found, ms = timed(lambda q: faiss_index.search(q, K, BREADTH), queries)
        rows["faiss HNSW SQ8"] = {"found": found, "ms": ms, "build_s": built, "bytes": info.bytes}
        found, ms = timed(lambda q: lostx_search.nearest(q, K)[0], queries)
        rows["faiss + exact re-rank (lostx)"] = {"found": found, "ms": ms, "build_s": built, "bytes": info.bytes}
        rows["usearch HNSW i8"] = usearch_row(descriptors, queries, folder)  # type: ignore[assignment]

    def distance(i: int, ids: np.ndarray) -> np.ndarray:
        return exact.distances(queries[i], ids)

    table, results = [], {}
    for name, row in rows.items():
        if row is None:
            table.append([name, "not installed: not measured", "", "", ""])
            results[name] = None
            continue
        r = recall(row["found"], truth, distance)
        results[name] = {"recall_at_10": r, "query": summary(row["ms"]), "build_s": row["build_s"],
                         "bytes_per_frame": row["bytes"] / args.size}
        table.append([name, r, results[name]["query"]["median_ms"], row["build_s"], row["bytes"] / args.size])
    print_table(f"{args.size} LoST descriptors (K = {real.shape[1]}), {args.queries} queries, one thread",
                ["search", "Recall@10", "ms per query (median)", "build s", "bytes per frame"], table)
    write_json(args.out, {"benchmark": "index", "size": args.size, "queries": args.queries, "breadth": BREADTH,
                          "neighbours": NEIGHBOURS, "build_breadth": BUILD_BREADTH, "results": results})


if __name__ == "__main__":
    main()
