"""What reading frames costs per format: opening a source, and decoding each frame.

The ten RobotCar day frames (1024 x 640), cycled to ``--frames`` frames, stored as a
folder of PNG files, a ROS 2 bag (raw ``rgb8`` images; PNG and JPEG ``CompressedImage``),
and an MPEG-4 video; each is opened with ``open_traverse`` and read forwards and
backwards (``Traverse.reversed``: bags then find each message through their index,
videos seek). Times are per frame, with the ratio to the folder's, measured in one run.

    python benchmarks/bench_readers.py [--frames 50] [--quick] [--out benchmarks/results/readers.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2

from common import parse, print_table, write_json
from lostx.core.images import list_images, read_image
from lostx.core.paths import data_dir
from lostx.replay.dataset import SourceOptions, open_traverse

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from bagtools import compressed_image, raw_image, write_bag  # noqa: E402  (the tests' bag writer)

T0 = 1_700_000_000_000_000_000


def make_sources(root: Path, frames: int) -> dict[str, tuple[Path, SourceOptions]]:
    files = list_images(data_dir() / "robotcar-daynight" / "day")
    cycled = [files[k % len(files)] for k in range(frames)]
    folder = root / "folder"
    folder.mkdir()
    for k, file in enumerate(cycled):
        (folder / f"{k:06d}.png").symlink_to(file)
    images = [read_image(f) for f in files]

    def messages():
        for k in range(frames):
            t = T0 + k * 100_000_000
            image = images[k % len(images)]
            yield "/raw", "sensor_msgs/msg/Image", raw_image(image, t, "rgb8"), t
            yield "/png", "sensor_msgs/msg/CompressedImage", compressed_image(image, t, ".png"), t
            yield "/jpeg", "sensor_msgs/msg/CompressedImage", compressed_image(image, t, ".jpg"), t

    bag = write_bag(root / "drive.mcap", messages())
    video = root / "drive.mp4"
    height, width = images[0].shape[:2]
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (width, height))
    for k in range(frames):
        writer.write(cv2.imread(str(cycled[k])))
    writer.release()
    return {
        "folder (PNG files)": (folder, SourceOptions()),
        "bag, sensor_msgs/Image rgb8": (bag, SourceOptions(topic="/raw")),
        "bag, CompressedImage PNG": (bag, SourceOptions(topic="/png")),
        "bag, CompressedImage JPEG": (bag, SourceOptions(topic="/jpeg")),
        "video (MPEG-4 Part 2)": (video, SourceOptions()),
    }


def per_frame_ms(frames) -> float:
    start = time.perf_counter()
    count = sum(1 for _ in frames)
    return 1e3 * (time.perf_counter() - start) / count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=50)
    args = parse(parser, "readers", quick="5 frames")
    if args.quick:
        args.frames = 5
    rows, results = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        sources = make_sources(Path(tmp), args.frames)
        for name, (path, options) in sources.items():
            start = time.perf_counter()
            traverse = open_traverse(path, options=options)
            opened = 1e3 * (time.perf_counter() - start)
            forwards = min(per_frame_ms(traverse) for _ in range(2))
            backwards = min(per_frame_ms(traverse.reversed()) for _ in range(2))
            results[name] = {"open_ms": opened, "forwards_ms_per_frame": forwards,
                             "backwards_ms_per_frame": backwards, "frames": len(traverse)}
    folder = results["folder (PNG files)"]["forwards_ms_per_frame"]
    for name, r in results.items():
        rows.append([name, r["open_ms"], r["forwards_ms_per_frame"], r["forwards_ms_per_frame"] / folder,
                     r["backwards_ms_per_frame"], r["backwards_ms_per_frame"] / folder])
    print_table(f"reading {args.frames} frames of 1024 x 640 (ratios to the folder read forwards)",
                ["source", "open ms", "ms/frame", "x folder", "reversed ms/frame", "x folder"], rows)
    write_json(args.out, {"frames": args.frames, "results": results})


if __name__ == "__main__":
    main()
