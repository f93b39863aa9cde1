"""A frame's layout grid from its own labels and those of the frames around it, moved together by the motion.

One frame sees the road ahead from one place; a few frames gathered along the distance travelled fill in
the stretch and its sides (accumulating with the motion roughly doubled the places found on the nuScenes
front/rear frames, docs/opposite-view.md). Which frames are gathered is set in metres travelled, not in
frames, so that it does not depend on the frame rate:

- a live frame: those of the last ``query_travel`` metres (never a future one);
- a map frame: those within ``map_travel`` metres on either side (the map is known in advance);

at most ``max_frames`` of them, spread evenly over that distance.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..config import LayoutConfig, MotionConfig
from ..frame import Frame
from ..geometry import CameraGeometry
from ..motion.odometer import Odometer
from .classes import ROAD, LayoutClasses
from .curve import opposite_turns, turned_about_centre
from .grid import Gathering, LayoutGrid, accumulate
from .projection import FramePoints, GroundProjector


@dataclass(frozen=True)
class Placed:
    """A frame's road-plane evidence, where its camera stood and how far the stream had travelled."""

    points: FramePoints
    pose: np.ndarray
    """(3,) the camera's ground frame in the stream's odometry frame."""
    travelled: float
    """Metres travelled since the stream's first frame."""
    progress: float = 0.0
    """Metres advanced along the camera's own axis (signed, :class:`lostx.core.motion.odometer.Placement`)."""
    step: np.ndarray | None = None
    """(3,) the camera's ground frame in the previous frame's."""
    known: bool = True
    """Whether the motion from the previous frame is known (:class:`lostx.core.motion.odometer.Placement`)."""


def spread(travelled: np.ndarray, low: float, high: float, limit: int, keep: int) -> np.ndarray:
    """Indices of the frames whose distance travelled lies in [low, high], at most ``limit`` of them, spread
    evenly over that distance; frame ``keep`` (the one the grid is for) always among them."""
    inside = np.flatnonzero((travelled >= low - 1e-9) & (travelled <= high + 1e-9))
    if len(inside) <= limit:
        return inside
    targets = np.linspace(low, high, limit)
    chosen = {int(inside[np.argmin(np.abs(travelled[inside] - t))]) for t in targets}
    chosen.add(int(keep))
    return np.array(sorted(chosen), dtype=np.int64)


def keep_apart(kept: deque[tuple[int, Placed]], number: int, frame: Placed, spacing: float) -> None:
    """Append ``frame`` (its ``number`` in the stream) to ``kept``, frames kept at least ``spacing`` metres apart but
    for the newest: where the newest kept lies within the spacing of the one before it, the new frame takes its
    place, so that the frames kept span their distance at any frame rate, and a stop keeps the road before it."""
    if len(kept) > 1 and kept[-1][1].travelled - kept[-2][1].travelled < spacing:
        kept.pop()
    kept.append((number, frame))


class Projectors:
    """The road-plane look-up of each camera and label-map shape met so far (built once each)."""

    def __init__(self, classes: LayoutClasses, config: LayoutConfig) -> None:
        self.classes, self.config = classes, config
        self._built: dict[tuple, GroundProjector] = {}

    def __call__(self, labels: np.ndarray, geometry: CameraGeometry, image_size: tuple[int, int],
                 box: tuple[float, float, float, float] | None = None) -> FramePoints:
        """A frame's evidence from its label map; ``image_size`` (width, height) of the frame as it came, whose
        region ``box`` (default: all of it) the label map covers."""
        camera = geometry.scaled_to(*image_size)
        key = (camera, labels.shape, box)
        projector = self._built.get(key)
        if projector is None:
            projector = self._built[key] = GroundProjector(camera, labels.shape, self.classes, self.config.max_range,
                                                           box)
        return projector(labels)


class FramePlacer:
    """A stream's frames placed on the road plane: each frame's evidence and where its camera stood, from its
    label map and the stream's motion (its odometry, or visual odometry on the frames)."""

    def __init__(self, classes: LayoutClasses, layout: LayoutConfig, motion: MotionConfig) -> None:
        self.classes = classes
        self.projectors = Projectors(classes, layout)
        self.odometer = Odometer(motion)

    def reset(self) -> None:
        self.odometer.reset()

    def state(self) -> dict:
        """The stream's motion so far (:meth:`Odometer.state`)."""
        return {"odometer": self.odometer.state()}

    def restore(self, state: dict) -> None:
        self.odometer.restore(state["odometer"])

    def __call__(self, frame: Frame, label_map: np.ndarray,
                 box: tuple[float, float, float, float] | None = None) -> Placed | None:
        """``label_map`` covers the region ``box`` of the frame's image (all of it by default). None for a
        frame without a camera geometry, or without motion."""
        if frame.geometry is None:
            return None
        height, width = frame.image.shape[:2]
        ids = label_map.astype(np.intp, copy=False)
        whole = box is None or tuple(box) == (0.0, 0.0, float(width), float(height))
        # Visual odometry takes masks over the whole frame; a label map of part of it gives none (nor does a frame
        # its odometry places). The road alone: kerbs and sidewalks stand above its plane.
        masks = whole and not self.odometer.uses_odometry(frame)
        ground, movers = (self.classes.ray[ids] == ROAD, self.classes.is_mover[ids]) if masks else (None, None)
        placement = self.odometer.place(frame, ground, movers)
        if placement is None:
            return None
        points = self.projectors(label_map, frame.geometry, (width, height), box)
        return Placed(points, placement.pose, placement.travelled, placement.progress, placement.step,
                      placement.known)


