"""A stream's running pose on the road plane and the distance it has travelled, from whichever motion it has.

Each frame's camera *ground frame* (on the road under the camera, along its level axis, see
:mod:`lostx.core.layout.projection`) is placed in the stream's odometry frame:

- from the source's odometry (a frame's ``odometry``, the vehicle's pose) and the camera's pose on the
  vehicle, where frames carry it;
- else from visual odometry on the frames themselves (:mod:`.visual`), metric through the camera's height.

*Progress* is the distance travelled along the vehicle's own axis, signed: a vehicle driving forwards advances,
one reversing goes back, whichever way its camera is mounted (a camera looking sideways progresses as much as one
looking ahead). Two vehicles driving a road the same way progress together along it; driving it the other way,
against each other. The sequence filter lines frames up with a map by it (:mod:`lostx.core.route.sequence`), and
the cameras' mountings tell how that direction of travel goes with the heading (:func:`mounting`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..config import MotionConfig
from ..frame import Frame
from ..geometry import CameraGeometry
from .pose import camera_ground_pose, compose, relative


@dataclass(frozen=True)
class Placement:
    """Where a frame's camera stood, and how far the stream had come."""

    pose: np.ndarray
    """(3,) the camera's ground frame in the stream's odometry frame (x, y metres, yaw radians)."""
    travelled: float
    """Metres travelled since the stream's first frame (unsigned)."""
    progress: float
    """Metres advanced along the vehicle's own axis since the first frame (signed; see the module docstring)."""
    step: np.ndarray
    """(3,) this frame's ground frame in the previous frame's (zeros for the first frame)."""
    source: str
    """``odometry`` or ``visual``."""
    known: bool = True
    """Whether the distance moved since the previous frame is known: visual odometry cannot tell how far the camera
    moved until it has measured a first step (the road hidden, say, by a car following close behind)."""


class Odometer:
    """The running placement of one stream's frames (call :meth:`place` with every frame, in order)."""

    def __init__(self, config: MotionConfig | None = None) -> None:
        self.config = config or MotionConfig()
        self._visual = None
        self._visual_geometry: CameraGeometry | None = None
        self.reset()

    def reset(self) -> None:
        self._last: Placement | None = None
        self._scale_known = False
        self._pending_visual: dict | None = None
        if self._visual is not None:
            self._visual.reset()

    def uses_odometry(self, frame: Frame) -> bool:
        return frame.odometry is not None and self.config.source != "visual"

    def place(self, frame: Frame, ground: np.ndarray | None = None, movers: np.ndarray | None = None) -> Placement | None:
        """The frame's placement; None where no motion can be known (no odometry, and no camera geometry for
        visual odometry, or ``source = odometry`` without it). ``ground`` and ``movers``: optional masks of the
        frame's road-plane pixels and of things that move (from its segmentation), for visual odometry."""
        geometry = frame.geometry
        if geometry is None:
            return None
        if self.uses_odometry(frame):
            vehicle = np.asarray(frame.odometry, dtype=np.float64)
            pose = camera_ground_pose(vehicle, geometry)
            step = np.zeros(3) if self._last is None else relative(self._last.pose, pose)
            return self._advance(pose, step, "odometry", geometry)
        if self.config.source == "odometry":
            return None
        step = self._visual_step(frame, geometry, ground, movers)
        if self._last is None or step is None:
            # How far later frames are from this one is known only once visual odometry has measured a step.
            return self._advance(np.zeros(3) if self._last is None else self._last.pose, np.zeros(3), "visual",
                                 geometry, self._scale_known)
        self._scale_known |= step.measured
        motion = np.asarray(step.motion, dtype=np.float64)
        return self._advance(compose(self._last.pose, motion), motion, "visual", geometry, self._scale_known)

    def _visual_step(self, frame: Frame, geometry: CameraGeometry, ground: np.ndarray | None,
                     movers: np.ndarray | None):  # noqa: ANN202 (visual.Step | None)
        from .visual import VisualOdometry

        if self._visual is None or self._visual_geometry != geometry:
            self._visual = VisualOdometry(geometry, width=self.config.visual_width)
            self._visual_geometry = geometry
        if self._pending_visual is not None:
            self._visual.restore(self._pending_visual)
            self._pending_visual = None
        return self._visual.step(frame.image, ground, movers)

    def state(self) -> dict:
        """Where the stream stands (its last placement) and, where visual odometry places the frames, what it
        carries to the next frame, as plain values and arrays."""
        last = self._last
        visual = self._visual.state() if self._visual is not None else self._pending_visual
        return {"last": None if last is None else dataclasses.asdict(last), "scale_known": self._scale_known,
                "visual": visual}

    def restore(self, state: dict) -> None:
        """Continue from :meth:`state`; visual odometry's part is taken up at the next frame, whose camera it
        runs on."""
        self.reset()
        last = state["last"]
        if last is not None:
            self._last = Placement(**{**last, "pose": np.asarray(last["pose"], dtype=np.float64),
                                      "step": np.asarray(last["step"], dtype=np.float64)})
        self._scale_known = bool(state["scale_known"])
        self._pending_visual = state.get("visual")

    def _advance(self, pose: np.ndarray, step: np.ndarray, source: str, geometry: CameraGeometry,
                 known: bool = True) -> Placement:
        last = self._last
        travelled = 0.0 if last is None else last.travelled + float(np.hypot(step[0], step[1]))
        progress = 0.0 if last is None else last.progress + forwards(step, geometry.yaw)
        self._last = Placement(pose, travelled, progress, step, source, known)
        return self._last


def forwards(step: np.ndarray, yaw_deg: float | np.ndarray) -> float | np.ndarray:
    """Metres a step (in the camera's ground frame: x along its level axis, y to its left) moves the vehicle along
    its own axis, the camera mounted ``yaw_deg`` anticlockwise from it: the step turned into the vehicle's frame."""
    step = np.asarray(step, dtype=np.float64)
    yaw = np.radians(yaw_deg)
    return np.cos(yaw) * step[..., 0] - np.sin(yaw) * step[..., 1]


def mounting(query_yaw_deg: float, map_yaw_deg: float) -> int:
    """How the direction of travel goes with the heading for two cameras mounted on their vehicles at these yaws:
    +1 where they face their vehicles' same way (a heading ``same`` then means driving the map's way), -1 the
    opposite way (a front camera against a rear-camera map: ``same`` means driving the other way), 0 where they are
    mounted within 30 degrees of square to each other, where the heading says nothing about the travel."""
    c = float(np.cos(np.radians(query_yaw_deg - map_yaw_deg)))
    return 0 if abs(c) < 0.5 else (1 if c > 0 else -1)
