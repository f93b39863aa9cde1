"""A calibrated camera on a vehicle: its intrinsics, where it sits and which way it looks, and what that
says about the ground it sees.

Frames: the vehicle's x forward, y left, z up, its origin on the ground (z = 0 is the road plane); the
camera's x right, y down, z along the optical axis (OpenCV). The mounting is given as a position
(``x``, ``y``, ``z``: ``z`` is the camera's height over the road) and three angles in degrees: ``yaw``
anticlockwise from the vehicle's forward direction (180 for a rear camera), ``pitch`` positive looking
down, ``roll`` positive when the image's right side is higher. Intrinsics are in pixels of frames of
``width`` x ``height``; frames of another size are scaled to them.

A camera file (``camera.toml`` beside a folder of frames, or any file given with ``--camera-file``)
holds these numbers, flat::

    fx = 1252.8
    fy = 1252.8
    cx = 826.6
    cy = 470.0
    width = 1600
    height = 900
    x = 1.72        # metres forward of the vehicle's origin
    y = 0.0         # metres to the left
    z = 1.49        # metres above the road: the camera's height
    yaw = 0.0       # degrees; 180 for a camera looking backwards
    pitch = 0.0     # degrees, positive looking down
    roll = 0.0      # degrees, positive when the image's right side is higher
    body = 0.0      # share of the image height, at the bottom, that shows the vehicle itself
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError

CAMERA_FILE = "camera.toml"
"""The camera file a folder of frames may hold, read without any option."""

# Camera axes (x right, y down, z forward) in the vehicle frame of a level camera looking forward.
_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class CameraGeometry:
    """Pinhole intrinsics and the camera's pose on the vehicle (see the module docstring)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    x: float = 0.0
    y: float = 0.0
    z: float = 1.5
    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    body: float = 0.0
    source: str = field(default="", compare=False)
    """Where the numbers came from (a file, a dataset's calibration), for messages."""

    def __post_init__(self) -> None:
        where = f"{self.source}: " if self.source else ""
        for name in ("fx", "fy", "width", "height", "z"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"{where}camera {name} must be a positive number, got {value!r}")
        for name in ("cx", "cy", "x", "y", "yaw", "pitch", "roll"):
            if not math.isfinite(getattr(self, name)):
                raise InputError(f"{where}camera {name} must be a finite number, got {getattr(self, name)!r}")
        if abs(self.pitch) >= 60 or abs(self.roll) >= 60:
            raise InputError(f"{where}camera pitch {self.pitch:g} and roll {self.roll:g} degrees: a camera that sees "
                             f"the road ahead has both within 60 degrees of level")
        if not 0 <= self.body < 0.9:
            raise InputError(f"{where}camera body must be a share of the image height in [0, 0.9), got {self.body!r}")

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) camera axes in the vehicle frame (columns: right, down, forward)."""
        yaw, pitch, roll = (math.radians(a) for a in (self.yaw, self.pitch, self.roll))
        forward = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), -math.sin(pitch)])
        level_right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
        level_up = np.cross(level_right, forward)
        right = math.cos(roll) * level_right + math.sin(roll) * level_up
        down = np.cross(forward, right)
        return np.stack([right, down, forward], axis=1)

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z])

    @property
    def facing(self) -> str:
        """``front`` or ``rear``: which way along the vehicle the camera looks."""
        return "rear" if abs((self.yaw + 180.0) % 360.0 - 180.0) > 90.0 else "front"

    def scaled_to(self, width: int, height: int) -> "CameraGeometry":
        """The same camera for frames of ``width`` x ``height`` (the intrinsics scaled)."""
        if (width, height) == (self.width, self.height):
            return self
        sx, sy = width / self.width, height / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=(self.cx + 0.5) * sx - 0.5,
                       cy=(self.cy + 0.5) * sy - 0.5, width=int(width), height=int(height))

    def rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(..., 3) directions in the vehicle frame of the pixels (u, v) (not normalised)."""
        camera = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones(np.shape(u))], axis=-1)
        return camera @ self.rotation.T

    def ground(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the rays of pixels (u, v) meet the road plane: (..., 2) vehicle (x, y) in metres, and whether
        they meet it at all (below the horizon)."""
        rays = self.rays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
        down = rays[..., 2] < -1e-9
        scale = np.where(down, -self.z / np.where(down, rays[..., 2], -1.0), np.nan)
        return self.position[:2] + scale[..., None] * rays[..., :2], down

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., 2) pixels of vehicle-frame points (..., 3), and whether each lies in front of the camera."""
        camera = (np.asarray(points, dtype=np.float64) - self.position) @ self.rotation
        depth = camera[..., 2]
        safe = np.where(depth > 1e-9, depth, np.nan)
        return np.stack([self.fx * camera[..., 0] / safe + self.cx, self.fy * camera[..., 1] / safe + self.cy],
                        axis=-1), depth > 1e-9

    def horizon_row(self, u: float | None = None) -> float:
        """The image row of the horizon (where the road plane meets the sky, infinitely far) at column ``u``."""
        u = self.cx if u is None else u
        forward = self.rotation[:, 2]
        right = self.rotation[:, 0]
        down = self.rotation[:, 1]
        # A ray through (u, v) is level when its vehicle z is 0: solve for v.
        a = (u - self.cx) / self.fx
        return float(self.cy - self.fy * (forward[2] + a * right[2]) / down[2])

    def ground_row(self, distance: float) -> float:
        """The image row of the road ``distance`` metres ahead of the camera, straight along its axis."""
        forward = self.rotation[:, 2]
        level = forward[:2] / np.linalg.norm(forward[:2])
        (_, row), _ = self.project(np.array([*(self.position[:2] + distance * level), 0.0]))
        return float(row)

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "source"}

    @classmethod
    def from_pose(cls, intrinsics: np.ndarray, rotation: np.ndarray, translation: np.ndarray, width: int, height: int,
                  body: float = 0.0, source: str = "") -> "CameraGeometry":
        """From a 3x3 intrinsic matrix and the camera's rotation (its axes as columns, in the vehicle frame)
        and position in the vehicle frame, as datasets and transform trees give them."""
        k = np.asarray(intrinsics, dtype=np.float64)
        r = np.asarray(rotation, dtype=np.float64)
        forward, right = r[:, 2], r[:, 0]
        yaw = math.atan2(forward[1], forward[0])
        pitch = -math.asin(float(np.clip(forward[2], -1.0, 1.0)))
        level_right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
        level_up = np.cross(level_right, forward)
        roll = math.atan2(float(right @ level_up), float(right @ level_right))
        t = np.asarray(translation, dtype=np.float64)
        return cls(fx=float(k[0, 0]), fy=float(k[1, 1]), cx=float(k[0, 2]), cy=float(k[1, 2]), width=int(width),
                   height=int(height), x=float(t[0]), y=float(t[1]), z=float(t[2]), yaw=math.degrees(yaw),
                   pitch=math.degrees(pitch), roll=math.degrees(roll), body=body, source=source)


