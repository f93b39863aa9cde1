"""Building a reference map from a traverse."""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from tqdm import tqdm

from .config import Config
from .describe import DescribedFrame, LostDescriber
from .errors import MapError
from .frame import Frame
from .inputcheck import ProfileBuilder
from .lost import centred_window, window_means
from .calibration import calibrate
from .camera import Geometry
from .refmap import MapFrame, MapWriter, ReferenceMap
from .thumbnail import ThumbnailDescriber


@dataclass
class BuildSummary:
    path: Path
    n_frames: int
    seconds: float
    bytes: int

    @property
    def bytes_per_frame(self) -> float:
        return self.bytes / max(self.n_frames, 1)


def _windowed(
    frames: Iterable[Frame], describe: Callable[[np.ndarray], DescribedFrame], geometry: Geometry, window: int
) -> Iterable[tuple[Frame, DescribedFrame, np.ndarray]]:
    """Yield each frame with its class means averaged over a centred window (clipped at the ends).

    Frames stream through: frame j is finished as soon as frame j + window // 2
    has been described, so at most ``window`` frames are held at a time.
    """
    half = window // 2
    held: deque[tuple[int, Frame, DescribedFrame]] = deque()
    done = 0

    def finish(j: int, length: int) -> tuple[Frame, DescribedFrame, np.ndarray]:
        span = centred_window(j, length, window)
        chosen = [d for i, _, d in held if span.start <= i < span.stop]
        mu, _ = window_means(np.stack([d.means for d in chosen]), np.stack([d.present for d in chosen]))
        _, frame, described = next(item for item in held if item[0] == j)
        while held and held[0][0] < j + 1 - half:
            held.popleft()
        return frame, described, mu

    count = 0
    for i, frame in enumerate(frames):
        held.append((i, frame, describe(geometry.prepare(frame.image, frame.camera))))
        count = i + 1
        if i - half >= done:
            yield finish(done, count)
            done += 1
    while done < count:
        yield finish(done, count)
        done += 1


def build_map(
    frames: Iterable[Frame],
    out: str | Path,
    config: Config | None = None,
    describer: LostDescriber | ThumbnailDescriber | None = None,
    metadata: dict | None = None,
    overwrite: bool = False,
    total: int | None = None,
    progress: bool = True,
    label: str | None = None,
) -> BuildSummary:
    """Describe every frame of a traverse and commit the map atomically.

    ``describer`` is a :class:`LostDescriber` (a LoST map: the default) or a
    :class:`ThumbnailDescriber` (a map of SeqSLAM thumbnails). Any error while
    reading or describing a frame aborts the build and leaves no map behind.
    ``label`` names the work on the progress bar (default: the map folder's name).
    """
    config = config or Config()
    if describer is None:
        from .backbones import load_backbone

        describer = LostDescriber(load_backbone(config.backbone), config.lost)
    start = time.perf_counter()
    kind = "lost" if isinstance(describer, LostDescriber) else "thumbnail"
    info = describer.backbone.info if isinstance(describer, LostDescriber) else None
    meta = dict(metadata or {})
    meta["settings"] = config.to_dict()
    if isinstance(describer, LostDescriber):
        meta["classes"] = describer.groups.spec()
        meta["label_names"] = list(describer.groups.label_names)
        geometry = Geometry.for_backbone(config.camera, config.camera.view_hfov_deg, config.backbone.fit,
                                         describer.backbone.info)
        meta["geometry"] = geometry.record()
    else:
        meta["thumbnail"] = describer.settings()
    profile = ProfileBuilder(meta.get("label_names"))
    bar = tqdm(total=total, desc=label or f"building {Path(out).name}", unit="frame", disable=not progress,
               leave=False)
    with MapWriter(out, kind, meta, backbone=info, overwrite=overwrite) as writer:
        try:
            if isinstance(describer, LostDescriber):
                for frame, described, mu in _windowed(_ticking(frames, bar), describer, geometry,
                                                      config.lost.reference_window):
                    profile.add(frame.image, described.labels)
                    writer.cameras.append(frame.camera)
                    writer.add(
                        MapFrame(frame.name, describer.descriptor(described, mu), described.evidence,
                                 described.appearance(), frame.position, frame.timestamp)
                    )
            else:
                for frame in _ticking(frames, bar):
                    profile.add(frame.image)
                    writer.cameras.append(frame.camera)
                    writer.add(MapFrame(frame.name, describer(frame.image), position=frame.position,
                                        timestamp=frame.timestamp))
        finally:
            bar.close()
        if not writer.frames:
            raise MapError("the traverse has no frames; nothing to build")
        writer.metadata["input"] = profile.profile().to_dict()
        # The map's camera is what its frames declare, unless the caller says otherwise: a declared query
        # camera is read against it (which way the query views and drives the route).
        writer.metadata.setdefault("camera", writer.cameras[0] if len(set(writer.cameras)) == 1 else None)
        path = writer.commit()
    refmap = ReferenceMap.open(path)
    backbone = describer.backbone if isinstance(describer, LostDescriber) else None
    frames_measured = min(refmap.n_frames, config.decision.calibration_frames)
    with tqdm(total=frames_measured, desc="calibrating", unit="frame", disable=not progress, leave=False) as bar:
        refmap.store_calibration(calibrate(refmap, config, backbone, progress=bar.update))
    return BuildSummary(path=path, n_frames=len(writer.frames), seconds=time.perf_counter() - start, bytes=writer.nbytes)


def _ticking(frames: Iterable[Frame], bar: tqdm) -> Iterable[Frame]:
    for frame in frames:
        yield frame
        bar.update(1)

