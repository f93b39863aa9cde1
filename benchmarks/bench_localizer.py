"""Time per Localizer.step, excluding the network, at map sizes 1k, 10k and 100k (issue 3).

The maps are thumbnail maps of synthetic descriptors (the size is what
matters here: a 100k-frame LoST map would be 4.7 GB on disk), queried with
real-sized thumbnails whose true place moves one reference per frame, so the
sequence filter and tracker run as they do on a real traverse. The LoST
candidate search (cosine over 1344-dim descriptors) is timed on its own at the
same sizes. Stages: search (single-frame, grows with the map, as any
exhaustive search does), costs (normalising the frame's cost for every
reference: also O(map size)), sequence (the trajectory update: must not grow),
tracker. The sequence update is timed twice: searching both directions of
travel (the default when the query camera is not declared) and one (a declared
camera whose heading is known), to show what the second hypothesis costs.

    python benchmarks/bench_localizer.py [--sizes 1000 10000 100000] [--steps 200]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import tempfile
from pathlib import Path

import numpy as np

from common import RESULTS, print_table, summary, time_call, write_json
from lostx.core import Config, Frame, Localizer, ReferenceMap
from lostx.core.calibration import Calibration
from lostx.core.config import HeadingConfig
from lostx.core.matcher import FrameMatch, MatchResult
from lostx.core.mapwriter import MapFrame, MapWriter
from lostx.core.search import cosine_distances, sad_distances, top_k


def thumbnail_map(out: Path, n: int, rng: np.random.Generator) -> tuple[ReferenceMap, np.ndarray]:
    descriptors = rng.integers(124, 133, (n, 2048)).astype(np.uint8)
    with MapWriter(out, "thumbnail", {"camera": "front", "thumbnail": {"size": [64, 32], "patch": 8}}) as writer:
        for i in range(n):
            writer.add(MapFrame(f"{i:06d}", descriptors[i]))
        writer.commit()
    return ReferenceMap.open(out), descriptors


class SyntheticQueries:
    """Stands in for the describing step only: the query at step t is reference t plus noise."""

    def __init__(self, refs: np.ndarray, rng: np.random.Generator) -> None:
        self.refs, self.rng, self.t = refs, rng, 0
        self.last_evidence = None

    def match(self, image: np.ndarray) -> FrameMatch:
        noise = self.rng.integers(-2, 3, self.refs.shape[1])
        query = np.clip(self.refs[self.t % len(self.refs)].astype(np.int16) + noise, 0, 255).astype(np.uint8)
        self.t += 1
        distances = sad_distances(query, self.refs)
        order = top_k(distances, 10)
        return FrameMatch.either(MatchResult(order, distances[order], distances[order], 1.0, map_scores=distances,
                                             timings={"network": 0.0, "descriptor": 0.0, "search": 0.0,
                                                      "verify": 0.0}))

    def reset(self) -> None:
        self.t = 0


# Any margin counts as sure: the tracker then runs as it does on a recognised route (a map's own
# calibration is not what is timed here).
SURE = Calibration(np.zeros(999), np.zeros(999), {})


def timed_steps(refmap: ReferenceMap, refs: np.ndarray, n: int, steps: int, one_direction: bool) -> tuple[dict, list, str]:
    config = Config(heading=HeadingConfig(declared_prior=1.0)) if one_direction else Config()
    localizer = Localizer(refmap, config, calibration=SURE)
    localizer.matcher = SyntheticQueries(refs, np.random.default_rng(n))  # type: ignore[assignment]
    # Declared and trusted, the heading is known and so is the direction of travel: one sign searched.
    frame = Frame(0, np.zeros((32, 64, 3), dtype=np.uint8), camera="front" if one_direction else None)
    stages: dict[str, list[float]] = {"costs": [], "sequence": [], "tracker": []}
    totals = []
    for _ in range(steps):
        estimate = localizer.step(frame)
        for k in stages:
            stages[k].append(estimate.latency_ms[k])
        totals.append(estimate.latency_ms["total"])
    return stages, totals, estimate.state


def run_size(n: int, steps: int) -> dict:
    rng = np.random.default_rng(n)
    with tempfile.TemporaryDirectory() as tmp:
        refmap, refs = thumbnail_map(Path(tmp) / "map", n, rng)
        queries = SyntheticQueries(refs, rng)
        search = time_call(lambda: queries.match(np.zeros((32, 64, 3), dtype=np.uint8)), 20)
        one, _, _ = timed_steps(refmap, refs, n, steps, one_direction=True)
        stages, totals, localized = timed_steps(refmap, refs, n, steps, one_direction=False)
    lost_refs = np.random.default_rng(1).normal(size=(n, 1344)).astype(np.float32)
    lost_query = lost_refs[0]
    lost_search = time_call(lambda: top_k(cosine_distances(lost_query, lost_refs), 10), 20)
    return {
        "map_frames": n,
        "thumbnail_search": summary(search),
        "lost_search": summary(lost_search),
        "costs": summary(stages["costs"]),
        "sequence": summary(stages["sequence"]),
        "sequence_one_direction": summary(one["sequence"]),
        "tracker": summary(stages["tracker"]),
        "step_total": summary(totals),
        "last_state": localized,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--steps", type=int, default=200, help="steps timed per map size")
    parser.add_argument("--out", type=Path, default=RESULTS / "localizer.json")
    args = parser.parse_args()
    results = [run_size(n, args.steps) for n in args.sizes]
    rows = [[r["map_frames"], r["lost_search"]["median_ms"], r["thumbnail_search"]["median_ms"],
             r["costs"]["median_ms"], r["sequence"]["median_ms"], r["sequence"]["p90_ms"],
             r["sequence_one_direction"]["median_ms"], r["tracker"]["median_ms"],
             r["step_total"]["median_ms"]] for r in results]
    print_table("Localizer.step without the network (median ms; sequence p90 too)",
                ["map frames", "LoST search", "thumbnail search", "costs", "sequence (both directions)",
                 "sequence p90", "sequence (one direction)", "tracker", "step (thumbnails)"], rows)
    write_json(args.out, {"benchmark": "localizer", "sizes": results})


if __name__ == "__main__":
    main()
