"""A whole LoST map at city size, as ``lostx map build`` writes it and ``lostx match`` reads it: its bytes on disk, the
time to open it, the memory it takes to match, and the time per frame after the network.

The map is made of one real nuScenes scene's frames (``--scene``, the front camera, described once with the layout),
repeated along a route as long as asked: each map frame is a real frame's keypoint evidence, layout grids and motion,
with its LoST and appearance descriptors moved by noise (so that repeats are places of their own, as a city's streets
are). It is written through the map writer (chunks spooled to disk, arrays and index written at the commit, as a build
does), then opened and matched in a process of its own per size, so that each size's memory is its own: the
scene's front frames replayed as a live stream through the localizer with the defaults (``--costs`` aside: the index
and the looked-up costs from the sizes where ``auto`` turns them on), heading not declared.

Columns: the build (writing and indexing; the real frames' description is done once, before), the map's bytes on disk
per frame, the time to open the map and make the localizer (calibration given: the map's own takes minutes at a
million frames and is measured apart by ``study_calibration.py``), the process's resident memory after opening and its
peak while matching, and everything after the network per frame (median, p90).

    python benchmarks/bench_bigmap.py [--sizes 10000 100000] [--steps 40] [--scene scene-0523]
                                      [--costs auto|every|looked-up] [--quick] [--out benchmarks/results/bigmap.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import json
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from common import parse, print_table, summary, write_json

NOISE = 0.5
"""Noise on each descriptor component, relative to that component's spread over the real frames."""
SPACING = 2.0
"""Metres between map frames along the synthetic route (a city mapped at a frame every 2 m)."""


NOT_AFTER = ("network", "total")
"""The latencies that are not stages after the network."""


def resident() -> tuple[float, float]:
    """This process's resident memory now and at its peak, GB (Linux)."""
    from lostx.core.budget import proc_status

    status = proc_status("/proc/self/status")
    return status["VmRSS"] / 1e9, status["VmHWM"] / 1e9


def real_frames(scene: str, folder: Path) -> Path:
    """The scene's front-camera frames described as a map build describes them (with the layout), pickled once."""
    out = folder / "real.pickle"
    if out.is_file():
        return out
    from lostx.core import Config, LostDescriber, load_backbone
    from lostx.core.build import describe_range, map_metadata
    from lostx.core.paths import data_dir
    from lostx.replay.dataset import open_traverse

    config = Config()
    traverse = open_traverse(data_dir() / "nuscenes-frontrear" / scene / "front")
    describer = LostDescriber(load_backbone(), config.lost)
    frames = [frame for _, frame in describe_range(traverse, 0, None, config, describer)]
    meta = map_metadata(traverse, config, describer)
    out.write_bytes(pickle.dumps({"frames": frames, "meta": meta, "backbone": describer.backbone.info}))
    return out


def write_map(real: dict, n: int, out: Path, spool: Path) -> float:
    """An ``n``-frame map around the real frames (see the module's docstring); the seconds it took."""
    from lostx.core.maps.mapwriter import MapWriter

    frames, rng = real["frames"], np.random.default_rng(n)
    descriptors = np.stack([f.descriptor for f in frames])
    appearance = np.stack([f.appearance for f in frames])
    spread, look_spread = descriptors.std(axis=0) + 1e-6, appearance.std(axis=0) + 1e-6
    spooled = iter(range(10**9))

    def save(chunk):  # noqa: ANN001, ANN202
        path = spool / f"chunk-{next(spooled)}.npz"
        chunk.save(path)
        return path

    start = time.perf_counter()
    with MapWriter(out, "lost", real["meta"], backbone=real["backbone"], spool=save) as writer:
        for i in range(n):
            f = frames[i % len(frames)]
            writer.add(dataclasses.replace(
                f, name=f"{i:07d}",
                descriptor=(f.descriptor + rng.normal(0.0, NOISE, spread.shape) * spread).astype(np.float32),
                appearance=(f.appearance + rng.normal(0.0, NOISE, look_spread.shape) * look_spread).astype(np.float32),
                position=(SPACING * i, 0.0), timestamp=0.5 * i))
        writer.commit()
    return time.perf_counter() - start


