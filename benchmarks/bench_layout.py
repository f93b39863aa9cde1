"""The layout's cost per frame beside the network's, and the map bytes it adds, in one run.

A 1,000-frame map is made of the 40 real nuScenes rear-camera frames (described with their layout, cycled, the
descriptors jittered so the search is not degenerate); the 40 front-camera frames query it with the scene's ego
poses as odometry. Per query frame: the network; everything after it (LoST descriptor, search, verification,
placing the frame and choosing the frames its layout grid gathers, gathering the grid and comparing it with every
map frame under both headings, the sequence filter following the distance travelled, the tracker); and, beside the
network, visual odometry on the same frames (what a source without odometry pays). The gathering and the comparison
run in a process of its own (on a map of this size) from the moment the frame is placed, beside its descriptor,
search and verification: "layout compare" is their own time there, "layout" choosing the frames, "cues" each cue's
own sequence filter and agreement under each heading and the combined ranking; "after the network" is the frame's
wall-clock time less the network's.

    python benchmarks/bench_layout.py [--frames 1000] [--repeat 80] [--quick] [--out benchmarks/results/layout.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from common import parse, print_table, summary, write_json
from lostx.core import Config, Localizer, LostDescriber, ReferenceMap, build_map, load_backbone
from lostx.core.layout.classes import ROAD, LayoutClasses
from lostx.core.layout.grid import pack_both
from lostx.core.maps.mapwriter import MapFrame, MapWriter
from lostx.core.motion.visual import VisualOdometry
from lostx.core.paths import data_dir
from lostx.replay.dataset import open_traverse

SCENE = data_dir() / "nuscenes-frontrear" / "scene-0523"
STAGES = ("descriptor", "search", "verify", "layout compare", "cues", "motion", "layout", "costs", "sequence",
          "tracker", "other heading")


def cycled_map(out: Path, real: ReferenceMap, describer: LostDescriber, frames: int,
               rng: np.random.Generator) -> ReferenceMap:
    """``frames`` map frames cycling through ``real``'s, each with its layout grid and step."""
    rear = list(open_traverse(SCENE / "rear"))
    described = [describer(f.image) for f in rear]
    steps = np.asarray(real._arrays["steps"])
    meta = {key: real.manifest[key] for key in ("classes", "label_names", "layout", "geometry", "camera")}
    with MapWriter(out, "lost", meta, backbone=describer.backbone.info) as writer:
        for i in range(frames):
            k = i % len(described)
            d = described[k]
            desc = describer.descriptor(d, d.means) + rng.normal(0, 0.01, d.means.size).astype(np.float32)
            layout = pack_both(real.layout_grid(k), real.layout_grid(k, "opposite"))
            writer.add(MapFrame(f"{i:06d}.jpg", desc, d.evidence, d.appearance(), layout=layout,
                                step=steps[k] if k else steps[1]))
        writer.commit()
    return ReferenceMap.open(out)


def localizer_stages(refmap: ReferenceMap, backbone, repeat: int) -> dict[str, dict[str, float]]:
    front = list(open_traverse(SCENE / "front"))
    samples: dict[str, list[float]] = {k: [] for k in ("network", *STAGES, "after the network")}
    localizer = Localizer(refmap, Config(), backbone)
    for t in range(max(repeat, len(front))):
        frame = front[t % len(front)]
        if t % len(front) == 0:
            localizer.reset()
        estimate = localizer.step(frame)
        latency = estimate.latency_ms
        for k in samples:
            if k in latency:
                samples[k].append(latency[k])
        samples["after the network"].append(latency["total"] - latency["network"])
    return {k: summary(v) for k, v in samples.items() if v}


def visual_odometry_ms(backbone, camera: str) -> dict[str, float]:
    traverse = open_traverse(SCENE / camera)
    classes = LayoutClasses.of_model(backbone.info.class_names)
    odometry = VisualOdometry(traverse.geometry)
    samples = []
    for frame in traverse:
        labels = backbone(frame.image).label_map
        ground, movers = classes.ray[labels] == ROAD, classes.is_mover[labels]
        start = time.perf_counter()
        odometry.step(frame.image, ground, movers)
        samples.append(1e3 * (time.perf_counter() - start))
    return summary(samples[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000, help="reference frames in the map")
    parser.add_argument("--repeat", type=int, default=80, help="timed query frames")
    args = parse(parser, "layout", quick="a 100-frame map, each of the 40 query frames once")
    if args.quick:
        args.frames, args.repeat = 100, 1
    backbone = load_backbone()
    describer = LostDescriber(backbone)
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        build_map(open_traverse(SCENE / "rear"), Path(tmp) / "real", describer=describer, progress=False)
        real = ReferenceMap.open(Path(tmp) / "real")
        refmap = cycled_map(Path(tmp) / "map", real, describer, args.frames, rng)
        layout_bytes = sum(refmap.manifest["arrays"][name]["bytes"] for name in ("layout_values", "layout_mask",
                                                                                  "steps")) / refmap.n_frames
        per_frame = refmap.nbytes / refmap.n_frames
        stages = localizer_stages(refmap, backbone, args.repeat)
    odometry = {camera: visual_odometry_ms(backbone, camera) for camera in ("front", "rear")}
    rows = [[k, v["median_ms"], v["p90_ms"]] for k, v in stages.items()]
    rows += [[f"visual odometry ({camera}; beside the network)", v["median_ms"], v["p90_ms"]]
             for camera, v in odometry.items()]
    print_table(f"MOSAIC, nuScenes front frames against a {args.frames}-frame map with its layout: ms per frame",
                ["stage", "median ms", "p90 ms"], rows)
    print(f"map bytes per frame: {per_frame / 1e3:.1f} kB, of which the layout (grid, mask, motion) "
          f"{layout_bytes:.0f} bytes")
    write_json(args.out, {"benchmark": "layout", "map_frames": args.frames, "stages": stages,
                          "visual_odometry": odometry, "map_bytes_per_frame": per_frame,
                          "layout_bytes_per_frame": layout_bytes})


if __name__ == "__main__":
    main()
