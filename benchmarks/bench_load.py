"""One service, many robots: frames per second and latency with 1, 4 and 16 concurrent streams,
with the result journal on and off.

`lostx serve --mode lossless` runs as its own process on a thumbnail map of the
Nordland summer traverse (the localizer's per-frame work is then about a
millisecond, so the service itself is what is measured, not the network).
This process plays the robots: N producer threads, each a FramePublisher with
its own stream id, send their share of the Nordland winter frames as fast as
the credit allows, and one listener thread (a Listener, as `lostx listen`)
takes every answer. Every configuration starts a fresh service; the
configurations are interleaved, round after round (the machine is shared),
and medians are reported.

- frames/s: answers per second from the first frame sent to the last answer received;
- latency: a frame handed to the producer's socket -> its answer received by the listener
  (in lossless mode this includes the wait behind the other streams' frames in the queue);
- service p99: the service's own frame read -> answer handed to the socket, from its final stats;
- service CPU: CPU time of the service process (all its threads) per frame, steadier than the wall
  clock on a shared machine;
- journal: the same with `--journal DIR` (every answer written and fsync'ed before its frame is
  acknowledged) against `--no-journal`, as ratios within the run.

    python benchmarks/bench_load.py [--frames 1200] [--streams 1,4,16] [--rounds 2] [--quick] [--out benchmarks/results/load.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from common import cpu_seconds, parse, print_table, write_json
from lostx.core import Frame
from lostx.core.build import build_map
from lostx.core.paths import data_dir
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.replay.folder import folder_traverse
from lostx.stream.client import Listener
from lostx.stream.processes import ProcessGroup, lostx_command
from lostx.stream.producer import FramePublisher
from lostx.stream.messages import Result, Stats


@dataclasses.dataclass
class Run:
    streams: int
    journal: bool
    fps: float
    latency_ms: list[float]
    service_p99_ms: float
    service_cpu_ms: float
    """CPU time of the service per frame."""

    def summary(self) -> dict:
        return {"streams": self.streams, "journal": self.journal, "fps": self.fps,
                "latency_ms": {"p50": float(np.percentile(self.latency_ms, 50)),
                               "p99": float(np.percentile(self.latency_ms, 99)), "n": len(self.latency_ms)},
                "service_p99_ms": self.service_p99_ms, "service_cpu_ms_per_frame": self.service_cpu_ms}


class Arrivals(threading.Thread):
    """Every answer as it arrives: (stream, frame id) -> perf_counter; and the service's final stats."""

    def __init__(self, endpoint: str, expected: int) -> None:
        super().__init__(daemon=True)
        self.listener = Listener(endpoint)
        self.expected = expected
        self.at: dict[tuple[str, int], float] = {}
        self.final: Stats | None = None
        self.all_in = threading.Event()
        self.halt = threading.Event()
        self.start()

    def run(self) -> None:
        while not self.halt.is_set():
            message = self.listener.receive(0.05)
            if isinstance(message, Result):
                self.at[(message.tag.stream, message.frame_id)] = time.perf_counter()
                if len(self.at) == self.expected:
                    self.all_in.set()
            elif isinstance(message, Stats) and message.final:
                self.final = message
        self.listener.close()


def produce(endpoint: str, stream: str, frames: list[Frame], sent: dict, ready: threading.Barrier) -> None:
    with FramePublisher(endpoint, stream=stream) as publisher:
        publisher.wait_ready(120)
        ready.wait()
        for frame in frames:
            publisher.send(frame, timeout=600)
            sent[(stream, frame.id)] = time.perf_counter()
        publisher.flush(600)


