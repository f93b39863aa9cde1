"""What the live Rerun view costs the localizer: frames per second with the sink off and with ``--rrd``.

    python benchmarks/bench_viz.py [--map MAP] [--queries DIR] [--frames 10] [--rounds 30] [--quick]
                                   [--out benchmarks/results/viz.json]

The RobotCar night frames (decoded once) are localized against the day map.
Each mode keeps one sink (one .rrd file) for the whole run; the run is
``--rounds`` rounds, and each round gives every mode one pass of ``--frames``
frames, in a shuffled order, so that bursts of load from other processes fall
on all modes alike. Reported per mode:

- fps: frames over the summed time of the passes (localizer step + sink call);
- slower: the median over rounds of 1 - fps(mode) / fps(off) in the same round,
  with its interquartile range;
- CPU ms/frame: the process's CPU time (all threads: the network's, the sink's
  worker, Rerun's encoder and file writer) per frame, the worker flushed at the
  end of each pass; other processes' load hardly moves it, so on a shared
  machine "extra CPU" is the steadier measure of what the view costs.

Modes:

- ``off``: no sink;
- ``rrd``: the sink as ``--rrd FILE`` makes it (images, label maps, lines and
  the sequence window at most 10 frames a second, on a background thread);
- ``rrd-frame-by-frame``: as ``rrd``, but each frame handed over whole, as the sink does for a
  live viewer (``SinkSettings.frame_by_frame``), instead of letting Rerun batch frames: what
  keeping the panels in step costs;
- ``rrd-new-refs``: as ``rrd``, but no reference image is kept: each match to
  another reference decodes its original image (the first run along a long
  route, where every match is new; on this 10-frame map the memory cache would
  otherwise hold them all);
- ``rrd-disk-refs``: the same, but each reference's JPEG is read from the disk
  cache a previous run left (later runs against the same map);
- ``rrd-every-frame``: images, label maps, lines and the sequence window for every frame (``--viewer-rate 0``);
- ``rrd-inline``: every frame, on the localizer's own thread (the whole logging
  cost lands on the localizer).
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import json
import os
import platform
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

from common import parse
from lostx.core.backbones import load_backbone
from lostx.core.build import build_map
from lostx.core.config import Config
from lostx.core.describe.describer import LostDescriber
from lostx.core.frame import Frame
from lostx.core.localizer import Localizer
from lostx.core.paths import data_dir
from lostx.core.maps.refmap import ReferenceMap
from lostx.replay.folder import folder_traverse
from lostx.viz.images import ReferenceImages
from lostx.viz.sink import RerunSink, SinkSettings
from lostx.viz.target import ViewerOutput

def modes(disk: Path) -> dict[str, SinkSettings | None]:
    """The sink settings of each mode; ``disk`` holds the reference-image cache (in the run's temp folder)."""
    return {
        "off": None,
        "rrd": SinkSettings(reference_disk_cache=disk / "rrd"),
        "rrd-frame-by-frame": SinkSettings(frame_by_frame=True, reference_disk_cache=disk / "frame-by-frame"),
        "rrd-new-refs": SinkSettings(reference_cache=1, reference_disk_cache=None),
        "rrd-disk-refs": SinkSettings(reference_cache=1, reference_disk_cache=disk / "warm"),
        "rrd-every-frame": SinkSettings(heavy_hz=None, reference_disk_cache=disk / "every-frame"),
        "rrd-inline": SinkSettings(heavy_hz=None, background=False, reference_disk_cache=disk / "inline"),
    }


@dataclasses.dataclass
class Pass:
    seconds: float
    cpu_seconds: float
    frames: int
    caller_seconds: float = 0.0


def run_pass(localizer: Localizer, frames: list[Frame], sink: RerunSink | None) -> Pass:
    localizer.reset()
    caller = sink.seconds if sink is not None else 0.0
    cpu = time.process_time()
    start = time.perf_counter()
    for frame in frames:
        estimate = localizer.step(frame)
        if sink is not None:
            sink(frame, estimate)
    elapsed = time.perf_counter() - start
    if sink is not None:
        sink.flush()  # the worker's last frame: its CPU time belongs to this pass (not its wall time)
    return Pass(elapsed, time.process_time() - cpu, len(frames), (sink.seconds - caller) if sink is not None else 0.0)


def _quartiles(values: list[float]) -> tuple[float, float]:
    if len(values) < 2:
        return values[0], values[0]
    q = statistics.quantiles(values, n=4)
    return q[0], q[2]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", type=Path, help="reference map (default: build the RobotCar day map in a temp folder)")
    parser.add_argument("--queries", type=Path, help="query images (default: the RobotCar night frames)")
    parser.add_argument("--frames", type=int, default=10, help="frames per pass (the queries cycled)")
    parser.add_argument("--rounds", type=int, default=30)
    args = parse(parser, "viz", quick="3 frames a pass, 2 rounds", argv=argv)
    if args.quick:
        args.frames, args.rounds = 3, 2

    robotcar = data_dir() / "robotcar-daynight"
    config = Config()
    backbone = load_backbone(config.backbone)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        if args.map is None:
            day = robotcar / "day"
            build_map(folder_traverse(day), tmpdir / "day", config, LostDescriber(backbone, config.lost),
                      {"camera": "front", "image_root": str(day.resolve())}, progress=False)
        refmap = ReferenceMap.open(args.map or tmpdir / "day")
        queries = list(folder_traverse(args.queries or robotcar / "night"))
        localizer = Localizer(refmap, config, backbone)
        settings_of = modes(tmpdir / "thumbs")
        warm = ReferenceImages(refmap, SinkSettings().image_width, SinkSettings().jpeg_quality,
                               disk=settings_of["rrd-disk-refs"].reference_disk_cache)  # type: ignore[union-attr]
        for index in range(refmap.n_frames):
            warm.get(index)
        sinks = {mode: RerunSink(refmap, ViewerOutput(rrd=tmpdir / f"{mode}.rrd"), settings)
                 for mode, settings in settings_of.items() if settings is not None}

        def frames_of(round_: int) -> list[Frame]:
            # Frame ids keep increasing over the run: one timeline per sink.
            ids = range(round_ * args.frames, (round_ + 1) * args.frames)
            return [dataclasses.replace(queries[i % len(queries)], id=i, timestamp=0.1 * i) for i in ids]

        run_pass(localizer, frames_of(0)[:5], None)  # warm-up
        runs: dict[str, list[Pass]] = {mode: [] for mode in settings_of}
        order = list(settings_of)
        shuffle = random.Random(0)
        for round_ in range(args.rounds):
            shuffle.shuffle(order)
            for mode in order:
                runs[mode].append(run_pass(localizer, frames_of(round_), sinks.get(mode)))
            if (round_ + 1) % 5 == 0:
                print(f"round {round_ + 1}/{args.rounds}", file=sys.stderr)
        stats = {}
        for mode, sink in sinks.items():
            sink.close()
            n = args.frames * args.rounds
            stats[mode] = {"heavy_logged": sink.heavy_logged, "heavy_dropped": sink.heavy_dropped,
                           "references_decoded": sink.match_view.references.decoded,
                           "rrd_kb_per_frame": (tmpdir / f"{mode}.rrd").stat().st_size / 1e3 / n}

    table = []
    off = runs["off"]
    for mode, passes in runs.items():
        frames = sum(p.frames for p in passes)
        slower = [1.0 - (o.seconds / p.seconds) for p, o in zip(passes, off)]
        extra_cpu = [p.cpu_seconds / o.cpu_seconds - 1.0 for p, o in zip(passes, off)]
        table.append({
            "mode": mode,
            "fps": frames / sum(p.seconds for p in passes),
            "slowdown": statistics.median(slower),
            "slowdown_iqr": _quartiles(slower),
            "cpu_ms_per_frame": 1e3 * sum(p.cpu_seconds for p in passes) / frames,
            "extra_cpu": statistics.median(extra_cpu),
            "extra_cpu_iqr": _quartiles(extra_cpu),
            "caller_ms_per_frame": 1e3 * sum(p.caller_seconds for p in passes) / frames,
            **stats.get(mode, {}),
        })

    load_after = os.getloadavg()
    print(f"\nlocalizer with the Rerun sink: {args.rounds} rounds x {args.frames} frames per mode, "
          f"{refmap.n_frames}-frame map; {os.cpu_count()} CPUs, load average {load_before[0]:.1f} before, "
          f"{load_after[0]:.1f} after")
    print(f"{'mode':<16s} {'fps':>6s} {'slower':>7s} {'(IQR)':>15s} {'CPU ms/frame':>13s} {'extra CPU':>10s} "
          f"{'(IQR)':>13s} {'caller ms/frame':>16s} {'heavy frames':>13s} {'refs decoded':>13s} {'rrd kB/frame':>13s}")
    for row in table:
        lo, hi = row["slowdown_iqr"]
        clo, chi = row["extra_cpu_iqr"]
        print(f"{row['mode']:<16s} {row['fps']:6.2f} {100 * row['slowdown']:6.1f}% "
              f"{f'({100 * lo:.1f}, {100 * hi:.1f})':>15s} {row['cpu_ms_per_frame']:13.1f} "
              f"{100 * row['extra_cpu']:9.1f}% {f'({100 * clo:.1f}, {100 * chi:.1f})':>13s} "
              f"{row['caller_ms_per_frame']:16.2f} {row.get('heavy_logged', 0):13d} "
              f"{row.get('references_decoded', 0):13d} {row.get('rrd_kb_per_frame', 0.0):13.1f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "benchmark": "viz",
        "frames_per_pass": args.frames,
        "rounds": args.rounds,
        "map_frames": refmap.n_frames,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                    "load_average_before": load_before, "load_average_after": load_after},
        "modes": table,
    }, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
