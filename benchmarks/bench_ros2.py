"""What the ROS 2 path costs: frames per second through `lostx ros2` against `lostx match` on the same frames, and
the latency it adds per frame.

`lostx ros2` runs as its own process, as a user runs it, subscribed to two camera topics over DDS on loopback:
`/bench/image_raw` (sensor_msgs/Image, rgb8, 1.97 MB a frame) and `/bench/image_raw/compressed`
(CompressedImage, the frames' PNG files). This process publishes the real 1024 x 640 RobotCar night frames, cycled,
and subscribes to the answers. `lostx match --sequence` runs on the same frames (a folder of them, as PNG files)
and its own time per frame is taken (its loop of reading, decoding and stepping; its first frame's warm-up
included), and so is the same loop in this process, warmed up (the stricter comparison). All answer with the
same settings (a 3-frame sequence window). The machine is shared, so the runs are interleaved (match, then each topic,
round after round) and medians are reported.

- throughput: a batch published at once, reliable and keep-all (every frame answered, in order; DDS holds the
  publisher back); frames per second from the first frame published to the last answer received;
- added latency: one frame at a time; the round trip (published -> answer received) minus the localizer's own
  step time (the answer's `total` latency): serialising, DDS on loopback, decoding the image and the answer.

    python benchmarks/bench_ros2.py [--quick] [--frames 20] [--rounds 3] [--pings 20]
                                    [--out benchmarks/results/ros2.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import os
import random
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import cv2
import numpy as np

from common import parse, print_table, write_json
from lostx.core import Config, Localizer, LostDescriber, ReferenceMap, load_backbone
from lostx.core.build import build_map
from lostx.core.config import Ros2Config, SequenceConfig
from lostx.core.images import list_images
from lostx.core.paths import data_dir
from lostx.replay.folder import folder_traverse
from lostx.stream.processes import ProcessGroup, lostx_command

TOPICS = {"raw": "/bench/image_raw", "png": "/bench/image_raw/compressed"}
WINDOW = 3
T0 = 1_700_000_000_000_000_000
NIGHT = data_dir() / "robotcar-daynight" / "night"


class Arrivals(threading.Thread):
    """The answers as they arrive: (stream, frame) -> (perf_counter at arrival, the localizer's total ms, the
    node's decoding ms)."""

    def __init__(self, participant) -> None:
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from lostx.stream.ros2 import dds, msgs

        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet

        super().__init__(daemon=True)
        keep_all = dds.answer_qos(Ros2Config(answer_depth=10_000))
        self.reader = DataReader(participant, Topic(participant, "rt/lostx/place", msgs.Place), keep_all)
        self.waitset = WaitSet(participant)  # asleep until an answer comes: no CPU taken from the node
        self.waitset.attach(ReadCondition(self.reader, SampleState.Any | ViewState.Any | InstanceState.Any))
        self.got: dict[tuple[str, int], tuple[float, float, float]] = {}
        self.arrived = threading.Condition()
        self.halt = threading.Event()
        self.start()

    def run(self) -> None:
        from cyclonedds.util import duration

        while not self.halt.is_set():
            self.waitset.wait(duration(milliseconds=100))
            places = self.reader.take(64)
            now = time.perf_counter()
            if not places:
                continue
            with self.arrived:
                for place in places:
                    if place.sample_info.valid_data:
                        stages = {x.stage: x.ms for x in place.latency}
                        self.got[(place.stream, place.frame)] = (now, stages["total"], stages["decode"])
                self.arrived.notify_all()

    def wait(self, key: tuple[str, int], timeout: float = 300.0) -> tuple[float, float, float]:
        with self.arrived:
            if not self.arrived.wait_for(lambda: key in self.got, timeout):
                raise RuntimeError(f"no answer for {key} within {timeout:.0f} s")
            return self.got[key]


class Camera:
    """One topic's publisher, numbering its frames as the node does (from 0) and stamping them 0.1 s apart."""

    def __init__(self, participant, encoding: str) -> None:
        from cyclonedds.core import Policy, Qos
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        from lostx.stream.ros2 import msgs

        self.encoding, self.topic, self.msgs = encoding, TOPICS[encoding], msgs
        kind = msgs.Image if encoding == "raw" else msgs.CompressedImage
        qos = Qos(Policy.Reliability.Reliable(duration(seconds=60)), Policy.History.KeepAll,
                  Policy.DataRepresentation(use_cdrv0_representation=True))
        self.writer = DataWriter(participant, Topic(participant, f"rt{self.topic}", kind), qos)
        files = list_images(NIGHT)
        if encoding == "raw":
            self.payloads = [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in files]
        else:
            self.payloads = [f.read_bytes() for f in files]
        self.sent = 0

    def publish(self) -> int:
        """The next frame; its number."""
        k, m = self.sent, self.msgs
        stamp = T0 + k * 100_000_000
        header = m.Header(m.Time.from_ns(stamp), "camera_optical_frame")
        payload = self.payloads[k % len(self.payloads)]
        if self.encoding == "raw":
            h, w = payload.shape[:2]
            message = m.Image(header, h, w, "rgb8", 0, 3 * w, payload.tobytes())
        else:
            message = m.CompressedImage(header, "png", payload)
        self.writer.write(message)
        self.sent += 1
        return k

    def wait_matched(self, timeout: float = 300.0) -> None:
        end = time.monotonic() + timeout
        while self.writer.get_publication_matched_status().current_count == 0:
            if time.monotonic() > end:
                raise RuntimeError(f"lostx ros2 did not subscribe to {self.topic} within {timeout:.0f} s")
            time.sleep(0.05)


def cycled_night(folder: Path, frames: int) -> Path:
    """A folder of ``frames`` frames: the night frames cycled (links, in name order)."""
    folder.mkdir(parents=True, exist_ok=True)
    files = list_images(NIGHT)
    for k in range(frames):
        (folder / f"{k:06d}.png").symlink_to(files[k % len(files)])
    return folder


def match_batch(map_path: Path, folder: Path, out: Path) -> float:
    """`lostx match` itself on the frames of ``folder``: its frames per second, from the time per frame it
    reports (its loop of reading, decoding and stepping; not its start-up)."""
    proc = subprocess.run(lostx_command("match", str(map_path), str(folder), "--sequence", "--window", str(WINDOW),
                                        "--out", str(out), "--quiet"), capture_output=True, text=True, timeout=900)
    found = re.search(r"\((\d+) ms per frame", proc.stdout)
    if proc.returncode != 0 or found is None:
        raise RuntimeError(f"lostx match failed: {proc.stderr or proc.stdout}")
    return 1e3 / float(found.group(1))


def warm_batch(localizer: Localizer, folder: Path) -> float:
    """The same loop as `lostx match`'s in this process, warmed up: read, decode and step each frame. Frames/s."""
    localizer.reset()
    start = time.perf_counter()
    frames = 0
    for frame in folder_traverse(folder):
        localizer.step(frame)
        frames += 1
    return frames / (time.perf_counter() - start)


def ros2_batch(camera: Camera, arrivals: Arrivals, frames: int) -> float:
    start = time.perf_counter()
    numbers = [camera.publish() for _ in range(frames)]
    last = arrivals.wait((camera.topic, numbers[-1]))[0]
    return frames / (last - start)


def added_latency(camera: Camera, arrivals: Arrivals, pings: int) -> tuple[list[float], list[float]]:
    """Per frame sent alone: the round trip less the localizer's step, and the node's decoding (ms)."""
    added, decoding = [], []
    for _ in range(pings):
        sent = time.perf_counter()
        number = camera.publish()
        arrived, total, decode = arrivals.wait((camera.topic, number))
        added.append(1e3 * (arrived - sent) - total)
        decoding.append(decode)
    return added, decoding


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20, help="frames per batch (default 20)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds of batches (default 3)")
    parser.add_argument("--pings", type=int, default=20, help="frames sent one at a time for latency (default 20)")
    args = parse(parser, "ros2", quick="one round of 10 frames and 5 pings")
    if args.quick:
        args.frames, args.rounds, args.pings = 10, 1, 5
    load_start = os.getloadavg()[0]
    domain = random.SystemRandom().randrange(100, 200)
    # A discovery tag of this run's own: nothing else on the machine takes part.
    os.environ["CYCLONEDDS_URI"] = (f"<CycloneDDS><Domain><Discovery><Tag>lostx-bench-{uuid.uuid4().hex}</Tag>"
                                    f"</Discovery></Domain></CycloneDDS>")
    from lostx.stream.ros2 import dds

    backbone = load_backbone()
    fps: dict[str, list[float]] = {"match": [], "warm": [], **{e: [] for e in TOPICS}}
    added: dict[str, tuple[list[float], list[float]]] = {}
    with tempfile.TemporaryDirectory(prefix="lostx-bench-") as tmp, ProcessGroup(log_dir=tmp) as procs:
        build_map(folder_traverse(data_dir() / "robotcar-daynight" / "day"), Path(tmp) / "day",
                  describer=LostDescriber(backbone), progress=False)
        refmap = ReferenceMap.open(Path(tmp) / "day")
        frames_folder = cycled_night(Path(tmp) / "night", args.frames)
        localizer = Localizer(refmap, Config(sequence=SequenceConfig(length=WINDOW)), backbone)
        participant = dds.participant(Ros2Config(domain_id=domain))
        arrivals = Arrivals(participant)
        cameras = {e: Camera(participant, e) for e in TOPICS}
        procs.start("ros2", lostx_command(
            "ros2", "--map", str(refmap.path), "--topic", TOPICS["raw"], "--topic", TOPICS["png"],
            "--image-qos", "reliable", "--image-depth", "0", "--window", str(WINDOW), "--domain-id", str(domain)))
        try:
            for camera in cameras.values():
                camera.wait_matched()
            warm_batch(localizer, frames_folder)  # warm-up, not counted
            for camera in cameras.values():
                ros2_batch(camera, arrivals, 2)
            for _ in range(args.rounds):
                fps["match"].append(match_batch(refmap.path, frames_folder, Path(tmp) / "match.csv"))
                fps["warm"].append(warm_batch(localizer, frames_folder))
                for encoding, camera in cameras.items():
                    fps[encoding].append(ros2_batch(camera, arrivals, args.frames))
            for encoding, camera in cameras.items():
                added[encoding] = added_latency(camera, arrivals, args.pings)
        finally:
            arrivals.halt.set()
            arrivals.join(5)
        procs.stop("ros2")
        node_log = procs.log("ros2")
    match_fps, warm_fps = statistics.median(fps["match"]), statistics.median(fps["warm"])
    rows = [["lostx match --sequence (read, decode, step)", match_fps, 1.0, "-", "-", "-", "-", "-"],
            ["its loop in this process, warmed up", warm_fps, warm_fps / match_fps, 1.0, "-", "-", "-", "-"]]
    runs = []
    for encoding, topic in TOPICS.items():
        median_fps = statistics.median(fps[encoding])
        ms, decoding = sorted(added[encoding][0]), added[encoding][1]
        run = {"topic": topic, "encoding": encoding, "fps": median_fps, "fps_batches": fps[encoding],
               "ratio": median_fps / match_fps, "ratio_warm": median_fps / warm_fps,
               "added_latency_ms": {"median": statistics.median(ms), "p90": float(np.percentile(ms, 90)),
                                    "max": ms[-1], "n": len(ms)},
               "decode_ms": {"median": statistics.median(decoding)}}
        runs.append(run)
        kind = "Image rgb8, 1.97 MB" if encoding == "raw" else "CompressedImage png"
        rows.append([f"lostx ros2, {kind}", median_fps, run["ratio"], run["ratio_warm"],
                     f"{run['added_latency_ms']['median']:.1f}",
                     f"{run['added_latency_ms']['p90']:.1f}", f"{run['decode_ms']['median']:.1f}", len(ms)])
    print_table(f"RobotCar night frames, 1024 x 640, over DDS on loopback (Cyclone DDS); median of {args.rounds} "
                f"interleaved batches of {args.frames}; {os.cpu_count()} cores, load average {load_start:.1f}",
                ["", "frames/s", "x match", "x warm loop", "added ms (median)", "added ms (p90)", "of it decoding",
                 "pings"], rows)
    print(f"\nlostx match per batch: {', '.join(f'{v:.2f}' for v in fps['match'])} frames/s (its time per frame "
          f"includes its first frame's warm-up); warm loop: {', '.join(f'{v:.2f}' for v in fps['warm'])}")
    for run in runs:
        print(f"{run['topic']}: {run['ratio']:.3f} x lostx match's frame rate, {run['ratio_warm']:.3f} x its warm "
              f"loop's (goal: at least 0.95), {run['added_latency_ms']['median']:.1f} ms added per frame (median)")
    summary = [line for line in node_log.splitlines() if "answered" in line]
    if summary:
        print(f"lostx ros2: {summary[-1].split('lostx ros2: ', 1)[-1]}")
    write_json(args.out, {
        "frames_per_batch": args.frames, "rounds": args.rounds, "pings": args.pings, "image": [640, 1024, 3],
        "window": WINDOW, "cores": os.cpu_count(), "load_average": {"start": load_start, "end": os.getloadavg()[0]},
        "match": {"fps": match_fps, "fps_batches": fps["match"]},
        "warm_loop": {"fps": warm_fps, "fps_batches": fps["warm"]}, "ros2": runs,
    })
    return 0


if __name__ == "__main__":
    sys.exit(main())
