"""What the wire costs (issue 4): frames per second end to end against the Localizer alone.

End to end is replay -> serve -> listen on one machine: `lostx serve` runs as
its own process (lossless, so every frame is answered and counted), and this
process publishes the frames (a FramePublisher, as `lostx replay` does) and
listens to the results (a Listener, as `lostx listen` does). The frames are
the real 1024 x 640 RobotCar night frames, cycled. In the same run the
Localizer alone steps through the same frames in this process. The machine is
shared, so the batches are interleaved (alone, then each encoding streamed,
round after round) and medians are reported.

Per encoding:

- throughput: a batch sent as fast as the credit allows; frames per second from
  the first send to the last result, and CPU time per frame of everything
  involved (the service, the producer and the listener);
- added latency: one frame at a time; the round trip (send -> result received)
  minus the localizer's own step time (``latency_ms.total`` in the result), i.e.
  encoding, both sockets, decoding the image, the hand-offs, decoding the result.

    python benchmarks/bench_stream.py [--frames 10] [--rounds 3] [--pings 20] [--encodings raw,jpeg]
                                      [--transport tcp|ipc] [--quick] [--out benchmarks/results/stream.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import os
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from common import cpu_seconds, parse, print_table, write_json
from lostx.core import Config, Frame, Localizer, LostDescriber, ReferenceMap, load_backbone
from lostx.core.build import build_map
from lostx.core.paths import data_dir
from lostx.replay.folder import folder_traverse
from lostx.stream.client import Listener
from lostx.stream.processes import ProcessGroup, lostx_command
from lostx.stream.producer import FramePublisher
from lostx.stream.messages import Result
from lostx.stream.wire import encode_frame


def night_frames(n: int) -> list[Frame]:
    night = list(folder_traverse(data_dir() / "robotcar-daynight" / "night"))
    return [dataclasses.replace(night[i % len(night)], id=i) for i in range(n)]


def day_map(out: Path, backbone) -> ReferenceMap:
    day = folder_traverse(data_dir() / "robotcar-daynight" / "day")
    build_map(day, out, describer=LostDescriber(backbone), metadata={"camera": "front"}, progress=False)
    return ReferenceMap.open(out)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclasses.dataclass
class Batch:
    fps: float
    cpu_ms: float
    """CPU time per frame of everything involved."""


def alone_batch(localizer: Localizer, frames: list[Frame]) -> Batch:
    localizer.reset()  # a new traverse, as a new stream is for the service
    start, cpu = time.perf_counter(), time.process_time()
    for frame in frames:
        localizer.step(frame)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    return Batch(len(frames) / wall, 1e3 * cpu / len(frames))


class Arrivals(threading.Thread):
    """Results as they arrive: frame id -> (perf_counter at arrival, the result)."""

    def __init__(self, endpoint: str) -> None:
        super().__init__(daemon=True)
        self.listener = Listener(endpoint, topics=("result",))
        self.got: dict[int, tuple[float, Result]] = {}
        self.arrived = threading.Condition()
        self.halt = threading.Event()
        self.start()

    def run(self) -> None:
        while not self.halt.is_set():
            message = self.listener.receive(0.05)
            if isinstance(message, Result):
                with self.arrived:
                    self.got[message.frame_id] = (time.perf_counter(), message)
                    self.arrived.notify_all()
        self.listener.close()

    def wait(self, frame_id: int, timeout: float = 120.0) -> tuple[float, Result]:
        with self.arrived:
            if not self.arrived.wait_for(lambda: frame_id in self.got, timeout):
                raise RuntimeError(f"no result for frame {frame_id} within {timeout:.0f} s")
            return self.got[frame_id]


class Stream:
    """One running `lostx serve`, with this process as its producer and listener."""

    def __init__(self, procs: ProcessGroup, refmap: ReferenceMap, transport: str, tmp: Path) -> None:
        if transport == "tcp":
            self.frames_ep, results_ep = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
        else:
            self.frames_ep, results_ep = f"ipc://{tmp}/frames", f"ipc://{tmp}/results"
        self.arrivals = Arrivals(results_ep)
        self.service = procs.start("serve", lostx_command(
            "serve", "--map", str(refmap.path), "--frames", self.frames_ep, "--results", results_ep,
            "--mode", "lossless", "--no-journal"))
        self.publishers: dict[str, FramePublisher] = {}
        self.next_id = 0

    def publisher(self, encoding: str) -> FramePublisher:
        if encoding not in self.publishers:
            publisher = FramePublisher(self.frames_ep, encoding=encoding)
            publisher.wait_ready(120)
            self.publishers[encoding] = publisher
        return self.publishers[encoding]

    def _fresh_ids(self, frames: list[Frame]) -> list[Frame]:
        """The same frames under ids not used before (results are told apart by id)."""
        out = [dataclasses.replace(f, id=self.next_id + i) for i, f in enumerate(frames)]
        self.next_id += len(frames)
        return out

    def batch(self, frames: list[Frame], encoding: str, label: str) -> Batch:
        publisher = self.publisher(encoding)
        publisher.stream = label  # a new stream: the service's localizer starts afresh
        frames = self._fresh_ids(frames)
        start, cpu_here, cpu_service = time.perf_counter(), time.process_time(), cpu_seconds(self.service.pid)
        for frame in frames:
            publisher.send(frame, timeout=600)
        publisher.flush(600)
        last = self.arrivals.wait(frames[-1].id)[0]
        cpu = (time.process_time() - cpu_here) + (cpu_seconds(self.service.pid) - cpu_service)
        return Batch(len(frames) / (last - start), 1e3 * cpu / len(frames))

    def added_latency(self, frames: list[Frame], encoding: str) -> list[float]:
        """Round trip minus the localizer's own step time, one frame at a time (ms)."""
        publisher = self.publisher(encoding)
        publisher.stream = f"pings-{encoding}"
        added = []
        for frame in self._fresh_ids(frames):
            sent = time.perf_counter()
            publisher.send(frame, timeout=600)
            arrived, result = self.arrivals.wait(frame.id)
            added.append(1e3 * (arrived - sent) - result.latency_ms["total"])
        publisher.flush(60)
        return added

    def close(self) -> None:
        for publisher in self.publishers.values():
            publisher.close()
        self.arrivals.halt.set()
        self.arrivals.join(5)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10, help="frames per batch (default 10)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds of batches (default 3)")
    parser.add_argument("--pings", type=int, default=20, help="frames sent one at a time for latency (default 20)")
    parser.add_argument("--encodings", default="raw,jpeg", help="comma-separated: raw, png, jpeg (default raw,jpeg)")
    parser.add_argument("--transport", choices=["tcp", "ipc"], default="tcp", help="loopback TCP (default) or IPC")
    args = parse(parser, "stream", quick="3 frames a batch, one round, 3 pings")
    if args.quick:
        args.frames, args.rounds, args.pings = 3, 1, 3
    encodings = [e.strip() for e in args.encodings.split(",")]
    load_start = os.getloadavg()[0]
    frames = night_frames(args.frames)
    backbone = load_backbone()
    batches: dict[str, list[Batch]] = {"alone": [], **{e: [] for e in encodings}}
    added: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="lostx-bench-") as tmp, ProcessGroup(log_dir=tmp) as procs:
        refmap = day_map(Path(tmp) / "day", backbone)
        localizer = Localizer(refmap, Config(), backbone)
        stream = Stream(procs, refmap, args.transport, Path(tmp))
        try:
            for frame in frames[:2]:  # warm-up on both sides, not counted
                localizer.step(frame)
            for encoding in encodings:
                stream.batch(frames[:2], encoding, f"warmup-{encoding}")
            for r in range(args.rounds):
                batches["alone"].append(alone_batch(localizer, frames))
                for encoding in encodings:
                    batches[encoding].append(stream.batch(frames, encoding, f"{encoding}-{r}"))
            for encoding in encodings:
                added[encoding] = stream.added_latency(night_frames(args.pings), encoding)
        finally:
            stream.close()

    alone_fps = statistics.median(b.fps for b in batches["alone"])
    alone_cpu = statistics.median(b.cpu_ms for b in batches["alone"])
    rows = [["Localizer alone (in process)", alone_fps, 1.0, alone_cpu, 1.0, "-", "-", "-"]]
    runs = []
    for encoding in encodings:
        fps = statistics.median(b.fps for b in batches[encoding])
        cpu = statistics.median(b.cpu_ms for b in batches[encoding])
        ms = sorted(added[encoding])
        run = {
            "encoding": encoding, "bytes_per_frame": len(encode_frame(frames[0], encoding)),
            "fps": fps, "fps_batches": [b.fps for b in batches[encoding]],
            "ratio": fps / alone_fps, "wire_cost_percent": 100.0 * (1.0 - fps / alone_fps),
            "cpu_ms_per_frame": cpu, "cpu_ms_batches": [b.cpu_ms for b in batches[encoding]],
            "cpu_ratio": alone_cpu / cpu, "wire_cpu_cost_percent": 100.0 * (1.0 - alone_cpu / cpu),
            "added_latency_ms": {"median": statistics.median(ms), "p99": float(np.percentile(ms, 99)),
                                 "max": ms[-1], "n": len(ms)},
        }
        runs.append(run)
        rows.append([f"replay -> serve -> listen, {encoding}", fps, run["ratio"], cpu, run["cpu_ratio"],
                     f"{run['bytes_per_frame'] / 1e3:.0f} kB", f"{run['added_latency_ms']['median']:.2f}",
                     f"{run['added_latency_ms']['p99']:.2f}"])
    print_table(f"RobotCar night frames, 1024 x 640, lossless over {args.transport}; median of {args.rounds} "
                f"interleaved batches of {args.frames}; {os.cpu_count()} cores, load average {load_start:.1f}",
                ["", "frames/s", "ratio", "CPU ms/frame", "CPU ratio", "message", "added ms (median)",
                 "added ms (p99)"], rows)
    print(f"\nLocalizer alone per batch: {', '.join(f'{b.fps:.2f}' for b in batches['alone'])} frames/s")
    print("ratio: frames per second, streamed / alone (wall clock); CPU ratio: CPU time per frame, alone / "
          "streamed (service, producer and listener all counted).")
    for run in runs:
        print(f"{run['encoding']}: the wire costs {run['wire_cost_percent']:.1f} % of the frame rate "
              f"({run['wire_cpu_cost_percent']:.1f} % in CPU time) and adds "
              f"{run['added_latency_ms']['median']:.1f} ms per frame (median), "
              f"{run['added_latency_ms']['p99']:.1f} ms (p99); goal: under 10 %")
    write_json(args.out, {
        "frames_per_batch": args.frames, "rounds": args.rounds, "pings": args.pings, "image": [640, 1024, 3],
        "mode": "lossless", "transport": args.transport, "cores": os.cpu_count(),
        "load_average": {"start": load_start, "end": os.getloadavg()[0]},
        "localizer_alone": {"fps": alone_fps, "fps_batches": [b.fps for b in batches["alone"]],
                            "cpu_ms_per_frame": alone_cpu, "cpu_ms_batches": [b.cpu_ms for b in batches["alone"]]},
        "streamed": runs,
    })
    return 0


if __name__ == "__main__":
    sys.exit(main())
