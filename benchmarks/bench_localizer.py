"""Time per frame of everything after the network, at map sizes up to 1,000,000 frames: with the map's
approximate index and with exact search, side by side in one run.

The map descriptors are LoST descriptors sampled around real ones: each is a real map frame's
normalised descriptor (``--real``, by default a LoST map of the Nordland summer frames, built once)
plus Gaussian noise, renormalised. A map is a chain of stretches of ``STRETCH`` consecutive real frames,
each starting at a random frame of the real route, so that neighbouring map frames look alike as on a
real traverse (what contrast normalisation and the sequence filter work on). Each stretch has its
descriptors' components in an order of its own, so that the stretches are different places, as the
streets of a city are, rather than copies of the same 3,576 (``--repeat-places`` keeps the copies: every
place then has about map size / 3,576 look-alikes, a worst case in which the filter never settles). The queries are map frames
plus as much noise again, their true place moving one map frame per step, so the sequence filter and
tracker run as on a real traverse.

Stages, per frame:

- search: the matcher's search (its ``verify.top_k`` candidates, ranked by exact distance) through
  the index (faiss HNSW over 8-bit codes, as a map stores it) and exactly; the index's Recall@10
  against exact on the same queries.
- verify: keypoint verification of the top ``verify.top_k`` on the real map (it reads only the k
  candidates' evidence, so the map's size does not change it).
- costs, sequence, tracker: ``Localizer.step`` on a map of this size, searching as the matcher does
  (index or exact) and scoring with the LoST distances of the sampled descriptors. With the index the
  costs are looked up where the sequence filter looks (``sequence.costs = "looked-up"``, as on a map of
  ``costs_min_frames`` or more); with exact search they are computed for every map frame, sharing the
  search's distances to every map frame. Both directions are searched (heading unknown, the tracker
  never settles: the most look-ups), and, for the costs, one direction too (a declared camera: the
  tracker follows the route).

"after the network" is descriptor + verify + the step's search, costs, sequence and tracker; memory per map
frame is the map's descriptors (float16), the index and the per-frame evidence of the real map; the saved state is
one stream's after the steps, packed as the service writes it beside its journal (none where costs are looked up).

    python benchmarks/bench_localizer.py [--sizes 1000 10000 100000 1000000] [--steps 200] [--real MAP] [--repeat-places]
                                         [--quick] [--out benchmarks/results/localizer.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import os
import resource
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common import parse, print_table, summary, time_call, write_json
from lostx.core import Config, Frame, Localizer, ReferenceMap
from lostx.core.decide.calibration import Calibration
from lostx.core.config import HeadingConfig, SearchConfig, SequenceConfig
from lostx.core.match.scores import MapScores
from lostx.core.maps.index import ApproximateIndex, build_index
from lostx.core.maps.mapwriter import MapFrame, MapWriter
from lostx.core.match.matcher import FrameMatch, MatchResult, PlaceMatcher
from lostx.core.paths import data_dir
from lostx.core.match.search import CandidateSearch, QueryDistances
from lostx.core.errors import StateError
from lostx.stream.states import pack

NOISE = 0.5
"""Noise per dimension, relative to a unit descriptor's typical component (1 / sqrt(K))."""
STRETCH = 1000
"""Consecutive real frames in each stretch of a sampled map."""
BLOCK = 64 * STRETCH
DEFAULT_REAL = Path.home() / ".cache" / "lostx-bench" / "nordland-summer-lost"
QUICK_REAL_FRAMES = 200
"""Nordland summer frames in a quick run's real map (the whole route's takes minutes to build)."""
FIXED_QUERIES = 50
"""Real query frames timed for the descriptor and verification (10 in a quick run)."""


def real_map(path: Path, frames: int | None = None) -> ReferenceMap:
    """The real LoST map the descriptors are sampled around: built from the Nordland summer frames (the first
    ``frames`` of them, where given) the first time it is asked for."""
    if not (path / "manifest.json").is_file():
        from lostx.core.build import build_map
        from lostx.replay.folder import folder_traverse

        path.parent.mkdir(parents=True, exist_ok=True)
        summer = folder_traverse(data_dir() / "nordland-64x32" / "summer")
        build_map(summer if frames is None else summer.subset(range(frames)), path, overwrite=True)
    return ReferenceMap.open(path)


