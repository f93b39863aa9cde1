"""Map-building throughput on Ray with 1 and 2 workers, beside the single-process build, on this machine.

The same real frames (by default the first 400 Nordland summer frames) are described by the default
backbone, one thread per describer; Ray is started here with one CPU per worker. Throughput is
frames per second of the describing on Ray (the network and the descriptors, chunk by chunk,
Ray's start-up of the workers included), and of the whole build (the commit, the index and the
calibration after it run in the driver, the same in every build).
Every map is checked to hold the single-process build's descriptors, byte for byte.

    python benchmarks/bench_raybuild.py [--frames 400] [--workers 1 2] [--quick] [--out benchmarks/results/raybuild.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import json
import logging
import os
import tempfile
import time
from pathlib import Path

from common import parse, print_table, write_json
from lostx.core.build import build_map
from lostx.core.config import BackboneConfig, Config
from lostx.core.paths import data_dir
from lostx.replay.folder import folder_traverse


class Timed:
    """Wraps a build's describers (None: the build's own loop) to time the describing alone."""

    def __init__(self, inner) -> None:  # noqa: ANN001 (a ChunkDescribers)
        self.inner, self.seconds = inner, 0.0

    def describe(self, *args, **kwargs) -> None:  # noqa: ANN002, ANN003
        start = time.perf_counter()
        self.inner.describe(*args, **kwargs)
        self.seconds = time.perf_counter() - start


def digest(path: Path) -> str:
    return json.loads((path / "manifest.json").read_text())["arrays"]["descriptors"]["sha256"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--source", type=Path, default=data_dir() / "nordland-64x32" / "summer")
    args = parse(parser, "raybuild", quick="40 frames, one worker")
    if args.quick:
        args.frames, args.workers = 40, [1]

    import ray

    from lostx.cluster.raybuild import RayDescribers

    traverse = folder_traverse(args.source).subset(range(args.frames))
    config = Config(backbone=BackboneConfig(threads=1))
    rows, results = [], []
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        single = build_map(traverse, Path(tmp) / "single", config, progress=False)
        total = time.perf_counter() - start
        reference = digest(single.path)
        results.append({"build": "single process", "workers": 1, "seconds": total, "frames": single.n_frames})
        rows.append(["single process", 1, "-", single.n_frames / total, total, "(reference)"])
        for workers in args.workers:
            ray.init(num_cpus=workers, include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False,
                     configure_logging=False)
            try:
                timed = Timed(RayDescribers(workers=workers))
                start = time.perf_counter()
                built = build_map(traverse, Path(tmp) / f"ray{workers}", config, progress=False, cluster=timed)
                total = time.perf_counter() - start
            finally:
                ray.shutdown()
            same = digest(built.path) == reference
            results.append({"build": "ray", "workers": workers, "seconds": total, "describe_seconds": timed.seconds,
                            "frames": built.n_frames, "same_descriptors": same})
            rows.append([f"ray, {workers} worker{'s' if workers > 1 else ''}", workers,
                         built.n_frames / timed.seconds, built.n_frames / total, total, "yes" if same else "NO"])
    print_table(f"Building a map of {args.frames} frames ({args.source.name}), {os.cpu_count()} CPUs",
                ["build", "describers", "frames/s describing", "frames/s whole build", "whole build s",
                 "same descriptors"], rows)
    write_json(args.out, {"benchmark": "raybuild", "frames": args.frames, "source": str(args.source),
                          "cpus": os.cpu_count(), "results": results})


if __name__ == "__main__":
    main()
