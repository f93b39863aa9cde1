"""What follows the network for wide and dense features: 320, 960 and 2048 channels on a 32 x 32 grid.

Per query frame: the LoST descriptor, the keypoints (projected where the map's are), the candidate search over a 1,000-frame
map's global descriptors, reading the 10 candidates' keypoint evidence from a map on disk, and
verifying them (both headings); and the map's bytes per frame. Features are synthetic, of two kinds:

* dense: signed values everywhere (a linear projection's output) and every channel's keypoint on
  its own cell (every cell a keypoint where there are at least 1,024 channels);
* sparse: ReLU-like, 9 % of the values non-zero, the keypoints on a quarter of the cells (what
  MOSAIC's features look like).

Map frames are noisy copies of one scene (so most correspondences pass the label test: the
worst case for verification). Each kind is measured with the keypoint descriptors kept whole and,
where the defaults reduce them (more than 512 channels), reduced to 64 dimensions by the map's own
projection.

    python benchmarks/bench_verify.py [--repeat 30] [--quick] [--out benchmarks/results/verify.json]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)
import numpy as np
from common import parse, print_table, summary, time_call, write_json

from lostx.core.backbones import BackboneInfo
from lostx.core.config import VerifyConfig
from lostx.core.describe.keypoints import frame_evidence
from lostx.core.describe.lost import class_means, l2_normalise, lost_descriptor
from lostx.core.describe.reduce import reduced_dims
from lostx.core.maps.mapwriter import MapFrame, MapWriter
from lostx.core.maps.refmap import ReferenceMap
from lostx.core.match.search import cosine_distances, top_k
from lostx.core.match.verify import verify

GRID = (32, 32)
GROUPS = 3
MAP_FRAMES = 1000
CANDIDATES = 10
LABEL_P = np.array([0.35, 0.3, 0.25, 0.1])  # road, building, vegetation, the rest


def scene(d: int, dense: bool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(D, h, w) features and (h, w) grouped labels of one synthetic frame."""
    n = GRID[0] * GRID[1]
    if dense:
        features = rng.normal(0.0, 1.0, (d, n)).astype(np.float32)
        peaks = np.arange(d) % n
    else:
        features = (rng.random((d, n), dtype=np.float32) * (rng.random((d, n)) < 0.09)).astype(np.float32)
        peaks = rng.choice(rng.choice(n, n // 4, replace=False), d)
    features[np.arange(d), peaks] += 6.0
    labels = rng.choice(len(LABEL_P), n, p=LABEL_P).astype(np.uint8)
    return features.reshape(d, *GRID), labels.reshape(GRID)


def noisy(features: np.ndarray, labels: np.ndarray, dense: bool, rng: np.random.Generator):
    """A map frame of the same place: the features jittered, a tenth of the labels changed."""
    jitter = rng.normal(0.0, 0.3, features.shape).astype(np.float32)
    out = features + jitter if dense else np.maximum(features + jitter * (features > 0), 0.0)
    flip = rng.random(labels.shape) < 0.1
    return out.astype(np.float32), np.where(flip, rng.choice(len(LABEL_P), labels.shape), labels).astype(np.uint8)


def measure(d: int, dense: bool, reduced: bool, repeat: int, tmp: Path) -> dict:
    rng = np.random.default_rng(d + dense)
    features, labels = scene(d, dense, rng)
    flat, n = features.reshape(d, -1), GRID[0] * GRID[1]
    probs = np.full((GROUPS, n), 0.1, dtype=np.float32)
    probs[np.minimum(labels.ravel(), GROUPS - 1), np.arange(n)] = 0.8
    out = tmp / f"map-{d}-{dense}-{reduced}"
    verify_config = VerifyConfig() if reduced else VerifyConfig(reduce_above=4096)
    info = BackboneInfo(f"synthetic-{d}", "none", "0", d, GRID, ("road", "building", "vegetation", "other"), {})
    with MapWriter(out, "lost", {"camera": "front"}, backbone=info, index=False, verify=verify_config) as writer:
        for i in range(CANDIDATES + 2):
            f, lab = noisy(features, labels, dense, rng)
            writer.add(MapFrame(f"{i:04d}.png", rng.normal(0, 1, GROUPS * d).astype(np.float32),
                                frame_evidence(f, lab)))
        writer.commit()
    refmap = ReferenceMap.open(out)
    descriptors = l2_normalise(rng.normal(0, 1, (MAP_FRAMES, GROUPS * d)).astype(np.float32))
    query_vector = descriptors[7] + rng.normal(0, 0.01, GROUPS * d).astype(np.float32)
    query = frame_evidence(*noisy(features, labels, dense, rng))
    shortlist = np.arange(CANDIDATES)

    def descriptor() -> None:
        lost_descriptor(flat, probs, class_means(flat, labels.ravel(), GROUPS)[0])

    def keypoints() -> None:
        refmap.query_evidence(frame_evidence(features, labels))

    def search() -> None:
        top_k(cosine_distances(query_vector, descriptors), CANDIDATES)

    projected = refmap.query_evidence(query)
    refs = refmap.evidence(shortlist)
    calls = {
        "LoST descriptor": descriptor,
        "keypoints, projected": keypoints,
        "search, 1,000 frames": search,
        "map evidence, 10 frames": lambda: refmap.evidence(shortlist),
        "verify 10, both headings": lambda: verify(projected, refs, np.full(CANDIDATES, 0.5)),
    }
    stages = {}
    for name, call in calls.items():
        samples = time_call(call, repeat)
        stages[name] = {**summary(samples), "fastest_ms": min(samples)}
    # Per frame: the keypoint evidence and the descriptor (not the map's one projection and statistics).
    evidence_bytes = sum(e["bytes"] for name, e in refmap.manifest["arrays"].items()
                         if name not in ("descriptors", "stats_mean", "stats_std", "projection"))
    return {"channels": d, "features": "dense" if dense else "sparse", "reduced": reduced,
            "dims_compared": projected.dims, "slots_per_frame": len(query.slot_keys),
            "pairs_verified": int(verify(projected, refs, np.full(CANDIDATES, 0.5)).n_consistent.sum()),
            "stages": stages, "total_median_ms": sum(s["median_ms"] for s in stages.values()),
            "total_fastest_ms": sum(s["fastest_ms"] for s in stages.values()),
            "map_bytes_per_frame": evidence_bytes / refmap.n_frames + 2 * GROUPS * d}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=30, help="timed calls per stage")
    args = parse(parser, "verify", quick="960 channels only (whole and reduced), 3 timed calls per stage")
    channels = (320, 960, 2048)
    if args.quick:
        channels, args.repeat = (960,), 3
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for d in channels:
            for dense in (True, False):
                for reduced in (False, True) if reduced_dims(VerifyConfig(), d) else (False,):
                    results.append(measure(d, dense, reduced, args.repeat, Path(tmp)))
    rows = [[r["channels"], r["features"], r["dims_compared"], r["slots_per_frame"], r["pairs_verified"],
             *(s["fastest_ms"] for s in r["stages"].values()), r["total_fastest_ms"], r["total_median_ms"],
             f"{r['map_bytes_per_frame'] / 1e3:.1f}"] for r in results]
    print_table(f"after the network, ms per query frame, fastest of {args.repeat} calls (the machine is shared; "
                f"medians in the JSON) ({MAP_FRAMES:,}-frame map, {CANDIDATES} candidates, {GRID[0]} x {GRID[1]} grid)",
                ["channels", "features", "dims", "slots", "pairs", "LoST", "keypoints", "search", "read",
                 "verify", "total", "total, median", "map kB/frame"], rows)
    write_json(args.out, {"benchmark": "verify", "map_frames": MAP_FRAMES, "candidates": CANDIDATES,
                          "grid": list(GRID), "results": results})


if __name__ == "__main__":
    main()
