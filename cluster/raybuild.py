"""Describing a map's frames on a Ray cluster: ``lostx map build SOURCE --out MAP --ray [ADDRESS]``.

The traverse is cut into chunks of ``CHUNK_FRAMES`` frames; each Ray worker (an actor that loads
the backbone once, on a GPU of its own where the cluster has them) describes a chunk at a time,
with the 7 frames on either side that the 15-frame class-mean window needs, and sends the chunk
back. The driver keeps every chunk in the build's checkpoint as it arrives and commits the map
as a single-process build does: the map is the same, byte for byte, and an interrupted cluster
build resumes like any other.

The workers read the frames themselves: the traverse (its file paths) is sent to them, so its
files must be where every worker can read them (one machine, or a shared file system).
"""

from __future__ import annotations

import logging
from typing import Any, Callable

from lostx.core.build import FrameSource, describe_chunks, make_describer
from lostx.core.config import Config
from lostx.core.errors import InputError, LostxError
from lostx.core.maps.format import backbone_dict
from lostx.core.maps.mapwriter import CHUNK_FRAMES, MapChunk


def import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise InputError('--ray needs Ray: pip install "lostx[ray]"') from None
    return ray


class ChunkWorker:
    """One Ray worker: a describer built once, describing chunks of a traverse."""

    def __init__(self, config: Config, thumbnail: dict | None) -> None:
        self.config = config
        self.describer = make_describer(config, thumbnail)
        info = getattr(self.describer, "backbone", None)
        self.identity = backbone_dict(info.info) if info is not None else None

    def describe(self, frames: FrameSource, start: int, stop: int) -> tuple[list[MapChunk], dict | None]:
        return list(describe_chunks(frames, start, stop, self.config, self.describer)), self.identity


class RayDescribers:
    """Describes the ranges of a build on Ray (:class:`lostx.core.build.ChunkDescribers`).

    ``address``: the cluster to join (``auto``, ``ray://HOST:10001``, ...); None starts a Ray instance on
    this machine for the build (or joins the one ``RAY_ADDRESS`` names) and stops it after.
    ``workers``: describers at once (default: one per GPU where the cluster has GPUs, else one per
    ``backbone.threads`` CPUs). ``task_frames``: frames per task.
    """

    def __init__(self, address: str | None = None, workers: int | None = None,
                 task_frames: int = CHUNK_FRAMES) -> None:
        if workers is not None and workers < 1:
            raise InputError(f"--ray-workers must be at least 1, got {workers}")
        self.address = address
        self.workers = workers
        self.task_frames = task_frames

    def describe(self, frames: FrameSource, ranges: list[tuple[int, int]], config: Config, thumbnail: dict | None,
                 on_chunk: Callable[[MapChunk, dict | None], None]) -> None:
        ray = import_ray()
        from ray.util import ActorPool
        started = not ray.is_initialized()
        if started:
            try:
                ray.init(address=self.address, include_dashboard=False, logging_level=logging.ERROR,
                         log_to_driver=False, configure_logging=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise InputError(f"cannot reach the Ray cluster {self.address or '(local)'}: "
                                 f"{str(exc).splitlines()[0]}") from None
        actors: list[Any] = []
        try:
            resources = ray.cluster_resources()
            gpus, cpus = int(resources.get("GPU", 0)), float(resources.get("CPU", 1))
            threads = 1 if thumbnail is not None else config.backbone.threads
            workers = self.workers or (gpus if gpus else max(1, int(cpus) // threads))
            # Every worker must fit on the cluster at once: each takes its share of the CPUs (and GPUs).
            actor = ray.remote(num_cpus=min(float(threads), cpus / workers),
                               num_gpus=(min(1.0, gpus / workers) if gpus else 0),
                               runtime_env={"env_vars": {"OPENBLAS_NUM_THREADS": "1"}})(ChunkWorker)
            actors = [actor.remote(config, thumbnail) for _ in range(workers)]
            pool = ActorPool(actors)
            shared = ray.put(frames)
            # A small build is still shared out: every worker gets a task where there are frames enough.
            frames_left = sum(stop - start for start, stop in ranges)
            step = max(1, min(self.task_frames, -(-frames_left // workers)))
            tasks = [(a, min(a + step, stop)) for start, stop in ranges for a in range(start, stop, step)]
            for chunks, identity in pool.map_unordered(lambda w, task: w.describe.remote(shared, *task), tasks):
                for chunk in chunks:
                    on_chunk(chunk, identity)
        except ray.exceptions.RayTaskError as exc:
            cause = getattr(exc, "cause", None)
            if isinstance(cause, LostxError):
                raise cause from None
            raise
        finally:
            for worker in actors:
                ray.kill(worker)
            if started:
                ray.shutdown()