def one_run(procs: ProcessGroup, map_path: Path, frames: list[Frame], streams: int, journal: bool, tmp: Path,
            tag: str) -> Run:
    frames_ep, results_ep = f"ipc://{tmp}/{tag}-frames", f"ipc://{tmp}/{tag}-results"
    storage = ["--journal", str(tmp / f"{tag}-journal")] if journal else ["--no-journal"]
    name = f"serve-{tag}"
    arrivals = Arrivals(results_ep, len(frames) // streams * streams)
    service = procs.start(name, lostx_command("serve", "--map", str(map_path), "--frames", frames_ep, "--results", results_ep,
                                    "--mode", "lossless", "--max-streams", "64", *storage))
    length = len(frames) // streams  # each robot drives its own stretch of the route, frame ids from 0
    share = [[dataclasses.replace(f, id=i) for i, f in enumerate(frames[k * length:(k + 1) * length])]
             for k in range(streams)]
    sent: dict[tuple[str, int], float] = {}
    barrier = threading.Barrier(streams + 1)
    threads = [threading.Thread(target=produce, args=(frames_ep, f"robot-{k}", share[k], sent, barrier), daemon=True)
               for k in range(streams)]
    for thread in threads:
        thread.start()
    barrier.wait()
    start, cpu = time.perf_counter(), cpu_seconds(service.pid)
    for thread in threads:
        thread.join()
    if not arrivals.all_in.wait(120):
        raise RuntimeError(f"{tag}: {len(arrivals.at)} of {arrivals.expected} answers arrived")
    cpu = cpu_seconds(service.pid) - cpu
    last = max(arrivals.at.values())
    procs.stop(name, timeout=30)
    deadline = time.monotonic() + 10
    while arrivals.final is None and time.monotonic() < deadline:
        time.sleep(0.05)
    arrivals.halt.set()
    arrivals.join(5)
    latency = [1e3 * (arrivals.at[key] - t) for key, t in sent.items()]
    service_p99 = arrivals.final.latency_ms["service"]["p99"] if arrivals.final else float("nan")
    return Run(streams, journal, arrivals.expected / (last - start), latency, service_p99,
               1e3 * cpu / arrivals.expected)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1200, help="frames per run, shared by the streams (default 1200)")
    parser.add_argument("--streams", default="1,4,16", help="concurrent streams per run (default 1,4,16)")
    parser.add_argument("--rounds", type=int, default=2, help="interleaved rounds of all runs (default 2)")
    args = parse(parser, "load", quick="20 frames a run, 1 and 2 streams, one round")
    if args.quick:
        args.frames, args.streams, args.rounds = 20, "1,2", 1
    counts = [int(n) for n in args.streams.split(",")]
    load_start = os.getloadavg()[0]
    winter = list(folder_traverse(data_dir() / "nordland-64x32" / "winter"))
    frames = [winter[i % len(winter)] for i in range(args.frames)]
    runs: dict[tuple[int, bool], list[Run]] = {(n, j): [] for n in counts for j in (False, True)}
    with tempfile.TemporaryDirectory(prefix="lostx-load-") as tmp_name, ProcessGroup(log_dir=tmp_name) as procs:
        tmp = Path(tmp_name)
        map_path = tmp / "summer"
        build_map(folder_traverse(data_dir() / "nordland-64x32" / "summer"), map_path, describer=ThumbnailDescriber(),
                  metadata={"camera": "front"}, progress=False)
        for r in range(args.rounds):
            order = [(n, j) for n in counts for j in (False, True)]
            if r % 2:
                order.reverse()
            for n, journal in order:
                tag = f"r{r}-n{n}-{'j' if journal else 'nj'}"
                run = one_run(procs, map_path, frames, n, journal, tmp, tag)
                runs[(n, journal)].append(run)
                print(f"  {tag}: {run.fps:.0f} frames/s, latency p99 {np.percentile(run.latency_ms, 99):.1f} ms",
                      file=sys.stderr)

    def med(n: int, journal: bool, key) -> float:
        return statistics.median(key(run) for run in runs[(n, journal)])

    def fps(run: Run) -> float:
        return run.fps

    def p99(run: Run) -> float:
        return float(np.percentile(run.latency_ms, 99))

    def p50(run: Run) -> float:
        return float(np.percentile(run.latency_ms, 50))

    def service(run: Run) -> float:
        return run.service_p99_ms

    def cpu(run: Run) -> float:
        return run.service_cpu_ms

    rows, table = [], []
    for n in counts:
        for journal in (False, True):
            rows.append([n, "on" if journal else "off", med(n, journal, fps), med(n, journal, p50),
                         med(n, journal, p99), med(n, journal, service), med(n, journal, cpu),
                         med(n, journal, fps) / med(n, False, fps), med(n, journal, p99) / med(n, False, p99),
                         med(n, journal, cpu) / med(n, False, cpu)])
            table.append({"streams": n, "journal": journal, "fps": med(n, journal, fps),
                          "latency_p50_ms": med(n, journal, p50), "latency_p99_ms": med(n, journal, p99),
                          "service_p99_ms": med(n, journal, service), "service_cpu_ms_per_frame": med(n, journal, cpu),
                          "fps_vs_journal_off": rows[-1][7], "p99_vs_journal_off": rows[-1][8],
                          "cpu_vs_journal_off": rows[-1][9], "runs": [run.summary() for run in runs[(n, journal)]]})
    print_table(f"One lossless service, Nordland winter frames against a thumbnail map of summer; {args.frames} "
                f"frames per run, median of {args.rounds} interleaved rounds; {os.cpu_count()} cores, load average "
                f"{load_start:.1f}",
                ["streams", "journal", "frames/s", "latency p50 ms", "latency p99 ms", "service p99 ms",
                 "service CPU ms/frame", "fps / off", "p99 / off", "CPU / off"], rows)
    one = med(counts[0], False, fps)
    for n in counts[1:]:
        print(f"{n} streams: {med(n, False, fps) / one:.2f} x the frames per second of {counts[0]} (journal off), "
              f"p99 latency {med(n, False, p99) / med(counts[0], False, p99):.1f} x")
    write_json(args.out, {
        "frames_per_run": args.frames, "rounds": args.rounds, "mode": "lossless", "transport": "ipc",
        "map": "thumbnail, nordland-64x32 summer (3576 frames)", "queries": "nordland-64x32 winter",
        "cores": os.cpu_count(), "load_average": {"start": load_start, "end": os.getloadavg()[0]},
        "configurations": table,
    })
    return 0


if __name__ == "__main__":
    sys.exit(main())
