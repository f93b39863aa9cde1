"""The frame: what every source (a folder, a dataset reader, a socket) hands the localizer."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:  # only named in annotations: the CLI's parser reads this module's vocabulary without numpy
    import numpy as np

    from .geometry import CameraGeometry

Camera = Literal["front", "rear"]
CAMERAS: tuple[str, ...] = ("front", "rear")
Heading = Literal["same", "opposite"]
"""How a query camera views the route relative to the map's camera: the same way, or the opposite way
(a rear camera against a front-camera map, or the route driven in the other direction)."""
HEADINGS: tuple[str, ...] = ("same", "opposite")


@dataclass
class Frame:
    """One camera frame in a traverse or a stream."""

    id: int
    """Frame number in its stream (0-based position in name order for a folder)."""
    image: np.ndarray
    """RGB uint8, H x W x 3."""
    timestamp: float | None = None
    """Seconds; ``None`` where the source has no clock."""
    camera: Camera | None = None
    """Which way the camera faces along the direction of travel, where the source declares it
    (a prior on the heading relative to the map); ``None``: not declared."""
    position: tuple[float, float] | None = None
    """Ground-truth position, for evaluation only: the localizer never reads it."""
    name: str = ""
    """File name or other label of the frame."""
    metadata: dict[str, Any] = field(default_factory=dict)
    geometry: CameraGeometry | None = None
    """The camera's intrinsics and its pose on the vehicle, where the source knows them (the layout needs
    them; ``None``: no layout)."""
    odometry: tuple[float, float, float] | None = None
    """The vehicle's pose (x, y in metres, yaw in radians) in the odometry frame of its source, where it
    has one (wheel or visual odometry, a localisation): only the motion between frames is used, never
    the pose itself. ``None``: the motion is estimated from the frames (visual odometry)."""