def chosen_real(real: Path | None, quick: bool, scratch: Path) -> ReferenceMap:
    """``--real``; without it, the whole route's map (built once in ``DEFAULT_REAL``), or a quick run's own small
    one in ``scratch``."""
    if real is None and quick:
        return real_map(scratch / "real", QUICK_REAL_FRAMES)
    return real_map(real or DEFAULT_REAL)


def sampled(real: np.ndarray, rows: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Unit descriptors around ``real[rows]``."""
    out = real[rows] + rng.normal(0.0, NOISE / np.sqrt(real.shape[1]), (len(rows), real.shape[1])).astype(np.float32)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return out


@dataclass
class DescriptorMap:
    """What :class:`CandidateSearch` reads of a map: its descriptors and its index. As a map does, it
    compares every frame with float32 descriptors in memory and reads single rows of the float16 ones it
    stores (what a search through the index reads)."""

    descriptors: np.ndarray
    stored: np.ndarray
    index: ApproximateIndex | None
    path: Path
    kind: str = "lost"

    @property
    def n_frames(self) -> int:
        return len(self.descriptors)

    def descriptor_rows(self, indices: np.ndarray) -> np.ndarray:
        return np.asarray(self.stored[np.asarray(indices, dtype=np.int64)], dtype=np.float32)


def stretches(start: int, stop: int, n_real: int, rng: np.random.Generator) -> np.ndarray:
    """Real frames for map frames [start, stop): runs of ``STRETCH`` consecutive ones from random starts."""
    frames = np.arange(start, stop)
    first = rng.integers(0, n_real, (stop - 1) // STRETCH - start // STRETCH + 1)
    return (first[frames // STRETCH - start // STRETCH] + frames % STRETCH) % n_real


def lost_map(n: int, real: np.ndarray, folder: Path, rng: np.random.Generator, threads: int,
             repeat_places: bool = False) -> tuple[DescriptorMap, dict]:
    stored = np.empty((n, real.shape[1]), np.float16)
    for start in range(0, n, BLOCK):
        stop = min(n, start + BLOCK)
        block = sampled(real, stretches(start, stop, len(real), rng), rng)
        if not repeat_places:
            for first in range(start, stop, STRETCH):
                rows = slice(first - start, min(stop, first + STRETCH) - start)
                block[rows] = block[rows][:, rng.permutation(real.shape[1])]
        stored[start:stop] = block
    # As a map: float16 on disk, compared as float32 in memory when every frame is searched.
    descriptors = stored.astype(np.float32)
    t0 = time.perf_counter()
    info = build_index(stored, "lost", folder, threads=threads)
    built = time.perf_counter() - t0
    index = ApproximateIndex(folder / info.file, n)
    return DescriptorMap(descriptors, stored, index, folder), {"index_bytes": info.bytes, "index_build_s": built,
                                                      "index_build_threads": threads}


def search_stage(refs: DescriptorMap, config: Config, rng: np.random.Generator, queries: int) -> dict:
    """The matcher's search through the index and exactly, and the index's Recall@10 on the same queries."""
    count = config.verify.top_k
    indexed = CandidateSearch(refs, SearchConfig(index="on"))  # type: ignore[arg-type]
    exact = CandidateSearch(refs, SearchConfig(index="off"))  # type: ignore[arg-type]
    places = rng.integers(0, refs.n_frames, queries)
    vectors = sampled(refs.descriptors, places, rng)
    found = []
    for q in vectors:
        _, near = indexed.nearest(q, 10)
        _, truth = exact.nearest(q, 10)
        found.append(np.count_nonzero(near <= truth[-1] + 1e-6) / 10)
    it = iter(range(10**9))
    index_ms = time_call(lambda: indexed.nearest(vectors[next(it) % queries], count), queries)
    it = iter(range(10**9))
    exact_ms = time_call(lambda: exact.nearest(vectors[next(it) % queries], count), min(queries, 20))
    return {"index": summary(index_ms), "exact": summary(exact_ms), "recall_at_10": float(np.mean(found))}


class SyntheticAnswers:
    """Stands in for the matcher: the query at step t is map frame t plus noise; it is searched as the
    matcher searches (through the index or exactly), and its map scores are its exact LoST distances,
    sharing what the search computed (an exact search's distances to every map frame)."""

    def __init__(self, search: CandidateSearch, rng: np.random.Generator, nearest: int) -> None:
        """``nearest``: map frames the search returns (the seeds of a filter that looks its costs up)."""
        self.search, self.rng, self.t, self.nearest = search, rng, 0, nearest
        self.search_ms: list[float] = []
        self.last_evidence = None

    def match(self, image: np.ndarray, camera: str | None = None) -> FrameMatch:
        refs = self.search.map
        n = refs.n_frames
        place = self.t % n
        self.t += 1
        query = sampled(refs.descriptors, np.array([place]), self.rng)[0]
        start = time.perf_counter()
        distances = QueryDistances(self.search, query)
        nearest, near = self.search.nearest(query, max(10, self.nearest), None, distances)
        top, near = nearest[:10], near[:10]
        self.search_ms.append(1e3 * (time.perf_counter() - start))
        return FrameMatch.either(MatchResult(top, near, near, 1.0, map_scores=MapScores(distances, n), nearest=nearest,
                                             timings={"network": 0.0, "descriptor": 0.0, "search": 0.0,
                                                      "verify": 0.0}))

    def reset(self) -> None:
        self.t = 0

    def state(self) -> dict:
        """What the matcher adds to a stream's saved state: nothing here (a real matcher's query statistics are a
        few kB)."""
        return {}


# Any margin counts as sure: the tracker then runs as it does on a recognised route (a map's own
# calibration is not what is timed here).
SURE = Calibration(np.zeros(999), np.zeros(999), {})


def stub_map(out: Path, n: int) -> ReferenceMap:
    """A map of ``n`` frames for the localizer to hold (its own descriptors are never searched here)."""
    with MapWriter(out, "thumbnail", {"camera": "front", "thumbnail": {"size": [4, 2], "patch": 2}},
                   index=False) as writer:
        blank = np.zeros(8, np.uint8)
        for i in range(n):
            writer.add(MapFrame(f"{i:07d}", blank))
        writer.commit()
    return ReferenceMap.open(out)


def step_stages(refmap: ReferenceMap, refs: DescriptorMap, steps: int, one_direction: bool,
                index: bool) -> dict[str, list[float]]:
    heading = HeadingConfig(declared_prior=1.0) if one_direction else HeadingConfig()
    # The localizer's own matcher (on a stub map without an index) is replaced before it searches anything.
    # With the index, as on a city-scale map, the costs are looked up; with exact search, computed for every frame.
    config = Config(heading=heading, search=SearchConfig(index="off"),
                    sequence=SequenceConfig(costs="looked-up" if index else "every"))
    localizer = Localizer(refmap, config, calibration=SURE)
    answers = SyntheticAnswers(CandidateSearch(refs, SearchConfig(index="on" if index else "off")),  # type: ignore[arg-type]
                               np.random.default_rng(refs.n_frames), config.sequence.nearest if index else 10)
    localizer.matcher = answers  # type: ignore[assignment]
    # Declared and trusted, the heading is known and so is the direction of travel: one sign searched.
    frame = Frame(0, np.zeros((32, 64, 3), dtype=np.uint8), camera="front" if one_direction else None)
    stages: dict[str, list[float]] = {"costs": [], "sequence": [], "tracker": []}
    scores: list[float] = []
    for _ in range(steps):
        before = getattr(localizer.sequence.costs, "computed", 0)
        estimate = localizer.step(frame)
        for k in stages:
            stages[k].append(estimate.latency_ms[k])
        scores.append(getattr(localizer.sequence.costs, "computed", 0) - before)
    stages["search"] = answers.search_ms
    stages["state"] = [estimate.state == "localized"]  # type: ignore[list-item]
    try:
        stages["state_bytes"] = [len(pack(localizer.state()))]
    except StateError:  # costs looked up: the window's pasts are read through the index, not saved
        stages["state_bytes"] = []
    # Scores looked up (each a map row read, a descriptor distance) per step, once the window is full.
    stages["scores"] = scores[config.sequence.length:] or scores
    return stages


def network_free_stages(real: ReferenceMap, queries: int) -> dict:
    """Descriptor and verification times on the real map, from real query frames (the winter traverse)."""
    from lostx.core.backbones import load_backbone
    from lostx.replay.folder import folder_traverse

    matcher = PlaceMatcher(real, Config(search=SearchConfig(index="off")), load_backbone())
    winter = folder_traverse(data_dir() / "nordland-64x32" / "winter")
    descriptor, verify = [], []
    for frame in winter.subset(range(0, queries * 10, 10)):
        described = matcher.describe(frame)
        t = time.perf_counter()
        result = matcher.match_description(described)
        wall = time.perf_counter() - t
        descriptor.append(1e3 * described.timings["descriptor"])
        # Verification, ranking and the heading vote: all of the match but its search.
        verify.append(1e3 * (wall - result.same.timings["search"]))
    return {"descriptor": summary(descriptor), "verify": summary(verify)}


def run_size(n: int, real: np.ndarray, steps: int, queries: int, threads: int, repeat_places: bool) -> dict:
    rng = np.random.default_rng(n)
    with tempfile.TemporaryDirectory() as tmp:
        refs, built = lost_map(n, real, Path(tmp), rng, threads, repeat_places)
        search = search_stage(refs, Config(), rng, queries)
        refmap = stub_map(Path(tmp) / "map", n)
        one = step_stages(refmap, refs, steps, one_direction=True, index=True)
        both = step_stages(refmap, refs, steps, one_direction=False, index=True)
        exact = step_stages(refmap, refs, max(10, steps // 4), one_direction=False, index=False)
    return {
        "map_frames": n,
        **built,
        "index_bytes_per_frame": built["index_bytes"] / n,
        "search_index": search["index"],
        "search_exact": search["exact"],
        "exact_over_index": search["exact"]["median_ms"] / search["index"]["median_ms"],
        "recall_at_10": search["recall_at_10"],
        "costs": summary(both["costs"]),
        "costs_one_direction": summary(one["costs"]),
        "costs_after_exact_search": summary(exact["costs"]),
        "sequence": summary(both["sequence"]),
        "sequence_one_direction": summary(one["sequence"]),
        "step_index": summary([sum(v) for v in zip(*(both[k] for k in ("search", "costs", "sequence", "tracker")))]),
        "step_index_one_direction": summary([sum(v) for v in zip(*(one[k] for k in ("search", "costs", "sequence",
                                                                                    "tracker")))]),
        "step_exact": summary([sum(v) for v in zip(*(exact[k] for k in ("search", "costs", "sequence", "tracker")))]),
        "tracker": summary(both["tracker"]),
        "scores_per_frame": float(np.median(both["scores"])),
        "scores_per_frame_one_direction": float(np.median(one["scores"])),
        "localized_at_end": bool(both["state"][0]),
        "state_bytes_index": both["state_bytes"][0] if both["state_bytes"] else None,
        "state_bytes_exact": exact["state_bytes"][0] if exact["state_bytes"] else None,
    }


def report(args: argparse.Namespace, real: ReferenceMap) -> None:
    """Measures every stage at each map size around ``real``, prints the table and writes the JSON."""
    fixed = network_free_stages(real, 10 if args.quick else FIXED_QUERIES)
    per_frame_evidence = sum(int(e["bytes"]) for name, e in real.manifest["arrays"].items()
                             if name not in ("descriptors", "appearance")) / real.n_frames
    vectors = np.asarray(real.descriptors, dtype=np.float32)
    results = [run_size(n, vectors, args.steps, args.queries, args.build_threads, args.repeat_places)
               for n in args.sizes]
    fixed_ms = fixed["descriptor"]["median_ms"] + fixed["verify"]["median_ms"]
    rows = []
    for r in results:
        r["after_network_index_ms"] = fixed_ms + r["step_index"]["median_ms"]
        r["after_network_index_one_direction_ms"] = fixed_ms + r["step_index_one_direction"]["median_ms"]
        r["after_network_exact_ms"] = fixed_ms + r["step_exact"]["median_ms"]
        r["bytes_per_frame"] = 2 * vectors.shape[1] + r["index_bytes_per_frame"] + per_frame_evidence
        rows.append([r["map_frames"], r["search_index"]["median_ms"], r["search_exact"]["median_ms"],
                     r["exact_over_index"], r["recall_at_10"], r["costs"]["median_ms"],
                     r["costs_one_direction"]["median_ms"],
                     f'{r["scores_per_frame"]:.0f} / {r["scores_per_frame_one_direction"]:.0f}',
                     r["costs_after_exact_search"]["median_ms"], r["sequence"]["median_ms"],
                     r["sequence"]["p90_ms"], r["tracker"]["median_ms"], r["after_network_index_ms"],
                     r["after_network_index_one_direction_ms"],
                     r["after_network_exact_ms"], r["bytes_per_frame"] / 1e3, saved(r["state_bytes_index"]),
                     saved(r["state_bytes_exact"])])
    print(f"\ndescriptor {fixed['descriptor']['median_ms']:.3g} ms, verify {fixed['verify']['median_ms']:.3g} ms "
          f"(median, real Nordland map and queries; independent of the map's size)")
    print_table("Everything after the network, per frame (median ms; sequence p90 too)",
                ["map frames", "search (index)", "search (exact)", "exact / index", "index Recall@10", "costs",
                 "costs (one direction)", "rows read (both / one direction)", "costs (exact search)", "sequence",
                 "sequence p90", "tracker", "after network (index)", "after network (index, one direction)", "after network (exact)",
                 "kB per map frame", "saved state (index)", "saved state (exact)"], rows)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    write_json(args.out, {"benchmark": "localizer", "real_map": str(real.path), "noise": NOISE,
                          "stretch": STRETCH, "repeat_places": args.repeat_places,
                          "fixed_stages": fixed, "evidence_bytes_per_frame": per_frame_evidence,
                          "peak_rss_gb": peak, "sizes": results})


def saved(size: int | None) -> str:
    """A stream's saved state, or why there is none."""
    return "none (looked up)" if size is None else f"{size / 1e6:.2f} MB"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000, 1000000])
    parser.add_argument("--steps", type=int, default=200, help="localizer steps timed per map size")
    parser.add_argument("--queries", type=int, default=200, help="searches timed per map size")
    parser.add_argument("--real", type=Path, help="a LoST map to sample descriptors around (default: the Nordland "
                        f"summer frames', built once in {DEFAULT_REAL}; with --quick, their first {QUICK_REAL_FRAMES}'s, "
                        "in a temporary folder)")
    parser.add_argument("--build-threads", type=int, default=os.cpu_count() or 1,
                        help="threads building each index (a benchmark's graph need not be reproducible)")
    parser.add_argument("--repeat-places", action="store_true",
                        help="stretches that repeat the real route's places (a worst case) rather than places of their own")
    args = parse(parser, "localizer", quick=f"a 1,000-frame map around {QUICK_REAL_FRAMES} real frames, 20 steps "
                                            f"and searches, 10 real queries")
    if args.quick:
        args.sizes, args.steps, args.queries = [1000], 20, 20
    with tempfile.TemporaryDirectory() as scratch:
        report(args, chosen_real(args.real, args.quick, Path(scratch)))


if __name__ == "__main__":
    main()
