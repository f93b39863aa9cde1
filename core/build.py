"""Building a reference map from a traverse: describe every frame, commit the map atomically, calibrate.

Described frames are checkpointed in chunks beside the map folder (:mod:`lostx.core.maps.checkpoint`):
an interrupted build resumes from them. The describing runs here, or on a cluster
(:class:`ChunkDescribers`, e.g. Ray: :mod:`lostx.cluster`); either way every frame's class
means are averaged over the same centred window, so the map is the same.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterable, Iterator, Protocol, Sequence, TypeVar

import numpy as np
from tqdm import tqdm

from .config import Config, LayoutConfig
from .decide.calibration import store
from .describe.camera import Geometry
from .describe.describer import DescribedFrame, LostDescriber
from .describe.inputcheck import label_frequencies, looks
from .describe.lost import centred_window, window_means
from .describe.thumbnail import ThumbnailDescriber
from .errors import MapError
from .frame import Frame
from .layout.classes import LayoutClasses
from .layout.describer import FramePlacer, Placed, keep_apart, map_grids, route_reach
from .layout.grid import LayoutGrid, pack_both
from .localizer import calibrate
from .maps.checkpoint import BuildCheckpoint, missing_ranges
from .maps.format import BACKBONE_IDENTITY, MAP_VERSION, MapKind, backbone_dict
from .maps.mapwriter import CHUNK_FRAMES, MapChunk, MapFrame, MapWriter
from .maps.refmap import ReferenceMap


@dataclass
class BuildSummary:
    path: Path
    n_frames: int
    seconds: float
    bytes: int
    resumed: int = 0
    """Frames an earlier, interrupted run of the same build had described (taken from its checkpoint)."""

    @property
    def bytes_per_frame(self) -> float:
        return self.bytes / max(self.n_frames, 1)


class BuildInterrupted(KeyboardInterrupt):
    """Ctrl-C (or another stop signal) stopped a build; what it kept for the same build to resume from."""

    def __init__(self, kept: int, checkpoint: Path) -> None:
        super().__init__(kept, checkpoint)
        self.kept = kept
        """Frames described and kept in the checkpoint (0: none, or a traverse that cannot be resumed)."""
        self.checkpoint = checkpoint


class FrameSource(Protocol):
    """A traverse that can be cut into ranges and identified (lostx.replay's traverses are)."""

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[Frame]: ...

    def subset(self, indices: Sequence[int] | np.ndarray) -> "FrameSource": ...

    def fingerprint(self) -> list: ...


class ChunkDescribers(Protocol):
    """Describes ranges of a traverse elsewhere (other processes, other machines) and hands back chunks."""

    def describe(self, frames: FrameSource, ranges: list[tuple[int, int]], config: Config,
                 thumbnail: dict | None, on_chunk: Callable[[MapChunk, dict | None], None]) -> None:
        """Describe frames [start, stop) of each range, as :func:`describe_chunks` does with
        :func:`make_describer`, calling ``on_chunk`` with every chunk as it arrives and the backbone that
        described it (:func:`lostx.core.maps.format.backbone_dict`; None for thumbnails)."""


def make_describer(config: Config, thumbnail: dict | None) -> LostDescriber | ThumbnailDescriber:
    """The describer a build with these settings uses: ``config``'s backbone and LoST settings, or
    thumbnails of the given settings (:meth:`ThumbnailDescriber.settings`)."""
    if thumbnail is not None:
        return ThumbnailDescriber(tuple(thumbnail["size"]), thumbnail["patch"])  # type: ignore[arg-type]
    from .backbones import load_backbone

    return LostDescriber(load_backbone(config.backbone), config.lost)


def describe_chunks(frames: FrameSource, start: int, stop: int, config: Config,
                    describer: LostDescriber | ThumbnailDescriber) -> Iterator[MapChunk]:
    """Frames [start, stop) of a traverse as map chunks (of ``CHUNK_FRAMES`` frames at most)."""
    lost = isinstance(describer, LostDescriber)
    info = describer.backbone.info if lost else None
    n_labels = len(describer.groups.label_names) if lost else 0  # type: ignore[union-attr]
    run: list[MapFrame] = []
    first = start
    for index, frame in describe_range(frames, start, stop, config, describer):
        run.append(frame)
        if len(run) == CHUNK_FRAMES:
            yield MapChunk.of_frames(first, run, "lost" if lost else "thumbnail", info, n_labels)
            first, run = index + 1, []
    if run:
        yield MapChunk.of_frames(first, run, "lost" if lost else "thumbnail", info, n_labels)


@dataclass(eq=False)
class _Held:
    index: int
    frame: Frame
    described: DescribedFrame
    placed: Placed | None


def held_for_layout(layout: LayoutConfig) -> int:
    """Frames described before a range of a traverse for the route behind its first frames' layout grids (their
    gathering and the route around their other end, :func:`route_reach`). A whole traverse's build holds the route
    as far back as the grids need, whatever the frame rate."""
    return 4 * layout.max_frames


def waiting_for_layout(layout: LayoutConfig) -> int:
    """Described map frames waiting at most for the route ahead of them to reach as far as their layout grids need
    (at 30 frames a second and 7 m/s, 50 m): held as the map stores them, so that a build's memory stays bounded
    where the vehicle stands still."""
    return 16 * layout.max_frames


def route_spacing(layout: LayoutConfig) -> float:
    """Metres apart the route held for the map's layout grids keeps its frames: four to choose from for each frame a
    grid gathers, whatever the frame rate."""
    return layout.map_travel / (2 * layout.max_frames)


def _windowed(
    frames: Iterable[Frame], describe: Callable[[np.ndarray], DescribedFrame], geometry: Geometry, window: int,
    placer: FramePlacer | None = None,
) -> Iterator[tuple[int, Frame, DescribedFrame, np.ndarray, Placed | None]]:
    """Yield each frame with its class means averaged over a centred window, clipped at the ends of ``frames``, and,
    with a ``placer``, its placement on the road (None where it has none). Each image is fitted to the backbone by
    ``geometry`` for the camera its frame declares.

    Frames stream through: frame j is finished once frame j + window // 2 has been described, so at most
    window // 2 + 1 frames are held at a time.
    """
    half = window // 2
    held: deque[_Held] = deque()
    done = 0

    def finish(j: int, length: int) -> tuple[int, Frame, DescribedFrame, np.ndarray, Placed | None]:
        span = centred_window(j, length, window)
        chosen = [h.described for h in held if span.start <= h.index < span.stop]
        mu, _ = window_means(np.stack([d.means for d in chosen]), np.stack([d.present for d in chosen]))
        item = held[j - held[0].index]
        while held and held[0].index < j + 1 - half:
            held.popleft()
        return j, item.frame, item.described, mu, item.placed

    count = 0
    for i, frame in enumerate(frames):
        described = describe(geometry.prepare(frame.image, frame.camera))
        placed = None
        if placer is not None and described.label_map is not None:
            box = geometry.region((frame.image.shape[1], frame.image.shape[0]), frame.camera)
            placed = placer(frame, described.label_map, box)
        held.append(_Held(i, frame, described, placed))
        count = i + 1
        while done < count and i - done >= half:
            yield finish(done, count)
            done += 1
    while done < count:
        yield finish(done, count)
        done += 1


_Item = TypeVar("_Item")


def _with_grids(items: Iterable[tuple[int, _Item, Placed | None]], layout: LayoutConfig,
                ) -> Iterator[tuple[int, _Item, tuple[LayoutGrid, LayoutGrid] | None]]:
    """Each map frame's item (in order) with its layout grids (:func:`map_grids`: as its camera and as the other end
    of its stretch views it; None where the frame was not placed), once the route reaches :func:`route_reach`
    metres beyond it, :func:`waiting_for_layout` items wait, or the frames end.

    The route is held as the frames' placements :func:`route_spacing` apart (each waiting frame's own among them),
    as far back as the oldest waiting frame's grids reach: what the grids gather is set in metres, so a densely
    recorded traverse gives the grids a sparse one gives, and the memory held does not grow with the frame rate.
    """
    reach, spacing, limit = route_reach(layout), route_spacing(layout), waiting_for_layout(layout)
    route: deque[tuple[int, Placed]] = deque()
    waiting: deque[tuple[int, _Item, Placed | None]] = deque()

    def finish() -> tuple[int, _Item, tuple[LayoutGrid, LayoutGrid] | None]:
        j, item, placed = waiting.popleft()
        grids = None
        if placed is not None:
            around = dict(route)
            around[j] = placed
            order = sorted(around)
            grids = map_grids([around[i] for i in order], order.index(j), layout)
        oldest = next((p for _, _, p in waiting if p is not None), None)
        while route and oldest is not None and route[0][1].travelled < oldest.travelled - reach - 1e-9:
            route.popleft()
        return j, item, grids

    for j, item, placed in items:
        if placed is not None:
            keep_apart(route, j, placed, spacing)
        waiting.append((j, item, placed))
        newest = route[-1][1].travelled if route else None
        while waiting and (waiting[0][2] is None or len(waiting) > limit
                           or (newest is not None and newest >= waiting[0][2].travelled + reach)):
            yield finish()
    while waiting:
        yield finish()


def layout_placer(config: Config, describer: LostDescriber) -> FramePlacer | None:
    """What places a map's frames on the road for their layout, unless the layout is off or the model has no
    road (frames without a camera geometry then simply have none)."""
    if config.layout.enabled == "off":
        return None
    classes = LayoutClasses.of_model(describer.backbone.info.class_names)
    return None if classes is None else FramePlacer(classes, config.layout, config.motion)


def describe_range(frames: Iterable[Frame] | FrameSource, start: int, stop: int | None, config: Config,
                   describer: LostDescriber | ThumbnailDescriber) -> Iterator[tuple[int, MapFrame]]:
    """Map frames ``start`` to ``stop`` of a traverse (None: to its end), with their map indices.

    A LoST frame's class means need the ``lost.reference_window // 2`` frames on each side: those are
    described too (and no others), so any range gives the frames a whole-traverse build gives. Its layout grids
    need the route around it: a range is described from :func:`held_for_layout` frames before it (on a traverse
    with frames less than a metre apart, a range's first grids then gather less behind them than a whole build's).
    """
    if isinstance(describer, ThumbnailDescriber):
        for index, frame in _cut(frames, start, stop):
            yield index, MapFrame(frame.name, describer(frame.image), position=frame.position,
                                  timestamp=frame.timestamp, looks=looks(frame.image), camera=frame.camera)
        return
    geometry = Geometry.for_backbone(config.camera, config.camera.view_hfov_deg, config.backbone.fit,
                                     describer.backbone.info)
    n_labels = len(describer.groups.label_names)
    placer = layout_placer(config, describer)
    half = config.lost.reference_window // 2
    behind, ahead = ((held_for_layout(config.layout), waiting_for_layout(config.layout)) if placer is not None
                     else (0, 0))
    first = max(0, start - max(half, behind))
    cut = (frame for _, frame in _cut(frames, first, None if stop is None else stop + max(half, ahead)))

    def wanted(index: int) -> bool:
        return index >= start and (stop is None or index < stop)

    # The evidence as a map stores it, made as soon as the class means are known: the frame's whole features are
    # not held while its layout waits for the route ahead, nor until its chunk is packed.
    stored = ((j, _map_frame(describer, frame, desc, mu, placed, n_labels) if wanted(first + j) else None, placed)
              for j, frame, desc, mu, placed in _windowed(cut, describer, geometry, config.lost.reference_window,
                                                          placer))
    gridded = _with_grids(stored, config.layout) if placer is not None else ((j, f, None) for j, f, _ in stored)
    for j, frame, grids in gridded:
        index = first + j
        if stop is not None and index >= stop:
            break
        if frame is not None:
            yield index, frame if grids is None else replace(frame, layout=pack_both(*grids))


def _map_frame(describer: LostDescriber, frame: Frame, desc: DescribedFrame, mu: np.ndarray, placed: Placed | None,
               n_labels: int) -> MapFrame:
    return MapFrame(frame.name, describer.descriptor(desc, mu), desc.evidence.sparse(), desc.appearance(),
                    frame.position, frame.timestamp, looks(frame.image), label_frequencies(desc.labels, n_labels),
                    frame.camera, step=placed.step if placed is not None else None)


def _cut(frames: Iterable[Frame] | FrameSource, start: int, stop: int | None) -> Iterator[tuple[int, Frame]]:
    """Frames [start, stop) with their indices: cut out of a traverse that can be, read through otherwise."""
    if hasattr(frames, "subset") and hasattr(frames, "__len__"):
        end = len(frames) if stop is None else min(stop, len(frames))  # type: ignore[arg-type]
        if start < end:
            for offset, frame in enumerate(frames.subset(range(start, end))):  # type: ignore[union-attr]
                yield start + offset, frame
        return
    for index, frame in enumerate(frames):
        if stop is not None and index >= stop:
            return
        if index >= start:
            yield index, frame


def map_metadata(frames: Iterable[Frame] | FrameSource, config: Config, describer: LostDescriber | ThumbnailDescriber,
                 metadata: dict | None = None) -> dict:
    """What a map's manifest records of how its frames were described: the settings, and for a LoST map its classes,
    the network's view of the frames and, where the traverse's camera is calibrated, the layout's grid and camera."""
    meta = dict(metadata or {})
    meta["settings"] = config.to_dict()
    if isinstance(describer, LostDescriber):
        meta["classes"] = describer.groups.spec()
        meta["label_names"] = list(describer.groups.label_names)
        geometry = Geometry.for_backbone(config.camera, config.camera.view_hfov_deg, config.backbone.fit,
                                         describer.backbone.info)
        meta["geometry"] = geometry.record()
        camera = getattr(frames, "geometry", None)
        if camera is not None and layout_placer(config, describer) is not None:
            grid = ("cell", "length", "width", "centre", "max_range", "blur", "map_travel", "max_frames")
            meta["layout"] = {"settings": {name: getattr(config.layout, name) for name in grid},
                              "geometry": camera.to_dict()}
    else:
        meta["thumbnail"] = describer.settings()
    return meta


def build_map(
    frames: Iterable[Frame] | FrameSource,
    out: str | Path,
    config: Config | None = None,
    describer: LostDescriber | ThumbnailDescriber | None = None,
    metadata: dict | None = None,
    overwrite: bool = False,
    total: int | None = None,
    progress: bool = True,
    label: str | None = None,
    cluster: ChunkDescribers | None = None,
) -> BuildSummary:
    """Describe every frame of a traverse and commit the map atomically.

    ``describer`` is a :class:`LostDescriber` (a LoST map: the default) or a
    :class:`ThumbnailDescriber` (a map of SeqSLAM thumbnails). An error while reading or
    describing a frame, or an interruption, stops the build and leaves no map behind, but keeps
    what was described in the build's checkpoint: the same build started again resumes from it
    (for a traverse that can be identified: lostx.replay's can). ``cluster`` describes the frames
    elsewhere (with ``config``'s backbone and settings; the traverse must be one that can be cut).
    ``label`` names the work on the progress bar (default: the map folder's name).
    """
    config = config or Config()
    describer = describer or make_describer(config, None)
    start = time.perf_counter()
    kind: MapKind = "lost" if isinstance(describer, LostDescriber) else "thumbnail"
    info = describer.backbone.info if isinstance(describer, LostDescriber) else None
    meta = map_metadata(frames, config, describer, metadata)
    n_frames = len(frames) if hasattr(frames, "subset") and hasattr(frames, "__len__") else None  # type: ignore[arg-type]
    if cluster is not None and n_frames is None:
        raise MapError("describing on a cluster needs a traverse that can be cut into ranges (a folder, a dataset)")
    checkpoint = BuildCheckpoint(out, _build_key(frames, kind, meta, info))
    with MapWriter(out, kind, meta, backbone=info, overwrite=overwrite, spool=checkpoint.save,
                   verify=config.verify) as writer:
        saved = checkpoint.resume()
        for first, _, path in saved:
            writer.add_chunk(path, first)
        resumed = sum(stop - first for first, stop, _ in saved)
        bar = tqdm(total=total, initial=resumed, desc=label or f"building {Path(out).name}", unit="frame",
                   disable=not progress, leave=False)
        try:
            ranges = missing_ranges(saved, n_frames)
            if cluster is not None:
                def arrived(chunk: MapChunk, backbone: dict | None) -> None:
                    _check_same_backbone(backbone, info)
                    writer.add_chunk(checkpoint.save(chunk), chunk.start)
                    bar.update(len(chunk.names))

                thumbnail = describer.settings() if isinstance(describer, ThumbnailDescriber) else None
                cluster.describe(frames, ranges, config, thumbnail, arrived)  # type: ignore[arg-type]
            else:
                for first, stop in ranges:
                    for index, frame in describe_range(frames, first, stop, config, describer):
                        writer.add(frame, index)
                        bar.update(1)
                    writer.flush()
        except KeyboardInterrupt:
            with contextlib.suppress(Exception):
                writer.flush()  # what was described stays in the checkpoint
            raise BuildInterrupted(writer.n_frames if checkpoint.key is not None else 0, checkpoint.folder) from None
        except BaseException:
            with contextlib.suppress(Exception):
                writer.flush()  # what was described stays in the checkpoint
            raise
        finally:
            bar.close()
        if not writer.n_frames:
            raise MapError("the traverse has no frames; nothing to build")
        path = writer.commit()
    checkpoint.remove()
    refmap = ReferenceMap.open(path)
    backbone = describer.backbone if isinstance(describer, LostDescriber) else None
    frames_measured = min(refmap.n_frames, config.decision.calibration_frames)
    with tqdm(total=frames_measured, desc="calibrating", unit="frame", disable=not progress, leave=False) as cbar:
        store(refmap.path, calibrate(refmap, config, backbone, progress=cbar.update))
    return BuildSummary(path=path, n_frames=refmap.n_frames, seconds=time.perf_counter() - start, bytes=writer.nbytes,
                        resumed=resumed)


def _check_same_backbone(theirs: dict | None, info: object) -> None:
    mine = backbone_dict(info) or {}  # type: ignore[arg-type]
    differ = [what for key, what in BACKBONE_IDENTITY.items() if (theirs or {}).get(key) != mine.get(key)]
    if differ:
        raise MapError(f"the cluster's workers describe with another backbone than this build's ({', '.join(differ)} "
                       f"differ): give every worker the same model file")


def _build_key(frames: Iterable[Frame] | FrameSource, kind: MapKind, meta: dict, info: object) -> str | None:
    """What identifies a build, so that only the same build resumes from a checkpoint (None: a stream of frames
    that cannot be identified)."""
    fingerprint = getattr(frames, "fingerprint", None)
    if fingerprint is None or not hasattr(frames, "subset"):
        return None
    payload = {"frames": fingerprint(), "kind": kind, "metadata": meta, "backbone": backbone_dict(info),  # type: ignore[arg-type]
               "version": MAP_VERSION}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()
