"""Per-stage time per frame and map bytes per reference frame (issue 2).

Stages: network, LoST descriptor, candidate search, verification of the top 10.
Run against a 1,000-frame map made of the ten real RobotCar day frames'
evidence (cycled, with jittered descriptors so the search is not degenerate),
queried with the real night frames; and, for a like-for-like comparison with
the authors' released code, the descriptor and verification stages on synthetic
tensors of their shapes (2048 channels on a 20 x 31 grid, 20 classes).

    python benchmarks/bench_core.py [--frames 1000] [--repeat 50] [--quick] [--out benchmarks/results/core.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import tempfile
from pathlib import Path

import numpy as np

from common import parse, print_table, summary, time_call, write_json
from lostx.core import Config, Frame, Localizer, LostDescriber, ReferenceMap, load_backbone
from lostx.core.describe.keypoints import KeypointEvidence, frame_evidence
from lostx.core.describe.lost import class_means, lost_descriptor
from lostx.core.paths import data_dir
from lostx.core.maps.mapwriter import MapFrame, MapWriter
from lostx.core.match.verify import score_pairs, verify
from lostx.replay.folder import folder_traverse


def build_cycled_map(out: Path, describer: LostDescriber, frames: int, rng: np.random.Generator) -> ReferenceMap:
    day = folder_traverse(data_dir() / "robotcar-daynight" / "day")
    described = [describer(f.image) for f in day]
    with MapWriter(out, "lost", {"camera": "front", "classes": describer.groups.spec(),
                                 "label_names": list(describer.groups.label_names)},
                   backbone=describer.backbone.info) as writer:
        for i in range(frames):
            d = described[i % len(described)]
            desc = describer.descriptor(d, d.means) + rng.normal(0, 0.01, d.means.size).astype(np.float32)
            writer.add(MapFrame(f"{i:06d}.png", desc, d.evidence, d.appearance()))
        writer.commit()
    return ReferenceMap.open(out)


def real_stages(frames: int, repeat: int) -> tuple[list[list], dict]:
    """Every stage of Localizer.step on real night frames against a ``frames``-frame map: the network, then
    what follows it (both headings verified, trajectories of both directions of travel searched)."""
    rng = np.random.default_rng(0)
    backbone = load_backbone()
    describer = LostDescriber(backbone)
    with tempfile.TemporaryDirectory() as tmp:
        refmap = build_cycled_map(Path(tmp) / "map", describer, frames, rng)
        night = [f.image for f in folder_traverse(data_dir() / "robotcar-daynight" / "night")]
        names = ("network", "descriptor", "search", "verify", "costs", "sequence", "tracker")
        stage_samples: dict[str, list[float]] = {k: [] for k in names + ("after the network",)}
        localizer = Localizer(refmap, Config(), backbone)
        mirror_ms: list[float] = []
        for t in range(max(1, repeat // len(night)) * len(night)):
            estimate = localizer.step(Frame(t, night[t % len(night)], timestamp=float(t)))
            for k in names:
                stage_samples[k].append(estimate.latency_ms[k])
            stage_samples["after the network"].append(estimate.latency_ms["total"] - estimate.latency_ms["network"])
            mirror_ms.append(_other_mirroring_ms(sum(c.correspondences for c in estimate.candidates)))
        per_frame = refmap.nbytes / refmap.n_frames
    stats = {k: summary(v) for k, v in stage_samples.items()}
    stats["verify: the other mirroring"] = summary(mirror_ms)
    rows = [[k, stats[k]["median_ms"], stats[k]["p90_ms"]] for k in stats]
    after = stats["after the network"]["median_ms"]
    return rows, {"map_frames": frames, "stages": stats, "after_network_median_ms": after,
                  "map_bytes_per_frame": per_frame}


def _other_mirroring_ms(pairs: int) -> float:
    """What scoring the second heading hypothesis adds to a verification: one more Eq. 4 sum over the same
    ``pairs`` surviving correspondences (keypoints, labels, the density test and the similarities are shared)."""
    rng = np.random.default_rng(pairs)
    group = np.sort(rng.integers(0, 10, pairs))
    similarity, p_query, p_ref = rng.random(pairs), rng.random(pairs), rng.random(pairs)
    return time_call(lambda: score_pairs("eq4-lost", group, similarity, p_query, p_ref, np.full(10, 0.5)), 5,
                     warmup=1)[2]

def paper_shaped(repeat: int) -> tuple[list[list], dict]:
    """Our descriptor and verification on synthetic tensors of the authors' shapes.

    The synthetic features follow what the real MOSAIC features show: 9 % of
    the values non-zero (ReLU), per-channel peaks concentrated on about a
    quarter of the locations, and a street scene's label histogram (sky, road,
    building dominant) rather than 20 equally likely classes.
    """
    rng = np.random.default_rng(1)
    d, h, w, n_classes, k = 2048, 20, 31, 20, 10
    n = h * w
    label_p = np.array([0.34, 0.29, 0.23, 0.05, 0.05, 0.02] + [0.02 / 14] * 14)

    def tensor() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        features = rng.random((d, n), dtype=np.float32) * (rng.random((d, n)) < 0.09)
        hot = rng.choice(n, n // 4, replace=False)
        features[np.arange(d), rng.choice(hot, d)] += 2.0  # peaks on a few locations
        labels = rng.choice(n_classes, n, p=label_p).astype(np.uint8)
        probs = np.full((n_classes, n), 0.2 / (n_classes - 1), dtype=np.float32)
        probs[labels, np.arange(n)] = 0.8
        return features.reshape(d, h, w), probs, labels

    query_f, query_p, query_l = tensor()
    flat = query_f.reshape(d, -1)
    desc_ms = time_call(lambda: lost_descriptor(flat, query_p[:3], class_means(flat, query_l, 3)[0]), repeat)
    kp_ms = time_call(lambda: frame_evidence(query_f, query_l.reshape(h, w)), repeat)
    query = frame_evidence(query_f, query_l.reshape(h, w))
    refs = KeypointEvidence.stack([frame_evidence(f, lab.reshape(h, w)) for f, _, lab in (tensor() for _ in range(k))])
    verify_ms = time_call(lambda: verify(query, refs, np.full(k, 0.5)), repeat)
    stats = {"descriptor": summary(desc_ms), "keypoints": summary(kp_ms), "verify_10": summary(verify_ms)}
    authors = {"descriptor": 32.0, "verify_10": 68.0}
    rows = [
        ["LoST descriptor (Eq. 1-3)", stats["descriptor"]["median_ms"], authors["descriptor"],
         authors["descriptor"] / stats["descriptor"]["median_ms"]],
        ["keypoints + evidence", stats["keypoints"]["median_ms"], float("nan"), float("nan")],
        ["verify 10 candidates", stats["verify_10"]["median_ms"], authors["verify_10"],
         authors["verify_10"] / stats["verify_10"]["median_ms"]],
    ]
    return rows, {"shape": [d, h, w], "stages": stats, "authors_ms": authors}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000, help="reference frames in the map")
    parser.add_argument("--repeat", type=int, default=50, help="timed queries per stage")
    args = parse(parser, "core", quick="a 100-frame map, 5 timed queries per stage")
    if args.quick:
        args.frames, args.repeat = 100, 5

    rows, real = real_stages(args.frames, args.repeat)
    print_table(f"MOSAIC, real frames, {args.frames}-frame map: ms per query frame",
                ["stage", "median ms", "p90 ms"], rows)
    print(f"map bytes per reference frame: {real['map_bytes_per_frame'] / 1e3:.1f} kB "
          f"({10e6 / real['map_bytes_per_frame']:.0f}x smaller than the authors' 10 MB)")
    rows, paper = paper_shaped(args.repeat)
    print_table("authors' tensor shapes (2048 x 20 x 31): ms per query frame",
                ["stage", "lostx median ms", "authors' code ms", "speed-up"], rows)
    write_json(args.out, {"benchmark": "core", "real": real, "paper_shaped": paper})


if __name__ == "__main__":
    main()