def quaternion_matrix(wxyz: Any) -> np.ndarray:
    """The rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(wxyz, dtype=np.float64) / np.linalg.norm(wxyz)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


_REQUIRED = ("fx", "fy", "cx", "cy", "width", "height")
_INTEGERS = ("width", "height")


def read_camera_file(path: str | Path) -> CameraGeometry:
    """A camera file (see the module docstring); an error naming the file and the field at fault."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"camera file not found: {path}") from None
    except IsADirectoryError:
        raise InputError(f"{path} is a folder; a camera file is a TOML file (see docs/datasets.md)") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid TOML camera file ({exc})") from None
    known = {f.name for f in fields(CameraGeometry)} - {"source"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InputError(f"{path}: unknown camera setting {unknown[0]!r}; known: {', '.join(sorted(known))}")
    missing = [name for name in _REQUIRED if name not in data]
    if missing:
        raise InputError(f"{path}: the camera file needs {', '.join(missing)} (intrinsics in pixels and the frame size)")
    values: dict[str, Any] = {}
    for name, value in data.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{path}: camera {name} must be a number, got {value!r}")
        if name in _INTEGERS and value != int(value):
            raise InputError(f"{path}: camera {name} must be a whole number of pixels, got {value!r}")
        values[name] = int(value) if name in _INTEGERS else float(value)
    return CameraGeometry(**values, source=str(path))


def write_camera_file(geometry: CameraGeometry, path: str | Path) -> None:
    """Write ``geometry`` as a camera file."""
    lines = [f"{name} = {value!r}" for name, value in geometry.to_dict().items()]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