def measure(map_path: Path, scene: str, steps: int, costs: str) -> dict:
    """Open the map, make a localizer (``costs``: the sequence costs, ``[sequence] costs``) and replay the scene's
    frames through it (in this process)."""
    from lostx.core import Config, Localizer, ReferenceMap, load_backbone
    from lostx.core.config import SequenceConfig
    from lostx.core.decide.calibration import Calibration
    from lostx.core.paths import data_dir
    from lostx.replay.dataset import open_traverse

    backbone = load_backbone()
    traverse = list(open_traverse(data_dir() / "nuscenes-frontrear" / scene / "front"))
    before = resident()[0]
    t0 = time.perf_counter()
    refmap = ReferenceMap.open(map_path)
    config = Config(sequence=SequenceConfig(costs=costs))  # type: ignore[arg-type]
    localizer = Localizer(refmap, config, backbone, calibration=Calibration(np.zeros(999), np.zeros(999), {}))
    opened = time.perf_counter() - t0
    after_open = resident()[0]
    stages = [localizer.step(frame).latency_ms for frame in traverse[:steps]]
    timed = stages[len(stages) // 2:]  # after the window filled
    now, peak = resident()
    return {"open_s": opened, "rss_before_open_gb": before, "rss_after_open_gb": after_open, "rss_now_gb": now,
            "rss_peak_gb": peak,
            "after_network": summary([sum(v for k, v in t.items() if k not in NOT_AFTER) for t in timed]),
            "stages_median_ms": {k: float(np.median([t.get(k, 0.0) for t in timed])) for k in timed[0]},
            "index": refmap.index is not None,
            "map_bytes": refmap.nbytes, "map_frames": refmap.n_frames}


def slowest(stages: dict[str, float], count: int = 3) -> str:
    """The ``count`` stages after the network that took longest, with their medians."""
    after = {k: v for k, v in stages.items() if k not in NOT_AFTER}
    return ", ".join(f"{k} {v:.3g}" for k, v in sorted(after.items(), key=lambda kv: -kv[1])[:count])


def child(args: argparse.Namespace) -> None:
    """One size, in its own process: build (unless built) and measure; the result as JSON on stdout's last line."""
    folder = Path(args.work)
    real = pickle.loads(real_frames(args.scene, folder).read_bytes())
    out = folder / f"map-{args.child}"
    built = None
    if not (out / "manifest.json").is_file():
        with tempfile.TemporaryDirectory(dir=folder) as spool:
            built = write_map(real, args.child, out, Path(spool))
    result = measure(out, args.scene, args.steps, args.costs)
    result["build_s"] = built
    print(json.dumps(result))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10000, 100000])
    parser.add_argument("--steps", type=int, default=40, help="frames matched per size (at most the scene's; the "
                        "second half timed, after the window filled)")
    parser.add_argument("--scene", default="scene-0523")
    parser.add_argument("--costs", choices=("auto", "every", "looked-up"), default="auto",
                        help="the sequence costs (default: as lostx chooses by the map's size)")
    parser.add_argument("--work", help="a folder for the maps (default: a temporary one, removed at the end)")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parse(parser, "bigmap", quick="a 2,000-frame map, 20 frames matched")
    if args.child is not None:
        child(args)
        return
    if args.quick:
        args.sizes, args.steps = [2000], 20
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(args.work or scratch)
        work.mkdir(parents=True, exist_ok=True)
        real_frames(args.scene, work)
        results = []
        for n in args.sizes:
            command = [sys.executable, __file__, "--child", str(n), "--steps", str(args.steps), "--scene", args.scene,
                       "--costs", args.costs, "--work", str(work), "--out", str(args.out)]
            done = subprocess.run(command, capture_output=True, text=True)
            if done.returncode != 0:
                raise SystemExit(f"the {n}-frame map failed:\n{done.stderr[-4000:]}")
            results.append(json.loads(done.stdout.strip().splitlines()[-1]))
    rows = [[r["map_frames"], "" if r["build_s"] is None else f"{r['build_s']:.0f}",
             r["map_bytes"] / r["map_frames"] / 1e3,
             r["open_s"], r["rss_after_open_gb"], r["rss_peak_gb"], r["after_network"]["median_ms"],
             r["after_network"]["p90_ms"], slowest(r["stages_median_ms"])] for r in results]
    print_table("A city-size map: disk, opening, memory and time per frame after the network",
                ["map frames", "build s", "kB per frame on disk", "open s", "RSS after open GB", "RSS peak GB",
                 "after network ms", "p90 ms", "slowest stages (median ms)"], rows)
    write_json(args.out, {"benchmark": "bigmap", "scene": args.scene, "costs": args.costs, "noise": NOISE,
                          "steps": args.steps, "sizes": results})


if __name__ == "__main__":
    main()