class LiveLayout:
    """The grids of a live stream: each frame's with those of the distance travelled just before it (kept a short
    distance apart, whatever the frame rate)."""

    def __init__(self, config: LayoutConfig) -> None:
        self.config = config
        self._recent: deque[tuple[int, Placed]] = deque()
        """The frames kept, each with its number in the stream."""
        self._numbers = itertools.count()
        self._spacing = config.query_travel / (4 * config.max_frames)
        """Metres between the frames kept (but the newest): four to choose from for each one gathered."""

    def reset(self) -> None:
        self._recent.clear()

    def state(self) -> dict:
        """The frames of the distance travelled just before, each with its evidence and pose, as plain values and
        arrays."""
        return {"recent": [dataclasses.asdict(placed) for _, placed in self._recent]}

    def restore(self, state: dict) -> None:
        """Continue from :meth:`state`."""
        self._recent = deque(
            (next(self._numbers),
             Placed(FramePoints(**p["points"]), np.asarray(p["pose"], dtype=np.float64), float(p["travelled"]),
                    float(p["progress"]), np.asarray(p["step"], dtype=np.float64), bool(p["known"])))
            for p in state["recent"])

    def add(self, frame: Placed) -> Gathering:
        """The newest frame's grid, to be gathered (:class:`.grid.Gathering`)."""
        cfg = self.config
        if not frame.known:
            self._recent.clear()  # where it stood against the frames before is unknown: they cannot be gathered
        keep_apart(self._recent, next(self._numbers), frame, self._spacing)
        while self._recent and self._recent[0][1].travelled < frame.travelled - cfg.query_travel - 1e-9:
            self._recent.popleft()
        while len(self._recent) > 4 * cfg.max_frames:
            self._recent.popleft()
        travelled = np.array([p.travelled for _, p in self._recent])
        chosen = [self._recent[i] for i in spread(travelled, frame.travelled - cfg.query_travel, frame.travelled,
                                                  cfg.max_frames, len(self._recent) - 1)]
        return Gathering(tuple(p.points for _, p in chosen), tuple(n for n, _ in chosen),
                         tuple(n for n, _ in self._recent), np.stack([p.pose for _, p in chosen]), frame.pose, cfg)


def map_grid(frames: list[Placed], index: int, config: LayoutConfig, turn: float = 0.0) -> LayoutGrid:
    """The grid of map frame ``frames[index]`` from the frames around it (within ``map_travel`` metres either
    side, at most ``max_frames``), gathered in its camera's ground frame turned by ``turn`` degrees about its centre
    point (the grid turned by ``-turn``, every point counted where it lands: nothing resampled)."""
    travelled = np.array([f.travelled for f in frames])
    centre = travelled[index]
    chosen = spread(travelled, centre - config.map_travel, centre + config.map_travel, config.max_frames, index)
    picked = [frames[i] for i in chosen]
    current = frames[index].pose if turn == 0.0 else turned_about_centre(frames[index].pose, turn, config.centre)
    return accumulate([f.points for f in picked], np.stack([f.pose for f in picked]), current, config)


def route_reach(config: LayoutConfig) -> float:
    """Metres of route on each side of a map frame its grids need: the frames it gathers, and the route around its
    other end (:func:`.curve.opposite_turns`: about ``2 * centre`` along, searched ``centre`` either side)."""
    return max(config.map_travel, 3.0 * config.centre)


def map_grids(frames: list[Placed], index: int, config: LayoutConfig) -> tuple[LayoutGrid, LayoutGrid]:
    """Map frame ``frames[index]``'s grid as its camera views the stretch, and as the camera at the stretch's other
    end views it, turned back to face the same way (:mod:`.curve`: the two differ where the road bends). The frames
    are the map's route around it, in order."""
    turn = float(opposite_turns(np.stack([f.pose for f in frames]), config.centre, np.array([index]))[0])
    return map_grid(frames, index, config), map_grid(frames, index, config, turn)
